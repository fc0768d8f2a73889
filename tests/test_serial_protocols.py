"""Byte-level tests of every serial driver: what it sends, what it makes of each reply.

Each case: the exact request the driver must send, the reply the device gives, and the value
or typed error the driver must return. Malformed, truncated (no terminator) and silent replies
must end in InstrumentFault or InstrumentTimeout, never in a hang or another exception.
"""

from __future__ import annotations

import pytest

from drivers.addresses import parse_address
from drivers.errors import InstrumentFault, InstrumentTimeout
from drivers.serial_instruments import ElcomatAutocollimator, LineLaserTracer, QsbEncoder, SylvacIndicator
from simulators.bench import Bench
from simulators.instruments import SimAutocollimator, SimDialIndicator, SimEncoder, SimLaserTracer
from simulators.scenario import Scenario
from simulators.servers.serial_protocols import ElcomatHandler, QsbHandler, SylvacHandler, TracerHandler
from tests.fakes import ScriptedDevice

TIMEOUT = 0.3


def _read(make, request: bytes, reply: bytes | None, call: str):
    with ScriptedDevice([(request, reply)]) as dev:
        driver = make(dev.path)
        try:
            return getattr(driver, call)()
        finally:
            driver.close()
            assert dev.received == [request]


AUTOCOLLIMATOR = lambda path: ElcomatAutocollimator(parse_address(path), TIMEOUT)  # noqa: E731
INDICATOR = lambda path: SylvacIndicator(parse_address(path), "dial_indicator_1", TIMEOUT)  # noqa: E731
ENCODER = lambda path: QsbEncoder(parse_address(path + "?counts_per_rev=3600000"), TIMEOUT)  # noqa: E731
TRACER = lambda path: LineLaserTracer(parse_address(path), TIMEOUT)  # noqa: E731

GOOD = [
    (AUTOCOLLIMATOR, b"M\r", b"0 +12.3450 -3.2100\r", "read_arcsec", (12.345, -3.21)),
    (INDICATOR, b"?\r", b"+0.001230\r", "read_um", 1.23),
    (INDICATOR, b"?\r", b"-0.250000\r", "read_um", -250.0),
    (ENCODER, b"R0E\r", b"0E0000A000\r\n", "read_angle_deg", 40960 * 360 / 3600000),
    (ENCODER, b"R0E\r", b"0EFFFFFFFF\r\n", "read_angle_deg", -360 / 3600000),
    (TRACER, b"REF\r\n", b"OK REF 3\r\n", "reference", 3),
]

BAD = [
    (AUTOCOLLIMATOR, b"M\r", b"1 0 0\r", InstrumentFault, "no reflection"),
    (AUTOCOLLIMATOR, b"M\r", b"0 +12.3x -3\r", InstrumentFault, "unexpected reply"),
    (AUTOCOLLIMATOR, b"M\r", b"0 +12.34", InstrumentTimeout, "truncated"),
    (AUTOCOLLIMATOR, b"M\r", None, InstrumentTimeout, "no reply"),
    (INDICATOR, b"?\r", b"ERR1\r", InstrumentFault, "out of range"),
    (INDICATOR, b"?\r", b"\xff\xfe\r", InstrumentFault, "not ASCII"),
    (INDICATOR, b"?\r", b"+0.00", InstrumentTimeout, "truncated"),
    (INDICATOR, b"?\r", None, InstrumentTimeout, "no reply"),
    (ENCODER, b"R0E\r", b"0E12G45678\r\n", InstrumentFault, "unexpected reply"),
    (ENCODER, b"R0E\r", b"0E1234", InstrumentTimeout, "truncated"),
    (ENCODER, b"R0E\r", None, InstrumentTimeout, "no reply"),
    (TRACER, b"REF\r\n", b"OK REFX\r\n", InstrumentFault, "unexpected reply"),
    (TRACER, b"REF\r\n", None, InstrumentTimeout, "no reply"),
    (TRACER, b"REF\r\n", b"OK REF " + b"9" * 40 + b"\r\n", InstrumentFault, "unexpected reply"),
    # values a line can carry but no instrument can measure: garbage, never a reading
    (AUTOCOLLIMATOR, b"M\r", b"0 +9999.0000 +0.0000\r", InstrumentFault, "outside what it can measure"),
    (AUTOCOLLIMATOR, b"M\r", b"0 +0.0000 -" + b"9" * 200 + b"\r", InstrumentFault, "outside what it can measure"),
    (INDICATOR, b"?\r", b"+250.000000\r", InstrumentFault, "outside what it can measure"),
]


@pytest.mark.parametrize("make,request_,reply,call,expected", GOOD)
def test_driver_reads(make, request_, reply, call, expected):
    assert _read(make, request_, reply, call) == pytest.approx(expected)


@pytest.mark.parametrize("make,request_,reply,error,text", BAD)
def test_driver_raises_typed_errors(make, request_, reply, error, text):
    call = {AUTOCOLLIMATOR: "read_arcsec", INDICATOR: "read_um", ENCODER: "read_angle_deg", TRACER: "reference"}[make]
    with pytest.raises(error, match=text):
        _read(make, request_, reply, call)


@pytest.mark.parametrize("reply,expected", [
    (b"LEN 1234.500 3\r\n", (1.2345e-3, 3)),
    (b"LEN -5.000 0\r\n", (-5e-6, 0)),
])
def test_tracer_length(reply, expected):
    r = _read(TRACER, b"LEN?\r\n", reply, "read_length")
    assert r.length_mm == pytest.approx(expected[0]) and r.segment == expected[1]


@pytest.mark.parametrize("reply,error,text", [
    (b"ERR LOST\r\n", InstrumentFault, "tracking lost"),
    (b"LEN 12 x\r\n", InstrumentFault, "unexpected reply"),
    (b"LEN 12", InstrumentTimeout, "truncated"),
    (None, InstrumentTimeout, "no reply"),
    (b"LEN 9" + b"9" * 200 + b" 1\r\n", InstrumentFault, "outside what it can measure"),  # 1e194 mm
    (b"LEN 100000000000001 1\r\n", InstrumentFault, "outside what it can measure"),  # 100 m + 1 nm
    (b"LEN 12 " + b"9" * 12 + b"\r\n", InstrumentFault, "unexpected reply"),  # a segment number beyond 10⁹
])
def test_tracer_length_errors(reply, error, text):
    with pytest.raises(error, match=text):
        _read(TRACER, b"LEN?\r\n", reply, "read_length")


def test_simulator_ends_answer_as_documented():
    """The instrument ends of the protocols, byte for byte, on a noise-free bench."""
    bench = Bench(Scenario())
    assert ElcomatHandler(SimAutocollimator(bench)).handle(b"M") == b"0 +0.0000 +0.0000\r"
    assert ElcomatHandler(SimAutocollimator(bench)).handle(b"X") == b"9 0 0\r"
    assert SylvacHandler(SimDialIndicator(bench, 0)).handle(b"?") == b"+0.000000\r"
    assert SylvacHandler(SimDialIndicator(bench, 0)).handle(b"Z") == b"ERR3\r"
    bench.move_stage(0.5, +1)  # rad
    enc = QsbHandler(SimEncoder(bench), 2**20).handle(b"R0E")
    assert enc == f"0E{round(0.5 / 6.283185307179586 * 2**20):08X}\r\n".encode()
    tracer = TracerHandler(SimLaserTracer(bench))
    assert tracer.handle(b"REF\r") == b"OK REF 0\r\n"
    assert tracer.handle(b"LEN?\r") == b"LEN 0.000 0\r\n"
    assert tracer.handle(b"HELLO\r") == b"ERR CMD\r\n"
