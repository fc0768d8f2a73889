"""A `rtcal run --live` as its page sees it to the end: idle connections from anyone on the computer
never take the run's process to its descriptor limit, and every event stream ends with the run's
final state (finished) instead of breaking off at `running`."""

from __future__ import annotations

import errno
import json
import resource
import shutil
import socket
import subprocess
import sys
import re
import time
import urllib.request
from pathlib import Path

import pytest
import yaml

from rtcal.live.control import send_control
from rtcal.live.server import LiveServer
from rtcal.run.runner import run_procedure
from tests.polling import wait_for
from tests.test_live_run import start_run

REPO = Path(__file__).resolve().parents[1]
ISO = REPO / "procedures" / "iso230_2_polygon.yaml"

pytestmark = pytest.mark.slow


def short_iso(tmp_path: Path, runs: int = 2) -> Path:
    data = yaml.safe_load(ISO.read_text(encoding="utf-8"))
    (tmp_path / "bench.yaml").write_bytes((ISO.parent / data["bench"]).read_bytes())
    data["bench"] = "bench.yaml"
    data["steps"]["runs"] = runs
    path = tmp_path / "iso_short.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True), encoding="utf-8")
    return path


def _limit_descriptors() -> None:  # the default of a login session: what a lab's run gets
    resource.setrlimit(resource.RLIMIT_NOFILE, (1024, 1024))


def start_live_run(procedure: Path, run_dir: Path) -> tuple[subprocess.Popen, str, str]:
    """`rtcal run --live` with the descriptors of a login session; its URL and token."""
    proc, seen = start_run("run", str(procedure), "--out", str(run_dir), "--live", "127.0.0.1:0",
                           preexec_fn=_limit_descriptors)
    return proc, seen["live view"], seen["control token"]


def state(url: str) -> dict:
    with urllib.request.urlopen(url + "api/state", timeout=10) as r:
        return json.loads(r.read())


def open_idle(host: str, port: int, count: int) -> list[socket.socket]:
    """``count`` connections that never send a byte (non-blocking: a full backlog does not hold the test)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft < count + 200:
        resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, count + 400), hard))
    socks = []
    for _ in range(count):
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setblocking(False)
        code = s.connect_ex((host, port))
        assert code in (0, errno.EINPROGRESS), errno.errorcode.get(code)
        socks.append(s)
    return socks


def test_1100_idle_connections_never_starve_the_run(tmp_path):
    run_dir = tmp_path / "run"
    proc, url, token = start_live_run(short_iso(tmp_path), run_dir)
    socks: list[socket.socket] = []
    try:
        send_control(run_dir, token, "pause")
        wait_for(lambda: state(url)["state"] == "paused", 60)
        host, port = url.removeprefix("http://").rstrip("/").rsplit(":", 1)
        socks = open_idle(host, int(port), 1100)
        time.sleep(3.0)  # the run's server accepts (and closes at once beyond its cap) them
        assert proc.poll() is None
        send_control(run_dir, token, "resume")
        out, err = proc.communicate(timeout=300)
    finally:
        for s in socks:
            s.close()
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err[-3000:]
    assert (run_dir / "results.json").is_file() and (run_dir / "report.pdf").is_file()
    assert len(err) < 5000, err[-3000:]  # no traceback per connection


def read_stream(url: str, timeout_s: float = 300) -> list[tuple[str, str]]:
    """Every event of one /api/events stream until the server ends it: (event, data)."""
    events = []
    with urllib.request.urlopen(url + "api/events", timeout=timeout_s) as r:
        name, data = "message", ""
        for raw in r:
            line = raw.decode("utf-8").rstrip("\n")
            if not line:
                if data:
                    events.append((name, data))
                name, data = "message", ""
            elif line.startswith("event: "):
                name = line[7:]
            elif line.startswith("data: "):
                data += line[6:]
    return events


def test_the_event_stream_ends_with_the_finished_state(tmp_path):
    run_dir = tmp_path / "run"
    proc, url, token = start_live_run(short_iso(tmp_path), run_dir)
    try:
        events = read_stream(url)
        out, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err[-3000:]
    states = [json.loads(d) for n, d in events if n == "state"]
    last = states[-1]
    assert last["state"] == "finished" and last["done_readings"] == last["planned_readings"]
    assert last["result"] is not None and last["result"]["error"] is None  # the result comes with it


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.mark.skipif(CHROMIUM is None, reason="no chromium installed (Debian: apt-get install chromium)")
def test_the_finished_page_of_24_targets(tmp_path):
    """What a lab sees at the end: no cell lit as `now`, none left `to do`, the grid from 0° to 345° with
    its done column and the readings' age column inside 1300 px, the result in a sentence (the console's
    lines one click away), units as µm and °C."""
    sync_api = pytest.importorskip("playwright.sync_api")
    procedure = short_iso(tmp_path)
    data = yaml.safe_load(procedure.read_text(encoding="utf-8"))
    data["steps"]["targets_deg"] = [15 * k for k in range(24)]
    procedure.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True), encoding="utf-8")
    run_procedure(procedure, out_dir=tmp_path / "run", show_progress=False)
    with LiveServer(tmp_path / "run", "127.0.0.1", 0) as server, sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--headless", "--no-sandbox", "--disable-gpu",
                                                                    "--disable-background-networking"])
        try:
            page = browser.new_page(viewport={"width": 1300, "height": 1000})
            page.goto(server.url)
            page.wait_for_selector("#result-card:not([hidden])", timeout=60000)
            page.wait_for_selector("#grid table")
            assert page.locator("#grid .cell.current").count() == 0 and page.locator("#grid .cell.pending").count() == 0
            assert page.is_hidden("#legend-now") and page.inner_text("#current") == "–"
            heads = page.eval_on_selector_all("#grid thead th", "ths => ths.map(t => t.textContent)")
            assert heads[1] == "0°" and heads[-2] == "345°" and heads[-1] == "done" and len(heads) == 26
            assert page.eval_on_selector_all("#grid thead th", "ths => ths[ths.length - 1].getBoundingClientRect().right") <= 1300
            assert page.eval_on_selector("#grid-card", "e => e.scrollWidth <= e.clientWidth")
            age = page.eval_on_selector_all("#latest th", "ths => ths[ths.length - 1].getBoundingClientRect().right")
            card = page.eval_on_selector("#latest-card", "e => e.getBoundingClientRect().right")
            assert age <= card <= 1300
            assert re.match(r"Bidirectional systematic positional deviation E = \d+\.\d+″ \(U \d",
                            page.inner_text("#result-headline")), page.inner_text("#result-headline")
            assert not page.is_visible("#result-lines")  # the console's lines are one click away
            page.click("#result-details summary")
            assert "positioning deviation" in page.inner_text("#result-lines")
            latest = page.inner_text("#latest") + page.inner_text("#environment")
            assert "µm" in latest and "°C" in latest and " um" not in latest and "degC" not in latest
            # a run that ended early: where it was is not lit, what it never took is `not measured`, not `to do`
            page.evaluate("""() => renderGrid({state: "aborted", current: {target_deg: 15, run: 1, direction: "+"},
                progress: {axis: "target", columns: ["0°", "15°"], rows: [{label: "run 1 ↑", cells: ["done", "pending"],
                done: 1}]}})""")
            assert page.locator("#grid .cell.current").count() == 0 and page.locator("#grid .cell.pending").count() == 0
            assert page.get_attribute("#grid .cell.unmeasured", "title") == "run 1 ↑, 15°: not measured"
            assert page.inner_text("#legend-pending") == "not measured"
        finally:
            browser.close()


def test_a_run_out_of_descriptors_exits_1_with_the_resume_hint(tmp_path, capsys):
    """EMFILE mid-run (here from a source file the run imports late) is the computer's fault: exit 1 and
    how to resume, not exit 2 as if the user had named a bad file."""
    from rtcal.cli.run import _execute

    (tmp_path / "run.sqlite").write_bytes(b"")

    def start_plain() -> None:
        raise OSError(errno.EMFILE, "Too many open files", str(REPO / "rtcal" / "deliverables" / "report.py"))

    assert _execute(start_plain, str(tmp_path)) == 1
    err = capsys.readouterr().err
    assert "ran out of file descriptors" in err and f"rtcal resume {tmp_path}" in err
