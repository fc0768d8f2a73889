"""rtcal — angular positioning calibration of precision rotary tables."""

__version__ = "0.2.0"
