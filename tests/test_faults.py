"""Every fault type, injected by the protocol simulators (and in process), met by the policies.

The protocol tests run the real drivers against `SimulatorHub` servers (Modbus TCP/RTU, I++,
serial lines on ptys) with a virtual clock and 0.3 s timeouts.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from rtcal.run.runner import resume_run, run_procedure
from rtcal.engine.faults import RunAborted
from rtcal.store.runstore import RunStore
from simulators.scenario import FaultSpec, Scenario
from simulators.servers.hub import SimulatorHub

REPO = Path(__file__).resolve().parents[1]
SMALL = REPO / "tests" / "data" / "small_multistation.yaml"
ABBE = REPO / "procedures" / "encoder_abbe_error.yaml"


def _procedure(tmp_path: Path, base: Path, replace: dict[str, str] | None = None) -> Path:
    text = base.read_text()
    for old, new in (replace or {}).items():
        assert old in text
        text = text.replace(old, new)
    path = tmp_path / base.name
    path.write_text(text)
    return path


def _over_wires(tmp_path: Path, procedure: Path, faults: list[dict], modbus: str = "tcp", serial: str = "pty"):
    scenario = Scenario(faults=[FaultSpec(**f) for f in faults])
    with SimulatorHub(scenario, seed=3, serial=serial, modbus=modbus) as hub:
        return run_procedure(procedure, out_dir=tmp_path / "run", show_progress=False, addresses=hub.addresses,
                             virtual_clock=True).results


def _events(results, kind: str) -> list[str]:
    return [e.message for e in results.events if e.kind == kind]


TRANSIENT = [
    ({"instrument": "laser_tracer", "kind": "no_reply", "at_request": [10]}, "no reply"),
    ({"instrument": "laser_tracer", "kind": "garbled", "at_request": [10]}, "unexpected reply"),
    ({"instrument": "laser_tracer", "kind": "truncated", "at_request": [10]}, "truncated"),
    ({"instrument": "cmm", "kind": "no_reply", "at_request": [3]}, "no reply"),
    ({"instrument": "cmm", "kind": "garbled", "at_request": [3]}, "malformed reply"),
    ({"instrument": "cmm", "kind": "truncated", "at_request": [3]}, "no reply"),
    ({"instrument": "stage", "kind": "modbus_exception", "at_request": [4]}, "Modbus exception 4"),
    ({"instrument": "stage", "kind": "crc_error", "at_request": [4]}, "no valid reply"),
    ({"instrument": "stage", "kind": "no_reply", "at_request": [4]}, "no valid reply"),
    ({"instrument": "stage", "kind": "alarm", "alarm": "stall", "at_request": [4]}, "alarm 0x30"),
    ({"instrument": "stage", "kind": "alarm", "alarm": "following_error", "at_request": [4]}, "alarm 0x10"),
    ({"instrument": "stage", "kind": "alarm", "alarm": "limit_switch", "at_request": [4]}, "alarm 0x66"),
]


@pytest.mark.parametrize("fault,text", TRANSIENT, ids=[f"{f['instrument']}-{f['kind']}-{f.get('alarm', '')}" for f, _ in TRANSIENT])
def test_transient_fault_is_retried_over_the_wire(tmp_path, fault, text):
    r = _over_wires(tmp_path, SMALL, [fault])
    assert r.raw_readings == 64 and r.skipped_readings == 0
    faults = _events(r, "fault")
    assert faults and text in faults[0], faults
    assert _events(r, "retry")


def test_crc_error_over_rtu(tmp_path):
    r = _over_wires(tmp_path, SMALL, [{"instrument": "stage", "kind": "crc_error", "at_request": [4]}], modbus="rtu")
    assert r.raw_readings == 64
    assert "no valid reply" in _events(r, "fault")[0]


def test_beam_breaks_are_reacquired_into_new_segments(tmp_path):
    r = _over_wires(tmp_path, SMALL, [{"instrument": "laser_tracer", "kind": "beam_break", "at_request": [10, 30]}])
    assert r.raw_readings == 64
    assert len(_events(r, "reacquire")) == 2
    store = RunStore.open(tmp_path / "run")
    assert store.max_segment() == 2  # the first reference and two re-acquisitions
    assert set(r.estimates.shared_dead_path.dead_paths_mm) == {"0", "1", "2"}


def test_emergency_stop_aborts_to_a_safe_state_and_keeps_readings(tmp_path):
    with pytest.raises(RunAborted, match="rtcal resume"):
        _over_wires(tmp_path, SMALL, [{"instrument": "stage", "kind": "emergency_stop", "at_request": [5]}])
    store = RunStore.open(tmp_path / "run")
    assert store.meta()["status"] == "aborted"
    assert len(store.done_plan_indices()) == 3  # stations 1–3 of point 1 were measured before it
    assert any(e["kind"] == "abort" for e in store.events())


def test_emergency_stop_with_pause_waits_for_the_operator(tmp_path):
    proc = _procedure(tmp_path, SMALL, {"stage: {retries: 2, backoff_s: 0.1, then: abort}": "stage: {retries: 1, backoff_s: 0.1, then: pause}"})
    r = _over_wires(tmp_path, proc, [{"instrument": "stage", "kind": "emergency_stop", "at_request": [5]}])
    assert r.raw_readings == 64
    assert _events(r, "pause")


def test_skip_policy_retakes_the_reading_after_the_pass(tmp_path):
    """Reading 10 fails three times and is skipped; after the pass it is taken again (requests 67–69
    are the retake's: 64 readings, 3 of them failed): all 64 stored, each once."""
    proc = _procedure(tmp_path, SMALL, {"laser_tracer: {retries: 2, backoff_s: 0.1, then: reacquire}":
                                        "laser_tracer: {retries: 2, backoff_s: 0.1, then: skip}"})
    r = _over_wires(tmp_path, proc, [{"instrument": "laser_tracer", "kind": "no_reply", "at_request": [10, 11, 12]}])
    assert len(_events(r, "skip")) == 1
    assert r.skipped_readings == 0 and r.raw_readings == 64
    store = RunStore.open(tmp_path / "run")
    lengths = [x.plan_index for x in store.readings(instrument="laser_tracer", quantity="length_mm")]
    assert sorted(lengths) == list(range(64))


def test_skip_policy_marks_the_reading_and_the_solvers_use_the_rest(tmp_path):
    """The retake of reading 10 fails too (requests 67–69): it stays skipped, the solvers use the rest."""
    proc = _procedure(tmp_path, SMALL, {"laser_tracer: {retries: 2, backoff_s: 0.1, then: reacquire}":
                                        "laser_tracer: {retries: 2, backoff_s: 0.1, then: skip}"})
    r = _over_wires(tmp_path, proc, [{"instrument": "laser_tracer", "kind": "no_reply", "at_request": [10, 11, 12, 67, 68, 69]}])
    assert r.skipped_readings == 1 and r.raw_readings == 63
    assert len(r.estimates.shared_dead_path.deviation_arcsec) == 3


def test_seed001_instruments_faults_over_sockets(tmp_path):
    faults = [{"instrument": "encoder", "kind": "garbled", "at_request": [7]},
              {"instrument": "autocollimator", "kind": "no_reply", "at_request": [3]},
              {"instrument": "dial_indicator_2", "kind": "truncated", "at_request": [11]}]
    proc = _procedure(tmp_path, ABBE, {"encoder: {backend: sim}": "encoder: {backend: sim, timeout_s: 0.3}",
                                       "autocollimator: {backend: sim}": "autocollimator: {backend: sim, timeout_s: 0.3}",
                                       "dial_indicator_2: {backend: sim}": "dial_indicator_2: {backend: sim, timeout_s: 0.3}"})
    r = _over_wires(tmp_path, proc, faults, serial="tcp")
    assert r.raw_readings == 96 and r.skipped_readings == 0
    messages = _events(r, "fault")
    assert len(messages) == 3
    assert any("unexpected reply" in m for m in messages)  # encoder, garbled
    assert any("no reply" in m for m in messages)  # autocollimator, silent
    assert any("truncated" in m for m in messages)  # indicator, cut short


@pytest.mark.parametrize("fault", [f for f, _ in TRANSIENT] + [{"instrument": "laser_tracer", "kind": "beam_break", "at_request": [10]}])
def test_same_faults_in_process(tmp_path, fault):
    """In process, the simulated instruments raise the typed errors the drivers would."""
    scenario = tmp_path / "s.yaml"
    import yaml

    scenario.write_text(yaml.safe_dump({"seed": 3, "faults": [fault]}))
    r = run_procedure(SMALL, scenario, out_dir=tmp_path / "run", show_progress=False).results
    assert r.raw_readings == 64 and r.faults >= 1


def test_paper000_with_two_percent_beam_breaks_completes_within_no_fault_noise(tmp_path):
    """Beam breaks in 2 % of tracer readings (12 in this run): every planned reading is taken by
    re-acquiring. The shared-dead-path estimate stays within the no-fault run's noise: each
    deviation within 3.5σ of the no-fault uncertainty, RMS error below 1.5× the no-fault RMS
    uncertainty (measured: 0.91″ against 1.08″). The per-station model pays for the extra dead
    paths (one per segment and station): its error stays within its own, larger, 3.5σ."""
    import numpy as np

    faulty = run_procedure(REPO / "procedures" / "laser_tracer_multistation.yaml", REPO / "tests" / "data" / "paper000_beam_breaks.yaml",
                           out_dir=tmp_path / "faulty", show_progress=False).results
    clean = run_procedure(REPO / "procedures" / "laser_tracer_multistation.yaml", out_dir=tmp_path / "clean",
                          show_progress=False).results
    assert faulty.raw_readings == 704 and faulty.skipped_readings == 0
    assert len(_events(faulty, "reacquire")) >= 5
    truth = np.array(faulty.truth.realized_deviation_arcsec)
    shared = np.array(faulty.estimates.shared_dead_path.deviation_arcsec) - truth
    no_fault_unc = np.array(clean.estimates.shared_dead_path.uncertainty_arcsec)
    assert np.all(np.abs(shared) < 3.5 * no_fault_unc)
    assert np.sqrt(np.mean(shared**2)) < 1.5 * np.sqrt(np.mean(no_fault_unc**2))
    paper = faulty.estimates.paper
    assert np.all(np.abs(np.array(paper.deviation_arcsec) - truth) < 3.5 * np.array(paper.uncertainty_arcsec))


def test_a_run_whose_data_the_solvers_cannot_use_says_so(tmp_path, capsys):
    """Every tracer reading fails and is skipped (the policy allows any number in a row): measuring
    ends, the solvers have nothing; a clear message and exit 1, the store intact."""
    import yaml

    from rtcal.cli import main

    proc = _procedure(tmp_path, SMALL, {"laser_tracer: {retries: 2, backoff_s: 0.1, then: reacquire}":
                                        "laser_tracer: {retries: 0, backoff_s: 0.1, then: skip, max_skips_in_a_row: 1000}"})
    scenario = tmp_path / "s.yaml"
    scenario.write_text(yaml.safe_dump({"faults": [{"instrument": "laser_tracer", "kind": "no_reply", "probability": 1.0}]}))
    assert main(["run", str(proc), "--scenario", str(scenario), "--out", str(tmp_path / "run")]) == 1
    err = capsys.readouterr().err
    assert "solvers could not use them" in err and "Traceback" not in err
    assert len(RunStore.open(tmp_path / "run").skipped_plan_indices()) == 64


def test_pause_resets_the_drive_once_the_operator_has_released_the_emergency_stop(tmp_path):
    """No retry is left after the pause: the drive's latched e-stop alarm is reset (ALM-RST) as soon
    as the operator has released it, so the one attempt after the pause moves (it failed on the
    latched alarm and the run stopped)."""
    proc = _procedure(tmp_path, SMALL, {"stage: {retries: 2, backoff_s: 0.1, then: abort}": "stage: {retries: 0, backoff_s: 0.1, then: pause}"})
    r = _over_wires(tmp_path, proc, [{"instrument": "stage", "kind": "emergency_stop", "at_request": [5]}])
    assert r.raw_readings == 64 and r.skipped_readings == 0
    assert len(_events(r, "pause")) == 1


def test_pause_after_a_beam_break_references_the_tracer_again(tmp_path):
    """The operator frees the beam; the tracer's count is lost, so it is referenced again before the
    attempt after the pause (it was not, and every beam break under `pause` stopped the run)."""
    import yaml

    proc = _procedure(tmp_path, SMALL, {"laser_tracer: {retries: 2, backoff_s: 0.1, then: reacquire}":
                                        "laser_tracer: {retries: 1, backoff_s: 0.1, then: pause}"})
    scenario = tmp_path / "s.yaml"
    scenario.write_text(yaml.safe_dump({"faults": [{"instrument": "laser_tracer", "kind": "beam_break", "at_request": [10]}]}))
    r = run_procedure(proc, scenario, out_dir=tmp_path / "run", show_progress=False, outputs=False).results
    assert r.raw_readings == 64 and len(_events(r, "pause")) == 1
    assert len(_events(r, "reacquire")) == 1
    assert RunStore.open(tmp_path / "run").max_segment() == 1  # the first reference and the one after the pause


def test_pause_without_an_operator_stops_safely(tmp_path):
    """A pause with nobody to ask (a run over transports without a terminal or a simulated operator)
    is a safe stop with its reason, not a traceback."""
    proc = _procedure(tmp_path, SMALL, {"stage: {retries: 2, backoff_s: 0.1, then: abort}": "stage: {retries: 0, backoff_s: 0.1, then: pause}"})
    scenario = Scenario(faults=[FaultSpec(instrument="stage", kind="emergency_stop", at_request=[5])])
    with SimulatorHub(scenario, seed=3) as hub:
        addresses = {k: v for k, v in hub.addresses.items() if k != "operator"}
        with pytest.raises(RunAborted, match="no operator could clear it"):
            run_procedure(proc, out_dir=tmp_path / "run", show_progress=False, addresses=addresses, virtual_clock=True,
                          outputs=False)
    store = RunStore.open(tmp_path / "run")
    assert store.meta()["status"] == "aborted"
    kinds = [e["kind"] for e in store.events()]
    assert kinds[kinds.index("abort") - 1:] == ["fault", "abort", "stopped", "stopped"]  # the stage and the CMM at rest


def _stopped_then_resumed(tmp_path: Path, proc: Path, scenario: dict, instrument: str):
    """Run with ``instrument`` failing its first three requests under `abort`: the readings stored
    at the stop (plan index, instrument, quantity), whether plan index 0 is skipped and nothing
    done, and the results once resumed."""
    import yaml

    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump({**scenario, "faults": [{"instrument": instrument, "kind": "no_reply",
                                                            "at_request": [1, 2, 3]}]}))
    with pytest.raises(RunAborted):
        run_procedure(proc, path, out_dir=tmp_path / "run", show_progress=False, outputs=False)
    store = RunStore.open(tmp_path / "run")
    rows = [(r.plan_index, r.instrument, r.quantity) for r in store.readings()]
    pending = store.done_plan_indices() == set() and store.skipped_plan_indices() == {0}
    store.close()
    return rows, pending, resume_run(tmp_path / "run", show_progress=False).results


def test_a_safe_stop_keeps_what_the_interrupted_reading_took(tmp_path):
    """The tracer fails three times on the first reading and the run stops: the CMM position that
    reading took is stored (it was dropped), with the mark of the tracer's failure; the resume takes
    the reading again and every planned reading is done once."""
    proc = _procedure(tmp_path, SMALL, {"laser_tracer: {retries: 2, backoff_s: 0.1, then: reacquire}":
                                        "laser_tracer: {retries: 2, backoff_s: 0.1, then: abort}"})
    rows, pending, r = _stopped_then_resumed(tmp_path, proc, {}, "laser_tracer")
    assert rows == [(0, "stage", "feedback_deg"), (0, "cmm", "position_x_mm"), (0, "cmm", "position_y_mm"),
                    (0, "cmm", "position_z_mm"), (0, "laser_tracer", "skipped")]
    assert pending
    assert (r.raw_readings, r.skipped_readings) == (64, 0)


def test_a_safe_stop_keeps_what_the_interrupted_visit_took(tmp_path):
    """Seed 001: dial indicator 2 fails on the first visit and the run stops; the encoder, the
    autocollimator and indicator 1 read at that visit are stored, marked as not whole."""
    import yaml

    proc = _procedure(tmp_path, ABBE, {"bench: scenarios/abbe_bench.yaml\n": "",
                                       "autocollimator: {retries: 2, backoff_s: 0.5, then: skip}":
                                       "dial_indicator_2: {retries: 2, backoff_s: 0.5, then: abort}"})
    bench = yaml.safe_load((REPO / "procedures" / "scenarios" / "abbe_bench.yaml").read_text())
    rows, _, r = _stopped_then_resumed(tmp_path, proc, bench, "dial_indicator_2")
    assert rows == [(0, "stage", "feedback_deg"), (0, "encoder", "angle_deg"), (0, "autocollimator", "x_arcsec"),
                    (0, "dial_indicator_1", "y_um"), (0, "dial_indicator_2", "skipped")]
    assert (r.raw_readings, r.skipped_readings) == (96, 0)


def test_resume_retakes_what_a_solved_run_skipped(tmp_path, capsys):
    """A skip run ends with results and one reading skipped (its retake after the pass failed too);
    `rtcal resume` takes it (it returned the first results unchanged) and solves again with it."""
    import json

    import yaml

    from rtcal.cli import main

    proc = _procedure(tmp_path, SMALL, {"laser_tracer: {retries: 2, backoff_s: 0.1, then: reacquire}":
                                        "laser_tracer: {retries: 2, backoff_s: 0.1, then: skip}"})
    scenario = tmp_path / "s.yaml"
    scenario.write_text(yaml.safe_dump({"faults": [{"instrument": "laser_tracer", "kind": "no_reply",
                                                    "at_request": [10, 11, 12, 67, 68, 69]}]}))
    run_dir = tmp_path / "run"
    assert main(["run", str(proc), "--scenario", str(scenario), "--out", str(run_dir)]) == 0
    first = json.loads((run_dir / "results.json").read_text())
    assert (first["raw_readings"], first["skipped_readings"], first["starts"]) == (63, 1, 1)
    assert main(["resume", str(run_dir)]) == 0
    assert "run complete: 64 planned readings taken" in capsys.readouterr().out
    again = json.loads((run_dir / "results.json").read_text())
    assert (again["raw_readings"], again["skipped_readings"], again["starts"]) == (64, 0, 2)
    assert main(["resume", str(run_dir)]) == 0  # now finished: left as it is
    assert json.loads((run_dir / "results.json").read_text()) == again


def test_seed001_counts_whole_visits_as_readings(tmp_path):
    """A skipped visit is a skipped reading, not also a raw one: 95 + 1 of 96 (it said 96 + 1)."""
    import yaml

    proc = _procedure(tmp_path, ABBE, {"bench: scenarios/abbe_bench.yaml\n": ""})
    scenario = tmp_path / "s.yaml"
    bench = yaml.safe_load((REPO / "procedures" / "scenarios" / "abbe_bench.yaml").read_text())
    scenario.write_text(yaml.safe_dump({**bench, "faults": [{"instrument": "autocollimator", "kind": "no_reply",
                                                             "at_request": [3, 4, 5]}]}))
    r = run_procedure(proc, scenario, out_dir=tmp_path / "run", show_progress=False, outputs=False).results
    assert (r.raw_readings, r.skipped_readings) == (95, 1)


def test_an_operator_who_cannot_be_reached_is_a_typed_error():
    """No terminal, or a simulated operator gone: OperatorUnavailable (an InstrumentError the fault
    policies stop safely on and the command line reports), not a RuntimeError's traceback."""
    from rtcal.engine.operator import ConsoleOperator, OperatorUnavailable, RemoteSimOperator
    from rtcal.engine.steps import OperatorStep
    from simulators.servers.hub import free_port

    gone = RemoteSimOperator(f"sim-operator://127.0.0.1:{free_port('127.0.0.1')}", timeout_s=0.5)
    seat = OperatorStep("Seat the polygon.", "seated", lambda hands: hands.reseat_polygon(15.0), "re-seat the polygon")
    for step in (lambda: gone.clear_fault("stage: e-stop"), lambda: gone.perform(seat), gone.ping,
                 lambda: gone.hands().polygon_certificate_arcsec()):
        with pytest.raises(OperatorUnavailable, match="does not answer"):
            step()
    with pytest.raises(OperatorUnavailable, match="no terminal"):  # pytest's stdin is no terminal
        ConsoleOperator().clear_fault("stage: e-stop")
