"""No certificate for a table that did not move: every motion and reading checked against the
command and the other instruments (rtcal/engine/checks.py), in process and over the wires.

Each fault is a physical one the simulators play: a drive that says "in position" and echoes the
command but never turns (`stuck`), one that stops short and says so (`short`), and another client
that turns the table or moves the probe (`moved`, at a position read; over Modbus, a real second
client). A run that meets one it cannot ride out stops safely: exit 1, a message naming the
instrument and the disagreement, every reading kept, no results.json.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml
from pymodbus.client import ModbusTcpClient

from drivers import az_registers as az
from drivers.addresses import parse_address
from rtcal.run.runner import resume_run, run_procedure
from rtcal.store.runstore import REJECTED, RunStore
from rtcal.engine.faults import RunAborted
from simulators.scenario import FaultSpec, Scenario
from simulators.servers.hub import SimulatorHub
from tests.test_faults import _procedure

REPO = Path(__file__).resolve().parents[1]
SMALL = REPO / "tests" / "data" / "small_multistation.yaml"
ABBE = REPO / "procedures" / "encoder_abbe_error.yaml"


def _scenario(tmp_path: Path, faults: list[dict], base: Path | None = None) -> Path:
    data = yaml.safe_load(base.read_text()) if base else {}
    path = tmp_path / "bench.yaml"
    path.write_text(yaml.safe_dump({**data, "faults": faults}))
    return path


def _aborted(tmp_path: Path, procedure: Path, scenario: Path | None = None, addresses: dict | None = None) -> tuple[str, RunStore]:
    with pytest.raises(RunAborted) as stop:
        run_procedure(procedure, scenario, out_dir=tmp_path / "run", show_progress=False, addresses=addresses,
                      virtual_clock=addresses is not None)
    assert not (tmp_path / "run" / "results.json").exists()  # no certificate for a motion that could not be trusted
    store = RunStore.open(tmp_path / "run")
    assert store.meta()["status"] == "aborted"
    return str(stop.value), store


ABBE_BENCH = REPO / "procedures" / "scenarios" / "abbe_bench.yaml"


def test_a_drive_that_never_turns_gives_no_certificate_multistation(tmp_path):
    """It echoes every command as its feedback: only the tracer can tell, and does at the second
    station (the nominal geometry expects the lengths to change by centimetres)."""
    message, store = _aborted(tmp_path, SMALL, _scenario(tmp_path, [{"instrument": "stage", "kind": "stuck", "probability": 1.0}]))
    assert message.startswith("stage: run aborted after stage: the laser tracer's length")
    assert "verification.tracer_tolerance_mm" in message
    events = store.events()
    kinds = [e["kind"] for e in events]
    assert kinds.count("retry") == 2 and kinds[-1] == "stopped" and "abort" in kinds[-3:]  # then the machines at rest
    rejected = [r for r in store.readings() if r.quantity == REJECTED]
    assert len(rejected) == 3 and {r.instrument for r in rejected} == {"stage"}  # the first try and two retries
    assert any(r.instrument == "laser_tracer" and r.plan_index == 1 for r in store.readings())  # kept, not used


def test_a_drive_that_never_turns_gives_no_certificate_abbe(tmp_path):
    """Seed 001: the encoder tells at the second visit."""
    message, store = _aborted(tmp_path, ABBE, _scenario(tmp_path, [{"instrument": "stage", "kind": "stuck", "probability": 1.0}],
                                                         ABBE_BENCH))
    assert "the encoder turned 0.0000° where 7.5000° was commanded" in message
    assert "verification.encoder_tolerance_arcsec" in message
    assert len(store.done_plan_indices()) == 1 and store.skipped_plan_indices() == {1}


def test_a_drive_that_stops_short_is_tried_again_then_stops_the_run(tmp_path):
    """It stops 0.01° short and its feedback says so; each retry approaches again, in vain."""
    message, store = _aborted(tmp_path, SMALL, _scenario(tmp_path, [{"instrument": "stage", "kind": "short",
                                                                      "shortfall_deg": 0.01, "probability": 1.0}]))
    assert "feedback position" in message and "-36.0″ off" in message
    assert [e["kind"] for e in store.events()].count("retry") == 2


def test_a_drive_that_stops_short_once_is_approached_again_and_the_run_goes_on(tmp_path):
    path = _scenario(tmp_path, [{"instrument": "stage", "kind": "short", "shortfall_deg": 0.01, "at_request": [3]}])
    r = run_procedure(SMALL, path, out_dir=tmp_path / "run", show_progress=False).results
    assert (r.raw_readings, r.skipped_readings) == (64, 0)
    faults = [e.message for e in r.events if e.kind == "fault"]
    assert len(faults) == 1 and "feedback position" in faults[0]


@pytest.mark.parametrize("instrument", ["stage", "cmm"])
def test_another_client_moving_a_machine_during_a_reading_stops_the_run_at_once(tmp_path, instrument):
    """Position reads 1, 2 are the first reading's before and after; read 4 is the second reading's after."""
    message, store = _aborted(tmp_path, SMALL, _scenario(tmp_path, [{"instrument": instrument, "kind": "moved", "at_request": [4]}]))
    assert ("the table turned" if instrument == "stage" else "the probe moved") in message
    assert "another client" in message
    assert [e["kind"] for e in store.events()].count("retry") == 0  # no retry gives rtcal its machine back
    assert store.done_plan_indices() == {0}
    assert any(r.quantity == REJECTED and r.plan_index == 1 for r in store.readings())


def test_a_table_turned_between_readings_is_approached_again(tmp_path):
    """Read 3 is the second reading's before: the table is found off and approached anew."""
    path = _scenario(tmp_path, [{"instrument": "stage", "kind": "moved", "offset_deg": 0.003, "at_request": [3]}])
    r = run_procedure(SMALL, path, out_dir=tmp_path / "run", show_progress=False).results
    assert (r.raw_readings, r.skipped_readings) == (64, 0)
    assert len([e for e in r.events if e.kind == "fault"]) == 1


def test_a_rejected_reading_is_kept_retaken_and_never_used(tmp_path):
    """Once stuck (move 3), under `skip`: the reading at station 3 contradicts the geometry and is
    rejected; it is taken again after the pass, and the results use only the retake."""
    proc = _procedure(tmp_path, SMALL, {"stage: {retries: 2, backoff_s: 0.1, then: abort}": "stage: {retries: 0, backoff_s: 0.1, then: skip}"})
    path = _scenario(tmp_path, [{"instrument": "stage", "kind": "stuck", "at_request": [3]}])
    clean = run_procedure(SMALL, out_dir=tmp_path / "clean", show_progress=False).results
    r = run_procedure(proc, path, out_dir=tmp_path / "run", show_progress=False).results
    assert (r.raw_readings, r.skipped_readings) == (64, 0)
    store = RunStore.open(tmp_path / "run")
    rejected = {(x.plan_index, x.attempt) for x in store.readings() if x.quantity == REJECTED}
    assert len(rejected) == 1
    lengths = [x for x in store.readings(instrument="laser_tracer") if (x.plan_index, x.attempt) in rejected]
    assert lengths  # the contradicted length is kept in the store …
    # … and used nowhere: the deviations agree with a clean run's to the bench's noise (0.2 µm over 65 mm ≈ 0.6″, 1σ)
    for name in ("shared_dead_path", "network"):
        a, b = r.estimates.named(name).cumulative_deviation_arcsec, clean.estimates.named(name).cumulative_deviation_arcsec
        assert max(abs(x - y) for x, y in zip(a, b)) < 3.0


def test_a_run_stopped_by_a_contradiction_resumes_once_the_cause_is_gone(tmp_path):
    """Stuck from move 3 to move 7 (the reading at station 3 and both retries' approaches, an
    overshoot and the target each), then fixed: the stopped run resumes, retakes the rejected reading,
    and solves with every planned reading."""
    path = _scenario(tmp_path, [{"instrument": "stage", "kind": "stuck", "at_request": [3, 4, 5, 6, 7]}])
    _aborted(tmp_path, SMALL, path)
    r = resume_run(tmp_path / "run", show_progress=False).results
    assert (r.raw_readings, r.skipped_readings) == (64, 0)


# -- over the wires -------------------------------------------------------------------------------

def test_a_drive_that_never_turns_over_modbus_gives_no_certificate(tmp_path):
    with SimulatorHub(Scenario(faults=[FaultSpec(instrument="stage", kind="stuck", probability=1.0)]), seed=3) as hub:
        message, _ = _aborted(tmp_path, SMALL, addresses=hub.addresses)
    assert "the laser tracer's length" in message


def test_a_drive_that_stops_short_over_modbus_rtu_gives_no_certificate(tmp_path):
    """The feedback check finds the table short of the target; the attempt is rejected and retaken, and the
    retake's move (0.01° to the same target) does not start either: the run stops, the stage named."""
    scenario = Scenario(faults=[FaultSpec(instrument="stage", kind="short", shortfall_deg=0.01, probability=1.0)])
    with SimulatorHub(scenario, seed=3, modbus="rtu") as hub:
        message, store = _aborted(tmp_path, SMALL, addresses=hub.addresses)
    assert message.startswith("stage: run aborted")
    faults = [e["message"] for e in store.events() if e["kind"] == "fault"]
    assert "feedback position" in faults[0] and "commanded" in faults[0], faults
    assert any(r.quantity == REJECTED for r in store.readings())


def test_a_second_modbus_client_nudging_the_drive_stops_the_run(tmp_path):
    """A real second client turns the table 3 steps every 5 ms (incremental moves through the same
    direct-data registers): the run stops with the stage named, whatever moment the nudges hit."""
    stop = threading.Event()
    # a drive that starts each motion at once: with a start latency a nudge and rtcal's own move can replace each
    # other's pending trigger, and the retries put the table back (docs/faults.md)
    with SimulatorHub(Scenario(), seed=3, stage_start_latency_s=0.0) as hub:
        address = parse_address(hub.addresses["stage"])
        intruder = ModbusTcpClient(address.host, port=address.port, timeout=1, retries=0)
        assert intruder.connect()

        def nudge() -> None:
            while not stop.is_set():
                words = [w for v in (2, 3, 1000, 1000, 1000, 1000, 1) for w in az.split32(v)]
                intruder.write_registers(az.OPERATION_TYPE, words, device_id=1)
                time.sleep(0.005)

        thread = threading.Thread(target=nudge, daemon=True)
        thread.start()
        try:
            message, store = _aborted(tmp_path, SMALL, addresses=hub.addresses)
        finally:
            stop.set()
            thread.join(2)
            intruder.close()
    assert message.startswith("stage: ")
    assert "the table turned" in message or "feedback position" in message


def test_the_command_line_says_exit_1_and_names_the_instrument(tmp_path):
    bench = _scenario(tmp_path, [{"instrument": "stage", "kind": "stuck", "probability": 1.0}])
    done = subprocess.run([sys.executable, "-m", "rtcal.cli", "run", str(SMALL), "--scenario", str(bench), "--out",
                           str(tmp_path / "run")], capture_output=True, text=True, timeout=120)
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stderr
    first = next(line for line in done.stderr.splitlines() if line.startswith("rtcal:") and not line.startswith("rtcal: readings "))  # not the token or progress lines
    assert first.startswith("rtcal: instrument error: stage: run aborted after stage: the laser tracer's length"), first
    assert "rtcal resume" in done.stderr
    exported = subprocess.run([sys.executable, "-m", "rtcal.cli", "export", str(tmp_path / "run")], capture_output=True,
                              text=True, timeout=60)
    assert exported.returncode == 0, exported.stderr
    events = (tmp_path / "run" / "events.csv").read_text()
    assert "the laser tracer's length" in events and ",abort," in events
