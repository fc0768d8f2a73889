"""What `rtcal plan` may vary in an encoder Abbe-error plan (the method's ``planner``): its runs."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any, Callable

from rtcal.methods.abbe.procedure import EncoderAbbeError
from rtcal.api import Candidate


def more_runs(plan: Candidate, runs: int) -> Candidate:
    data = copy.deepcopy(plan.procedure)
    data.setdefault("steps", {})["runs"] = runs
    return Candidate(data, plan.bench, plan.changes + (f"{runs} runs",))


class AbbePlanner:
    """What `rtcal plan` may vary in an encoder Abbe-error plan: its runs."""

    def levers(self, plan: Candidate, proc: EncoderAbbeError, max_radius_mm: float | None) -> list[Candidate]:
        return [more_runs(plan, r) for r in (2 * proc.steps.runs, 5 * proc.steps.runs) if r <= 100]

    def notes(self, proc: EncoderAbbeError) -> list[str]:
        return ["samples per reading: the budget takes each reading's stated noise as it is; runs average it"]

    def candidates(self, plan: Candidate, proc: EncoderAbbeError, max_radius_mm: float | None,
                   chains: dict[int, tuple[Candidate, ...]], duration_s: Callable[[Candidate], float]) -> list[tuple[float, Candidate]]:
        return [(float(n), p) for n, p in abbe_candidates(plan, proc)]

    def pruning(self, candidate: Candidate) -> tuple[bool, Any]:
        return False, None

    def points_refusal(self, path: Path, proc: EncoderAbbeError) -> str | None:
        return f"{path} is a procedure of {proc.method}; choosing CMM points is for laser_tracer_multistation procedures"

    def choose_points(self, path: Path, proc: EncoderAbbeError, scenario: Any, out: Path,
                      simulate: Callable[[Path, Path, Path], None]) -> str:
        raise ValueError(self.points_refusal(path, proc))


def abbe_candidates(plan: Candidate, proc: EncoderAbbeError) -> list[tuple[int, Candidate]]:
    runs = sorted({r for r in (proc.steps.runs, 2, 3, 4, 5, 7, 10, 15, 20, 30, 50, 100) if proc.steps.runs <= r <= 100})
    return [(r, plan if r == proc.steps.runs else more_runs(plan, r)) for r in runs]
