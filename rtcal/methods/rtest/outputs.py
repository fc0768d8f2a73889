"""The R-test's outputs: location_errors.csv, the sphere path before and after compensation (a figure), the
control's kinematics corrected in each location-error format (compensation/), the report's section and the
certificate's ISO 230-7 table of both axes with U (k = 2)."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any, Mapping

from matplotlib.figure import Figure

from rtcal import api
from rtcal.methods.rtest.procedure import FORMATS
from rtcal.methods.rtest.results import RTestResults

FIGURE = "rtest_sphere_path.png"
FILES = {"linuxcnc-xyzac-trt": "linuxcnc-xyzac-trt.hal", "siemens-tc-carr": "siemens-tc-carr.mpf",
         "fanuc-tcp-table": "fanuc-tcp-table.txt"}
UNIT = {"um": "µm", "arcsec": "″"}


def location_errors(results: RTestResults) -> Any:
    """The results' location errors as the compensation formats take them (symbol → value, u)."""
    return api.LocationErrors.of({s: (e.value, e.standard_uncertainty) for s, e in results.location_errors.items()},
                                 "ISO 230-7, docs/rtest.md's signs")


def compensation(results: RTestResults) -> dict[str, Any]:
    """Each format's :class:`KinematicsOutput` for the measured location errors, from the control's records."""
    errors = location_errors(results)
    return {fmt: api.kinematics_format(fmt).write(results.control_records[fmt], errors) for fmt in FORMATS
            if fmt in results.control_records}


def _symbol(s: str) -> tuple[str, str]:
    name, unit = s.split("_")
    return name, UNIT[unit]


class RTestOutputs(api.OutputsBase):
    def __init__(self, results: RTestResults):
        self.results = results

    def write_files(self, run_dir: Path) -> list[Path]:
        r = self.results
        out = run_dir / "location_errors.csv"
        with out.open("w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(["symbol", "axis", "value", "unit", "u", "U", "k"])
            for s, e in r.location_errors.items():
                name, unit = _symbol(s)
                w.writerow([name, e.axis, e.value, unit, e.standard_uncertainty, e.expanded_uncertainty, e.coverage_factor])
        written = [out]
        folder = run_dir / "compensation"
        folder.mkdir(exist_ok=True)
        for fmt, kin in compensation(r).items():
            path = folder / FILES[fmt]
            path.write_text(kin.text, encoding="utf-8")
            written.append(path)
        fig = Figure(figsize=(9, 4.6), layout="constrained")
        ax = fig.add_subplot()
        p = r.sphere_path
        k = list(range(1, len(p.before_um) + 1))
        ax.plot(k, p.before_um, "o-", label="before compensation (as measured)")
        ax.plot(k, p.after_um, "s-", label="after: the eight location errors compensated")
        ax.set_xlabel("pose of the kinematic tests")
        ax.set_ylabel("|sphere centre − nest zero| / µm")
        ax.grid(alpha=0.3)
        api.legend_below(fig)  # inside the axes it covered the first poses' deviations
        fig.savefig(run_dir / FIGURE, dpi=110)
        return [*written, run_dir / FIGURE]

    def _rows(self) -> list[list[str]]:
        rows = []
        for s, e in self.results.location_errors.items():
            name, unit = _symbol(s)
            rows.append([e.axis, name, f"{e.value:+.2f} {unit}", f"{e.expanded_uncertainty:.2f} {unit}"])
        return rows

    def report_body(self) -> list[str]:
        r = self.results
        lines = ["## Location errors (ISO 230-7)", "", "| axis | symbol | value | U (k = 2) |", "|---|---|---|---|"]
        lines += [f"| {' | '.join(row)} |" for row in self._rows()]
        lines += ["", "Not determined with this set-up:", ""]
        lines += [f"- {s.split('_')[0]}: {why}" for s, why in r.not_determined.items()]
        p = r.sphere_path
        lines += ["", f"Sphere path: largest deviation {max(p.before_um):.2f} µm as measured, {max(p.after_um):.2f} µm once "
                  f"the location errors are compensated; drift {', '.join(f'{v:+.2f}' for v in r.drift_um)} µm (x, y, z).", ""]
        second = r.sphere.second
        if second is not None:
            lines[-1:] = [f"The sphere's second position, X {second.position_mm[0]:g}, Y {second.position_mm[1]:g}, "
                          f"Z {second.position_mm[2]:g} mm: its set-up offset "
                          f"{', '.join(f'{v:+.2f}' for v in second.setup_um)} µm, its drift "
                          f"{', '.join(f'{v:+.2f}' for v in second.drift_um)} µm (x, y, z).", ""]
        return lines

    def certificate_figures(self) -> list[tuple[str, str]]:
        return [(FIGURE, "the sphere centre's deviation at each pose of the kinematic tests, before and after "
                         "compensation of the location errors")]

    def method_text(self) -> list[str]:
        s = self.results.sphere
        return [f"R-test (ISO 10791-6 kinematic tests): a sphere of radius {s.radius_mm:g} mm (form "
                f"{s.form_um:g} µm{', certificate ' + s.certificate if s.certificate else ''}) "
                "on the table, a nest of three displacement sensors in the spindle, calibrated on the machine from seven "
                "positions of the linear axes. C was turned at A = 0 and at a tilt, A at C = 0, both directions, the "
                "linear axes following the sphere's nominal path by the control's own kinematics; the first pose was "
                "repeated at the end for the drift. "
                + (f"The tests were repeated with the sphere moved to a second position (Z {s.second.position_mm[2]:g} "
                   "mm, its own drift measured; the drift while it was moved bridged at the measured rates). "
                   if s.second is not None else "")
                + "The location errors are the least-squares adjustment of the exact "
                "kinematic model to the sphere-centre displacements, with a GUM budget per parameter (k = 2)."]

    def subject(self) -> str:
        """The subtitle: what the R-test measured, its location errors axis by axis, then C's deviation."""
        axes = sorted({e.axis for e in self.results.location_errors.values()})
        parts = [f"location errors of the rotary {'axes' if len(axes) > 1 else 'axis'} {' and '.join(axes)} (ISO 230-7)"] \
            if axes else []
        q = self.results.recommended_result()
        if isinstance(q, api.QuantityEstimate):
            parts.append(f"{q.quantity} ({q.unit})")
        text = "; ".join(parts)
        return text[:1].upper() + text[1:]

    def standards_applied(self) -> list[str]:
        return ["ISO 230-7:2015 (location errors of the axes of rotation)",
                "ISO 10791-6:2014 (the kinematic tests of the rotary axes)"]

    def method_name(self) -> str:
        return "R-test of a trunnion table's rotary axes (ISO 230-7 location errors)"

    def summary(self) -> list[str]:
        r = self.results
        errs = ", ".join(f"{_symbol(s)[0]} {e.value:+.2f} ± {e.expanded_uncertainty:.2f} {_symbol(s)[1]}"
                         for s, e in r.location_errors.items())
        p = r.sphere_path
        return [f"location errors (U, k = 2): {errs}",
                f"sphere path: largest {max(p.before_um):.2f} µm as measured, {max(p.after_um):.2f} µm after compensation",
                "compensation: " + ", ".join(f"compensation/{f}" for f in FILES.values())]

    def certificate_tables(self) -> list[dict[str, Any]]:
        r = self.results
        tables: list[dict[str, Any]] = [
            {"heading": "Result: location errors of the rotary axes (ISO 230-7)",
             "note": "signs of docs/rtest.md; U = 2u (k = 2)",
             "header": ["axis", "symbol", "value", "U"], "rows": self._rows()},
            {"heading": "Not determined with this set-up", "note": "",
             "header": ["symbol", "why"], "rows": [[s.split("_")[0], why] for s, why in r.not_determined.items()]},
            {"heading": "Uncertainty budget", "note": "u (k = 1) per source and location error",
             "header": ["symbol", *sorted({k for e in r.location_errors.values() for k in e.budget})],
             "rows": [[_symbol(s)[0], *(f"{e.budget.get(k, 0.0):.3f}" for k in
                                        sorted({k for e in r.location_errors.values() for k in e.budget}))]
                      for s, e in r.location_errors.items()]}]
        nc = r.nest_calibration
        tables.append({"heading": "Nest calibration", "note": f"seven positions, ±{nc.move_mm:g} mm",
                       "header": ["sensor", "direction (x, y, z)", "u / °"],
                       "rows": [[str(i + 1), ", ".join(f"{v:+.4f}" for v in row), f"{u:.4f}"]
                                for i, (row, u) in enumerate(zip(nc.matrix, nc.direction_u_deg))]})
        return tables


def compensation_summary(kin: Mapping[str, Any]) -> list[str]:
    """What each format absorbed and what it could not."""
    return [f"{fmt}: absorbs {', '.join(k.absorbed) or 'nothing'}" + (f"; not: {', '.join(k.not_absorbed)}" if k.not_absorbed else "")
            for fmt, k in kin.items()]
