"""Issue 46 items 5, 6, 9: the live page says what the certificate says and what the run does.

- the result in the certificate's own words and rounded numbers (its result in brief, conformity and
  departures; not a figure of its own: 0.60″ against 0.61″, "not an ISO 230-2 result" dropped);
- a run on simulators, or rehearsed, marked at the top of the page in the certificate's words;
- Abort said as what it does (at once, each machine watched until seen at rest), then each stop as seen;
- the time left counted down between readings, its end as a clock time, the solving it holds, and on a
  virtual clock said to be the virtual clock's;
- the progress grid's column labels over their columns (they were half a column to the right)."""

from __future__ import annotations

import datetime as dt
import json
import shutil
import time
from pathlib import Path

import pytest
import yaml

from rtcal.live.server import LiveServer
from rtcal.live.storeview import StoreView
from rtcal.run.runner import run_procedure
from rtcal.store.runstore import RunStore

REPO = Path(__file__).resolve().parents[1]
ISO = REPO / "procedures" / "iso230_2_polygon.yaml"
BENCH = REPO / "procedures" / "scenarios" / "abbe_bench.yaml"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason="no chromium installed (Debian: apt-get install chromium)")


def _two_runs(tmp_path: Path) -> Path:
    """The shipped ISO test with 2 runs a direction: a departure from ISO 230-2 (it asks 5)."""
    data = yaml.safe_load(ISO.read_text(encoding="utf-8"))
    data.pop("bench")
    data["steps"]["runs"] = 2
    path = tmp_path / "iso2.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True), encoding="utf-8")
    return path


def _browser(p):
    return p.chromium.launch(executable_path=CHROMIUM, args=["--headless", "--no-sandbox", "--disable-gpu",
                                                             "--disable-background-networking"])


def _store(where: Path, meta: dict[str, str]) -> None:
    where.mkdir()
    RunStore.create(where, meta).close()


def test_the_time_left_counts_down_with_its_end_and_says_its_clock(tmp_path):
    """Between readings the page's time left stood still; it now counts down from when the run estimated it
    (a real clock, nothing waiting), gives the end as a time, the solving it holds, and says a virtual clock."""
    now = time.time()
    _store(tmp_path / "real", {"method": "test", "engine_state": "running", "planned_readings": "10", "clock": "real",
                               "eta_s": "100.0", "eta_at": json.dumps({"t_s": 5.0, "utc": now - 30.0, "after_s": 12.0})})
    state = StoreView(tmp_path / "real", 0.0).state()
    assert 69.0 <= state["eta_s"] <= 71.0 and state["clock"] == "real" and state["solving_s"] == 12.0
    end = dt.datetime.fromisoformat(state["ends_utc"]).timestamp()
    assert abs(end - (now + 70.0)) <= 2.0
    started = "2026-03-02T08:00:00+00:00"
    _store(tmp_path / "virtual", {"method": "test", "engine_state": "running", "planned_readings": "10", "clock": "virtual",
                                  "eta_s": "3600.0", "started_utc": started,
                                  "eta_at": json.dumps({"t_s": 1800.0, "utc": now - 30.0, "after_s": 0.0})})
    state = StoreView(tmp_path / "virtual", 0.0).state()
    assert state["eta_s"] == 3600.0 and state["clock"] == "virtual"  # no wall-clock countdown of the bench's time
    assert state["ends_utc"] == "2026-03-02T09:30:00+00:00"  # its start, the virtual time then, the time left


def test_a_rehearsal_and_a_run_on_simulators_are_marked_in_the_certificates_words(tmp_path):
    from rtcal.run.runner import simulation_statement

    meta = {"method": "test", "engine_state": "running", "operator_address": "sim-operator://127.0.0.1:9?token=x",
            "simulators": json.dumps({"stage": "rtcal SIMULATED drive"}), "rehearsed": "1"}
    _store(tmp_path / "rehearsal", meta)
    marking = StoreView(tmp_path / "rehearsal", 0.0).state()["marking"]
    assert marking == simulation_statement(False, ["operator", "stage"], True)
    assert marking.startswith("SIMULATED AND REHEARSED — NOT A CALIBRATION")
    _store(tmp_path / "real", {"method": "test", "engine_state": "running"})
    assert StoreView(tmp_path / "real", 0.0).state()["marking"] == ""


@needs_chromium
def test_the_finished_page_states_the_certificates_result(tmp_path):
    """A run that departs from ISO 230-2 (2 runs a direction): the headline and the result in brief are the
    certificate's strings (certificate.json, written by the run), "not an ISO 230-2 result" included; the
    marking is the certificate's; the grid's column labels are centred over their cells."""
    sync_api = pytest.importorskip("playwright.sync_api")
    run_procedure(_two_runs(tmp_path), BENCH, out_dir=tmp_path / "run", show_progress=False)
    certificate = json.loads((tmp_path / "run" / "certificate.json").read_text(encoding="utf-8"))
    rows = certificate["result_in_brief"]["rows"]
    e_row = next(r for r in rows if r["quantity"].startswith("E:"))
    with LiveServer(tmp_path / "run", "127.0.0.1", 0) as server, sync_api.sync_playwright() as p:
        browser = _browser(p)
        try:
            page = browser.new_page(viewport={"width": 1300, "height": 1000})
            page.goto(server.url)
            page.wait_for_selector("#result-card:not([hidden])", timeout=60000)
            page.wait_for_selector("#result-brief table")
            headline = page.inner_text("#result-headline")
            assert f"E = {e_row['value_arcsec']} ({e_row['expanded_uncertainty_arcsec']}, k = 2)" in headline, headline
            assert "not an ISO 230-2 result" in headline and certificate["conformity"]["verdict"].upper() in headline
            assert "2 runs per target and direction (ISO 230-2 asks 5)" in page.inner_text("#result-departures")
            shown = page.eval_on_selector_all("#result-brief tbody tr", "trs => trs.map(r => [...r.cells].map(c => c.textContent))")
            assert shown == [[r["quantity"], r["value_arcsec"], r["expanded_uncertainty_arcsec"]] for r in rows]
            conformity = page.eval_on_selector_all("#result-conformity tbody tr", "trs => trs.map(r => r.cells[3].textContent)")
            assert conformity == [r["value_arcsec"] for r in certificate["conformity"]["rows"]]
            assert page.inner_text("#marking") == certificate["header"]["marking"] != ""
            offsets = page.evaluate("""() => {
                const table = document.querySelector("#grid table");
                const heads = [...table.tHead.rows[0].cells].slice(1);
                const cells = [...table.tBodies[0].rows[0].cells].slice(1);
                const centre = (r) => (r.left + r.right) / 2;
                const text = (node) => { const range = document.createRange(); range.selectNodeContents(node);
                                         return range.getBoundingClientRect(); };
                return heads.map((th, i) => centre(text(th)) - centre(
                    (cells[i].querySelector(".cell") || cells[i]) === cells[i] ? text(cells[i])
                        : cells[i].querySelector(".cell").getBoundingClientRect()));
            }""")
            # each target's label over its cells (was 17–20 px to the right), "done" over its counts (was 30 px left)
            assert len(offsets) == 13 and max(abs(x) for x in offsets) <= 3.0, offsets
            page.evaluate("""() => renderEta({state: "running", eta_s: 5400, clock: "virtual",
                ends_utc: "2026-03-02T09:30:00+00:00", operator: null, solving_s: null})""")
            assert "on the virtual clock" in page.inner_text("#eta") and "virtual" in page.inner_text("#eta-note")
        finally:
            browser.close()


@needs_chromium
def test_abort_from_the_page_says_it_stops_at_once_and_then_where_each_machine_was_seen_at_rest(tmp_path):
    """A wired run in real time, watched in Chromium: marked as simulated, its time left with its end and the
    solving it holds; the page's Abort is said as what it does, and once the engine has watched the stage
    to rest the page says where (the engine's `stopped` event), not "at the next checkpoint"."""
    sync_api = pytest.importorskip("playwright.sync_api")
    from simulators.servers.hub import SimulatorHub
    from tests.test_live_run import _scenario, fast_iso, start_run

    procedure = fast_iso(tmp_path, settle_s=0.3, runs=2)
    with SimulatorHub(_scenario(tmp_path, "none"), seed=1) as hub:
        proc, seen = start_run("run", str(procedure), "--instruments", json.dumps(dict(hub.addresses)), "--out",
                               str(tmp_path / "run"), "--live", "127.0.0.1:0")
        try:
            with sync_api.sync_playwright() as p:
                browser = _browser(p)
                page = browser.new_page(viewport={"width": 1300, "height": 1000})
                page.goto(seen["live view"] + "#token=" + seen["control token"])
                deadline = time.monotonic() + 60
                while "ends about" not in page.inner_text("#eta") and time.monotonic() < deadline:
                    time.sleep(0.2)
                assert "ends about" in page.inner_text("#eta")
                assert "to solve and write the results" in page.inner_text("#eta-note")
                assert page.inner_text("#marking").startswith("SIMULATED — NOT A CALIBRATION")
                help_text = page.inner_text("#control-help")
                assert "Abort stops it at once" in help_text and "seen at rest" in help_text
                page.click("#btn-abort")
                page.click("#btn-abort")  # armed, then confirmed
                deadline = time.monotonic() + 60
                while not page.inner_text("#control-msg").startswith("aborted") and time.monotonic() < deadline:
                    time.sleep(0.1)
                message = page.inner_text("#control-msg")
                assert message.startswith("aborted: stage stopped: seen at rest at "), message
                assert "next checkpoint" not in message
                browser.close()
        finally:
            out, err = proc.communicate(timeout=120)
        assert proc.returncode == 130 and "aborted by the live page" in err
