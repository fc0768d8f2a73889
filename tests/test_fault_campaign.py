"""The fault campaign: every fault kind × every policy that applies (abort, skip, pause,
reacquire) at 10 % and 30 % of requests, in process and over both wirings of the protocol
simulators, for both methods.

Every run and every resume must end with results (or the solvers' clear "cannot use them"), or
with a safe stop (RunAborted) — never another exception. After each, the store holds only
planned readings and none done twice. A run that stopped or skipped is resumed (fresh fault
draws: a new bench generation, or a new simulator) until every planned reading is done: each
exactly once, whatever was skipped retaken. (At 30 % emergency stops with `abort` a start takes
about one reading, so up to four starts per planned reading are allowed.)

CI runs every second (method, instrument, fault kind), each policy and each wiring met several times (about a
minute); the whole grid is under `pytest -m campaign` (README: Tests).
"""

from __future__ import annotations

import itertools
import json
import os
import sqlite3
from pathlib import Path

import pytest
import yaml

from rtcal.methods import load_procedure
from rtcal.run.runner import METHODS, AnalysisFailed, resume_run, run_procedure
from rtcal.engine.faults import RunAborted
from simulators.scenario import FaultSpec, Scenario
from simulators.servers.hub import SimulatorHub

REPO = Path(__file__).resolve().parents[1]
TIMEOUT_S = 0.2  # over the wires: a silent instrument costs this much real time per attempt
STARTS_PER_READING = 4  # a run that stops at 30 % e-stops takes about one reading per start; a bound, not a budget

KINDS = {  # what each instrument can suffer (simulators/scenario.py FaultKind and its checks)
    "stage": ["no_reply", "modbus_exception", "crc_error", "alarm", "emergency_stop", "stuck", "short", "moved"],
    "cmm": ["no_reply", "garbled", "truncated", "moved"],
    "laser_tracer": ["beam_break", "no_reply", "garbled", "truncated"],
    "encoder": ["no_reply", "garbled", "truncated"],
    "autocollimator": ["no_reply", "garbled", "truncated"],
    "dial_indicator_1": ["no_reply", "garbled", "truncated"],
    "dial_indicator_2": ["no_reply", "garbled", "truncated"],
}
METHOD_INSTRUMENTS = {"multistation": ["stage", "cmm", "laser_tracer"],
                      "abbe": ["stage", "encoder", "autocollimator", "dial_indicator_1", "dial_indicator_2"]}
TRANSPORTS = ["in_process", "ptys+modbus_tcp", "sockets+modbus_rtu"]


def _policies(instrument: str) -> list[str]:
    return ["abort", "skip", "pause"] + (["reacquire"] if instrument == "laser_tracer" else [])


def _grid() -> list[tuple]:
    return [(m, i, k, p, rate, t) for m, instruments in METHOD_INSTRUMENTS.items() for i in instruments
            for k in KINDS[i] for p in _policies(i) for rate in (0.1, 0.3) for t in TRANSPORTS
            if not (k == "crc_error" and t == "in_process")]  # a CRC exists on the wire only


def _subset() -> list[tuple]:
    """Every second (method, instrument, kind) — the others with -m campaign, and every one in the full
    grid — the policies and transports taking turns so that each policy and each transport is met
    several times; 30 % in process, 10 % over the wires."""
    picks, turn = [], itertools.count()
    for m, instruments in METHOD_INSTRUMENTS.items():
        for i in instruments:
            for k in KINDS[i]:
                n = next(turn)
                policies = _policies(i)
                transports = [t for t in TRANSPORTS if not (k == "crc_error" and t == "in_process")]
                transport = transports[n % len(transports)]
                rate = 0.3 if transport == "in_process" else 0.1  # a silent line costs real time on a wire
                picks.append((m, i, k, policies[n % len(policies)], rate, transport))
    return picks[::2]


def _procedure(tmp_path: Path, method: str, instrument: str, policy: str) -> Path:
    """A small procedure whose ``instrument`` follows ``policy``; the others abort."""
    if method == "multistation":
        data = yaml.safe_load((REPO / "tests" / "data" / "small_multistation.yaml").read_text())
    else:
        data = yaml.safe_load((REPO / "procedures" / "encoder_abbe_error.yaml").read_text())
        data.pop("bench")
        data["steps"]["steps_per_face"] = 1  # 24 targets × 2 directions
    for name in data["instruments"]:
        data["instruments"][name]["timeout_s"] = TIMEOUT_S
    data["on_fault"] = {name: {"retries": 2, "backoff_s": 0.1, "then": "abort"} for name in METHOD_INSTRUMENTS[method]}
    data["on_fault"][instrument] = {"retries": 2, "backoff_s": 0.1, "then": policy, "max_skips_in_a_row": 5}
    path = tmp_path / f"{method}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _done_counts(db: Path) -> dict[int, int]:
    """Done attempts per planned reading (an attempt that skipped nothing and was not rejected)."""
    with sqlite3.connect(db) as c:
        return dict(c.execute(
            "SELECT plan_index, COUNT(DISTINCT attempt) FROM readings r WHERE plan_index IS NOT NULL AND quantity NOT IN "
            "('skipped', 'rejected') AND NOT EXISTS (SELECT 1 FROM readings s WHERE s.plan_index = r.plan_index AND "
            "s.attempt IS r.attempt AND s.quantity IN ('skipped', 'rejected')) GROUP BY plan_index").fetchall())


def _ended_cleanly(call) -> str:
    """'results', 'unusable' (the solvers said why) or 'safe stop'; any other exception fails the test."""
    try:
        call()
    except RunAborted as exc:
        assert "every reading taken is kept" in str(exc)
        return "safe stop"
    except AnalysisFailed as exc:
        assert "every reading is in" in str(exc)
        return "unusable"
    return "results"


def run_case(tmp_path: Path, method: str, instrument: str, kind: str, policy: str, rate: float, transport: str) -> list[str]:
    procedure = _procedure(tmp_path, method, instrument, policy)
    planned = METHODS[load_procedure(procedure).method].plan_length(load_procedure(procedure))
    max_starts = STARTS_PER_READING * planned
    fault = FaultSpec(instrument=instrument, kind=kind, probability=rate)
    out, db = tmp_path / "run", tmp_path / "run" / "run.sqlite"
    outcomes: list[str] = []

    def check_store() -> dict[int, int]:
        counts = _done_counts(db)
        assert set(counts) <= set(range(planned)), "a reading that was not planned"
        assert all(n == 1 for n in counts.values()), "a planned reading done twice"
        return counts

    if transport == "in_process":
        scenario = tmp_path / "scenario.yaml"
        scenario.write_text(yaml.safe_dump({"seed": 7, "faults": [fault.model_dump()]}))
        outcomes.append(_ended_cleanly(lambda: run_procedure(procedure, scenario, out_dir=out, show_progress=False)))
        while len(check_store()) < planned and len(outcomes) < max_starts:
            outcomes.append(_ended_cleanly(lambda: resume_run(out, show_progress=False)))
    else:
        serial, modbus = ("pty", "tcp") if transport == "ptys+modbus_tcp" else ("tcp", "rtu")
        for start in range(max_starts):
            with SimulatorHub(Scenario(faults=[fault]), seed=11 + start, serial=serial, modbus=modbus) as hub:
                if start == 0:
                    outcomes.append(_ended_cleanly(lambda: run_procedure(procedure, out_dir=out, show_progress=False,
                                                                         addresses=hub.addresses, virtual_clock=True)))
                else:
                    outcomes.append(_ended_cleanly(lambda: resume_run(out, addresses=hub.addresses, virtual_clock=True,
                                                                      show_progress=False)))
            if len(check_store()) == planned:
                break
    counts = check_store()
    assert sorted(counts) == list(range(planned)), f"not every planned reading taken after {len(outcomes)} starts"
    if os.environ.get("RTCAL_CAMPAIGN_LOG"):  # one JSON line per case, for the campaign's figures
        with open(os.environ["RTCAL_CAMPAIGN_LOG"], "a", encoding="utf-8") as log:
            log.write(json.dumps({"case": [method, instrument, kind, policy, rate, transport], "outcomes": outcomes}) + "\n")
    return outcomes


@pytest.mark.parametrize("case", _subset(), ids=lambda c: "-".join(map(str, c)))
def test_fault_campaign_subset(tmp_path, case):
    run_case(tmp_path, *case)


@pytest.mark.campaign
@pytest.mark.parametrize("case", _grid(), ids=lambda c: "-".join(map(str, c)))
def test_fault_campaign(tmp_path, case):
    run_case(tmp_path, *case)
