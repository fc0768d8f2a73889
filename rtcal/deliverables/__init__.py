"""What a user takes away, all read from one positioning-deviation table and the run's metadata:
evaluation (ISO 230-2, VDI 3441), compensation tables, comparison of two runs, the report, figures."""
