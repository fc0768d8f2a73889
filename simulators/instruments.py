"""In-process simulated instruments: the driver interfaces, read off the bench.

Physics comes from :class:`simulators.bench.Bench`; an instrument adds only its own reading
noise and resolution. Motions advance the bench's (virtual) clock by their duration.

With ``inject=True`` (in-process runs) each request first draws from the bench's fault
injector and raises the typed error a real driver would raise; the protocol simulators build
them with ``inject=False`` and inject on the wire instead.
"""

from __future__ import annotations

import math

import numpy as np

from drivers.interfaces import (
    Autocollimator,
    Cmm,
    DialIndicator,
    Encoder,
    EnvironmentReading,
    EnvironmentSensor,
    LaserTracer,
    LengthReading,
    MachineTarget,
    MachineTool,
    RotaryStage,
    STOP_WATCH_S,
    StopSeen,
)
from drivers.errors import InstrumentError, InstrumentFault, InstrumentTimeout, OutOfLimits, TrackingLost
from rtcal.solvers.air import standard_air_n
from rtcal.solvers.rtest import TrunnionGeometry, joint_targets, nominal_machine_to_table
from rtcal.units import rad_to_arcsec, um_to_mm
from simulators.bench import Bench
from simulators.faults import ALARM_CODES
from simulators.machine_tool import machine_of
from simulators.scenario import STATE_KINDS, FaultSpec


def _quantise(value: float, step: float) -> float:
    return value if step <= 0 else round(value / step) * step


def communication_fault(name: str, kind: str) -> InstrumentError:
    """The typed error a driver raises for a fault on the wire."""
    return {
        "no_reply": InstrumentTimeout(name, "no reply (injected)"),
        "truncated": InstrumentTimeout(name, "truncated reply (injected)"),
        "crc_error": InstrumentTimeout(name, "no valid reply: CRC error (injected)"),
        "garbled": InstrumentFault(name, "unexpected reply (injected garbage)"),
        "modbus_exception": InstrumentFault(name, "Modbus exception 4 (server device failure, injected)"),
    }[kind]


class _Injecting:
    """Draws one fault per request when ``inject`` is set."""

    bench: Bench
    inject: bool = True
    name: str
    state_fault: FaultSpec | None = None  # a fault inside the instrument that stays (stale, frozen, creep, inch)
    _last_reply: float | None = None  # what the instrument answered last
    _buffer: float | None = None  # a stale instrument's reading of the previous request

    def _fault(self) -> FaultSpec | None:
        return self.bench.faults.draw(self.name) if self.inject else None

    def afflict(self, fault: FaultSpec) -> None:
        """From now on the instrument suffers ``fault`` (one of the scenario's STATE_KINDS); the
        protocol simulators call it when their injector draws one."""
        if self.state_fault is None:
            self.state_fault = fault

    def _request(self) -> None:
        """One request: raise a fault on the wire as a driver would, or take on a lasting fault."""
        fault = self._fault()
        if fault is not None and fault.kind in STATE_KINDS:
            self.afflict(fault)
        elif fault is not None:
            raise communication_fault(self.name, fault.kind)

    def _reply(self, fresh: float) -> float:
        """What the instrument answers for a fresh reading: stale, the previous request's reading;
        frozen, the last answer again."""
        kind = self.state_fault.kind if self.state_fault is not None else None
        reply = fresh
        if kind == "stale":
            reply = self._buffer if self._buffer is not None else fresh
        elif kind == "frozen" and self._last_reply is not None:
            reply = self._last_reply
        self._buffer, self._last_reply = fresh, reply
        return reply


class SimStage(_Injecting, RotaryStage):
    name = "stage"

    def __init__(self, bench: Bench, inject: bool = True):
        self.bench = bench
        self.inject = inject
        self.limits_deg = bench.scenario.stage.soft_limits_deg
        self.step_deg = math.degrees(bench.step_rad)
        self.alarm: str | None = None
        self.stuck_at_deg: float | None = None  # a stuck drive's feedback: the command it echoes

    def home(self) -> None:
        self.move_to(0.0)

    def reset_alarm(self) -> None:
        self.alarm = None

    def move_to(self, angle_deg: float) -> None:
        self.check_target(angle_deg)
        fault = self._fault()
        if fault is not None and fault.kind == "alarm":
            self.alarm = f"drive alarm 0x{ALARM_CODES[fault.alarm]:02X} ({fault.alarm.replace('_', ' ')}, injected)"
        if fault is not None and fault.kind == "emergency_stop":
            self.bench.emergency_stop = True
        if self.bench.emergency_stop:
            raise InstrumentFault(self.name, "emergency stop: release it on the machine")
        if self.alarm:
            raise InstrumentFault(self.name, self.alarm)
        if fault is not None and fault.kind == "modbus_exception":
            raise communication_fault(self.name, fault.kind)
        self.stuck_at_deg = None
        if fault is not None and fault.kind == "stuck":
            self.stuck_at_deg = angle_deg  # "in position", and the table has not turned
            return
        if fault is not None and fault.kind == "short":
            here = math.degrees(self.bench.target_rad)
            way = 1 if angle_deg > here else -1 if angle_deg < here else self.bench.last_direction
            self._move(angle_deg - way * min(fault.shortfall_deg, abs(angle_deg - here)), way)
            return
        self._move(angle_deg)
        if fault is not None and fault.kind in ("no_reply", "crc_error"):
            raise communication_fault(self.name, fault.kind)  # the drive moved; its reply was lost

    def _move(self, angle_deg: float, direction: int | None = None) -> None:
        target = math.radians(angle_deg)
        delta = target - self.bench.target_rad  # from the last command, as the controller sees it (not the compensated motor)
        if direction is None:
            direction = self.bench.last_direction if delta == 0 else (1 if delta > 0 else -1)
        self.bench.clock.sleep(abs(math.degrees(delta)) / self.bench.scenario.stage.speed_deg_per_s)
        self.bench.move_stage(target, direction)

    def position_deg(self) -> float:
        return self.stuck_at_deg if self.stuck_at_deg is not None else math.degrees(self.bench.target_rad)

    def feedback_deg(self) -> float:
        """Where the drive's position feedback says the table is (a stuck drive echoes the command)."""
        fault = self.bench.faults.draw(self.name, position_read=True) if self.inject else None
        if fault is not None and fault.kind == "moved":  # another client turns the table
            self._move(math.degrees(self.bench.target_rad) + fault.offset_deg)
        return self.position_deg()

    def stop(self) -> None:
        pass

    def wait_stopped(self, timeout_s: float = STOP_WATCH_S) -> StopSeen:
        """A simulated motion is whole or not begun (the table moves when its time has passed), so
        nothing moves after a stop: seen at rest where it is, without spending the run's clock."""
        return StopSeen(True, f"{self.position_deg():.6f}°")


class SimCmm(_Injecting, Cmm):
    name = "cmm"

    def __init__(self, bench: Bench, inject: bool = True):
        self.bench = bench
        self.inject = inject
        sc = bench.scenario.cmm
        self.volume_min_mm, self.volume_max_mm = sc.volume_min_mm, sc.volume_max_mm
        self._rng = bench.rng("cmm")
        self._reading_error_mm = np.zeros(3)

    def home(self) -> None:
        self.bench.move_probe(np.zeros(3))

    def move_to(self, xyz_mm: np.ndarray) -> None:
        self.check_target(xyz_mm)
        self._request()
        distance = float(np.linalg.norm(np.asarray(xyz_mm) - self.bench.probe_target_mm))
        self.bench.clock.sleep(distance / self.bench.scenario.cmm.speed_mm_per_s)
        self.bench.move_probe(xyz_mm)
        self._reading_error_mm = um_to_mm(self.bench.scenario.cmm.point_noise_um) * self._rng.standard_normal(3)

    def position_mm(self) -> np.ndarray:
        """The CMM's scales: the target plus this move's point error (fixed while at rest)."""
        fault = self.bench.faults.draw(self.name, position_read=True) if self.inject else None
        if fault is not None and fault.kind == "moved":  # another client moves the probe
            self.bench.move_probe(self.bench.probe_target_mm + np.asarray(fault.offset_mm, float))
        self.bench.reading()
        return self.bench.probe_target_mm + self._reading_error_mm

    def stop(self) -> None:
        pass

    def wait_stopped(self, timeout_s: float = STOP_WATCH_S) -> StopSeen:
        """As the stage's: a simulated motion is whole or not begun; the probe is where the bench has it."""
        return StopSeen(True, "(" + ", ".join(f"{v:.4f}" for v in self.bench.probe_target_mm) + ") mm")


class SimLaserTracer(_Injecting, LaserTracer):
    """Counts optical path in the air of the moment: relative length = (n·L − n_ref·L_ref)/n_std,
    with n the bench's air index (n_std: standard air, which the tracer assumes), plus noise
    a + b·L. In standard, steady air this is L − L_ref."""

    name = "laser_tracer"

    def __init__(self, bench: Bench, inject: bool = True):
        self.bench = bench
        self.inject = inject
        self._rng = bench.rng("laser_tracer")
        self._reference_mm: float | None = None  # optical path at the reference, in standard-air mm
        self._segment = -1
        self._n_std = standard_air_n()
        self._creep_readings = 0

    def _optical_mm(self) -> float:
        """The optical path counted, standard-air mm; the reference sphere's form where the beam touches it shortens
        the distance from the sphere's surface, which the tracer reports (a bump toward the beam: shorter)."""
        return (self.bench.tracer_length_mm() - self.bench.sphere_deviation_mm()) * self.bench.air_index() / self._n_std

    def reference(self) -> int:
        self._take_reference()
        return self._segment

    def _take_reference(self) -> float:
        self.bench.beam_broken = False  # re-acquired: the beam reaches the reflector again
        self._reference_mm = reference_mm = self._optical_mm()
        self._segment += 1
        return reference_mm

    def read_length(self) -> LengthReading:
        fault = self._fault()
        if fault is not None and fault.kind == "beam_break":
            self.bench.beam_broken = True
        elif fault is not None and fault.kind in STATE_KINDS:
            self.afflict(fault)
        elif fault is not None:
            raise communication_fault(self.name, fault.kind)
        if self.bench.beam_broken:
            raise TrackingLost(self.name, "tracking lost: re-reference the tracer")
        self.bench.reading()
        reference_mm = self._take_reference() if self._reference_mm is None else self._reference_mm
        length = self.bench.tracer_length_mm()
        lt = self.bench.scenario.laser_tracer
        sigma_mm = um_to_mm(lt.length_noise_um + lt.length_noise_ppm * length * 1e-3)
        creep_mm = 0.0
        if self.state_fault is not None and self.state_fault.kind == "creep":  # every reading adds to the count
            self._creep_readings += 1
            creep_mm = um_to_mm(self.state_fault.creep_um_per_reading) * self._creep_readings
        return LengthReading(self._optical_mm() - reference_mm + creep_mm + sigma_mm * self._rng.standard_normal(),
                             self._segment)


class SimEncoder(_Injecting, Encoder):
    """The encoder below the tilt centre: reads the Abbe-shifted grating (seed 001)."""

    name = "encoder"

    def __init__(self, bench: Bench, inject: bool = True):
        self.bench = bench
        self.inject = inject
        self._rng = bench.rng("encoder")

    def read_angle_deg(self) -> float:
        self._request()
        self.bench.reading()
        enc = self.bench.scenario.encoder
        value = rad_to_arcsec(self.bench.encoder_true_rad()) + enc.noise_arcsec * self._rng.standard_normal()
        return self._reply(_quantise(value, enc.resolution_arcsec) / 3600.0)


class SimAutocollimator(_Injecting, Autocollimator):
    """Reads the polygon face in front of it: x about the table axis, arcsec."""

    name = "autocollimator"

    def __init__(self, bench: Bench, inject: bool = True):
        self.bench = bench
        self.inject = inject
        self._rng = bench.rng("autocollimator")

    def read_arcsec(self) -> tuple[float, float]:
        self._request()
        ac = self.bench.scenario.autocollimator
        x_rad, _ = self.bench.autocollimator_true()
        self.bench.reading()
        x = rad_to_arcsec(x_rad) * (1.0 + ac.scale_error_ppm * 1e-6) + ac.noise_arcsec * self._rng.standard_normal()
        if abs(x) > ac.range_arcsec:
            raise InstrumentFault(self.name, f"no polygon face within ±{ac.range_arcsec:g}″ (deflection {x:.0f}″)")
        return float(self._reply(_quantise(x, ac.resolution_arcsec))), 0.0


class SimDialIndicator(_Injecting, DialIndicator):
    """Y displacement of the shaft at a height below the tilt centre, µm.

    Set to inches (fault ``inch``), it displays inches to 0.00005 in; over the wire the Sylvac
    reply says ``in`` (:meth:`display`); in process it stands for a reply without a unit that a
    driver reads as mm, so :meth:`read_um` returns the inch number as if it were mm (25.4× small)."""

    INCH_DIGIT = 0.00005

    def __init__(self, bench: Bench, index: int, inject: bool = True):
        self.bench = bench
        self.inject = inject
        self.index = index
        self.name = f"dial_indicator_{index + 1}"
        self._rng = bench.rng(self.name)
        self._creep_readings = 0

    def display(self) -> tuple[float, str]:
        """The display: (value, "mm") or, set to inches, (value, "in"); a creeping indicator (fault
        ``creep``) adds ``creep_um_per_reading`` more at each display than at the one before."""
        di = self.bench.scenario.dial_indicators
        creep_um = 0.0
        if self.state_fault is not None and self.state_fault.kind == "creep":
            self._creep_readings += 1
            creep_um = self.state_fault.creep_um_per_reading * self._creep_readings
        y_um = self.bench.shaft_y_mm(di.heights_mm[self.index]) * 1e3 + creep_um + di.noise_um * self._rng.standard_normal()
        if self.state_fault is not None and self.state_fault.kind == "inch":
            return _quantise(y_um / 25400.0, self.INCH_DIGIT), "in"
        return _quantise(y_um, di.resolution_um) / 1000.0, "mm"

    def read_um(self) -> float:
        self._request()
        self.bench.reading()
        return self.display()[0] * 1000.0  # in process: the number as mm, whatever the display's unit


class SimEnvironmentSensor(_Injecting, EnvironmentSensor):
    """The bench's air and material conditions now, with the sensor's noise; ``mount_probe``: a second material
    probe on the tracer's mount reads the temperature of the region that carries the tracer (its own noise)."""

    name = "environment"

    def __init__(self, bench: Bench, inject: bool = True, mount_probe: bool = False):
        self.bench = bench
        self.inject = inject
        self.mount_probe = mount_probe
        self._rng = bench.rng("environment")

    def read(self) -> EnvironmentReading:
        self._request()
        self.bench.reading()
        e = self.bench.scenario.environment
        t, p, rh, tm = self.bench.environment()
        z = self._rng.standard_normal(4)
        # the mount's noise drawn after the others' (and only with the probe): a bench without it draws as before
        mount = self.bench.mount_temperature_c() + e.temperature_noise_k * float(self._rng.standard_normal()) \
            if self.mount_probe else float("nan")
        return EnvironmentReading(t + e.temperature_noise_k * z[0], p + e.pressure_noise_pa * z[1],
                                  rh + e.humidity_noise_pct * z[2], tm + e.temperature_noise_k * z[3], mount)


class SimMachineTool(_Injecting, MachineTool):
    """The five-axis machine of the scenario's ``machine:`` (simulators/machine_tool.py): coordinated
    moves through their waypoints, each segment sampled finely (0.25°, 0.5 mm) and checked for the
    sphere striking the nest; a move takes the time its longest axis needs at the scenario's speeds.
    Joint targets are interpolated in joint space; tool-centre-point targets (``MachineTarget.tcp``)
    through the control's model, the scenario's nominal ``kinematics`` with the nest's stated offset as
    its tool (joints = T(a, c)·p − offset at every sample), as a control's TCP function does. The control
    reports the commanded joints (its scales; the geometry it does not know is the truth)."""

    name = "machine_tool"
    STEP_DEG, STEP_MM = 0.25, 0.5
    tcp = True

    def __init__(self, bench: Bench, inject: bool = True):
        self.bench = bench
        self.inject = inject
        self.machine = machine_of(bench)
        spec = self.machine.spec
        lo, hi = spec.limits_mm
        self.limits = {"x": (lo[0], hi[0]), "y": (lo[1], hi[1]), "z": (lo[2], hi[2]), "a": spec.a_limits_deg,
                       "c": spec.c_limits_deg}
        self.geometry = TrunnionGeometry(spec.kinematics.c_point_mm, spec.kinematics.a_point_mm)
        self.tool_mm = np.array(spec.nest.offset_mm, float)
        self._rng = bench.rng(self.name)

    def home(self) -> None:
        self.move_to(MachineTarget({a: 0.0 for a in self.axes}))

    def _joint_legs(self, target: MachineTarget) -> list[np.ndarray]:
        """Each leg's samples (K, 5) of a joint target: linear in joint space."""
        here = np.array([self.machine.joints[a] for a in self.axes])
        legs = []
        for point in target.points():
            there = np.array([point[a] for a in self.axes])
            span_lin, span_rot = float(np.max(np.abs(there[:3] - here[:3]))), float(np.max(np.abs(there[3:] - here[3:])))
            steps = max(1, math.ceil(max(span_lin / self.STEP_MM, span_rot / self.STEP_DEG)))
            legs.append(here + np.arange(1, steps + 1)[:, None] / steps * (there - here))
            here = there
        return legs

    def _tcp_legs(self, target: MachineTarget) -> list[np.ndarray]:
        """Each leg's samples (K, 5) of a tool-centre-point target: linear in the table point and the rotary
        angles, each sample's joints by the control's nominal kinematics; OutOfLimits if any joint leaves
        its limits (nothing has moved)."""
        j = self.machine.joints
        a0, c0 = j["a"], j["c"]
        p0 = nominal_machine_to_table(self.geometry, np.array([a0]), np.array([c0]), np.array([j["x"], j["y"], j["z"]]) + self.tool_mm)[0]
        legs = []
        for point in target.points():
            p1, a1, c1 = np.array([point["x"], point["y"], point["z"]]), point["a"], point["c"]
            span = max(float(np.max(np.abs(p1 - p0))) / self.STEP_MM, max(abs(a1 - a0), abs(c1 - c0)) / self.STEP_DEG)
            f = np.arange(1, max(1, math.ceil(span)) + 1) / max(1, math.ceil(span))
            legs.append(joint_targets(self.geometry, p0 + f[:, None] * (p1 - p0), a0 + f * (a1 - a0), c0 + f * (c1 - c0),
                                      tuple(self.tool_mm)))
            p0, a0, c0 = p1, a1, c1
        for leg in legs:
            for k, axis in enumerate(self.axes):
                lo, hi = self.limits[axis]
                if np.any(leg[:, k] < lo) or np.any(leg[:, k] > hi):
                    unit = "mm" if axis in "xyz" else "°"
                    raise OutOfLimits(self.name, f"the tool-centre-point move takes joint {axis.upper()} outside its limits "
                                                 f"[{lo:g}, {hi:g}] {unit}")
        return legs

    def move_to(self, target: MachineTarget) -> None:
        self.check_target(target)
        legs = self._tcp_legs(target) if target.tcp else self._joint_legs(target)
        self._request()
        spec = self.machine.spec
        here = np.array([self.machine.joints[a] for a in self.axes])
        direction = self.machine.c_direction
        directions, seconds = [], 0.0
        for leg in legs:
            steps = np.diff(np.vstack([here, leg]), axis=0)
            if leg[-1, 4] != here[4]:
                direction = 1 if leg[-1, 4] > here[4] else -1
            directions.append(np.full(len(leg), direction))
            seconds += max(float(np.max(np.sum(np.abs(steps[:, :3]), axis=0))) / spec.linear_speed_mm_per_s,
                           float(np.max(np.sum(np.abs(steps[:, 3:]), axis=0))) / spec.rotary_speed_deg_per_s)
            here = leg[-1]
        path = np.vstack(legs)
        k = self.machine.strikes(path, np.concatenate(directions))
        if k >= 0:
            at = dict(zip(self.axes, (float(v) for v in path[k])))
            self.machine.arrive(at, self._rng)
            raise InstrumentFault(self.name, self.machine.struck(at))
        self.bench.clock.sleep(seconds)
        self.machine.arrive(dict(zip(self.axes, (float(v) for v in path[-1]))), self._rng, direction)

    def joint_positions(self) -> dict[str, float]:
        return dict(self.machine.joints)

    def stop(self) -> None:
        """Nothing moves between calls in process: every axis stands still."""

    def wait_stopped(self, timeout_s: float = STOP_WATCH_S) -> StopSeen:
        """As the stage's: a simulated motion is whole or not begun; the joints are where the machine has them."""
        return StopSeen(True, self.show_joints([self.machine.joints[a] for a in self.axes]))


class SimNestIndicator(SimDialIndicator):
    """One of the nest's three indicators (``index`` 0–2), read as a Sylvac: the sensor's plunger position
    (simulators/machine_tool.py), with the nest's noise and resolution; creep and inch as a dial indicator's."""

    def __init__(self, bench: Bench, index: int, inject: bool = True):
        super().__init__(bench, index, inject)
        self.name = f"nest_indicator_{index + 1}"
        self._rng = bench.rng(self.name)
        self.machine = machine_of(bench)

    def display(self) -> tuple[float, str]:
        nest = self.machine.spec.nest
        creep_um = 0.0
        if self.state_fault is not None and self.state_fault.kind == "creep":
            self._creep_readings += 1
            creep_um = self.state_fault.creep_um_per_reading * self._creep_readings
        um = self.machine.sensor_mm(self.index) * 1e3 + creep_um + nest.noise_um * self._rng.standard_normal()
        if self.state_fault is not None and self.state_fault.kind == "inch":
            return _quantise(um / 25400.0, self.INCH_DIGIT), "in"
        return _quantise(um, nest.resolution_um) / 1000.0, "mm"
