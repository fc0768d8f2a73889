"""One rounding of an expanded uncertainty for every place it is shown.

The GUM (JCGM 100:2008, 7.2.6) advises at most two significant digits for an uncertainty,
rounded up rather than to the nearest where the rounding would understate it. U is rounded
here once; the certificate (page 1 and the tables), the console and results.json's rounded
fields all take :func:`u_text` or :func:`round_up`, so they show one string.
"""

from __future__ import annotations

import math

DIGITS = 2  # significant digits of a stated uncertainty (GUM 7.2.6)
_SLACK = 1e-6  # a U of 0.52 stored as 0.52000001 stays 0.52, not 0.53


def _step(value: float, digits: int = DIGITS) -> float:
    """The place of the last significant digit kept: 0.01 for 0.51, 1 for 10.4."""
    return 10.0 ** (math.floor(math.log10(value)) - digits + 1)


def round_up(value: float | None, digits: int = DIGITS) -> float | None:
    """``value`` rounded up to ``digits`` significant digits (0 and None as they are)."""
    if value is None or not math.isfinite(value) or value <= 0:
        return value
    q = _step(value, digits)
    up = math.ceil(value / q - _SLACK) * q
    return float(f"{up:.{digits}g}") if up < 10 ** digits else float(round(up))


def decimals(rounded: float | None, digits: int = DIGITS) -> int:
    """Decimal places that show ``rounded`` with ``digits`` significant digits (0.10 → 2, 11 → 0)."""
    if rounded is None or not math.isfinite(rounded) or rounded <= 0:
        return 2
    return max(0, digits - 1 - math.floor(math.log10(rounded)))


def u_text(value: float | None, digits: int = DIGITS) -> str:
    """An uncertainty as the certificate states it: two significant digits, rounded up ("–" if none)."""
    if value is None:
        return "–"
    r = round_up(value, digits)
    return format(r, f".{decimals(r, digits)}f")


def value_text(value: float | None, uncertainty: float | None, sign: str = "") -> str:
    """A measured value to the same decimal place as its rounded uncertainty (GUM 7.2.6), at least
    one decimal less than two; "–" if none."""
    if value is None:
        return "–"
    places = decimals(round_up(uncertainty)) if uncertainty is not None and uncertainty > 0 else 2
    return format(value, f"{sign}.{places}f")


def fmt(v: float | None, spec: str) -> str:
    """A value as ``format(v, spec)``; "–" for a missing one."""
    return "–" if v is None else format(v, spec)


def significant(value: float, digits: int = 3) -> str:
    """``value`` to ``digits`` significant digits as a person writes it — 1000, 2500, 0.0123, 2.5 —
    never in exponent form ("1e+03" on a certificate reads as a typo)."""
    if not math.isfinite(value) or value == 0:
        return format(value, "g")
    places = digits - 1 - math.floor(math.log10(abs(value)))
    text = format(round(value, places), f".{max(places, 0)}f")
    return text.rstrip("0").rstrip(".") if "." in text else text
