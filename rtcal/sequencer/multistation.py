"""Sequencer of the laser-tracer multi-station procedure (seed 000).

Point-major (the paper): for each CMM point, the table indexes through every station.
Station-major: for each station, the CMM visits every point. Either way each reading — the
CMM's reported position at each visit, every tracer sample — is stored before the next motion.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np

from drivers.interfaces import Cmm, LaserTracer, RotaryStage
from rtcal.clock import Clock
from rtcal.procedure.models import LaserTracerMultistation
from rtcal.sequencer.motion import approach
from rtcal.store import Reading, RunStore


@dataclass(frozen=True)
class MultistationInstrumentSet:
    stage: RotaryStage
    cmm: Cmm
    laser_tracer: LaserTracer

    def close(self) -> None:
        for i in (self.stage, self.cmm, self.laser_tracer):
            i.close()


def planned_readings(proc: LaserTracerMultistation) -> list[tuple[int, int]]:
    """(point, station) pairs in measuring order; each pair is one planned tracer reading."""
    n, m = len(proc.points_array()), proc.stations.count
    if proc.order == "point_major":
        return [(i, j) for i in range(n) for j in range(m)]
    return [(i, j) for j in range(m) for i in range(n)]


def run_multistation(
    proc: LaserTracerMultistation,
    inst: MultistationInstrumentSet,
    store: RunStore,
    clock: Clock,
    progress: Callable[[Iterator], Iterator] = lambda it: it,
) -> int:
    """Execute the planned readings not yet in the store; returns how many it stored.

    A fresh start and a resume are the same: the first pending reading moves both machines
    (approaching from the procedure's direction) and references the tracer, which starts a new
    tracking segment numbered after every segment already stored.
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

    done = store.done_plan_indices()
    at_point: int | None = None
    at_station: int | None = None
    segment: int | None = None
    stored = 0
    for k, (i, j) in progress(iter(list(enumerate(plan)))):
        if k in done:
            continue
        stage_moved = at_station != j
        cmm_moved = at_point != i
        if stage_moved:
            approach(inst.stage, float(angles[j]), direction, proc.stations.overshoot_deg)
            at_station = j
        if cmm_moved:
            inst.cmm.move_to(points[i])
            at_point = i
        if stage_moved or cmm_moved:
            clock.sleep(proc.settle_time_s)
        readings: list[Reading] = []
        state = dict(point=i, station=j, plan_index=k, commanded_angle_deg=float(angles[j]),
                     commanded_x_mm=float(points[i][0]), commanded_y_mm=float(points[i][1]), commanded_z_mm=float(points[i][2]))
        if cmm_moved:
            xyz = inst.cmm.position_mm()
            t = clock.now_s()
            readings += [Reading(t, "cmm", f"position_{axis}_mm", float(v), "mm", **state) for axis, v in zip("xyz", xyz)]
        if segment is None:
            inst.laser_tracer.reference()
            segment = store.max_segment() + 1
            store.add_event(clock.now_s(), "reference", f"tracking segment {segment} referenced at point {i + 1}, station {j + 1}", "laser_tracer")
        for s in range(proc.samples_per_reading):
            r = inst.laser_tracer.read_length()
            readings.append(Reading(clock.now_s(), "laser_tracer", "length_mm", r.length_mm, "mm", sample=s, segment=segment, **state))
        store.add_readings(readings)
        stored += 1
    return stored
