"""The I++ DME protocol, as much of it as a CMM needs: framing, parsing, the error table.

A command line is ``TTTTT Name(args)\\r\\n`` with a five-digit tag; the server answers with
``TTTTT &`` (acknowledged), ``TTTTT # data`` (zero or more), then ``TTTTT %`` (complete); an
error is ``TTTTT ! Error(F1, F2, F3, "text")`` — severity, four-digit code, the method that
caused it (unquoted in the specification's §8.1, quoted by NIST's and pyippdme's servers), a
text — and the transaction still ends with ``%``. Severities 0 and 1 are warnings: the
transaction goes on. After an error of severity 2 or more the server answers every command
with 0514 until ``ClearAllErrors()``. The server's own events carry the tag ``E0000`` (an
emergency stop, §6.2.4.1); a client's event commands (``AbortE()``) carry ``E0001``…``E9999``.
Sources: docs/protocols/ipp_dme.md.
"""

from __future__ import annotations

import re

ACK, DATA, DONE, ERROR = "&", "#", "%", "!"
LINE = re.compile(r"(\d{5}|E\d{4}) ([&#%!])(?: (.*))?")
COMMAND = re.compile(r"(\d{5}|E\d{4}) ([A-Za-z]+)\((.*)\)")
AXIS = re.compile(r"([XYZ])\(\s*([+-]?\d+(?:\.\d*)?(?:[eE][+-]?\d+)?)?\s*\)")
IJK = re.compile(r"IJK\(\s*([^,()]+),\s*([^,()]+),\s*([^,()]+)\)")
# F3 quoted (NIST, pyippdme) or bare (the specification's §8.1: ``Error(3, 2500, GoTo, "…")``)
ERROR_ARGS = re.compile(r'Error\(\s*(\d+)\s*,\s*(\d+)\s*,\s*(?:"([^"]*)"|([^,"()]*?))\s*,\s*"([^"]*)"\s*\)')
IS_HOMED = re.compile(r"IsHomed\(\s*([01])\s*\)")
EVENT_TAG = "E0000"  # the server's unsolicited events (§6.2.4)
WARNING_SEVERITY = 1  # 0 info, 1 warning: the transaction goes on (§8.1)
DME_VERSION = re.compile(r'DMEVersion\(\s*"([^"]*)"\s*\)')
STRING_ARG = re.compile(r'\s*"([^"]{1,200})"\s*')

PROTOCOL_ERROR = "0008"
UNSUPPORTED_COMMAND = "0501"
INCORRECT_ARGUMENTS = "0502"
ILLEGAL_COMMAND = "0507"
BAD_ARGUMENT = "0509"
USE_CLEAR_ALL_ERRORS = "0514"
TRANSACTION_ABORTED = "0006"
EMERGENCY_STOP = "0500"
SURFACE_NOT_FOUND = "1006"
OUT_OF_VOLUME = "1008"
TOOL_NOT_FOUND = "1502"
MACHINE_LIMIT = "2500"

# the standard's pre-defined errors rtcal meets: code → (severity, text)
ERRORS: dict[str, tuple[int, str]] = {
    "0001": (2, "Illegal tag"), "0002": (2, "No space at pos. 6"), "0006": (2, "Transaction aborted"),
    "0007": (3, "Illegal character"), PROTOCOL_ERROR: (3, "Protocol error"), "0500": (3, "Emergency stop"),
    UNSUPPORTED_COMMAND: (3, "Unsupported command"), INCORRECT_ARGUMENTS: (3, "Incorrect arguments"),
    "0504": (1, "Argument out of range"), ILLEGAL_COMMAND: (3, "Illegal command"), BAD_ARGUMENT: (3, "Bad argument"),
    USE_CLEAR_ALL_ERRORS: (2, "Use ClearAllErrors to continue"), "1003": (2, "No touch"),
    SURFACE_NOT_FOUND: (2, "Surface not found"), OUT_OF_VOLUME: (3, "Target position out of machine volume"),
    TOOL_NOT_FOUND: (3, "Tool not found"), "1503": (3, "Tool not defined"),
    MACHINE_LIMIT: (3, "Machine limit encountered [Move Out Of Limits]"),
}


def parse_error(text: str) -> tuple[int, str, str, str] | None:
    """``Error(3, 2500, GoTo, "text")`` or ``Error(3,2500,"GoTo","text")`` → (3, "2500", "GoTo", "text")."""
    m = ERROR_ARGS.search(text)
    if m is None:
        return None
    return int(m.group(1)), m.group(2), m.group(3) if m.group(3) is not None else m.group(4).strip(), m.group(5)


def axes(text: str) -> dict[str, float | None]:
    """``X(1.5), Y(2), Z()`` → {"X": 1.5, "Y": 2.0, "Z": None}."""
    return {m.group(1): (float(m.group(2)) if m.group(2) else None) for m in AXIS.finditer(text)}


def format_axes(x: float, y: float, z: float) -> str:
    return f"X({x:.6f}), Y({y:.6f}), Z({z:.6f})"


def error_line(tag: str, code: str, cause: str, text: str = "", quoted: bool = True, severity: int | None = None) -> str:
    """The error reply line, with the standard's severity for ``code``; ``quoted=False`` writes F3 bare (§8.1)."""
    standard_severity, standard_text = ERRORS.get(code, (3, "Error"))
    f3 = f'"{cause}"' if quoted else cause
    return f'{tag} ! Error({standard_severity if severity is None else severity}, {code}, {f3}, "{text or standard_text}")\r\n'
