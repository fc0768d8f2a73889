"""Byte-level tests of every serial driver: what it sends, what it makes of each reply.

Each case: the exact request the driver must send, the reply the device gives, and the value
or typed error the driver must return. Malformed, truncated (no terminator) and silent replies
must end in InstrumentFault or InstrumentTimeout, never in a hang or another exception. The
devices are scripted pseudo-terminals (8N1: this machine's kind of pty refuses other framings
on some kernels); the framings themselves are checked over socket:// in tests/test_probe.py.
"""

from __future__ import annotations

import pytest

from drivers.addresses import parse_address
from drivers.errors import InstrumentFault, InstrumentTimeout
from drivers.serial_instruments import QSB_SIMULATED_VERSION, ElcomatAutocollimator, LineLaserTracer, QsbEncoder, SylvacIndicator
from simulators.bench import Bench
from simulators.instruments import SimAutocollimator, SimDialIndicator, SimEncoder, SimLaserTracer
from simulators.scenario import Scenario
from simulators.servers.serial_protocols import ElcomatHandler, QsbHandler, SylvacHandler, TracerHandler
from tests.fakes import ScriptedDevice

TIMEOUT = 0.3
PTY = "?bytesize=8&parity=N&stopbits=1"
QSB_OPEN = [(b"W1503\r\n", b"w1500000003!\r\n"), (b"W0000\r\n", b"w0000000000!\r\n"), (b"W0303\r\n", b"w0300000003!\r\n"),
            (b"R14\r\n", b"r1400000100!\r\n")]


ELCOMAT_OPEN = [(b"d\r\n", b"8 30123 15 01 2026 300\r")]  # dls-controls/elcomat3000: serial, date, focal length
SYLVAC_OPEN = [(b"MM\r", None), (b"UNI?\r", b"MM\r"),  # the reply carries no unit: mm set and confirmed at open
               (b"ID?\r", b"SY289.A\r")]  # then its identification (OPTO-RS: SY, instrument, option)
TRACER_OPEN = [(b"ID?\r\n", b"ERR CMD\r\n")]  # a bridge that does not name itself


def _read(make, request: bytes, reply: bytes | None, call: str):
    opening = {ENCODER: QSB_OPEN, INDICATOR: SYLVAC_OPEN, AUTOCOLLIMATOR: ELCOMAT_OPEN, TRACER: TRACER_OPEN}.get(make, [])
    with ScriptedDevice(opening + [(request, reply)]) as dev:
        driver = make(dev.path)
        try:
            return getattr(driver, call)()
        finally:
            driver.close()
            assert dev.received == [r for r, _ in opening] + [request]


AUTOCOLLIMATOR = lambda path: ElcomatAutocollimator(parse_address(path + PTY), TIMEOUT)  # noqa: E731
INDICATOR = lambda path: SylvacIndicator(parse_address(path + PTY), TIMEOUT, "dial_indicator_1")  # noqa: E731
ENCODER = lambda path: QsbEncoder(parse_address(path + PTY + "&counts_per_rev=3600000"), TIMEOUT)  # noqa: E731
TRACER = lambda path: LineLaserTracer(parse_address(path + PTY), TIMEOUT)  # noqa: E731

GOOD = [
    (AUTOCOLLIMATOR, b"a\r\n", b"4 003 12.34 -5.67\r", "read_arcsec", (12.34, -5.67)),  # the reference's example
    (AUTOCOLLIMATOR, b"a\r\n", b"4 003 +12.3450 -3.2100\r", "read_arcsec", (12.345, -3.21)),
    (AUTOCOLLIMATOR, b"a\r\n", b"4 001 12.34 -5.67\r", "read_arcsec", (12.34, float("nan"))),  # X valid, Y not
    (AUTOCOLLIMATOR, b"a\r\n", b"4 002 12.34 -5.67\r", "read_axes_arcsec", (float("nan"), -5.67)),  # Y only
    (INDICATOR, b"?\r", b"+0.001230\r", "read_um", 1.23),
    (INDICATOR, b"?\r", b"-0.250000\r\n", "read_um", -250.0),  # CR LF as well as CR
    (INDICATOR, b"?\r", b"- 0.2500 mm\r", "read_um", -250.0),  # a sign apart and a unit: tolerated
    (INDICATOR, b"?\r", b" 0.0100\r", "read_um", 10.0),  # the OPTO-RS manual's form: a space for +, CR
    (ENCODER, b"R0E\r\n", b"r0E0001F4A2!\r\n", "read_angle_deg", 128162 * 360 / 3600000),  # the reference's example
    (ENCODER, b"R0E\r\n", b"r0E0000A000\r\n", "read_angle_deg", 40960 * 360 / 3600000),  # older firmware: no "!"
    (ENCODER, b"R0E\r\n", b"r0EFFFFFFFF0000ABCD!\r\n", "read_angle_deg", -360 / 3600000),  # with a timestamp
    (ENCODER, b"R0E\r\n", b"r 0E 0000A000 !\r\n", "read_angle_deg", 40960 * 360 / 3600000),  # spaces between fields
    (TRACER, b"REF\r\n", b"OK REF 3\r\n", "reference", 3),
]

BAD = [
    (AUTOCOLLIMATOR, b"a\r\n", b"4 000 0.00 0.00\r", InstrumentFault, "no valid absolute measurement"),
    (AUTOCOLLIMATOR, b"a\r\n", b"2 103 1.00 2.00\r", InstrumentFault, "no valid absolute measurement"),
    (AUTOCOLLIMATOR, b"a\r\n", b"4 002 1.00 2.00\r", InstrumentFault, "X axis not valid"),  # what a run needs
    (AUTOCOLLIMATOR, b"a\r\n", b"4 003 +12.3x -3\r", InstrumentFault, "unexpected reply"),
    (AUTOCOLLIMATOR, b"a\r\n", b"0 +12.3450 -3.2100\r", InstrumentFault, "unexpected reply"),  # three fields
    (AUTOCOLLIMATOR, b"a\r\n", b"4 003 +12.34", InstrumentTimeout, "truncated"),
    (AUTOCOLLIMATOR, b"a\r\n", None, InstrumentTimeout, "no reply"),
    (INDICATOR, b"?\r", b"\r", InstrumentFault, "initialising"),
    (INDICATOR, b"?\r", b"ERR1\r", InstrumentFault, "indicator error ERR1 .incorrect command"),
    (INDICATOR, b"?\r", b"ERR2\r", InstrumentFault, "indicator error ERR2 .parity error: check the line's framing"),
    (INDICATOR, b"?\r", b"ERR0\r", InstrumentFault, "indicator error ERR0 .sensor error"),
    (INDICATOR, b"?\r", b"ERR3\r", InstrumentFault, "ERR3 .measuring range exceeded"),
    (INDICATOR, b"?\r", b"+0.0100 in\r", InstrumentFault, "unexpected reply"),  # no unit but mm is ever right
    (INDICATOR, b"?\r", b"\xff\xfe\r", InstrumentFault, "not ASCII"),
    (INDICATOR, b"?\r", b"+0.00", InstrumentTimeout, "truncated"),
    (INDICATOR, b"?\r", None, InstrumentTimeout, "no reply"),
    (ENCODER, b"R0E\r\n", b"0E0001F4A2\r\n", InstrumentFault, "unexpected reply"),  # no response letter
    (ENCODER, b"R0E\r\n", b"r0E12G45678!\r\n", InstrumentFault, "unexpected reply"),
    (ENCODER, b"R0E\r\n", b"r140001F4A2!\r\n", InstrumentFault, "not for register 0E"),
    (ENCODER, b"R0E\r\n", b"e0E00000000!\r\n", InstrumentFault, "error"),
    (ENCODER, b"R0E\r\n", b"r0E1234", InstrumentTimeout, "truncated"),
    (ENCODER, b"R0E\r\n", None, InstrumentTimeout, "no reply"),
    (TRACER, b"REF\r\n", b"OK REFX\r\n", InstrumentFault, "unexpected reply"),
    (TRACER, b"REF\r\n", None, InstrumentTimeout, "no reply"),
    (TRACER, b"REF\r\n", b"OK REF " + b"9" * 40 + b"\r\n", InstrumentFault, "unexpected reply"),
    # values a line can carry but no instrument can measure: garbage, never a reading
    (AUTOCOLLIMATOR, b"a\r\n", b"4 003 9999.0000 0.0000\r", InstrumentFault, "outside what it can measure"),
    (AUTOCOLLIMATOR, b"a\r\n", b"4 003 0.0000 -" + b"9" * 200 + b"\r", InstrumentFault, "outside what it can measure"),
    (INDICATOR, b"?\r", b"+250.000000\r", InstrumentFault, "outside what it can measure"),
]


@pytest.mark.parametrize("make,request_,reply,call,expected", GOOD)
def test_driver_reads(make, request_, reply, call, expected):
    assert _read(make, request_, reply, call) == pytest.approx(expected, nan_ok=True)


@pytest.mark.parametrize("make,request_,reply,error,text", BAD)
def test_driver_raises_typed_errors(make, request_, reply, error, text):
    call = {AUTOCOLLIMATOR: "read_arcsec", INDICATOR: "read_um", ENCODER: "read_angle_deg", TRACER: "reference"}[make]
    with pytest.raises(error, match=text):
        _read(make, request_, reply, call)


def test_qsb_is_configured_at_open_and_identifies_itself():
    with ScriptedDevice(QSB_OPEN) as dev:
        encoder = ENCODER(dev.path)
        assert encoder.identity() == "US Digital QSB, VERSION register 0x00000100"
        encoder.close()
        assert dev.received == [r for r, _ in QSB_OPEN]


def test_qsb_refusing_its_configuration_is_a_fault():
    with ScriptedDevice([(b"W1503\r\n", b"e1500000000!\r\n")]) as dev:
        with pytest.raises(InstrumentFault, match="W1503: the counter answered with an error"):
            ENCODER(dev.path)


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
    elcomat = ElcomatHandler(SimAutocollimator(bench))
    assert elcomat.handle(b"a\r") == b"4 003 0.0000 0.0000\r"
    assert elcomat.handle(b"r\r") == b"2 103 0.0000 0.0000\r"
    assert elcomat.handle(b"X\r") == b""
    assert elcomat.handle(b"d\r") == b"8 SIMULATED 15 01 2026 300\r"
    assert SylvacHandler(SimDialIndicator(bench, 0)).handle(b"?") == b" 0.0000\r"  # OPTO-RS: space for +, CR
    inch = SylvacHandler(SimDialIndicator(bench, 0), echo=True, inch=True)
    assert (inch.handle(b"UNI?"), inch.handle(b"MM"), inch.handle(b"UNI?")) == (b"UNI?\rIN\r", b"MM\r", b"UNI?\rMM\r")
    assert inch.handle(b"FOO") == b"FOO\rERR1\r"
    bench.move_stage(0.5, +1)  # rad: no polygon face in front of the autocollimator
    assert elcomat.handle(b"a\r") == b"4 000 0.0000 0.0000\r"
    qsb = QsbHandler(SimEncoder(bench), 2**20)
    assert qsb.handle(b"R0E") == f"r0E{round(0.5 / 6.283185307179586 * 2**20):08X}!\r\n".encode()
    assert qsb.handle(b"W1509") == b"w 15 00000009 !\n"  # EOR: LF only, spaces between fields (from this reply on)
    assert qsb.handle(b"R14") == f"r 14 {QSB_SIMULATED_VERSION:08X} !\n".encode()
    assert qsb.handle(b"R0E0") == b"e00000000!\r\n"
    tracer = TracerHandler(SimLaserTracer(bench))
    assert tracer.handle(b"REF\r") == b"OK REF 0\r\n"
    assert tracer.handle(b"LEN?\r") == b"LEN 0.000 0\r\n"
    assert tracer.handle(b"HELLO\r") == b"ERR CMD\r\n"
