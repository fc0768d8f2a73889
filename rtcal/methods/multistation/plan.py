"""The plan of the laser-tracer multi-station procedure (seed 000).

Point-major (the paper): for each CMM point, the table indexes through every station.
Station-major: for each station, the CMM visits every point. Either way each reading — the
CMM's reported position at each visit, every tracer sample — is committed before the next motion.

Every reading is checked (:mod:`rtcal.engine.checks`, :mod:`rtcal.methods.multistation.checks`): the stage's feedback and the CMM's
reported position against the commands before the tracer is read and unchanged after it, the
lengths against the nominal geometry. A moved tracer (a second mount) is referenced again.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import Any, Iterator

import numpy as np

from rtcal.api import (DESCRIPTIONS, Attempt, Cmm, Contradiction, Entry, EnvironmentSensor, LaserTracer, MotionChecks, Move,
                       OperatorStep, Parallel, Read, ReadSamples, Reference, RotaryStage, Settle, Skipped, Step, Validate, environment_read)
from rtcal.methods.multistation.procedure import LaserTracerMultistation
from rtcal.methods.multistation.checks import TracerCheck, TracerReturnCheck

# what a reading takes, named by each kind's description (drivers/interfaces.py), which also names and unites what is stored
CMM_POSITION = tuple(DESCRIPTIONS["cmm"])  # x, y, z in the description's order


def tracer_instruction(mount: int, where: str, resumed: bool = False) -> str:
    """What the person is asked before the laser tracer's mount ``mount`` (0: the first)."""
    if resumed:
        return f"The run resumes with the laser tracer on mount {mount + 1}. Do not move it."
    return (f"Move the laser tracer to mount {mount + 1} ({where}), at the same height as before, and fix it "
            "(rtcal then re-references the beam).")


@dataclass(frozen=True)
class MultistationInstrumentSet:
    stage: RotaryStage
    cmm: Cmm
    laser_tracer: LaserTracer
    environment: EnvironmentSensor | None = None

    def devices(self) -> dict[str, Any]:
        found = {"stage": self.stage, "cmm": self.cmm, "laser_tracer": self.laser_tracer}
        return found if self.environment is None else {**found, "environment": self.environment}

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


class MultistationPlan:
    """Seed 000's order of work. Both machines move only when the next reading needs them elsewhere;
    ``concurrent`` starts the table and the CMM together where both move."""

    method = "laser_tracer_multistation"
    retake_skipped = True

    def __init__(self, proc: LaserTracerMultistation, stage_step_deg: float = 0.0, concurrent: bool | None = None):
        self.proc = proc
        self.points = proc.points_array()
        self.angles = proc.stations.angles_deg()
        self.direction = 1 if proc.stations.approach == "positive" else -1
        self.concurrent = proc.concurrent_motions if concurrent is None else concurrent
        self.policies = {"stage": proc.on_fault.stage, "cmm": proc.on_fault.cmm, "laser_tracer": proc.on_fault.laser_tracer,
                         "environment": proc.on_fault.environment}
        v = proc.verification
        self.checks = MotionChecks(stage_step_deg, v.stage_tolerance_deg, v.cmm_tolerance_mm)
        guesses = [np.array(proc.solver.first_station_guess_mm)]
        if proc.second_mount is not None:
            guesses.append(np.array(proc.second_mount.first_station_guess_mm))
        self.lengths = TracerCheck(guesses, np.array(proc.solver.axis_point_mm), self.angles, self.points,
                                   v.tracer_tolerance_mm)
        self.entries = [
            Entry(k, mk, {"point": i, "station": j, "plan_index": k, "commanded_angle_deg": float(self.angles[j]),
                          "seating": mk, "commanded_x_mm": float(self.points[i][0]),
                          "commanded_y_mm": float(self.points[i][1]), "commanded_z_mm": float(self.points[i][2])},
                  {"point": i + 1, "station": j + 1, "target_deg": float(self.angles[j]), "mount": mk + 1},
                  f"reading at point {i + 1}, station {j + 1}")
            for k, (mk, i, j) in enumerate(planned_readings(proc))]
        # the tracer measured again where its segment was referenced, before it leaves a mount and at the end (creep, drift)
        u = proc.uncertainty
        radius_mm = max(float(np.linalg.norm(g[:2] - np.array(proc.solver.axis_point_mm)[:2])) for g in guesses)
        self.returns = TracerReturnCheck(u.laser_tracer_noise_um, u.laser_tracer_noise_ppm, u.cmm_point_noise_um,
                                         u.stage_repeatability_arcsec, radius_mm, v.tracer_drift_um)
        self.segment_ref: dict[int, tuple[int, int]] = {}  # tracking segment → (point, station) it was referenced at
        self.at_point: int | None = None
        self.at_station: int | None = None

    def prologue(self) -> Iterator[Step]:
        overshoot = self.proc.stations.overshoot_deg
        yield Validate("cmm", tuple(self.points))
        yield Validate("stage", tuple(x for a in self.angles for x in (a, a - self.direction * overshoot)))

    def enter_group(self, entry: Entry, first: bool) -> Iterator[Step]:
        """The operator moves the tracer to mount ``entry.group`` (or confirms where it is on a resumed run)."""
        mk = entry.group
        resumed = first and entry.index > 0
        second = self.proc.second_mount
        if second is not None and (mk > 0 or resumed):
            where = ("its first mount" if mk == 0 else
                     f"the second mount: centre near {list(second.first_station_guess_mm)} mm at station 1")
            yield OperatorStep(tracer_instruction(mk, where, resumed),
                               f"laser tracer {'confirmed' if resumed else 'moved'} on mount {mk + 1}",
                               lambda bench: bench.mount_tracer(mk), "move the laser tracer", "laser_tracer",
                               seconds=0.0 if resumed else self.proc.durations.move_tracer_s)

    def positions_unknown(self) -> None:
        self.at_point = self.at_station = None

    def leave_group(self, group: int, segment: int | None) -> tuple[dict[str, Any], Attempt] | None:
        """Back to the point and station where the tracer's segment was referenced, its length read again
        (not a planned reading: no plan index); a length away from the first one there is a drift."""
        if segment is None or segment not in self.returns.first:
            return None
        i, j = self.segment_ref[segment]
        angle, point = float(self.angles[j]), self.points[i]
        context = {"point": i, "station": j, "commanded_angle_deg": angle, "seating": group,
                   "commanded_x_mm": float(point[0]), "commanded_y_mm": float(point[1]), "commanded_z_mm": float(point[2])}
        where = f"point {i + 1}, station {j + 1}"

        def steps() -> Attempt:
            self.at_point = self.at_station = None
            yield Move("stage", angle, self.direction, self.proc.stations.overshoot_deg, what=f"move to station {j + 1}")
            yield Move("cmm", point, what=f"move to point {i + 1}")
            self.at_point, self.at_station = i, j
            yield Settle(self.proc.settle_time_s)
            samples = yield ReadSamples("laser_tracer", "length_mm", self.proc.samples_per_reading,
                                        self.expected_length_mm(group, i, j), where, f"length back at {where}",
                                        self.proc.durations.tracer_sample_s, purpose="return")
            self.returns.check(segment, list(samples.values), float(self.lengths.distance_mm[group][i, j]), where)

        return context, steps()

    def expected_length_mm(self, mount: int, point: int, station: int) -> float:
        """What the nominal geometry expects the tracer to count here (the walker's answer)."""
        ref = self.lengths.reference
        if ref is None:
            return 0.0
        k, i, j = ref
        return float(self.lengths.distance_mm[mount][point, station] - self.lengths.distance_mm[k][i, j])

    def attempt(self, entry: Entry) -> Attempt:
        try:
            yield from self._attempt(entry)
        except Skipped as exc:  # where the skipped machine is, is not known: the next attempt moves it again
            if exc.instrument == "stage":
                self.at_station = None
            elif exc.instrument == "cmm":
                self.at_point = None
            raise
        except Contradiction:
            self.at_point = self.at_station = None  # the next attempt moves both again and reads where they are
            raise

    def _attempt(self, entry: Entry) -> Attempt:
        mk, i, j = entry.group, entry.context["point"], entry.context["station"]
        proc, checks = self.proc, self.checks
        angle, point = float(self.angles[j]), self.points[i]
        overshoot = proc.stations.overshoot_deg
        stage_moved, cmm_moved = self.at_station != j, self.at_point != i
        to_station = Move("stage", angle, self.direction, overshoot, what=f"move to station {j + 1}")
        to_point = Move("cmm", point, what=f"move to point {i + 1}")
        if stage_moved and cmm_moved and self.concurrent:
            self.at_station = self.at_point = None
            yield Parallel((to_station, to_point))
            self.at_station, self.at_point = j, i
        else:
            if stage_moved:
                self.at_station = None
                yield to_station
                self.at_station = j
            if cmm_moved:
                self.at_point = None
                yield to_point
                self.at_point = i
        if stage_moved or cmm_moved:
            yield Settle(proc.settle_time_s)
        feedback = yield Read("stage", ("feedback_deg",), partial(checks.stage_at, command_deg=angle), angle,
                              f"position at station {j + 1}")
        purpose = "" if cmm_moved else "check"  # the solvers average one position per visit of the point
        xyz = yield Read("cmm", CMM_POSITION, partial(checks.cmm_at, point_mm=point), point,
                         f"position at point {i + 1}", purpose)
        where = f"point {i + 1}, station {j + 1}"
        durations = proc.durations
        referenced_here = yield Reference("laser_tracer", where, seconds=durations.reference_tracer_s)
        if referenced_here:
            self.lengths.referenced(mk, i, j)
        if proc.instruments.environment is not None:  # the air the lengths are counted in, read just before them
            yield environment_read(f"environment at point {i + 1}, station {j + 1}")
        samples = yield ReadSamples("laser_tracer", "length_mm", proc.samples_per_reading, self.expected_length_mm(mk, i, j),
                                    where, f"length at {where}", durations.tracer_sample_s, durations.reference_tracer_s)
        if samples.reacquired:
            self.lengths.referenced(mk, i, j)
        if (referenced_here or samples.reacquired) and samples.segment is not None:
            self.segment_ref[samples.segment] = (i, j)
        for value in samples.values:
            self.lengths.check(value, mk, i, j)
        # the table and the probe stood still while the tracer counted: read both again
        yield Read("stage", ("feedback_deg",), partial(checks.stage_still, before_deg=feedback), angle,
                   f"position at station {j + 1}", "after")
        yield Read("cmm", CMM_POSITION, partial(checks.cmm_still, before_mm=xyz), point, f"position at point {i + 1}", "after")
        if samples.segment is not None and self.segment_ref.get(samples.segment) == (i, j):  # the segment's first reading
            self.returns.referenced(samples.segment, list(samples.values))                 # at its reference point
