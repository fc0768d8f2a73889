"""The I++ DME protocol, as much of it as a CMM driver needs: framing, parsing, error codes.

A command line is ``TTTTT Name(args)\\r\\n`` with a five-digit tag; the server answers with
``TTTTT &`` (acknowledged), ``TTTTT # data`` (zero or more), then ``TTTTT %`` (complete), or
``TTTTT ! Error(severity, code, "command", "text")``.
"""

from __future__ import annotations

import re

ACK, DATA, DONE, ERROR = "&", "#", "%", "!"
LINE = re.compile(r"(\d{5}|E\d{4}) ([&#%!])(?: (.*))?")
COMMAND = re.compile(r"(\d{5}) ([A-Za-z]+)\((.*)\)")
AXIS = re.compile(r"([XYZ])\(\s*([+-]?\d+(?:\.\d*)?(?:[eE][+-]?\d+)?)?\s*\)")
ERROR_ARGS = re.compile(r'Error\((\d+),\s*(\d+),\s*"([^"]*)",\s*"([^"]*)"\)')

# codes used here (I++ DME error table)
PROTOCOL_ERROR = "0008"
UNSUPPORTED_COMMAND = "0501"
BAD_ARGUMENT = "0502"
BAD_ARGUMENT_COUNT = "0509"
OUT_OF_VOLUME = "1008"


def axes(text: str) -> dict[str, float | None]:
    """``X(1.5), Y(2), Z()`` → {"X": 1.5, "Y": 2.0, "Z": None}."""
    return {m.group(1): (float(m.group(2)) if m.group(2) else None) for m in AXIS.finditer(text)}


def format_axes(x: float, y: float, z: float) -> str:
    return f"X({x:.6f}), Y({y:.6f}), Z({z:.6f})"


def error_line(tag: str, severity: int, code: str, command: str, text: str) -> str:
    return f'{tag} ! Error({severity}, {code}, "{command}", "{text}")\r\n'
