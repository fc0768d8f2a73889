"""Issue 26, items 2-7: outputs checked against the store, one fence for every driver, addresses
and secrets, bounded simulated benches, the operator's emergency stop, a Modbus drive that
serves each connection on its own, and `resume` of a finished run."""

from __future__ import annotations

from rtcal.results.model import SCHEMA_VERSION
import json
import math
import os
import shutil
import socket
import sqlite3
import struct
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from drivers import models
from drivers.addresses import parse_address
from drivers.interfaces import DialIndicator
from rtcal.cli import main

REPO = Path(__file__).resolve().parents[1]
PROCEDURE = REPO / "procedures" / "laser_tracer_multistation.yaml"


def _one_line(capsys, code: int, argv: list[str]) -> str:
    """Run the command; it must exit ``code`` with one line on stderr and no traceback."""
    capsys.readouterr()
    assert main(argv) == code, argv
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err[:1000]
    return err


# -- 2. digests ------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def solved(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("solved") / "run"
    assert main(["run", str(PROCEDURE), "--out", str(out)]) == 0
    return out


def _copy(run: Path, tmp_path: Path, name: str = "copy") -> Path:
    target = tmp_path / name / "run"
    shutil.copytree(run, target, ignore=shutil.ignore_patterns(".rtcal.lock"))
    return target


def test_results_and_store_record_each_others_digests_and_a_copied_run_stays_valid(solved, tmp_path, capsys):
    results = json.loads((solved / "results.json").read_text())
    assert results["schema_version"] == SCHEMA_VERSION
    d = results["digests"]
    with sqlite3.connect(solved / "run.sqlite") as db:
        readings = db.execute("SELECT COUNT(*) FROM readings").fetchone()[0]
        recorded = db.execute("SELECT value FROM meta WHERE key = 'results_sha256'").fetchone()[0]
    import hashlib

    assert d["readings"] == readings and len(d["readings_sha256"]) == 64
    assert recorded == hashlib.sha256((solved / "results.json").read_bytes()).hexdigest()
    copy = _copy(solved, tmp_path)  # another place: no digest covers a path
    capsys.readouterr()
    assert main(["evaluate", str(copy)]) == 0
    assert main(["verify", str(copy)]) == 0
    assert f"{copy} agrees: 0 differ of " in capsys.readouterr().out


def _edit_results(run: Path, edit) -> None:
    data = json.loads((run / "results.json").read_text())
    edit(data)
    (run / "results.json").write_text(json.dumps(data, indent=2) + "\n")


def _every_seventh_plus_5(data: dict) -> None:
    table = data["positioning_deviations"]["deviation_arcsec"]
    for i in range(1, len(table), 7):
        table[i] += 5.0


def _zero_uncertainties(data: dict) -> None:
    u = data["positioning_deviations"]["uncertainty_arcsec"]
    data["positioning_deviations"]["uncertainty_arcsec"] = [0.0 for _ in u]


@pytest.mark.parametrize("edit", [_every_seventh_plus_5, _zero_uncertainties], ids=["plus-5-every-7th", "u-zero"])
def test_an_edited_results_file_is_refused_by_every_reading_command_and_found_by_verify(solved, tmp_path, capsys, edit):
    run = _copy(solved, tmp_path)
    _edit_results(run, edit)
    for argv in (["evaluate", str(run)], ["compensate", str(run), "--format", "linuxcnc", "--out", str(tmp_path / "c.comp")],
                 ["compare", str(solved), str(run), "--out", str(tmp_path)], ["resume", str(run)]):
        err = _one_line(capsys, 2, argv)
        assert "does not match the digest" in err and str(run / "results.json") in err, err
    assert not (tmp_path / "c.comp").exists()
    capsys.readouterr()
    assert main(["verify", str(run)]) == 1
    captured = capsys.readouterr()
    assert "does NOT agree" in captured.out and "positioning_deviations" in captured.err


def test_an_edited_store_is_refused_and_found_by_verify(solved, tmp_path, capsys):
    run = _copy(solved, tmp_path)
    with sqlite3.connect(run / "run.sqlite") as db:
        db.execute("UPDATE readings SET value = value + 0.001 WHERE id = (SELECT MIN(id) FROM readings WHERE quantity = 'length_mm')")
    err = _one_line(capsys, 2, ["evaluate", str(run)])
    assert "its readings" in err and "run.sqlite" in err
    assert main(["verify", str(run)]) == 1


def test_results_without_their_digests_or_store_are_refused(solved, tmp_path, capsys):
    run = _copy(solved, tmp_path, "nodigest")
    _edit_results(run, lambda d: d.pop("digests"))
    assert "does not match the digest" in _one_line(capsys, 2, ["evaluate", str(run)])
    alone = _copy(solved, tmp_path, "alone")
    os.unlink(alone / "run.sqlite")
    assert "run.sqlite is missing" in _one_line(capsys, 2, ["evaluate", str(alone)])


def _csv(tmp_path: Path, rows: list[tuple[float, int, float, str]]) -> Path:
    path = tmp_path / "d.csv"
    path.write_text("target_deg,direction,run,deviation_arcsec,uncertainty_arcsec\n"
                    + "".join(f"{t},{d},1,{x},{u}\n" for t, d, x, u in rows))
    return path


@pytest.mark.parametrize("rows, expect", [
    ([(0, 1, 0.0, "0.5"), (90, 1, 1.2e6, "0.5"), (180, 1, -3.0, "0.5"), (270, 1, 2.0, "0.5")], "beyond ±3600″"),
    ([(0, 1, 0.0, "0"), (90, 1, 4.0, "0"), (180, 1, -3.0, "0"), (270, 1, 2.0, "0")], "uncertainty 0″"),
])
def test_values_no_rotary_table_has_are_refused(tmp_path, capsys, rows, expect):
    both = [(t, d, x, u) for t, _, x, u in rows for d in (1, -1)]
    path = _csv(tmp_path, both)
    for argv in (["evaluate", str(path)], ["compensate", str(path), "--format", "linuxcnc", "--out", str(tmp_path / "c")],
                 ["compare", str(path), str(path), "--out", str(tmp_path)]):
        assert expect in _one_line(capsys, 2, argv)
    assert not (tmp_path / "c").exists()
    ok = _csv(tmp_path, [(t, d, x if abs(x) < 3600 else 10.0, "0.5" if x else "0") for t, d, x, _ in both])
    assert main(["evaluate", str(ok)]) == 0  # the same table with plausible values is evaluated


def test_a_trim_beyond_the_formats_bound_is_refused():
    from rtcal.deliverables.compensation import MAX_TRIM_ARCSEC, CompensationError, CompensationTable, write_table

    positions = np.array([0.0, 90.0, 180.0, 270.0, 360.0])
    ok = CompensationTable(positions, np.full(5, 0.5), np.full(5, 0.5))  # 0.5° = 1800″
    assert write_table("linuxcnc", ok)
    for fmt in MAX_TRIM_ARCSEC:
        bad = CompensationTable(positions, np.array([0, 133.0, 0, 0, 0]), np.zeros(5))
        with pytest.raises(CompensationError, match="beyond ±3600″"):
            write_table(fmt, bad)


def test_resume_of_a_finished_run_says_it_is_finished(solved, tmp_path, capsys):
    run = _copy(solved, tmp_path)
    before = (run / "results.json").read_bytes()
    capsys.readouterr()
    assert main(["resume", str(run)]) == 0
    assert capsys.readouterr().out.startswith("run already finished:")
    assert (run / "results.json").read_bytes() == before


# -- 3. one fence for every driver --------------------------------------------------------------------

class _PluginIndicator(DialIndicator):
    """A plugin's dial indicator whose behaviour each test picks (``MODE``)."""

    kind, model, schemes, name = "dial_indicator", "test-indicator", ("serial",), "dial_indicator"
    MODE = "nan"

    def __init__(self, address, timeout_s: float = 1.0, **context):
        if self.MODE == "raise-built":
            raise ZeroDivisionError("division by zero in the vendor SDK")

    def identity(self) -> str:
        return "X" * 10_000_000 if self.MODE == "huge-identity" else "ACME indicator"

    def read_um(self) -> float:
        if self.MODE == "raise-read":
            raise KeyError("buffer")
        return {"nan": math.nan, "inf": math.inf, "far": 5e8, "text": "12.5"}.get(self.MODE, 12.5)  # type: ignore[return-value]


@pytest.fixture()
def plugin(monkeypatch):
    model = models.Model("test-indicator", "dial_indicator", f"{__name__}:_PluginIndicator", ("serial",),
                         plugin="rtcal-test-indicator")
    monkeypatch.setattr(models.MODELS, "_plugins", {"test-indicator": model})
    return _PluginIndicator


@pytest.mark.parametrize("mode, expect", [
    ("nan", "outside what a dial indicator can read"), ("inf", "outside what a dial indicator can read"),
    ("far", "outside what a dial indicator can read"), ("text", "is not a number"),
    ("raise-built", "its constructor raised ZeroDivisionError"), ("raise-read", "read_um raised KeyError"),
])
def test_a_plugins_bad_reading_or_failure_is_exit_1_naming_the_plugin(plugin, monkeypatch, capsys, mode, expect):
    monkeypatch.setattr(plugin, "MODE", mode)
    err = _one_line(capsys, 1, ["probe", "dial_indicator", "socket://127.0.0.1:9?model=test-indicator"])
    assert expect in err and "rtcal-test-indicator" in err, err


def test_a_plugins_identity_is_bounded(plugin, monkeypatch, capsys):
    monkeypatch.setattr(plugin, "MODE", "huge-identity")
    capsys.readouterr()
    assert main(["probe", "dial_indicator", "socket://127.0.0.1:9?model=test-indicator", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert len(out["identity"]) <= 200 and out["reading"]["displacement_mm"] == pytest.approx(0.0125)


def test_every_opened_driver_is_fenced():
    from drivers import factory
    from drivers.fence import FencedDialIndicator

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(models.MODELS, "_plugins", {"test-indicator": models.Model(
            "test-indicator", "dial_indicator", f"{__name__}:_PluginIndicator", ("serial",), plugin="p")})
        mp.setattr(_PluginIndicator, "MODE", "ok")
        inst = factory.open_instrument("dial_indicator", "socket://h:9?model=test-indicator", 1.0)
        assert isinstance(inst, FencedDialIndicator) and inst.read_um() == 12.5


def test_a_drive_feedback_of_int_min_is_a_fault(capsys):
    from simulators.scenario import Scenario
    from simulators.servers.hub import SimulatorHub

    with SimulatorHub(Scenario(), seed=1, serial="tcp") as hub:
        hub.drive.feedback_steps = -(1 << 31)
        err = _one_line(capsys, 1, ["probe", "stage", hub.addresses["stage"], "--timeout-s", "1"])
    assert "INT_MIN" in err or "outside what a stage can read" in err, err


# -- 4. addresses and secrets ----------------------------------------------------------------------

@pytest.mark.parametrize("address, expect", [
    ("modbus-tcp://[::1:5", "malformed address"),
    ("modbus-tcp://user:pw@10.0.0.5:502", "credentials"),
    ("ipp://operator:secret@cmm:1294", "credentials"),
    ("modbus-tcp://10.0.0.5:５０２", "not a printable ASCII character"),
    ("modbus-tcp://ｃｍｍ.example:502", "not a printable ASCII character"),
    ("socket://[fe80::1:4001?model=sylvac", "malformed address"),
    ("modbus-tcp://10.0.0.5:502/extra", "nothing may follow HOST:PORT"),
    ("modbus-tcp://10.0.0.5:99999", "bad port (1 to 65535)"),
])
def test_a_malformed_address_is_one_line_exit_2(capsys, address, expect):
    kind = "dial_indicator" if address.startswith("socket") else "stage" if address.startswith("modbus") else "cmm"
    assert expect in _one_line(capsys, 2, ["probe", kind, address])


def test_no_token_is_stored_and_a_resume_asks_for_it(tmp_path, monkeypatch):
    from drivers.addresses import redact_tokens
    from rtcal.run.rundir import RunDirError, RunLock
    from rtcal.run.runner import _stored_operator
    from rtcal.store.runstore import RunStore

    token = "s3cretTOKEN_abcdef"
    address = f"sim-operator://127.0.0.1:4000?token={token}"
    store = RunStore.create(tmp_path, {"method": "encoder_abbe_error", "operator_address": address,
                                       "instruments": json.dumps({"stage": {"address": f"x?token={token}"}})})
    store.set_meta({"error": f"OperatorUnavailable('{address}')"})
    store.add_event(0.0, "resume", f"resumed with {address}")
    store.close()
    monkeypatch.setattr("sys.argv", ["rtcal", "resume", str(tmp_path), "--instruments", json.dumps({"operator": address})])
    lock = RunLock(tmp_path).acquire()
    held = (tmp_path / ".rtcal.lock").read_bytes()
    lock.release()
    assert token.encode() not in held and b"token=" in held
    for path in tmp_path.iterdir():
        if path.is_file():
            assert token.encode() not in path.read_bytes(), path
    meta = dict(sqlite3.connect(tmp_path / "run.sqlite").execute("SELECT key, value FROM meta"))
    assert meta["operator_address"] == redact_tokens(address) == "sim-operator://127.0.0.1:4000?token=…"
    monkeypatch.delenv("RTCAL_OPERATOR_TOKEN", raising=False)
    with pytest.raises(RunDirError, match="--instruments .* or set RTCAL_OPERATOR_TOKEN"):
        _stored_operator(meta, tmp_path)
    monkeypatch.setenv("RTCAL_OPERATOR_TOKEN", token)
    assert _stored_operator(meta, tmp_path) == address


def test_a_token_is_never_echoed_in_a_message(capsys):
    err = _one_line(capsys, 2, ["check", str(PROCEDURE), "--instruments",
                                json.dumps({"operator": "sim-operator://h:[1?token=SECRETSECRET"})])
    assert "SECRETSECRET" not in err


def _ipp(sock_file, line: str) -> list[str]:
    sock_file.write(line.encode() + b"\r\n")
    sock_file.flush()
    replies = []
    while True:
        reply = sock_file.readline().decode().rstrip("\r\n")
        replies.append(reply)
        if reply.endswith(" %") or not reply:
            return replies


def test_the_simulated_cmm_releases_a_session_left_idle():
    from simulators.scenario import Scenario
    from simulators.servers.hub import SimulatorHub

    with SimulatorHub(Scenario(), seed=1, serial="tcp", ipp_idle_timeout_s=1.5) as hub:
        a = parse_address(hub.addresses["cmm"])
        with socket.create_connection((a.host, a.port), timeout=5) as silent, \
                socket.create_connection((a.host, a.port), timeout=5) as other:
            first, second = silent.makefile("rwb"), other.makefile("rwb")
            assert _ipp(first, "00001 StartSession()") == ["00001 &", "00001 %"]
            refused = _ipp(second, "00001 StartSession()")
            assert any("Another client holds the session" in r for r in refused), refused  # after a 0.5 s grace
            time.sleep(1.5)  # the first stays silent beyond the idle time
            assert _ipp(second, "00002 StartSession()") == ["00002 &", "00002 %"]
            assert first.readline() == b""  # its connection was closed


# -- 5. bounded simulated benches --------------------------------------------------------------------

@pytest.mark.parametrize("text, field, line", [
    ("stage:\n  speed_deg_per_s: 1.0e-300\n", "stage.speed_deg_per_s", 2),
    ("seed: 1\nlaser_tracer:\n  length_noise_um: 5000\n", "laser_tracer.length_noise_um", 3),
    ("cmm:\n  point_noise_um: 1.0e6\n", "cmm.point_noise_um", 2),
    ("stage:\n  positioning_error:\n    - {order: 1, amplitude_arcsec: 3000}\n    - {order: 2, amplitude_arcsec: 3000}\n",
     "stage.positioning_error", 2),
    ("stage:\n  radial_motion_x:\n    - {order: 1, amplitude_um: 9000}\n", "stage.radial_motion_x", 2),
])
def test_a_bench_beyond_any_real_one_is_refused_located(tmp_path, capsys, text, field, line):
    path = tmp_path / "bench.yaml"
    path.write_text(text)
    capsys.readouterr()
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"{path}:{line}:" in err and field in err, err
    assert main(["run", str(PROCEDURE), "--scenario", str(path), "--out", str(tmp_path / "run")]) == 2
    assert not (tmp_path / "run" / "run.sqlite").exists()


# -- 6. the operator port's emergency stop ----------------------------------------------------------

def _operator_line(address: str, line: bytes, read: bool = True) -> bytes:
    a = parse_address(address)
    with socket.create_connection((a.host, a.port), timeout=5) as s:
        s.sendall(line)
        return s.makefile("rb").readline() if read else b""


def test_only_the_token_holder_releases_an_emergency_stop():
    from simulators.scenario import Scenario
    from simulators.servers.hub import SimulatorHub

    with SimulatorHub(Scenario(), seed=1, serial="tcp") as hub:
        address, token = hub.addresses["operator"], hub.operator_token
        hub.bench.emergency_stop = True
        assert _operator_line(address, b"AUTH wrongtoken1 CLEAR\n") == b"ERR AUTH\n"
        assert _operator_line(address, b"CLEAR\n") == b"ERR AUTH\n"
        _operator_line(address, b"AUTH wrongtoken1 CLE", read=False)  # a connection that ends mid-line
        _operator_line(address, b"", read=False)  # one that ends without a word
        time.sleep(0.2)
        assert hub.bench.emergency_stop, "released by a connection without the token"
        _operator_line(address, f"AUTH {token} CERT?\n".encode())  # the holder's connection ends: still pressed
        time.sleep(0.2)
        assert hub.bench.emergency_stop
        assert _operator_line(address, f"AUTH {token} CLEAR\n".encode()) == b"OK\n"
        assert not hub.bench.emergency_stop


# -- 7. the simulated Modbus drive serves each connection on its own ----------------------------------

def test_frames_for_other_units_on_one_connection_leave_another_clients_replies_alone():
    from drivers.modbus_stage import ModbusStage
    from simulators.scenario import Scenario
    from simulators.servers.hub import SimulatorHub

    with SimulatorHub(Scenario(), seed=1, serial="tcp") as hub:
        a = parse_address(hub.addresses["stage"])
        stop, sent = threading.Event(), [0]

        def hostile() -> None:
            with socket.create_connection((a.host, a.port), timeout=5) as s:
                tid = 0
                while not stop.is_set():
                    for unit in (0, 255):
                        tid = (tid + 1) & 0xFFFF
                        s.sendall(struct.pack(">HHHBBHH", tid, 0, 6, unit, 3, 0x00CC, 2))
                        sent[0] += 1
                    time.sleep(0.0002)

        thread = threading.Thread(target=hostile, daemon=True)
        stage = ModbusStage(a, limits_deg=(-360.0, 360.0), timeout_s=0.5)
        try:
            stage.move_to(12.5)
            thread.start()
            time.sleep(0.05)
            readings = [stage.feedback_deg() for _ in range(300)]
        finally:
            stop.set()
            thread.join(5)
            stage.close()
    assert sent[0] > 300 and readings == [pytest.approx(12.5)] * 300


def test_resuming_a_wired_run_without_the_operators_token_says_where_to_give_it(solved, tmp_path, capsys, monkeypatch):
    run = _copy(solved, tmp_path)
    with sqlite3.connect(run / "run.sqlite") as db:
        db.execute("UPDATE meta SET value = 'interrupted' WHERE key = 'status'")
        db.execute("INSERT OR REPLACE INTO meta(key, value) VALUES ('operator_address', 'sim-operator://127.0.0.1:9?token=…')")
        db.execute("DELETE FROM readings WHERE plan_index = (SELECT MAX(plan_index) FROM readings)")
    monkeypatch.delenv("RTCAL_OPERATOR_TOKEN", raising=False)
    err = _one_line(capsys, 2, ["resume", str(run)])
    assert "token is not stored" in err and "--instruments" in err and "RTCAL_OPERATOR_TOKEN" in err
