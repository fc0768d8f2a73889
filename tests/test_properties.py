"""Property-based tests (hypothesis): parsers and loaders meet any input with a typed error or a
value — never another exception, never a hang — and no out-of-limits motion reaches a transport."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from drivers import az_registers as az
from drivers.addresses import Address, AddressError, parse_address
from drivers.errors import InstrumentError, OutOfLimits
from drivers.ipp_cmm import IppCmm
from drivers.modbus_stage import ModbusStage
from drivers.serial_instruments import ElcomatAutocollimator, LineLaserTracer, QsbEncoder, SylvacIndicator
from drivers.serial_line import SerialLine
from rtcal.procedure.loader import load_procedure
from rtcal.procedure.yamlfile import FileProblems, validate_text
from simulators.az_drive import AzDriveModel
from simulators.bench import Bench
from simulators.instruments import SimAutocollimator, SimCmm, SimDialIndicator, SimEncoder, SimLaserTracer, SimStage
from simulators.scenario import Scenario
from simulators.servers.ipp_server import IppSession
from simulators.servers.serial_protocols import ElcomatHandler, QsbHandler, SylvacHandler, TracerHandler

REPO = Path(__file__).resolve().parents[1]
GOOD = (REPO / "procedures" / "laser_tracer_multistation.yaml").read_text()
FAST = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


# -- the procedure and scenario loaders ---------------------------------------------------------

@FAST
@given(st.text(max_size=400))
@example("-")
@example("method: laser_tracer_multistation\nstations: {count: 1e400}")
def test_loader_on_arbitrary_text(tmp_path, text):
    path = tmp_path / "p.yaml"
    path.write_text(text, encoding="utf-8")
    try:
        load_procedure(path)
    except FileProblems as exc:
        assert exc.problems and all(p.line >= 1 and p.column >= 1 for p in exc.problems)


SCALARS = st.one_of(st.integers(-10**6, 10**6), st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8),
                    st.booleans(), st.none(), st.lists(st.integers(-5, 5), max_size=4))


@FAST
@given(st.data())
def test_loader_on_mutated_procedures(tmp_path, data):
    """Replace or delete random keys of the shipped procedure: a model or a located problem."""
    doc = yaml.safe_load(GOOD)

    def paths(node, prefix=()):
        if isinstance(node, dict):
            for k, v in node.items():
                yield prefix + (k,)
                yield from paths(v, prefix + (k,))

    for target in data.draw(st.lists(st.sampled_from(list(paths(doc))), min_size=1, max_size=3)):
        parent = doc
        for key in target[:-1]:
            parent = parent.get(key) if isinstance(parent, dict) else None
        if isinstance(parent, dict) and target[-1] in parent:
            if data.draw(st.booleans()):
                del parent[target[-1]]
            else:
                parent[target[-1]] = data.draw(SCALARS)
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump(doc, allow_unicode=True))
    try:
        load_procedure(path)
    except FileProblems:
        pass


@FAST
@given(st.text(max_size=120))
@example("-")  # found on CI: a sequence holding one empty scalar
@example("? [a]\n: 1")  # a key that is not a scalar
def test_scenario_loader_on_arbitrary_text(text):
    try:
        validate_text(text, Scenario, "s.yaml")
    except FileProblems:
        pass


@FAST
@given(st.text(max_size=80))
def test_address_parser(text):
    try:
        assert isinstance(parse_address(text), Address)
    except AddressError:
        pass


# -- driver ends of the protocols -------------------------------------------------------------

class FakePort:
    def __init__(self, reply: bytes):
        self.reply = reply

    def reset_input_buffer(self): ...
    def write(self, data): ...
    def flush(self): ...
    def close(self): ...

    def read_until(self, terminator, size):
        end = self.reply.find(terminator)
        return self.reply[: end + len(terminator)] if end >= 0 else self.reply[:size]


def _driver(cls, reply: bytes, **kw):
    d = cls.__new__(cls)
    terminator = b"\r\n" if cls in (QsbEncoder, LineLaserTracer) else b"\r"
    d.line = SerialLine.__new__(SerialLine)
    d.line.name, d.line.terminator, d.line.port = "x", terminator, FakePort(reply)
    for k, v in kw.items():
        setattr(d, k, v)
    return d


REPLIES = st.one_of(st.binary(max_size=40),
                    st.from_regex(rb"\A[0-9 +\-.ELNOKRFEQ?]{0,20}(\r\n|\r)?\Z"),
                    st.sampled_from([b"0 +1.0 -2.0\r", b"LEN 12.5 3\r\n", b"0E0000FFFF\r\n", b"+0.0012\r", b"ERR LOST\r\n"]))


@FAST
@given(REPLIES)
def test_serial_drivers_on_arbitrary_replies(reply):
    calls = [
        (ElcomatAutocollimator, "read_arcsec", {}),
        (SylvacIndicator, "read_um", {"name": "dial_indicator_1"}),
        (QsbEncoder, "read_angle_deg", {"counts_per_rev": 3600000}),
        (LineLaserTracer, "read_length", {}),
        (LineLaserTracer, "reference", {}),
    ]
    for cls, method, kw in calls:
        try:
            value = getattr(_driver(cls, reply, **kw), method)()
        except InstrumentError:
            continue
        assert value is not None


class FakeSocket:
    def __init__(self, data: bytes):
        self.data = data

    def sendall(self, data): ...
    def close(self): ...
    def settimeout(self, seconds): ...

    def recv(self, n):
        out, self.data = self.data[:n], self.data[n:]
        return out


@FAST
@given(st.lists(st.one_of(st.binary(max_size=30), st.sampled_from([b"00001 &", b"00001 %", b"00001 # X(1), Y(2), Z(3)",
                                                                   b'00001 ! Error(2, 1008, "GoTo", "x")', b"E0000 # event"])),
                max_size=6))
def test_ipp_client_on_arbitrary_replies(lines):
    cmm = IppCmm.__new__(IppCmm)
    cmm._tag, cmm._buffer, cmm.timeout_s = 0, b"", 1.0
    cmm.volume_min_mm, cmm.volume_max_mm = (-math.inf,) * 3, (math.inf,) * 3
    cmm.sock = FakeSocket(b"".join(line + b"\r\n" for line in lines))
    try:
        cmm.position_mm()
    except InstrumentError:
        pass


# -- simulator ends of the protocols ----------------------------------------------------------

@FAST
@given(st.binary(max_size=40))
def test_serial_simulators_on_arbitrary_requests(request):
    bench = Bench(Scenario())
    for handler in (ElcomatHandler(SimAutocollimator(bench)), SylvacHandler(SimDialIndicator(bench, 0)),
                    QsbHandler(SimEncoder(bench), 2**20), TracerHandler(SimLaserTracer(bench))):
        assert isinstance(handler.handle(request), bytes)


@FAST
@given(st.text(max_size=60))
def test_ipp_server_on_arbitrary_lines(line):
    session = IppSession(SimCmm(Bench(Scenario())))
    session.started = True
    assert isinstance(session.handle(line), str)


@FAST
@given(st.integers(0, 0x200), st.lists(st.integers(0, 0xFFFF), max_size=16), st.integers(0, 0x200), st.integers(1, 20))
def test_drive_model_on_arbitrary_registers(address, values, read_address, count):
    model = AzDriveModel(SimStage(Bench(Scenario())), 1000.0)
    assert model.write(address, values) in (None, 1, 2, 3, 4)
    result = model.read(read_address, count)
    assert isinstance(result, int) or (len(result) == count and all(0 <= v <= 0xFFFF for v in result))


@FAST
@given(st.integers(-(2**31), 2**31 - 1))
def test_32bit_words_round_trip(value):
    assert az.join32(*az.split32(value)) == value


# -- safety: nothing outside the soft limits reaches a transport --------------------------------

class RecordingClient:
    def __init__(self):
        self.writes = []

    def write_registers(self, address, values, device_id):
        self.writes.append((address, values))
        return type("Ok", (), {"isError": lambda self: False})()

    def read_holding_registers(self, address, count, device_id):
        regs = az.split32(az.OUT_IN_POS | az.OUT_READY) + az.split32(0)
        return type("R", (), {"isError": lambda self: False, "registers": regs[:count]})()


@FAST
@given(st.floats(-1e4, 1e4, allow_nan=False), st.floats(-400, 0), st.floats(0, 400))
def test_no_stage_command_outside_soft_limits_reaches_the_wire(target, lo, hi):
    stage = ModbusStage.__new__(ModbusStage)
    stage.unit, stage.steps_per_deg, stage.speed_hz, stage.timeout_s = 1, 1000.0, 10000, 1.0
    stage.limits_deg, stage.client = (lo, hi), RecordingClient()
    if lo <= target <= hi:
        stage.move_to(target)
        position = az.join32(*stage.client.writes[0][1][2:4])
        assert lo * 1000 - 1 <= position <= hi * 1000 + 1
    else:
        with pytest.raises(OutOfLimits):
            stage.move_to(target)
        assert stage.client.writes == []


@FAST
@given(st.lists(st.floats(-3000, 3000, allow_nan=False), min_size=3, max_size=3))
def test_no_cmm_command_outside_the_volume_reaches_the_wire(xyz):
    cmm = IppCmm.__new__(IppCmm)
    cmm.volume_min_mm, cmm.volume_max_mm = (0.0, -500.0, 0.0), (1200.0, 500.0, 800.0)
    sent = []
    cmm.sock = type("S", (), {"sendall": lambda self, data: sent.append(data)})()
    inside = all(lo <= v <= hi for v, lo, hi in zip(xyz, cmm.volume_min_mm, cmm.volume_max_mm))
    if inside:
        return
    with pytest.raises(OutOfLimits):
        cmm.move_to(np.array(xyz))
    assert sent == []


# -- the compensation readers, the deviation table and the command-line option parsers ---------

def _written_tables() -> dict[str, str]:
    from rtcal.deliverables.compensation import WRITERS, CompensationTable

    grid = np.linspace(0.0, 360.0, 25)
    trims = 1e-3 * np.sin(np.radians(grid))
    table = CompensationTable(grid, trims, -trims)
    return {fmt: write(table) for fmt, write in WRITERS.items()}


WRITTEN = _written_tables()


@FAST
@given(st.sampled_from(sorted(WRITTEN)), st.data())
def test_compensation_readers_on_mutated_tables(fmt, data):
    """A controller's table with characters deleted, replaced or inserted: read, or refused with a
    CompensationError naming where — never another exception."""
    from rtcal.deliverables.compensation import PARSERS, CompensationError

    text = WRITTEN[fmt]
    for _ in range(data.draw(st.integers(1, 4))):
        at = data.draw(st.integers(0, len(text)))
        new = data.draw(st.sampled_from(["", "-", "9", "e999", "nan", ".", ",", "\n", "=", "]", " ", "\x00", "é"]))
        text = text[:at] + new + text[at + data.draw(st.integers(0, 3)):]
    try:
        table = PARSERS[fmt](text, "t")
    except CompensationError as exc:
        assert str(exc)
    else:
        for values in (table.positions_deg, table.trim_up_deg, table.trim_down_deg):
            assert np.all(np.isfinite(values))


@FAST
@given(st.sampled_from(sorted(WRITTEN)), st.text(max_size=300))
def test_compensation_readers_on_arbitrary_text(fmt, text):
    from rtcal.deliverables.compensation import PARSERS, CompensationError

    try:
        PARSERS[fmt](text, "t")
    except CompensationError:
        pass


DEVIATIONS = "target_deg,direction,run,deviation_arcsec,uncertainty_arcsec\n0,+,1,0.0,0.1\n90,+,1,1.5,0.1\n180,-,1,-2.0,0.1\n"


@FAST
@given(st.one_of(st.text(max_size=300), st.builds(lambda cut, add: DEVIATIONS[:cut] + add, st.integers(0, len(DEVIATIONS)),
                                                   st.text(max_size=40))))
@example("target_deg,direction,run,deviation_arcsec,uncertainty_arcsec\n1e999,+,1,nan,0\n")
def test_deviation_table_reader(text):
    from rtcal.deliverables.deviations import DeviationTableError, PositioningDeviations

    try:
        PositioningDeviations.parse_csv(text, "t")
    except DeviationTableError as exc:
        assert str(exc)


@FAST
@given(st.text(max_size=200).map(lambda t: "{" + t))
@example("{" + '"a": ' + "[" * 100_000)
@example('{"stage": 1}')
def test_instruments_option(text):
    """`--instruments`: a dict of strings, or a UserError (exit 2) — deep nesting included."""
    from rtcal.cli import UserError, parse_instruments_option

    try:
        parsed = parse_instruments_option(text)
    except UserError as exc:
        assert str(exc).startswith("--instruments")
    else:
        assert all(isinstance(k, str) and isinstance(v, str) for k, v in parsed.items())


@FAST
@given(st.text(max_size=300))
@example("X,Y,Z\n" + "1,2,3\n" * 3 + "1e999,0,0\n")
def test_stations_csv_reader(tmp_path, text):
    from rtcal.cli import UserError, read_stations_csv

    path = tmp_path / "stations.csv"
    path.write_bytes(text.encode("utf-8", "replace"))
    try:
        rows = read_stations_csv(path)
    except UserError:
        pass
    else:
        assert rows.shape[1] == 3 and np.all(np.isfinite(rows))
