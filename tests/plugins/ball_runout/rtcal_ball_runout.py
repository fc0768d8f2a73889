"""A calibration method as an installed plugin, written against ``rtcal.api`` alone: the radial runout of a
test ball on a rotary table, read by a dial indicator at each target.

The operator mounts a test ball on the table's axis, its centre ``ball.height_mm`` above the table top, and
sets a dial indicator's tip against it (the method's own operator step). The table then visits each target of
an ISO 230-2 style cycle (runs × directions, each target approached past an overrun from its own side); at
each visit the stage moves, settles and is checked, the indicator is read ``samples_per_reading`` times, and
the stage is seen to have stood still. The result per target and direction is the ball's radial displacement
relative to the first target of the first direction, in µm, with its uncertainty: a quantity of its own, not
an angular positioning deviation, so rtcal evaluates no ISO 230-2 parameters and writes no compensation from
it. Every reading carries the ball's height (a context column the method declares), and the analysis refuses
readings taken at two heights. The indicator is an instrument of the procedure named ``probe``, declared by
its kind (``kind: dial_indicator``): simulated on the bench (this module's :class:`BallIndicator`, reading the
ball the simulated operator mounted) or at an address (a Sylvac indicator, e.g. what ``rtcal sim serve``
prints for ``dial_indicator_1``).
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any, Literal

import numpy as np
from matplotlib.figure import Figure
from pydantic import Field, model_validator

from rtcal import api

NAME = "ball_runout"
BALL = "test_ball"  # the artefact the operator mounts (the simulated bench knows it by this name)
INDICATOR = "y_um"  # the dial indicator kind's described field
HEIGHT = "ball_height_mm"  # the method's own context column


# -- the procedure ------------------------------------------------------------------------------------
class Instruments(api.InstrumentsBase):
    stage: api.StageChoice = Field(api.StageChoice(), description="the rotary table's drive")
    probe: api.InstrumentChoice = Field(description=(
        "the dial indicator against the test ball: `{kind: dial_indicator, backend: sim}` or `{kind: dial_indicator, "
        "address: …}`"))

    @model_validator(mode="after")
    def _probe_is_an_indicator(self) -> Instruments:
        if self.probe.kind != "dial_indicator":
            raise ValueError("probe.kind: declare the probe's kind, `kind: dial_indicator` (it reads y_um)")
        return self


class Ball(api.StrictModel):
    height_mm: float = Field(40.0, ge=0.0, le=1000.0, description="the test ball's centre above the table top, mm")


class OnFault(api.StrictModel):
    stage: api.FaultPolicy = Field(api.FaultPolicy(), description="when the stage fails")
    probe: api.FaultPolicy = Field(api.FaultPolicy(), description="when the dial indicator fails")


class Uncertainty(api.StrictModel):
    probe_noise_um: float = Field(0.2, ge=0.0, le=1000.0, description=(
        "1σ of one indicator reading, µm (Type B; with two runs or more the runs' scatter is used instead)"))
    probe_calibration_u_um: float = Field(0.0, ge=0.0, le=1000.0, description=(
        "standard uncertainty of the indicator's indication from its calibration, µm (0: not stated)"))
    probe_digit_um: float = Field(0.1, ge=0.0, le=1000.0, description=(
        "the indicator's digit (its resolution), µm: a reading is within half of it of what it shows"))


class Durations(api.StrictModel):
    mount_ball_s: float = Field(120.0, ge=0.0, le=86_400.0, description="what mounting the ball and the indicator takes, s")


class BallRunout(api.CycleProcedureBase):
    """The radial runout of a test ball on the table, read by a dial indicator at each target."""

    method: Literal["ball_runout"] = Field(description="a test ball's radial runout (plugin)")
    instruments: Instruments = Field(description="the stage and the dial indicator (declared by its kind)")
    ball: Ball = Field(Ball(), description="where the test ball is mounted")
    on_fault: OnFault = Field(OnFault(), description="what to do when an instrument fails")
    verification: api.VerificationBase = Field(api.VerificationBase(), description="what every motion is checked against")
    uncertainty: Uncertainty = Field(Uncertainty(), description="inputs of the uncertainty budget")
    durations: Durations = Field(Durations(), description="what the operator's step takes")


def planned_visits(proc: BallRunout) -> list[api.Visit]:
    """ISO 230-2's linear cycle: each run ↑ through every target, then ↓."""
    return proc.steps.visits()


# -- the plan -----------------------------------------------------------------------------------------
def mount_instruction(height_mm: float, resumed: bool) -> str:
    if resumed:
        return f"The run resumes with the test ball mounted at {height_mm:g} mm. Do not move it or the indicator."
    return (f"Mount the test ball on the table's axis, its centre {height_mm:g} mm above the table top, and set the dial "
            "indicator's tip against it at its equator, square to the axis.")


class BallPlan(api.PlanBase):
    """Mount the ball (an operator step), then at every visit: arrive, read the indicator, stand still."""

    method = NAME

    def __init__(self, proc: BallRunout, done: set[int], generation: int, stage_step_deg: float):
        self.proc = proc
        self.visits = planned_visits(proc)
        self.policies = {"stage": proc.on_fault.stage, "probe": proc.on_fault.probe}
        self.checks = api.MotionChecks(stage_step_deg, proc.verification.stage_tolerance_deg)
        self.resumed = bool(done)
        h = proc.ball.height_mm
        self.entries = [
            api.Entry(k, 0, {"station": v.step, "run": v.run, "direction": v.direction, "commanded_angle_deg": v.angle_deg,
                             "plan_index": k, "segment": generation, HEIGHT: h},
                      {"target_deg": v.angle_deg, "run": v.run + 1, "direction": "↑" if v.direction > 0 else "↓"},
                      f"visit at {v.angle_deg:g}°")
            for k, v in enumerate(self.visits)]

    def enter_group(self, entry: api.Entry, first: bool) -> list[api.Step]:
        h = self.proc.ball.height_mm

        def mount(bench: api.SimBench) -> None:  # what the simulated operator does on a simulated bench
            bench.mount_artefact(BALL, (0.0, 0.0, h))

        return [api.OperatorStep(mount_instruction(h, self.resumed), f"test ball {'confirmed' if self.resumed else 'mounted'} "
                                 f"at {h:g} mm", mount, "mount the test ball", "probe",
                                 0.0 if self.resumed else self.proc.durations.mount_ball_s)]

    def attempt(self, entry: api.Entry) -> api.Attempt:
        proc, v = self.proc, self.visits[entry.index]
        feedback = yield from api.arrive(self.checks, v.angle_deg, v.direction, proc.steps.overshoot_deg, proc.settle_time_s)
        for s in range(proc.samples_per_reading):
            yield api.Read("probe", (INDICATOR,), None, 0.0, f"ball at {v.angle_deg:g}°", sample=s)
        yield from api.stood_still(self.checks, v.angle_deg, feedback)


# -- the simulation of the indicator on the bench ------------------------------------------------------
class BallIndicator(api.DialIndicator):
    """A dial indicator whose tip touches the test ball on the simulated bench: the ball's displacement along the
    indicator (the housing's y) as the table's motion carries it, plus the indicator's noise and digit. With no
    ball mounted there is nothing to read (a fault: the operator step was not done)."""

    name = "probe"

    def __init__(self, bench: api.SimBench, noise_um: float = 0.05, resolution_um: float = 0.01):
        self.bench, self.noise_um, self.resolution_um = bench, noise_um, resolution_um
        self._rng = bench.rng("probe")

    def read_um(self) -> float:
        self.bench.reading()
        ball = self.bench.artefact_mm(BALL)
        if ball is None:
            raise api.InstrumentFault("probe", "nothing touches the tip: the test ball is not mounted")
        y_um = float(ball[1]) * 1000.0 + self.noise_um * float(self._rng.standard_normal())
        return round(y_um / self.resolution_um) * self.resolution_um


# -- the results ------------------------------------------------------------------------------------------
class BallEstimates(api.NamedSet[api.QuantityEstimate]):
    """``estimates`` of the ball-runout method."""

    probe: api.QuantityEstimate | None = Field(None, description="the ball's radial displacement per target and direction, µm")


class BallTruth(api.Truth):
    """What the simulated bench really had (a simulated run only)."""

    displacement_um: list[api.Um] = Field(description="the ball's true radial displacement per target, relative to the first, µm")


class BallAnalysis(api.Analysis):
    recommended: Literal["probe"] | None = Field(description="the estimate to quote")
    estimates: BallEstimates = Field(description="every estimate that could run")
    truth: BallTruth | None = Field(None, description="what the simulated bench really had (absent: on instruments)")
    ball_height_mm: api.Mm = Field(description="the test ball's height the readings were taken at (their context), mm")


class BallResults(BallAnalysis, api.RunResults):
    """results.json of the ball-runout method (a plugin's)."""

    method: Literal["ball_runout"] = Field(description="the calibration method")


def visit_means(store: api.RunReadings, proc: BallRunout) -> tuple[np.ndarray, float]:
    """Per planned visit the mean indicator reading, µm (NaN: none counts), and the ball height every counted
    reading was taken at (their context); readings taken at two heights are a contradiction, never a result."""
    visits = planned_visits(proc)
    total, count = np.zeros(len(visits)), np.zeros(len(visits))
    heights = set()
    for r in store.counted("probe", INDICATOR, whole_only=True):
        if r.plan_index is None:
            continue
        heights.add(float((r.context or {}).get(HEIGHT, float("nan"))))
        total[r.plan_index] += r.value
        count[r.plan_index] += 1
    if len(heights) != 1 or not np.isfinite(next(iter(heights))):
        raise api.DataContradiction(f"the indicator's readings were taken at ball heights {sorted(heights)} mm: one "
                                    "mounting is one result")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan), heights.pop()


def analyse(proc: BallRunout, store: api.RunReadings, bench: api.SimBench | None, estimate_noise: bool) -> BallAnalysis:
    """Per target and direction the mean over the runs of the indicator, relative to the first target of the first
    direction (its zero is arbitrary), with its budget."""
    visits = planned_visits(proc)
    means, height = visit_means(store, proc)
    keys = [(t, d) for d in proc.directions() for t in proc.steps.targets_deg]
    index = {(v.angle_deg, v.direction, v.run): i for i, v in enumerate(visits)}
    runs = proc.steps.runs
    per_key = np.array([[means[index[(t, d, r)]] for r in range(runs)] for t, d in keys])
    u = proc.uncertainty

    def estimate() -> api.QuantityEstimate:
        if np.isnan(per_key).any():
            raise ValueError(f"{int(np.isnan(per_key).sum())} visits have no indicator reading")
        apart = np.r_[0.0, np.full(len(keys) - 1, np.sqrt(2.0))]  # a difference to the first target's mean
        if estimate_noise and runs >= 2:
            sigma = float(np.sqrt(np.mean(np.var(per_key, axis=1, ddof=1))))
            sources = [api.QuantitySource("indicator repeatability", "A", sigma, "µm", apart * sigma / np.sqrt(runs), True,
                                          "pooled 1σ of one visit over the runs")]
        else:
            sigma = u.probe_noise_um / np.sqrt(proc.samples_per_reading)
            sources = [api.QuantitySource("indicator reading noise", "B", sigma, "µm", apart * sigma / np.sqrt(runs), False,
                                          f"the procedure's stated 1σ of one reading ({u.probe_noise_um:g} µm)")]
        if u.probe_digit_um > 0:  # two rounded readings: uniform, d/√12 each; the runs' scatter cannot show it
            digit = u.probe_digit_um / np.sqrt(12.0)
            sources.append(api.QuantitySource("indicator digit", "B", digit, "µm", apart * digit, False,
                                              f"a {u.probe_digit_um:g} µm digit, uniform (d/√12)"))
        omitted = ["the ball's own roundness: not separated from the table's radial motion"]
        if u.probe_calibration_u_um > 0:
            sources.append(api.QuantitySource("indicator calibration", "B", u.probe_calibration_u_um, "µm",
                                              apart * u.probe_calibration_u_um, False, "from the indicator's certificate"))
        else:
            omitted.append("the indicator's calibration (not stated)")
        values = per_key.mean(axis=1) - per_key[0].mean()
        return api.quantity_estimate("radial displacement of the test ball", "µm", [t for t, _ in keys], [d for _, d in keys],
                                     values, sources, omitted, "mean over the runs per target")

    found, status = api.run_estimators({"probe": estimate})
    truth = None
    if bench is not None and "probe" in found:
        at = [bench.true_table_point_mm((0.0, 0.0, height), t, d)[1] * 1000.0 for t, d in keys]
        ez = [bench.true_positioning_error_arcsec(t, d) for t, d in keys]
        truth = BallTruth(displacement_um=[round(x - at[0], 6) for x in at],
                          cumulative_deviation_arcsec=[round(x - ez[0], 6) for x in ez])
    return BallAnalysis(nominal_angles_deg=[float(t) for t in proc.steps.targets_deg],
                        raw_readings=len(store.done_plan_indices()), recommended=api.choose_recommended(found, status),
                        solver_status=status, estimates=BallEstimates(**found), truth=truth, ball_height_mm=height)


# -- the outputs ---------------------------------------------------------------------------------------------
class BallOutputs(api.OutputsBase):
    """A CSV and a figure of the displacement per target, the report's section, the certificate's tables."""

    FIGURE = "ball_runout.png"

    def __init__(self, results: BallResults):
        e = results.estimates.probe
        if e is None:
            raise ValueError("estimates.probe: missing")
        self.results, self.e = results, e

    def rows(self) -> list[tuple[float, int, float | None, float | None, float | None]]:
        e = self.e
        return list(zip(e.target_deg, e.target_direction, e.value, e.standard_uncertainty, e.expanded_uncertainty))

    def write_files(self, run_dir: Path) -> list[Path]:
        path = run_dir / "ball_runout.csv"
        with path.open("w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(["target_deg", "direction", "displacement_um", "u_um", "U_um"])
            w.writerows(self.rows())
        fig = Figure(figsize=(8, 4.6), layout="constrained")
        ax = fig.add_subplot()
        for d, label in ((1, "↑"), (-1, "↓")):
            sel = [r for r in self.rows() if r[1] == d and r[2] is not None]
            if sel:
                ax.errorbar([r[0] for r in sel], [r[2] or 0.0 for r in sel], [r[4] or 0.0 for r in sel], marker="o",
                            capsize=3, label=f"{label} (U, k = 2)")
        ax.set_xlabel("table angle / °")
        ax.set_ylabel("radial displacement of the ball / µm")
        ax.grid(alpha=0.3)
        ax.legend()
        fig.savefig(run_dir / self.FIGURE, dpi=110)
        return [path, run_dir / self.FIGURE]

    def report_body(self) -> list[str]:
        lines = [f"## Test ball at {self.results.ball_height_mm:g} mm", "",
                 "| target / ° | dir | displacement / µm | U (k = 2) / µm |", "|---|---|---|---|"]
        for t, d, x, _, U in self.rows():
            lines.append(f"| {t:g} | {'↑' if d > 0 else '↓'} | {'–' if x is None else x} | {'–' if U is None else U} |")
        return lines + [""]

    def certificate_figures(self) -> list[tuple[str, str]]:
        return [(self.FIGURE, "the test ball's radial displacement per target, with U (k = 2)")]

    def method_text(self) -> list[str]:
        return [f"A test ball was mounted on the table's axis {self.results.ball_height_mm:g} mm above the table top and "
                "a dial indicator set against it; the table was moved to each target from both sides and the indicator "
                "read there. The result is the ball's radial displacement relative to the first target, in µm."]

    def method_name(self) -> str:
        return "radial runout of a test ball, read by a dial indicator at each target"

    def summary(self) -> list[str]:
        values = [abs(x) for x in self.e.value if x is not None]
        return [f"test ball runout: largest |displacement| {max(values, default=0.0):.2f} µm over "
                f"{len(set(self.e.target_deg))} targets (estimate `probe`)"]

    def certificate_tables(self) -> list[dict[str, Any]]:
        e = self.e
        return [{"heading": f"Result: {e.quantity} per target and direction",
                 "note": f"relative to the first target of the first direction, {e.unit}; U = {e.coverage_factor:g}u",
                 "header": ["target / °", "direction", f"displacement / {e.unit}", f"U / {e.unit}"],
                 "rows": [[f"{t:g}", "↑" if d > 0 else "↓", "–" if x is None else f"{x:+.2f}", "–" if U is None else f"{U:.2f}"]
                          for t, d, x, _, U in self.rows()]},
                {"heading": "Uncertainty budget", "note": "largest contribution over the targets, µm",
                 "header": ["source", "type", "input", f"contribution / {e.unit}"],
                 "rows": [[c.source, c.type, f"{c.input_sigma:.3g} {c.unit}",
                           f"{max((x for x in c.contribution if x is not None), default=0.0):.3f}"] for c in e.budget]}]


# -- the method -----------------------------------------------------------------------------------------------
class BallRunoutMethod(api.MethodBase):
    """The ball-runout method: its procedure and results models, its plan, its analysis and its outputs;
    :class:`rtcal.api.MethodBase` says the rest."""

    name = NAME
    procedure_model = BallRunout
    results_model = BallResults
    estimators = ("probe",)
    positioning_deviation = False  # a displacement in µm: no ISO 230-2 evaluation, conformity or compensation
    operator_steps = True  # the ball's mounting
    context_columns = {HEIGHT: "the test ball's centre height above the table top, mm"}

    def plan(self, proc: BallRunout, done: set[int], generation: int = 0, stage_step_deg: float = 0.0) -> BallPlan:
        return BallPlan(proc, done, generation, stage_step_deg)

    def sim_instruments(self, proc: BallRunout, bench: api.SimBench) -> api.Instruments:
        return api.Instruments({"stage": api.simulated_instrument(bench, "stage"), "probe": BallIndicator(bench)})

    def analyse(self, proc: BallRunout, store: api.RunReadings, bench: api.SimBench | None,
                estimate_noise: bool = True) -> BallAnalysis:
        return analyse(proc, store, bench, estimate_noise)

    def instrument_roles(self, results: api.RunResults) -> dict[str, str]:
        return {"stage": "the item's drive (commanded)",
                "probe": "measuring instrument: the test ball's radial displacement (dial indicator)"}

    def outputs(self, results: api.RunResults) -> BallOutputs:
        if not isinstance(results, BallResults):
            raise TypeError(f"ball-runout outputs need its results, not {type(results).__name__}")
        return BallOutputs(results)
