"""PI GCS stage (`model=pi-gcs`, issue 27): the driver against an emulator written from pipython's
command syntax (tests/emulators.pi_gcs), `rtcal probe stage` reading it without moving it, and
the hub's simulator behind the simulated bench."""

from __future__ import annotations

import json

import pytest

from drivers.addresses import parse_address
from drivers.errors import InstrumentFault, OutOfLimits
from drivers.pi_gcs import PiGcsStage
from rtcal.cli import main
from simulators.scenario import Scenario
from simulators.servers.hub import SimulatorHub
from tests import emulators as emu
from tests.emulators import Emulator


def test_probe_reads_the_position_and_moves_nothing(capsys):
    answer = emu.pi_gcs(position_deg=12.5, referenced=False)
    with Emulator(answer, b"\n") as controller:
        code = main(["probe", "stage", f"{controller.url()}?model=pi-gcs&axis=1", "--json", "--timeout-s", "1"])
        out, err = capsys.readouterr()
    assert code == 0, err
    r = json.loads(out)
    assert r["model"] == "pi-gcs" and r["identity"].startswith("(c)2019 Physik Instrumente (PI)")
    # issue 46: the probe said nothing of the unreferenced axis a run then refused
    assert "axis 1 NOT referenced (FRF? 1 = 0): a run refuses it" in r["identity"]
    assert r["reading"] == {"position_deg": 12.5}
    assert [line.split()[0] for line in controller.requests] == [b"*IDN?", b"ERR?", b"FRF?", b"POS?"]  # no SVO, FRF or MOV


def test_probe_says_nothing_of_a_referenced_axis(capsys):
    with Emulator(emu.pi_gcs(position_deg=1.0, referenced=True), b"\n") as controller:
        assert main(["probe", "stage", f"{controller.url()}?model=pi-gcs&axis=1", "--json", "--timeout-s", "1"]) == 0
    assert "referenced" not in json.loads(capsys.readouterr().out)["identity"]


def test_driver_references_only_when_allowed_moves_and_stops():
    answer = emu.pi_gcs(position_deg=3.0, referenced=False)
    with Emulator(answer, b"\n") as controller:
        with pytest.raises(InstrumentFault, match="not referenced.*home=1"):
            PiGcsStage(parse_address(f"{controller.url()}?model=pi-gcs&axis=1"), 1.0)
        stage = PiGcsStage(parse_address(f"{controller.url()}?model=pi-gcs&axis=1&home=1"), 1.0)
        try:
            assert answer.state["referenced"] and stage.position_deg() == 0.0  # FRF: the reference switch at 0
            stage.move_to(45.25)
            assert stage.position_deg() == 45.25
            assert answer.state["ont_polls"] >= 2  # waited for ONT? = 1
            with pytest.raises(OutOfLimits, match="GCS error 7"):
                stage.move_to(350.0)  # the controller's travel range is ±180° here, rtcal's limits ±360°
            stage.stop()
            assert stage.position_deg() == 45.25
            seen = stage.wait_stopped()  # the default of every stage: POS? read until it no longer changes
            assert seen.still and seen.where == "45.250000°", seen
        finally:
            stage.close()
    sent = [line.decode() for line in controller.requests]
    assert "SVO 1 1" in sent and "FRF 1" in sent and "MOV 1 45.25" in sent and "HLT 1" in sent


def test_hub_serves_a_pi_stage_that_a_run_can_drive():
    with SimulatorHub(Scenario(), seed=1, serial="tcp", stage_model="pi-gcs") as hub:
        address = hub.addresses["stage"]
        assert "model=pi-gcs" in address and "axis=1" in address
        stage = PiGcsStage(parse_address(address), 1.0)
        try:
            stage.move_to(30.0)
            assert stage.position_deg() == pytest.approx(30.0, abs=1e-6)
            assert hub.bench.target_rad == pytest.approx(0.5235987755982988, abs=1e-8)
        finally:
            stage.close()


def test_a_wired_iso_230_2_run_on_the_pi_simulator(tmp_path):
    """`rtcal sim serve --stage pi-gcs`: the ISO 230-2 procedure (two runs each way) drives the PI
    stage over its GCS line; its estimates agree with the in-process run of the same bench within the
    stage's repeatability (0.3″ in this scenario): targets travel as pipython formats them (12
    significant digits), so a target that in process is 45.00000000000001° is 45° on the wire, the
    simulated table may then see another approach direction and draw its noise anew. The error
    curves span ±26″."""
    import numpy as np

    from rtcal.run.runner import run_procedure
    from tests.test_transport_end_to_end import PROC, _values, sim_serve

    procedure = tmp_path / "iso.yaml"
    procedure.write_text((PROC / "iso230_2_polygon.yaml").read_text().replace("runs: 5", "runs: 2")
                         .replace("bench: scenarios/", f"bench: {PROC / 'scenarios'}/"))
    scenario = PROC / "scenarios" / "abbe_bench.yaml"
    local = run_procedure(procedure, scenario, out_dir=tmp_path / "local", show_progress=False).results
    with sim_serve(scenario, "--stage", "pi-gcs", "--serial", "tcp") as addresses:
        assert "model=pi-gcs" in addresses["stage"]
        remote = run_procedure(procedure, out_dir=tmp_path / "remote", show_progress=False, addresses=addresses,
                               virtual_clock=True).results
    assert remote.instruments["stage"].startswith("socket://127.0.0.1:")
    assert remote.raw_readings == local.raw_readings  # every planned reading taken
    for key in ("measured_encoder_error_arcsec", "positioning_error_arcsec"):
        a, b = _values(local, "abbe", key), _values(remote, "abbe", key)
        assert np.array_equal(np.isnan(a), np.isnan(b)) and np.nanmax(np.abs(a - b)) < 1.5, key
        assert np.nanmax(np.abs(a)) > 10.0  # a real error curve, not two empty ones
