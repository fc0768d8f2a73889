"""Sequencer of the laser-tracer multi-station procedure (seed 000).

Point-major (the paper): for each CMM point, the table indexes through every station.
Station-major: for each station, the CMM visits every point. Either way each reading — the
CMM's reported position at each visit, every tracer sample — is stored before the next motion.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np

from drivers.errors import InstrumentError, TrackingLost
from drivers.interfaces import Cmm, EnvironmentSensor, LaserTracer, RotaryStage
from rtcal.clock import Clock
from rtcal.procedure.models import LaserTracerMultistation
from rtcal.run.store import REJECTED, Reading, RunStore
from rtcal.run.store import SKIPPED as SKIPPED_QUANTITY
from rtcal.sequencer.checks import Contradiction, MotionChecks, TracerCheck, TracerReturnCheck
from rtcal.sequencer.conditions import read_environment
from rtcal.sequencer.faults import SKIPPED, FaultHandler
from rtcal.sequencer.motion import approach


@dataclass(frozen=True)
class MultistationInstrumentSet:
    stage: RotaryStage
    cmm: Cmm
    laser_tracer: LaserTracer
    environment: EnvironmentSensor | None = None

    def close(self) -> None:
        for i in (self.stage, self.cmm, self.laser_tracer, self.environment):
            if i is not None:
                i.close()




def planned_readings(proc: LaserTracerMultistation) -> list[tuple[int, int, int]]:
    """(mount, point, station) in measuring order; each is one planned tracer reading. With a
    second mount the whole plan is measured again after the tracer is moved."""
    n, m = len(proc.points_array()), proc.stations.count
    if proc.order == "point_major":
        one = [(i, j) for i in range(n) for j in range(m)]
    else:
        one = [(i, j) for j in range(m) for i in range(n)]
    return [(k, i, j) for k in range(proc.mounts) for i, j in one]


def run_multistation(
    proc: LaserTracerMultistation,
    inst: MultistationInstrumentSet,
    store: RunStore,
    clock: Clock,
    progress: Callable[[Iterator], Iterator] = lambda it: it,
    operator=None,
) -> int:
    """Execute the planned readings not yet in the store; returns how many it stored.

    A fresh start and a resume are the same: the first pending reading moves both machines
    (approaching from the procedure's direction) and references the tracer, which starts a new
    tracking segment numbered after every segment already stored. Faults go through the
    procedure's ``on_fault`` policies. A reading skipped because the tracer lost the beam makes
    the next reading re-reference it first; after the pass, the readings this pass skipped are
    tried once more (in the tracer's newest segment), and a resume retakes any still missing.

    Every reading is checked (:mod:`rtcal.sequencer.checks`): the stage's feedback and the CMM's
    reported position against the commands before the tracer is read and unchanged after it, the
    lengths against the nominal geometry. A reading the checks contradict is kept, marked
    rejected, and taken again as the policy of the instrument named says.
    """
    points = proc.points_array()
    angles = proc.stations.angles_deg()
    direction = 1 if proc.stations.approach == "positive" else -1
    plan = planned_readings(proc)
    for p in points:  # refuse the whole plan before moving anything
        inst.cmm.check_target(p)
    for a in angles:
        inst.stage.check_target(a)
        inst.stage.check_target(a - direction * proc.stations.overshoot_deg)

    def safe_state() -> None:
        inst.stage.stop()
        inst.cmm.stop()

    policies = {"stage": proc.on_fault.stage, "cmm": proc.on_fault.cmm, "laser_tracer": proc.on_fault.laser_tracer,
                "environment": proc.on_fault.environment}
    faults = FaultHandler(policies, store, clock, operator, safe_state)
    v = proc.verification
    checks = MotionChecks(inst.stage, v.stage_tolerance_deg, v.cmm_tolerance_mm)
    guesses = [np.array(proc.solver.first_station_guess_mm)]
    if proc.second_mount is not None:
        guesses.append(np.array(proc.second_mount.first_station_guess_mm))
    lengths = TracerCheck(guesses, np.array(proc.solver.axis_point_mm), angles, points, v.tracer_tolerance_mm)
    # issue 26: the tracer measured again where its segment was referenced, at the end of each pass (creep, drift)
    u = proc.uncertainty
    radius_mm = max(float(np.linalg.norm(g[:2] - np.array(proc.solver.axis_point_mm)[:2])) for g in guesses)
    returns = TracerReturnCheck(u.laser_tracer_noise_um, u.laser_tracer_noise_ppm, u.cmm_point_noise_um,
                                u.stage_repeatability_arcsec, radius_mm, v.tracer_drift_um)
    segment_ref: dict[int, tuple[int, int]] = {}  # segment → (point, station) it was referenced at
    taken_in_segment: dict[int, list[dict]] = {}  # segment → states of the readings stored whole in it
    done = store.done_plan_indices()
    next_segment = store.max_segment() + 1
    at_point: int | None = None
    at_station: int | None = None
    segment: int | None = None
    mount: int | None = None

    def reference(i: int, j: int, why: str) -> None:
        nonlocal segment, next_segment
        inst.laser_tracer.reference()
        lengths.referenced(mount or 0, i, j)
        segment, next_segment = next_segment, next_segment + 1
        segment_ref[segment] = (i, j)  # issue 26
        store.add_event(clock.now_s(), why, f"tracking segment {segment} referenced at point {i + 1}, station {j + 1}", "laser_tracer")

    def to_mount(k: int, mk: int) -> None:
        """The operator moves the tracer (or confirms where it is on a resumed run)."""
        nonlocal mount, segment
        if mk == mount:
            return
        resumed = mount is None and k > 0
        where = ("its first mount" if mk == 0 else
                 f"the second mount: centre near {list(proc.second_mount.first_station_guess_mm)} mm at station 1")
        if proc.mounts > 1 and (mk > 0 or resumed):
            store.add_event(clock.now_s(), "operator", f"laser tracer {'confirmed' if resumed else 'moved'} on mount {mk + 1}",
                            "laser_tracer")
            operator.move_tracer(mk, where, resumed)
        mount, segment = mk, None  # a moved tracer is referenced again: a new tracking segment

    def take(k: int, mk: int, i: int, j: int) -> bool:
        """Planned reading k (mount mk, point i, station j); True if it was stored whole. Each attempt
        has its own number; a safe stop during one keeps what it took, marked as skipped by the
        instrument that stopped it, and a reading the checks contradict is kept marked rejected."""
        nonlocal at_point, at_station
        tries = 0
        while True:
            state = dict(point=i, station=j, plan_index=k, commanded_angle_deg=float(angles[j]), seating=mk,
                         attempt=store.new_attempt(),
                         commanded_x_mm=float(points[i][0]), commanded_y_mm=float(points[i][1]), commanded_z_mm=float(points[i][2]))
            readings: list[Reading] = []

            def skip(instrument: str) -> bool:
                """Store what this attempt took and the mark of what it skipped; the reading stays pending."""
                store.add_readings(readings + [Reading(clock.now_s(), instrument, SKIPPED_QUANTITY, 0.0, "", **state)])
                return False

            try:
                with faults.keeping(readings, state):
                    return one_attempt(i, j, state, readings, skip)
            except Contradiction as exc:
                store.add_readings(readings + [Reading(clock.now_s(), exc.instrument, REJECTED, 0.0, "", **state)])
                at_point = at_station = None  # the next attempt moves both again and reads where they are
                if faults.rejected(exc, tries, f"reading at point {i + 1}, station {j + 1}") is SKIPPED:
                    return False
                tries += 1

    def one_attempt(i: int, j: int, state: dict, readings: list[Reading], skip: Callable[[str], bool]) -> bool:
        nonlocal at_point, at_station, segment
        angle, point = float(angles[j]), points[i]
        stage_moved, cmm_moved = at_station != j, at_point != i
        if stage_moved:
            at_station = None
            if faults.call("stage", lambda: approach(inst.stage, angle, direction, proc.stations.overshoot_deg),
                           recover=inst.stage.reset_alarm, what=f"move to station {j + 1}") is SKIPPED:
                return skip("stage")
            at_station = j
        if cmm_moved:
            at_point = None
            if faults.call("cmm", lambda: inst.cmm.move_to(point), recover=inst.cmm.recover,
                           what=f"move to point {i + 1}") is SKIPPED:
                return skip("cmm")
            at_point = i
        if stage_moved or cmm_moved:
            clock.sleep(proc.settle_time_s)

        def stage_again() -> None:  # before checking once more: approach and settle anew
            inst.stage.reset_alarm()
            approach(inst.stage, angle, direction, proc.stations.overshoot_deg)
            clock.sleep(proc.settle_time_s)

        def cmm_again() -> None:
            inst.cmm.recover()  # an I++ server in its error state answers nothing else
            inst.cmm.move_to(point)
            clock.sleep(proc.settle_time_s)

        feedback = faults.call("stage", lambda: checks.stage_at(inst.stage, angle), recover=stage_again,
                               what=f"position at station {j + 1}")
        if feedback is SKIPPED:
            at_station = None
            return skip("stage")
        readings.append(Reading(clock.now_s(), "stage", "feedback_deg", float(feedback), "deg", **state))
        xyz = faults.call("cmm", lambda: checks.cmm_at(inst.cmm, point), recover=cmm_again, what=f"position at point {i + 1}")
        if xyz is SKIPPED:
            at_point = None
            return skip("cmm")
        t = clock.now_s()
        kind = "position" if cmm_moved else "check_position"  # the solvers average one position per visit of the point
        readings += [Reading(t, "cmm", f"{kind}_{axis}_mm", float(value), "mm", **state) for axis, value in zip("xyz", xyz)]
        # the air the lengths are counted in, with every reading
        readings += read_environment(inst.environment, faults, clock, state, f"environment at point {i + 1}, station {j + 1}")
        if segment is None and faults.call("laser_tracer", lambda: reference(i, j, "reference"), what="reference") is SKIPPED:
            return skip("laser_tracer")  # no valid count without a reference
        samples: list[Reading] = []
        reacquired = False

        def reacquire() -> None:
            nonlocal reacquired
            reference(i, j, "reacquire")
            reacquired = True

        while len(samples) < proc.samples_per_reading:
            r = faults.call("laser_tracer", inst.laser_tracer.read_length, reacquire=reacquire,
                            what=f"length at point {i + 1}, station {j + 1}")
            if r is SKIPPED:
                if isinstance(faults.last_error, TrackingLost):
                    segment = None  # the count is lost: the next reading references the tracer first
                return skip("laser_tracer")
            if reacquired:  # a reading never mixes two tracking segments
                samples, reacquired = [], False
            samples.append(Reading(clock.now_s(), "laser_tracer", "length_mm", r.length_mm, "mm", sample=len(samples),
                                   segment=segment, **state))
        readings += samples
        for sample in samples:
            lengths.check(sample.value, mount or 0, i, j)
        # the table and the probe stood still while the tracer counted: read both again
        after = faults.call("stage", lambda: checks.stage_still(inst.stage, feedback), what=f"position at station {j + 1}")
        if after is SKIPPED:
            at_station = None
            return skip("stage")
        readings.append(Reading(clock.now_s(), "stage", "feedback_after_deg", float(after), "deg", **state))
        xyz_after = faults.call("cmm", lambda: checks.cmm_still(inst.cmm, xyz), recover=inst.cmm.recover,
                                what=f"position at point {i + 1}")
        if xyz_after is SKIPPED:
            at_point = None
            return skip("cmm")
        t = clock.now_s()
        readings += [Reading(t, "cmm", f"after_position_{axis}_mm", float(value), "mm", **state) for axis, value in zip("xyz", xyz_after)]
        store.add_readings(readings)
        if segment_ref.get(segment) == (i, j):  # issue 26: the segment's first reading at its reference point
            returns.referenced(segment, [r.value for r in samples])
        taken_in_segment.setdefault(segment, []).append(state)
        return True

    def return_to_reference() -> None:
        """Issue 26: the tracer measured again at its segment's reference point (not a planned reading: no
        plan index). A length away from the first one there beyond the noise marks every reading of the
        segment rejected (kept; a resume takes them again) and stops the run. A fault on the way only
        leaves the check undone (an event says so)."""
        nonlocal at_point, at_station
        if segment is None or segment not in returns.first:
            return
        i, j = segment_ref[segment]
        state = dict(point=i, station=j, commanded_angle_deg=float(angles[j]), seating=mount or 0,
                     commanded_x_mm=float(points[i][0]), commanded_y_mm=float(points[i][1]), commanded_z_mm=float(points[i][2]))
        try:
            at_point = at_station = None
            approach(inst.stage, float(angles[j]), direction, proc.stations.overshoot_deg)
            inst.cmm.move_to(points[i])
            at_point, at_station = i, j
            clock.sleep(proc.settle_time_s)
            values = [inst.laser_tracer.read_length() for _ in range(proc.samples_per_reading)]
        except InstrumentError as exc:
            store.add_event(clock.now_s(), "check", f"return to the reference point not measured: {exc}", "laser_tracer")
            return
        if any(r.segment != values[0].segment for r in values):
            return  # the tracer re-referenced itself: another segment
        store.add_readings([Reading(clock.now_s(), "laser_tracer", "return_length_mm", r.length_mm, "mm", sample=s,
                                    segment=segment, **state) for s, r in enumerate(values)])
        try:
            returns.check(segment, [r.length_mm for r in values], float(lengths.distance_mm[mount or 0][i, j]),
                          f"point {i + 1}, station {j + 1}")
        except Contradiction as exc:
            store.add_readings([Reading(clock.now_s(), "laser_tracer", REJECTED, 0.0, "", **taken)
                                for taken in taken_in_segment.get(segment, [])])
            faults.abort("laser_tracer", exc, "every reading of the segment is marked rejected: a resume takes them again")

    stored = 0
    skipped: list[int] = []

    def retake_skipped() -> None:
        """Once more, now that the fault may have passed (and the tracer is referenced again)."""
        nonlocal stored
        for k in skipped:
            stored += take(k, *plan[k])
        skipped.clear()

    for k, (mk, i, j) in progress(iter([(k, entry) for k, entry in enumerate(plan) if k not in done])):
        if mk != mount and skipped:  # before the tracer leaves the mount they were planned on
            retake_skipped()
        if mount is not None and mk != mount:
            return_to_reference()  # issue 26: before the tracer leaves its mount
        to_mount(k, mk)
        if take(k, mk, i, j):
            stored += 1
        else:
            skipped.append(k)
    retake_skipped()
    return_to_reference()  # issue 26: at the end of the pass
    return stored
