"""Issue 36, what is trusted too readily: a plugin that is not its kind's interface (8), a Sylvac
that keeps sending (6), a PI controller's motion error and long moves (5), a drive that never moves
blamed on the encoder (7), dial indicators trusted alone (11)."""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from drivers import models, pi_gcs
from drivers.addresses import parse_address
from drivers.errors import InstrumentFault
from drivers.pi_gcs import PiGcsStage
from simulators.scenario import Scenario
from simulators.servers.hub import SimulatorHub
from tests import emulators as emu
from tests.emulators import Emulator
from tests.test_trust_round2 import _one_line


class _NotAnIndicator:
    """A plugin's class that reads like an indicator but does not subclass DialIndicator."""

    kind, model, schemes, name = "dial_indicator", "loose-indicator", ("serial",), "dial_indicator"
    opened = False

    def __init__(self, address, timeout_s: float = 1.0, **context):
        type(self).opened = True

    def identity(self) -> str:
        return "loose"


def test_a_plugin_that_is_not_its_kinds_interface_is_refused_in_one_line(monkeypatch, capsys):
    monkeypatch.setattr(models.MODELS, "_plugins", {"loose-indicator": models.Model(
        "loose-indicator", "dial_indicator", f"{__name__}:_NotAnIndicator", ("serial",), plugin="rtcal-loose")})
    err = _one_line(capsys, 2, ["probe", "dial_indicator", "socket://127.0.0.1:9?model=loose-indicator"])
    assert "rtcal-loose" in err and f"{__name__}:_NotAnIndicator" in err, err
    assert "is not a DialIndicator" in err and "lacks read_um" in err, err
    assert not _NotAnIndicator.opened  # refused before its constructor opens anything


class _Flooding:
    """A Sylvac that sends readings on its own, without end (continuous output left on), until closed."""

    def __init__(self):
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.sent_bytes = 0
        threading.Thread(target=self._serve, daemon=True).start()

    def url(self) -> str:
        return f"socket://127.0.0.1:{self.listener.getsockname()[1]}"

    def _serve(self) -> None:
        conn, _ = self.listener.accept()
        with conn:
            try:
                while True:
                    conn.sendall(b" 0.0123\r" * 128)
                    self.sent_bytes += 1024
            except OSError:
                return


def test_a_sylvac_that_keeps_sending_ends_the_probe_within_a_bound(capsys):
    flood = _Flooding()
    start = time.monotonic()
    err = _one_line(capsys, 1, ["probe", "dial_indicator", f"{flood.url()}?model=sylvac", "--timeout-s", "1"])
    took_s = time.monotonic() - start
    flood.listener.close()
    assert "keeps sending after MM" in err and "dial_indicator" in err, err
    assert took_s < 3.0, took_s  # the loop after MM had no deadline: it read as long as the indicator sent


class _FastClock:
    """Time running ``factor`` times faster than the wall clock, for the driver and the emulator
    alike: a 35 s turn takes under 2 s of the test's time, every deadline scaled with it."""

    def __init__(self, factor: float):
        self.factor, self.t0 = factor, time.monotonic()

    def monotonic(self) -> float:
        return self.t0 + (time.monotonic() - self.t0) * self.factor

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds / self.factor)


def _pi_stage(controller: Emulator) -> PiGcsStage:
    return PiGcsStage(parse_address(f"{controller.url()}?model=pi-gcs&axis=1"), 1.0)


def test_a_pi_turn_of_350_deg_at_10_deg_per_s_arrives(monkeypatch):
    """35 s of travel: the wait was ten timeouts (10 s) whatever the move; now it is the move's own."""
    clock = _FastClock(20.0)
    monkeypatch.setattr(pi_gcs, "time", clock)
    answer = emu.pi_gcs(travel_deg=360.0, velocity_deg_per_s=10.0, clock=clock.monotonic)
    with Emulator(answer, b"\n") as controller:
        stage = _pi_stage(controller)
        try:
            start_s = clock.monotonic()
            stage.move_to(350.0)
            took_s = clock.monotonic() - start_s
            assert stage.position_deg() == 350.0
        finally:
            stage.close()
    assert 35.0 <= took_s < 40.0, took_s


def test_a_pi_motion_error_mid_move_is_named_when_it_happens():
    """Error 1024 two seconds into a 35 s move: the fault names it then, not after ten timeouts as
    "not on target in time" (ERR? was never read while waiting)."""
    answer = emu.pi_gcs(travel_deg=360.0, velocity_deg_per_s=10.0, motion_error_after_s=2.0)
    with Emulator(answer, b"\n") as controller:
        stage = _pi_stage(controller)
        try:
            start_s = time.monotonic()
            with pytest.raises(InstrumentFault, match=r"GCS error 1024 \(motion error") as fault:
                stage.move_to(350.0)
            took_s = time.monotonic() - start_s
        finally:
            stage.close()
    assert "at 20.0" in str(fault.value)  # where it stopped: 2 s at 10°/s
    assert took_s < 2.5, took_s


def test_the_pi_simulator_injects_a_motion_error_and_reports_it_by_err():
    with SimulatorHub(Scenario(), seed=1, serial="tcp", stage_model="pi-gcs") as hub:
        assert hub.pi_gcs is not None
        hub.pi_gcs.motion_error_moves = {2}
        stage = PiGcsStage(parse_address(hub.addresses["stage"]), 1.0)
        try:
            stage.move_to(10.0)
            start_s = time.monotonic()
            with pytest.raises(InstrumentFault, match=r"move to 30\.000000°: GCS error 1024 \(motion error.*at 20\.0"):
                stage.move_to(30.0)
            assert time.monotonic() - start_s < 1.0
            stage.reset_alarm()  # ERR? read, servo on again: the table moves on
            stage.move_to(40.0)
            assert stage.position_deg() == pytest.approx(40.0, abs=1e-6)
        finally:
            stage.close()


def test_a_drive_that_never_moves_is_named_not_the_encoder(tmp_path):
    """The stage stuck from its 10th request on (it reports in position, the table stays): the encoder
    reads the target before, and the autocollimator sees a face square — the same face, reading as it
    did, since the step is whole faces. It was blamed on the encoder ("a frozen counter")."""
    from rtcal.run.runner import RunAborted, run_procedure
    from tests.test_cross_checks import ISO, _scenario_file

    scenario = _scenario_file(tmp_path, [{"instrument": "stage", "kind": "stuck", "at_request": list(range(10, 60))}])
    with pytest.raises(RunAborted, match="the table did not turn") as exc:
        run_procedure(ISO, scenario, out_dir=tmp_path / "run", show_progress=False)
    assert exc.value.instrument == "stage"
    assert "drive did not move the table" in str(exc.value) and "encoder's count is frozen" in str(exc.value)


def test_a_drive_that_never_moves_from_the_first_step_is_named_beside_the_encoder(tmp_path):
    """Issue 46: stuck from the very first step, the visit retried compared the encoder with its own
    failed attempt at the same target, and the run ended blaming the encoder alone ("it misreads").
    Where the table stood before is the target before: the stage is named, the encoder beside it."""
    from rtcal.run.runner import RunAborted, run_procedure
    from tests.test_cross_checks import ISO, _scenario_file

    scenario = _scenario_file(tmp_path, [{"instrument": "stage", "kind": "stuck", "at_request": list(range(1, 60))}])
    with pytest.raises(RunAborted, match="the table did not turn") as exc:
        run_procedure(ISO, scenario, out_dir=tmp_path / "run", show_progress=False)
    assert exc.value.instrument == "stage"
    assert "drive did not move the table" in str(exc.value) and "encoder's count is frozen" in str(exc.value)


def test_an_encoder_whole_faces_off_names_the_stage_too():
    """The encoder two faces from the command while a face is square: the autocollimator cannot tell
    the table there from the table two faces short, so the message names both causes."""
    from rtcal.methods.abbe.checks import EncoderCheck
    from rtcal.engine.checks import Contradiction

    check = EncoderCheck(600.0, pitch_deg=15.0, face_still_arcsec=1.4)
    check.check(0.0, 0.0, table_seen=True, face_arcsec=-5.7)
    check.check(15.0, 15.0, table_seen=True, face_arcsec=3.0)
    with pytest.raises(Contradiction, match="it misreads — or the stage did not turn the table as commanded: the "
                                            r"encoder reads 2 faces \(30°\) from the command") as exc:
        check.check(15.0 - 15.0, 30.0, table_seen=True, face_arcsec=-2.0)
    assert exc.value.instrument == "encoder"
    other = EncoderCheck(600.0, pitch_deg=15.0, face_still_arcsec=1.4)
    other.check(0.0, 0.0, table_seen=True, face_arcsec=-5.7)
    other.check(15.0, 15.0, table_seen=True, face_arcsec=3.0)
    with pytest.raises(Contradiction) as exc:  # 7° off: no whole number of faces, the encoder alone
        other.check(23.0, 30.0, table_seen=True, face_arcsec=-2.0)
    assert "stage" not in str(exc.value)


def _abbe_run(tmp_path, procedure: str, faults: list[dict], seed: int) -> subprocess.CompletedProcess:
    from tests.test_cross_checks import REPO, _scenario_file

    scenario = _scenario_file(tmp_path, faults)
    out = tmp_path / f"run-{procedure}-{seed}"
    return subprocess.run([sys.executable, "-m", "rtcal.cli", "run", str(REPO / "procedures" / f"{procedure}.yaml"),
                           "--scenario", str(scenario), "--seed", str(seed), "--out", str(out)],
                          capture_output=True, text=True, timeout=300, cwd=REPO)


@pytest.mark.parametrize("procedure", ["encoder_abbe_error", "polygon_closure"])
def test_a_creeping_dial_indicator_fails_the_run_naming_it(tmp_path, procedure):
    """0.5 µm more at each reading: the tilt and radial motion came out hundreds of arcsec and ~90 µm
    off, the certificate clean, exit 0 (the closure run blamed the geometry). The indicator at a target
    it saw before now reads away from what it read there."""
    done = _abbe_run(tmp_path, procedure, [{"instrument": "dial_indicator_2", "kind": "creep",
                                            "creep_um_per_reading": 0.5, "at_request": [1]}], seed=3)
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stderr
    first = next(line for line in done.stderr.splitlines() if line.startswith("rtcal: instrument error"))
    assert first.startswith("rtcal: instrument error: dial_indicator_2: run aborted after dial_indicator_2:"), first
    assert "earlier visit(s) of this target" in first and "creeps" in first, first
    assert not (tmp_path / f"run-{procedure}-3" / "results.json").exists()


def test_a_clean_bench_passes_the_indicator_check(tmp_path):
    """The same bench without the creep still ends in a certificate (the false-alarm rate, over 30 runs
    of three procedures and ten seeds, was 0; one seed here)."""
    done = _abbe_run(tmp_path, "encoder_abbe_error", [], seed=3)
    assert done.returncode == 0, done.stderr


def test_a_simulated_indicator_creeps():
    from simulators.bench import Bench
    from simulators.instruments import SimDialIndicator
    from tests.test_cross_checks import _bench

    data = _bench([{"instrument": "dial_indicator_1", "kind": "creep", "creep_um_per_reading": 0.5, "at_request": [2]}])
    data["dial_indicators"]["resolution_um"] = 0.0  # unrounded: the creep itself
    indicator = SimDialIndicator(Bench(Scenario.model_validate(data)), 0)
    readings = [indicator.read_um() for _ in range(5)]  # the table stands still: only the creep changes them
    assert np.diff(readings) == pytest.approx([0.5, 0.5, 0.5, 0.5], abs=1e-9)
