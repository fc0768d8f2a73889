"""Files a command reads besides procedures and scenarios: a run's positioning deviations (its
results.json, checked against its store, or a deviation CSV) and a list of station centres. A mistake
is a :class:`~rtcal.errors.UserError` naming the file (and line or field)."""

from __future__ import annotations

import csv
import io
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from rtcal.errors import UserError
from rtcal.procedure.yamlfile import FileProblems, read_bytes

if TYPE_CHECKING:
    from rtcal.deliverables.deviations import PositioningDeviations
    from rtcal.results import RunResults


def read_deviation_table(path_text: str) -> tuple[PositioningDeviations, RunResults | None]:
    """A run directory's positioning deviations (its results.json, validated) or a deviation CSV;
    mistakes are UserErrors naming the file and, in results.json, the field."""
    from rtcal.deliverables.deviations import DeviationTableError, PositioningDeviations
    from rtcal.methods import read_results
    from rtcal.results import ResultsError

    path = Path(path_text)
    try:
        if path.is_dir():
            if not (path / "results.json").exists():
                raise UserError(f"{path}: not a run directory with a readable results.json (a run that was not solved?)")
            from rtcal.run.integrity import check_run

            try:
                results = read_results(path)
                for warning in check_run(path, results):  # refused if it does not match its store
                    print(f"rtcal: warning: {warning}", file=sys.stderr)
            except ResultsError as exc:
                raise UserError(str(exc)) from None
            if results.positioning_deviations is None:
                raise UserError(f"{path / 'results.json'}: no positioning_deviations (the run has no recommended estimate)")
            table = PositioningDeviations.from_model(results.positioning_deviations, str(path / "results.json"))
            table.check_plausible(str(path / "results.json"))
            return table, results
        table = PositioningDeviations.read_csv(path)
        table.check_plausible(str(path))
        _same_as_its_run(table, path)
        return table, None
    except DeviationTableError as exc:
        raise UserError(str(exc)) from None


def _same_as_its_run(table: PositioningDeviations, path: Path) -> None:
    """A run's own positioning_deviations.csv (a results.json beside it) must hold the run's table:
    an edited copy is refused (UserError naming both files), not compensated or certified."""
    from rtcal.deliverables.deviations import PositioningDeviations
    from rtcal.methods import read_results
    from rtcal.results import ResultsError
    from rtcal.run.integrity import check_run

    beside = path.parent / "results.json"
    if path.name != RUN_CSV or not beside.is_file():
        return
    try:
        results = read_results(path.parent)
        check_run(path.parent, results)  # the run's own results, as its store records them
    except ResultsError as exc:
        raise UserError(f"{path} lies beside {beside}, which cannot be checked against: {exc}") from None
    if results.positioning_deviations is None:
        raise UserError(f"{path} lies beside {beside}, which holds no positioning_deviations: not that run's table")
    run_table = PositioningDeviations.from_model(results.positioning_deviations, str(beside))
    if table.to_csv() != run_table.to_csv():
        raise UserError(f"{path} does not hold the positioning deviations of {beside} beside it: it was edited after "
                        f"the run; give the run directory ({path.parent}) to use the run's table")


RUN_CSV = "positioning_deviations.csv"  # what every run writes beside its results.json


def read_stations_csv(path: Path) -> np.ndarray:
    """Station centres from a CSV with header X,Y,Z (mm), one station per row, in order."""
    try:
        data = read_bytes(path, 16 * 1024 * 1024)
    except FileProblems as exc:
        raise UserError(str(exc.problems[0])) from None
    try:
        with io.StringIO(data.decode("utf-8-sig"), newline="") as fh:  # -sig: a spreadsheet's byte-order mark
            reader = csv.DictReader(fh)
            fields = [f.strip() for f in (reader.fieldnames or [])]
            if not {"X", "Y", "Z"} <= set(fields):
                raise UserError(f"{path}:1: header must name X,Y,Z (found {','.join(fields) or 'nothing'})")
            rows = []
            for k, row in enumerate(reader, start=2):
                row = {key.strip(): v for key, v in row.items() if key}
                try:
                    xyz = [float(row["X"]), float(row["Y"]), float(row["Z"])]
                except (TypeError, ValueError):
                    raise UserError(f"{path}:{k}: X, Y and Z must be numbers (mm)") from None
                if not all(abs(v) <= 1e6 for v in xyz):  # also false for NaN
                    raise UserError(f"{path}:{k}: X, Y and Z must be finite and within ±1e6 mm")
                rows.append(xyz)
    except UnicodeDecodeError:
        raise UserError(f"{path}: not UTF-8 text") from None
    except csv.Error as exc:
        raise UserError(f"{path}:{reader.line_num}: not CSV: {exc}") from None
    if len(rows) < 4:
        raise UserError(f"{path}: {len(rows)} stations; at least 4 are needed (eq. 2)")
    return np.array(rows)
