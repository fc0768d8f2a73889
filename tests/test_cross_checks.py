"""Instruments checked against each other (issue 26, item 1): the autocollimator against the encoder,
a stale or frozen autocollimator, the tracer back at its reference point (creep), the dial
indicators' range and unit. Unit tests of each check class, the simulated faults, and runs in
process and over the wires that must stop (exit 1, the instrument named, no certificate) — while
the shipped procedures on their benches still pass."""

from __future__ import annotations

import json
import math
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from rtcal.run.runner import resume_run, run_procedure
from rtcal.store.runstore import RunStore
from rtcal.engine.checks import Contradiction, combined_sigma
from rtcal.methods.abbe.checks import AutocollimatorEncoderCheck, EncoderCheck, IndicatorCheck
from rtcal.methods.multistation.checks import TracerReturnCheck
from rtcal.engine.faults import RunAborted
from simulators.bench import Bench
from simulators.instruments import SimAutocollimator, SimDialIndicator, SimLaserTracer
from simulators.scenario import FaultSpec, Scenario
from simulators.servers.hub import SimulatorHub
from simulators.servers.serial_protocols import SylvacHandler
from tests.test_serial_protocols import INDICATOR, _read

REPO = Path(__file__).resolve().parents[1]
ISO = REPO / "procedures" / "iso230_2_polygon.yaml"
ABBE_BENCH = REPO / "procedures" / "scenarios" / "abbe_bench.yaml"
SMALL = REPO / "tests" / "data" / "small_multistation.yaml"
CROSS_CHECK_WORDS = ("autocollimator − encoder", "earlier visit", "stale", "frozen", "digits", "reference point",
                     "the shaft may move")


def _bench(faults: list[dict], base: Path = ABBE_BENCH) -> dict:
    data = yaml.safe_load(base.read_text()) if base is not None else {}
    data["faults"] = faults
    return data


def _scenario_file(tmp_path: Path, faults: list[dict], base: Path = ABBE_BENCH) -> Path:
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(_bench(faults, base)))
    return path


# -- the autocollimator against the encoder, as a class

SIGMA = combined_sigma((0.2, 0.1), (0.05, 0.05))
TARGETS = [0.0, 15.0, 45.0, 90.0, 105.0, 150.0, 180.0, 210.0, 240.0, 270.0, 315.0, 330.0]


def _table_error(angle_deg: float, direction: int) -> float:
    """A table's positioning error, arcsec: what both instruments see (cancels in their difference)."""
    a = math.radians(angle_deg)
    return 20.0 * math.sin(a + 0.7) + 6.0 * math.sin(12 * a - 0.5) - (8.0 if direction < 0 else 0.0)


def _encoder_error(angle_deg: float) -> float:
    a = math.radians(angle_deg)
    return 18.0 * math.sin(a + 0.3) + 4.0 * math.sin(2 * a)


def _visits(runs: int = 3):
    """(run, direction, target) in the ISO linear cycle."""
    for r in range(runs):
        for d in (1, -1):
            for t in (TARGETS if d > 0 else TARGETS[::-1]):
                yield r, d, t


def _feed(check: AutocollimatorEncoderCheck, rng: np.random.Generator, reply=lambda fresh, previous: fresh,
          encoder_zero_deg: float = 123.4) -> tuple[int, Contradiction | None]:
    """Feed an ISO cycle; ``reply(fresh, previous)`` is what the autocollimator answers. Returns how
    many visits passed and the contradiction that stopped it."""
    previous = None
    for n, (r, d, t) in enumerate(_visits()):
        actual = _table_error(t, d) + 0.3 * rng.standard_normal()  # the table's error this visit, arcsec
        fresh = round((actual + 0.2 * rng.standard_normal()) / 0.1) * 0.1
        x = reply(fresh, previous)
        previous = fresh
        encoder = (t + encoder_zero_deg + (actual + _encoder_error(t) + 0.05 * rng.standard_normal()) / 3600.0) % 360.0
        try:
            check.check(x, encoder, t, 0, r, d, n)
        except Contradiction as exc:
            return n, exc
    return n + 1, None


def _check() -> AutocollimatorEncoderCheck:
    return AutocollimatorEncoderCheck(SIGMA, drift_arcsec=0.5, encoder_bound_arcsec=30.0, face_bound_arcsec=5.0)


def test_tolerances_are_five_sigma_of_the_stated_noise_plus_the_stated_bounds():
    check = AutocollimatorEncoderCheck(0.2, drift_arcsec=0.5, encoder_bound_arcsec=10.0, face_bound_arcsec=2.0)
    assert check.same_tolerance_arcsec(1) == pytest.approx(5 * 0.2 * math.sqrt(2) + 0.5)
    assert check.same_tolerance_arcsec(4) == pytest.approx(5 * 0.2 * math.sqrt(1.25) + 0.5)
    assert check.neighbour_tolerance_arcsec == pytest.approx(5 * 0.2 * math.sqrt(2) + 0.5 + 2 * (10.0 + 2.0))
    assert SIGMA == pytest.approx(math.sqrt(0.2**2 + 0.1**2 / 12 + 0.05**2 + 0.05**2 / 12))


@pytest.mark.parametrize("seed", range(5))
def test_an_honest_autocollimator_passes_every_visit(seed):
    passed, exc = _feed(_check(), np.random.default_rng(seed))
    assert exc is None and passed == 3 * 2 * len(TARGETS)


def test_a_stale_autocollimator_is_named_and_said_to_be_one_request_behind():
    passed, exc = _feed(_check(), np.random.default_rng(1),
                        reply=lambda fresh, previous: previous if previous is not None else fresh)
    assert exc is not None and exc.instrument == "autocollimator"
    assert passed < 2 * len(TARGETS)  # no later than the first return to a target


def _late(kind: str, after: int):
    """An autocollimator that turns stale (the previous request's reading) or frozen (the last reply
    again) after ``after`` requests."""
    state = {"n": 0, "frozen": None}

    def reply(fresh, previous):
        state["n"] += 1
        if state["n"] <= after or previous is None:
            return fresh
        if kind == "stale":
            return previous
        state["frozen"] = previous if state["frozen"] is None else state["frozen"]
        return state["frozen"]
    return reply


def test_a_stale_autocollimator_found_late_stays_suspect_so_a_retake_cannot_hide_it():
    check = _check()
    passed, exc = _feed(check, np.random.default_rng(2), reply=_late("stale", 40))
    assert exc is not None and exc.instrument == "autocollimator"
    assert 40 <= passed <= 50
    with pytest.raises(Contradiction, match="autocollimator"):  # a retake: its previous request is the same target
        check.check(0.0, 0.0, 0.0, 0, 9, 1, 999)


def test_a_frozen_autocollimator_is_named():
    passed, exc = _feed(_check(), np.random.default_rng(3), reply=_late("frozen", 30))
    assert exc is not None and exc.instrument == "autocollimator"
    assert 30 <= passed <= 40


@pytest.mark.parametrize("offset_arcsec, caught", [(1.0, False), (3.0, True), (-3.0, True)])
def test_one_reading_off_at_a_target_seen_before_is_caught_beyond_the_tolerance(offset_arcsec, caught):
    check = AutocollimatorEncoderCheck(0.2, drift_arcsec=0.5, encoder_bound_arcsec=30.0, face_bound_arcsec=5.0)
    check.check(5.0, 10.0 + 5.0 / 3600.0, 10.0, 0, 0, 1, 0)  # d = 0
    check.check(5.0, 20.0 + 5.0 / 3600.0, 20.0, 0, 0, 1, 1)
    if caught:
        with pytest.raises(Contradiction, match="earlier visit"):
            check.check(5.0 + offset_arcsec, 10.0 + 5.0 / 3600.0, 10.0, 0, 1, 1, 2)
    else:
        check.check(5.0 + offset_arcsec, 10.0 + 5.0 / 3600.0, 10.0, 0, 1, 1, 2)


def test_along_a_pass_a_jump_beyond_the_stated_bounds_is_caught():
    check = AutocollimatorEncoderCheck(0.2, drift_arcsec=0.5, encoder_bound_arcsec=10.0, face_bound_arcsec=2.0)
    check.check(0.0, 0.0, 0.0, 0, 0, 1, 0)
    check.check(20.0, 15.0, 15.0, 0, 0, 1, 1)  # the difference changed 20″: within 2·(10 + 2) + noise
    with pytest.raises(Contradiction, match="changed by"):
        check.check(60.0, 30.0, 30.0, 0, 0, 1, 2)  # 40″ more: beyond


@pytest.mark.parametrize("reading_deg, words", [(10.0 + 15.0 + 3e-4, "one request behind"),  # where 15° was
                                                 (10.0 + 15.0 + 2e-4, "repeats")])  # the same value again
def test_an_encoder_stale_or_frozen_is_named_when_the_autocollimator_saw_the_table_turn(reading_deg, words):
    check = EncoderCheck(600.0)
    check.check(10.0, 0.0, table_seen=True)
    check.check(10.0 + 15.0 + 2e-4, 15.0, table_seen=True)
    with pytest.raises(Contradiction, match=words) as exc:
        check.check(reading_deg, 45.0, table_seen=True)
    assert exc.value.instrument == "encoder"
    with pytest.raises(Contradiction, match="encoder"):  # stays suspect: a retake cannot hide it
        check.check(10.0 + 45.0, 45.0, table_seen=True)


def test_an_encoder_that_disagrees_without_the_autocollimator_names_the_stage():
    check = EncoderCheck(600.0)  # a table that did not turn and an encoder that did not count look the same
    check.check(10.0, 0.0)
    check.check(10.0 + 15.0, 15.0)
    with pytest.raises(Contradiction) as exc:
        check.check(10.0 + 15.0 + 1e-4, 45.0)
    assert exc.value.instrument == "stage"


# -- the indicators and the tracer, as classes

def test_indicator_range_and_unit():
    check = IndicatorCheck(range_um=50.0, digit_um=1.0)
    assert check.inch_grid_um == pytest.approx(0.05)  # 1 µm digit → 0.00005 in → 0.05 as mm µm
    check.check("dial_indicator_1", 3.0000000000000004)  # whole µm, as a driver computes them from mm
    check.check("dial_indicator_1", -12.0)
    with pytest.raises(Contradiction, match="beyond"):
        check.check("dial_indicator_1", 51.0)
    inch = [0.1, 0.15, 0.0, -0.05, 0.1]  # 0.0001 in, 0.00015 in, … read as mm; a zero says nothing
    for y in inch[:-1]:
        check.check("dial_indicator_2", y)
    with pytest.raises(Contradiction, match="inches") as exc:
        check.check("dial_indicator_2", inch[-1])
    assert exc.value.instrument == "dial_indicator_2"
    check = IndicatorCheck(range_um=50.0, digit_um=1.0)
    for y in (0.1, 0.15, 2.0, 0.1, 0.05, 0.1):  # a whole-digit reading between: no four in a row
        check.check("dial_indicator_1", y)
    rng = np.random.default_rng(0)
    for y in 3.0 * rng.standard_normal(2000):  # a bench without quantisation: any value, never four in a row
        check.check("dial_indicator_1", float(y))
    IndicatorCheck(range_um=50.0, digit_um=0.0).check("dial_indicator_1", 0.1)  # no stated digit: no unit check


def test_tracer_return_to_reference():
    check = TracerReturnCheck(0.2, 0.3, 0.3, 0.2, 65.0, drift_um=2.0)
    tol = check.tolerance_um(800.0, 1)
    assert tol == pytest.approx(5 * math.sqrt(2 * 0.44**2 + 2 * 0.3**2 + 2 * (math.radians(0.2 / 3600) * 65e3) ** 2) + 2.0)
    check.referenced(0, [0.0])
    check.check(0, [(tol - 0.1) * 1e-3], 800.0, "point 1, station 1")
    with pytest.raises(Contradiction, match="creeps") as exc:
        check.check(0, [(tol + 0.1) * 1e-3], 800.0, "point 1, station 1")
    assert exc.value.instrument == "laser_tracer"
    check.check(1, [1.0], 800.0, "point 1, station 1")  # a segment never referenced here: nothing to compare


# -- the simulated faults

def test_simulated_stale_frozen_creep_and_inch():
    def bench(kind: str, instrument: str) -> Bench:
        return Bench(Scenario.model_validate(_bench([{"instrument": instrument, "kind": kind, "at_request": [2]}])))

    b = bench("stale", "autocollimator")
    ac = SimAutocollimator(b)
    b.reseat_polygon(0.0)
    first = ac.read_arcsec()[0]
    b.move_stage(math.radians(0.01), 1)  # 36″ further: a fresh reading changes
    assert ac.read_arcsec()[0] == first  # the stale buffer: the previous request's reading
    fresh = ac.read_arcsec()[0]
    assert fresh != first and abs(fresh - math.degrees(b.autocollimator_true()[0]) * 3600) < 1.5  # this position's
    b = bench("frozen", "autocollimator")
    ac = SimAutocollimator(b)
    b.reseat_polygon(0.0)
    first = ac.read_arcsec()[0]
    b.move_stage(math.radians(0.01), 1)
    assert ac.read_arcsec()[0] == ac.read_arcsec()[0] == first
    tracer = SimLaserTracer(Bench(Scenario.model_validate(_bench([{"instrument": "laser_tracer", "kind": "creep",
                                                                    "at_request": [1]}], None))))
    lengths = [tracer.read_length().length_mm for _ in range(4)]
    assert np.diff(lengths) * 1e3 == pytest.approx([0.5, 0.5, 0.5])
    b = bench("inch", "dial_indicator_1")
    b.move_stage(math.radians(90.0), 1)
    healthy = SimDialIndicator(b, 0, inject=False)
    inch = SimDialIndicator(b, 0)
    truth = healthy.read_um()
    inch.read_um()
    assert abs(truth) >= 1.0
    assert inch.read_um() == pytest.approx(truth / 25.4, abs=0.05)  # in process: the inch number read as mm
    with pytest.raises(ValueError, match="autocollimator or the encoder"):
        FaultSpec(instrument="laser_tracer", kind="stale", at_request=[1])


def test_an_indicator_stuck_in_inches_over_the_wire_says_so_when_asked():
    """The Sylvac's reply carries no unit (OPTO-RS manual): an indicator stuck in inches answers the inch
    number, and `UNI?` answers IN, which the driver asks at open and refuses (test_serial_round2); one that
    goes to inches mid-run is caught by the indicator check above (its readings on the inch grid)."""
    b = Bench(Scenario.model_validate(_bench([])))
    b.move_stage(math.radians(90.0), 1)
    truth = SimDialIndicator(b, 0, inject=False).read_um()
    inch = SimDialIndicator(b, 0, inject=False)
    inch.afflict(FaultSpec(instrument="dial_indicator_1", kind="inch", at_request=[1]))
    handler = SylvacHandler(inch)
    assert handler.handle(b"MM") == b"" and handler.handle(b"UNI?") == b"IN\r"
    reply = handler.handle(b"?")
    assert reply.endswith(b"\r") and b"in" not in reply
    assert float(reply) * 25.4 * 1000 == pytest.approx(truth, abs=25.4 * 0.00005 * 1000 / 2 + 1e-9)


# -- runs

def _no_certificate(out: Path) -> None:
    assert not (out / "results.json").exists() and not (out / "report.pdf").exists() and not (out / "report.md").exists()


@pytest.mark.parametrize("instrument, kind", [("autocollimator", "stale"), ("autocollimator", "frozen")])
def test_a_run_with_a_stale_or_frozen_autocollimator_stops_with_exit_1_naming_it(tmp_path, instrument, kind):
    scenario = _scenario_file(tmp_path, [{"instrument": instrument, "kind": kind, "at_request": [30]}])
    out = tmp_path / "run"
    done = subprocess.run([sys.executable, "-m", "rtcal.cli", "run", str(ISO), "--scenario", str(scenario), "--out", str(out)],
                          capture_output=True, text=True, timeout=120, cwd=REPO)
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stderr
    first = next(line for line in done.stderr.splitlines() if line.startswith("rtcal:") and not line.startswith("rtcal: readings "))  # not the token or progress lines
    assert first.startswith(f"rtcal: instrument error: {instrument}: run aborted after {instrument}:"), first
    _no_certificate(out)
    store = RunStore.open(out)
    try:
        rejected = [r for r in store.readings() if r.quantity == "rejected"]
    finally:
        store.close()
    assert rejected and all(r.instrument == instrument for r in rejected)


@pytest.mark.parametrize("instrument, kind, words", [("encoder", "stale", "encoder"), ("encoder", "frozen", "encoder"),
                                                     ("dial_indicator_2", "inch", "inches")])
def test_in_process_a_stale_encoder_or_an_inch_indicator_stops_the_run_naming_it(tmp_path, instrument, kind, words):
    scenario = _scenario_file(tmp_path, [{"instrument": instrument, "kind": kind, "at_request": [30]}])
    with pytest.raises(RunAborted, match=words) as exc:
        run_procedure(ISO, scenario, out_dir=tmp_path / "run", show_progress=False)
    assert exc.value.instrument == instrument
    _no_certificate(tmp_path / "run")


@pytest.mark.parametrize("kind, at", [("stale", 1), ("frozen", 1)])
def test_over_the_wires_a_stale_or_frozen_autocollimator_stops_the_run(tmp_path, kind, at):
    scenario = Scenario.model_validate(_bench([{"instrument": "autocollimator", "kind": kind, "at_request": [at]}]))
    with SimulatorHub(scenario, seed=11, serial="pty", modbus="tcp") as hub:
        with pytest.raises(RunAborted) as exc:
            run_procedure(ISO, out_dir=tmp_path / "run", show_progress=False, addresses=hub.addresses, virtual_clock=True)
    assert exc.value.instrument == "autocollimator"
    _no_certificate(tmp_path / "run")


def test_a_creeping_tracer_stops_the_run_and_its_segment_is_retaken_on_resume(tmp_path):
    scenario = _scenario_file(tmp_path, [{"instrument": "laser_tracer", "kind": "creep", "at_request": [1]}],
                              REPO / "procedures" / "scenarios" / "paper000_bench.yaml")
    out = tmp_path / "run"
    with pytest.raises(RunAborted, match="creeps") as exc:
        run_procedure(SMALL, scenario, out_dir=out, show_progress=False)
    assert exc.value.instrument == "laser_tracer"
    _no_certificate(out)
    with sqlite3.connect(out / "run.sqlite") as c:
        lengths = c.execute("SELECT COUNT(DISTINCT plan_index) FROM readings WHERE quantity = 'length_mm'").fetchone()[0]
        rejected = c.execute("SELECT COUNT(DISTINCT plan_index) FROM readings WHERE quantity = 'rejected'").fetchone()[0]
    assert lengths > 0 and rejected == lengths  # every reading of the creeping segment is marked
    outcome = resume_run(out, show_progress=False)  # a restarted tracer (the fault drawn at request 1 is behind)
    assert outcome is not None and (out / "results.json").exists()


SHIPPED = [("iso230_2_polygon.yaml", None), ("encoder_abbe_error.yaml", None), ("laser_tracer_multistation.yaml", None)]


@pytest.mark.parametrize("name, _", SHIPPED)
def test_the_shipped_runs_pass_their_cross_checks(tmp_path, name, _):
    out = tmp_path / "run"
    run_procedure(REPO / "procedures" / name, out_dir=out, show_progress=False)
    results = json.loads((out / "results.json").read_text())
    assert results
    store = RunStore.open(out)
    try:
        assert not [r for r in store.readings() if r.quantity == "rejected"]
        faults = [e["message"] for e in store.events() if e["kind"] in ("fault", "abort")]
        returns = [r.value for r in store.readings() if r.quantity == "return_length_mm"]
    finally:
        store.close()
    assert not [m for m in faults if any(w in m for w in CROSS_CHECK_WORDS)], faults
    if "multistation" in name:
        assert len(returns) >= 1 and all(abs(v) < 5e-3 for v in returns)  # measured, and within a few µm
