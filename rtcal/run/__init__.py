"""The runner above the engine: a procedure run or resumed end to end, its directory, its digests, its
verification, the control statement, and the instruments checked before a run (probe, check)."""
