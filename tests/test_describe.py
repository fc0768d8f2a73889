"""Instruments read and describe uniformly (issue 25, item 2): every kind's one table, the adapters
over each kind's own read methods, the fence that refuses a plugin's reading outside its description,
the engine that refuses a plan's undescribed quantity, and the store that keeps the descriptions
(and still reads a store written before them)."""

from __future__ import annotations

import csv
import math
import shutil
import sqlite3
import sys
from pathlib import Path

import numpy as np
import pytest

from drivers.errors import InstrumentFault
from drivers.fence import fenced
from drivers.interfaces import (DESCRIPTIONS, Autocollimator, Cmm, DialIndicator, Encoder, EnvironmentReading,
                                EnvironmentSensor, LaserTracer, LengthReading, MachineTarget, MachineTool, RotaryStage,
                                Value)
from drivers.kinds import describe_kind, recorded
from drivers.kinds import BUILTIN
from rtcal.clock import VirtualClock
from rtcal.cli import main
from rtcal.engine.engine import Engine
from rtcal.engine.plan import Entry
from rtcal.engine.steps import Read
from rtcal.procedure.models import FaultPolicy
from rtcal.methods.abbe.dataset import abbe_visits
from rtcal.store.salvage import _READING_TYPES, _REAL_COLUMNS
from rtcal.store.runstore import CONTEXT, READING_COLUMN_TYPES, READING_COLUMNS, SCHEMA, RunStore

REPO = Path(__file__).resolve().parents[1]
ABBE = REPO / "procedures" / "encoder_abbe_error.yaml"
PLUGIN = REPO / "tests" / "plugins" / "acme_bridge"


class Stage(RotaryStage):
    def __init__(self, position: float, feedback: float):
        self.position, self.feedback, self.calls = position, feedback, []

    def home(self) -> None: ...

    def move_to(self, angle_deg: float) -> None: ...

    def stop(self) -> None: ...

    def position_deg(self) -> float:
        self.calls.append("position")
        return self.position

    def feedback_deg(self) -> float:
        self.calls.append("feedback")
        return self.feedback


class Probe(Cmm):
    def home(self) -> None: ...

    def move_to(self, xyz_mm: np.ndarray) -> None: ...

    def stop(self) -> None: ...

    def position_mm(self) -> np.ndarray:
        return np.array([1.5, -2.0, 300.25])


class Tracer(LaserTracer):
    name = "laser_tracer"

    def reference(self) -> int:
        return 3

    def read_length(self) -> LengthReading:
        return LengthReading(812.125, 3)


class Counter(Encoder):
    def read_angle_deg(self) -> float:
        return 45.0001


class Elcomat(Autocollimator):
    def read_arcsec(self) -> tuple[float, float]:
        return (1.25, -0.5)

    def read_axes_arcsec(self) -> tuple[float, float]:
        return (1.25, math.nan)  # the y axis reported invalid


class Dial(DialIndicator):
    def read_um(self) -> float:
        return 7.5


class Mill(MachineTool):
    def home(self) -> None: ...

    def move_to(self, target: MachineTarget) -> None: ...

    def joint_positions(self) -> dict[str, float]:
        return {"x": 1.0, "y": 2.0, "z": 3.0, "a": 4.0, "c": 5.0}

    def stop(self) -> None: ...


class Weather(EnvironmentSensor):
    def read(self) -> EnvironmentReading:
        return EnvironmentReading(20.1, 101_325.0, 45.0)  # no material probe: NaN


def test_every_kind_describes_itself_by_its_one_table_and_reads_named_values_with_units():
    devices = {"stage": Stage(10.0, 10.002), "cmm": Probe(), "laser_tracer": Tracer(), "encoder": Counter(),
               "autocollimator": Elcomat(), "dial_indicator": Dial(), "environment": Weather(), "machine_tool": Mill()}
    assert sorted(devices) == sorted(BUILTIN) == sorted(DESCRIPTIONS)
    for kind, device in devices.items():
        assert device.kind == kind and device.describe() == describe_kind(kind)
        values = device.read_values()
        assert list(values) == list(device.describe())
        assert all(v.unit == device.describe()[n].unit for n, v in values.items())
    assert devices["stage"].read_values() == {"position_deg": Value(10.0, "deg"), "feedback_deg": Value(10.002, "deg")}
    assert [v.value for v in devices["cmm"].read_values().values()] == [1.5, -2.0, 300.25]
    assert devices["laser_tracer"].read_values() == {"length_mm": Value(812.125, "mm"), "segment": Value(3, "1")}
    assert devices["encoder"].read_values()["angle_deg"] == Value(45.0001, "deg")
    axes = devices["autocollimator"].read_values()
    assert axes["x_arcsec"] == Value(1.25, "arcsec") and math.isnan(axes["y_arcsec"].value)  # described as maybe NaN
    assert devices["dial_indicator"].read_values() == {"y_um": Value(7.5, "um")}
    env = devices["environment"].read_values()
    assert env["humidity_pct"] == Value(45.0, "%") and math.isnan(env["material_temperature_c"].value)


def test_a_subset_is_read_with_only_the_calls_it_needs():
    stage = Stage(1.0, 2.0)
    assert stage.read_values(["position_deg"]) == {"position_deg": Value(1.0, "deg")}
    assert stage.calls == ["position"]


def test_the_stored_quantities_come_from_the_descriptions():
    """The names stores have always held: a plan's quantities are the description's, by purpose."""
    assert recorded("stage", "feedback_deg") == (("feedback_deg", "deg"),)
    assert recorded("stage", "feedback_deg", purpose="after") == (("feedback_after_deg", "deg"),)
    assert recorded("cmm", "position_y_mm", purpose="check") == (("check_position_y_mm", "mm"),)
    assert recorded("cmm", "position_z_mm", purpose="after") == (("after_position_z_mm", "mm"),)
    assert recorded("laser_tracer", "length_mm", purpose="return") == (("return_length_mm", "mm"),)
    with pytest.raises(ValueError, match="unknown purpose"):
        recorded("encoder", "angle_deg", purpose="later")


# -- plugins: a reading outside the description is refused by the framework --------------------------

class OwnReadingTracer(Tracer):
    """A plugin tracer with its own read_values (what it returns is set per test)."""

    returned: object = None

    def read_values(self, fields=None):  # type: ignore[override]
        return self.returned


def _plugin(returned: object) -> LaserTracer:
    OwnReadingTracer.returned = returned
    return fenced("laser_tracer", "acme-own", "rtcal-acme-own", OwnReadingTracer)  # type: ignore[return-value]


@pytest.mark.parametrize("returned, message", [
    ({"length_mm": Value(0.8, "m"), "segment": Value(3, "1")}, r"length_mm in 'm'; its description says 'mm'"),
    ({"length_um": Value(800.0, "um"), "segment": Value(3, "1")}, r"not described: length_um.*missing: length_mm"),
    ({"length_mm": Value(math.nan, "mm"), "segment": Value(3, "1")}, r"length_mm is nan: not a reading"),
    ({"length_mm": 812.0, "segment": Value(3, "1")}, r"length_mm: '812.0' is not a value with its unit"),
    ({"length_mm": Value(812.0, "mm"), "segment": Value(3.5, "1")}, r"segment is 3.5: its description says a whole number"),
    ([812.0, 3], r"is not named values"),
])
def test_a_plugin_reading_outside_its_description_is_refused_in_one_line(returned, message):
    tracer = _plugin(returned)
    with pytest.raises(InstrumentFault, match=message) as caught:
        tracer.read_values()
    text = str(caught.value)
    assert "\n" not in text and text.startswith("laser_tracer: reading refused") and "model acme-own of plugin rtcal-acme-own" in text


def test_a_plugin_reading_as_described_passes_the_fence():
    tracer = _plugin({"segment": Value(4, "1"), "length_mm": Value(12.5, "mm")})
    assert tracer.read_values() == {"length_mm": Value(12.5, "mm"), "segment": Value(4.0, "1")}
    assert tracer.read_values(["length_mm"]) == {"length_mm": Value(12.5, "mm")}


def test_a_plugin_that_describes_its_readings_otherwise_is_refused_when_opened():
    closed = []

    class OtherUnits(Tracer):
        def describe(self):
            return {**describe_kind("laser_tracer"), "length_mm": Value(0.0, "m")}  # has .unit, wrong; no .name

        def close(self) -> None:
            closed.append(True)

    with pytest.raises(InstrumentFault, match="describes its readings otherwise than a laser tracer reads") as caught:
        fenced("laser_tracer", "acme-m", "rtcal-acme-m", OtherUnits)
    assert "length_mm" in str(caught.value) and closed == [True]

    class SameDescription(Tracer):
        def describe(self):
            return describe_kind("laser_tracer")

    assert fenced("laser_tracer", "acme-ok", "rtcal-acme-ok", SameDescription).describe() == describe_kind("laser_tracer")


def test_the_sample_plugin_reads_through_its_kinds_description():
    """The ACME bridge (tests/plugins/acme_bridge) has no read_values of its own: the kind's adapter reads it."""
    from drivers.addresses import parse_address
    from drivers.testing import replay

    sys.path.insert(0, str(PLUGIN))
    try:
        from rtcal_acme_bridge import AcmeBridgeTracer
    finally:
        sys.path.remove(str(PLUGIN))
    with replay([(b"REF\r\n", b"OK REF 2\r\n"), (b"LEN?\r\n", b"LEN 1500.000 2\r\n")]) as line:
        tracer = fenced("laser_tracer", "acme-bridge", "rtcal-acme-bridge",
                        lambda: AcmeBridgeTracer(parse_address("socket://bridge:4001"), 1.0))
        assert tracer.reference() == 2
        values = tracer.read_values()
    line.assert_done()
    assert values["length_mm"].value == pytest.approx(1.5e-3) and values["length_mm"].unit == "mm"
    assert values["segment"] == Value(2.0, "1")


# -- the engine stores only what a device describes ------------------------------------------------

class OneReadPlan:
    method = "test_describe"
    retake_skipped = False

    def __init__(self, fields):
        self.fields = fields
        self.policies = {"encoder": FaultPolicy(retries=0, backoff_s=0.0)}
        self.entries = [Entry(0, 0, {"plan_index": 0}, {}, "one reading")]

    def prologue(self):
        return iter(())

    def enter_group(self, entry, first):
        return iter(())

    def positions_unknown(self):
        pass

    def leave_group(self, group, segment):
        return None

    def attempt(self, entry):
        yield Read("encoder", self.fields, None, 0.0, "reading")


def test_the_engine_refuses_a_field_its_device_does_not_describe_and_publishes_the_descriptions():
    """A plan names fields; what is stored, and in which unit, is the device's description's."""
    docs: list = []
    engine = Engine({"encoder": Counter()}, VirtualClock(), None, [lambda n, d: docs.append((n, d))])
    assert engine.run(OneReadPlan(("angle_deg",))) == 1
    start = dict(docs)["start"]
    assert {(d.instrument, d.quantity, d.unit) for d in start["descriptions"]} >= {("encoder", "angle_deg", "deg")}
    readings = [r for n, d in docs if n == "readings" for r in d["readings"]]
    assert [(r.quantity, r.value, r.unit) for r in readings] == [("angle_deg", 45.0001, "deg")]
    for wrong in (("angle_rad",), ("angle_deg", "x_arcsec")):
        with pytest.raises(TypeError, match="is not in its description"):
            Engine({"encoder": Counter()}, VirtualClock(), None).run(OneReadPlan(wrong))


# -- the store -----------------------------------------------------------------------------------

def test_the_column_types_are_the_schemas_and_salvage_decodes_by_them():
    db = sqlite3.connect(":memory:")
    for statement in SCHEMA.split(";"):
        if statement.strip():
            db.execute(statement)
    declared = [(row[1], row[2]) for row in db.execute("PRAGMA table_info(readings)")][1:]
    assert declared[:-1] == list(READING_COLUMN_TYPES.items()) and tuple(READING_COLUMN_TYPES) == READING_COLUMNS
    assert declared[-1] == (CONTEXT, "TEXT"), "the method's declared context, last"
    assert {k for k, c in enumerate(READING_COLUMNS) if READING_COLUMN_TYPES[c] == "REAL"} == _REAL_COLUMNS
    assert _READING_TYPES[READING_COLUMNS.index("instrument")] == (str,)
    assert type(None) in _READING_TYPES[READING_COLUMNS.index("segment")]


@pytest.fixture(scope="module")
def abbe_run(tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("describe") / "abbe"
    assert main(["run", str(ABBE), "--out", str(run)]) == 0
    return run


def test_a_run_stores_what_each_quantity_is_and_each_start(abbe_run):
    store = RunStore.open(abbe_run)
    try:
        described = store.descriptions()
        stored = {(r.instrument, r.quantity) for r in store.readings() if r.quantity not in ("skipped", "rejected")}
        assert stored and stored <= set(described)  # every stored quantity is described
        for instrument, quantity in stored:
            d = described[(instrument, quantity)]
            assert d.unit == next(r.unit for r in store.readings(instrument, quantity))
            assert DESCRIPTIONS[d.kind][d.field].quantity(d.purpose) == quantity and d.what
        assert described[("dial_indicator_2", "y_um")].kind == "dial_indicator"
        assert described[("stage", "feedback_after_deg")].purpose == "after"
        first = min(r.attempt for r in store.readings() if r.attempt is not None)
        assert store.start_of(first) == 0 and store.start_of(None) is None
    finally:
        store.close()


def test_a_store_written_before_descriptions_still_exports_and_reads_the_same(abbe_run, tmp_path):
    old = tmp_path / "old"
    shutil.copytree(abbe_run, old)
    with sqlite3.connect(old / "run.sqlite") as db:
        db.execute("DROP TABLE descriptions")
        db.execute("DROP TABLE starts")
    new_store, old_store = RunStore.open(abbe_run), RunStore.open(old)  # opening it adds the tables, empty
    try:
        assert old_store.descriptions() == {} and old_store.start_of(5) is None
        assert set(new_store.descriptions()) <= set(old_store.described())  # the kind tables stand in
        seatings = [0.0, 7.5, 15.0, 22.5, 30.0]
        a, b = abbe_visits(new_store, seatings), abbe_visits(old_store, seatings)
        for name in ("encoder_deg", "autocollimator_arcsec", "indicator1_um", "commanded_deg"):
            assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True)
        assert np.isfinite(a.encoder_deg).all()
    finally:
        new_store.close()
        old_store.close()
    assert main(["export", str(old), "--out", str(tmp_path / "csv")]) == 0
    with (tmp_path / "csv" / "descriptions.csv").open() as fh:  # what each exported quantity is, from the kind tables
        rows = {(r["instrument"], r["quantity"]): r for r in csv.DictReader(fh)}
    assert rows[("encoder", "angle_deg")]["unit"] == "deg" and rows[("stage", "feedback_after_deg")]["purpose"] == "after"
    assert ("encoder", "check_angle_deg") not in rows  # only what the store holds
