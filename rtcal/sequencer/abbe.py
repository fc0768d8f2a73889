"""Sequencer of the encoder Abbe-error procedure (seed 001).

For each polygon seating (an operator step), each run and each direction: a full turn in
steps; at each step the encoder, both dial indicators and — where a polygon face is in front —
the autocollimator are read, and stored before the next motion.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterator

from drivers.interfaces import Autocollimator, DialIndicator, Encoder, EnvironmentSensor, RotaryStage
from rtcal.clock import Clock
from rtcal.procedure.models import EncoderAbbeError
from rtcal.run.store import REJECTED, Reading, RunStore
from rtcal.run.store import SKIPPED as SKIPPED_QUANTITY
from rtcal.sequencer.checks import Contradiction, EncoderCheck, MotionChecks, abbe_cross_checks, check_abbe_visit, check_face
from rtcal.sequencer.conditions import read_environment
from rtcal.sequencer.faults import SKIPPED, FaultHandler
from rtcal.sequencer.motion import approach
from rtcal.sequencer.operator import Operator


@dataclass(frozen=True)
class AbbeInstrumentSet:
    stage: RotaryStage
    encoder: Encoder
    autocollimator: Autocollimator
    indicators: tuple[DialIndicator, DialIndicator]
    environment: EnvironmentSensor | None = None

    def close(self) -> None:
        for i in (self.stage, self.encoder, self.autocollimator, *self.indicators, self.environment):
            if i is not None:
                i.close()


@dataclass(frozen=True)
class Visit:
    seating: int
    run: int
    direction: int
    step: int
    angle_deg: float
    face_in_front: bool


def planned_visits(proc: EncoderAbbeError) -> list[Visit]:
    """Every visit in measuring order: per seating, the linear cycle (each run ↑ through all targets,
    then ↓) or the pilgrim cycle (each target visited every run from each side before the next)."""
    visits = []
    dirs = [1 if d == "positive" else -1 for d in proc.steps.directions]
    for j, seating in enumerate(proc.polygon.seatings_deg):
        angles = proc.pass_angles_deg(seating)

        def visit(r: int, direction: int, i: int) -> Visit:
            return Visit(j, r, direction, i, float(angles[i]), proc.face_in_front(float(angles[i]), seating))

        if proc.steps.cycle == "pilgrim":
            visits += [visit(r, d, i) for i in range(len(angles)) for r in range(proc.steps.runs) for d in dirs]
            continue
        for r in range(proc.steps.runs):
            for d in dirs:
                order = range(len(angles)) if d > 0 else range(len(angles) - 1, -1, -1)
                visits += [visit(r, d, i) for i in order]
    return visits


def run_abbe(
    proc: EncoderAbbeError,
    inst: AbbeInstrumentSet,
    store: RunStore,
    clock: Clock,
    operator: Operator,
    progress: Callable[[Iterator], Iterator] = lambda it: it,
    generation: int = 0,
) -> int:
    """Execute the visits not yet in the store; returns how many it stored.

    Readings carry the run's ``generation`` (0, +1 per resume) as their segment, for the record.
    A resumed run asks the operator to confirm the polygon's seating when it goes on where it
    stopped (it stays where it was unless someone moved it), and to seat it anew for a seating
    it left earlier (a visit skipped there is retaken). A visit that skipped any reading stays
    pending: a resume takes it again whole; its first readings are kept (those of a visit a safe
    stop interrupted too).

    Every visit is checked (:mod:`rtcal.sequencer.checks`): the stage's feedback against the
    command before the readings and unchanged after them, the encoder's motion against the
    commanded motion, the face in view seen near square. A visit the checks contradict is kept,
    marked rejected, and taken again as the policy of the instrument named says.
    """
    plan = planned_visits(proc)
    for v in plan:
        inst.stage.check_target(v.angle_deg)
        inst.stage.check_target(v.angle_deg - v.direction * proc.steps.overshoot_deg)
    def safe_state() -> None:
        inst.stage.stop()

    policies = {name: getattr(proc.on_fault, name) for name in type(proc.on_fault).model_fields}
    faults = FaultHandler(policies, store, clock, operator, safe_state)
    checks = MotionChecks(inst.stage, proc.verification.stage_tolerance_deg)
    encoder_moves = EncoderCheck(proc.verification.encoder_tolerance_arcsec)
    cross = abbe_cross_checks(proc)  # instruments against each other (issue 26): autocollimator vs encoder, indicators
    done = store.done_plan_indices()
    last_seating = plan[max(done)].seating if done else None  # where the polygon was left
    seating = None
    stored = 0

    def visit_once(v: Visit, state: dict, readings: list[Reading]) -> None:
        """Move, settle, check the feedback, read every instrument, check the readings and that the table stood still."""
        def stage_again() -> None:  # before checking once more: approach and settle anew
            inst.stage.reset_alarm()
            approach(inst.stage, v.angle_deg, v.direction, proc.steps.overshoot_deg)
            clock.sleep(proc.settle_time_s)

        moved = faults.call("stage", lambda: approach(inst.stage, v.angle_deg, v.direction, proc.steps.overshoot_deg),
                            recover=inst.stage.reset_alarm, what=f"move to {v.angle_deg:g}°")
        if moved is SKIPPED:
            readings.append(Reading(clock.now_s(), "stage", SKIPPED_QUANTITY, 0.0, "", **state))
            return
        clock.sleep(proc.settle_time_s)
        feedback = faults.call("stage", lambda: checks.stage_at(inst.stage, v.angle_deg), recover=stage_again,
                               what=f"position at {v.angle_deg:g}°")
        if feedback is SKIPPED:
            readings.append(Reading(clock.now_s(), "stage", SKIPPED_QUANTITY, 0.0, "", **state))
            return
        readings.append(Reading(clock.now_s(), "stage", "feedback_deg", float(feedback), "deg", **state))
        readings.extend(read_environment(inst.environment, faults, clock, state, f"environment at {v.angle_deg:g}°"))
        taken = [("encoder", "angle_deg", "deg", inst.encoder.read_angle_deg)]
        if v.face_in_front:
            taken.append(("autocollimator", "x_arcsec", "arcsec", lambda: inst.autocollimator.read_arcsec()[0]))
        taken += [(f"dial_indicator_{n + 1}", "y_um", "um", ind.read_um) for n, ind in enumerate(inst.indicators)]
        for s in range(proc.samples_per_reading):
            for instrument, quantity, unit, read in taken:
                value = faults.call(instrument, read, what=f"reading at {v.angle_deg:g}°")
                if value is SKIPPED:
                    readings.append(Reading(clock.now_s(), instrument, SKIPPED_QUANTITY, 0.0, "", sample=s, **state))
                else:
                    readings.append(Reading(clock.now_s(), instrument, quantity, float(value), unit, sample=s, **state))
        seen = any(r.quantity == "x_arcsec" and abs(r.value) <= proc.verification.autocollimator_tolerance_arcsec
                   for r in readings)  # issue 26: the table turned, so an encoder that disagrees misreads
        for r in readings:
            if r.quantity == "angle_deg":
                encoder_moves.check(r.value, v.angle_deg, table_seen=seen)
            elif r.quantity == "x_arcsec":
                check_face(r.value, proc.verification.autocollimator_tolerance_arcsec, v.angle_deg)
        check_abbe_visit(*cross, readings, v.angle_deg, v.seating, v.run, v.direction, state["plan_index"])  # issue 26
        after = faults.call("stage", lambda: checks.stage_still(inst.stage, feedback), what=f"position at {v.angle_deg:g}°")
        if after is SKIPPED:
            readings.append(Reading(clock.now_s(), "stage", SKIPPED_QUANTITY, 0.0, "", **state))
            return
        readings.append(Reading(clock.now_s(), "stage", "feedback_after_deg", float(after), "deg", **state))

    for k, v in progress(iter([(k, v) for k, v in enumerate(plan) if k not in done])):
        if v.seating != seating:
            offset = proc.polygon.seatings_deg[v.seating]
            resumed = seating is None and v.seating == last_seating
            store.add_event(clock.now_s(), "operator", f"polygon {'confirmed' if resumed else 'seated'} at {offset:g}° (seating {v.seating + 1})")
            operator.reseat_polygon(offset, proc.polygon.pitch_deg, resumed)
            seating = v.seating
        tries = 0
        while True:
            state = dict(station=v.step, seating=v.seating, run=v.run, direction=v.direction, commanded_angle_deg=v.angle_deg,
                         plan_index=k, segment=generation, attempt=store.new_attempt())
            readings: list[Reading] = []
            try:
                with faults.keeping(readings, state):  # a safe stop keeps what the visit took: a resume takes it again
                    visit_once(v, state, readings)
            except Contradiction as exc:  # kept, marked, never used; the policy of the instrument named decides
                store.add_readings(readings + [Reading(clock.now_s(), exc.instrument, REJECTED, 0.0, "", **state)])
                if faults.rejected(exc, tries, f"visit at {v.angle_deg:g}°") is SKIPPED:
                    break
                tries += 1
                continue
            store.add_readings(readings)
            stored += all(r.quantity != SKIPPED_QUANTITY for r in readings)
            break
    return stored
