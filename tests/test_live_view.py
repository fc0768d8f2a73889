"""The live view and remote control (issue 24, items 5-7): the HTTP API against a store being
written by a thread, server-sent events and their resumption, the control socket and
`rtcal control`, `rtcal view`, and the page in a real headless Chromium."""

from __future__ import annotations

import http.client
import json
import os
import shutil
import signal
import socket
from contextlib import closing
import stat
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from live_fill import PROCEDURE, StoreWriter  # noqa: E402

from rtcal.live.control import (SOCKET_NAME, ControlServer, NoEngine, new_token, send_control)  # noqa: E402
from rtcal.live.server import LiveServer, LiveSpecError, parse_live_spec  # noqa: E402
from rtcal.live.storeview import open_read_only  # noqa: E402
from tests.polling import wait_for  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
CONTRACT_KEYS = {"state", "method", "planned_readings", "done_readings", "eta_s", "faults", "current"}
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


class FakeEngine:
    """A Controllable that records the requests and holds the writer while paused, as the engine
    holds the machines."""

    def __init__(self, writer: StoreWriter | None = None):
        self.calls: list[str] = []
        self.confirmed_steps: list[int | None] = []
        self.writer = writer

    def request_pause(self) -> None:
        self.calls.append("pause")
        if self.writer:
            self.writer.hold.set()

    def request_resume(self) -> None:
        self.calls.append("resume")
        if self.writer:
            self.writer.hold.clear()

    def request_abort(self, by: str = "") -> None:
        self.calls.append("abort")
        if self.writer:
            self.writer.halt.set()

    def request_confirm(self, step: int | None = None) -> None:
        from rtcal.engine.operator import NothingToConfirm

        if self.writer is None or not self.writer.asking or self.writer.confirmed.is_set() or step not in (None, 1):
            raise NothingToConfirm("nothing to confirm: no operator step waits now")
        self.calls.append("confirm")
        self.confirmed_steps.append(step)
        self.writer.confirmed.set()


def get_json(url: str) -> dict:
    with urllib.request.urlopen(url, timeout=20) as r:
        assert r.headers["Content-Type"].startswith("application/json")
        return json.load(r)


def post(url: str, token: str | None = None) -> int:
    req = urllib.request.Request(url, method="POST", data=b"")
    if token is not None:
        req.add_header("Authorization", f"Bearer {token}")
    try:
        with urllib.request.urlopen(req, timeout=20) as r:
            return r.status
    except urllib.error.HTTPError as exc:
        return exc.code


def planned_of_procedure() -> int:
    from rtcal.methods import METHODS
    from rtcal.methods import load_procedure

    proc = load_procedure(PROCEDURE, False, PROCEDURE.read_text())
    return METHODS[proc.method].plan_length(proc)


def store_ids(run_dir: Path) -> list[int]:
    with closing(open_read_only(run_dir / "run.sqlite")) as db:  # `mode=ro` alone would create -wal and -shm
        return [r[0] for r in db.execute("SELECT id FROM readings ORDER BY id")]


def read_sse(host: str, port: int, readings: int, last_event_id: int | None = None, timeout_s: float = 30.0) -> list[dict]:
    """Server-sent events as dicts (event, id, data) until ``readings`` reading events came."""
    conn = http.client.HTTPConnection(host, port, timeout=timeout_s)
    headers = {"Accept": "text/event-stream"}
    if last_event_id is not None:
        headers["Last-Event-ID"] = str(last_event_id)
    conn.request("GET", "/api/events", headers=headers)
    resp = conn.getresponse()
    assert resp.status == 200 and resp.getheader("Content-Type").startswith("text/event-stream")
    events, current, buf = [], {}, b""
    deadline = time.monotonic() + timeout_s
    while sum(e.get("event") == "reading" for e in events) < readings and time.monotonic() < deadline:
        buf += resp.read1(65536)
        while b"\n" in buf:
            line, buf = buf.split(b"\n", 1)
            text = line.decode()
            if not text:
                if current:
                    events.append(current)
                current = {}
            elif not text.startswith(":"):
                field, _, value = text.partition(":")
                current[field] = value[1:] if value.startswith(" ") else value
    conn.close()
    return events


@pytest.fixture
def writing(tmp_path):
    """A store being written by a thread (the ISO 230-2 procedure's visits), a fake engine and a
    live server with control; everything stopped afterwards."""
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    writer = StoreWriter(run_dir, interval_s=0.02, engine=False)
    engine = FakeEngine(writer)
    token = new_token()
    server = LiveServer(run_dir, "127.0.0.1", 0, engine, token)
    url = server.start()
    yield run_dir, writer, engine, token, server, url
    server.stop()
    writer.halt.set()
    writer.hold.clear()
    if writer.is_alive():
        writer.join(10)


def test_state_follows_the_store_being_written(writing):
    run_dir, writer, engine, token, server, url = writing
    first = get_json(url + "api/state")
    assert CONTRACT_KEYS <= set(first)
    assert first["state"] == "running" and first["done_readings"] == 0 and first["eta_s"] is None
    assert first["planned_readings"] == planned_of_procedure() == len(writer.visits)
    assert first["method"] == "encoder_abbe_error" and first["control"] is True
    writer.start()
    wait_for(lambda: writer.written >= 30)
    writer.hold.set()  # hold the writer still to compare with the store
    time.sleep(0.3)
    written = writer.written
    state = wait_for(lambda: (s := get_json(url + "api/state"))["done_readings"] == written and s)
    assert state["faults"] == 1  # the rejected attempt's fault event; the rejected attempt is not counted done
    remaining = state["planned_readings"] - written
    assert 2.9 * remaining <= state["eta_s"] <= 3.6 * remaining  # 3 s of run clock per visit
    last = writer.visits[written]  # written counts the visits done: one more (5) was skipped
    assert state["current"]["target_deg"] == last.angle_deg and state["current"]["run"] == last.run + 1
    latest = {(r["instrument"], r["quantity"]): r for r in state["latest"]}
    assert latest[("autocollimator", "x_arcsec")]["age_s"] == pytest.approx(0.1)
    assert latest[("environment", "air_temperature_c")]["value"] == 20.1
    rows = state["progress"]["rows"]
    assert rows[0]["label"] == "run 1 ↑" and sum(r["done"] for r in rows) == written
    # visit 3 was rejected and taken again (done), visit 5 skipped (to do on resume)
    assert rows[0]["cells"][3] == "done" and rows[0]["cells"][5] == "skipped" and rows[0]["done"] == 11


def test_engine_meta_is_preferred(tmp_path):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    writer = StoreWriter(run_dir, interval_s=0.01, stop_after=8, engine=True)
    writer.start()
    writer.join(20)
    with LiveServer(run_dir, port=0) as server:
        state = get_json(server.url + "api/state")
    assert state["state"] == "finished" and state["done_readings"] == writer.written == 7 and state["eta_s"] == 0.0
    assert state["current"] == {"plan_index": 7, "target_deg": writer.visits[7].angle_deg, "run": 1, "direction": "+"}


def test_control_needs_the_token_and_a_view_has_none(writing):
    run_dir, writer, engine, token, server, url = writing
    for command in ("pause", "resume", "abort"):
        assert post(url + f"api/{command}") == 401
        assert post(url + f"api/{command}", ("y" if token[0] == "x" else "x") + token[1:]) == 401
        assert post(url + f"api/{command}", "") == 401
    assert engine.calls == [] and not writer.hold.is_set() and not writer.halt.is_set()
    assert post(url + "api/pause", token) == 202 and engine.calls == ["pause"]
    assert post(url + "api/resume", token) == 202 and post(url + "api/abort", token) == 202
    assert engine.calls == ["pause", "resume", "abort"]
    assert post(url + "api/jump", token) == 404
    with LiveServer(run_dir, port=0) as view:  # `rtcal view`: read-only whatever the token
        assert post(view.url + "api/pause", token) == 409 and post(view.url + "api/abort") == 409
        assert get_json(view.url + "api/state")["control"] is False
    assert engine.calls == ["pause", "resume", "abort"]


def test_events_carry_reading_ids_and_resume_after_last_event_id(writing):
    run_dir, writer, engine, token, server, url = writing
    writer.stop_after = 20
    writer.skip_at = None
    writer.start()
    writer.join(20)
    ids = store_ids(run_dir)
    host, port = "127.0.0.1", server.port
    events = read_sse(host, port, len(ids))
    readings = [e for e in events if e.get("event") == "reading"]
    assert [int(e["id"]) for e in readings] == ids
    assert all(json.loads(e["data"])["id"] == int(e["id"]) for e in readings)
    assert any(e.get("event") == "state" and "id" not in e for e in events)  # state events leave Last-Event-ID alone
    logs = [json.loads(e["data"]) for e in events if e.get("event") == "log"]
    assert [e["kind"] for e in logs] == ["fault"]
    k = ids[len(ids) // 2]
    again = [e for e in read_sse(host, port, len(ids) - ids.index(k) - 1, last_event_id=k) if e.get("event") == "reading"]
    assert [int(e["id"]) for e in again] == [i for i in ids if i > k]


def test_a_finished_run_is_read_without_touching_a_byte(tmp_path):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    writer = StoreWriter(run_dir, interval_s=0.0, stop_after=15, finish=True)
    writer.start()
    writer.join(20)
    before = {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in run_dir.iterdir()}
    with LiveServer(run_dir, port=0) as server:
        state = get_json(server.url + "api/state")
        assert len(read_sse("127.0.0.1", server.port, len(store_ids(run_dir)))) > len(store_ids(run_dir))
    assert state["state"] == "finished" and state["done_readings"] == writer.written == 14
    assert {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in run_dir.iterdir()} == before  # no -wal, no -shm


def test_page_and_assets_are_served_from_the_package(writing):
    run_dir, writer, engine, token, server, url = writing
    with urllib.request.urlopen(url, timeout=20) as r:
        page = r.read().decode()
        assert r.headers["Content-Type"].startswith("text/html") and "script-src 'self'" in r.headers["Content-Security-Policy"]
    assert "static/app.js" in page and "http://" not in page and "https://" not in page  # no CDN
    for name in ("app.js", "style.css"):
        with urllib.request.urlopen(url + "static/" + name, timeout=20) as r:
            assert b"http://" not in r.read() or name == "app.js"
    (run_dir / "secret.txt").write_text("not served")
    for path in ("static/../run.sqlite", "files/run.sqlite", "files/secret.txt", "files/report.pdf", "static/secret.txt"):
        try:
            status = urllib.request.urlopen(url + path, timeout=20).status
        except urllib.error.HTTPError as exc:
            status = exc.code
        assert status == 404, path
    (run_dir / "report.pdf").write_bytes(b"%PDF-1.4 test")
    with urllib.request.urlopen(url + "files/report.pdf", timeout=20) as r:
        assert r.read() == b"%PDF-1.4 test"


def test_a_foreign_host_header_is_refused(writing):
    """A page elsewhere that rebinds its name to 127.0.0.1 cannot read the view."""
    run_dir, writer, engine, token, server, url = writing
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=20)
    conn.request("GET", "/api/state", headers={"Host": "attacker.example"})
    assert conn.getresponse().status == 400
    conn.close()


@pytest.mark.parametrize("spec, expected", [("8765", ("127.0.0.1", 8765)), ("0", ("127.0.0.1", 0)),
                                            ("0.0.0.0:9000", ("0.0.0.0", 9000)), ("[::1]:80", ("::1", 80)),
                                            ("localhost:0", ("localhost", 0))])
def test_live_spec(spec, expected):
    assert parse_live_spec(spec) == expected


@pytest.mark.parametrize("spec", ["", "abc", "70000", "host:", ":80", "::1:80", "-1", "[::1]80", "a b:1", "1.5"])
def test_live_spec_refused(spec):
    with pytest.raises(LiveSpecError):
        parse_live_spec(spec)


def test_tokens_are_long_random_and_url_safe():
    tokens = {new_token() for _ in range(50)}
    assert len(tokens) == 50
    for t in tokens:
        assert len(t) >= 22 and all(c.isalnum() or c in "-_" for c in t)  # ≥ 128 bits in base64url


def rtcal_started(*args: str, env: dict | None = None) -> subprocess.Popen:
    """`rtcal ARGS` started as a process of its own (its exit code is what the contract names)."""
    return subprocess.Popen([sys.executable, "-m", "rtcal.cli", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, "PYTHONPATH": str(REPO), **(env or {})}, cwd=REPO)


def finished(proc: subprocess.Popen, timeout: float = 60) -> subprocess.CompletedProcess:
    out, err = proc.communicate(timeout=timeout)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def rtcal_here(capsys, *args: str) -> tuple[int, str]:
    """`rtcal` in this process (its exit code and stderr): the subprocess costs seconds of imports."""
    from rtcal.cli import main

    capsys.readouterr()
    try:
        code = main(list(args))
    except SystemExit as exc:  # argparse's own refusals
        code = int(exc.code or 0)
    return code, capsys.readouterr().err


@pytest.mark.slow
def test_control_socket_and_rtcal_control(tmp_path, capsys, monkeypatch):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    engine, token = FakeEngine(), new_token()
    assert rtcal_here(capsys, "control", str(run_dir), "pause", "--token", token)[0] == 1  # no engine yet
    with ControlServer(run_dir, token, engine):
        st = os.lstat(run_dir / SOCKET_NAME)
        assert stat.S_ISSOCK(st.st_mode) and stat.S_IMODE(st.st_mode) == 0o600
        (tmp_path / "idle").mkdir()
        # the three exit codes from processes of their own, started together (each spends seconds importing)
        started = [rtcal_started("control", str(run_dir), "pause", "--token", ("y" if token[0] == "x" else "x") + token[1:]),
                   rtcal_started("control", str(run_dir), "pause", env={"RTCAL_CONTROL_TOKEN": token}),
                   rtcal_started("control", str(tmp_path / "idle"), "abort", "--token", token)]
        wrong, ok, gone = (finished(p) for p in started)
        assert wrong.returncode == 2 and wrong.stderr.count("\n") == 1 and "Traceback" not in wrong.stderr
        assert token[1:] not in wrong.stderr
        assert ok.returncode == 0, ok.stderr
        assert gone.returncode == 1 and "no engine" in gone.stderr and "Traceback" not in gone.stderr
        assert engine.calls == ["pause"]  # the wrong token changed nothing
        assert rtcal_here(capsys, "control", str(run_dir), "resume", "--token", token)[0] == 0
        assert engine.calls == ["pause", "resume"]
        assert rtcal_here(capsys, "control", str(run_dir), "jump", "--token", token)[0] == 2
        monkeypatch.delenv("RTCAL_CONTROL_TOKEN", raising=False)
        code, err = rtcal_here(capsys, "control", str(run_dir), "abort")  # no token given
        assert code == 2 and "token" in err
        with pytest.raises(RuntimeError):  # a second engine on the same directory
            ControlServer(run_dir, new_token(), FakeEngine()).start()
        # raw requests: an over-long line and a token that is no string get an answer, change nothing
        for request in (b"x" * 10000 + b"\n", json.dumps({"token": 5, "command": "abort"}).encode() + b"\n"):
            with socket.socket(socket.AF_UNIX) as s:
                s.connect(str(run_dir / SOCKET_NAME))
                s.sendall(request)
                assert json.loads(s.makefile().readline())["ok"] is False
        assert engine.calls == ["pause", "resume"]
    assert not os.path.lexists(run_dir / SOCKET_NAME)
    assert rtcal_here(capsys, "control", str(run_dir), "abort", "--token", token)[0] == 1
    stale = socket.socket(socket.AF_UNIX)  # a killed engine leaves its socket behind
    stale.bind(str(run_dir / SOCKET_NAME))
    stale.close()
    with pytest.raises(NoEngine):
        send_control(run_dir, token, "pause")
    assert rtcal_here(capsys, "control", str(run_dir), "pause", "--token", token)[0] == 1
    assert rtcal_here(capsys, "control", str(tmp_path / "missing"), "pause", "--token", token)[0] == 2
    with ControlServer(run_dir, token, engine):  # a stale socket is replaced
        send_control(run_dir, token, "abort")
    assert engine.calls == ["pause", "resume", "abort"]


def test_a_deep_run_directory_still_gets_its_socket(tmp_path):
    deep = tmp_path.joinpath(*["d" * 30] * 5)
    deep.mkdir(parents=True)
    assert len(str(deep / SOCKET_NAME)) > 108
    engine, token = FakeEngine(), new_token()
    with ControlServer(deep, token, engine):
        send_control(deep, token, "pause")
    assert engine.calls == ["pause"]


def test_token_is_written_nowhere(writing):
    run_dir, writer, engine, token, server, url = writing
    writer.start()
    with ControlServer(run_dir, token, engine):
        send_control(run_dir, token, "pause")
        assert post(url + "api/resume", token) == 202
        wait_for(lambda: get_json(url + "api/state")["done_readings"] >= 5)
    writer.halt.set()
    writer.join(10)
    server.stop()
    files = [p for p in run_dir.rglob("*") if p.is_file()]
    assert any(p.name == "run.sqlite" for p in files)
    for p in files:
        assert token.encode() not in p.read_bytes(), p


@pytest.mark.slow
def test_rtcal_view_serves_until_interrupted(tmp_path):
    """`rtcal view` in a process of its own follows a run being written until it is finished."""
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    writer = StoreWriter(run_dir, interval_s=0.02, finish=True)
    proc = subprocess.Popen([sys.executable, "-m", "rtcal.cli", "view", str(run_dir), "--live", "0"], cwd=REPO,
                            env={**os.environ, "PYTHONPATH": str(REPO)}, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stderr.readline()
        assert line.startswith("live view: http://127.0.0.1:") and line.endswith("/\n"), line
        url = line.split(": ", 1)[1].strip()
        writer.start()
        first = wait_for(lambda: get_json(url + "api/state")["done_readings"] or None)
        wait_for(lambda: get_json(url + "api/state")["done_readings"] > first)  # in progress, rising
        assert post(url + "api/pause", "anything") == 409
        writer.join(60)
        final = wait_for(lambda: (s := get_json(url + "api/state"))["state"] == "finished" and s)
        assert final["done_readings"] == writer.written == len(writer.visits) - 1  # one visit was skipped
    finally:
        writer.halt.set()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(20) in (0, 130)
    assert "Traceback" not in proc.stderr.read()


def test_rtcal_view_refuses_bad_arguments(tmp_path, capsys):
    code, err = rtcal_here(capsys, "view", str(tmp_path / "nothing"))
    assert code == 2 and err.count("\n") == 1
    assert rtcal_here(capsys, "view", str(tmp_path), "--live", "0")[0] == 2  # no run.sqlite in it
    (tmp_path / "run.sqlite").write_bytes(b"")
    code, err = rtcal_here(capsys, "view", str(tmp_path), "--live", "nohost:port")
    assert code == 2 and err.count("\n") == 1
    with socket.socket() as busy:  # a port that is taken
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        code, err = rtcal_here(capsys, "view", str(tmp_path), "--live", str(busy.getsockname()[1]))
    assert code == 2 and "cannot listen" in err


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="no chromium installed (Debian: apt-get install chromium)")
def test_the_page_in_headless_chromium(tmp_path):
    sync_api = pytest.importorskip("playwright.sync_api")
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    writer = StoreWriter(run_dir, interval_s=0.12, engine=True)
    engine = FakeEngine(writer)
    token = new_token()
    errors: list[str] = []
    with LiveServer(run_dir, "127.0.0.1", 0, engine, token) as server, sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 1400})
            page.on("pageerror", lambda e: errors.append(str(e)))
            writer.start()
            page.goto(server.url)

            def done() -> int:
                text = page.inner_text("#done")
                return int(text) if text.isdigit() else -1

            first = wait_for(lambda: (d := done()) >= 3 and d)
            wait_for(lambda: done() >= first + 3)  # progress rises on the page
            assert page.inner_text("#planned") == str(len(writer.visits))
            page.fill("#token", "wrong" + token)
            page.click("#btn-pause")
            wait_for(lambda: "wrong control token" in page.inner_text("#control-msg"))
            assert engine.calls == []
            page.fill("#token", token)
            page.click("#btn-pause")
            wait_for(lambda: engine.calls == ["pause"])
            wait_for(lambda: page.inner_text("#state").lower() == "paused")
            held = done()
            time.sleep(1.0)
            assert done() == held  # paused: nothing more is taken
            assert page.locator("#plot polyline").count() >= 1  # the readings plotted per run and direction
            page.screenshot(path=str(tmp_path / "live_view.png"), full_page=True)
            page.click("#btn-resume")
            wait_for(lambda: engine.calls == ["pause", "resume"])
            wait_for(lambda: done() > held)
            assert page.inner_text("#state").lower() == "running"
            # an operator step: the instruction shows at the top with Done, which confirms it with the token
            assert not page.is_visible("#operator-card")
            writer.ask_at = writer.written + 4  # a visit still to come (one was skipped: k > written)
            page.wait_for_selector("#operator-card", state="visible", timeout=20000)
            assert page.inner_text("#operator-instruction") == writer.instruction
            assert page.is_visible("#btn-confirm") and page.title().startswith("Operator step")
            asked = done()
            with LiveServer(run_dir, "127.0.0.1", 0) as view:  # `rtcal view`: the instruction, no working button
                readonly = browser.new_page()
                readonly.goto(view.url)
                readonly.wait_for_selector("#operator-card", state="visible", timeout=20000)
                assert readonly.inner_text("#operator-instruction") == writer.instruction
                assert not readonly.is_visible("#btn-confirm") and readonly.is_visible("#operator-readonly")
                readonly.close()
            page.screenshot(path=str(tmp_path / "live_operator.png"), full_page=True)
            assert done() == asked and engine.calls == ["pause", "resume"]  # it waits
            page.click("#btn-confirm")
            wait_for(lambda: engine.calls == ["pause", "resume", "confirm"])
            assert engine.confirmed_steps == [1]  # Done named the step it showed: a late one cannot answer the next
            page.wait_for_selector("#operator-card", state="hidden", timeout=20000)
            wait_for(lambda: done() > asked)  # the run goes on
            other = browser.new_page()  # the token given in the URL's fragment: kept in the page, gone from the URL
            other.goto(server.url + "#token=" + token)
            assert other.input_value("#token") == token and "token" not in other.url
        finally:
            browser.close()
            writer.halt.set()
            writer.hold.clear()
            writer.join(10)
    assert errors == []
    assert (tmp_path / "live_view.png").stat().st_size > 10000
    assert (tmp_path / "live_operator.png").stat().st_size > 10000


def test_a_viewer_far_behind_catches_up_from_the_store(writing, monkeypatch):
    """A long run: the shared feed keeps only the newest readings; a browser from the start reads
    the older ones from the store in batches and then joins the feed, missing none."""
    import rtcal.live.server as live_server

    monkeypatch.setattr(live_server, "FEED_WINDOW", 10)
    monkeypatch.setattr(live_server, "CATCH_UP_BATCH", 7)
    run_dir, writer, engine, token, server, url = writing
    writer.stop_after = 12
    writer.start()
    writer.join(20)
    ids = store_ids(run_dir)
    with LiveServer(run_dir, port=0) as late:  # its feed starts near the store's end
        got = [int(e["id"]) for e in read_sse("127.0.0.1", late.port, len(ids)) if e.get("event") == "reading"]
        assert got == ids
        again = [int(e["id"]) for e in read_sse("127.0.0.1", late.port, 5, last_event_id=ids[-6])
                 if e.get("event") == "reading"]
        assert again == ids[-5:]


def test_another_host_than_loopback_is_warned_of(tmp_path, capsys):
    with LiveServer(tmp_path, "0.0.0.0", 0) as server:
        assert server.url.startswith("http://0.0.0.0:")
        assert get_json(f"http://127.0.0.1:{server.port}/api/state")["state"] == "starting"  # no store yet
    err = capsys.readouterr().err
    assert err.startswith("rtcal: warning:") and err.count("\n") == 1


def test_a_session_prints_the_two_lines_and_serves_both_ways(tmp_path):
    """What `rtcal run --live` starts: the socket always, the page with control, the lines on stderr."""
    import io

    from rtcal.live.session import start_session

    engine, out = FakeEngine(), io.StringIO()
    with start_session(tmp_path, engine, ("127.0.0.1", 0), out) as session:
        lines = out.getvalue().splitlines()
        assert lines == [f"live view: {session.url}", f"control token: {session.token}"]
        assert session.url.startswith("http://127.0.0.1:") and len(session.token) >= 22
        send_control(tmp_path, session.token, "pause")
        assert post(session.url + "api/resume", session.token) == 202
        assert post(session.url + "api/abort") == 401
    assert engine.calls == ["pause", "resume"]
    assert not os.path.lexists(tmp_path / SOCKET_NAME)
    out = io.StringIO()
    with start_session(tmp_path, engine, None, out) as session:  # without --live: no token, none printed
        assert out.getvalue() == "" and session.token is None and session.url is None
        send_control(tmp_path, "", "abort")  # the socket admits its own user's processes
        send_control(tmp_path, "any-token-is-ignored", "resume")
    assert engine.calls == ["pause", "resume", "abort", "resume"]
    with socket.socket() as busy, pytest.raises(OSError):
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        start_session(tmp_path, engine, ("127.0.0.1", busy.getsockname()[1]), io.StringIO())
    assert not os.path.lexists(tmp_path / SOCKET_NAME)  # nothing left behind


def test_a_store_from_before_attempts_is_read_as_it_is(tmp_path):
    """No `attempt` column (rtcal before attempts): each planned reading was attempted once; the
    view reads it without adding the column as `rtcal resume` would."""
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    writer = StoreWriter(run_dir, interval_s=0.0, stop_after=4, reject_at=-1, skip_at=None, finish=True)
    writer.start()
    writer.join(20)
    import sqlite3

    with closing(sqlite3.connect(run_dir / "run.sqlite", isolation_level=None)) as db:
        db.execute("DROP INDEX readings_by_plan")
        db.execute("ALTER TABLE readings DROP COLUMN attempt")
    before = (run_dir / "run.sqlite").read_bytes()
    with LiveServer(run_dir, port=0) as server:
        state = get_json(server.url + "api/state")
        readings = [e for e in read_sse("127.0.0.1", server.port, 4 * 7) if e.get("event") == "reading"]
    assert state["state"] == "finished" and state["done_readings"] == 4 and len(readings) == 28
    assert json.loads(readings[0]["data"])["attempt"] is None
    assert (run_dir / "run.sqlite").read_bytes() == before


def test_a_poll_of_a_long_run_touches_the_new_readings_not_every_planned_reading(tmp_path):
    """Issue 43: each state counted every planned reading done and laid out the whole grid again (36 000 cells a
    poll for 36 stations × 1 000 points). The count is a running total and the grid is rebuilt only in the rows a
    new reading touched; it stays the grid of every planned reading as the store holds it."""
    from rtcal.live.storeview import StoreView
    from rtcal.store.runstore import Reading, RunStore

    store = RunStore.create(tmp_path, {"method": "laser_tracer_multistation", "planned_readings": "1200"})

    def reading(k: int, skipped: bool = False) -> list[Reading]:
        point, station = divmod(k, 12)
        r = [Reading(float(k), "laser_tracer", "length_mm", 100.0 + k, "mm", point=point, station=station,
                     plan_index=k, attempt=k + (10_000 if skipped else 0))]
        return r + ([Reading(float(k), "laser_tracer", "skipped", 0.0, "", point=point, station=station,
                             plan_index=k, attempt=k + 10_000)] if skipped else [])

    store.add_readings([r for k in range(1000) for r in reading(k, skipped=k == 500)])
    view = StoreView(tmp_path, 0.0)
    before = view.state()
    assert before["done_readings"] == 999
    rows = before["progress"]["rows"]
    assert len(rows) == 84 and rows[41]["cells"][8] == "skipped" and rows[0]["cells"] == ["done"] * 12
    store.add_readings(reading(500) + reading(1000))  # the skipped one retaken, one more begun on a new row
    after = view.state()
    assert after["done_readings"] == 1001
    new_rows = after["progress"]["rows"]
    assert len(new_rows) == 84 and new_rows[41]["cells"][8] == "done" and new_rows[83]["cells"][4] == "done"
    untouched = [k for k in range(84) if k not in (41, 83)]
    assert all(new_rows[k] is rows[k] for k in untouched)  # the rows no new reading touched are not laid out again
    store.close()
