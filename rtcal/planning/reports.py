"""The typed documents `rtcal plan --json` and `rtcal uncertainty` (its uncertainty.json) write:
built here, in the package, so that the command line only prints them and other tools can read
them against a JSON Schema. Their JSON shape is what those commands have always written."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from pydantic import BaseModel, ConfigDict, Field, model_serializer

if TYPE_CHECKING:
    from rtcal.planning.levers import Outcome, Proposal
    from rtcal.procedure.models import Procedure


class _Document(BaseModel):
    """Fields in the order they are written (``FIRST`` ahead of the rest); a field that is None and
    listed in ``OMIT_WHEN_NONE`` is left out of the JSON (today's documents have no such key then)."""

    model_config = ConfigDict(extra="forbid")
    OMIT_WHEN_NONE: ClassVar[tuple[str, ...]] = ()
    FIRST: ClassVar[tuple[str, ...]] = ()

    @model_serializer(mode="wrap")
    def _shape(self, handler: Any) -> dict[str, Any]:
        data: dict[str, Any] = handler(self)
        for name in self.OMIT_WHEN_NONE:
            if name in data and data[name] is None:
                del data[name]
        return {**{k: data.pop(k) for k in self.FIRST if k in data}, **data}


# --- rtcal plan --json

class PredictedEstimator(_Document):
    """One estimator's prediction under the stated noise."""

    predicted_sigma_arcsec: list[float | None] = Field(description="predicted 1σ per target, arcsec (the first target is the reference)")
    predicted_expanded_arcsec: list[float | None] = Field(description="predicted U (k = 2) per target, arcsec")
    rms_predicted_sigma_arcsec: float = Field(description="RMS of the predicted 1σ over the targets after the first, arcsec")
    budget: dict[str, list[float | None]] = Field(description="each source's 1σ contribution per target, arcsec")


class DominantSource(_Document):
    source: str = Field(description="an uncertainty source of the recommended estimator")
    share: float = Field(description="its share of the variance over the targets (0 … 1)")


class LeverBuys(_Document):
    """What one lever of a proposal changes, applied after the ones before it."""

    lever: str = Field(description="the lever, in words")
    seconds: float = Field(description="the machine time it adds (negative: saves), s, walked")
    arcsec: float | None = Field(description="the change of U (k = 2) at the worst target, arcsec (null: a lever that "
                                             "changes no reading, so no prediction was made)")


class PlanOutcome(_Document):
    """A plan predicted the same way as the procedure (a lever, or a proposal)."""

    OMIT_WHEN_NONE = ("problem", "levers_buy")
    changes: list[str] = Field(description="what was changed, in words (['as written']: nothing)")
    recommended: str | None = Field(description="the recommended estimator of this plan")
    expanded_uncertainty_max_arcsec: float | None = Field(description="U (k = 2) at its worst target, arcsec (null: not finite)")
    duration_s: float = Field(description="its machine time, s")
    raw_readings: int = Field(description="its planned readings")
    sources_rms_arcsec: dict[str, float] = Field(description="each source's RMS 1σ over the targets, arcsec")
    problem: str | None = Field(None, description="why the plan could not be predicted (absent when it was)")
    levers_buy: list[LeverBuys] | None = Field(
        None, description="a proposal's levers applied in turn from the procedure as written, each with what it buys "
                          "(absent for a single lever)")

    @classmethod
    def of(cls, outcome: Outcome) -> PlanOutcome:
        return cls.model_validate(outcome.summary())


class LeverOutcome(PlanOutcome):
    """One lever applied alone to the procedure as written."""

    FIRST = ("lever",)
    lever: str = Field(description="the lever, in words")

    @classmethod
    def of(cls, outcome: Outcome) -> LeverOutcome:
        return cls.model_validate({"lever": "; ".join(outcome.plan.changes), **outcome.summary()})


class PlanProposal(_Document):
    """`--target-u`: the shortest plan that reaches the target U, or the smallest U found."""

    OMIT_WHEN_NONE = ("plan", "written")
    target_u_arcsec: float = Field(description="the U (k = 2) asked for, arcsec")
    margin: float = Field(description="the fraction below the target the plan was made for")
    reached: bool = Field(description="whether a plan reaches the target")
    plan: PlanOutcome | None = Field(None, description="the proposed plan (absent when none reaches the target)")
    written: list[str] | None = Field(None, description="the files the proposed plan was written to")
    smallest: PlanOutcome | None = Field(description="the plan with the smallest U found")
    plans_predicted: int = Field(description="how many plans were predicted")
    plans_skipped: list[str] = Field(description="mounts skipped (their error motions alone exceed the target)")


class PlanPrediction(_Document):
    """`rtcal plan --json`: each estimator's predicted 1σ per target, the run's duration, what the
    recommended estimator's uncertainty is made of, and what each lever would do."""

    OMIT_WHEN_NONE = ("proposal",)
    procedure: str = Field(description="the procedure file")
    targets: list[str] = Field(description="target labels (angle and direction)")
    measurement_duration_s: float = Field(description="motions, settling and readings on the simulated clock, s")
    raw_readings: int = Field(description="planned readings")
    recommended: str | None = Field(description="the recommended estimator")
    estimators: dict[str, PredictedEstimator] = Field(description="each estimator's prediction")
    expanded_uncertainty_max_arcsec: float | None = Field(description="U (k = 2) of the recommended estimator at its worst target, arcsec")
    duration_s: float = Field(description="the same as measurement_duration_s, s")
    dominant_sources: list[DominantSource] = Field(description="the recommended estimator's sources, largest share first")
    levers: list[LeverOutcome] = Field(description="each lever alone, predicted the same way (empty with --no-levers)")
    lever_notes: list[str] = Field(description="what the levers leave out, and why")
    proposal: PlanProposal | None = Field(None, description="with --target-u: the proposed plan")

    def to_json(self) -> str:
        """The JSON `rtcal plan --json` prints (json's own formatting, as it always was)."""
        return json.dumps(self.model_dump(), indent=2)


def plan_prediction(path: Path, proc: Procedure, scenario: Any, *, levers: bool = True,
                    max_radius_mm: float | None = None) -> tuple[PlanPrediction, list[Outcome]]:
    """Predict the procedure as written and each lever alone (rtcal/planning/predict.py, levers.py)."""
    from rtcal.planning import levers as lv
    from rtcal.planning.predict import predict

    plan = predict(path, proc, scenario)
    rec = plan["recommended"]
    predicted = plan["estimators"].get(rec) if rec else None
    expanded = [v for v in (predicted["predicted_expanded_arcsec"][1:] if predicted else []) if v is not None]
    shares = lv.shares_of(predicted["budget"], predicted["predicted_sigma_arcsec"]) if predicted else {}
    outcomes = [lv.evaluate(p) for p in lv.levers(lv.base_plan(path, scenario), proc, max_radius_mm)] if levers else []
    document = PlanPrediction.model_validate({
        **plan,
        "expanded_uncertainty_max_arcsec": max(expanded) if expanded else None,
        "duration_s": plan["measurement_duration_s"],
        "dominant_sources": [{"source": k, "share": round(v, 4)} for k, v in sorted(shares.items(), key=lambda kv: -kv[1])],
        "levers": [LeverOutcome.of(o) for o in outcomes],
        "lever_notes": lv.lever_notes(proc),
    })
    return document, outcomes


def plan_proposal(path: Path, proc: Procedure, scenario: Any, target_u_arcsec: float, margin: float,
                  max_radius_mm: float | None, out: Path, scenario_given: bool) -> tuple[PlanProposal, Proposal, list[Path] | None]:
    """`--target-u`: search for the shortest plan reaching the target; write it to ``out`` if found."""
    from rtcal.planning import levers as lv

    base = lv.base_plan(path, scenario)
    proposal = lv.propose(base, proc, target_u_arcsec, max_radius_mm, margin)
    written = None
    if proposal.best is not None:
        written = lv.write_proposal(path, base, proposal.best, out, target_u_arcsec, scenario_given)
    document = PlanProposal(
        target_u_arcsec=target_u_arcsec, margin=margin, reached=proposal.best is not None,
        plan=PlanOutcome.of(proposal.best) if proposal.best else None,
        written=[str(w) for w in written or []] if proposal.best else None,
        smallest=PlanOutcome.of(proposal.smallest) if proposal.smallest else None,
        plans_predicted=len(proposal.tried), plans_skipped=proposal.skipped)
    return document, proposal, written


# --- rtcal uncertainty (uncertainty.json)

class OverallTrials(_Document):
    """Over every target after the first (the reference, 0 ± 0 by definition)."""

    rms_error_arcsec: float = Field(description="RMS error against truth, arcsec")
    rms_reported_sigma_arcsec: float = Field(description="RMS of the reported 1σ, arcsec")
    ratio_min: float | None = Field(description="smallest ratio reported 1σ / error over the targets")
    ratio_max: float | None = Field(description="largest ratio reported 1σ / error over the targets")
    coverage_k2: float = Field(description="share of (trial, target) pairs whose error the reported U (k = 2) covers")


class EstimatorTrials(_Document):
    """One estimator over the trials, per target."""

    trials: int = Field(description="trials that gave this estimator")
    not_converged: int = Field(description="of them, how many did not converge")
    residual_test_failed: float | None = Field(None, description=(
        "share of the trials whose residual test failed (null: none tested); on a bench the budget models, the "
        "test's false-alarm rate (rtcal.solvers.uncertainty.FALSE_ALARM_RATE)"))
    rms_error_arcsec: list[float | None] = Field(description="RMS error against truth per target, arcsec")
    rms_reported_sigma_arcsec: list[float | None] = Field(description="RMS of the reported 1σ per target, arcsec")
    ratio: list[float | None] = Field(description="their ratio per target")
    ratio_sigma: list[float | None] = Field(description="the ratio's 1σ from the number of trials (±1/√(2N))")
    mean_error_arcsec: list[float | None] = Field(description="mean error per target (bias), arcsec")
    overall: OverallTrials


class RecommendedTrials(_Document):
    """What the certificate quotes: each trial's own recommended estimate, over every target after the first."""

    trials: int = Field(description="trials that recommended an estimate")
    estimators: dict[str, int] = Field(description="how many trials recommended each estimator")
    coverage_k2: float = Field(description="share of (trial, target) pairs whose error the recommended U (k = 2) covers")
    ratio: float | None = Field(description="RMS reported 1σ / RMS error over the trials and targets (0.8–1.25: U as stated)")
    mean_error_arcsec: float = Field(description="the bias: the mean error over trials and targets, arcsec")
    largest_mean_error_arcsec: float = Field(description="the target whose mean error over the trials is largest: that mean")
    residual_test_failed: float = Field(description=(
        "share of the trials whose recommended estimate failed its residual test: their certificate says its U is not a "
        "coverage interval, and why (rtcal.methods.estimates.choose_recommended)"))
    coverage_k2_quoted: float | None = Field(description=(
        "the coverage over the trials whose test passed: the U a certificate quotes without that warning (null: none)"))


class UncertaintySummary(_Document):
    """`rtcal uncertainty`: the reported 1σ beside the errors against truth, per estimator and target."""

    trials: int = Field(description="trials run")
    failed_trials: int = Field(description="of them, how many failed")
    targets: list[str] = Field(description="target labels")
    estimators: dict[str, EstimatorTrials] = Field(description="each estimator over the trials")
    recommended: str | None = Field(description="the estimator most trials recommended")
    recommended_estimate: RecommendedTrials | None = Field(None, description=(
        "each trial's recommended estimate, as its certificate quotes it (null: none recommended)"))
    procedure: str = Field(description="the procedure file")
    bench: str = Field(description="the bench scenario file ('ideal': none)")
    seed: int = Field(description="seed of the trials")
    systematics: str = Field(description="how the systematic errors were drawn")

    def to_json(self) -> str:
        return json.dumps(self.model_dump(), indent=2) + "\n"


def systematics_text(drawn: bool, balanced: bool) -> str:
    """How a Monte Carlo drew the systematic errors, in words (uncertainty.json's ``systematics``)."""
    if not drawn:
        return "fixed as in the scenario"
    return "drawn from the stated uncertainties" + (" (balanced: moment-matched antithetic pairs)" if balanced else "")


def uncertainty_summary(trials: list[dict[str, Any]], procedure: Path, proc: Procedure, scenario_file: str | None,
                        seed: int, drawn: bool, balanced: bool) -> UncertaintySummary:
    """The summary of successful ``trials`` (montecarlo.summarize) with what was run."""
    from rtcal.planning import montecarlo

    ok = [t for t in trials if "failed" not in t]
    summary = montecarlo.summarize(trials, ok[0]["labels"])
    bench = scenario_file or (str(procedure.parent / proc.bench) if proc.bench else "ideal")
    return UncertaintySummary.model_validate({**summary, "procedure": str(procedure), "bench": bench, "seed": seed,
                                              "systematics": systematics_text(drawn, balanced)})


def plan_schema() -> str:
    """JSON Schema of `rtcal plan --json`."""
    return json.dumps(PlanPrediction.model_json_schema(), indent=2)


def uncertainty_schema() -> str:
    """JSON Schema of uncertainty.json."""
    return json.dumps(UncertaintySummary.model_json_schema(), indent=2)


def optimize_refusal(path: Path, proc: Procedure) -> str | None:
    """Why `rtcal plan --optimize` cannot choose points for this procedure (None: its method's planner can),
    asked before anything is predicted."""
    from rtcal.methods import METHODS

    planner = METHODS[proc.method].planner
    if planner is None:
        return f"{path} is a procedure of {proc.method}, whose method has no planner: there are no points to choose"
    refusal: str | None = planner.points_refusal(path, proc)
    return refusal


def optimized_points(path: Path, proc: Procedure, scenario: Any, out: Path) -> str:
    """`rtcal plan --optimize OUT`: points chosen by the method's planner (for the multi-station method,
    CMM points: rtcal/methods/multistation/design.py), the procedure with them written to ``out``; what was done, in
    words. ValueError: it cannot be done (the method's planner says why)."""
    from rtcal.methods import METHODS

    planner = METHODS[proc.method].planner
    if planner is None:
        raise ValueError(optimize_refusal(path, proc))
    from rtcal.run.runner import run_procedure

    def simulate(procedure: Path, bench: Path, run_dir: Path) -> None:
        run_procedure(procedure, bench, out_dir=run_dir, show_progress=False, outputs=False, estimate_noise=False)

    return str(planner.choose_points(path, proc, scenario, out, simulate))
