"""What every compensation format shares: the table of trims a writer takes and a parser
returns, the error a table that cannot be made or read raises, and the checks every rotary
table read from a file must pass (0 … 360°, evenly spaced, closing on itself)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ARCSEC_PER_DEG = 3600.0


class CompensationError(ValueError):
    """A table that cannot be made or read; the message says why (and where, for a file)."""


@dataclass(frozen=True)
class CompensationTable:
    """Trims (deg) at ascending positions. From ``table_from_deviations``: one turn, 0 … 360
    inclusive (the last repeats the first), at the measured targets — with 0° (and so 360°)
    interpolated across the wrap when 0° was not measured — or on a regular grid when one was
    asked for (``resampled``).

    ``modulo``: the controller applies the table to the command modulo one turn (SINUMERIK modulo
    tables, FANUC rotary axes, HEIDENHAIN 0 … 360 tables). False for LinuxCNC, which does not wrap:
    beyond its first and last lines the end trims hold (its sentinel entries have zero slope), so
    its table must span the joint's travel.

    ``measured_targets``: how many distinct targets the table was made from (0: read from a file).
    ``warnings``: what the user must read before loading it (one direction written both ways,
    gaps too wide for the error the data show) — on the console, and in the file where the
    format takes comments.
    """

    positions_deg: np.ndarray
    trim_up_deg: np.ndarray
    trim_down_deg: np.ndarray  # equal to trim_up_deg for a one-direction format
    modulo: bool = True
    measured_targets: int = 0
    resampled: bool = False
    off_grid: int = 0  # measured targets a resampled grid does not hold (it keeps only their interpolation)
    warnings: tuple[str, ...] = ()

    @property
    def step_deg(self) -> float:
        return float(self.positions_deg[1] - self.positions_deg[0])

    @property
    def evenly_spaced(self) -> bool:
        """Entries at one pitch from 0° to 360° (what a format with a fixed pitch can hold)."""
        p = np.asarray(self.positions_deg, float)
        return len(p) >= 3 and abs(p[0]) < 1e-6 and abs(p[-1] - 360.0) < 1e-6 and float(np.ptp(np.diff(p))) < 1e-6

    def summary(self) -> str:
        """How many points were measured and how many written, e.g. "12 measured targets, 12 points
        written" or "12 measured targets resampled to 24 points every 15°" (per turn: the entry at
        360° repeats the one at 0°)."""
        per_turn = len(self.positions_deg) - 1
        if self.resampled:
            return (f"{self.measured_targets} measured targets resampled to {per_turn} points every {self.step_deg:g}° "
                    + (f"(--step-deg; {self.off_grid} of the measured targets lie between the grid's points, which keep "
                       "only their interpolation)" if self.off_grid else "(--step-deg; every measured target is a grid point)"))
        extra = per_turn - self.measured_targets
        return (f"{self.measured_targets} measured targets, {per_turn} points written"
                + (" (0° interpolated across the wrap: it was not measured)" if extra else ""))

    def trim_deg(self, commanded_deg: float, direction: int) -> float:
        """What the controller adds to a command approached in ``direction``: linear between entries."""
        values = self.trim_up_deg if direction >= 0 else self.trim_down_deg
        at = np.mod(commanded_deg, 360.0) if self.modulo else commanded_deg
        return float(np.interp(at, self.positions_deg, values))  # np.interp holds the end values outside


def empty(where: str) -> CompensationTable:
    """A file with no entries: an error naming it."""
    raise CompensationError(f"{where}: no entries")


def sane(up: np.ndarray, down: np.ndarray, where: str) -> None:
    """Finite trims below one degree in both directions (what any file read must hold)."""
    for name, values in (("positive", up), ("negative", down)):
        if not np.all(np.isfinite(values)) or np.max(np.abs(values)) > 1.0:
            raise CompensationError(f"{where}: {name}-direction values must be finite and below 1 degree")


def regular_table(positions: np.ndarray, up: np.ndarray, down: np.ndarray, where: str, max_points: int) -> CompensationTable:
    """Check what every fixed-pitch format needs for a rotary axis: 0 … 360, evenly spaced, closing on itself."""
    positions = np.asarray(positions, float)
    if len(positions) < 3 or len(positions) > max_points:
        raise CompensationError(f"{where}: {len(positions)} entries (3 … {max_points})")
    steps = np.diff(positions)
    if np.any(steps <= 0):
        raise CompensationError(f"{where}: positions must be strictly ascending")
    if abs(positions[0]) > 1e-6 or abs(positions[-1] - 360.0) > 1e-6 or np.ptp(steps) > 1e-6:
        raise CompensationError(f"{where}: a rotary table's entries run evenly from 0 to 360 degrees")
    sane(up, down, where)
    for name, values in (("positive", up), ("negative", down)):
        if abs(values[0] - values[-1]) > 1e-9:
            raise CompensationError(f"{where}: the {name}-direction value at 360° must equal the one at 0° (one turn closes)")
    return CompensationTable(positions, np.asarray(up, float), np.asarray(down, float))
