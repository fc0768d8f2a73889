"""Compensation formats as one class each, in one registry: a plugin's format (the sample
package tests/plugins/toy_format) is found through the entry-point group
``rtcal.compensation_formats``, checked, offered with its options, and — installed into a fresh
environment — writes a table from a run that the simulated controller loads and applies, with no
change to rtcal's files."""

from __future__ import annotations

import json
import subprocess
import sys
from importlib.metadata import EntryPoint
from pathlib import Path

import numpy as np
import pytest

from rtcal.compensation import CompensationError, CompensationFormat, FormatOption, registry
from rtcal.deliverables.compensation import PARSERS, table_from_deviations, write_table
from rtcal.deliverables.deviations import PositioningDeviations
from tests.compensation_loop import AFTER_SEED, ISO, load_table, run
from tests.test_plugins import venv_with_plugin

REPO = Path(__file__).resolve().parents[1]
PLUGIN = REPO / "tests" / "plugins" / "toy_format"


def _deviations() -> PositioningDeviations:
    """Two directions, three runs, 12 targets: a once-per-turn error, a 6″ reversal and some scatter."""
    rng = np.random.default_rng(5)
    rows = [(t, d, r, 20 * np.sin(np.radians(t)) + (-3 if d < 0 else 3) + rng.normal(0, 0.3))
            for t in np.arange(0.0, 360.0, 30.0) for d in (1, -1) for r in (1, 2, 3)]
    target, direction, run_no, dev = (np.array(c) for c in zip(*rows))
    return PositioningDeviations(target, direction.astype(int), run_no.astype(int), dev, np.zeros(len(dev)))


class _Wrong(CompensationFormat):
    """A plugin format whose --axis means something else than the built-ins' (an integer)."""

    name = "wrong-axis"
    max_points = 10
    options = (FormatOption("axis_number", "--axis", "axis number", type=int),)

    def write(self, table, axis_number: int = 1) -> str:
        return ""

    def parse(self, text, where=""):
        raise CompensationError(where)


@pytest.fixture
def toy_registered(monkeypatch):
    """The registry as this process would see it with the sample plugin (and three broken ones) installed."""
    monkeypatch.syspath_prepend(str(PLUGIN))
    sys.modules["rtcal_toy_broken"] = type(sys)("rtcal_toy_broken")
    sys.modules["rtcal_toy_broken"].Wrong = _Wrong  # type: ignore[attr-defined]
    eps = [EntryPoint("toy-csv", "rtcal_toy_format:ToyCsvFormat", registry.ENTRY_POINT_GROUP),
           EntryPoint("wrong-axis", "rtcal_toy_broken:Wrong", registry.ENTRY_POINT_GROUP),
           EntryPoint("misnamed", "rtcal_toy_format:ToyCsvFormat", registry.ENTRY_POINT_GROUP),
           EntryPoint("missing", "rtcal_toy_nowhere:Format", registry.ENTRY_POINT_GROUP),
           EntryPoint("fanuc", "rtcal_toy_format:ToyCsvFormat", registry.ENTRY_POINT_GROUP)]
    monkeypatch.setattr(registry, "entry_points", lambda group: [e for e in eps if e.group == group])
    monkeypatch.setattr(registry.FORMATS, "_plugins", None)  # read again, through the entry points above
    monkeypatch.setattr(registry.FORMATS, "broken", {})
    yield
    sys.modules.pop("rtcal_toy_broken", None)
    sys.modules.pop("rtcal_toy_format", None)


def test_builtins_are_the_registry():
    assert registry.format_names() == ("linuxcnc", "siemens-lec", "siemens-cec", "fanuc", "heidenhain", "isg-volcomp")
    assert list(PARSERS) == list(registry.format_names())
    flags = {o.flag: o for o in registry.cli_options()}
    assert list(flags) == ["--range-deg", "--axis", "--reference-deg", "--max-points", "--table-index", "--cec-tables",
                           "--detection-unit-deg", "--first-point", "--series", "--reference-return", "--axis-number",
                           "--listing", "--generation", "--error-motions-from", "--location-from"]
    assert flags["--axis"].formats == ("siemens-lec", "siemens-cec", "heidenhain")
    assert flags["--reference-deg"].formats == ("siemens-lec", "siemens-cec", "heidenhain")
    assert "fanuc (required: 0.001 for IS-B, 0.0001 for IS-C)" in flags["--detection-unit-deg"].help
    assert flags["--listing"].argparse_kwargs()["action"] == "store_const"  # a switch: no value
    assert "siemens-lec/siemens-cec (default C1), heidenhain (default C)" in flags["--axis"].help
    given = registry.options_given({"range_deg": [-10.0, 350.0], "axis": None, "detection_unit_deg": 0.001, "format": "x",
                                    "listing": True})
    assert given == {"range_deg": (-10.0, 350.0), "unit_deg": 0.001, "listing": True}
    with pytest.raises(CompensationError, match="unknown format 'okuma'; one of linuxcnc, siemens-lec"):
        registry.get_format("okuma")


def test_a_plugin_format_is_registered_checked_and_offered(toy_registered):
    names = registry.format_names()
    assert names == ("linuxcnc", "siemens-lec", "siemens-cec", "fanuc", "heidenhain", "isg-volcomp", "toy-csv")
    assert type(registry.get_format("fanuc")).__module__ == "rtcal.compensation.fanuc"  # a built-in is never replaced
    for name, why in (("wrong-axis", "--axis means something else"), ("misnamed", "the format 'toy-csv'"),
                      ("missing", "No module named 'rtcal_toy_nowhere'")):
        with pytest.raises(CompensationError, match=f"format '{name}': plugin .*{why}"):
            registry.get_format(name)
    toy = {o.flag: o for o in registry.cli_options()}["--trim-decimals"]
    assert toy.formats == ("toy-csv",) and toy.dest == "trim_decimals" and toy.argparse_kwargs()["type"] is int

    comp = table_from_deviations(_deviations())
    text = write_table("toy-csv", comp, trim_decimals=2)
    assert text.splitlines()[0] == "position_deg,trim_up_arcsec,trim_down_arcsec" and len(text.splitlines()) == 14
    back = registry.get_format("toy-csv").load(text, "t.csv")
    np.testing.assert_allclose(back.positions_deg, comp.positions_deg)
    np.testing.assert_allclose(back.trim_up_deg * 3600, comp.trim_up_deg * 3600, atol=0.005)
    np.testing.assert_allclose(back.trim_down_deg * 3600, comp.trim_down_deg * 3600, atol=0.005)
    assert back.modulo and back.trim_deg(390.0, -1) == pytest.approx(back.trim_deg(30.0, -1))
    with pytest.raises(CompensationError, match="toy-csv takes no --axis"):
        write_table("toy-csv", comp, axis="C")
    with pytest.raises(CompensationError, match="fanuc takes no --trim-decimals"):
        write_table("fanuc", comp, trim_decimals=1)
    with pytest.raises(CompensationError, match="t.csv:3: expected three finite numbers"):
        PARSERS["toy-csv"](text.replace(text.splitlines()[2], "30,1"), "t.csv")

    from simulators.scenario import CompensationScenario, Scenario

    assert CompensationScenario(format="toy-csv", text=text).format == "toy-csv"
    schema = Scenario.model_json_schema()["$defs"]["CompensationScenario"]["properties"]["format"]
    assert schema["enum"][-1] == "toy-csv"
    with pytest.raises(ValueError, match="Input should be 'linuxcnc', .* 'isg-volcomp' or 'toy-csv'"):
        CompensationScenario(format="missing", text=text)


@pytest.fixture(scope="module")
def toy_venv(tmp_path_factory):
    """A fresh venv that sees rtcal (and its dependencies) but not this test's process, with the
    sample plugin installed by pip from a wheel of tests/plugins/toy_format; and a calibration run
    (the shipped ISO 230-2 test on its bench) made in this process, where no plugin is installed."""
    tmp = tmp_path_factory.mktemp("toy")
    python = venv_with_plugin(PLUGIN, tmp)
    before = run(ISO, tmp / "calibration")
    return python, tmp, before


@pytest.mark.slow
def test_an_installed_format_writes_a_table_the_simulated_controller_applies(toy_venv):
    """In the fresh venv: the table written in toy-csv from the calibration run (through the
    package: the registry's write_table), named by a scenario's stage.compensation, loaded by the
    simulated controller: the test again with another seed shows the error reduced."""
    python, tmp, before = toy_venv
    with pytest.raises(CompensationError, match="unknown format 'toy-csv'"):  # this process has no such plugin
        registry.get_format("toy-csv")
    write = ("import sys\nfrom rtcal.methods import read_results\n"
             "from rtcal.deliverables.deviations import PositioningDeviations\n"
             "from rtcal.deliverables.compensation import table_from_deviations, write_table\n"
             "r = read_results(sys.argv[1]); t = PositioningDeviations.from_model(r.positioning_deviations, sys.argv[1])\n"
             "open(sys.argv[2], 'w').write(write_table('toy-csv', table_from_deviations(t)))\n")
    table = tmp / "api.csv"
    done = subprocess.run([str(python), "-c", write, str(tmp / "calibration"), str(table)], capture_output=True, text=True,
                          timeout=60, cwd=tmp)
    assert done.returncode == 0, done.stderr
    assert table.read_text().startswith("position_deg,trim_up_arcsec,trim_down_arcsec\n0.000000,")
    schema = subprocess.run([str(python), "-m", "rtcal.cli", "schema", "--scenario"], capture_output=True, text=True,
                            timeout=60, cwd=tmp)
    assert schema.returncode == 0 and '"toy-csv"' in schema.stdout, schema.stderr
    bench = load_table(table, "toy-csv")
    after = subprocess.run([str(python), "-m", "rtcal.cli", "run", str(ISO), "--scenario", str(bench), "--seed",
                            str(AFTER_SEED), "--out", str(tmp / "after")], capture_output=True, text=True, timeout=300, cwd=tmp)
    assert after.returncode == 0, after.stderr
    results = json.loads((tmp / "after" / "results.json").read_text())
    assert results["evaluation"]["iso230_2"]["E"] < before["E"] / 4, (before["E"], results["evaluation"]["iso230_2"]["E"])


@pytest.mark.slow
def test_rtcal_compensate_writes_an_installed_format(toy_venv):
    """`rtcal compensate RUN --format toy-csv --trim-decimals 2` in the fresh venv: the plugin's
    format and its option flag on the command line."""
    python, tmp, _ = toy_venv
    out = tmp / "cli.csv"
    done = subprocess.run([str(python), "-m", "rtcal.cli", "compensate", str(tmp / "calibration"), "--format", "toy-csv",
                           "--trim-decimals", "2", "--out", str(out)], capture_output=True, text=True, timeout=60, cwd=tmp)
    assert done.returncode == 0, done.stderr
    assert "toy-csv table written to" in done.stdout
    rows = out.read_text().splitlines()
    assert rows[0] == "position_deg,trim_up_arcsec,trim_down_arcsec"
    assert all(len(r.split(",")[1].split(".")[1]) == 2 for r in rows[1:]), rows[:3]
