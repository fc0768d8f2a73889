"""LinuxCNC ``xyzac-trt-kins`` (a tilting table A carrying a rotary C): its HAL pins with the axes
where they were measured, as ``setp`` lines of a .hal file or ``HALCMD =`` lines of an INI's [HAL]
section. Source: LinuxCNC src/emc/kinematics/trtfuncs.c (``trtKinematicsSetup`` makes the pins
``x-rot-point``, ``y-rot-point``, ``z-rot-point``, ``x-offset``, ``y-offset``, ``z-offset``,
``tool-offset`` under the module's HAL prefix; ``xyzacKinematicsInverse`` turns a workpiece point p
into joints Rx(a)·[Rz(c)·(p − r) − d] + r + d with r the rot point and d = (0, y-offset,
z-offset + tool-offset): C turns about the vertical line through r, A about the line along X through
r + d; ``x-offset`` is not read by xyzac). Confirmed on Debian's linuxcnc-uspace 2.9 module, whose
strings hold the same seven pin names. LinuxCNC's own example (configs/sim/axis/vismach/5axis/
table-rotary-tilting/xyzac-trt.ini) sets the rot point to 0 and nets y-offset 20, z-offset 10.

**Sign.** Every pin is a position in the machine frame, mm: x-rot-point, y-rot-point where C's line
is (at A = C = 0), y-offset, z-offset from there to A's line. A location error adds to the pin of
its line: x-rot-point += X0C, y-rot-point += Y0A + Y0C (C moves with A, and by Y0C from it),
y-offset −= Y0C (A stays where Y0A puts it), z-offset += Z0A; z-rot-point is kept (it only names
where on C's line the rot point is). The module holds both axes exactly along X and Z: the four
angular location errors stay (a tilt of 20″ moves a point 100 mm along the axis by 9.7 µm).
"""

from __future__ import annotations

import re
from typing import Any, Mapping

from rtcal.compensation.kinematics import (OFFSETS, ActualLines, KinematicsFormat, KinematicsOutput, LocationErrors,
                                          number, tilts_not_held)
from rtcal.compensation.table import CompensationError
from rtcal.solvers.rtest import TrunnionGeometry

PINS = ("x-rot-point", "y-rot-point", "z-rot-point", "y-offset", "z-offset")
PREFIX = "xyzac-trt-kins"
SETP = re.compile(r"\s*(?:HALCMD\s*=\s*)?setp\s+(\S+)\s+(\S+)\s*(?:#.*)?")
NET = re.compile(r"\s*(?:HALCMD\s*=\s*)?net\s+(.*)")


class LinuxCncTrtFormat(KinematicsFormat):
    name = "linuxcnc-xyzac-trt"
    keys = PINS
    sign = ("machine-frame positions, mm: x/y-rot-point where C's line is at A = C = 0, y/z-offset from there to A's "
            "line (trtfuncs.c); a location error adds to the pin of its line")
    absorbs = OFFSETS
    cannot = tilts_not_held("the module's")

    def geometry(self, record: Mapping[str, float]) -> TrunnionGeometry:
        r = self.check_record(record)
        return TrunnionGeometry.from_linuxcnc(r["x-rot-point"], r["y-rot-point"], r["z-rot-point"], r["y-offset"],
                                              r["z-offset"])

    def record_for(self, record: Mapping[str, float], lines: ActualLines) -> dict[str, float]:
        zr = record["z-rot-point"]
        c = lines.c_at_z(zr)
        a = lines.a_at_x(float(c[0]))
        return {"x-rot-point": float(c[0]), "y-rot-point": float(c[1]), "z-rot-point": zr,
                "y-offset": float(a[1] - c[1]), "z-offset": float(a[2] - zr)}

    def write(self, record: Mapping[str, float], errors: LocationErrors, form: str = "hal", prefix: str = PREFIX,
              **options: Any) -> KinematicsOutput:
        """The five pins' ``setp`` lines (``form`` "hal": a .hal file; "ini": ``HALCMD =`` lines for the
        INI's [HAL] section), six decimals (nm), after ``#`` lines that say what they hold and what stays."""
        if options:
            raise CompensationError(f"{self.name} takes no {', '.join(sorted(options))} (its options: form, prefix)")
        if form not in ("hal", "ini"):
            raise CompensationError(f"{self.name}: form {form!r}: hal or ini")
        if not re.fullmatch(r"[A-Za-z0-9_.-]+", prefix):
            raise CompensationError(f"{self.name}: prefix {prefix!r} is not a HAL name")
        new, absorbed, left = self.corrected(record, errors)
        lead = "HALCMD = " if form == "ini" else ""
        lines = [f"# rtcal: {prefix} with the rotary axes where they were measured (LinuxCNC trtfuncs.c: C turns about "
                 "the rot point, A about rot point + (0, y-offset, z-offset))",
                 "# " + "; ".join(f"{s} {errors.value(s):+.3f} {'um' if s.endswith('_um') else 'arcsec'}" for s in absorbed)
                 + (" absorbed" if absorbed else "nothing to absorb")]
        lines += [f"# NOT absorbed: {s} {why}".replace("µm", "um") for s, why in left.items()]
        lines += [f"{lead}setp {prefix}.{pin} {number(new[pin], 6)}" for pin in PINS]
        where = "the INI's [HAL] section (replacing its setp/sets of these pins)" if form == "ini" else \
            "a .hal file loaded after the kinematics module (HALFILE), replacing the pins' earlier setp/sets"
        return KinematicsOutput("\n".join(lines) + "\n", new, absorbed, left,
                                (f"put the lines in {where}, then restart LinuxCNC: the kinematics read the pins "
                                 "at every servo period, a running machine would jump",))

    def parse(self, text: str, where: str = "<hal>", prefix: str = PREFIX) -> dict[str, float]:
        """The pins a .hal file or INI [HAL] lines ``setp``; a pin they do not set reads 0 in LinuxCNC (an
        unconnected HAL input). A pin fed by a signal (``net``) is refused: its value is the signal's."""
        found: dict[str, float] = {}
        for line_no, line in enumerate(text.splitlines(), start=1):
            net = NET.fullmatch(line)
            if net:
                fed = [p for p in PINS if f"{prefix}.{p}" in net.group(1).split()]
                if fed:
                    raise CompensationError(f"{where}:{line_no}: {prefix}.{fed[0]} is fed by a signal (net): its value is "
                                            "the signal's; set the pins with setp")
                continue
            m = SETP.fullmatch(line)
            if not m or not m.group(1).startswith(prefix + "."):
                continue
            pin = m.group(1)[len(prefix) + 1:]
            if pin not in PINS:
                continue  # tool-offset, x-offset: not the axes' location
            try:
                value = float(m.group(2))
            except ValueError:
                raise CompensationError(f"{where}:{line_no}: {m.group(1)} {m.group(2)!r} is not a number") from None
            found[pin] = value
        return {p: found.get(p, 0.0) for p in PINS}
