"""Open a real-transport driver from an address string: the one place schemes meet drivers."""

from __future__ import annotations

from drivers.addresses import Address, AddressError, parse_address
from drivers.interfaces import Autocollimator, Cmm, DialIndicator, Encoder, EnvironmentSensor, LaserTracer, RotaryStage


# the kinds of address each instrument of a procedure speaks (checked when a procedure is validated)
SCHEMES: dict[str, tuple[str, ...]] = {
    "stage": ("modbus-tcp", "modbus-rtu"), "cmm": ("ipp",), "laser_tracer": ("serial",), "encoder": ("serial",),
    "autocollimator": ("serial",), "dial_indicator_1": ("serial",), "dial_indicator_2": ("serial",),
    "environment": ("serial",),
}


def _expect(kind: str, address: str, schemes: tuple[str, ...]) -> Address:
    parsed = parse_address(address)
    if parsed.scheme not in schemes:
        raise AddressError(f"{kind}: {address!r} is a {parsed.scheme} address; a {kind} needs {' or '.join(schemes)}")
    return parsed


def open_stage(address: str, limits_deg: tuple[float, float], timeout_s: float) -> RotaryStage:
    from drivers.modbus_stage import ModbusStage

    return ModbusStage(_expect("stage", address, SCHEMES["stage"]), limits_deg, timeout_s)


def open_cmm(address: str, volume_min_mm, volume_max_mm, timeout_s: float) -> Cmm:
    from drivers.ipp_cmm import IppCmm

    return IppCmm(_expect("cmm", address, SCHEMES["cmm"]), timeout_s, volume_min_mm, volume_max_mm)


def open_laser_tracer(address: str, timeout_s: float) -> LaserTracer:
    from drivers.serial_instruments import LineLaserTracer

    return LineLaserTracer(_expect("laser tracer", address, SCHEMES["laser_tracer"]), timeout_s)


def open_encoder(address: str, timeout_s: float) -> Encoder:
    from drivers.serial_instruments import QsbEncoder

    return QsbEncoder(_expect("encoder", address, SCHEMES["encoder"]), timeout_s)


def open_autocollimator(address: str, timeout_s: float) -> Autocollimator:
    from drivers.serial_instruments import ElcomatAutocollimator

    return ElcomatAutocollimator(_expect("autocollimator", address, SCHEMES["autocollimator"]), timeout_s)


def open_dial_indicator(address: str, name: str, timeout_s: float) -> DialIndicator:
    from drivers.serial_instruments import SylvacIndicator

    return SylvacIndicator(_expect("dial indicator", address, SCHEMES["dial_indicator_1"]), name, timeout_s)


def open_environment(address: str, timeout_s: float) -> EnvironmentSensor:
    from drivers.serial_instruments import LineEnvironmentSensor

    return LineEnvironmentSensor(_expect("environment sensor", address, SCHEMES["environment"]), timeout_s)
