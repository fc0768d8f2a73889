"""Issue 33: a machine's OPC 40001-1 identification over OPC UA (asyncua's client against
asyncua's server, on loopback): `rtcal probe machine`, `rtcal sim serve --opcua`, and a
procedure's `metadata.machine_identity` that fills the item and refuses another machine."""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from rtcal.cli import main
from rtcal.methods import load_procedure
from rtcal.run.runner import with_machine_identity
from simulators.opcua_machine import DECOY_SERIAL, DEFAULT_IDENTITY, SECOND_MACHINE, OpcUaMachine

REPO = Path(__file__).resolve().parents[1]
PROCEDURE = REPO / "procedures" / "iso230_2_verification.yaml"


@pytest.fixture()
def machine():
    m = OpcUaMachine(identity={"SerialNumber": "SN-4711", "Model": "RT-200"})
    yield m
    m.close()


def test_probe_reads_the_identification_by_the_machinery_namespace(machine, capsys):
    assert main(["probe", "machine", machine.address, "--json"]) == 0
    ident = json.loads(capsys.readouterr().out)
    assert ident["serial_number"] == "SN-4711" and ident["model"] == "RT-200"
    assert ident["manufacturer"] == DEFAULT_IDENTITY["Manufacturer"]
    assert ident["year_of_construction"] == DEFAULT_IDENTITY["YearOfConstruction"]
    assert ident["software_revision"] == DEFAULT_IDENTITY["SoftwareRevision"]


def test_a_machine_that_does_not_answer_is_exit_1_in_one_line(capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    assert main(["probe", "machine", f"opc.tcp://127.0.0.1:{port}", "--timeout-s", "1"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err


def _procedure(tmp_path: Path, address: str, serial: str | None) -> Path:
    """The shipped ISO verification naming the machine's server (and ``serial``, or none), its bench beside it."""
    text = PROCEDURE.read_text()
    line = "  serial_number: SIM-230-2\n"
    assert line in text
    text = text.replace(line, (f"  serial_number: {serial}\n" if serial else "") + f"  machine_identity: '{address}'\n")
    path = tmp_path / "proc.yaml"
    path.write_text(text)
    (tmp_path / "scenarios").mkdir(exist_ok=True)  # the bench lies in the procedure's folder (a link would not)
    bench = REPO / "procedures" / "scenarios" / "abbe_bench.yaml"
    (tmp_path / "scenarios" / bench.name).write_text(bench.read_text())
    return path


def test_another_machines_serial_number_refuses_the_run_before_anything(machine, tmp_path, capsys):
    path = _procedure(tmp_path, machine.address, "SIM-230-2")
    assert main(["run", str(path), "--virtual-clock", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "metadata.machine_identity" in err and "SN-4711" in err
    assert re.match(rf"{re.escape(str(path))}:\d+:", err)
    assert not (tmp_path / "run" / "run.sqlite").exists()


def test_the_machines_identification_fills_the_item(machine, tmp_path):
    path = _procedure(tmp_path, machine.address, None)
    proc = load_procedure(path)
    filled, read = with_machine_identity(proc, path, path.read_text())
    assert read is not None and read["serial_number"] == "SN-4711"
    assert filled.metadata.serial_number == "SN-4711"
    assert filled.metadata.machine == proc.metadata.machine  # the procedure's own name is kept


def test_sim_serve_opcua_serves_the_identity():
    proc = subprocess.Popen([sys.executable, "-m", "rtcal.cli", "sim", "serve", "--opcua", "--no-pacing"], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        address = None
        for _ in range(50):
            line = proc.stderr.readline()
            if m := re.search(r"machine identity \(OPC UA\): (opc\.tcp://\S+)", line):
                address = m.group(1)
                break
        assert address, "no OPC UA address printed"
        def probe(where: str) -> subprocess.CompletedProcess:
            return subprocess.run([sys.executable, "-m", "rtcal.cli", "probe", "machine", where, "--json"], cwd=REPO,
                                  capture_output=True, text=True, timeout=60, env={**os.environ, "PYTHONPATH": str(REPO)})

        r = probe(f"{address}?serial={DEFAULT_IDENTITY['SerialNumber']}")
        assert r.returncode == 0, r.stderr
        assert json.loads(r.stdout)["serial_number"] == DEFAULT_IDENTITY["SerialNumber"]
        # laid out as OPC 40001-1 does: a second machine beside the table, so a choice is needed
        r = probe(address)
        assert r.returncode == 1 and "2 machines under Machines" in r.stderr and len(r.stderr.splitlines()) == 1
        r = probe(f"{address}?machine={SECOND_MACHINE[0]}")
        assert json.loads(r.stdout)["serial_number"] == SECOND_MACHINE[1]["SerialNumber"] != DECOY_SERIAL
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(30)


def test_the_refusal_names_the_line_of_metadata_machine_identity(machine, tmp_path, capsys):
    """Issue 46 item 9: the line was that of the first text naming machine_identity (a comment above it, here)
    and, with --certificate-number, of the text rtcal had rewritten; it is the key's own line in the user's file."""
    path = _procedure(tmp_path, machine.address, "SIM-230-2")
    text = "# metadata.machine_identity: the machine's nameplate, read over OPC UA\n" + path.read_text()
    path.write_text(text)
    line = next(i for i, t in enumerate(text.splitlines(), 1) if t.startswith("  machine_identity:"))
    assert line > 2
    for extra in ([], ["--certificate-number", "EML-1"]):
        assert main(["run", str(path), "--virtual-clock", "--out", str(tmp_path / "run"), *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith(f"{path}:{line}:") and "metadata.machine_identity" in err, err
