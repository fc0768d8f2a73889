"""`rtcal probe` and `rtcal check` against emulators of the real products that share no code with
rtcal (tests/emulators/, written from the public references), and against `rtcal sim serve`.

Values are compared exactly as the emulators print them (float parsing only), angles to 1e-9°.
"""

from __future__ import annotations

import json

import pytest

from drivers import factory
from drivers.addresses import parse_address
from rtcal.cli import main
from tests import emulators as emu
from tests.emulators import AzDriveEmulator, Emulator


def probe(capsys, *args: str) -> tuple[int, str, str]:
    code = main(["probe", *args])
    out, err = capsys.readouterr()
    return code, out, err


def probe_json(capsys, kind: str, address: str) -> dict:
    code, out, err = probe(capsys, kind, address, "--json", "--timeout-s", "1")
    assert code == 0, err
    result = json.loads(out)
    assert list(result) == ["kind", "address", "model", "identity", "reading"]
    assert result["kind"] == kind and result["address"] == address
    return result


def test_probe_stage_reads_the_feedback_position_at_0x00cc(capsys):
    with AzDriveEmulator({0x00CC: 123456, 0x00C6: 999999, 0x007E: 0x4020, 0x0080: 0}) as drive:
        r = probe_json(capsys, "stage", f"modbus-tcp://127.0.0.1:{drive.port}?unit=1&steps_per_rev=10000&gear=36")
    assert r["model"] == "oriental-az" and r["reading"] == {"position_deg": pytest.approx(123.456, abs=1e-9)}
    assert drive.requests[-1][7:] == b"\x03\x00\xcc\x00\x02"  # FC03 at 0x00CC, two registers (the reference's example)


def test_probe_cmm_clears_the_i_plus_plus_error_state(capsys):
    """A first Get answered with a severity-2 error, then 0514 until ClearAllErrors(): the probe
    clears the state and reads."""
    with Emulator(emu.ipp_answer(), b"\r\n") as cmm:
        r = probe_json(capsys, "cmm", cmm.url("ipp"))
    assert r["model"] == "ipp" and r["identity"] == "I++ DME server, DMEVersion 1.4, coordinate system MachineCsy"
    assert r["reading"] == {"x_mm": 1.0, "y_mm": 2.0, "z_mm": 3.0}
    commands = [line[6:].decode() for line in cmm.requests]
    assert commands == ["StartSession()", "GetDMEVersion()", "SetCoordSystem(MachineCsy)", "IsHomed()", "Get(X(), Y(), Z())",
                        "ClearAllErrors()", "Get(X(), Y(), Z())", "EndSession()"]


@pytest.mark.parametrize("kind,answer,terminator,options,model,identity,reading", [
    ("autocollimator", emu.elcomat, b"\n", "", "elcomat",
     "Möller-Wedel ELCOMAT, serial number 30123, focal length 300 mm, date 15.01.2026", {"x_arcsec": 12.34, "y_arcsec": -5.67}),
    ("dial_indicator", emu.sylvac, b"\r", "", "sylvac", "", {"displacement_mm": -0.0123}),
    ("encoder", emu.qsb, b"\n", "&counts_per_rev=3600000", "qsb", "US Digital QSB, VERSION register 0x00020304",
     {"angle_deg": 128162 * 360 / 3600000}),
    ("laser_tracer", emu.tracer, b"\n", "", "rtcal-line", "", {"length_mm": 1.234567125}),
])
def test_probe_serial_products(capsys, kind, answer, terminator, options, model, identity, reading):
    with Emulator(answer, terminator) as device:
        r = probe_json(capsys, kind, f"{device.url()}?model={model}{options}")
    assert r["model"] == model and r["identity"] == identity
    assert r["reading"] == pytest.approx(reading, abs=1e-12)


def test_probe_vaisala_ptu300_with_the_thermometer(capsys):
    with Emulator(emu.vaisala("PTU300")) as ptu, Emulator(emu.ithx) as thermometer:
        r = probe_json(capsys, "environment", f"{ptu.url()}?model=vaisala-ptu300&thermometer={thermometer.url()}")
    assert r["identity"] == "PTU300 / 1.12, serial number P4040154"
    assert r["reading"] == pytest.approx({"air_temperature_c": 17.7, "air_pressure_pa": 100380.0, "humidity_pct": 40.9,
                                          "material_temperature_c": 25.1})
    assert ptu.requests[:4] == [b"S", b"ECHO OFF", b"?", b'FORM "P=" 4.4 P " " U4 " T=" 3.4 T " " U3 " RH=" 3.3 RH " " U3 #r #n']
    assert thermometer.requests == [b"*SRTC2"]


def test_probe_vaisala_ptb330_takes_the_air_from_the_thermometer(capsys):
    with Emulator(emu.vaisala("PTB330")) as ptb, Emulator(emu.ithx) as thermometer:
        r = probe_json(capsys, "environment", f"{ptb.url()}?model=vaisala-ptb330&thermometer={thermometer.url()}")
        assert r["reading"] == pytest.approx({"air_temperature_c": 19.3, "air_pressure_pa": 100380.0, "humidity_pct": 42.5,
                                              "material_temperature_c": 25.1})
        code, _, err = probe(capsys, "environment", f"{ptb.url()}?model=vaisala-ptb330")  # no thermometer: no air
    assert code == 2 and "thermometer=" in err and len(err.splitlines()) == 1


def test_probe_ptu300_without_a_thermometer_measures_no_material(capsys):
    with Emulator(emu.vaisala("PTU300")) as ptu:
        r = probe_json(capsys, "environment", f"{ptu.url()}?model=vaisala-ptu300")
    assert set(r["reading"]) == {"air_temperature_c", "air_pressure_pa", "humidity_pct"}


@pytest.mark.parametrize("kind,model,address_options,expected", [
    ("dial_indicator", "sylvac", "", (4800, 7, "E", 2)),  # the defaults: SylvacCtrl.py
    ("environment", "vaisala-ptu300", "", (4800, 7, "E", 1)),  # msl-equipment's defaults
    ("encoder", "qsb", "", (230400, 8, "N", 1)),
    ("dial_indicator", "sylvac", "&baud=9600&bytesize=8&parity=O&stopbits=1", (9600, 8, "O", 1)),
])
def test_framing_options_reach_pyserial(kind, model, address_options, expected):
    """7-bit even-parity framing and its overrides are what pyserial opens the line with (over
    socket://: this machine's pseudo-terminals refuse such framings on some kernels)."""
    answer = {"sylvac": emu.sylvac, "vaisala-ptu300": emu.vaisala("PTU300"), "qsb": emu.qsb}[model]
    with Emulator(answer, b"\n" if model == "qsb" else b"\r") as device:
        instrument = factory.open_instrument(kind, f"{device.url()}?model={model}{address_options}", 1.0)
        port = instrument.line.port
        assert (port.baudrate, port.bytesize, port.parity, port.stopbits) == expected
        instrument.close()


def test_modbus_rtu_framing_defaults_to_8e1(monkeypatch):
    from drivers.modbus_stage import ModbusStage

    seen = {}

    class Client:
        def __init__(self, port, **kw):
            seen.update(kw)

        def connect(self):
            return True

        def read_device_information(self, **kw):  # an AZ drive implements no FC 43: an exception reply
            from pymodbus.exceptions import ModbusException

            raise ModbusException("Exception Response(171, 43, IllegalFunction)")

    monkeypatch.setattr("drivers.modbus_stage.ModbusSerialClient", Client)
    ModbusStage(parse_address("modbus-rtu:///dev/ttyUSB0?unit=1"), 1.0)
    assert (seen["baudrate"], seen["bytesize"], seen["parity"], seen["stopbits"]) == (115200, 8, "E", 1)
    ModbusStage(parse_address("modbus-rtu:///dev/ttyUSB0?baud=9600&parity=N&stopbits=2"), 1.0)
    assert (seen["baudrate"], seen["parity"], seen["stopbits"]) == (9600, "N", 2)


@pytest.mark.parametrize("args,text", [
    (["stage", "modbus-tcp://127.0.0.1:502?unit=0"], "option unit='0'"),
    (["dial_indicator", "socket://127.0.0.1:5?parity=X"], "option parity='X': must be N, E or O"),
    (["dial_indicator", "socket://127.0.0.1:5?bytesize=6"], "option bytesize='6'"),
    (["encoder", "socket://127.0.0.1:5?model=sylvac"], "model 'sylvac' is a dial indicator, not a encoder"),
    (["cmm", "socket://127.0.0.1:5?model=nonesuch"], "unknown model 'nonesuch'"),
    (["cmm", "modbus-tcp://127.0.0.1:5"], "is a modbus-tcp address"),
])
def test_probe_malformed_address_exits_2_in_one_line(capsys, args, text):
    code, out, err = probe(capsys, *args)
    assert code == 2 and text in err and len(err.splitlines()) == 1 and "Traceback" not in err


def test_probe_silent_or_wrong_instrument_exits_1_in_one_line(capsys):
    with Emulator(lambda line, state: b"", b"\n") as silent:
        code, _, err = probe(capsys, "autocollimator", silent.url(), "--timeout-s", "0.2")
    assert code == 1 and err.startswith("rtcal: autocollimator at socket://") and "no reply" in err
    assert len(err.splitlines()) == 1
    with Emulator(lambda line, state: b"4 003 north south\r", b"\n") as wrong:
        code, _, err = probe(capsys, "autocollimator", wrong.url(), "--timeout-s", "0.5")
    assert code == 1 and "unexpected reply" in err and len(err.splitlines()) == 1


def test_check_tells_what_is_ready(tmp_path, capsys):
    """`rtcal check` on the seed-001 procedure: every instrument probed; a stage outside the
    procedure's soft limits is not ready (exit 1, one line naming it)."""
    with AzDriveEmulator({0x00CC: 123456, 0x007E: 0x4020, 0x0080: 0}) as drive, Emulator(emu.qsb, b"\n") as encoder, \
            Emulator(emu.elcomat, b"\n") as ac, Emulator(emu.sylvac) as di1, Emulator(emu.sylvac) as di2:
        addresses = {"stage": f"modbus-tcp://127.0.0.1:{drive.port}?unit=1&steps_per_rev=10000&gear=36",
                     "encoder": encoder.url(), "autocollimator": ac.url(), "dial_indicator_1": di1.url(),
                     "dial_indicator_2": di2.url()}
        (tmp_path / "a.json").write_text(json.dumps(addresses))
        procedure = tmp_path / "p.yaml"
        from pathlib import Path

        text = (Path(__file__).resolve().parents[1] / "procedures" / "encoder_abbe_error.yaml").read_text()
        procedure.write_text(text.replace("bench: scenarios/abbe_bench.yaml", ""))
        code = main(["check", str(procedure), "--instruments", str(tmp_path / "a.json")])
        out, err = capsys.readouterr()
        assert code == 0, out + err
        assert "5 of 5 ready" in out and "US Digital QSB" in out
        drive.words[0x00CC], drive.words[0x00CD] = 0x0007, 0xA120  # 500000 steps: 500°, beyond the limits
        code = main(["check", str(procedure), "--instruments", str(tmp_path / "a.json")])
        out, err = capsys.readouterr()
    assert code == 1 and "4 of 5 ready" in out
    assert err.splitlines() == [l for l in err.splitlines() if l.startswith("rtcal: stage: position 500.0000°")]


def test_check_refuses_an_unknown_instrument(tmp_path, capsys):
    from pathlib import Path

    procedure = Path(__file__).resolve().parents[1] / "procedures" / "encoder_abbe_error.yaml"
    assert main(["check", str(procedure), "--instruments", '{"telescope": "socket://127.0.0.1:1"}']) == 2
    assert "telescope: no such instrument" in capsys.readouterr().err
