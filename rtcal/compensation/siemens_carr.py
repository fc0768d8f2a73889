"""SINUMERIK swivel data record (orientable toolholder, ``$TC_CARR1 … $TC_CARR65``) of a swivel table,
kinematic type P, with its rotary axes where they were measured: the offset vectors I2, I3, I4 and
the rotary axis vectors V1 (the 1st axis, on the machine: A) and V2 (the 2nd, carried by it: C), as a
part program that sets them.

Sources: SINUMERIK 840D sl Commissioning Manual (IM9) 03/2013, 6FC5397-1DP40-3BA1, p. 502 ("Offset
vectors I1 to I4 $TC_CARR1[n] … $TC_CARR20[n] … three components, which represent the reference to
the machine axes (X, Y, Z) … refer to the non-swiveled state of the rotary axes"; swivel table: "I2
distance from the machine reference point to the pivot point/intersection of the 1st rotary axis, I3
distance from the pivot point/intersection of the 1st rotary axis to the pivot point/intersection of
the 2nd rotary axis, I4 closure of the I4 = −(I2+I3) vector chain"); SINUMERIK 828D Function Manual
Basic Functions 09/2011 (W1, 18.6) p. 1502: I1 = $TC_CARR1…3, I2 = 4…6, V1 = 7…9, V2 = 10…12,
I3 = 15…17, I4 = 18…20, kinematic type $TC_CARR23 ("P: only the part can rotate", 840D PGA 04.00
p. 15-512); p. 1503: $TC_CARR41…65 are fine offsets "added to the values in the basic parameters",
at the basic number + 40, and 47…54 are not defined — the rotary axis vectors have none, so rtcal
writes the basic values; Commissioning Manual 12/2017 p. 572: type P is transformation type 40 with
I2, I3, I4 and V1, V2 as listed.

**Sign.** Offsets are machine-frame vectors (mm) between points of the lines at the non-swivelled
state; rtcal keeps I2's x (where along A its point lies) and I2 + I3's z (where along C), moves the
points onto the measured lines, and closes I4 = −(I2 + I3). V1 and V2 are the measured directions as
unit vectors, each with the sign the commissioned vector has (the control's sense of rotation, which
for a table "is reversed" — Commissioning Manual 12/2017 p. 572 — is the commissioning's, kept as
it was). The record holds every one of the eight location errors. Machine reference point: the
machine frame's origin (``reference_mm`` otherwise).
"""

from __future__ import annotations

import re
from typing import Any, ClassVar, Mapping

import numpy as np

from rtcal.compensation.kinematics import ActualLines, KinematicsFormat, KinematicsOutput, LocationErrors, number
from rtcal.compensation.table import CompensationError
from rtcal.solvers.rtest import LOCATION_SYMBOLS, TrunnionGeometry

VECTORS = {"I2": (4, 5, 6), "I3": (15, 16, 17), "I4": (18, 19, 20), "V1": (7, 8, 9), "V2": (10, 11, 12)}
KEYS = tuple(f"{v}{a}" for v in ("I2", "I3", "V1", "V2") for a in "xyz")
ASSIGNMENT = re.compile(r"\s*\$TC_CARR(\d+)\[(\d+)\]\s*=\s*([+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)\s*(?:;.*)?")


class SiemensCarrFormat(KinematicsFormat):
    name = "siemens-tc-carr"
    keys = KEYS
    sign = ("I2, I3, I4: machine-frame vectors between points of the lines (mm), I4 = −(I2 + I3); V1, V2: the axes' "
            "unit directions with the commissioned sign (Commissioning Manual 03/2013 p. 502)")
    absorbs = LOCATION_SYMBOLS
    cannot: ClassVar[Mapping[str, str]] = {}

    @staticmethod
    def _vec(record: Mapping[str, float], name: str) -> np.ndarray:
        return np.array([record[f"{name}{a}"] for a in "xyz"], float)

    def geometry(self, record: Mapping[str, float], reference_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> TrunnionGeometry:
        r = self.check_record(record)
        for name, axis in (("V1", 0), ("V2", 2)):
            v = self._vec(r, name)
            n = float(np.linalg.norm(v))
            if n == 0 or abs(abs(v[axis]) / n - 1.0) > 1e-3:
                raise CompensationError(f"{self.name}: {name} = {v.tolist()} is not along {'XYZ'[axis]}: rtcal's model is a "
                                        "trunnion with A (1st axis) along X carrying C (2nd) along Z")
        a_point = np.asarray(reference_mm, float) + self._vec(r, "I2")
        c_point = a_point + self._vec(r, "I3")
        return TrunnionGeometry(tuple(c_point), tuple(a_point))  # type: ignore[arg-type]

    def record_for(self, record: Mapping[str, float], lines: ActualLines) -> dict[str, float]:
        g = lines.geometry
        a = lines.a_at_x(g.a_point_mm[0])
        c = lines.c_at_z(g.c_point_mm[2])
        reference = np.asarray(g.a_point_mm, float) - self._vec(record, "I2")
        out = dict(record)
        for name, vec in (("I2", a - reference), ("I3", c - a), ("V1", lines.a_dir * np.sign(record["V1x"])),
                          ("V2", lines.c_dir * np.sign(record["V2z"]))):
            for axis, value in zip("xyz", vec):
                out[f"{name}{axis}"] = float(value)
        return out

    def write(self, record: Mapping[str, float], errors: LocationErrors, carrier: int = 1,
              reference_mm: tuple[float, float, float] = (0.0, 0.0, 0.0), **options: Any) -> KinematicsOutput:
        """A part program: ``$TC_CARRk[n]=value`` for I2, I3, I4 (mm, 4 decimals: 0.1 µm), V1, V2 (9 decimals),
        $TC_CARR23 = "P", after ``;`` comments; M30."""
        if options:
            raise CompensationError(f"{self.name} takes no {', '.join(sorted(options))} (its options: carrier, reference_mm)")
        if not (isinstance(carrier, int) and 1 <= carrier <= 99):
            raise CompensationError(f"{self.name}: carrier {carrier!r}: the swivel data record's number, 1 … 99")
        base = self.check_record(record)
        geometry = self.geometry(base, reference_mm)
        given = {s: errors.value(s) for s in LOCATION_SYMBOLS if s in errors.values}
        lines_ = ActualLines.of(geometry, given)
        new = self.record_for(base, lines_)
        i4 = -(self._vec(new, "I2") + self._vec(new, "I3"))
        out = [f"; rtcal: swivel data record {carrier} (kinematic type P, swivel table) with its rotary axes where they "
               "were measured",
               "; I2: machine reference point -> point of the 1st rotary axis (A); I3: -> point of the 2nd (C); "
               "I4 = -(I2+I3); V1, V2: the axes' directions (Commissioning Manual 03/2013 p. 502)",
               "; " + ", ".join(f"{s} {v:+.3f} {'um' if s.endswith('_um') else 'arcsec'}" for s, v in given.items())]
        for name in ("I2", "I3"):
            vec = self._vec(new, name)
            out += [f"$TC_CARR{k}[{carrier}]={number(float(v), 4)}" for k, v in zip(VECTORS[name], vec)]
        out += [f"$TC_CARR{k}[{carrier}]={number(float(v), 4)}" for k, v in zip(VECTORS["I4"], i4)]
        for name in ("V1", "V2"):
            out += [f"$TC_CARR{k}[{carrier}]={number(float(v), 9)}" for k, v in zip(VECTORS[name], self._vec(new, name))]
        out += [f'$TC_CARR23[{carrier}]="P"', "M30"]
        record_out = {**new, **{f"I4{a}": float(v) for a, v in zip("xyz", i4)}}
        return KinematicsOutput("\n".join(out) + "\n", record_out, tuple(given), {},
                                ("run the program on the control (or enter the values on the swivel data screen), then "
                                 "select the record again (CYCLE800 / TRAORI) before machining",))

    def parse(self, text: str, where: str = "<mpf>", carrier: int = 1) -> dict[str, float]:
        """I2, I3, V1, V2 (and I4, checked to close the chain) of record ``carrier`` from ``$TC_CARRk[n]=v``
        lines; other lines and records are passed over."""
        found: dict[int, float] = {}
        for line_no, line in enumerate(text.splitlines(), start=1):
            m = ASSIGNMENT.fullmatch(line)
            if m and int(m.group(2)) == carrier:
                found[int(m.group(1))] = float(m.group(3))
        record: dict[str, float] = {}
        for name in ("I2", "I3", "V1", "V2"):
            for axis, k in zip("xyz", VECTORS[name]):
                if k not in found:
                    raise CompensationError(f"{where}: $TC_CARR{k}[{carrier}] ({name} {axis}) is not set")
                record[f"{name}{axis}"] = found[k]
        if all(k in found for k in VECTORS["I4"]):
            i4 = np.array([found[k] for k in VECTORS["I4"]])
            gap = i4 + self._vec(record, "I2") + self._vec(record, "I3")
            if float(np.max(np.abs(gap))) > 1e-3:
                raise CompensationError(f"{where}: I4 = {i4.tolist()} does not close the chain (I4 = −(I2 + I3) for a fixed "
                                        "swivel table, Commissioning Manual 03/2013 p. 502)")
        return record
