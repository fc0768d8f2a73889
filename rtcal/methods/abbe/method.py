"""The encoder Abbe-error method (seed 001): plan, instruments, measurement, analysis.

:class:`AbbeMethod` implements :class:`rtcal.methods.protocol.Method`; its analysis is a typed
:class:`rtcal.results.abr.AbbeAnalysis`. Its files, figures (seed 001's Figures 9–12) and report
sections are the output layer's (:mod:`rtcal.methods.abbe.outputs`).
"""

from __future__ import annotations

import dataclasses
import json
from typing import TYPE_CHECKING, Callable

import numpy as np

from drivers import factory
from rtcal.methods.abbe.dataset import abbe_conditions, abbe_visits
from rtcal.api import (DataContradiction, EnvironmentSummary, Estimate, Operator, PositioningDeviations, PreparationError,
                       RunReadings, RunResults, Scenario, address_of, choose_recommended, deviation_block, finite_or_none,
                       residual_test, run_estimators, with_residual_test)
from rtcal.methods.abbe.procedure import EncoderAbbeError
from rtcal.results import model as rm  # its estimate blocks stay in the shared model (docs/architecture.md)
from rtcal.methods.abbe import results as abr
from rtcal.methods.abbe.plan import AbbeInstrumentSet, AbbePlan, planned_visits
from rtcal.methods.abbe.recalibration import AbbeRecalibration
from rtcal.solvers.abbe import (
    AbbeEstimate,
    AbbeNoise,
    AbbeSetup,
    AbbeVisits,
    analyse_abbe,
    steps_within_directions,
)
from rtcal.solvers.harmonics import HarmonicFit
from rtcal.solvers.periodic import periodic_error
from rtcal.solvers.uncertainty import BudgetComponent, DeviationBudget
from simulators.bench import Bench
from simulators.instruments import (
    SimAutocollimator,
    SimDialIndicator,
    SimEncoder,
    SimEnvironmentSensor,
    SimStage,
)
from simulators.truth import abbe_truth

if TYPE_CHECKING:
    from rtcal.methods.abbe.planner import AbbePlanner
    from rtcal.methods.abbe.outputs import AbbeOutputs

NOTES = (
    "Seed 001's equations (1) and (2) are missing from its text; rtcal uses the model its words give: "
    "tangential grating shift Δt = δy + Zs·εx and encoder error Δt/rE (positive: the encoder reads more).",
    "Indicator, encoder and autocollimator zeros are arbitrary but constant while the polygon stays seated: encoder "
    "errors are given up to one constant per seating (mean over the faces removed, the same for both directions); "
    "εz relative to the first target of the first direction, so that the reversal between directions shows.",
)


ROLES = {"polygon": "reference standard: angle (face errors from its certificate)",
         "autocollimator": "reference standard: angle", "environment": "measuring instrument: conditions",
         "encoder": "the item's encoder (analysed)", "dial_indicator_1": "measuring instrument: shaft motion",
         "dial_indicator_2": "measuring instrument: shaft motion", "stage": "the item's drive (commanded)"}
"""The certificate's role of each instrument and standard (a reference standard's begins with those words)."""


class CertificateUnavailable(PreparationError):
    """``certificate_arcsec: bench`` on a bench that cannot hand one over (hardware)."""


def resolve_certificate(proc: EncoderAbbeError, operator: Operator) -> list[float] | None:
    """The face errors the analysis will use, fixed before the first motion (None: closure)."""
    cert = proc.polygon.certificate_arcsec
    if cert == "none":
        return None
    if cert == "bench":
        hands = operator.hands()  # the simulated bench's (or its simulated operator's); None on hardware
        values = None if hands is None else hands.polygon_certificate_arcsec()
        if values is None:
            raise CertificateUnavailable(
                "polygon.certificate_arcsec: `bench` takes the simulated polygon's certificate from the simulated bench "
                "or its simulated operator, and this run has neither (its operator steps are a person's): give the "
                "`operator` address `rtcal sim serve` printed in --instruments, or list the certificate's "
                f"{proc.polygon.faces} face errors (arcsec), or write `none` (closure)")
        if len(values) != proc.polygon.faces:
            raise CertificateUnavailable(f"the bench's polygon has {len(values)} faces, the procedure {proc.polygon.faces}")
        return [float(v) for v in values]
    return [float(v) for v in cert]


def harmonic_terms(fit: HarmonicFit) -> list[rm.HarmonicTerm]:
    return [rm.HarmonicTerm(order=t.order, amplitude=round(t.amplitude, 4), amplitude_sigma=round(t.amplitude_sigma, 4),
                            phase_deg=round(float(np.degrees(t.phase_rad)), 3),
                            phase_sigma_deg=round(float(np.degrees(t.phase_sigma_rad)), 3),
                            significant=bool(t.significant), threshold=round(t.threshold, 4), aliased=t.aliased,
                            not_separable_from=list(t.not_separable_from) or None)
            for t in fit.terms]


def noise_model(proc: EncoderAbbeError, estimate: bool = True) -> AbbeNoise:
    u = proc.uncertainty
    return AbbeNoise(u.autocollimator_noise_arcsec, u.autocollimator_resolution_arcsec, u.stage_repeatability_arcsec,
                     u.encoder_noise_arcsec, u.encoder_resolution_arcsec, u.indicator_noise_um, u.indicator_resolution_um,
                     proc.polygon.certificate_uncertainty_arcsec, estimate, u.autocollimator_scale_u_ppm,
                     u.autocollimator_calibration_u_arcsec, u.indicator_scale_u_ppm)


def not_included(proc: EncoderAbbeError) -> list[str]:
    u, out = proc.uncertainty, []
    if proc.steps.runs < 2 and proc.polygon.certificate_arcsec != "none":
        if u.autocollimator_noise_arcsec == 0 and u.stage_repeatability_arcsec == 0:
            out.append("autocollimator noise and stage repeatability: not stated (uncertainty section) and one run "
                       "cannot estimate them")
    if proc.polygon.certificate_arcsec != "none" and proc.polygon.certificate_uncertainty_arcsec == 0:
        out.append("polygon certificate: no uncertainty stated (polygon.certificate_uncertainty_arcsec)")
    if u.autocollimator_scale_u_ppm == 0 and u.autocollimator_calibration_u_arcsec == 0:
        out.append("autocollimator calibration (its certificate's scale): not stated (uncertainty.autocollimator_scale_u_ppm)")
    return out


def _round_or_none(value: float | None) -> float | None:
    return None if value is None else round(value, 4)


def abbe_estimate(est: AbbeEstimate, source: str, omitted: list[str]) -> rm.AbbeEstimate:
    """``estimates.abbe``: εz against the reference, and the encoder analysis per step."""
    residual = est.residual_arcsec[np.isfinite(est.residual_arcsec)]
    ref = est.reference
    return rm.AbbeEstimate(
        target_deg=[round(float(a), 6) for a in ref.target_deg],
        target_direction=[int(d) for d in ref.direction],
        **dict(deviation_block(ref.cumulative_arcsec, ref.budget, ref.steps, omitted)),
        random_error_from=ref.random_source,
        converged=True,  # a linear estimate: nothing to iterate
        message=with_residual_test("linear least squares", est.residual_check),
        residual_test=residual_test(est.residual_check),
        angle_deg=[round(float(a), 6) for a in est.angle_deg],
        direction=[int(d) for d in est.direction],
        tilt_x_arcsec=finite_or_none(est.tilt_x_arcsec),
        radial_y_um=finite_or_none(est.radial_y_um),
        predicted_encoder_error_arcsec=finite_or_none(est.predicted_encoder_error_arcsec),
        predicted_encoder_error_sigma_arcsec=finite_or_none(est.predicted_sigma_arcsec),
        measured_encoder_error_arcsec=finite_or_none(est.measured_encoder_error_arcsec),
        measured_encoder_error_sigma_arcsec=finite_or_none(est.measured_sigma_arcsec),
        residual_arcsec=finite_or_none(est.residual_arcsec),
        residual_sigma_arcsec=finite_or_none(est.residual_sigma_arcsec),
        positioning_error_arcsec=finite_or_none(est.positioning_error_arcsec),
        positioning_error_sigma_arcsec=finite_or_none(est.positioning_sigma_arcsec),
        encoder_vs_command_arcsec=finite_or_none(est.encoder_vs_command_arcsec),
        residual_rms_arcsec=round(float(np.sqrt(np.mean(residual**2))), 4) if residual.size else None,
        reversal_arcsec=_round_or_none(est.reversal_arcsec),
        reversal_reference_arcsec=_round_or_none(est.reversal_reference_arcsec),
        repeatability_arcsec=_round_or_none(est.repeatability_arcsec),
        extrapolation_factor=round(est.extrapolation_factor, 6),
        face_errors_used_arcsec=finite_or_none(est.face_error_arcsec),
        polygon_source=source,
        harmonics=rm.HarmonicSeries(**{name: harmonic_terms(fit) for name, fit in est.harmonics.items()}),
        harmonic_warnings=rm.HarmonicWarnings(**{name: fit.warnings for name, fit in est.harmonics.items() if fit.warnings}),
        notes=list(NOTES),
    )


def closure_estimate(est: AbbeEstimate) -> abr.ClosureEstimate:
    """The closure's own table errors, referred to the first target like every estimate (with the
    per-visit random error the analysis used: the closure residuals', or the stated one)."""
    c, angles, dirs = est.closure, est.closure_table_angle_deg, est.closure_table_direction
    if c is None or angles is None or dirs is None:
        raise ValueError("no closure: the polygon's face errors came from its certificate")
    sigma = est.random_sigma_arcsec
    n_t = len(c.table_error)
    ref = 0  # keys are sorted positive direction first, then by angle
    R = np.eye(n_t) - np.outer(np.ones(n_t), np.eye(n_t)[ref])
    cov = sigma**2 * (R @ c.solution_map[:n_t]) @ (R @ c.solution_map[:n_t]).T
    estimated = est.random_sigma_type == "A"
    budget = DeviationBudget([BudgetComponent("closure residuals (autocollimator, repeatability)" if estimated else
                                              "autocollimator and stage, as stated", "A" if estimated else "B", sigma, "″",
                                              cov, estimated, "per reading")])
    dirs = np.asarray(dirs)
    return abr.ClosureEstimate(
        target_deg=[round(float(a), 6) for a in angles],
        target_direction=[int(d) for d in dirs],
        **dict(deviation_block(R @ c.table_error, budget, steps_within_directions(dirs))),
        converged=True,
        message=with_residual_test("linear least squares with closure constraints", est.residual_check),
        residual_test=residual_test(est.residual_check),
        table_angle_deg=[round(float(a), 6) for a in angles],
        direction=[int(d) for d in dirs],
        table_error_arcsec=finite_or_none(c.table_error),
        table_uncertainty_arcsec=finite_or_none(c.table_sigma),
        face_error_arcsec=finite_or_none(c.face_error),
        face_uncertainty_arcsec=finite_or_none(c.face_sigma),
        seating_offset_arcsec=finite_or_none(c.offsets),
        residual_rms_arcsec=round(c.residual_rms, 4),
    )


PERIODIC_REFERENCE = (
    "the stage's shaft encoder at every fine step (encoder − command, one constant per direction); its own slow error "
    "(eccentricity, the Abbe shift of seed 001's model: orders 1–3 per turn) is part of the slow error removed over the "
    "arc, its interpolation error at its line period is not separated from the table's (a period of the encoder's "
    "lines is its own test); the autocollimator reads the polygon face at the start")
PERIODIC_DEFINITION = (
    "rtcal's reading of ISO 230-2:2014 Annex C (\"considerations related to periodic positioning error\", the 2014 "
    "scope; the annex's text was not reached): per direction, the range over one period of the mean positional "
    "deviation x̄_i less the slow error of the arc (a polynomial of degree {degree} per direction fitted jointly with "
    "the period's harmonics); the axis's figure is the larger of the two directions")


def periodic_block(proc: EncoderAbbeError, visits: AbbeVisits) -> rm.PeriodicError:
    """The periodic positioning error of a fine-step run (ISO 230-2:2014 Annex C as rtcal reads it) and
    the harmonics of its period, from the encoder at every step."""
    test = proc.periodic
    assert test is not None
    enc_vs_cmd = ((np.asarray(visits.encoder_deg) - np.asarray(visits.commanded_deg) + 180.0) % 360.0 - 180.0) * 3600.0
    angle = np.round(np.mod(np.asarray(visits.commanded_deg, float), 360.0), 9)
    floor = proc.uncertainty.encoder_resolution_arcsec / np.sqrt(12.0)
    found = periodic_error(angle, np.asarray(visits.direction), enc_vs_cmd, test.period, test.start_deg, test.worm_ratio,
                           float(floor), PERIODIC_TREND_DEGREE)
    up, down = found.per_direction_arcsec.get(1), found.per_direction_arcsec.get(-1)
    worst = max(found.per_direction_arcsec, key=lambda d: found.per_direction_arcsec[d])
    notes = ["The repeatability of the table is in the scatter over the runs, hence in U; with one run U holds the "
             "encoder's digit only." if proc.steps.runs > 1 else "One run: U holds the encoder's digit only, not the "
             "table's repeatability."]
    return rm.PeriodicError(
        definition=PERIODIC_DEFINITION.format(degree=PERIODIC_TREND_DEGREE), reference=PERIODIC_REFERENCE,
        period_deg=round(test.period, 9), worm_ratio=test.worm_ratio, start_deg=test.start_deg, step_deg=test.step_deg,
        targets_per_period=found.targets_per_period, trend_degree=PERIODIC_TREND_DEGREE,
        periodic_error_up_arcsec=None if up is None else round(up, 4),
        periodic_error_down_arcsec=None if down is None else round(down, 4),
        periodic_error_arcsec=round(found.per_direction_arcsec[worst], 4),
        expanded_uncertainty_arcsec=round(2.0 * found.per_direction_u_arcsec[worst], 4),
        expanded_uncertainty_up_arcsec=None if up is None else round(2.0 * found.per_direction_u_arcsec[1], 4),
        expanded_uncertainty_down_arcsec=None if down is None else round(2.0 * found.per_direction_u_arcsec[-1], 4),
        harmonics=[rm.PeriodicTerm(order=t.order, period_deg=round(t.period_deg, 9),
                                   period_worm_revolutions=None if t.period_worm_revolutions is None
                                   else round(t.period_worm_revolutions, 6),
                                   amplitude_arcsec=round(t.amplitude_arcsec, 4),
                                   amplitude_sigma_arcsec=round(t.amplitude_sigma_arcsec, 4),
                                   phase_deg=round(t.phase_deg, 3), significant=t.significant,
                                   threshold_arcsec=round(t.threshold_arcsec, 4)) for t in found.terms],
        target_deg=[round(float(a), 6) for a in found.target_deg], direction=[int(d) for d in found.direction],
        residual_arcsec=[round(float(x), 4) for x in found.residual_arcsec], notes=notes)


PERIODIC_TREND_DEGREE = 2  # the slow error over a few degrees: the turn's orders 1–12 are smooth there


class AbbeMethod:
    """Seed 001's encoder Abbe-error method (:class:`rtcal.methods.protocol.Method`)."""

    name = "encoder_abbe_error"
    procedure_model = EncoderAbbeError
    results_model = abr.AbbeResults
    operator_steps = True  # the polygon's seatings
    context_columns: dict[str, str] = {}  # its plan's entries carry the store's own columns only
    estimators = ("abbe", "closure")
    positioning_deviation = True  # εz: evaluation, conformity and compensation follow
    recalibration = AbbeRecalibration()  # a reference instrument's new calibration, taken into a run (catalog reassess)

    def plan_length(self, proc: EncoderAbbeError) -> int:
        return len(planned_visits(proc))

    def scenario_problem(self, proc: EncoderAbbeError, scenario: Scenario) -> tuple[tuple[str, ...], str] | None:
        """The autocollimator reads the bench's polygon: it must have the procedure's faces."""
        if proc.polygon.faces != scenario.polygon.faces:
            return ("polygon", "faces"), f"the procedure's polygon has {proc.polygon.faces} faces, the bench's {scenario.polygon.faces}"
        return None

    def checks_text(self, proc: EncoderAbbeError) -> list[str]:
        v = proc.verification
        return [f"encoder: its change since the run's first visit within {v.encoder_tolerance_arcsec:g}″ of the commanded change",
                f"autocollimator: the face the commanded angle puts in view read within ±{v.autocollimator_tolerance_arcsec:g}″"]

    def conditions(self, results: RunResults) -> EnvironmentSummary | None:
        return results.environment if isinstance(results, abr.AbbeResults) else None

    def instrument_roles(self, results: RunResults) -> dict[str, str]:
        """Each instrument's role on the certificate (reference standards first, in the order the traceability
        statement cites them); a polygon whose face errors this run separated by closure is an artefact."""
        abbe = results.estimates.abbe if isinstance(results, abr.AbbeResults) else None
        if abbe is not None and abbe.polygon_source == "closure":
            return {**ROLES, "polygon": "artefact: its face errors separated from the table's by closure in this run"}
        return dict(ROLES)

    @property
    def planner(self) -> AbbePlanner:
        from rtcal.methods.abbe.planner import AbbePlanner

        return AbbePlanner()

    def outputs(self, results: RunResults) -> AbbeOutputs:
        from rtcal.methods.abbe.outputs import AbbeOutputs

        if not isinstance(results, abr.AbbeResults):
            raise TypeError(f"encoder Abbe-error outputs need its results, not {type(results).__name__}")
        return AbbeOutputs(results)

    def sim_instruments(self, proc: EncoderAbbeError, bench: Bench) -> AbbeInstrumentSet:
        env = SimEnvironmentSensor(bench) if proc.instruments.environment is not None else None
        return AbbeInstrumentSet(SimStage(bench), SimEncoder(bench), SimAutocollimator(bench),
                                 (SimDialIndicator(bench, 0), SimDialIndicator(bench, 1)), env)

    def transport_instruments(self, proc: EncoderAbbeError) -> AbbeInstrumentSet:
        i = proc.instruments
        return AbbeInstrumentSet(
            factory.open_stage(address_of(i.stage), i.stage.soft_limits_deg, i.stage.timeout_s),
            factory.open_encoder(address_of(i.encoder), i.encoder.timeout_s),
            factory.open_autocollimator(address_of(i.autocollimator), i.autocollimator.timeout_s),
            (factory.open_dial_indicator(address_of(i.dial_indicator_1), "dial_indicator_1", i.dial_indicator_1.timeout_s),
             factory.open_dial_indicator(address_of(i.dial_indicator_2), "dial_indicator_2", i.dial_indicator_2.timeout_s)),
            factory.open_environment(address_of(i.environment), i.environment.timeout_s) if i.environment is not None else None,
        )

    def prepare(self, proc: EncoderAbbeError, operator: Operator) -> dict[str, str]:
        """Before any motion: fix the polygon certificate; the store records it for the analysis."""
        return {"polygon_certificate_arcsec": json.dumps(resolve_certificate(proc, operator))}

    def plan(self, proc: EncoderAbbeError, done: set[int], generation: int = 0, stage_step_deg: float = 0.0) -> AbbePlan:
        return AbbePlan(proc, done, generation, stage_step_deg)

    def analyse(self, proc: EncoderAbbeError, store: RunReadings, bench: Bench | None,
                estimate_noise: bool = True) -> abr.AbbeAnalysis:
        visits = abbe_visits(store, proc.polygon.seatings_deg)
        if proc.uncertainty.autocollimator_scale_error_ppm:  # its certificate's scale error, corrected
            visits = dataclasses.replace(visits, autocollimator_arcsec=visits.autocollimator_arcsec
                                         / (1.0 + proc.uncertainty.autocollimator_scale_error_ppm * 1e-6))
        recorded = json.loads(store.meta().get("polygon_certificate_arcsec", "null"))
        cert = None if recorded is None else np.asarray(recorded, float)
        # a fine-step test spans a few degrees: harmonics per turn mean nothing there (its own are per period)
        setup = AbbeSetup(proc.polygon.faces, proc.geometry.indicator_heights_mm, proc.geometry.grating_offset_mm,
                          proc.geometry.encoder_radius_mm, cert, 0 if proc.periodic is not None else proc.max_harmonic_order,
                          noise_model(proc, estimate_noise))
        omitted = not_included(proc)
        source = "closure" if cert is None else "certificate"
        solved: list[AbbeEstimate] = []

        def abbe() -> Estimate:
            solved.append(analyse_abbe(visits, setup))
            return abbe_estimate(solved[0], source, omitted)

        solvers: dict[str, Callable[[], Estimate]] = {"abbe": abbe}
        if cert is None:
            solvers["closure"] = lambda: closure_estimate(solved[0])
        estimates, status = run_estimators(solvers)
        check = solved[0].scale_check if solved else None
        if check is not None and check.failed:  # no reading is trusted alone: the data refute the geometry
            raise DataContradiction(check.message(proc.geometry.encoder_radius_mm))
        recommended = choose_recommended(estimates, status)
        found = estimates.get("abbe")
        a = found if isinstance(found, rm.AbbeEstimate) else None
        table = truth = None
        if solved:
            ref = solved[0].reference
            table = PositioningDeviations(
                ref.rows_target_deg, ref.rows_direction, ref.rows_run, ref.rows_arcsec, ref.rows_uncertainty_arcsec,
                estimator="abbe", notes=(f"εz from the autocollimator on the polygon ({source}), "
                                         "relative to the first target of the first direction",)).to_model()
        if bench is not None and a is not None:
            truth = abr.AbbeTruth.model_validate(abbe_truth(bench, np.array(a.angle_deg), np.array(a.direction),
                                                           np.array(a.target_deg), np.array(a.target_direction)))
        return abr.AbbeAnalysis(
            nominal_angles_deg=[] if a is None else a.angle_deg,
            raw_readings=len(store.done_plan_indices()),  # visits taken whole (as multistation counts); skipped ones apart
            recommended=recommended,
            solver_status=status,
            estimates=abr.AbbeEstimates(**estimates),
            positioning_deviations=table,
            truth=truth,
            environment=None if (conditions := abbe_conditions(store)) is None else EnvironmentSummary.model_validate(conditions),
            periodic_error=None if proc.periodic is None else periodic_block(proc, visits),
        )

    def draw_systematics(self, proc: EncoderAbbeError, scenario: Scenario, rng: np.random.Generator) -> Scenario:
        """The autocollimator's scale error from its certificate's stated uncertainty, N(0, u); the
        polygon's certificate error is drawn afresh with each trial's seed (the bench's certificate is
        truth plus its stated uncertainty)."""
        u = proc.uncertainty.autocollimator_scale_u_ppm
        if u <= 0:
            return scenario
        return scenario.model_copy(update={"autocollimator": scenario.autocollimator.model_copy(
            update={"scale_error_ppm": float(rng.normal(0.0, u))})})
