"""A positioning test's cycle as a method's procedure states it and its plan visits it: targets, approach
directions, runs, an overrun past each target (ISO 230-2's linear cycle: each run ↑ through every target, then ↓,
every target approached from its own side). A method whose plan is this cycle of its ``stage`` takes
:class:`CycleProcedureBase` as its procedure's base (its ``steps:`` a :class:`TargetCycle`; the plan's size and
the stage's soft limits checked once, here); the seed methods have cycles of their own (seatings, stations)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from pydantic import Field, ValidationInfo, model_validator

from rtcal.procedure.models import ProcedureBase, StrictModel, plan_outside_limits, plan_size_problem


@dataclass(frozen=True)
class Visit:
    """One visit of the stage: its run (0, 1, …), approach direction (+1, −1), target index and angle."""

    run: int
    direction: int
    step: int
    angle_deg: float


class TargetCycle(StrictModel):
    """The targets, directions, runs and overrun of a positioning test."""

    targets_deg: list[float] = Field([0.0, 45.0, 90.0, 135.0, 180.0, 225.0, 270.0, 315.0], min_length=2, max_length=360,
                                     description="the targets, deg, in increasing order")
    directions: list[Literal["positive", "negative"]] = Field(["positive", "negative"], min_length=1, max_length=2,
                                                              description="approach directions")
    runs: int = Field(2, ge=1, le=100, description="runs per direction (ISO 230-2: 5)")
    overshoot_deg: float = Field(1.0, ge=0.0, le=90.0, description="overrun past each target, deg")

    @model_validator(mode="after")
    def _increasing(self) -> TargetCycle:
        if any(b <= a for a, b in zip(self.targets_deg, self.targets_deg[1:])):
            raise ValueError("targets_deg: give the targets in increasing order, each once")
        return self

    def signs(self) -> list[int]:
        """The approach directions as +1 (positive) and −1 (negative), in the procedure's order."""
        return [1 if d == "positive" else -1 for d in self.directions]

    def approaches(self) -> tuple[set[int], int]:
        """The directions and runs per direction the positioning-deviation table will have."""
        return set(self.signs()), self.runs

    def stage_deg(self) -> list[float]:
        """Every angle the stage is commanded to: the targets and, for each direction, its overrun."""
        return list(self.targets_deg) + [a - d * self.overshoot_deg for a in self.targets_deg for d in self.signs()]

    def visits(self) -> list[Visit]:
        """Every visit in measuring order: each run ↑ through every target, then ↓ (the linear cycle)."""
        out = []
        for r in range(self.runs):
            for d in self.signs():
                order = range(len(self.targets_deg)) if d > 0 else range(len(self.targets_deg) - 1, -1, -1)
                out += [Visit(r, d, i, float(self.targets_deg[i])) for i in order]
        return out


class CycleProcedureBase(ProcedureBase):
    """A procedure whose plan visits its ``stage`` through a :class:`TargetCycle`, reading ``samples_per_reading``
    times after ``settle_time_s`` at each visit: what every such procedure says of its size, its directions and
    its stage's targets, said once (a subclass gives ``method``, ``instruments`` with a ``stage``, and its own)."""

    steps: TargetCycle = Field(TargetCycle(), description="targets, directions, runs, overrun")
    samples_per_reading: int = Field(1, ge=1, le=1000, description="readings averaged per visit")
    settle_time_s: float = Field(1.0, ge=0.0, le=3600.0, description="wait after each motion before reading, s")

    def directions(self) -> list[int]:
        return self.steps.signs()

    def approaches(self) -> tuple[set[int], int]:
        return self.steps.approaches()

    def plan_size(self, max_cells: int, hint: str) -> tuple[int, str, str, str | None]:
        visits = len(self.steps.visits())
        return visits * self.samples_per_reading, "steps", f"{visits} visits × {self.samples_per_reading} samples", None

    def planned_stage_deg(self) -> tuple[str, list[float]]:
        return "steps", self.steps.stage_deg()

    @model_validator(mode="after")
    def _within_limits(self, info: ValidationInfo) -> CycleProcedureBase:
        stage = getattr(self.instruments, "stage")
        problem = plan_size_problem(self, large=bool((info.context or {}).get("large"))) or plan_outside_limits(
            self, stage.soft_limits_deg)
        if problem:
            raise ValueError(problem)
        return self
