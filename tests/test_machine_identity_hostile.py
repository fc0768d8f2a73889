"""Issue 40 item 7: what a machine's OPC UA server says goes through the procedure's validators before
anything moves, is found where OPC 40001-1 puts it (the Machines folder by its standard NodeId, the
DI:SerialNumber by its qualified name), is chosen among several machines or refused as ambiguous, survives a
resume, and is reachable on a server that admits only signed and encrypted sessions. Every server here is
asyncua's, laid out by simulators/opcua_machine.py, some of them hostile."""

from __future__ import annotations

import asyncio
import datetime as dt
import json
from pathlib import Path

import pytest

from drivers.errors import InstrumentError
from drivers.opcua_identity import CERT_ENV, KEY_ENV, read_identity
from rtcal.cli import main
from rtcal.run.runner import run_procedure
from simulators.opcua_machine import DECOY_SERIAL, DEFAULT_IDENTITY, OpcUaMachine, default_machines
from tests.test_machine_identity import _procedure



@pytest.fixture()
def serve():
    started: list[OpcUaMachine] = []

    def start(**kwargs) -> OpcUaMachine:
        started.append(OpcUaMachine(**kwargs))
        return started[-1]

    yield start
    for m in started:
        m.close()


def _refused_before_anything(tmp_path: Path, capsys, address: str, code: int, serial: str | None = None) -> str:
    path = _procedure(tmp_path, address, serial)
    assert main(["run", str(path), "--virtual-clock", "--out", str(tmp_path / "run")]) == code
    lines = capsys.readouterr().err.strip().splitlines()
    if code == 1:  # an instrument error: its line, then where the readings are (none)
        assert lines[1:] == ["rtcal: nothing was measured"], lines
    assert len(lines[0]) < 600 and "Traceback" not in lines[0], lines
    assert not (tmp_path / "run" / "run.sqlite").exists()  # nothing started, nothing moved
    return lines[0]


@pytest.mark.parametrize("serial, shown", [("SN-\u202e1174", "u202e"), ("SN-47\n11", "u000a"), ("SN-47\x0011", "u0000")])
def test_a_control_character_in_the_serial_is_refused_by_the_procedures_validators(serve, tmp_path, capsys, serial, shown):
    machine = serve(identity={"SerialNumber": serial})
    err = _refused_before_anything(tmp_path, capsys, machine.address, 2)
    assert "metadata.machine_identity" in err and "serial_number" in err and shown in err.lower()


def test_a_newline_in_the_model_never_reaches_the_item_line(serve, tmp_path, capsys):
    machine = serve(identity={"Model": "RT-200\nSerial number: FORGED"})
    path = _procedure(tmp_path, machine.address, None)
    text = path.read_text().replace("  machine: Parker 200RT worm-drive stage\n", "")  # the item takes the model
    path.write_text(text)
    assert main(["run", str(path), "--virtual-clock", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "machine" in err and "FORGED" in err
    assert not (tmp_path / "run" / "run.sqlite").exists()


def test_a_100_kB_serial_is_refused_before_anything_moves(serve, tmp_path, capsys):
    machine = serve(identity={"SerialNumber": "S" * 100_000})
    err = _refused_before_anything(tmp_path, capsys, machine.address, 1)
    assert "SerialNumber is 100000 characters long" in err and len(err) < 600


def test_a_serial_longer_than_a_certificate_takes_is_refused_by_its_validator(serve, tmp_path, capsys):
    machine = serve(identity={"SerialNumber": "S" * 150})
    err = _refused_before_anything(tmp_path, capsys, machine.address, 2)
    assert "serial_number" in err and "100 characters" in err


def test_other_types_give_values_or_one_line(serve, capsys):
    from asyncua import ua

    machine = serve(identity={"YearOfConstruction": ua.Variant(dt.datetime(2019, 6, 1), ua.VariantType.DateTime),
                              "SerialNumber": ua.Variant(4711, ua.VariantType.Int32)})
    assert main(["probe", "machine", machine.address, "--json"]) == 0
    ident = json.loads(capsys.readouterr().out)
    assert ident["year_of_construction"] == 2019 and ident["serial_number"] == "4711"
    listed = serve(identity={"Model": ua.Variant(["RT-200", "RT-300"], ua.VariantType.String)})
    assert main(["probe", "machine", listed.address]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Model is an array of 2 values" in err


def test_printed_values_are_bounded_and_printable(serve, capsys):
    machine = serve(identity={"Manufacturer": "ACME\u202e" + "x" * 900})
    assert main(["probe", "machine", machine.address]) == 0
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if x.startswith("manufacturer:"))
    assert "\u202e" not in out and "\\u202e" in line and len(line) < 260


def test_the_machines_folder_is_found_by_its_standard_nodeid(serve):
    machine = serve(standard_folder=False)  # a folder named Machines, but not OPC 40001-1's
    with pytest.raises(InstrumentError, match="no Machines folder at its standard NodeId"):
        read_identity(machine.address)


def test_the_standard_serial_number_is_read_never_a_vendor_property_of_that_name(serve):
    machine = serve(identity={"SerialNumber": "SN-4711"}, decoy=True)
    assert read_identity(machine.address)["serial_number"] == "SN-4711" != DECOY_SERIAL


def test_several_machines_need_a_choice_and_an_ambiguous_one_is_refused(serve, tmp_path, capsys):
    machine = serve(machines=default_machines())
    with pytest.raises(InstrumentError, match="2 machines under Machines"):
        read_identity(machine.address)
    assert read_identity(f"{machine.address}?machine=SimulatedLathe")["serial_number"] == "SIM-LATHE-7"
    assert read_identity(machine.address, serial="SIM-230-2")["machine"] == "SimulatedTable"
    twins = serve(machines={"A": dict(DEFAULT_IDENTITY), "B": dict(DEFAULT_IDENTITY)})
    with pytest.raises(InstrumentError, match="2 machines match serial number 'SIM-230-2'|ambiguous"):
        read_identity(twins.address, serial="SIM-230-2")
    # the procedure's serial number chooses the machine it names
    path = _procedure(tmp_path, machine.address, "SIM-230-2")
    from rtcal.methods import load_procedure
    from rtcal.run.runner import with_machine_identity

    proc, read = with_machine_identity(load_procedure(path), path, path.read_text())
    assert read is not None and read["machine"] == "SimulatedTable"
    err = _refused_before_anything(tmp_path, capsys, twins.address, 1, serial="SIM-230-2")
    assert "ambiguous" in err


def test_resume_keeps_the_identification_read_at_the_start(serve, tmp_path):
    machine = serve(identity={"SerialNumber": "SN-4711", "Model": "RT-200"})
    path = _procedure(tmp_path, machine.address, None)
    run_dir = tmp_path / "run"

    def abort_at_once(engine, _run_dir):
        engine.request_abort("the test")
        return None

    with pytest.raises(KeyboardInterrupt, match="aborted by the test"):  # before its first reading
        run_procedure(path, out_dir=run_dir, show_progress=False, on_engine=abort_at_once)
    assert not (run_dir / "results.json").exists()
    machine.close()  # the server is gone: the resume must not need it
    assert main(["resume", str(run_dir)]) == 0
    results = json.loads((run_dir / "results.json").read_text())
    assert results["starts"] == 2 and results["metadata"]["serial_number"] == "SN-4711"
    certificate = json.loads((run_dir / "certificate.json").read_text())
    item = next(i["value"] for i in certificate["identification"]["items"] if i["label"] == "Item calibrated")
    assert "serial number SN-4711" in item


def _certificates(folder: Path) -> dict[str, Path]:
    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    out = {}
    for who, use in (("server", ExtendedKeyUsageOID.SERVER_AUTH), ("client", ExtendedKeyUsageOID.CLIENT_AUTH)):
        key, cert = folder / f"{who}.pem", folder / f"{who}.der"
        asyncio.run(setup_self_signed_certificate(key, cert, f"urn:rtcal:test:{who}", "localhost", [use],
                                                  {"commonName": f"rtcal test {who}"}))
        out[f"{who}_key"], out[f"{who}_cert"] = key, cert
    return out


def test_a_server_that_admits_only_signed_and_encrypted_sessions_is_reachable(serve, tmp_path, monkeypatch, capsys):
    files = _certificates(tmp_path)
    machine = serve(identity={"SerialNumber": "SN-4711"}, security="sign-and-encrypt",
                    certificate=(files["server_cert"], files["server_key"]))
    monkeypatch.delenv(CERT_ENV, raising=False)
    monkeypatch.delenv(KEY_ENV, raising=False)
    assert main(["probe", "machine", machine.address]) == 1  # no client certificate configured: said so, in one line
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "admits only secured sessions" in err and CERT_ENV in err
    monkeypatch.setenv(CERT_ENV, str(files["client_cert"]))
    monkeypatch.setenv(KEY_ENV, str(files["client_key"]))
    assert read_identity(machine.address)["serial_number"] == "SN-4711"
