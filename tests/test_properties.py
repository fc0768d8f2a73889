"""Property-based tests (hypothesis): parsers and loaders meet any input with a typed error or a
value — never another exception, never a hang — and no out-of-limits motion reaches a transport."""

from __future__ import annotations

import math
import os
import tempfile
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
from rtcal.methods import load_procedure
from rtcal.procedure.yamlfile import FileProblems, validate_text
from simulators.az_drive import AzDriveModel
from simulators.bench import Bench
from simulators.instruments import SimAutocollimator, SimCmm, SimDialIndicator, SimEncoder, SimLaserTracer, SimStage
from simulators.scenario import Scenario
from simulators.servers.ipp_server import IppSession
from simulators.servers.serial_protocols import ElcomatHandler, PiGcsHandler, QsbHandler, SylvacHandler, TracerHandler

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
                    QsbHandler(SimEncoder(bench), 2**20), TracerHandler(SimLaserTracer(bench)),
                    PiGcsHandler(SimStage(bench), referenced=True)):
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
    """A drive that is at once where it was sent: feedback (0x00CC) = the last target written."""

    def __init__(self):
        self.writes = []
        self.target = 0

    def write_registers(self, address, values, device_id):
        self.writes.append((address, values))
        if address == az.OPERATION_TYPE:
            self.target = az.join32(*values[2:4])
        return type("Ok", (), {"isError": lambda self: False})()

    def read_holding_registers(self, address, count, device_id):
        regs = (az.split32(self.target) if address == az.FEEDBACK_POSITION
                else az.split32(az.OUT_IN_POS | az.OUT_READY) + az.split32(0))
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
    required = {"fanuc": {"unit_deg": 0.0001, "first_point": 0}}  # no default (issue 46)
    return {fmt: write(table, **required.get(fmt, {})) for fmt, write in WRITERS.items()}


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


# -- readers of a run directory: a damaged store, results.json, a deviation CSV ----------------

def _small_store() -> tuple[bytes, dict[int, tuple], dict[int, tuple]]:
    """A store of 300 readings and 20 events (about 12 pages), its bytes and its rows by id."""
    import sqlite3
    import tempfile

    from rtcal.store.runstore import Reading, RunStore

    folder = Path(tempfile.mkdtemp(prefix="prop-store-"))
    store = RunStore.create(folder, {"method": "encoder_abbe_error", "procedure_yaml": "x" * 3000})
    for k in range(30):
        store.add_readings([Reading(0.5 * k + j, "encoder", "angle_deg", 1.0 / (j + 1) + k, "deg", sample=j, run=k % 3,
                                    direction=1 - 2 * (k % 2), plan_index=k, attempt=k) for j in range(10)])
        store.add_event(0.5 * k, "fault" if k % 2 else "retry", f"event {k} " + "é" * k, None if k % 3 else "stage")
    store.close()
    with sqlite3.connect(f"file:{folder / 'run.sqlite'}?immutable=1", uri=True) as db:
        readings = {row[0]: tuple(row[1:]) for row in db.execute("SELECT * FROM readings")}
        events = {row[0]: tuple(row[1:]) for row in db.execute("SELECT * FROM events")}
    data = (folder / "run.sqlite").read_bytes()
    import shutil

    shutil.rmtree(folder)
    return data, readings, events


STORE_BYTES, STORE_READINGS, STORE_EVENTS = _small_store()
PAGES = len(STORE_BYTES) // 4096
PAGE_DAMAGE = st.lists(st.tuples(st.integers(0, PAGES - 1), st.sampled_from(["zero", "noise", "copy"]),
                                 st.integers(0, PAGES - 1), st.binary(min_size=16, max_size=16)), max_size=4)


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(PAGE_DAMAGE, st.integers(0, len(STORE_BYTES)))
@example([], len(STORE_BYTES))  # undamaged: everything back
@example([(0, "zero", 0, b"\0" * 16)], len(STORE_BYTES))  # the header page lost
def test_damaged_store_readers(tmp_path, damage, length):
    """Pages zeroed, filled with noise or overwritten by another page, and the file cut short
    anywhere: the store's readers answer with a verdict, never another exception; every reading
    salvaged is one that was stored, as it was; `export` exits 0, 1 or 2."""
    from rtcal.store.salvage import salvage_store
    from rtcal.store.runstore import RunStore, StoreUnusable, check_store

    data = bytearray(STORE_BYTES)
    for page, kind, source, noise in damage:
        at = page * 4096
        data[at:at + 4096] = {"zero": bytes(4096), "noise": noise * 256,
                              "copy": STORE_BYTES[source * 4096:(source + 1) * 4096]}[kind]
    run = Path(tempfile.mkdtemp(prefix="run", dir=tmp_path))  # hypothesis may draw the same damage twice
    (run / "run.sqlite").write_bytes(bytes(data[:length]))
    assert check_store(run / "run.sqlite").kind in ("run", "empty", "orphan", "damaged")
    try:
        RunStore.open(run).close()
    except StoreUnusable:
        pass
    saved = salvage_store(run / "run.sqlite")
    assert all(STORE_READINGS.get(i) == row for i, row in saved.readings.items())
    assert all(STORE_EVENTS.get(i) == row for i, row in saved.events.items())
    assert saved.unreadable_readings >= 0
    if not damage and length == len(STORE_BYTES):
        assert saved.readings == STORE_READINGS and saved.events == STORE_EVENTS and saved.unreadable_readings == 0
    from rtcal.cli import main

    assert main(["export", str(run), "--out", str(run / "out")]) in (0, 1, 2)


@FAST
@given(st.one_of(st.binary(max_size=200), st.builds(lambda t: t.encode(), st.text(max_size=200)),
                 st.sampled_from([b'{"method": 1}', b"[]", b'{"method": "x"}', b"\xef\xbb\xbf{}", b"[" * 5000])))
def test_stored_results_reader(tmp_path, data):
    """results.json as found in a run directory: validated results, None (no file), or a ResultsError
    naming the file (and the field)."""
    from rtcal.results import ResultsError, RunResults
    from rtcal.run.rundir import stored_results

    (tmp_path / "results.json").write_bytes(data)
    try:
        found = stored_results(tmp_path)
    except ResultsError as exc:
        assert str(exc).startswith(str(tmp_path / "results.json"))
    else:
        assert found is None or isinstance(found, RunResults)


@FAST
@given(st.binary(max_size=300), st.booleans())
@example(b"\xef\xbb\xbftarget_deg,direction,run,deviation_arcsec\n0,1,1,0\n", False)
def test_deviation_csv_file_reader(tmp_path, data, bom):
    """A deviation CSV's bytes, with or without a byte-order mark: a table, or a located error."""
    from rtcal.deliverables.deviations import DeviationTableError, PositioningDeviations

    path = tmp_path / "d.csv"
    path.write_bytes((b"\xef\xbb\xbf" if bom else b"") + data)
    try:
        table = PositioningDeviations.read_csv(path)
    except DeviationTableError as exc:
        assert str(exc).startswith(str(path))
    else:
        assert len(table) >= 1 and np.all(np.abs(table.deviation_arcsec[np.isfinite(table.deviation_arcsec)]) <= 1.3e6)


# -- every command's arguments -------------------------------------------------------------

NUMBERS = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr), st.integers(-10**30, 10**30).map(str),
                    st.text(max_size=12), st.sampled_from(["nan", "-inf", "1e309", "0x10", "15", "7.5", "-0", "٣"]))


@FAST
@given(st.one_of(st.none(), st.integers(-10**20, 10**20)), st.booleans())
def test_workers_option(requested, large):
    from rtcal.cli import MAX_WORKERS, UserError, _workers

    try:
        n = _workers(requested, large)
    except UserError as exc:
        assert str(exc).startswith(f"--workers {requested}")
    else:
        cores = len(os.sched_getaffinity(0))
        assert 1 <= n <= (MAX_WORKERS if large else cores)


@FAST
@given(st.one_of(st.text(max_size=40), st.builds(lambda h, p: f"tcp://{h}:{p}", st.text(max_size=10), st.integers(-5, 10**6))))
@example("tcp://127.0.0.1:8786")
def test_scheduler_option(address):
    from urllib.parse import urlsplit

    from rtcal.cli import UserError, _check_scheduler

    try:
        _check_scheduler(address)
    except UserError as exc:
        assert str(exc).startswith("--scheduler")
    else:
        parts = urlsplit(address)
        assert parts.scheme == "tcp" and parts.hostname and 0 <= parts.port <= 65535


@FAST
@given(st.text(max_size=30))
@example("-1")
@example("9223372036854775808")
def test_seed_option(text):
    import argparse

    from rtcal.cli import MAX_SEED, _seed

    try:
        assert 0 <= _seed(text) <= MAX_SEED
    except argparse.ArgumentTypeError:
        pass


COMMAND_ARGS = st.one_of(
    st.tuples(st.just("evaluate"), st.sampled_from(["iso230-2", "vdi3441", "iso230-2:1988", "x"])).map(
        lambda a: ["evaluate", "{csv}", "--standard", a[1]]),
    st.tuples(st.sampled_from(["linuxcnc", "siemens-lec", "siemens-cec", "fanuc", "heidenhain"]), NUMBERS, NUMBERS,
              NUMBERS, NUMBERS).map(lambda a: ["compensate", "{csv}", "--format", a[0], "--out", "{out}/c.txt",
                                               "--step-deg", a[1], "--max-gap-deg", a[2], "--range-deg", "0", a[3],
                                               "--detection-unit-deg", a[4]]),
    st.tuples(NUMBERS, NUMBERS).map(lambda a: ["solve", "stations", "{stations}", "--step-deg", a[0], "--first-deg", a[1]]),
    st.lists(st.sampled_from(["{csv}", "{out}", "{out}/missing", "/dev/null", "{csv}/x"]), min_size=1, max_size=3).map(
        lambda a: ["compare", *a[:2], *(["--out", a[2]] if len(a) > 2 else [])]),
    st.sampled_from(["{out}", "{csv}", "/dev/null", "{out}/none"]).map(lambda a: ["export", a]),
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(COMMAND_ARGS)
def test_command_arguments(tmp_path, capsys, argv):
    """Arbitrary option values for the commands that read a table and write a file: exit 0 or 2
    with a message, never a traceback (argparse's own mistakes included)."""
    from rtcal.cli import main

    (tmp_path / "d.csv").write_text("target_deg,direction,run,deviation_arcsec,uncertainty_arcsec\n" + "".join(
        f"{t},{d},{r},{d * 0.5 + r * 0.1},0.1\n" for t in range(0, 360, 30) for d in (1, -1) for r in (1, 2)))
    (tmp_path / "s.csv").write_text("X,Y,Z\n65,0,0\n0,65,0\n-65,0,0\n0,-65,0\n")
    paths = {"{csv}": str(tmp_path / "d.csv"), "{out}": str(tmp_path), "{stations}": str(tmp_path / "s.csv")}
    args = []
    for a in argv:
        for key, value in paths.items():
            a = a.replace(key, value)
        args.append(a)
    try:
        code = main(args)
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err
    assert code in (0, 2) and "Traceback" not in err, (args, code, err)
    assert code == 0 or err.strip(), args
