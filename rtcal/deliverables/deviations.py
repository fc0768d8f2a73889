"""The positioning-deviation table: the one result type every method hands downstream.

One row per (target, direction, run): the deviation x = actual − target (ISO 230-2's x_ij; for
a rotary axis in arcsec, positive = the table turned further than commanded) and its standard
uncertainty u (k = 1), with the rows' covariance where the method knows it. Evaluation
(ISO 230-2, VDI 3441), compensation writers, run comparison and reports read only this table.

Deviations are referred to one zero: the first target of the first direction measured (ISO
230-1's ECC relative to the first target), so that a reversal between directions stays
visible. Runs are numbered from 1, directions are +1 (↑, positive approach) and −1 (↓).
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rtcal.results.model import DeviationTable

CSV_HEADER = ("target_deg", "direction", "run", "deviation_arcsec")
CSV_OPTIONAL = ("uncertainty_arcsec",)
MAX_CSV_BYTES = 200_000_000  # a million rows with room to spare; read whole, so bounded
MAX_TARGET_DEG = 36_000.0  # a hundred turns either way: beyond it a target is a mistake, not a table
MAX_DEVIATION_ARCSEC = 1_296_000.0  # one turn: no positioning deviation or uncertainty is larger
# what a rotary table in service deviates at most: 1° (the worst tables measured deviate some tens of
# arcseconds; a stepper that lost steps, a few hundred). Beyond it a table is an edit or a mix-up, and
# evaluate, compensate and compare refuse it rather than certify or compensate it (docs/faults.md)
PLAUSIBLE_DEVIATION_ARCSEC = 3600.0


def _rounded(value: float, digits: int) -> float:
    """``value`` to ``digits`` places, a rounding zero as 0 (never −0: a deviation of −1e-16 is no sign)."""
    return round(float(value), digits) + 0.0


class DeviationTableError(ValueError):
    """A deviation table (CSV or results.json) that cannot be read; the message says where."""


@dataclass(frozen=True)
class PositioningDeviations:
    """Rows of (target_deg, direction, run, deviation_arcsec, uncertainty_arcsec).

    ``covariance_arcsec2`` (rows × rows) is given where the estimator propagated one; its
    diagonal is ``uncertainty_arcsec``². ``estimator`` names the estimate the rows come from.
    """

    target_deg: np.ndarray
    direction: np.ndarray
    run: np.ndarray
    deviation_arcsec: np.ndarray
    uncertainty_arcsec: np.ndarray
    covariance_arcsec2: np.ndarray | None = None
    estimator: str = ""
    notes: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        n = len(np.asarray(self.target_deg))
        for name in ("direction", "run", "deviation_arcsec", "uncertainty_arcsec"):
            if len(np.asarray(getattr(self, name))) != n:
                raise ValueError(f"{name} has {len(np.asarray(getattr(self, name)))} rows, target_deg {n}")
        if self.covariance_arcsec2 is not None and np.shape(self.covariance_arcsec2) != (n, n):
            raise ValueError(f"covariance is {np.shape(self.covariance_arcsec2)}, expected {(n, n)}")

    def __len__(self) -> int:
        return len(self.target_deg)

    @property
    def expanded_uncertainty_arcsec(self) -> np.ndarray:
        """U = k·u with k = 2 (about 95 % for a normal distribution)."""
        return 2.0 * np.asarray(self.uncertainty_arcsec, float)

    def select(self, mask: np.ndarray) -> "PositioningDeviations":
        mask = np.asarray(mask, bool)
        cov = None if self.covariance_arcsec2 is None else self.covariance_arcsec2[np.ix_(mask, mask)]
        return PositioningDeviations(self.target_deg[mask], self.direction[mask], self.run[mask],
                                     self.deviation_arcsec[mask], self.uncertainty_arcsec[mask], cov,
                                     self.estimator, self.notes)

    # -- results.json ---------------------------------------------------------------------
    def to_model(self, digits: int = 4) -> DeviationTable:
        """The ``positioning_deviations`` block of results.json (the covariance is not repeated
        there: the estimate has it)."""
        def col(a: np.ndarray, d: int | None = None) -> list[float | None]:
            a = np.asarray(a, float)
            return [None if not np.isfinite(v) else (_rounded(v, d) if d is not None else float(v)) for v in a]

        return DeviationTable(
            estimator=self.estimator,
            target_deg=[round(float(t), 9) for t in self.target_deg],
            direction=[int(d) for d in self.direction],
            run=[int(r) for r in self.run],
            deviation_arcsec=col(self.deviation_arcsec, digits),
            uncertainty_arcsec=col(self.uncertainty_arcsec, digits),
            notes=list(self.notes),
        )

    @classmethod
    def from_model(cls, block: DeviationTable, where: str = "results.json") -> "PositioningDeviations":
        """The table of a (validated) results.json; a row twice is a DeviationTableError naming ``where``."""
        table = cls(
            np.asarray(block.target_deg, float),
            np.asarray(block.direction, int),
            np.asarray(block.run, int),
            np.asarray([np.nan if v is None else v for v in block.deviation_arcsec], float),
            np.asarray([np.nan if v is None else v for v in block.uncertainty_arcsec], float),
            estimator=block.estimator,
            notes=tuple(block.notes),
        )
        table.check(where)
        return table

    # -- CSV ----------------------------------------------------------------------------
    def to_csv(self) -> str:
        """``target_deg,direction,run,deviation_arcsec,uncertainty_arcsec``, one row per approach."""
        out = io.StringIO()
        w = csv.writer(out, lineterminator="\n")
        w.writerow(CSV_HEADER + CSV_OPTIONAL)
        for t, d, r, x, u in zip(self.target_deg, self.direction, self.run, self.deviation_arcsec, self.uncertainty_arcsec):
            w.writerow([f"{float(t):.9g}", int(d), int(r), "" if not np.isfinite(x) else f"{_rounded(x, 4):.4f}",
                        "" if not np.isfinite(u) else f"{_rounded(u, 4):.4f}"])
        return out.getvalue()

    def write_csv(self, path: Path) -> Path:
        path.write_text(self.to_csv(), encoding="utf-8")
        return path


    @classmethod
    def read_csv(cls, path: str | Path, max_rows: int = 1_000_000) -> "PositioningDeviations":
        """Read a deviation CSV (UTF-8, with or without the byte-order mark a spreadsheet writes);
        every problem names the file and line. Only a regular file of bounded size is read: a
        device, a pipe or a directory is refused without reading it."""
        from rtcal.procedure.yamlfile import FileProblems, read_bytes

        try:
            data = read_bytes(path, MAX_CSV_BYTES)
        except FileProblems as exc:
            raise DeviationTableError(f"{path}: {exc.problems[0].message}") from None
        try:
            text = data.decode("utf-8-sig")
        except UnicodeDecodeError as exc:
            line = data.count(b"\n", 0, exc.start) + 1
            raise DeviationTableError(f"{path}:{line}: not UTF-8 text (a deviation CSV is UTF-8)") from None
        return cls.parse_csv(text, str(path), max_rows)

    @classmethod
    def parse_csv(cls, text: str, where: str = "<csv>", max_rows: int = 1_000_000) -> "PositioningDeviations":
        """The table in a CSV text; anything else is a DeviationTableError naming where."""
        try:
            return cls._parse_csv(text, where, max_rows)
        except csv.Error as exc:  # a NUL byte, a newline inside an unquoted field, …
            raise DeviationTableError(f"{where}: not CSV: {exc}") from None

    @classmethod
    def _parse_csv(cls, text: str, where: str, max_rows: int) -> "PositioningDeviations":
        reader = csv.reader(io.StringIO(text))
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise DeviationTableError(f"{where}:1: empty file; expected the header {','.join(CSV_HEADER)}") from None
        missing = [h for h in CSV_HEADER if h not in header]
        if missing:
            raise DeviationTableError(f"{where}:1: header must name {','.join(CSV_HEADER)} (missing {', '.join(missing)})")
        idx = {h: header.index(h) for h in CSV_HEADER + CSV_OPTIONAL if h in header}
        rows: list[tuple[float, int, int, float, float]] = []
        for line, row in enumerate(reader, start=2):
            if not row or all(not c.strip() for c in row):
                continue
            if len(rows) >= max_rows:
                raise DeviationTableError(f"{where}:{line}: more than {max_rows} rows")
            try:
                t = float(row[idx["target_deg"]])
                d = int(row[idx["direction"]])
                r = int(row[idx["run"]])
                x = float(row[idx["deviation_arcsec"]])
                u_text = row[idx["uncertainty_arcsec"]].strip() if "uncertainty_arcsec" in idx and idx["uncertainty_arcsec"] < len(row) else ""
                u = float(u_text) if u_text else float("nan")
            except (IndexError, ValueError):
                raise DeviationTableError(f"{where}:{line}: expected numbers in {','.join(CSV_HEADER)} "
                                          f"(direction +1/-1, run an integer); got {','.join(row)[:80]!r}") from None
            if d not in (1, -1):
                raise DeviationTableError(f"{where}:{line}: direction must be 1 (positive approach) or -1 (negative), got {d}")
            if not (np.isfinite(t) and np.isfinite(x)) or (np.isfinite(u) and u < 0) or u == float("inf"):
                raise DeviationTableError(f"{where}:{line}: target, deviation and uncertainty must be finite (u ≥ 0)")
            if not 1 <= r <= 1_000_000:
                raise DeviationTableError(f"{where}:{line}: runs are numbered from 1 (to at most 1000000), got {str(r)[:20]}")
            rows.append((t, d, r, x, u))
        if not rows:
            raise DeviationTableError(f"{where}: no rows after the header")
        a = np.array(rows, dtype=float)
        table = cls(a[:, 0], a[:, 1].astype(int), a[:, 2].astype(int), a[:, 3], a[:, 4], estimator="", notes=())
        table.check(where)
        return table

    def check_plausible(self, where: str, bound_arcsec: float = PLAUSIBLE_DEVIATION_ARCSEC) -> None:
        """Values a rotary table has: every deviation within ±``bound_arcsec``, and an uncertainty,
        where one is given, above 0 at every measured row (0 only at the reference row, whose
        deviation is 0 by definition). DeviationTableError naming the row otherwise."""
        x, u = np.asarray(self.deviation_arcsec, float), np.asarray(self.uncertainty_arcsec, float)

        def row(i: int) -> str:
            return (f"{where}: row {i + 1} (target {float(self.target_deg[i]):g}°, direction {int(self.direction[i]):+d}, "
                    f"run {int(self.run[i])})")

        beyond = np.nonzero(np.isfinite(x) & (np.abs(x) > bound_arcsec))[0]
        if len(beyond):
            i = int(beyond[0])
            raise DeviationTableError(f"{row(i)}: deviation {x[i]:.6g}″ lies beyond ±{bound_arcsec:g}″, more than any "
                                      "rotary table deviates: refused (an edited or mixed-up table?)")
        zero = np.nonzero(np.isfinite(x) & (x != 0) & np.isfinite(u) & (u <= 0))[0]
        if len(zero):
            i = int(zero[0])
            raise DeviationTableError(f"{row(i)}: uncertainty {u[i]:g}″ for a measured deviation of {x[i]:g}″: every "
                                      "measurement has an uncertainty above 0: refused (an edited table?)")

    def check(self, where: str) -> None:
        """Targets within ±100 turns, deviations and uncertainties within one turn (and so every sum
        and square of them finite), one row per (target, direction, run)."""
        for name, limit, unit in (("target_deg", MAX_TARGET_DEG, "°"), ("deviation_arcsec", MAX_DEVIATION_ARCSEC, "″"),
                                  ("uncertainty_arcsec", MAX_DEVIATION_ARCSEC, "″")):
            values = np.asarray(getattr(self, name), float)
            beyond = np.nonzero(np.abs(values) > limit)[0]  # NaN (a missing value) is not beyond
            if len(beyond):
                raise DeviationTableError(f"{where}: row {int(beyond[0]) + 1}: {name} {values[beyond[0]]:.6g} lies beyond "
                                          f"±{limit:,.0f}{unit}; not a positioning deviation table")
        keys = list(zip(np.round(self.target_deg, 9), self.direction, self.run))
        if len(set(keys)) != len(keys):
            seen: set[tuple[float, int, int]] = set()
            for dup in keys:  # the first key seen before (there is one)
                if dup in seen:
                    break
                seen.add(dup)
            raise DeviationTableError(f"{where}: target {dup[0]:g}°, direction {int(dup[1]):+d}, run {int(dup[2])} "
                                      "appears more than once")
