"""The R-test's order of work: the operator mounts the sphere and the nest; the nest is calibrated at the first
pose from seven positions of the linear axes (the start and ±x, ±y, ±z); then the kinematic tests, each pose a
tool-centre-point target (the sphere's nominal centre at A, C), so that a control with its kinematics (LinuxCNC's
xyzac-trt-kins, or the simulated machine's) holds the sphere in the nest by its own model — and what the nest reads
is where that model is wrong. C arrives at each target from the test's side (past it by ``overshoot_deg`` first).
At each position the joints the control chose are read (the model's J_k) and the three sensors."""

from __future__ import annotations

from typing import Any

import numpy as np

from rtcal import api
from rtcal.methods.rtest.procedure import NAME, NEST, RTestTrunnion

JOINTS = ("position_x_mm", "position_y_mm", "position_z_mm", "position_a_deg", "position_c_deg")
SENSOR = "y_um"  # the dial indicator kind's field
CALIBRATION_MOVES = np.array([[0, 0, 0], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
CLEARANCE_MM = 20.0  # above the sphere, where the nest is clear of it
ROTARY_TOLERANCE_DEG = 0.01  # the control must report A and C where they were commanded
# the store's context: which test each reading belongs to (0 the nest calibration)
TESTS = {0: "nest calibration", 1: "first pose", 2: "C turned at A = 0", 3: "A turned at C = 0", 4: "C turned at the tilt",
         5: "first pose again (drift)"}
CONTEXT = {"k_test": "the test: " + ", ".join(f"{k} {v}" for k, v in TESTS.items()),
           "a_deg": "A's commanded angle, deg", "nest_move": "the nest calibration's move (0 the start, 1–6 ±x ±y ±z; "
                                                                   "−1: a kinematic test's pose)"}


def k_test_labels(proc: RTestTrunnion) -> list[int]:
    """The test (TESTS) each pose of ``proc.poses()`` belongs to."""
    t = proc.tests
    per = 2 if t.both_directions else 1
    c, a = len(t.c_angles_deg) * per, len(t.a_angles_deg) * per
    labels = [1] + [2] * c + [3] * a + ([4] * c if t.tilt_deg is not None else []) + [5]
    return labels


def calibration_moves_mm(proc: RTestTrunnion) -> np.ndarray:
    """The nest calibration's positions, each the nest's offset from the start, mm (7, 3)."""
    return CALIBRATION_MOVES * proc.nest.calibration.move_mm


def move_instruction(proc: RTestTrunnion) -> str:
    """The operator's step between the two positions: the sphere moves, the nest stays as calibrated."""
    x, y, z = proc.sphere.second_position_mm or proc.sphere.position_mm
    return (f"The tests at the sphere's first position are done. Move the sphere to its second position, its centre "
            f"at X {x:g}, Y {y:g}, Z {z:g} mm (machine coordinates at A = C = 0), and clamp it. Leave the nest and its "
            f"sensors as they are (their calibration holds). The machine then moves the nest onto the sphere from "
            f"{CLEARANCE_MM:g} mm above.")


def mount_instruction(proc: RTestTrunnion, resumed: bool) -> str:
    s = proc.sphere
    if resumed:
        return "The run resumes with the sphere and the nest as they were. Do not move either."
    cert = f" (certificate {s.certificate.number})" if s.certificate.number else ""
    x, y, z = s.position_mm
    return (f"Set up the sphere{cert} on the table with its centre at X {x:g}, Y {y:g}, Z {z:g} mm (machine coordinates "
            "at A = C = 0), and the nest of three sensors in the spindle; zero the sensors on the nest's master. The "
            f"machine then moves the nest onto the sphere from {CLEARANCE_MM:g} mm above.")


class RTestPlan(api.PlanBase):
    """Mount (an operator step), the nest calibration, then the kinematic tests."""

    method = NAME

    def __init__(self, proc: RTestTrunnion, done: set[int], generation: int):
        self.proc = proc
        self.resumed = bool(done)
        self.reapproach = False
        self.policies = {"machine": proc.on_fault.machine, **{n: proc.on_fault.nest for n in NEST}}
        self.poses = proc.poses()
        self.spheres = proc.pose_spheres()
        labels = k_test_labels(proc) * len(proc.sphere.positions())
        self.moves = calibration_moves_mm(proc)
        entries = []
        for k in range(len(self.moves)):
            entries.append(api.Entry(k, 0, {"plan_index": k, "segment": generation, "run": 0, "direction": 1,
                                            "commanded_angle_deg": 0.0, "k_test": 0, "a_deg": 0.0, "nest_move": k},
                                     {"step": "nest calibration", "move": k}, f"nest calibration, move {k}"))
        for i, ((a, c, d), label) in enumerate(zip(self.poses, labels)):
            k = len(self.moves) + i
            j = self.spheres[i]
            where = {"sphere": j + 1} if len(proc.sphere.positions()) > 1 else {}
            entries.append(api.Entry(k, j, {"plan_index": k, "segment": generation, "run": 0, "direction": d,
                                            "commanded_angle_deg": c, "k_test": label, "a_deg": a, "nest_move": -1},
                                     {"test": TESTS[label], "A": a, "C": c, "direction": "↑" if d > 0 else "↓", **where},
                                     f"A {a:g}°, C {c:g}° {'↑' if d > 0 else '↓'}"
                                     + (f" (sphere position {j + 1})" if where else "")))
        self.entries = entries

    def enter_group(self, entry: api.Entry, first: bool) -> list[api.Step]:
        """Group 0: mount the sphere and the nest; group 1: move the sphere to its second position. On a simulated
        bench with two positions the operator's hands mount the group's sphere set-up (a resume too)."""
        group = entry.group
        self.reapproach = first and self.resumed  # the machine may stand anywhere: onto the sphere from above first
        simulate = None
        if self.proc.sphere.second_position_mm is not None:
            def simulate(hands: Any, index: int = group) -> None:
                hands.mount_sphere(index)
        if first and self.resumed and group > 0:  # the move may or may not have been made before the run stopped
            x, y, z = self.proc.sphere.second_position_mm or self.proc.sphere.position_mm
            return [api.OperatorStep(f"The run resumes at the sphere's second position: its centre at X {x:g}, Y {y:g}, "
                                     f"Z {z:g} mm (move it there if it is not). Do not move the nest.",
                                     "sphere at its second position confirmed", simulate,
                                     "confirm the sphere at its second position", "machine", 0.0)]
        if group == 0 or (first and self.resumed):
            return [api.OperatorStep(mount_instruction(self.proc, self.resumed),
                                     "sphere and nest " + ("confirmed" if self.resumed else "mounted"), simulate,
                                     "mount the sphere and the nest", "machine",
                                     0.0 if self.resumed else self.proc.durations.mount_s)]
        # the nest clear of both positions first (the operator's hands between them)
        top = max(p[2] for p in self.proc.sphere.positions()) - self.proc.sphere.position_mm[2] + CLEARANCE_MM
        return [api.Move("machine", api.MachineTarget({**self._point((0, 0, top)), "a": 0.0, "c": 0.0}, tcp=True),
                         what="the nest clear of the sphere"),
                api.OperatorStep(move_instruction(self.proc), "sphere moved to its second position", simulate,
                                 "move the sphere to its second position", "machine", self.proc.durations.mount_s)]

    def _point(self, offset_mm: Any = (0.0, 0.0, 0.0), sphere: int = 0) -> dict[str, float]:
        x, y, z = (float(v) + float(o) for v, o in zip(self.proc.sphere.positions()[sphere], offset_mm))
        return {"x": x, "y": y, "z": z}

    def _joints_at(self, a_deg: float, c_deg: float) -> Any:
        """Read the joints the control chose (the model's J_k), checking A and C are where commanded."""
        def check(values: tuple[float, ...]) -> tuple[float, ...]:
            a, c = values[3], values[4]
            if not (abs(a - a_deg) <= ROTARY_TOLERANCE_DEG and abs(c - c_deg) <= ROTARY_TOLERANCE_DEG):
                raise api.Contradiction("machine", f"the control reports A {a:.4f}°, C {c:.4f}° where A {a_deg:g}°, "
                                                   f"C {c_deg:g}° was commanded (tolerance {ROTARY_TOLERANCE_DEG:g}°)")
            return values
        return api.Read("machine", JOINTS, check, (0.0, 0.0, 0.0, a_deg, c_deg), f"joints at A {a_deg:g}°, C {c_deg:g}°")

    def attempt(self, entry: api.Entry) -> api.Attempt:
        proc = self.proc
        ctx = entry.context
        a, c, d = float(ctx["a_deg"]), float(ctx["commanded_angle_deg"]), int(ctx["direction"])
        if self.reapproach and ctx["nest_move"] != 0:  # a resumed run: the sphere path starts at the first pose
            self.reapproach = False
            j = 0 if ctx["nest_move"] >= 0 else self.spheres[int(ctx["plan_index"]) - len(self.moves)]
            yield api.Move("machine", api.MachineTarget({**self._point((0, 0, CLEARANCE_MM), j), "a": 0.0, "c": 0.0},
                                                        tcp=True), what="above the sphere")
            yield api.Move("machine", api.MachineTarget({**self._point(sphere=j), "a": 0.0, "c": 0.0}, tcp=True),
                           what="onto the sphere")
        if ctx["nest_move"] >= 0:
            move = self.moves[int(ctx["nest_move"])]
            if ctx["nest_move"] == 0:  # onto the sphere from above, whatever the machine's pose
                yield api.Move("machine", api.MachineTarget({**self._point((0, 0, CLEARANCE_MM)), "a": 0.0, "c": 0.0},
                                                            tcp=True), what="above the sphere")
            # the nest moves by +move: the controlled point too, the sphere stays
            yield api.Move("machine", api.MachineTarget({**self._point(move), "a": 0.0, "c": 0.0}, tcp=True),
                           what=f"nest calibration move {ctx['nest_move']}")
        else:
            j = self.spheres[int(ctx["plan_index"]) - len(self.moves)]
            if j > 0 and int(ctx["plan_index"]) == len(self.moves) + self.spheres.index(j):
                # onto the moved sphere from above (its first pose), as at the first position
                yield api.Move("machine", api.MachineTarget({**self._point((0, 0, CLEARANCE_MM), j), "a": a, "c": c},
                                                            tcp=True), what="above the sphere")
            past = {**self._point(sphere=j), "a": a, "c": c - d * proc.tests.overshoot_deg}
            via = (past,) if proc.tests.overshoot_deg > 0 else ()
            yield api.Move("machine", api.MachineTarget({**self._point(sphere=j), "a": a, "c": c}, via, tcp=True),
                           what=f"A {a:g}°, C {c:g}°")
        yield api.Settle(proc.settle_time_s)
        yield self._joints_at(a, c)
        for name in NEST:
            yield api.Read(name, (SENSOR,), None, 0.0, f"{name} at A {a:g}°, C {c:g}°")
