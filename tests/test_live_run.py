"""A wired ISO 230-2 run in real time, watched and controlled as a user would: `rtcal run --live` over the
protocols of `rtcal sim serve`, the page in headless Chromium (progress rising, Pause holding the run, Resume
finishing it with the results of an uninterrupted run), a request without the token changing nothing, a
remote abort ending like Ctrl-C (exit 130, `rtcal resume` finishes), and every way a run ends early
stopping the drive (Ctrl-C, SIGTERM, SIGHUP, SIGQUIT, a remote abort, a fault abort)."""

from __future__ import annotations

import json
import os
import select
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
import yaml

from rtcal.live.control import SOCKET_NAME
from rtcal.methods import read_results
from rtcal.run.runner import run_procedure
from simulators.servers.hub import SimulatorHub
from tests.test_transport_end_to_end import sim_serve
from tests.polling import wait_for as poll_until

REPO = Path(__file__).resolve().parents[1]
ISO = REPO / "procedures" / "iso230_2_polygon.yaml"
BENCH = REPO / "procedures" / "scenarios" / "abbe_bench.yaml"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")

pytestmark = pytest.mark.slow


def fast_iso(tmp_path: Path, settle_s: float = 0.05, runs: int = 5) -> Path:
    """The shipped ISO test with short settle times (a real-time run of a few seconds per run)."""
    data = yaml.safe_load(ISO.read_text(encoding="utf-8"))
    data.pop("bench", None)
    data["settle_time_s"] = settle_s
    data["steps"]["runs"] = runs
    path = tmp_path / "iso_fast.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True), encoding="utf-8")
    return path


def start_run(*args: str, preexec_fn: Callable[[], None] | None = None) -> tuple[subprocess.Popen, dict[str, str]]:
    """`rtcal ...` in a process; with --live waits for its `live view:` and `control token:` lines,
    without it for its control socket (such a run prints no token: "" stands for it)."""
    proc = subprocess.Popen([sys.executable, "-m", "rtcal.cli", *args], cwd=REPO, stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=preexec_fn)  # no terminal: as under nohup
    seen: dict[str, str] = {}
    deadline = time.monotonic() + 60
    if "--live" not in args:
        run_dir = Path(args[args.index("--out") + 1])
        wait_for(lambda: (run_dir / SOCKET_NAME).exists() or proc.poll() is not None, 60)  # a fault may end it first
        return proc, {"control token": ""}
    while "control token" not in seen:
        ready, _, _ = select.select([proc.stderr], [], [], max(0.0, deadline - time.monotonic()))
        line = proc.stderr.readline() if ready else ""
        assert line, f"no control token printed; exit {proc.poll()}"
        key, _, value = line.strip().partition(": ")
        if key in ("live view", "control token"):
            seen[key] = value
    return proc, seen


def state(url: str) -> dict:
    with urllib.request.urlopen(url + "api/state", timeout=10) as r:
        return json.loads(r.read())


def post(url: str, command: str, token: str | None) -> int:
    request = urllib.request.Request(url + f"api/{command}", method="POST", data=b"",
                                     headers={"Authorization": f"Bearer {token}"} if token else {})
    try:
        with urllib.request.urlopen(request, timeout=10) as r:
            return r.status
    except urllib.error.HTTPError as exc:
        return exc.code


def wait_for(predicate, timeout_s: float = 60.0):
    """tests.polling.wait_for every 0.1 s (real-time runs: patient, coarse)."""
    return poll_until(predicate, timeout_s, 0.1)


def finish(proc: subprocess.Popen, timeout_s: float = 180) -> tuple[int, str]:
    _, err = proc.communicate(timeout=timeout_s)
    return proc.returncode, err


def deviations(run_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    r = read_results(run_dir).positioning_deviations
    return np.array(r.deviation_arcsec, float), np.array(r.uncertainty_arcsec, float)


@pytest.mark.skipif(CHROMIUM is None, reason="no chromium installed (Debian: apt-get install chromium)")
def test_wired_iso_run_watched_paused_and_resumed_in_chromium(tmp_path):
    sync_api = pytest.importorskip("playwright.sync_api")
    procedure = fast_iso(tmp_path)
    local = run_procedure(procedure, BENCH, out_dir=tmp_path / "local", show_progress=False)  # uninterrupted, in process
    with sim_serve(BENCH) as addresses:
        proc, seen = start_run("run", str(procedure), "--instruments", json.dumps(addresses), "--out",
                               str(tmp_path / "run"), "--live", "127.0.0.1:0")
        url, token = seen["live view"], seen["control token"]
        try:
            with sync_api.sync_playwright() as p:
                browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
                try:
                    page = browser.new_page(viewport={"width": 1400, "height": 1300})
                    page.goto(url)

                    def done() -> int:
                        text = page.inner_text("#done")
                        return int(text) if text.isdigit() else -1

                    first = wait_for(lambda: (d := done()) >= 3 and d)
                    wait_for(lambda: done() >= first + 3)  # progress rises on the page
                    assert page.inner_text("#planned") == str(state(url)["planned_readings"])
                    assert post(url, "pause", None) == 401 and post(url, "pause", "x" + token) == 401
                    assert state(url)["state"] == "running"  # a request without the token changed nothing
                    page.fill("#token", token)
                    page.click("#btn-pause")
                    wait_for(lambda: state(url)["state"] == "paused")
                    held = state(url)["done_readings"]
                    time.sleep(2.0)
                    assert state(url)["done_readings"] == held and done() == held  # nothing taken while paused
                    page.screenshot(path=str(tmp_path / "live_paused.png"), full_page=True)
                    page.click("#btn-resume")
                    wait_for(lambda: state(url)["state"] != "paused")
                finally:
                    browser.close()
            code, err = finish(proc)
        finally:
            if proc.poll() is None:
                proc.kill()
    assert code == 0, err
    assert token not in err  # printed once (start_run read that line)
    for f in (tmp_path / "run").iterdir():  # and written nowhere
        if f.is_file():
            assert token.encode() not in f.read_bytes(), f.name
    remote, u = deviations(tmp_path / "run")
    ref, u_ref = deviations(tmp_path / "local")
    apart = np.abs(remote - ref)
    assert np.all(apart <= 4 * np.hypot(u, u_ref))  # the same results, within their noise (120 rows: 4σ)
    assert np.sqrt(np.mean(apart**2)) <= np.sqrt(np.mean(u**2 + u_ref**2))
    assert (tmp_path / "live_paused.png").stat().st_size > 10_000


def test_remote_abort_exits_130_and_resume_finishes(tmp_path):
    procedure = fast_iso(tmp_path, settle_s=0.25, runs=2)
    with sim_serve(BENCH) as addresses:
        proc, seen = start_run("run", str(procedure), "--instruments", json.dumps(addresses), "--out", str(tmp_path / "run"))
        assert "live view" not in seen  # every run has its control socket, --live or not
        time.sleep(1.0)
        control = subprocess.run([sys.executable, "-m", "rtcal.cli", "control", str(tmp_path / "run"), "abort", "--token",
                                  seen["control token"]], cwd=REPO, capture_output=True, text=True, timeout=30)
        assert control.returncode == 0, control.stderr
        code, err = finish(proc)
        assert code == 130, err
        assert f"rtcal resume {tmp_path / 'run'}" in err
        assert "control token" not in err  # without --live no token is printed: its user's `rtcal control` needs none
        resumed = subprocess.run([sys.executable, "-m", "rtcal.cli", "resume", str(tmp_path / "run"), "--instruments",
                                  json.dumps(addresses)], cwd=REPO, capture_output=True, text=True, timeout=180)
    assert resumed.returncode == 0, resumed.stderr
    assert (tmp_path / "run" / "results.json").is_file()
    gone = subprocess.run([sys.executable, "-m", "rtcal.cli", "control", str(tmp_path / "run"), "pause", "--token",
                           seen["control token"]], cwd=REPO, capture_output=True, text=True, timeout=30)
    assert gone.returncode == 1  # no engine runs for that directory any more


def start_for_a_person(procedure: Path, hub: SimulatorHub, run_dir: Path) -> tuple[subprocess.Popen, str, str, dict]:
    """`rtcal run --live` on the hub without its simulated operator (a person confirms each operator
    step; the polygon's certificate in ``procedure`` taken from that operator): the process, its
    page's URL, its token and the instruments' addresses."""
    from rtcal.engine.operator import RemoteSimOperator

    data = yaml.safe_load(procedure.read_text(encoding="utf-8"))
    data["polygon"]["certificate_arcsec"] = RemoteSimOperator(hub.addresses["operator"]).hands().polygon_certificate_arcsec()
    procedure.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True), encoding="utf-8")
    addresses = {k: v for k, v in hub.addresses.items() if k != "operator"}
    proc, seen = start_run("run", str(procedure), "--instruments", json.dumps(addresses), "--out", str(run_dir),
                           "--live", "127.0.0.1:0")
    return proc, seen["live view"], seen["control token"], addresses


def test_an_operator_step_without_a_terminal_waits_for_a_remote_confirm(tmp_path):
    """A wired ISO run with --live and no terminal (as under nohup): the polygon's seating waits for a person
    instead of stopping the run; the page's state shows the instruction; `rtcal control … confirm` continues it
    (a wrong token and a stray confirm change nothing, exit 2; the page's stray confirm is a 409). A second run
    aborted while it waits stops like Ctrl-C (exit 130)."""
    from rtcal.cli import main
    from rtcal.live.control import send_control
    from rtcal.engine.operator import RemoteSimOperator

    procedure = fast_iso(tmp_path, settle_s=0.05, runs=2)
    with SimulatorHub(_scenario(tmp_path, "none"), seed=1) as hub:
        run_dir = tmp_path / "run"
        proc, url, token, addresses = start_for_a_person(procedure, hub, run_dir)
        try:
            asked = wait_for(lambda: (s := state(url))["operator"] and s)
            assert asked["state"] == "running" and "Seat the polygon in its home seating" in asked["operator"]["instruction"]
            time.sleep(1.0)
            assert proc.poll() is None and state(url)["done_readings"] == 0  # it waits, nothing measured
            assert post(url, "confirm", None) == 401 and main(["control", str(run_dir), "confirm", "--token", "x" + token]) == 2
            assert state(url)["operator"] is not None  # refused: still waiting
            RemoteSimOperator(hub.addresses["operator"]).hands().reseat_polygon(0.0)  # the person seats the polygon …
            confirm = subprocess.run([sys.executable, "-m", "rtcal.cli", "control", str(run_dir), "confirm", "--token",
                                      token], cwd=REPO, capture_output=True, text=True, timeout=60)  # … and confirms
            assert confirm.returncode == 0, confirm.stderr
            wait_for(lambda: state(url)["operator"] is None)
            assert main(["control", str(run_dir), "confirm", "--token", token]) == 2  # nothing waits now
            request = urllib.request.Request(url + "api/confirm", method="POST", data=b"",
                                             headers={"Authorization": f"Bearer {token}"})
            with pytest.raises(urllib.error.HTTPError) as stray:
                urllib.request.urlopen(request, timeout=10)
            assert stray.value.code == 409 and "no operator step waits" in json.loads(stray.value.read())["error"]
            code, err = finish(proc)
        finally:
            if proc.poll() is None:
                proc.kill()
        assert code == 0, err
        assert "rtcal: operator: Seat the polygon" in err and f"`rtcal control {run_dir} confirm --step 1`" in err
        results = read_results(run_dir)
        assert any(e.kind == "confirm" and "remotely" in e.message for e in results.events)

        aborted = tmp_path / "aborted"
        proc, seen = start_run("run", str(procedure), "--instruments", json.dumps(addresses), "--out", str(aborted),
                               "--live", "127.0.0.1:0")
        try:
            wait_for(lambda: state(seen["live view"])["operator"])
            send_control(aborted, seen["control token"], "abort")
            code, err = finish(proc, 60)
        finally:
            if proc.poll() is None:
                proc.kill()
        assert code == 130, err
        assert f"rtcal resume {aborted}" in err


def end_early(tmp_path: Path, procedure: Path, scenario, how: str, cmm: bool = False):
    """Start a wired run against an in-process hub, end it early as ``how`` says, once the drive (and the
    CMM, with ``cmm``) has been commanded — a safe stop stops what the run moved; the hub, to look at."""
    with SimulatorHub(scenario, seed=1) as hub:
        proc, seen = start_run("run", str(procedure), "--instruments", json.dumps(dict(hub.addresses)), "--out",
                               str(tmp_path / "run"))
        if how == "fault":
            code, err = finish(proc)
            assert code == 1, err
        else:
            wait_for(lambda: hub.drive.command_steps != 0 and (not cmm or hub.ipp_machine.motions != 0), 60)  # moved
            if how == "abort":
                subprocess.run([sys.executable, "-m", "rtcal.cli", "control", str(tmp_path / "run"), "abort", "--token",
                                seen["control token"]], cwd=REPO, check=True, capture_output=True, timeout=30)
            else:
                os.kill(proc.pid, getattr(signal, how))
            code, err = finish(proc)
            assert code == 130, err
        assert "rtcal resume" in err
        return hub, err


@pytest.mark.parametrize("how", ["SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT", "abort", "fault"])
def test_every_early_end_stops_the_stage_and_the_cmm(tmp_path, how):
    """A seed-000 run over the Modbus drive and the I++ server: the drive receives STOP and the CMM `AbortE()`
    however the run ends early."""
    data = yaml.safe_load((REPO / "procedures" / "laser_tracer_multistation.yaml").read_text(encoding="utf-8"))
    data.pop("bench", None)
    data["settle_time_s"] = 0.2
    procedure = tmp_path / "multistation.yaml"
    procedure.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True), encoding="utf-8")
    faults = [{"instrument": "laser_tracer", "kind": "no_reply", "at_request": list(range(8, 60))}] if how == "fault" else []
    hub, err = end_early(tmp_path, procedure, _scenario(tmp_path, "none", REPO / "procedures" / "scenarios" /
                                                        "paper000_bench.yaml", faults), how, cmm=True)
    assert hub.drive.stops >= 1, err
    assert hub.ipp_machine.aborts >= 1, err
    # each then seen at rest (the drive's feedback, the CMM's Get(X(), Y(), Z()) read until unchanged)
    with sqlite3.connect(f"file:{tmp_path / 'run' / 'run.sqlite'}?mode=ro", uri=True) as db:
        seen = dict(db.execute("SELECT instrument, kind FROM events WHERE kind IN ('stopped', 'moving')"))
    assert seen == {"stage": "stopped", "cmm": "stopped"} and "may still be moving" not in err, (seen, err)


@pytest.mark.parametrize("how", ["SIGINT", "SIGTERM", "abort", "fault"])
def test_every_early_end_stops_the_drive(tmp_path, how):
    """An ISO run: the drive (Modbus, the simulated AZ) receives STOP however the run ends early."""
    hub, err = end_early(tmp_path, fast_iso(tmp_path, settle_s=0.25, runs=2), _scenario(tmp_path, how), how)
    assert hub.drive.stops >= 1, err


def _scenario(tmp_path: Path, how: str, bench: Path = BENCH, faults: list | None = None):
    from simulators.scenario_file import load_scenario

    data = yaml.safe_load(bench.read_text(encoding="utf-8"))
    if how == "fault":  # the autocollimator fails for good after a few readings: its policy aborts
        data["faults"] = [{"instrument": "autocollimator", "kind": "no_reply", "at_request": list(range(6, 40))}]
    if faults:
        data["faults"] = faults
    path = tmp_path / "bench.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return load_scenario(path, path.read_text(encoding="utf-8"))


def test_a_rehearsal_on_simulators_waits_for_a_person_then_the_simulated_operator_reseats(tmp_path, capsys):
    """`rtcal run --rehearse`: the polygon's two seatings each wait for a person as on hardware (no terminal, a
    --live run: the page and `rtcal control … confirm`); once confirmed the simulated operator re-seats the
    polygon on the simulators, so the run finishes (without it the second seating finds no reflection), its
    `certificate_arcsec: bench` handed over by the simulated operator; each seating is logged once done, after
    its confirm. Without the simulated operator's address --rehearse is refused with why (exit 2)."""
    from rtcal.cli import main

    procedure = fast_iso(tmp_path, settle_s=0.05, runs=2)
    data = yaml.safe_load(procedure.read_text(encoding="utf-8"))
    data["polygon"]["seatings_deg"] = [0, 7.5]
    procedure.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True), encoding="utf-8")
    with SimulatorHub(_scenario(tmp_path, "none"), seed=1) as hub:
        without = {k: v for k, v in hub.addresses.items() if k != "operator"}
        assert main(["run", str(procedure), "--instruments", json.dumps(without), "--out", str(tmp_path / "x"),
                     "--rehearse"]) == 2
        assert "give its address (`operator` in --instruments" in capsys.readouterr().err
        assert main(["run", str(procedure), "--instruments", json.dumps(without), "--out", str(tmp_path / "y")]) == 2
        assert "this run has neither (its operator steps are a person's)" in capsys.readouterr().err  # why `bench` is refused
        run_dir = tmp_path / "run"
        proc, seen = start_run("run", str(procedure), "--instruments", json.dumps(dict(hub.addresses)), "--out",
                               str(run_dir), "--live", "127.0.0.1:0", "--rehearse")
        url, token = seen["live view"], seen["control token"]
        try:
            for step in (1, 2):
                asked = wait_for(lambda: (s := state(url))["operator"] and s["operator"]["step"] == step and s)
                assert "Seat the polygon" in asked["operator"]["instruction"]
                assert main(["control", str(run_dir), "confirm", "--token", token, "--step", str(step)]) == 0
            code, err = finish(proc)
        finally:
            if proc.poll() is None:
                proc.kill()
        assert code == 0, err
    results = read_results(run_dir)
    kinds = [(e.kind, e.message) for e in results.events if e.kind in ("operator", "confirm")]
    assert [k for k, _ in kinds] == ["confirm", "operator", "confirm", "operator"], kinds
    assert "seated at 7.5°" in kinds[3][1]
