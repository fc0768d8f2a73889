"""An instrument kind is a plugin (issue 34): the registry (drivers.kinds.KINDS) reads installed packages'
entry points in the group ``rtcal.instrument_kinds``; a kind's interface, its field descriptions and its
adapter are all rtcal needs to describe, fence, store and probe it. tests/plugins/toy_kind adds an
inclinometer, and the toy method (tests/plugins/toy_method) reads it once per visit when its procedure
names one — in this process through the registry, and installed with pip into a fresh environment
through the `rtcal` command."""

from __future__ import annotations

import math
import sqlite3
import subprocess
from importlib.metadata import EntryPoint
from pathlib import Path

import pytest

import drivers.kinds as kinds
import rtcal.methods as methods
from drivers import factory
from drivers.addresses import AddressError
from drivers.errors import InstrumentFault
from drivers.fence import fenced, refuse_unfit_class
from drivers.interfaces import FieldDescription, Instrument, RotaryStage, Value
from drivers.kinds import describe_kind, recorded
from rtcal.methods import load_procedure
from rtcal.procedure.yamlfile import FileProblems
from tests.test_plugins import venv_with_plugin

REPO = Path(__file__).resolve().parents[1]
KIND = REPO / "tests" / "plugins" / "toy_kind"
METHOD = REPO / "tests" / "plugins" / "toy_method"
BENCH = REPO / "procedures" / "scenarios" / "abbe_bench.yaml"
PROCEDURE = """\
method: encoder_vs_command
name: encoder against the command, with the table's tilt (plugins)
instruments: {stage: {backend: sim}, encoder: {backend: sim}, inclinometer: {backend: sim}}
steps: {targets_deg: [0, 90, 180, 270], runs: 1}
settle_time_s: 0.5
"""
TILT = {"tilt_x_arcsec": "arcsec", "tilt_y_arcsec": "arcsec"}


# what the registry must refuse, each for one reason (loaded by the entry points below)
class NotAnInstrument:
    kind = "not_an_instrument"
    fields = (FieldDescription("x_mm", "mm", "a length"),)


class Undescribed(Instrument):
    kind = "undescribed"
    fields = (FieldDescription("x_mm", "", "a length without a unit"),)

    def _raw_values(self, wanted: frozenset[str]) -> dict[str, Value]:
        return {"x_mm": Value(0.0, "")}


class Unadapted(Instrument):
    kind = "unadapted"
    fields = (FieldDescription("x_mm", "mm", "a length"),)


def _entry_points(*specs: tuple[str, str]) -> list[EntryPoint]:
    return [EntryPoint(name, value, kinds.ENTRY_POINT_GROUP) for name, value in specs]


@pytest.fixture
def toy_kinds(monkeypatch):
    """This process's KINDS reading the toy kind's entry point (and broken ones, and one that would replace a
    built-in) as if they were installed; as it was after the test."""
    monkeypatch.syspath_prepend(str(KIND))
    monkeypatch.setattr(kinds, "entry_points", lambda group: _entry_points(
        ("inclinometer", "rtcal_toy_kind:Inclinometer"),
        ("gyro", "rtcal_no_such_module:Gyro"),
        ("not_an_instrument", "tests.test_kind_plugin:NotAnInstrument"),
        ("undescribed", "tests.test_kind_plugin:Undescribed"),
        ("unadapted", "tests.test_kind_plugin:Unadapted"),
        ("stage", "rtcal_toy_kind:Inclinometer")) if group == kinds.ENTRY_POINT_GROUP else [])
    for attr, value in (("_plugins", None), ("_names", None), ("broken", {})):
        monkeypatch.setattr(kinds.KINDS, attr, value)  # read again, through the entry points above
    return kinds.KINDS


@pytest.fixture
def toy_method(monkeypatch, toy_kinds):
    """The toy method registered too (tests/test_method_plugin.py's way)."""
    monkeypatch.syspath_prepend(str(METHOD))
    monkeypatch.setattr(methods, "entry_points", lambda group: [EntryPoint(
        "encoder_vs_command", "rtcal_toy_method:EncoderVsCommandMethod", group)] if group == methods.ENTRY_POINT_GROUP else [])
    monkeypatch.setattr(methods.METHODS, "_plugins", None)
    monkeypatch.setattr(methods.METHODS, "broken", {})


def test_the_registry_reads_entry_points_and_names_what_it_refuses(toy_kinds):
    from rtcal_toy_kind import Inclinometer

    assert list(toy_kinds) == ["stage", "cmm", "laser_tracer", "encoder", "autocollimator", "dial_indicator", "environment",
                               "machine_tool", "inclinometer"]
    assert toy_kinds["inclinometer"].interface is Inclinometer and toy_kinds["inclinometer"].plugin == "?"
    assert toy_kinds["stage"].interface is RotaryStage, "a plugin never replaces a built-in kind"
    assert {n: f.unit for n, f in describe_kind("inclinometer").items()} == TILT
    assert recorded("inclinometer", "tilt_y_arcsec", purpose="after") == (("after_tilt_y_arcsec", "arcsec"),)
    broken = toy_kinds.broken
    assert sorted(broken) == ["gyro", "not_an_instrument", "stage", "unadapted", "undescribed"]
    assert "rtcal_no_such_module" in broken["gyro"]
    assert "NotAnInstrument is not an Instrument subclass" in broken["not_an_instrument"]
    assert "x_mm: give its unit" in broken["undescribed"] and "lacks _raw_values" in broken["unadapted"]
    assert "a built-in kind" in broken["stage"]
    assert all("\n" not in why for why in broken.values())
    # a broken kind is named where it is asked for, and never stops the others
    with pytest.raises(AddressError, match=r"instrument kind 'gyro': its plugin \?: ModuleNotFoundError.*rtcal_no_such_module"):
        factory.kind_of("gyro")
    from rtcal.run.commission import probe

    with pytest.raises(AddressError, match="Instrument subclass"):
        probe("not_an_instrument", "socket://h:1")
    assert factory.kind_of("inclinometer") == "inclinometer" and factory.kind_of("dial_indicator_2") == "dial_indicator"


def test_the_probe_commands_choices_name_installed_kinds_without_loading_them(toy_kinds):
    assert toy_kinds.names()[-6:] == ("machine_tool", "inclinometer", "gyro", "not_an_instrument", "undescribed", "unadapted")
    assert toy_kinds._plugins is None, "listing the names loads no plugin"


def test_a_malformed_field_is_refused_in_one_line():
    def refused(*fields: object) -> str:
        interface = type("Level", (Instrument,), {"kind": "level", "fields": fields,
                                                  "_raw_values": lambda self, wanted: {}})
        with pytest.raises((TypeError, ValueError)) as caught:
            kinds.kind_from("level", interface, "rtcal-level")
        return str(caught.value)

    assert "no `fields`" in refused()
    assert "not a FieldDescription" in refused(("tilt", "arcsec"))
    assert "not an identifier" in refused(FieldDescription("tilt x", "arcsec", "tilt"))
    assert "physical_range" in refused(FieldDescription("tilt", "arcsec", "tilt", physical_range=(1.0, -1.0)))
    assert "stored twice" in refused(FieldDescription("a", "1", "a"), FieldDescription("a", "1", "again"))
    assert "marker" in refused(FieldDescription("skipped", "1", "a marker's name"))
    good = kinds.kind_from("level", type("Level", (Instrument,), {"kind": "level", "fields": (
        FieldDescription("tilt", "arcsec", "tilt"),), "_raw_values": lambda self, wanted: {}}), "rtcal-level")
    assert list(good.fields) == ["tilt"]


def _level_driver(reading: object) -> type:
    """A driver class of the toy kind whose level reads ``reading``."""
    from rtcal_toy_kind import Inclinometer

    class Level(Inclinometer):
        name = "inclinometer"

        def read_tilt_arcsec(self):
            return reading

    return Level


@pytest.mark.parametrize("reading, refused", [
    ((50_000.0, 0.0), r"tilt_x_arcsec 50000 arcsec is outside what an inclinometer can read \(-36000 … 36000 arcsec\)"),
    ((0.0, math.inf), "tilt_y_arcsec is inf: not a reading"),
    (("1.5", 0.0), "tilt_x_arcsec: '1.5' is not a number"),
    (None, "its inclinometer's reading raised TypeError"),
])
def test_the_fence_refuses_a_reading_outside_the_kinds_description(toy_kinds, reading, refused):
    from rtcal_toy_kind import Inclinometer

    level = fenced("inclinometer", "toy-level", "rtcal-toy-level", _level_driver(reading))
    assert isinstance(level, Inclinometer) and level.describe() == describe_kind("inclinometer")
    assert level.read_tilt_arcsec() == reading, "its own read method reaches the driver"
    with pytest.raises(InstrumentFault, match=refused) as caught:
        level.read_values()
    assert "model toy-level of plugin rtcal-toy-level" in str(caught.value)


def test_the_fence_passes_a_good_reading_and_refuses_a_driver_of_another_kind(toy_kinds):
    level = fenced("inclinometer", "toy-level", "rtcal-toy-level", _level_driver((1.5, -0.8)))
    assert level.read_values() == {"tilt_x_arcsec": Value(1.5, "arcsec"), "tilt_y_arcsec": Value(-0.8, "arcsec")}

    class OwnUnits(_level_driver((1.5, -0.8))):  # type: ignore[misc]
        def read_values(self, fields=None):
            return {"tilt_x_arcsec": Value(1.5, "deg"), "tilt_y_arcsec": Value(-0.8, "arcsec")}

    with pytest.raises(InstrumentFault, match="tilt_x_arcsec in 'deg'; its description says 'arcsec'"):
        fenced("inclinometer", "toy-level", "rtcal-toy-level", OwnUnits).read_values()

    class Failing(_level_driver((1.5, -0.8))):  # type: ignore[misc]
        def read_tilt_arcsec(self, averaged: int = 1):
            raise RuntimeError(f"no level on the bus ({averaged} samples)")

    with pytest.raises(InstrumentFault, match=r"model toy-level of plugin rtcal-toy-level: read_tilt_arcsec raised "
                                              r"RuntimeError: no level on the bus \(4 samples\)"):
        fenced("inclinometer", "toy-level", "rtcal-toy-level", Failing).read_tilt_arcsec(averaged=4)
    with pytest.raises(AddressError, match="is not a Inclinometer .* it lacks read_tilt_arcsec"):
        refuse_unfit_class("inclinometer", "toy-level", "rtcal-toy-level", "x:Level", type("Level", (), {}))


def test_probe_reads_an_installed_kinds_instrument_through_its_installed_model(toy_kinds, monkeypatch):
    """`rtcal probe inclinometer ADDRESS` as the command calls it: the kind's one installed model (a driver of
    another package, rtcal.drivers) is opened inside the fence, identified and read by its description."""
    import sys

    import drivers.models as models
    from rtcal.run.commission import probe

    class ConstantLevel(_level_driver((1.5, -0.8))):  # type: ignore[misc]
        def __init__(self, address, timeout_s, **context):
            self.address = address

        def identity(self):
            return "toy level 1"

    monkeypatch.setattr(sys.modules[__name__], "ConstantLevel", ConstantLevel, raising=False)
    level = models.Model("toy-level", "inclinometer", f"{__name__}:ConstantLevel", ("serial",), plugin="rtcal-toy-level")
    monkeypatch.setattr(models.MODELS, "_plugins", {"toy-level": level})
    for address in ("socket://bench:4001", "socket://bench:4001?model=toy-level"):
        result = probe("inclinometer", address)
        assert (result.model, result.identity, result.reading) == (
            "toy-level", "toy level 1", {"tilt_x_arcsec": 1.5, "tilt_y_arcsec": -0.8})
    monkeypatch.setattr(models.MODELS, "_plugins", {})
    with pytest.raises(AddressError, match="an inclinometer has no built-in model: name its model with model= "
                                           r"\(none is installed\)"):
        probe("inclinometer", "socket://bench:4001")


def test_a_procedure_names_the_inclinometer_only_where_its_kind_is_installed(toy_method, monkeypatch, tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text(PROCEDURE)
    assert load_procedure(path).instruments.inclinometer is not None
    monkeypatch.setattr(kinds, "entry_points", lambda group: [])
    monkeypatch.setattr(kinds.KINDS, "_plugins", None)
    with pytest.raises(FileProblems, match=r"unknown kind 'inclinometer' \(known: stage, .*\); install rtcal-toy-kind"):
        load_procedure(path)


def _check_store(run_dir: Path) -> None:
    """The run's store holds the inclinometer's readings, once per visit, under its described quantities and
    units, and its descriptions rows; the simulated table's tilt turns with the table."""
    with sqlite3.connect(run_dir / "run.sqlite") as db:
        rows = db.execute("SELECT quantity, unit, commanded_angle_deg, value FROM readings WHERE instrument = "
                          "'inclinometer' ORDER BY id").fetchall()
        described = db.execute("SELECT kind, quantity, field, purpose, unit, what FROM descriptions "
                               "WHERE instrument = 'inclinometer' AND purpose = ''").fetchall()
        visits = db.execute("SELECT count(*) FROM readings WHERE instrument = 'encoder'").fetchone()[0]
    assert {(q, u) for q, u, _, _ in rows} == set(TILT.items()) and len(rows) == 2 * visits == 16
    assert sorted((k, q, f, u) for k, q, f, _, u, _ in described) == [
        ("inclinometer", q, q, u) for q, u in sorted(TILT.items())]
    assert all("tilt" in what for *_, what in described)
    y = {a: v for q, _, a, v in rows if q == "tilt_y_arcsec"}
    assert abs(y[90.0] - y[0.0]) > 2.0, "the level on the table sees the axis's tilt turn with it"


def test_a_run_stores_the_plugin_kinds_readings_in_process(toy_method, tmp_path):
    from rtcal.run.runner import run_procedure

    (tmp_path / "p.yaml").write_text(PROCEDURE)
    run_procedure(tmp_path / "p.yaml", BENCH, out_dir=tmp_path / "run", show_progress=False)
    _check_store(tmp_path / "run")


def test_installed_kind_and_method_plugins_run_with_the_inclinometer(tmp_path):
    """A fresh venv that sees rtcal but not this process; the toy kind and the toy method installed into it with
    pip; there `rtcal run` reads the inclinometer and `rtcal probe` knows the kind (it has no model installed)."""
    python = venv_with_plugin(KIND, tmp_path, METHOD)
    (tmp_path / "p.yaml").write_text(PROCEDURE)

    def rtcal(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([str(python), "-m", "rtcal.cli", *args], capture_output=True, text=True, timeout=300,
                              cwd=tmp_path)

    run = rtcal("run", str(tmp_path / "p.yaml"), "--scenario", str(BENCH), "--out", str(tmp_path / "run"))
    assert run.returncode == 0, run.stderr
    _check_store(tmp_path / "run")
    probe = rtcal("probe", "inclinometer", "socket://localhost:1")
    assert probe.returncode == 2 and probe.stderr.strip() == (
        "rtcal: an inclinometer has no built-in model: name its model with model= (none is installed)"), probe.stderr
