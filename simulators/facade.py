"""The simulated bench as a method's or an instrument kind's simulation sees it (rtcal.api's ``SimBench``).

:class:`simulators.bench.Bench` is one; what a plugin's simulation may ask of it is this protocol, so that
a kind's simulated instrument never probes the bench for what it has (no ``hasattr``): its random streams,
the clock, where the table is and how it tilts, where a point of the table (or an artefact the operator
mounted on it) is now, the truth at a commanded angle; the operator's hands (what an operator step's
``simulate`` does: re-seat the polygon, move the tracer, mount an artefact); and the built-in kinds'
simulated instruments on it (:func:`simulated_instrument`). :func:`ideal_bench` is a bench with no error,
for a kind's own tests.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

if TYPE_CHECKING:
    from drivers.interfaces import Instrument


@runtime_checkable
class SimBench(Protocol):
    """What a simulation may ask of the simulated bench (frames: the housing's, origin on the axis, z along it)."""

    # -- randomness and time
    def rng(self, name: str) -> np.random.Generator:
        """The random stream of the consumer ``name`` (one per simulated instrument: interleaving changes no draw)."""
        ...

    def reading(self) -> None:
        """An instrument takes a reading now (the first one starts the bench's drifts and profiles)."""
        ...

    def now_s(self) -> float:
        """The bench's clock, s (virtual in a simulated run)."""
        ...

    # -- where the table is
    def table_angle_deg(self) -> float:
        """Where the table really is now (the command, its positioning error and its repeatability), deg."""
        ...

    def commanded_angle_deg(self) -> float:
        """Where the table was last commanded to (what its controller shows), deg."""
        ...

    def table_tilt_arcsec(self) -> tuple[float, float]:
        """The table's tilt about the housing's x and y axes now (the axis's tilt and its tilt error motion), arcsec."""
        ...

    def table_point_mm(self, on_table_mm: Any) -> np.ndarray:
        """Where a point of the table (its own frame, mm) is now: turned, tilted and displaced by the table's motion."""
        ...

    def artefact_mm(self, name: str) -> np.ndarray | None:
        """Where the artefact ``name`` the operator mounted is now (None: nothing of that name is mounted)."""
        ...

    # -- the truth at a commanded angle (what a simulated run's results compare with)
    def true_table_point_mm(self, on_table_mm: Any, commanded_deg: float, direction: int) -> np.ndarray:
        """Where a point of the table is, without noise, with the table at ``commanded_deg`` approached in
        ``direction`` (+1, −1): the systematic part of what an instrument touching it reads."""
        ...

    def true_positioning_error_arcsec(self, commanded_deg: float, direction: int) -> float:
        """The table's systematic positioning error εz at ``commanded_deg`` approached in ``direction``, arcsec."""
        ...

    def true_encoder_error_arcsec(self, commanded_deg: float, direction: int) -> float:
        """What a noise-free encoder of the bench misreads there (its Abbe shift, eccentricity, graduation), arcsec."""
        ...

    # -- the operator's hands (an operator step's ``simulate``)
    def mount_artefact(self, name: str, on_table_mm: Any) -> None: ...

    def reseat_polygon(self, offset_deg: float) -> None: ...

    def mount_tracer(self, index: int) -> None: ...

    def polygon_certificate_arcsec(self) -> list[float]: ...

    def release_emergency_stop(self) -> None: ...

    def mount_sphere(self, index: int) -> None: ...


def ideal_bench(seed: int = 0) -> SimBench:
    """A simulated bench with no error (a perfect table, instruments without noise unless they add their own)."""
    from simulators.bench import Bench
    from simulators.scenario import Scenario

    return Bench(Scenario(), seed=seed)


SIMULATED = {"stage": "SimStage", "encoder": "SimEncoder", "autocollimator": "SimAutocollimator", "cmm": "SimCmm",
             "laser_tracer": "SimLaserTracer", "environment": "SimEnvironmentSensor", "dial_indicator": "SimDialIndicator",
             "machine_tool": "SimMachineTool"}
"""The built-in kinds' simulations (simulators/instruments.py)."""


def simulated_instrument(bench: SimBench, kind: str, index: int = 0) -> Instrument:
    """The built-in kind's simulated instrument on ``bench`` (a dial indicator: the scenario's ``index``-th, touching
    the shaft at its height); KeyError naming the kinds that have one (an installed kind brings its own)."""
    from simulators import instruments
    from simulators.bench import Bench

    if kind not in SIMULATED:
        raise KeyError(f"no built-in simulation of the kind {kind!r} (those of {', '.join(SIMULATED)}; an installed "
                       "kind's package brings its own)")
    if not isinstance(bench, Bench):
        raise TypeError("the built-in simulations read rtcal's own bench")
    cls = getattr(instruments, SIMULATED[kind])
    instrument: Instrument = cls(bench, index) if kind == "dial_indicator" else cls(bench)
    return instrument


# -- the five-axis machine of a scenario's ``machine:`` (simulators/machine_tool.py), for the R-test
def simulated_nest_indicator(bench: SimBench, index: int) -> Instrument:
    """The R-test nest's sensor ``index`` (0–2) on the simulated machine, read as a dial indicator."""
    from simulators.bench import Bench
    from simulators.instruments import SimNestIndicator

    if not isinstance(bench, Bench):
        raise TypeError("the built-in simulations read rtcal's own bench")
    return SimNestIndicator(bench, index)


def true_location_errors(bench: SimBench) -> dict[str, float]:
    """The simulated machine's true location errors (X0C_um … C0A_arcsec), docs/rtest.md's signs."""
    from simulators.machine_tool import machine_of

    return machine_of(bench).truth_location_errors()  # type: ignore[arg-type]


def true_c_deviation_arcsec(bench: SimBench, c_deg: float, direction: int) -> float:
    """The simulated machine's C positioning deviation (actual − commanded) at ``c_deg`` approached in ``direction``."""
    from simulators.machine_tool import machine_of

    return machine_of(bench).truth_ecc_arcsec(c_deg, direction)  # type: ignore[arg-type]
