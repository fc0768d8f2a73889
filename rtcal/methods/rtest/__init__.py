"""The R-test of a trunnion table (issue 42): written against rtcal.api alone, and rtcal.solvers for mathematics."""
