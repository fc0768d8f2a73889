"""Procedure models. Units live in key names; the numeric core converts at the edge.

A procedure names its ``method``; its ``instruments`` section chooses a backend per
instrument; ``bench`` names the scenario that simulated backends observe (a path relative to
the procedure file), which ``rtcal run --scenario`` replaces.
"""

from __future__ import annotations

from typing import Literal, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

Vec3 = tuple[float, float, float]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class InstrumentChoice(_Strict):
    """Which backend serves an instrument. ``sim``: in-process, on the simulated bench."""

    backend: Literal["sim"] = "sim"


class MultistationInstruments(_Strict):
    stage: InstrumentChoice = InstrumentChoice()
    cmm: InstrumentChoice = InstrumentChoice()
    laser_tracer: InstrumentChoice = InstrumentChoice()


class Stations(_Strict):
    """Table stations: first angle, constant step, count (eq. 2 needs m ≥ 4)."""

    first_angle_deg: float = -145.0
    step_deg: float = Field(30.0, gt=0.0, lt=180.0)
    count: int = Field(11, ge=4, le=720)
    approach: Literal["positive", "negative"] = "positive"
    overshoot_deg: float = Field(1.0, ge=0.0, le=90.0)  # pass the target by this much to approach it the set way

    def angles_deg(self) -> np.ndarray:
        sign = 1.0 if self.approach == "positive" else -1.0
        return self.first_angle_deg + sign * self.step_deg * np.arange(self.count)


class GridPlan(_Strict):
    """The paper's plan: layers of a serpentine grid in a box (4 × 16 points in 450 × 600 × 450 mm)."""

    kind: Literal["grid"] = "grid"
    volume_min_mm: Vec3 = (700.0, -300.0, 100.0)
    volume_size_mm: Vec3 = (450.0, 600.0, 450.0)
    layers: int = Field(4, ge=1, le=100)
    columns: int = Field(4, ge=1, le=100)  # along X
    rows: int = Field(4, ge=1, le=100)  # along Y

    def points_mm(self) -> np.ndarray:
        lo, size = np.array(self.volume_min_mm), np.array(self.volume_size_mm)
        xs = lo[0] + size[0] * (np.arange(self.columns) / max(self.columns - 1, 1))
        ys = lo[1] + size[1] * (np.arange(self.rows) / max(self.rows - 1, 1))
        zs = lo[2] + size[2] * (np.arange(self.layers) / max(self.layers - 1, 1))
        layer = []
        for r, y in enumerate(ys):
            row = xs if r % 2 == 0 else xs[::-1]
            layer.extend((x, y) for x in row)
        return np.array([(x, y, z) for z in zs for x, y in layer])


class ListPlan(_Strict):
    """An explicit list of CMM points (mm, CMM frame), measured in the order given."""

    kind: Literal["list"]
    points_mm: list[Vec3] = Field(min_length=1)

    def points_mm_array(self) -> np.ndarray:
        return np.array(self.points_mm, dtype=float)


class LMSettings(_Strict):
    """The paper's LM parameters (section 4.2.1)."""

    beta: float = Field(0.55, gt=0.0, lt=1.0)
    sigma: float = Field(0.4, gt=0.0, lt=1.0)
    epsilon: float = Field(1e-4, gt=0.0)
    mu0: float | Literal["residual_norm"] = 0.75
    max_iterations: int = Field(200, ge=1)


class MultistationSolver(_Strict):
    lm: LMSettings = LMSettings()
    first_station_guess_mm: Vec3 = (-64.9938, -6.6256, 122.5133)  # the paper's X0, Y0, Z0
    axis_point_mm: Vec3 = (0.0, 0.0, 0.0)  # nominal axis (vertical) for the other stations' guesses


class LaserTracerMultistation(_Strict):
    """Seed 000: tracer on the table, CMM moves the reflector, table indexes through stations."""

    method: Literal["laser_tracer_multistation"]
    name: str = ""
    bench: str | None = None
    instruments: MultistationInstruments = MultistationInstruments()
    stations: Stations = Stations()
    points: Union[GridPlan, ListPlan] = Field(GridPlan(), discriminator="kind")
    order: Literal["point_major", "station_major"] = "point_major"
    samples_per_reading: int = Field(1, ge=1, le=1000)
    settle_time_s: float = Field(2.0, ge=0.0)
    solver: MultistationSolver = MultistationSolver()

    def points_array(self) -> np.ndarray:
        return self.points.points_mm() if isinstance(self.points, GridPlan) else self.points.points_mm_array()

    @model_validator(mode="after")
    def _solvable(self) -> "LaserTracerMultistation":
        pts = self.points_array()
        n, m = len(pts), self.stations.count
        if n < 16:
            raise ValueError(f"points: the plan has {n} points; eq. 2 needs n ≥ 16")
        if m * n < 4 * m + 3 * n:
            raise ValueError(f"points: m·n = {m * n} < 4m + 3n = {4 * m + 3 * n} (eq. 2): too few stations or points")
        centred = pts - pts.mean(axis=0)
        sv = np.linalg.svd(centred, compute_uv=False)
        if sv[-1] < 1e-6 * max(sv[0], 1e-12):
            raise ValueError("points: the CMM points are coplanar or collinear: station height cannot be determined")
        span = abs(self.stations.step_deg) * (self.stations.count - 1)
        if span >= 360.0:
            raise ValueError(f"stations: they span {span}° ≥ 360°: stations would repeat")
        return self


Procedure = LaserTracerMultistation
PROCEDURE_MODELS: dict[str, type[BaseModel]] = {"laser_tracer_multistation": LaserTracerMultistation}
