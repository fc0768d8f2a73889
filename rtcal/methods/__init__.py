"""One module per calibration method: its instruments, measurement, analysis, files and report.

Each exposes ``plan_length``, ``measure``, ``analyse``, ``write_files`` and ``report_body``; the
runner knows nothing more of them.
"""
