"""Issue 40 item 6: a run on rtcal's simulators, or rehearsed, is never taken for a calibration. Every
protocol simulator says SIMULATED in its identity reply (within its product's reply format), the drivers
record it, and the run says so on every page of its certificate, in results.json and on the console;
`catalog add` refuses it (the in-process demonstration too) unless --allow-simulated, and then every listing
marks it."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import pytest
import yaml

from drivers.factory import open_instrument, open_stage
from drivers.interfaces import SIMULATED_MARK
from rtcal.cli import main
from rtcal.results import SCHEMA_VERSION
from simulators.scenario_file import load_scenario
from rtcal.run.runner import run_procedure
from simulators.servers.hub import SimulatorHub

REPO = Path(__file__).resolve().parents[1]
ISO = REPO / "procedures" / "iso230_2_verification.yaml"
BENCH = REPO / "procedures" / "scenarios" / "abbe_bench.yaml"
KINDS = {"cmm": "cmm", "laser_tracer": "laser_tracer", "encoder": "encoder", "autocollimator": "autocollimator",
         "dial_indicator_1": "dial_indicator", "environment": "environment"}


def _scenario():
    return load_scenario(BENCH, BENCH.read_text(encoding="utf-8"))


def _fast_iso(tmp_path: Path, seatings: list[float] | None = None) -> Path:
    data = yaml.safe_load(ISO.read_text(encoding="utf-8"))
    data.pop("bench", None)
    data["settle_time_s"] = 0.01
    data["steps"]["runs"] = 2
    if seatings is not None:
        data["polygon"]["seatings_deg"] = seatings
    path = tmp_path / "iso_fast.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True), encoding="utf-8")
    return path


@pytest.mark.parametrize("stage_model", ["oriental-az", "pi-gcs"])
def test_every_protocol_simulator_says_so_in_its_identity_reply(stage_model):
    with SimulatorHub(_scenario(), seed=1, serial="tcp", stage_model=stage_model) as hub:
        stage = open_stage(hub.addresses["stage"], (-360.0, 360.0), 2.0)
        said = {"stage": stage.identity()}
        stage.close()
        if stage_model == "oriental-az":
            for name, kind in KINDS.items():
                device = open_instrument(kind, hub.addresses[name], 2.0, **({"name": name} if kind == "dial_indicator" else {}))
                said[name] = device.identity()
                device.close()
    missing = {k: v for k, v in said.items() if SIMULATED_MARK not in v}
    assert not missing, missing


def test_a_products_own_identity_is_not_taken_for_a_simulator():
    from tests import emulators as emu
    from tests.emulators import Emulator

    for kind, answer, terminator, extra in (("autocollimator", emu.elcomat, b"\n", "?model=elcomat"),
                                            ("dial_indicator", emu.sylvac, b"\r", "?model=sylvac"),
                                            ("encoder", emu.qsb, b"\n", "?model=qsb")):
        with Emulator(answer, terminator) as device:
            inst = open_instrument(kind, device.url() + extra, 2.0, **({"name": "dial_indicator_1"}
                                                                       if kind == "dial_indicator" else {}))
            assert SIMULATED_MARK not in inst.identity()
            inst.close()


class AutoConfirm:
    """A remote person who confirms every operator step as soon as it waits (a --live run's Done)."""

    remote_operator = True

    def __call__(self, engine, run_dir):
        stop = threading.Event()

        def confirm() -> None:
            while not stop.is_set():
                try:
                    engine.request_confirm()
                except Exception:  # noqa: BLE001 — nothing waits yet
                    pass
                time.sleep(0.02)

        threading.Thread(target=confirm, daemon=True).start()
        return stop.set


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    """A rehearsal on the simulators, a plain run on them through the command line (its console), and the
    in-process demonstration."""
    base = tmp_path_factory.mktemp("simulated")
    out = {"rehearsal": base / "rehearsal", "wired": base / "wired", "in_process": base / "in_process"}
    with SimulatorHub(_scenario(), seed=1) as hub:
        run_procedure(_fast_iso(base, [0, 7.5]), out_dir=out["rehearsal"], show_progress=False,
                      addresses=dict(hub.addresses), virtual_clock=True, rehearse=True, on_engine=AutoConfirm())
        mp = pytest.MonkeyPatch()
        try:
            import io
            import sys

            console = io.StringIO()
            mp.setattr(sys, "stdout", console)
            assert main(["run", str(_fast_iso(base)), "--instruments", json.dumps(dict(hub.addresses)), "--virtual-clock",
                         "--out", str(out["wired"])]) == 0
        finally:
            mp.undo()
        (base / "wired.console").write_text(console.getvalue())
    assert main(["run", str(ISO), "--virtual-clock", "--out", str(out["in_process"])]) == 0
    return {**out, "base": base}


def test_results_json_says_which_instruments_answered_from_simulators_and_that_it_was_rehearsed(runs):
    data = json.loads((runs["rehearsal"] / "results.json").read_text())
    assert data["schema_version"] == SCHEMA_VERSION
    sim = data["simulation"]
    assert sim["rehearsed"] is True and sim["in_process"] is False
    assert {"stage", "encoder", "autocollimator", "dial_indicator_1", "dial_indicator_2", "operator"} <= set(sim["simulators"])
    assert all(SIMULATED_MARK in v for k, v in sim["simulators"].items() if k != "operator")
    assert sim["statement"].startswith("SIMULATED AND REHEARSED — NOT A CALIBRATION")
    wired = json.loads((runs["wired"] / "results.json").read_text())["simulation"]
    assert wired["rehearsed"] is False and "stage" in wired["simulators"]
    assert wired["statement"].startswith("SIMULATED — NOT A CALIBRATION")
    assert json.loads((runs["in_process"] / "results.json").read_text())["simulation"]["in_process"] is True


@pytest.mark.parametrize("which", ["rehearsal", "wired", "in_process"])
def test_every_page_of_the_certificate_says_so(runs, which):
    import pymupdf as fitz

    statement = json.loads((runs[which] / "results.json").read_text())["simulation"]["statement"]
    with fitz.open(runs[which] / "report.pdf") as pdf:
        pages = [" ".join(page.get_text().split()) for page in pdf]
    assert len(pages) > 1 and all("NOT A CALIBRATION" in page for page in pages), [p[:80] for p in pages]
    assert statement[:100] in pages[0]  # page 1 says why, whole
    html = (runs[which] / "report.html").read_text()
    assert statement in html and "@top-center" in html  # every printed page's head
    assert statement in (runs[which] / "report.md").read_text().splitlines()[2]
    certificate = json.loads((runs[which] / "certificate.json").read_text())
    assert certificate["header"]["marking"] == statement


def test_the_console_says_so(runs):
    console = (runs["base"] / "wired.console").read_text()
    assert "SIMULATED — NOT A CALIBRATION" in console and "answered from rtcal's simulators" in console


def test_catalog_add_refuses_a_simulated_run_unless_allowed_and_every_listing_then_says_so(runs, tmp_path, capsys):
    from rtcal.catalog.page import _page

    db = str(tmp_path / "catalog.sqlite")
    for which in ("rehearsal", "wired", "in_process"):
        assert main(["catalog", "add", str(runs[which]), "--db", db]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "NOT A CALIBRATION" in err[0] and "--allow-simulated" in err[0], err
    assert not Path(db).exists() or main(["catalog", "list", "--db", db]) == 0
    capsys.readouterr()
    assert main(["catalog", "add", "--allow-simulated", str(runs["wired"]), "--db", db]) == 0
    assert "SIMULATED" in capsys.readouterr().out
    assert main(["catalog", "list", "--db", db]) == 0
    assert "SIMULATED" in capsys.readouterr().out.splitlines()[1]
    assert main(["catalog", "list", "--db", db, "--json"]) == 0
    assert "SIMULATED" in json.loads(capsys.readouterr().out)[0]["marks"]
    assert main(["catalog", "history", "--serial", "SIM-230-2", "--db", db]) == 0
    out = capsys.readouterr().out
    assert "SIMULATED" in out.splitlines()[1] and "not calibrations" in out
    assert main(["catalog", "history", "--serial", "SIM-230-2", "--db", db, "--json"]) == 0
    entry = json.loads(capsys.readouterr().out)[0]
    assert "SIMULATED" in entry["marks"] and entry["simulated"].startswith("SIMULATED")
    page = _page(db, "SIM-230-2")
    assert page.count('<td class="marks">SIMULATED') == 2  # the fleet's row and the history's


def test_a_rehearsal_nobody_can_confirm_is_refused_before_its_run_folder_is_made(tmp_path, capsys):
    """Issue 46 item 9: `--rehearse` without a terminal (pytest's stdin is none) and without --live made the run
    folder and failed at the first operator step; it is refused first (exit 2, one line), for a resume too."""
    with SimulatorHub(_scenario(), seed=1) as hub:
        instruments = json.dumps(dict(hub.addresses))
        assert main(["run", str(_fast_iso(tmp_path)), "--instruments", instruments, "--virtual-clock",
                     "--out", str(tmp_path / "run"), "--rehearse"]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "--rehearse" in err and "--live" in err and "terminal" in err, err
        assert not (tmp_path / "run").exists()
        assert main(["run", str(_fast_iso(tmp_path)), "--instruments", instruments, "--virtual-clock",
                     "--out", str(tmp_path / "run")]) == 0
        before = (tmp_path / "run" / "run.sqlite").read_bytes()
        capsys.readouterr()
        assert main(["resume", str(tmp_path / "run"), "--instruments", instruments, "--rehearse"]) == 2
        assert "--live" in capsys.readouterr().err
        assert (tmp_path / "run" / "run.sqlite").read_bytes() == before
