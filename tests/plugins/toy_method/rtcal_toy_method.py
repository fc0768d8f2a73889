"""A third calibration method as an installed plugin (entry point ``rtcal.methods``): the rotary
table's positioning deviation read from its own encoder against the command.

At each target of an ISO 230-2 style cycle (runs × directions, each target approached past an
overrun from its own side) the stage is moved, settled, its feedback checked, and the encoder read
``samples_per_reading`` times; the deviation is encoder − command, relative to the first target of
the first direction (an incremental encoder's zero is arbitrary). No reference standard is used:
what the encoder itself misreads (its Abbe error, graduation, eccentricity) is in the result, and
the certificate says so. Everything here is rtcal's public face, rtcal.api (with rtcal.solvers for the
budget's mathematics): the procedure model bases, the plan's steps and motion checks, the estimate block,
the results bases, the store's readings that count, the outputs' base and the simulated bench.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any, Literal

import numpy as np
from matplotlib.figure import Figure
from pydantic import Field, model_validator

from rtcal import api
from rtcal.solvers.uncertainty import BudgetComponent, DeviationBudget

NAME = "encoder_vs_command"
# the optional inclinometer: an installed instrument kind (tests/plugins/toy_kind), taken by its name
INCLINOMETER = "inclinometer"
TILT_FIELDS = ("tilt_x_arcsec", "tilt_y_arcsec")


# -- the procedure ------------------------------------------------------------------------------------
class Instruments(api.InstrumentsBase):
    stage: api.StageChoice = Field(api.StageChoice(), description="the rotary table's drive")
    encoder: api.InstrumentChoice = Field(api.InstrumentChoice(), description="the counter of the table's own encoder")
    inclinometer: api.InstrumentChoice | None = Field(None, description=(
        "an electronic level on the table (kind `inclinometer`, package rtcal-toy-kind), read once per visit after "
        "the encoder (e.g. {backend: sim})"))

    @model_validator(mode="after")
    def _inclinometer_installed(self) -> "Instruments":
        if self.inclinometer is not None:
            try:
                self.inclinometer.kind_of(INCLINOMETER)
            except ValueError as exc:
                raise ValueError(f"{exc}; install rtcal-toy-kind") from None
        return self


class OnFault(api.StrictModel):
    stage: api.FaultPolicy = Field(api.FaultPolicy(), description="when the stage fails")
    encoder: api.FaultPolicy = Field(api.FaultPolicy(), description="when the encoder counter fails")
    inclinometer: api.FaultPolicy = Field(api.FaultPolicy(), description="when the inclinometer fails")


class Verification(api.VerificationBase):
    encoder_tolerance_arcsec: float = Field(600.0, gt=0.0, le=648_000.0, description=(
        "how far the encoder's change since the start's first reading may be from the commanded change, arcsec"))


class Uncertainty(api.StrictModel):
    encoder_noise_arcsec: float = Field(0.3, ge=0.0, le=3600.0, description=(
        "1σ of one encoder reading, arcsec (Type B; with two runs or more the runs' scatter is used instead)"))
    encoder_calibration_u_arcsec: float = Field(0.0, ge=0.0, le=3600.0, description=(
        "standard uncertainty of the encoder's indication from its calibration, arcsec (0: not stated)"))


class EncoderVsCommand(api.CycleProcedureBase):
    """The table's positioning deviation as its own encoder reads it against the command."""

    method: Literal["encoder_vs_command"] = Field(description="the table's encoder against the command (plugin)")
    instruments: Instruments = Field(Instruments(), description="backend of each instrument")
    on_fault: OnFault = Field(OnFault(), description="what to do when an instrument fails")
    verification: Verification = Field(Verification(), description="what every motion and reading is checked against")
    uncertainty: Uncertainty = Field(Uncertainty(), description="inputs of the uncertainty budget")


def planned_visits(proc: EncoderVsCommand) -> list[api.Visit]:
    """ISO 230-2's linear cycle: each run ↑ through every target, then ↓."""
    return proc.steps.visits()


# -- the plan ------------------------------------------------------------------------------------------
class FollowsCommand:
    """The encoder moves as commanded: its reading minus the command stays within a tolerance of what it was at
    the start's first visit (an incremental counter's zero is arbitrary); a contradiction is the stage's."""

    def __init__(self, tolerance_arcsec: float):
        self.tolerance_arcsec = tolerance_arcsec
        self.offset_deg: float | None = None
        self.first_command_deg = 0.0

    def check(self, encoder_deg: float, command_deg: float) -> None:
        offset = encoder_deg - command_deg
        if self.offset_deg is None:
            self.offset_deg, self.first_command_deg = offset, command_deg
            return
        apart_deg = (offset - self.offset_deg + 180.0) % 360.0 - 180.0
        if not abs(apart_deg) * 3600.0 <= self.tolerance_arcsec:
            commanded = command_deg - self.first_command_deg
            raise api.Contradiction("stage", f"the encoder turned {commanded + apart_deg:.4f}° where {commanded:.4f}° was "
                                             f"commanded since the first visit: {apart_deg * 3600:+.0f}″ apart (tolerance "
                                             f"{self.tolerance_arcsec:g}″, verification.encoder_tolerance_arcsec)")


class EncoderPlan(api.PlanBase):
    """Move, settle, check the feedback, read the encoder, check it moved as commanded and the table stood still."""

    method = NAME

    def __init__(self, proc: EncoderVsCommand, generation: int, stage_step_deg: float):
        self.proc = proc
        self.visits = planned_visits(proc)
        self.policies = {name: getattr(proc.on_fault, name) for name in type(proc.on_fault).model_fields}
        self.checks = api.MotionChecks(stage_step_deg, proc.verification.stage_tolerance_deg)
        self.encoder_moves = FollowsCommand(proc.verification.encoder_tolerance_arcsec)
        self.tilt = proc.instruments.inclinometer is not None
        self.entries = [
            api.Entry(k, 0, {"station": v.step, "run": v.run, "direction": v.direction, "commanded_angle_deg": v.angle_deg,
                             "plan_index": k, "segment": generation},
                      {"target_deg": v.angle_deg, "run": v.run + 1, "direction": "↑" if v.direction > 0 else "↓"},
                      f"visit at {v.angle_deg:g}°")
            for k, v in enumerate(self.visits)]

    def prologue(self) -> list[api.Step]:
        overshoot = self.proc.steps.overshoot_deg
        return [api.Validate("stage", tuple(x for v in self.visits for x in (v.angle_deg, v.angle_deg - v.direction * overshoot)))]

    def attempt(self, entry: api.Entry) -> api.Attempt:
        proc, v = self.proc, self.visits[entry.index]
        angle = v.angle_deg
        feedback = yield from api.arrive(self.checks, angle, v.direction, proc.steps.overshoot_deg, proc.settle_time_s)
        for s in range(proc.samples_per_reading):
            value = yield api.Read("encoder", ("angle_deg",), None, angle, f"reading at {angle:g}°", sample=s)
            self.encoder_moves.check(float(value), angle)
        if self.tilt:
            yield api.Read(INCLINOMETER, TILT_FIELDS, None, (0.0, 0.0), f"tilt at {angle:g}°")
        yield from api.stood_still(self.checks, angle, feedback)


# -- results -----------------------------------------------------------------------------------------
class Estimates(api.NamedSet[api.Estimate]):
    """``estimates`` of the encoder-against-command method."""

    encoder: api.TargetedEstimate | None = Field(None, description="encoder − command per target and direction")


class EncoderAnalysis(api.Analysis):
    recommended: Literal["encoder"] | None = Field(description="the estimate to quote")  # the method's own estimator
    estimates: Estimates = Field(description="every estimate that could run")


class EncoderResults(EncoderAnalysis, api.RunResults):
    """results.json of the encoder-against-command method (a plugin's)."""

    method: Literal["encoder_vs_command"] = Field(description="the calibration method")


def encoder_means(store: api.RunReadings, proc: EncoderVsCommand) -> tuple[np.ndarray, np.ndarray]:
    """Per planned visit: mean of encoder − command (arcsec, wrapped to ±180°) and its sample count; only the
    readings that count (the store's rule), and of those only an attempt stored whole."""
    visits = planned_visits(proc)
    total, count = np.zeros(len(visits)), np.zeros(len(visits))
    for r in store.counted("encoder", "angle_deg", whole_only=True):
        if r.plan_index is None:
            continue
        off = (r.value - visits[r.plan_index].angle_deg + 180.0) % 360.0 - 180.0
        total[r.plan_index] += off * 3600.0
        count[r.plan_index] += 1
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan), count


def visit_sigma(per_key: np.ndarray, proc: EncoderVsCommand, samples: int,
                estimate_noise: bool) -> tuple[float, str, Literal["A", "B"], bool, str]:
    """1σ of one visit's mean reading: Type A from the runs' pooled scatter (two runs or more), else the
    procedure's stated noise; with the budget's source name, type, input σ, whether estimated, note."""
    if estimate_noise and proc.steps.runs >= 2:
        sigma = float(np.sqrt(np.mean(np.var(per_key, axis=1, ddof=1))))
        return sigma, "encoder repeatability", "A", True, "pooled 1σ of one visit over the runs"
    stated = proc.uncertainty.encoder_noise_arcsec
    return (stated / np.sqrt(samples), "encoder reading noise", "B", False,
            f"the procedure's stated 1σ of one reading ({stated:g}″), {samples} samples averaged")


def analyse(proc: EncoderVsCommand, store: api.RunReadings, bench: api.SimBench | None, estimate_noise: bool) -> EncoderAnalysis:
    """Per target and direction the mean over the runs of encoder − command, relative to the first target of
    the first direction, with its budget; the rows of every visit as the positioning-deviation table."""
    visits = planned_visits(proc)
    means, count = encoder_means(store, proc)
    keys = [(t, d) for d in proc.directions() for t in proc.steps.targets_deg]  # first direction first
    runs = proc.steps.runs
    index = {(v.angle_deg, v.direction, v.run): i for i, v in enumerate(visits)}
    per_key = np.array([[means[index[(t, d, r)]] for r in range(runs)] for t, d in keys])
    u_cal = proc.uncertainty.encoder_calibration_u_arcsec
    sigma, source, kind, estimated, note = visit_sigma(per_key, proc, max(int(count.min()), 1), estimate_noise)
    table = None

    def estimate() -> api.TargetedEstimate:
        if np.isnan(per_key).any():
            raise ValueError(f"{int(np.isnan(per_key).sum())} visits have no encoder reading")
        n = len(keys)
        D = np.eye(n) - np.outer(np.ones(n), np.eye(n)[0])  # relative to the first target
        components = [BudgetComponent(source, kind, sigma, "″", D @ (np.eye(n) * sigma**2 / runs) @ D.T, estimated, note)]
        omitted = ["the encoder's own errors (Abbe shift, graduation, eccentricity): no reference standard separates them"]
        if u_cal > 0:
            components.append(BudgetComponent("encoder calibration", "B", u_cal, "″", D @ (np.eye(n) * u_cal**2) @ D.T,
                                              False, "the encoder's indication, from its calibration"))
        else:
            omitted.append("the encoder's calibration (not stated)")
        cumulative = per_key.mean(axis=1) - per_key[0].mean()
        block = api.deviation_block(cumulative, DeviationBudget(components), not_included=omitted)
        return api.TargetedEstimate(**block.model_dump(), converged=True, message="mean over the runs per target",
                                   target_deg=[float(t) for t, _ in keys], target_direction=[d for _, d in keys])

    found, status = api.run_estimators({"encoder": estimate})
    if "encoder" in found:
        ref = per_key[0].mean()
        u_row = np.sqrt(sigma**2 + sigma**2 / runs + 2 * u_cal**2)  # one visit against the reference's mean
        table = api.PositioningDeviations(
            np.array([v.angle_deg for v in visits]), np.array([v.direction for v in visits]),
            np.array([v.run + 1 for v in visits]), np.round(means - ref, 4), np.full(len(visits), round(float(u_row), 4)),
            estimator="encoder", notes=("encoder − command, relative to the first target of the first direction "
                                        "(no reference standard: the encoder's own errors are in the deviations)",)).to_model()
    return EncoderAnalysis(
        nominal_angles_deg=[float(t) for t in proc.steps.targets_deg],
        raw_readings=len(store.done_plan_indices()),
        recommended=api.choose_recommended(found, status),
        solver_status=status,
        estimates=Estimates(**found),
        positioning_deviations=table,
        truth=None if bench is None or "encoder" not in found else api.Truth(cumulative_deviation_arcsec=true_reading(bench, keys)),
    )


def true_reading(bench: api.SimBench, keys: list[tuple[float, int]]) -> list[float]:
    """What a noise-free encoder reads against the command at each target, relative to the first: the
    table's true εz plus the encoder's own systematic error (the simulated bench's truth)."""
    seen = np.array([bench.true_positioning_error_arcsec(t, d) + bench.true_encoder_error_arcsec(t, d) for t, d in keys])
    return [round(float(x), 6) for x in seen - seen[0]]


# -- outputs ------------------------------------------------------------------------------------------
def _values(values: list[float | None]) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in values], float)


class EncoderOutputs(api.OutputsBase):
    """A CSV and one figure of the deviation per target, the report's section and the console's lines."""

    FIGURE = "encoder_deviation.png"

    def __init__(self, results: EncoderResults):
        self.results = results
        e = results.estimates.encoder
        if e is None:
            raise ValueError("estimates.encoder: missing")
        self.e: api.TargetedEstimate = e

    def write_files(self, run_dir: Path) -> list[Path]:
        e, csv_path = self.e, run_dir / "encoder_deviations.csv"
        with csv_path.open("w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(["target_deg", "direction", "deviation_arcsec", "u_arcsec", "U_arcsec"])
            for row in zip(e.target_deg, e.target_direction, e.cumulative_deviation_arcsec, e.cumulative_uncertainty_arcsec,
                           e.cumulative_expanded_uncertainty_arcsec):
                w.writerow(row)
        fig = Figure(figsize=(8, 4.6), layout="constrained")
        ax = fig.add_subplot()
        for d, label in ((1, "↑"), (-1, "↓")):
            sel = [i for i, x in enumerate(e.target_direction) if x == d]
            if sel:
                ax.errorbar(np.array([e.target_deg[i] for i in sel]), _values([e.cumulative_deviation_arcsec[i] for i in sel]),
                            _values([e.cumulative_expanded_uncertainty_arcsec[i] for i in sel]), marker="o", capsize=3,
                            label=f"encoder − command {label} (U, k = 2)")
        ax.set_xlabel("table angle / °")
        ax.set_ylabel("deviation / ″")
        ax.grid(alpha=0.3)
        ax.legend()
        fig.savefig(run_dir / self.FIGURE, dpi=110)
        return [csv_path, run_dir / self.FIGURE]

    def report_body(self) -> list[str]:
        e = self.e
        lines = ["## Encoder against the command", "", "| target / ° | dir | deviation / ″ | U (k = 2) / ″ |", "|---|---|---|---|"]
        for t, d, x, U in zip(e.target_deg, e.target_direction, e.cumulative_deviation_arcsec,
                              e.cumulative_expanded_uncertainty_arcsec):
            lines.append(f"| {t:g} | {'↑' if d > 0 else '↓'} | {x if x is not None else '–'} | {U if U is not None else '–'} |")
        return lines + [""]

    def certificate_figures(self) -> list[tuple[str, str]]:
        return [(self.FIGURE, "the table's deviation as its encoder reads it against the command, with U (k = 2)")]

    def method_text(self) -> list[str]:
        return ["The table was moved to each target from both sides and its own encoder read there; the deviation is the "
                "encoder's reading minus the commanded angle, relative to the first target. No reference standard was "
                "used: the encoder's own errors are part of the result and not in its uncertainty."]

    def method_name(self) -> str:
        return "positioning deviation read from the table's own encoder against the command"

    def summary(self) -> list[str]:
        values = [abs(x) for x in self.e.cumulative_deviation_arcsec if x is not None]
        return [f"encoder − command: largest |deviation| {max(values, default=0.0):.2f}″ over "
                f"{len(self.e.target_deg)} targets (estimate `encoder`)"]


# -- the method --------------------------------------------------------------------------------------
class EncoderVsCommandMethod(api.MethodBase):
    """The encoder-against-command method: its models, plan, analysis and outputs; rtcal.api.MethodBase says the
    rest (its instruments opened by their kinds at their addresses, no planner, nothing to prepare)."""

    name = NAME
    procedure_model = EncoderVsCommand
    results_model = EncoderResults
    estimators = ("encoder",)

    def plan(self, proc: EncoderVsCommand, done: set[int], generation: int = 0, stage_step_deg: float = 0.0) -> EncoderPlan:
        return EncoderPlan(proc, generation, stage_step_deg)

    def sim_instruments(self, proc: EncoderVsCommand, bench: api.SimBench) -> api.Instruments:
        devices = {"stage": api.simulated_instrument(bench, "stage"), "encoder": api.simulated_instrument(bench, "encoder")}
        if proc.instruments.inclinometer is not None:
            from rtcal_toy_kind import SimInclinometer  # the kind's package brings its simulation (extra `inclinometer`)

            devices[INCLINOMETER] = SimInclinometer(bench)
        return api.Instruments(devices)

    def analyse(self, proc: EncoderVsCommand, store: api.RunReadings, bench: api.SimBench | None,
                estimate_noise: bool = True) -> EncoderAnalysis:
        return analyse(proc, store, bench, estimate_noise)

    def checks_text(self, proc: EncoderVsCommand) -> list[str]:
        return [f"encoder: its change since the run's first visit within {proc.verification.encoder_tolerance_arcsec:g}″ "
                "of the commanded change"]

    def instrument_roles(self, results: api.RunResults) -> dict[str, str]:
        return {"stage": "the item's drive (commanded)",
                "encoder": "measuring instrument: the table's own encoder, read against the command (not a reference standard)",
                INCLINOMETER: "monitor: the table's tilt at each visit, recorded, not used in the result"}

    def outputs(self, results: api.RunResults) -> EncoderOutputs:
        if not isinstance(results, EncoderResults):
            raise TypeError(f"encoder-against-command outputs need its results, not {type(results).__name__}")
        return EncoderOutputs(results)
