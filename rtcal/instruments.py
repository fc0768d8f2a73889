"""Build a procedure's instruments from its ``instruments`` section: the one place backends are chosen."""

from __future__ import annotations

from rtcal.procedure.models import LaserTracerMultistation
from rtcal.sequencer.multistation import MultistationInstrumentSet
from simulators.bench import Bench
from simulators.instruments import SimCmm, SimLaserTracer, SimStage


def multistation_instruments(proc: LaserTracerMultistation, bench: Bench) -> MultistationInstrumentSet:
    """Every backend is ``sim`` today; real transports plug in here by address."""
    return MultistationInstrumentSet(stage=SimStage(bench), cmm=SimCmm(bench), laser_tracer=SimLaserTracer(bench))
