"""A real LinuxCNC stopped mid-move, however the run ends (issue 40), and the axis letter checked
against its kinematics.

One `rtcal sim serve --stage linuxcnc` (LinuxCNC headless, the simulated bench) serves every ending:
Ctrl-C (SIGINT), SIGTERM, SIGHUP, the live page's Abort and a fault policy's abort. The stage
address asks for 10 °/s, so the ISO test's move from 0° towards 89° takes 8.9 s; each run is ended
once the table passes 21°. A read-only linuxcncrsh session of the test's own (hello and `get`s only:
it never takes control) watches the table: it must come to rest within about a second of the stop,
far short of the target, and the run's store must say it stopped there — at the position the
watcher sees. Shares test_linuxcnc_loop's lock: one LinuxCNC per machine.
"""

from __future__ import annotations

import json
import re
import signal
import socket
import sqlite3
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import pytest
import yaml

from simulators.servers.linuxcnc import LinuxCncProcess, available
from tests.test_linuxcnc_loop import SHORT, linuxcnc_bench, one_linuxcnc_at_a_time
from rtcal.live.control import SOCKET_NAME

pytestmark = pytest.mark.skipif(bool(available()), reason=available() or "LinuxCNC present")
REPO = Path(__file__).resolve().parents[1]
SPEED_DEG_PER_S = 10.0
STOP_AT_DEG = 21.0  # the table passes here 2.1 s into its 8.9 s move from 0° towards 89°
TARGET_DEG = 89.0  # (90° approached from below, 1° overshoot)
AT_REST_S = 0.3  # a position unchanged this long (read every 10 ms) is the table at rest
BOUND_S = 1.5  # from the stop asked to the table at rest ("within about a second"; measured ≈ 0.4 s)


class Watcher:
    """A linuxcncrsh session that only asks: hello and ``get abs_act_pos 5`` (no `set enable`). A reply
    not of its request's form is asked again: linuxcncrsh 2.9 splits every session's request with one
    ``strtok`` for the whole server, so a request parsed while the run's session parses one may take its
    words (seen: the all-axes form, ``GET 5 NAK``). Before asking again the session is put back in step
    with a request only its own reply answers (``get WATCHER_SYNC_<n>``, answered ``GET … NAK``)."""

    def __init__(self, port: int):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=10)
        self.buffer = b""
        self.odd: list[str] = []  # the replies of another form, asked again
        self.syncs = 0
        for _ in range(5):  # HELLO NAK: its password word taken by another session's request
            self._send("hello EMC rtcal-test-watcher 1.0")
            if (hello := self._line()).startswith("HELLO ACK"):
                break
        assert hello.startswith("HELLO ACK"), hello
        self._send("set echo off")
        assert self._line() == "set echo off"  # its echo (written before it is parsed); verbose off: no reply

    def _send(self, line: str) -> None:
        self.sock.sendall(line.encode() + b"\r\n")

    def _line(self, timeout_s: float = 10.0) -> str:
        deadline = time.monotonic() + timeout_s
        while True:
            while b"\n" in self.buffer:
                raw, self.buffer = self.buffer.split(b"\n", 1)
                if raw.strip():
                    return raw.decode(errors="replace").strip()
            self.sock.settimeout(max(deadline - time.monotonic(), 1e-3))
            chunk = self.sock.recv(4096)  # socket.timeout past the deadline
            assert chunk, "linuxcncrsh closed the watcher's connection"
            self.buffer += chunk

    def ask(self, line: str) -> str:
        """The reply to ``line`` of its form (``get ITEM ARGS`` → ``ITEM ARGS …``, ``set ITEM …`` → ``SET ITEM …``)."""
        verb, item, *args = line.split()
        form = " ".join([item.upper(), *args]) + " " if verb == "get" else f"SET {item.upper()} "
        for _ in range(5):
            self._send(line)
            if (reply := self._line()).startswith(form):
                return reply
            self.odd.append(reply)
            while True:  # back in step: every line up to the marker's own reply dropped
                self.syncs += 1
                self._send(f"get WATCHER_SYNC_{self.syncs}")
                try:
                    while self._line(2.0) != f"GET WATCHER_SYNC_{self.syncs} NAK":
                        pass
                    break
                except socket.timeout:
                    continue  # the marker's words taken too: another one
        raise AssertionError(f"{line!r}: only replies of another form {self.odd[-5:]}")

    def position_deg(self) -> float:
        return float(self.ask("get abs_act_pos 5").split()[2])

    def when(self, test, timeout_s: float = 60.0) -> float:
        deadline = time.monotonic() + timeout_s
        while not test(at := self.position_deg()):
            assert time.monotonic() < deadline, f"the table never got there (at {at:.3f}°)"
            time.sleep(0.01)
        return at

    def at_rest(self, since_s: float, timeout_s: float = 10.0) -> tuple[float, float]:
        """(seconds from ``since_s`` until the table came to rest, where): the last change seen before
        AT_REST_S without one, LinuxCNC's status saying IDLE (on a loaded host its status may go
        unrefreshed for longer than AT_REST_S, repeating a moving table's position — and RUNNING)."""
        last, changed_s = self.position_deg(), time.monotonic()
        while time.monotonic() - changed_s < AT_REST_S:
            assert time.monotonic() - since_s < timeout_s, f"the table still moves {timeout_s:g} s after the stop"
            time.sleep(0.01)
            now = self.position_deg()
            if abs(now - last) > 1e-6 or self.ask("get program_status").split()[1:] != ["IDLE"]:
                last, changed_s = now, time.monotonic()
        return changed_s - since_s, last

    def close(self) -> None:
        self.sock.close()


def events(run_dir: Path, kind: str) -> list[str]:
    with sqlite3.connect(f"file:{run_dir / 'run.sqlite'}?mode=ro", uri=True) as db:
        return [m for (m,) in db.execute("SELECT message FROM events WHERE kind = ? ORDER BY id", (kind,))]


def policy_abort_procedure(tmp_path: Path) -> Path:
    """The short ISO test whose stage gives up at its first fault: a move that outlasts move_timeout_s."""
    data = yaml.safe_load(SHORT.read_text(encoding="utf-8"))
    data["on_fault"]["stage"] = {"retries": 0, "backoff_s": 0.0, "then": "abort"}
    path = tmp_path / "abort_at_first_fault.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True), encoding="utf-8")
    return path


def start_run(*args: str) -> tuple[subprocess.Popen, dict[str, str], list[str]]:
    """`rtcal run ARGS` in a process (SIGINT at its default, as at a terminal), its stderr read line by
    line as it comes (a thread: the live view's lines come together, and a select on the pipe would not
    see the second one already read into the buffer); returns once it can be ended — its control socket
    exists, or with --live its `control token:` was printed."""
    proc = subprocess.Popen([sys.executable, "-m", "rtcal.cli", *args], cwd=REPO, stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    seen: dict[str, str] = {}
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(proc.stderr), daemon=True).start()  # type: ignore[arg-type]
    threading.Thread(target=proc.stdout.read, daemon=True).start()  # type: ignore[union-attr]
    run_dir = Path(args[args.index("--out") + 1])
    deadline = time.monotonic() + 60
    while proc.poll() is None and time.monotonic() < deadline:
        seen.update(line.strip().split(": ", 1) for line in list(lines) if line.startswith(("live view:", "control token:")))
        if ("control token" in seen) if "--live" in args else (run_dir / SOCKET_NAME).exists():
            return proc, seen, lines
        time.sleep(0.05)
    raise AssertionError(f"the run could not be ended: exit {proc.poll()}, {''.join(lines)[-2000:]}")


def _end(how: str, proc: subprocess.Popen, seen: dict[str, str]) -> None:
    if how.startswith("SIG"):
        proc.send_signal(getattr(signal, how))
    else:
        request = urllib.request.Request(seen["live view"] + "api/abort", method="POST", data=b"",
                                         headers={"Authorization": f"Bearer {seen['control token']}"})
        with urllib.request.urlopen(request, timeout=10) as reply:
            assert reply.status == 202


def test_every_way_a_run_ends_stops_a_real_linuxcnc_move_where_the_store_says(tmp_path):
    """Issue 40: Ctrl-C at 21° of a 0→90° move, the run exits, the table goes on to 90° and the store says
    every machine was stopped. Now: each ending stops the table within BOUND_S, far short of its target,
    and the store's `stopped` event names the position a second session sees."""
    figures = []
    with linuxcnc_bench() as addresses:
        port = int(re.search(r":(\d+)\?", addresses["stage"]).group(1))
        slow = dict(addresses, stage=addresses["stage"] + f"&speed_deg_per_s={SPEED_DEG_PER_S:g}")
        watcher = Watcher(port)
        try:
            for how in ("SIGINT", "SIGTERM", "SIGHUP", "page", "policy"):
                run_dir = tmp_path / how
                stage = slow["stage"] + ("&move_timeout_s=3" if how == "policy" else "")
                procedure = policy_abort_procedure(tmp_path) if how == "policy" else SHORT
                live = ("--live", "127.0.0.1:0") if how == "page" else ()
                proc, seen, lines = start_run("run", str(procedure), "--instruments", json.dumps(dict(slow, stage=stage)),
                                              "--out", str(run_dir), *live)
                try:
                    watcher.when(lambda deg: deg < 1.0)
                    if how == "policy":  # its 3 s move timeout ends the move from 0° at about 30°
                        asked_at = watcher.when(lambda deg: deg > 29.0)
                        asked_s = time.monotonic()
                    else:
                        asked_at = watcher.when(lambda deg: deg > STOP_AT_DEG)
                        asked_s = time.monotonic()
                        _end(how, proc, seen)
                    took_s, rest_deg = watcher.at_rest(asked_s)
                    proc.wait(60)
                    time.sleep(0.2)  # the reader thread takes the last lines
                    err = "".join(lines)
                finally:
                    if proc.poll() is None:
                        proc.kill()
                figures.append(f"{how}: asked at {asked_at:.3f}°, at rest at {rest_deg:.3f}° {took_s:.2f} s later")
                assert proc.returncode == (1 if how == "policy" else 130), err
                assert "Traceback" not in err and "may still be moving" not in err, err
                assert rest_deg < TARGET_DEG - 40.0, figures[-1]
                if how != "policy":
                    assert took_s < BOUND_S, figures[-1]
                (stopped,) = events(run_dir, "stopped")
                assert stopped.startswith("stopped: seen at rest at "), stopped
                assert abs(float(stopped.split("at rest at ")[1].rstrip("°")) - rest_deg) < 1e-3, (stopped, rest_deg)
                assert not events(run_dir, "moving")
                abort = events(run_dir, "abort")[-1]
                if how != "policy":
                    assert "every machine the run moved was stopped (stage seen at rest at" in abort, abort
                time.sleep(0.5)
                assert abs(watcher.position_deg() - rest_deg) < 1e-6  # still there after the run has gone
        finally:
            watcher.close()
    print("LinuxCNC stop figures: " + "; ".join(figures) + f" (the watcher asked again {len(watcher.odd)} times)")


def _check(address: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "rtcal.cli", "probe", "stage", address, "--timeout-s", "5"],
                          cwd=REPO, capture_output=True, text=True, timeout=60)


def test_the_axis_letter_is_checked_against_a_real_four_axis_machine():
    """Issue 40: on X Y Z C (trivkins coordinates=XYZC: C is joint 3) `axis=Z&joint=3` moved Z 30 mm while
    rtcal reported the table at 30°. Refused, one line, exit 2 — the letter at the address, the joint
    against the INI's kinematics; `axis=C&joint=3` moves C and nothing else."""
    from drivers.factory import open_stage

    with one_linuxcnc_at_a_time():
        linuxcnc = LinuxCncProcess(machine="xyzc")
        try:
            port = linuxcnc.start()
            base = f"linuxcncrsh://127.0.0.1:{port}"
            for options, named in (("axis=Z&joint=3", "a LinuxCNC rotary axis is A, B or C"),
                                   ("axis=A&joint=3", "no axis A; joint 3 is C: give axis=C"),
                                   ("axis=C&joint=2", "joint 2 of this LinuxCNC is linear in mm"),
                                   ("axis=C&joint=0", "joint 0 of this LinuxCNC is linear in mm")):
                probe = _check(f"{base}?{options}")
                assert probe.returncode == 2 and named in probe.stderr, (options, probe.stderr)
                assert len(probe.stderr.strip().splitlines()) == 1, probe.stderr
            stage = open_stage(f"{base}?axis=C&joint=3&take_control=1", (-400.0, 400.0), 5.0)
            try:
                assert "axis C is joint 3 (trivkins coordinates=XYZC)" in stage.identity()
                stage.move_to(30.0)
                assert abs(stage.feedback_deg() - 30.0) < 2e-6
            finally:
                stage.close()
            watcher = Watcher(port)
            try:
                assert [watcher.ask(f"get abs_act_pos {i}").split()[-1] for i in (0, 1, 2)] == ["0.000000"] * 3
            finally:
                watcher.close()
        finally:
            linuxcnc.stop()


def test_a_program_running_in_auto_is_refused_at_connect_naming_it(tmp_path):
    """Issue 40: connecting while a program ran in AUTO waited ~17 s, then failed at the first move."""
    from drivers.errors import InstrumentFault
    from drivers.factory import open_stage

    with one_linuxcnc_at_a_time():
        linuxcnc = LinuxCncProcess()
        try:
            port = linuxcnc.start()
            program = Path(linuxcnc.folder) / "slow.ngc"
            program.write_text("G1 C60 F600\nG1 C0 F600\nM2\n")
            program.chmod(0o644)
            operator = Watcher(port)  # an operator's console runs it (not waiting for it to end)
            try:
                for line in ("set verbose on", "set enable EMCTOO", "set set_wait received", "set mode auto",
                             f"set open {program}", "set run"):
                    assert operator.ask(line).endswith("ACK"), line
                operator.when(lambda deg: deg > 1.0)
            finally:
                operator.close()
            started = time.monotonic()
            with pytest.raises(InstrumentFault, match=r"running a program in AUTO mode \(.*slow.ngc, running\)"):
                open_stage(f"linuxcncrsh://127.0.0.1:{port}?take_control=1", (-400.0, 400.0), 5.0)
            assert time.monotonic() - started < 2.0
            probe = _check(f"linuxcncrsh://127.0.0.1:{port}")
            assert probe.returncode == 1 and "running a program in AUTO mode" in probe.stderr, probe.stderr
        finally:
            linuxcnc.stop()
