"""Typed instrument errors: the contract between drivers and the engine's fault policies; and
the error of an address that cannot be understood."""

from __future__ import annotations


class AddressError(ValueError):
    """An address string that cannot be understood. Defined here, below the address parser
    (drivers/addresses.py, which re-exports it) and the model registry (drivers/models.py), so that
    the registry need not import the parser that imports it."""


class InstrumentError(Exception):
    """Base of every error an instrument driver raises; ``instrument`` names which one."""

    def __init__(self, instrument: str, message: str):
        super().__init__(f"{instrument}: {message}")
        self.instrument = instrument


class InstrumentTimeout(InstrumentError):
    """No (complete) answer within the driver's timeout."""


class InstrumentFault(InstrumentError):
    """The instrument answered with an error, garbage, an alarm, or lost tracking."""


class OutOfLimits(InstrumentError):
    """A commanded target lies outside the configured soft limits; nothing was sent."""


class TrackingLost(InstrumentFault):
    """The laser tracer lost the reflector: its count is invalid until it is re-referenced."""


class EmergencyStop(InstrumentFault):
    """The instrument reported an emergency stop: latched until a person releases it at the machine
    and rtcal is started again; no retry or recovery clears it."""
