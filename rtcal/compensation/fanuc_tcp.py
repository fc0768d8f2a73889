"""FANUC tool centre point control of a table-rotation machine (parameter 19680 = 12: two rotation axes
of the table, the 1st the master — A, on the machine — the 2nd the slave — C, on A): the rotary
table's position and the intersection offset vector with the axes where they were measured, as a
listing to key in (``19703 = -0.012  (comment)``, the form of rtcal's FANUC pitch listing).

Sources: FANUC Series 30i-MODEL A, Tool centre point control for 5-axis machining, Additional Manual
A-79348E: p. 72 (19680 mechanical unit type: 12 table rotation type, "the first rotation axis is the
master, and the second rotation axis is the slave"), p. 75 (19684: "Normally … 1 is set for a table
rotation axis"), p. 82 (19703–19705 "Intersection offset vector between the first and second rotation
axes of the table" — "When the rotation axes for controlling the table are all at 0 degrees, the
vector from point A to point B on the second rotation axis of the table is set as the intersection
offset vector in the machine coordinate system … As point B, set a position that is easy to measure
on the second rotary axis"; real, mm, IS-B 0.001); its figure names "Rotary table position", the
machine-frame position of point A on the 1st axis. **The rotary table position's parameter numbers are
not in the pages rtcal could read** (the reference notes give the quantity, not its number): the
listing names it, and ``position_parameter`` (e.g. 19700, for 19700–19702) puts its number on the
lines once checked in the control's parameter manual.

**Sign.** Both are machine-frame positions (mm): point A moves onto the measured A line (at A's x),
point B onto the measured C line (at B's z), the vector is B − A. FANUC's table model holds each axis
along a machine axis: the four angular location errors stay (reported, not written).
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from rtcal.compensation.kinematics import (OFFSETS, ActualLines, KinematicsFormat, KinematicsOutput, LocationErrors,
                                          number, tilts_not_held)
from rtcal.compensation.table import CompensationError
from rtcal.solvers.rtest import TrunnionGeometry

KEYS = ("table_position_x", "table_position_y", "table_position_z", "19703", "19704", "19705")
DECIMALS = {"is-b": 3, "is-c": 4}


class FanucTcpFormat(KinematicsFormat):
    name = "fanuc-tcp-table"
    keys = KEYS
    sign = ("machine-frame positions, mm: the rotary table position (point A on the 1st table axis) and 19703–19705 "
            "the vector from A to point B on the 2nd, all rotation axes at 0° (A-79348E p. 82)")
    absorbs = OFFSETS
    cannot = tilts_not_held("FANUC's table model (19682, 19687: each axis along a machine axis):", "Z", "X")

    def geometry(self, record: Mapping[str, float]) -> TrunnionGeometry:
        r = self.check_record(record)
        a = np.array([r["table_position_x"], r["table_position_y"], r["table_position_z"]])
        b = a + np.array([r["19703"], r["19704"], r["19705"]])
        return TrunnionGeometry((float(b[0]), float(b[1]), float(b[2])), (float(a[0]), float(a[1]), float(a[2])))

    def record_for(self, record: Mapping[str, float], lines: ActualLines) -> dict[str, float]:
        g = lines.geometry
        a = lines.a_at_x(g.a_point_mm[0])
        b = lines.c_at_z(g.c_point_mm[2])
        return {"table_position_x": float(a[0]), "table_position_y": float(a[1]), "table_position_z": float(a[2]),
                "19703": float(b[0] - a[0]), "19704": float(b[1] - a[1]), "19705": float(b[2] - a[2])}

    def write(self, record: Mapping[str, float], errors: LocationErrors, increment_system: str = "is-b",
              position_parameter: int | None = None, **options: Any) -> KinematicsOutput:
        if options:
            raise CompensationError(f"{self.name} takes no {', '.join(sorted(options))} "
                                    "(its options: increment_system, position_parameter)")
        if increment_system not in DECIMALS:
            raise CompensationError(f"{self.name}: increment system {increment_system!r}: is-b (0.001 mm) or is-c (0.0001 mm)")
        if position_parameter is not None and not (isinstance(position_parameter, int) and 19000 <= position_parameter <= 19997):
            raise CompensationError(f"{self.name}: position parameter {position_parameter!r}: the number of the rotary table "
                                    "position's X (its Y and Z follow), 19000 … 19997")
        new, absorbed, left = self.corrected(record, errors)
        d = DECIMALS[increment_system]
        lines = [f"(rtcal: table-rotation TCP parameters, 19680 = 12, with the rotary axes where they were measured)",
                 "(" + ", ".join(f"{s} {errors.value(s):+.3f} {'UM' if s.endswith('_um') else 'ARCSEC'}" for s in absorbed)
                 + (" ABSORBED)" if absorbed else "NOTHING TO ABSORB)")]
        lines += [f"(NOT ABSORBED: {s} {why.replace('µm', 'UM').replace('arcsec', 'ARCSEC')})" for s, why in left.items()]
        for k, axis in enumerate("xyz"):
            label = str(position_parameter + k) if position_parameter is not None else f"ROTARY TABLE POSITION {axis.upper()}"
            lines.append(f"{label} = {number(new[f'table_position_{axis}'], d)}  (point A on the 1st table axis, {axis.upper()}, MM)")
        for key, axis in zip(("19703", "19704", "19705"), "XYZ"):
            lines.append(f"{key} = {number(new[key], d)}  (intersection offset vector A to B, {axis}, MM)")
        return KinematicsOutput("\n".join(lines) + "\n", new, absorbed, left,
                                ("key the values in on the control's parameter screen as its manual says; the rotary table "
                                 "position's number is your control's (A-79348E names it, the pages rtcal read do not "
                                 "number it: give --position-parameter once checked)",))

    def parse(self, text: str, where: str = "<listing>") -> dict[str, float]:
        """The six values back from a listing (numbered or named lines; parenthesised comments skipped)."""
        found: dict[str, float] = {}
        named = {f"ROTARY TABLE POSITION {a}": f"table_position_{a.lower()}" for a in "XYZ"}
        for line_no, line in enumerate(text.splitlines(), start=1):
            body = line.split("(", 1)[0].strip()
            if not body:
                continue
            key, sep, value = body.partition("=")
            key = key.strip()
            if not sep:
                raise CompensationError(f"{where}:{line_no}: expected `parameter = value`")
            try:
                number_ = float(value)
            except ValueError:
                raise CompensationError(f"{where}:{line_no}: {value.strip()!r} is not a number") from None
            if key in named:
                found[named[key]] = number_
            elif key in ("19703", "19704", "19705"):
                found[key] = number_
            elif key.isdigit():
                found.setdefault(f"#{key}", number_)
        numbered = sorted(int(k[1:]) for k in found if k.startswith("#"))
        if "table_position_x" not in found and len(numbered) >= 3 and numbered[1] == numbered[0] + 1 == numbered[2] - 1:
            for axis, number_k in zip("xyz", numbered[:3]):
                found[f"table_position_{axis}"] = found[f"#{number_k}"]
        missing = [k for k in KEYS if k not in found]
        if missing:
            raise CompensationError(f"{where}: {', '.join(missing)} not given")
        return {k: found[k] for k in KEYS}
