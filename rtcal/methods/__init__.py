"""One class per calibration method, each implementing :class:`rtcal.methods.protocol.Method`:
its plan, instruments, measurement, analysis into typed results and Monte Carlo draws. The
runner, planning and the CLI know a method only through that protocol and :data:`METHODS`.
"""

from __future__ import annotations

from typing import Any

from rtcal.methods.abbe import AbbeMethod
from rtcal.methods.multistation import MultistationMethod
from rtcal.methods.protocol import Method
from rtcal.procedure.models import EncoderAbbeError, LaserTracerMultistation
from rtcal.plans.abbe import AbbeInstrumentSet
from rtcal.plans.multistation import MultistationInstrumentSet

# the type checker checks here that each class has the protocol's shape for its procedure and instruments
MULTISTATION: Method[LaserTracerMultistation, MultistationInstrumentSet] = MultistationMethod()
ABBE: Method[EncoderAbbeError, AbbeInstrumentSet] = AbbeMethod()

METHODS: dict[str, Method[Any, Any]] = {MULTISTATION.name: MULTISTATION, ABBE.name: ABBE}
"""Every method, by the procedure's ``method:``."""
