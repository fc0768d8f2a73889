"""Compensation of location errors: where a machine's rotary axes really are (ISO 230-7 location
errors) written into its control's kinematic model. One class per format, each in its module and
citing its manual: LinuxCNC ``xyzac-trt-kins`` pins (linuxcnc_kins.py), SINUMERIK swivel data
``$TC_CARR`` (siemens_carr.py), FANUC tool-centre-point parameters of a table (fanuc_tcp.py).

A format takes the record the control holds now (as commissioned) and a :class:`LocationErrors` —
what any method measured, the R-test's eight or seed 000's four (X0C, Y0C, A0C, B0C) — and writes
the record with the axes where they were measured, saying which errors it could not absorb. The
location errors are relative to the kinematics the control held while they were measured: the
nominal lines the writer moves are the record's own (:meth:`KinematicsFormat.geometry`).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any, ClassVar, Mapping

import numpy as np

from rtcal.compensation.table import CompensationError
from rtcal.solvers.rtest import LOCATION_SYMBOLS, TrunnionGeometry, axis_lines, location_vector

SYMBOL = re.compile(r"(?:[XYZ]0[ABC]_um|[ABC]0[ABC]_arcsec)")
# the four offsets a model with its axes along machine axes can hold, and the four tilts it cannot
OFFSETS = ("X0C_um", "Y0C_um", "Y0A_um", "Z0A_um")


def tilts_not_held(model: str, c_axis: str = "Z", a_axis: str = "X") -> dict[str, str]:
    """Why a model whose C lies exactly along ``c_axis`` and A along ``a_axis`` cannot hold the four tilts."""
    return {"A0C_arcsec": f"{model} C is exactly along {c_axis} (no tilt about X)",
            "B0C_arcsec": f"{model} C is exactly along {c_axis} (no tilt about Y)",
            "B0A_arcsec": f"{model} A is exactly along {a_axis} (no tilt about Y)",
            "C0A_arcsec": f"{model} A is exactly along {a_axis} (no tilt about Z)"}


@dataclass(frozen=True)
class LocationValue:
    """One location error in its symbol's unit (µm or arcsec) and its standard uncertainty (1σ)."""

    value: float
    u: float = 0.0

    @property
    def U(self) -> float:
        return 2.0 * self.u


@dataclass(frozen=True)
class LocationErrors:
    """ISO 230-7 location errors of a machine's rotary axes as a method reports them: symbol (``X0C_um``,
    ``B0A_arcsec``, …) → value and u, and the frame and convention they are stated in (docs/rtest.md for
    the R-test's; docs/paper000.md for seed 000's). A symbol not given is taken as not measured."""

    values: Mapping[str, LocationValue]
    frame: str = ""

    def __post_init__(self) -> None:
        for symbol, v in self.values.items():
            if not SYMBOL.fullmatch(symbol):
                raise CompensationError(f"{symbol!r} is not a location error's symbol (e.g. X0C_um, B0A_arcsec)")
            if not (math.isfinite(v.value) and math.isfinite(v.u) and v.u >= 0):
                raise CompensationError(f"{symbol}: {v.value!r} ± {v.u!r} is not a finite value with its uncertainty")

    @classmethod
    def of(cls, values: Mapping[str, float | tuple[float, float]], frame: str = "") -> "LocationErrors":
        """From symbol → value or (value, u)."""
        return cls({s: LocationValue(*(v if isinstance(v, tuple) else (v, 0.0))) for s, v in values.items()}, frame)

    def value(self, symbol: str) -> float:
        """The value, 0 if not measured."""
        v = self.values.get(symbol)
        return 0.0 if v is None else v.value


@dataclass(frozen=True)
class KinematicsOutput:
    """What a writer gives: the file's text, the record it holds (name → value), the location errors it
    absorbed and those it could not (symbol → why), and what the engineer must do on the control."""

    text: str
    record: dict[str, float]
    absorbed: tuple[str, ...]
    not_absorbed: dict[str, str] = field(default_factory=dict)
    instructions: tuple[str, ...] = ()


class KinematicsFormat:
    """A control's kinematic model of a trunnion table (A about X carrying C) as a file. A subclass names
    its record's keys (``keys``), says what its values mean (``sign``), which location errors the model
    can hold (``absorbs``) and why not the others (``cannot``), and defines :meth:`geometry` (its record
    as the nominal lines), :meth:`record_for` (the lines back to a record) and :meth:`write`/:meth:`parse`."""

    name: ClassVar[str]
    keys: ClassVar[tuple[str, ...]]
    sign: ClassVar[str]
    absorbs: ClassVar[tuple[str, ...]]
    cannot: ClassVar[Mapping[str, str]]

    def geometry(self, record: Mapping[str, float]) -> TrunnionGeometry:
        raise NotImplementedError

    def record_for(self, record: Mapping[str, float], lines: "ActualLines") -> dict[str, float]:
        raise NotImplementedError

    def write(self, record: Mapping[str, float], errors: LocationErrors, **options: Any) -> KinematicsOutput:
        raise NotImplementedError

    def parse(self, text: str, where: str = "") -> dict[str, float]:
        raise NotImplementedError

    # -- shared ------------------------------------------------------------------------------------
    def check_record(self, record: Mapping[str, float]) -> dict[str, float]:
        missing = [k for k in self.keys if k not in record]
        if missing:
            raise CompensationError(f"{self.name}: the control's record lacks {', '.join(missing)} (give every one of "
                                    f"{', '.join(self.keys)} as commissioned)")
        out = {k: float(record[k]) for k in self.keys}
        bad = [k for k, v in out.items() if not math.isfinite(v)]
        if bad:
            raise CompensationError(f"{self.name}: {', '.join(bad)} not a finite number")
        return out

    def corrected(self, record: Mapping[str, float], errors: LocationErrors) -> tuple[dict[str, float], tuple[str, ...],
                                                                                     dict[str, str]]:
        """The record with the measured lines, the symbols absorbed, and those left (symbol → why)."""
        rec = self.check_record(record)
        given = {s: errors.value(s) for s in LOCATION_SYMBOLS if s in errors.values}
        unknown = sorted(set(errors.values) - set(LOCATION_SYMBOLS))
        if unknown:
            raise CompensationError(f"{self.name}: {', '.join(unknown)} belong to no axis of a trunnion table (A on X "
                                    "carrying C); its location errors are " + ", ".join(LOCATION_SYMBOLS))
        absorbed = tuple(s for s in self.absorbs if s in given)
        lines = ActualLines.of(self.geometry(rec), {s: given[s] for s in absorbed})
        left = {s: f"{given[s]:+.3f} {'µm' if s.endswith('_um') else 'arcsec'}: {self.cannot[s]}"
                for s in given if s not in self.absorbs and abs(given[s]) > 0}
        return self.record_for(rec, lines), absorbed, left


@dataclass(frozen=True)
class ActualLines:
    """A's and C's lines at the reference pose with the location errors applied (machine frame, mm;
    unit directions), and the nominal geometry they were measured against."""

    geometry: TrunnionGeometry
    a_point: np.ndarray
    a_dir: np.ndarray
    c_point: np.ndarray
    c_dir: np.ndarray

    @classmethod
    def of(cls, geometry: TrunnionGeometry, errors: Mapping[str, float]) -> "ActualLines":
        a_point, a_dir, c_point, c_dir = axis_lines(geometry, location_vector(dict(errors)))
        return cls(geometry, np.real(a_point), np.real(a_dir), np.real(c_point), np.real(c_dir))

    def c_at_z(self, z_mm: float) -> np.ndarray:
        """Where C's line crosses the plane z = ``z_mm``."""
        return np.asarray(self.c_point + (z_mm - self.c_point[2]) / self.c_dir[2] * self.c_dir)

    def a_at_x(self, x_mm: float) -> np.ndarray:
        """Where A's line crosses the plane x = ``x_mm``."""
        return np.asarray(self.a_point + (x_mm - self.a_point[0]) / self.a_dir[0] * self.a_dir)


def number(value: float, decimals: int) -> str:
    """A value as a control reads it: fixed decimals, no exponent, no negative zero."""
    text = f"{value:.{decimals}f}"
    return text[1:] if re.fullmatch(r"-0\.?0*", text) else text
