"""Calibration solvers: arrays in, typed results out. No I/O, no drivers, no truth."""
