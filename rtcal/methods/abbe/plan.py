"""The plan of the encoder Abbe-error procedure (seed 001) and of the ISO 230-2 test.

For each polygon seating (an operator step), each run and each direction: a full turn in
steps; at each step the encoder, both dial indicators and — where a polygon face is in front —
the autocollimator are read, and committed before the next motion.

Every visit is checked (:mod:`rtcal.engine.checks`, :mod:`rtcal.methods.abbe.checks`): the stage's feedback against the
command before the readings and unchanged after them, the encoder's motion against the
commanded motion, the face in view seen near square. A visit that skipped a reading stays
pending (a resume takes it again whole); its readings are kept.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterator

import numpy as np

from rtcal.api import (Attempt, Autocollimator, DialIndicator, Encoder, Entry, EnvironmentSensor, MotionChecks, OperatorStep,
                       Read, Reading, RotaryStage, Skipped, Step, Validate, arrive, combined_sigma, environment_read,
                       stood_still)
from rtcal.methods.abbe.procedure import EncoderAbbeError
from rtcal.methods.abbe.checks import EncoderCheck, abbe_cross_checks, check_abbe_visit, check_face


# what a visit reads: each kind's field, named by its description (drivers/interfaces.py), stored under its name
ENCODER = "angle_deg"
FACE = "x_arcsec"  # about the table axis: the face's angle
INDICATOR = "y_um"


def reseat_instruction(offset_deg: float, face_pitch_deg: float, resumed: bool = False) -> str:
    """What the person is asked before a polygon seating (the console and the live page say the same)."""
    faces = offset_deg / face_pitch_deg
    whole = abs(faces - round(faces)) < 1e-9
    what = (f"{round(faces):d} {'face' if abs(round(faces)) == 1 else 'faces'}" if whole else f"{offset_deg:g}°")
    home = whole and round(faces) == 0  # not "turned by 0 faces": the home seating itself
    seated = "in its home seating" if home else f"seated turned by {what}"
    if resumed:
        return (f"The run resumes with the polygon {seated}. Do not move it; "
                "if it was moved, abort and start the seating again.")
    where = f"{offset_deg:g}° + k·{face_pitch_deg:g}°" if not home else f"k·{face_pitch_deg:g}°"
    return (f"Seat the polygon {'in its home seating' if home else f'turned by {what} from its home seating'} "
            f"(faces in front of the autocollimator at table angles {where}), "
            "and align it to the autocollimator within its range.")


def reseat_step(offset_deg: float, face_pitch_deg: float, resumed: bool, message: str, seconds: float) -> OperatorStep:
    """The polygon's seating as an operator step: a person seats it; the simulated operator turns the bench's."""
    return OperatorStep(reseat_instruction(offset_deg, face_pitch_deg, resumed), message,
                        lambda bench: bench.reseat_polygon(offset_deg), "re-seat the polygon", seconds=seconds)


@dataclass(frozen=True)
class AbbeInstrumentSet:
    stage: RotaryStage
    encoder: Encoder
    autocollimator: Autocollimator
    indicators: tuple[DialIndicator, DialIndicator]
    environment: EnvironmentSensor | None = None

    def devices(self) -> dict[str, Any]:
        found = {"stage": self.stage, "encoder": self.encoder, "autocollimator": self.autocollimator,
                 "dial_indicator_1": self.indicators[0], "dial_indicator_2": self.indicators[1]}
        return found if self.environment is None else {**found, "environment": self.environment}

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


class AbbePlan:
    """Seed 001's order of work. Readings carry the run's ``generation`` (0, +1 per resume) as their
    segment, for the record (docs/store.md: the documented mapping; every method's start is also the
    store's ``starts`` table, by attempt). A resumed run asks the operator to confirm the polygon's
    seating where it goes on (it stays where it was unless someone moved it), and to seat it anew for a
    seating it left earlier."""

    method = "encoder_abbe_error"
    retake_skipped = False  # a skipped visit is taken again by a resume, whole

    def __init__(self, proc: EncoderAbbeError, done: set[int] | frozenset[int] = frozenset(), generation: int = 0,
                 stage_step_deg: float = 0.0):
        self.proc = proc
        self.visits = planned_visits(proc)
        self.policies = {name: getattr(proc.on_fault, name) for name in type(proc.on_fault).model_fields}
        self.checks = MotionChecks(stage_step_deg, proc.verification.stage_tolerance_deg)
        u = proc.uncertainty
        self.encoder_moves = EncoderCheck(proc.verification.encoder_tolerance_arcsec, proc.polygon.pitch_deg, 5.0 * np.sqrt(2.0) * (
            combined_sigma((u.autocollimator_noise_arcsec, u.autocollimator_resolution_arcsec)) or 0.3))
        self.cross = abbe_cross_checks(proc)  # instruments against each other: autocollimator vs encoder, indicators
        self.last_seating = self.visits[max(done)].seating if done else None  # where the polygon was left
        self.entries = [
            Entry(k, v.seating, {"station": v.step, "seating": v.seating, "run": v.run, "direction": v.direction,
                                 "commanded_angle_deg": v.angle_deg, "plan_index": k, "segment": generation},
                  {"target_deg": v.angle_deg, "run": v.run + 1, "direction": "↑" if v.direction > 0 else "↓",
                   "seating": v.seating + 1},
                  f"visit at {v.angle_deg:g}°")
            for k, v in enumerate(self.visits)]

    def prologue(self) -> Iterator[Step]:
        overshoot = self.proc.steps.overshoot_deg
        yield Validate("stage", tuple(x for v in self.visits for x in (v.angle_deg, v.angle_deg - v.direction * overshoot)))

    def enter_group(self, entry: Entry, first: bool) -> Iterator[Step]:
        seating = entry.group
        offset = self.proc.polygon.seatings_deg[seating]
        resumed = first and seating == self.last_seating
        yield reseat_step(offset, self.proc.polygon.pitch_deg, resumed,
                          f"polygon {'confirmed' if resumed else 'seated'} at {offset:g}° (seating {seating + 1})",
                          0.0 if resumed or (first and self.last_seating is None) else self.proc.durations.reseat_polygon_s)

    def positions_unknown(self) -> None:
        """Nothing to forget: every visit approaches its target."""

    def leave_group(self, group: int, segment: int | None) -> "tuple[dict[str, Any], Attempt] | None":
        """Nothing to check before the polygon is seated anew."""
        return None

    def attempt(self, entry: Entry) -> Attempt:
        """Move, settle, check the feedback, read every instrument, check the readings and that the table stood still."""
        proc, v = self.proc, self.visits[entry.index]
        angle = v.angle_deg
        feedback = yield from arrive(self.checks, angle, v.direction, proc.steps.overshoot_deg, proc.settle_time_s)
        if proc.instruments.environment is not None:
            yield environment_read(f"environment at {angle:g}°")
        taken: list[tuple[str, str, float]] = [("encoder", ENCODER, angle)]
        if v.face_in_front:
            taken.append(("autocollimator", FACE, 0.0))
        taken += [(f"dial_indicator_{n + 1}", INDICATOR, 0.0) for n in range(2)]
        values: list[tuple[str, str, float]] = []
        for s in range(proc.samples_per_reading):
            for instrument, name, nominal in taken:
                try:
                    value = yield Read(instrument, (name,), None, nominal, f"reading at {angle:g}°", sample=s)
                except Skipped:
                    continue  # marked in the visit; the other instruments are still read
                values.append((instrument, name, float(value)))
        tolerance = proc.verification.autocollimator_tolerance_arcsec
        faces = [x for _, q, x in values if q == FACE]
        seen = any(abs(x) <= tolerance for x in faces)  # the table turned (or did not turn at all): see EncoderCheck
        face = float(np.mean(faces)) if faces else None
        for _, quantity, value in values:
            if quantity == ENCODER:
                self.encoder_moves.check(value, angle, table_seen=seen, face_arcsec=face)
            elif quantity == FACE:
                check_face(value, tolerance, angle)
        check_abbe_visit(*self.cross, [Reading(0.0, i, q, x, "") for i, q, x in values], angle, v.seating, v.run,
                         v.direction, entry.index)
        yield from stood_still(self.checks, angle, feedback)
