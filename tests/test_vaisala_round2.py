"""Vaisala PTU300 / PTB330 as they leave the factory (issue 27): `rtcal probe` against an emulator
written from the manuals (tests/emulators.VaisalaEmulator: paced at 4800 baud, echo on, the whole
`?` listing, RUN mode) and against the hub's paced, echoing simulator."""

from __future__ import annotations

import json
import time

import pytest

from rtcal.cli import main
from tests import emulators as emu
from tests.emulators import Emulator, VaisalaEmulator

EXPECTED = {"PTU300": {"air_temperature_c": 17.7, "air_pressure_pa": 100380.0, "humidity_pct": 40.9,
                       "material_temperature_c": 25.1},
            "PTB330": {"air_temperature_c": 19.3, "air_pressure_pa": 100380.0, "humidity_pct": 42.5,
                       "material_temperature_c": 25.1}}
SERIAL = {"PTU300": "P4040154", "PTB330": "G1234567"}


def _probe(capsys, address: str) -> tuple[int, dict | None, str]:
    code = main(["probe", "environment", address, "--json", "--timeout-s", "2"])
    out, err = capsys.readouterr()
    return code, (json.loads(out) if code == 0 else None), err


@pytest.mark.parametrize("model,echo,run", [("PTU300", True, False), ("PTU300", False, False), ("PTB330", True, True),
                                            ("PTB330", False, False)])
def test_probe_a_paced_vaisala_with_echo_on_and_off(capsys, model, echo, run):
    with VaisalaEmulator(model, echo=echo, run=run) as unit, Emulator(emu.ithx) as thermometer:
        started = time.monotonic()
        code, r, err = _probe(capsys, f"{unit.url()}?model=vaisala-{model.lower()}&thermometer={thermometer.url()}")
        took_s = time.monotonic() - started
    assert code == 0, err
    assert r["identity"] == f"{model} / 1.12, serial number {SERIAL[model]}"
    assert r["reading"] == pytest.approx(EXPECTED[model])
    assert unit.requests[:3] == [b"S", b"ECHO OFF", b"?"] and unit.requests[-1] == b"SEND"
    assert took_s > len(VaisalaEmulator.LISTING[model]) * 25 * 10 / 4800  # the listing really was paced


def test_probe_refuses_a_unit_of_another_model(capsys):
    with VaisalaEmulator("PTB330", baud=0) as unit, Emulator(emu.ithx) as thermometer:
        code, _, err = _probe(capsys, f"{unit.url()}?model=vaisala-ptu300&thermometer={thermometer.url()}")
    assert code == 1 and "PTB330" in err and "vaisala-ptu300" in err


def test_hub_paces_and_echoes(capsys):
    from simulators.scenario import Scenario
    from simulators.servers.hub import SimulatorHub

    with SimulatorHub(Scenario(), seed=1, serial="tcp", pace_serial=True) as hub:
        started = time.monotonic()
        code, r, err = _probe(capsys, hub.addresses["environment"])
        took_s = time.monotonic() - started
        handler = hub.handlers["environment"].handler
    assert code == 0, err
    assert r["identity"].startswith("PTU300 / 1.12, serial number SIMULATED")
    assert set(r["reading"]) == {"air_temperature_c", "air_pressure_pa", "humidity_pct", "material_temperature_c"}
    assert handler.echo is False  # the driver turned the factory default off
    assert took_s > len(handler.listing()) * 10 / 4800
