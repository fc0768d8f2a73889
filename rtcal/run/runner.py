"""A run end to end: procedure → instruments → engine → store → dataset → solvers → results.

The methods (:mod:`rtcal.methods`, each a :class:`~rtcal.methods.protocol.Method`) hold what
differs between methods; this module holds what every run shares: the run directory, the
store's metadata, the bench, the progress bar, and the typed results it assembles and writes.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import sqlite3
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, cast

import numpy as np
import yaml
from pydantic import BaseModel, ValidationError

from rtcal import __version__
from rtcal.clock import RealClock, VirtualClock
from rtcal.deliverables.deviations import PositioningDeviations
from rtcal.deliverables.evaluation import evaluate
from rtcal.methods import METHODS, load_procedure, procedure_models
from rtcal.methods.protocol import DataContradiction, Method
from rtcal.procedure.loader import bench_path
from rtcal.procedure.models import Procedure, plan_outside_limits
from rtcal.results import SCHEMA_VERSION, RunResults, write_results
from rtcal.results.model import (Analysis, Conformity, Evaluation, Event, Iso230Evaluation, ProcedureRef, RunInfo, RunLog,
                                 RunMetadata, Signature, Simulation, VdiEvaluation, assemble)
from rtcal.deliverables.conformity import assess
from rtcal.run.control import control_record
from rtcal.run.rundir import RunDirError, claim_new_run_dir, claim_run_dir, staged_outputs, stored_results
from rtcal.engine.engine import Engine, PlanError
from rtcal.engine.faults import RunAborted
from rtcal.engine.subscribers import ConsoleProgress, Eta, StoreWriter, solve_estimate_s
from rtcal.engine.walk import Timing, walk
from rtcal.engine.operator import BenchOperator, RehearsalOperator, RemoteSimOperator, WaitingOperator, stdin_terminal
from rtcal.store.runstore import CONTEXT_COLUMNS_KEY, RunStore, StoreUnusable
from rtcal.procedure.yamlfile import FileProblems, Problem, load_yaml, locate, problem_at, read_text, validate_text
from simulators.bench import Bench
from simulators.scenario import Scenario
from simulators.scenario_file import load_scenario
from drivers.addresses import REDACTED, redact_tokens
from rtcal.run.integrity import (RESULTS_DIGEST_KEY, check_run, deliverable_digests, digests_of, results_digest,
                                 signature_digests)
from rtcal.run.signing import SIGNATURE_FILENAME, KeyConfigError, LabKey, load_lab_key, signed_document
from rtcal.store.hint import OPERATOR_TOKEN_ENV, resume_hint

OnEngine = Callable[[Engine, Path], "Callable[[], None] | None"]
"""Called with the engine and the run directory before the first motion (remote control, the live
view); what it returns is called when the run ends, however it ends. One with a true
``remote_operator`` attribute (`--live`: the run serves its page) lets an operator step without a
terminal wait for a remote confirm instead of stopping the run."""

__all__ = ["METHODS", "AnalysisFailed", "RunOutcome", "resume_run", "run_procedure"]


class AnalysisFailed(Exception):
    """Measuring finished but the solvers could not use the data (e.g. too many readings skipped)."""


@dataclass(frozen=True)
class RunOutcome:
    run_dir: Path
    results: RunResults
    instrument_readings: int | None = None  # raw values stored (results' raw_readings counts planned readings)
    finished: bool = False  # a resume found the run finished: nothing was taken, nothing written


def default_run_dir(method: str) -> Path:
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    return Path("runs") / f"{stamp}-{method}"


def resolve_scenario(procedure_path: Path, proc: Procedure, scenario_path: Path | None) -> tuple[Scenario, str]:
    """The bench: ``--scenario`` if given, else the procedure's ``bench`` (relative to it, inside its
    folder), else ideal."""
    if scenario_path is None:
        scenario_path = bench_path(procedure_path, proc)
    if scenario_path is None:
        return Scenario(), ""
    text = read_text(scenario_path)
    scenario = load_scenario(scenario_path, text)
    if scenario.stage.compensation is not None:  # the table travels with the scenario stored in the run
        return scenario, yaml.safe_dump(scenario.model_dump(mode="json", exclude_defaults=True), sort_keys=False, allow_unicode=True)
    return scenario, text


def scenario_label(procedure_path: Path, proc: Procedure, scenario_path: str | Path | None) -> str:
    """Where the simulated bench came from, for the results: a file, or the ideal bench."""
    if scenario_path is not None:
        return str(scenario_path)
    return str(procedure_path.parent / proc.bench) if proc.bench is not None else ""


IDEAL_BENCH = ("ideal bench: the procedure names no `bench:` scenario and none was given with --scenario, so every "
               "simulated instrument is perfect and the results show no error")


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat()


class CalibrationExpired(RunDirError):
    """A reference standard or instrument past its calibration due date: a lab may not issue a
    certificate from it (ISO/IEC 17025 6.4.7), so the run does not start (exit 2)."""


def expired_instruments(proc: Procedure, on: _dt.date) -> list[tuple[str, str]]:
    """(name, calibration_due) of every instrument or standard in the metadata whose due date lies before ``on``."""
    return [(name, rec.calibration_due) for name, rec in proc.metadata.instruments.items()
            if rec.calibration_due and _dt.date.fromisoformat(rec.calibration_due) < on]


def with_metadata(procedure_yaml: str, values: dict[str, str], name: str) -> str:
    """The procedure's text with these ``metadata`` keys set (by `rtcal run --certificate-number`,
    `--as-found`, `--as-left`): what the run stores, and says so in its first line, so resume, verify
    and the live view read them. A procedure is a template used for many runs; each certificate needs
    its own number (ISO/IEC 17025 7.8.2.1)."""
    data = yaml.safe_load(procedure_yaml)
    data.setdefault("metadata", {}).update(values)
    return (f"# {name}, as run: metadata.{', metadata.'.join(values)} given on `rtcal run`'s command line\n"
            + yaml.safe_dump(data, sort_keys=False, allow_unicode=True))


def check_calibration_due(proc: Procedure, on: _dt.date | None = None) -> None:
    """Refuse a measurement on a day when a reference standard or instrument is past its due date."""
    on = on or _dt.datetime.now(_dt.timezone.utc).date()
    expired = expired_instruments(proc, on)
    if expired:
        which = "; ".join(f"{name} {proc.metadata.instruments[name].id or ''} calibration_due {due}".replace("  ", " ")
                          for name, due in expired)
        raise CalibrationExpired(f"refused: past its calibration due date on the measurement date {on.isoformat()}: "
                                 f"{which} (metadata.instruments): recalibrate it, or use one in calibration")


NON_INSTRUMENT_ADDRESSES = ("operator",)  # what `rtcal sim serve` prints besides the instruments


def known_address_names() -> list[str]:
    """Every name an ``--instruments`` object may hold: any method's instruments (`rtcal sim serve`
    serves them all, a procedure uses some) and the simulated operator."""
    names = {f for model in procedure_models().values()
             for f in cast("type[BaseModel]", model.model_fields["instruments"].annotation).model_fields}  # each method's Instruments
    return sorted(names) + list(NON_INSTRUMENT_ADDRESSES)


def check_address_names(addresses: dict[str, str]) -> None:
    """A name that is no instrument (a misspelling) is refused: ignored, it would leave that
    instrument where the procedure put it — on the in-process bench, for a simulated one."""
    known = known_address_names()
    unknown = [name for name in addresses if name not in known]
    if unknown:
        from difflib import get_close_matches

        hints = {n: get_close_matches(n, known, 1) for n in unknown}
        raise FileProblems([Problem("--instruments", 1, 1, n[:60], f"not an instrument rtcal knows; did you mean "
                                    f"`{hints[n][0]}`?" if hints[n] else f"no such instrument (known: {', '.join(known)})")
                            for n in unknown])


def with_addresses(proc: Procedure, addresses: dict[str, str]) -> Procedure:
    """The procedure with its instruments moved to the given addresses, validated again."""
    check_address_names(addresses)
    section = proc.instruments.model_dump()
    for name in section:
        if name in addresses and section[name] is not None:  # an instrument the procedure does not use stays out
            section[name].update(address=addresses[name], backend=None)
    try:
        instruments = type(proc.instruments).model_validate(section)
    except ValidationError as exc:
        raise FileProblems([Problem("--instruments", 1, 1, ".".join(map(str, e["loc"])) or "(instruments)",
                                    str(e["msg"]).removeprefix("Value error, ")) for e in exc.errors()]) from None
    return proc.model_copy(update={"instruments": instruments})


def check_plan_on_bench(procedure_path: Path, proc: Procedure, scenario: Scenario, method: Method[Any, Any]) -> None:
    """Refuse, before anything moves, a plan the simulated bench cannot do: stage limits, CMM
    volume, and what the method itself refuses (a polygon of another face count). `rtcal validate` runs
    the same check."""
    problem = plan_outside_limits(proc, scenario.stage.soft_limits_deg, scenario.cmm.volume_min_mm, scenario.cmm.volume_max_mm)
    if problem:
        field, _, message = problem.partition(": ")
        raise FileProblems([problem_at(procedure_path, (field,), f"{message} (the simulated bench's limits)")])
    refused = method.scenario_problem(proc, scenario)
    if refused is not None:
        raise FileProblems([problem_at(procedure_path, refused[0], refused[1])])


def _operator(bench: Bench | None, addresses: dict[str, str] | None, on_engine: OnEngine | None = None,
              run_dir: Path | None = None, rehearse: bool = False):
    """The simulated bench, the simulated operator of `rtcal sim serve`, or a person: at the terminal
    and by a remote confirm, which without a terminal is waited for only when the run serves its page.
    ``rehearse``: a person confirms each step, then the simulated bench or operator carries it out."""
    remote = bool(getattr(on_engine, "remote_operator", False))
    simulated: BenchOperator | RemoteSimOperator | None = None
    if bench:
        simulated = BenchOperator(bench)
    elif addresses and "operator" in addresses:
        simulated = RemoteSimOperator(addresses["operator"])
    if rehearse:
        if simulated is None:
            raise RunDirError("--rehearse: a person confirms each operator step and the simulated operator then does "
                              "it on the simulators: give its address (`operator` in --instruments, as `rtcal sim "
                              "serve` printed it); on hardware leave --rehearse out")
        check_rehearsal_reachable(on_engine)
        return RehearsalOperator(simulated, remote=remote, run_dir=run_dir)
    return simulated if simulated is not None else WaitingOperator(remote=remote, run_dir=run_dir)


def check_rehearsal_reachable(on_engine: OnEngine | None) -> None:
    """A rehearsal waits for a person at every operator step: at the terminal or on the live page. With
    neither it could only fail at its first step, so it is refused before a run folder is made or a
    stored run is changed (RunDirError, exit 2)."""
    if stdin_terminal() is None and not getattr(on_engine, "remote_operator", False):
        raise RunDirError("--rehearse: each operator step waits for a person to confirm it (Enter at the terminal, "
                          "Done on the live page) and this run has neither a terminal nor --live: run it from a "
                          "terminal, or add --live [HOST:]PORT")


def _keep_fault_counters(store: RunStore, bench: Bench | None) -> None:
    """A simulated bench's fault schedule counts requests over the whole run: the counters are
    stored with every reading and event, and a resume goes on from them (a fault scheduled at
    request 1 happens once, not at every start)."""
    if bench is not None and bench.faults.faults:
        bench.faults.requests.update(json.loads(store.meta().get("fault_requests", "{}")))
        store.keep_meta(lambda: {"fault_requests": json.dumps(dict(bench.faults.requests), sort_keys=True)})


IDENTITY_KEY = "machine_identity"
"""The store's meta key of the machine's identification read at the start (JSON): a resume applies it
again rather than lose it (the stored procedure is the template, without what the machine said)."""


def read_machine_identity(proc: Procedure) -> dict[str, Any] | None:
    """``metadata.machine_identity``'s identification (OPC 40001-1, or an MTConnect agent's probe), read
    before anything moves (None: the procedure names no server). With several machines the address (``?machine=``, ``?serial=``) or the
    procedure's ``serial_number`` chooses; an unreachable server or a nameplate of the wrong types is an
    InstrumentError (exit 1)."""
    address = proc.metadata.machine_identity
    if not address:
        return None
    from drivers.machine_identity import read_machine_identity as read

    return read(address, serial=proc.metadata.serial_number or None)


def apply_machine_identity(proc: Procedure, ident: dict[str, Any], where: str, line: int) -> Procedure:
    """The procedure whose certificate item takes the machine's serial number, manufacturer and model
    where the procedure leaves them empty, through the same validators as the procedure's own metadata
    (a control character, a right-to-left override or a 100 kB serial number refuse the run at ``where``
    before anything moves); a serial number other than the procedure's refuses it (FileProblems, exit 2)."""
    from drivers.opcua_identity import shown

    address = proc.metadata.machine_identity
    said = ident.get("serial_number")
    said = "" if said is None else str(said)
    if proc.metadata.serial_number and said != proc.metadata.serial_number:
        raise FileProblems([Problem(where, line, 1, "metadata.machine_identity",
                                    f"the machine at {address} says serial number {shown(said, 100)!r}, the procedure "
                                    f"{proc.metadata.serial_number!r}: another machine; nothing was moved")])
    machine = proc.metadata.machine or " ".join(str(ident.get(k) or "") for k in ("manufacturer", "model")).strip()
    data = {**proc.metadata.model_dump(), "serial_number": proc.metadata.serial_number or said, "machine": machine}
    try:
        meta = type(proc.metadata).model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        field = ".".join(map(str, first["loc"]))
        value = shown(first.get("input", ""), 60)
        raise FileProblems([Problem(where, line, 1, "metadata.machine_identity",
                                    f"the machine at {address} gives {field} {value!r}, which a certificate cannot "
                                    f"carry: {str(first['msg']).removeprefix('Value error, ')}; nothing was moved")]) from None
    return proc.model_copy(update={"metadata": meta})


def with_machine_identity(proc: Procedure, path: Path, text: str) -> tuple[Procedure, dict[str, Any] | None]:
    """The procedure with the machine's identification applied (:func:`apply_machine_identity`, located
    at the line of the file's ``metadata.machine_identity`` key), and the identification as read (None:
    none asked). ``text``: the file as the user wrote it (not the text a --certificate-number rewrote)."""
    ident = read_machine_identity(proc)
    if ident is None:
        return proc, None
    return apply_machine_identity(proc, ident, str(path), key_line(text, str(path), ("metadata", "machine_identity"))), ident


def key_line(text: str, where: str, key: tuple[str, ...]) -> int:
    """The line of ``key`` (a path of keys) in the YAML ``text`` as its parser sees it: a comment, a string
    value or another section naming the key is not it (1 if the text cannot be read)."""
    try:
        _, locations = load_yaml(text, where)
    except FileProblems:
        return 1
    return locate(key, locations)[0]


def run_procedure(
    procedure_path: str | Path,
    scenario_path: str | Path | None = None,
    seed: int | None = None,
    out_dir: str | Path | None = None,
    show_progress: bool | None = None,
    addresses: dict[str, str] | None = None,
    virtual_clock: bool = False,
    large: bool = False,
    outputs: bool = True,
    estimate_noise: bool = True,
    on_engine: OnEngine | None = None,
    certificate_number: str | None = None,
    rehearse: bool = False,
    item_state: str | None = None,
) -> RunOutcome:
    """Run a procedure and write the run directory (``outputs=False``: the store only, no
    results.json, figures or report — for Monte Carlo trials). ``certificate_number`` and ``item_state``
    (as_found, as_left) replace the procedure's metadata for this run (the stored procedure says so).

    All instruments ``sim``: an in-process bench (from the scenario) with a virtual clock, and
    the results carry its truth. Otherwise real transports at the procedure's addresses (or
    ``addresses``, e.g. what `rtcal sim serve` printed), a real clock unless ``virtual_clock``,
    and no truth. Raises FileProblems on bad input and InstrumentError on instrument failure.
    ``out_dir`` must be new or empty; it is locked (RunBusy) until the run ends.
    """
    procedure_path = Path(procedure_path)
    procedure_yaml = as_written = read_text(procedure_path)
    proc = load_procedure(procedure_path, large, procedure_yaml)
    given = {k: v for k, v in (("certificate_number", certificate_number), ("item_state", item_state)) if v is not None}
    if given:
        procedure_yaml = with_metadata(procedure_yaml, given, procedure_path.name)
        proc = load_procedure(procedure_path, large, procedure_yaml)
    if addresses:
        proc = with_addresses(proc, addresses)
    check_calibration_due(proc)
    proc, identity = with_machine_identity(proc, procedure_path, as_written)
    method = METHODS[proc.method]
    simulated = proc.instruments.all_sim()
    bench, scenario_text = None, ""
    if simulated:  # a run over transports has no bench here: the instruments are elsewhere
        scenario, scenario_text = resolve_scenario(procedure_path, proc, Path(scenario_path) if scenario_path else None)
        check_plan_on_bench(procedure_path, proc, scenario, method)
        seed = scenario.seed if seed is None else int(seed)
        bench = Bench(scenario, VirtualClock(), seed)
    bench_timing = _wired_motion_timing(procedure_path, proc, scenario_path) if not simulated else None
    motion_timing = bench_timing if virtual_clock else None
    run_dir = Path(out_dir) if out_dir is not None else default_run_dir(proc.method)
    key = load_lab_key(run_dir=run_dir) if outputs else None  # a key that cannot sign refuses the run before anything moves
    operator = _operator(bench, addresses, on_engine, run_dir, rehearse)
    prepared = method.prepare(proc, operator)
    lock = claim_new_run_dir(run_dir)
    try:
        store = RunStore.create(run_dir, {**prepared,
            "method": proc.method, "procedure_path": str(procedure_path), "procedure_yaml": procedure_yaml,
            "instruments": proc.instruments.model_dump_json(), "scenario_yaml": scenario_text,
            "scenario_path": scenario_label(procedure_path, proc, scenario_path) if simulated else "",
            "seed": str(seed) if simulated else "", "software_version": __version__,
            "started_utc": _now(), "status": "not started", "generation": "0", "large": "1" if large else "",
            "operator_address": (addresses or {}).get("operator", ""),
            CLOCK_KEY: "virtual" if simulated or virtual_clock else "real",
            **({CONTEXT_COLUMNS_KEY: json.dumps(dict(method.context_columns))} if method.context_columns else {}),
            **({IDENTITY_KEY: json.dumps(identity, sort_keys=True)} if identity is not None else {}),
            **({REHEARSED_KEY: "1"} if rehearse else {}),
        })
        _keep_fault_counters(store, bench)
        return _measure_and_solve(method, proc, run_dir, store, bench, operator, virtual_clock, show_progress, 0, outputs,
                                  estimate_noise, on_engine, motion_timing, bench_timing, key)
    finally:
        lock.release()


def resume_run(
    run_dir: str | Path,
    addresses: dict[str, str] | None = None,
    virtual_clock: bool | None = None,
    show_progress: bool | None = None,
    on_engine: OnEngine | None = None,
    rehearse: bool = False,
) -> RunOutcome:
    """Continue an interrupted run from its store: every planned reading not yet stored, once.

    The procedure, instrument section, scenario and seed come from the store, not from files
    that may have changed since. Simulated instruments get a new bench generation (fresh random
    draws); transports reconnect (``addresses`` replaces the stored ones, e.g. a restarted
    `rtcal sim serve`). The first pending reading re-approaches its targets from the
    procedure's direction and re-references the tracer. Skipped readings are retaken, also
    those of a run that was solved without them. A complete run is left as it is. The run directory is locked (RunBusy) until the resume ends.
    ``virtual_clock`` None: the clock kind stored with the run; either way the clock goes on from the
    run's last stored time, so times only increase and the duration counts every start.
    """
    run_dir = Path(run_dir)
    if addresses:
        check_address_names(addresses)
    if rehearse:
        check_rehearsal_reachable(on_engine)
    lock = claim_run_dir(run_dir)  # RunDirError: no such directory, no store in it
    try:
        try:
            store = RunStore.open(run_dir)
        except FileNotFoundError as exc:
            raise RunDirError(f"{run_dir}: nothing to resume: {exc}") from None
        except StoreUnusable as exc:
            raise RunDirError(f"cannot resume: {exc}") from None
        meta = store.meta()
        where = f"{run_dir / RunStore.FILENAME}"
        method = METHODS[_stored(meta, "method", lambda v: v if v in METHODS else None, run_dir,
                                 f"one of {', '.join(METHODS)}")]  # the registry chooses, once, by the stored name
        model = method.procedure_model
        proc = cast(Procedure, validate_text(_stored(meta, "procedure_yaml", str, run_dir, "the procedure's text"), model,
                                             f"{where} (stored procedure)", context={"large": bool(meta.get("large"))}))  # as load_procedure
        instruments = _stored(meta, "instruments", type(proc.instruments).model_validate_json, run_dir,
                              "the procedure's instrument section as JSON")
        proc = proc.model_copy(update={"instruments": instruments})
        if IDENTITY_KEY in meta:  # the machine's identification read at the start: the certificate's item keeps it
            identity = _stored(meta, IDENTITY_KEY, _identity, run_dir, "the machine's identification as JSON")
            try:
                proc = apply_machine_identity(proc, identity, f"{where} (stored procedure)", 1)
            except FileProblems as exc:
                raise RunDirError(f"cannot resume: {exc.problems[0]}") from None
        previous_generation = _stored(meta, "generation", _count, run_dir, "a whole number ≥ 0")
        twice = store.readings_stored_twice()
        if twice:
            raise RunDirError(f"cannot resume: {where} holds {twice} readings more than once (the same instrument, "
                              "quantity and sample of one attempt at a planned reading): the store was edited or "
                              f"merged, and its results would count them twice; `rtcal export {run_dir}` writes them all")
        complete = len(store.done_plan_indices()) >= method.plan_length(proc)
        finished = stored_results(run_dir) if meta.get("status") == "solved" and complete else None
        if finished is not None:  # nothing to take, nothing to count: the run stays as it is
            counted = store.instrument_readings()
            store.close()
            check_run(run_dir, finished)  # its results still match its readings
            return RunOutcome(run_dir, finished, counted, finished=True)
        # a run solved with readings its skip policy left out goes on too: it retakes them and solves again
        if addresses:
            proc = with_addresses(proc, addresses)
        simulated = proc.instruments.all_sim()
        done = len(store.done_plan_indices())
        planned = method.plan_length(proc)
        operator_address = (addresses or {}).get("operator") or (
            _stored_operator(meta, run_dir) if done < planned else "")
        if operator_address:  # a wired run goes on with the simulated operator it had
            addresses = {**(addresses or {}), "operator": operator_address}
            store.set_meta({"operator_address": operator_address})  # stored with its token redacted
        generation = previous_generation + (1 if done < planned else 0)
        virtual_clock = _resumed_clock(meta.get(CLOCK_KEY), proc, simulated, virtual_clock, run_dir, done < planned)
        bench = None
        if simulated:
            scenario_yaml = _stored(meta, "scenario_yaml", str, run_dir, "a bench scenario's text")
            scenario = validate_text(scenario_yaml, Scenario, f"{where} (stored scenario)") if scenario_yaml else Scenario()
            seed = _stored(meta, "seed", lambda v: _count(v) if _count(v) <= 2**63 - 1 else None, run_dir,
                           "a whole number 0 … 2⁶³ − 1")
            _stored(meta, "fault_requests", _counters, run_dir, "a JSON object of request counts", "{}")
            bench = Bench(scenario, VirtualClock(store.last_time_s()), seed, generation)
            _keep_fault_counters(store, bench)
        try:
            key = load_lab_key(run_dir=run_dir)  # before anything moves: a key that cannot sign refuses the resume
        except KeyConfigError:
            store.close()
            raise
        if rehearse:  # a rehearsal at any start makes the whole run one
            store.set_meta({REHEARSED_KEY: "1"})
        if done < planned:
            try:
                check_calibration_due(proc)
            except CalibrationExpired:
                store.close()
                raise
            store.set_meta({"generation": str(generation), "status": "running", f"resumed_utc_{generation}": _now()})
            store.add_event(store.last_time_s(), "resume", f"resumed (start {generation + 1}): {done} of "
                            f"{planned} planned readings were already stored")
            _record_clock(store, meta.get(CLOCK_KEY), virtual_clock)
        bench_timing = (_wired_motion_timing(Path(meta.get("procedure_path") or "."), proc, None)
                        if not simulated else None)  # as `run` counts them (from the procedure's bench)
        motion_timing = bench_timing if virtual_clock else None
        return _measure_and_solve(method, proc, run_dir, store, bench, _operator(bench, addresses, on_engine, run_dir, rehearse),
                                  virtual_clock, show_progress, generation, on_engine=on_engine, motion_timing=motion_timing,
                                  eta_timing=bench_timing, key=key)
    finally:
        lock.release()


CLOCK_KEY = "clock"
"""The store's meta key of the clock kind the run goes on (`virtual`, `real`): a resume reuses it."""


def _resumed_clock(stored: str | None, proc: Procedure, simulated: bool, asked: bool | None, run_dir: Path,
                   measuring: bool) -> bool:
    """Whether a resume goes on on the virtual clock: as asked, else as the run went (``stored``; a store
    from before the clock kind was stored: real, as resumes then did). An in-process simulation is always
    virtual; a real LinuxCNC never (RunDirError, exit 2). Not ``measuring`` (every reading stored),
    the stored kind stands."""
    if simulated:
        if asked is False and measuring:
            raise RunDirError(f"--real-clock: {run_dir} is simulated in process, which runs on the virtual clock; "
                              "drop --real-clock")
        return True
    # nothing left to measure: the results describe the clock the readings were taken on, whatever is asked
    virtual = asked if asked is not None and measuring else stored == "virtual"
    stage = getattr(proc.instruments, "stage", None)
    if virtual and str(getattr(stage, "address", "") or "").startswith("linuxcncrsh://"):
        raise RunDirError(f"cannot resume {run_dir} on the virtual clock: the stage is a real LinuxCNC "
                          "(linuxcncrsh://), which moves in real time; add --real-clock")
    return virtual


def _record_clock(store: RunStore, stored: str | None, virtual: bool) -> None:
    """A change of clock kind is stored (the next resume goes on on it) and logged (times still only grow)."""
    kind = "virtual" if virtual else "real"
    if kind != stored:
        store.set_meta({CLOCK_KEY: kind})
        if stored:
            store.add_event(store.last_time_s(), "resume", f"goes on on the {kind} clock (the run went on the {stored} "
                            "clock until now)")


def _stored_operator(meta: dict[str, str], run_dir: Path) -> str:
    """The simulated operator's address a wired run had, its token from the environment (the store
    keeps it redacted: whoever copies a run directory must not command the operator)."""
    stored = meta.get("operator_address", "")
    if not stored or f"token={REDACTED}" not in stored:
        return stored
    token = os.environ.get(OPERATOR_TOKEN_ENV, "")
    if not token:
        raise RunDirError(f"cannot resume: {run_dir} was run with the simulated operator at {stored}, whose token is "
                          f"not stored with the run: {resume_hint(run_dir, needs_addresses=True)}, or set "
                          f"{OPERATOR_TOKEN_ENV}")
    return stored.replace(f"token={REDACTED}", f"token={token}")


def _stored(meta: dict[str, str], key: str, parse, run_dir: Path, expected: str, default: str | None = None) -> Any:
    """``meta[key]`` parsed, or a RunDirError naming the key, what it holds and what it should: a
    store edited by hand is refused with one line, not a traceback. ``parse`` returns None or
    raises ValueError for a value it refuses (a pydantic ValidationError is one)."""
    value = meta.get(key, default)
    try:
        parsed = parse(value) if value is not None else None
    except (ValueError, TypeError, RecursionError):
        parsed = None
    if parsed is None:
        shown = "missing" if value is None else repr(value if len(value) <= 60 else value[:60] + "…")
        raise RunDirError(f"cannot resume: {run_dir / RunStore.FILENAME}: its `{key}` is {shown}, not {expected}: the "
                          f"store was edited; `rtcal export {run_dir}` writes its readings")
    return parsed


def _identity(text: str) -> dict[str, Any]:
    """A stored machine identification: a JSON object of text, whole numbers and nulls."""
    data = json.loads(text)
    if not isinstance(data, dict) or not all(isinstance(k, str) and (v is None or type(v) in (str, int))
                                             for k, v in data.items()):
        raise ValueError(text)
    return data


def _count(text: str) -> int:
    """A whole number ≥ 0 written in decimal digits (no sign, no spaces)."""
    if not (text.isascii() and text.isdigit()) or len(text) > 30:
        raise ValueError(text)
    return int(text)


def _counters(text: str) -> dict[str, int]:
    data = json.loads(text)
    if not isinstance(data, dict) or not all(isinstance(k, str) and type(v) is int and v >= 0 for k, v in data.items()):
        raise ValueError(text)
    return data


def evaluation_of(analysis: Analysis) -> Evaluation | None:
    """ISO 230-2 and VDI 3441 parameters of the run's positioning deviations (what a certificate lists)."""
    if analysis.positioning_deviations is None:
        return None
    table = PositioningDeviations.from_model(analysis.positioning_deviations)
    return Evaluation(iso230_2=Iso230Evaluation.model_validate(evaluate(table, "iso230-2")),
                      vdi3441=VdiEvaluation.model_validate(evaluate(table, "vdi3441")))


def conformity_of(proc: Procedure, analysis: Analysis, evaluation: Evaluation | None) -> Conformity | None:
    """The verdict against the procedure's acceptance limits (None: it states none, or nothing to evaluate)."""
    if proc.acceptance is None or evaluation is None or analysis.positioning_deviations is None:
        return None
    a = proc.acceptance
    return assess(a.decision_rule, a.limits_arcsec.items(), a.band_arcsec, evaluation.iso230_2, analysis,
                  PositioningDeviations.from_model(analysis.positioning_deviations))


def _virtual_end(started_utc: str | None, elapsed_s: float) -> str | None:
    """A simulated run's end: its start plus the virtual clock's elapsed time (the wall clock would
    say the few seconds the simulation took, not the hours the measurement stands for)."""
    if not started_utc:
        return None
    try:
        return (_dt.datetime.fromisoformat(started_utc) + _dt.timedelta(seconds=elapsed_s)).isoformat()
    except ValueError:
        return None


def _wired_motion_timing(procedure_path: Path, proc: Procedure, scenario_path: str | Path | None) -> Timing | None:
    """Simulators over wires on a virtual clock: their motions at the speeds of the bench they model
    (--scenario, else the procedure's `bench`); None when neither can be read (the clock then counts
    only what the drivers wait)."""
    try:
        scenario, _ = resolve_scenario(procedure_path, proc, Path(scenario_path) if scenario_path else None)
    except FileProblems:
        return None
    return Timing.of_scenario(scenario)


def _measure_and_solve(method: Method[Any, Any], proc: Procedure, run_dir: Path, store: RunStore, bench: Bench | None, operator,
                       virtual_clock: bool, show_progress: bool | None, generation: int, outputs: bool = True,
                       estimate_noise: bool = True, on_engine: OnEngine | None = None,
                       motion_timing: Timing | None = None, eta_timing: Timing | None = None,
                       key: LabKey | None = None) -> RunOutcome:
    """Open the instruments, take every pending planned reading, then analyse and write the outputs
    (``motion_timing``: a wired run on a virtual clock counts each motion at these speeds;
    ``eta_timing``: the speeds the time left is walked at, a simulated bench's own by default)."""
    goes_on_s = store.last_time_s()  # a resume's clock goes on where the run stopped: times only grow
    clock = bench.clock if bench else (VirtualClock(goes_on_s) if virtual_clock else RealClock(goes_on_s))
    try:
        store.reserve_space()  # a disk that fills up mid-run must still take the run's last status
        store.sync_each_commit(to_disk=isinstance(clock, RealClock))  # a simulation's readings to the OS, not the disk
        inst = method.sim_instruments(proc, bench) if bench else method.transport_instruments(proc)
    except BaseException as exc:
        if isinstance(exc, KeyboardInterrupt):  # nothing moved yet
            _record_interruption(store, goes_on_s, exc, "not started", "while the instruments were opened: nothing moved")
        else:
            _stop(store, "not started", exc)
        raise
    done = store.done_plan_indices()
    devices = inst.devices()
    if bench is None:  # what each instrument says it is: rtcal's simulators say SIMULATED
        _record_simulators(store, devices)
    step_deg = float(getattr(devices.get("stage"), "step_deg", 0.0) or 0.0)
    plan = method.plan(proc, done, generation, step_deg)
    shown = show_progress is not False or on_engine is not None  # a Monte Carlo trial shows no one the time left
    timing = (eta_timing or (Timing.of_scenario(bench.scenario) if bench is not None else None)) if shown else None
    virtual = not isinstance(clock, RealClock)
    person = isinstance(operator, WaitingOperator)  # a simulated operator's steps take no time on a real clock
    walked = walk(method.plan(proc, done, generation, step_deg), timing, done) if timing else None
    eta = Eta(walked.entry_s, virtual, operator_timed=virtual or person, motion_s=walked.entry_motion_s,
              after_s=0.0 if virtual else solve_estimate_s(len(plan.entries))) if walked is not None else None  # solving: wall
    subscribers: list = ([eta] if eta else []) + [StoreWriter(store, eta)]  # the estimate first: both read it
    if show_progress is not False:
        subscribers.append(ConsoleProgress(virtual_clock=virtual, eta=eta))
    engine = Engine(devices, clock, operator, subscribers, store.new_attempt, store.max_segment() + 1, motion_timing,
                    method.context_columns)
    detach = None
    try:
        try:
            if on_engine is not None:  # remote control (and the live view): before the first motion
                detach = on_engine(engine, run_dir)
            store.set_meta({"status": "running"})
            engine.run(plan, done)
        except BaseException as exc:  # the engine has stopped every machine it moved
            _stop(store, "aborted" if isinstance(exc, RunAborted) else "failed" if isinstance(exc, PlanError) else
                  "interrupted", exc)
            raise
        finally:
            inst.close()
        try:
            return _solve_and_write(method, proc, run_dir, store, bench, clock, generation, outputs, estimate_noise, key)
        except KeyboardInterrupt as exc:  # a signal while solving or writing: no results, recorded as any stop
            _record_interruption(store, clock.now_s(), exc, "interrupted", "while the results were computed: none were "
                                 "written; `rtcal resume` computes them again")
            raise
    finally:
        if detach is not None:  # the live view showed the run to its end
            detach()


def _solve_and_write(method: Method[Any, Any], proc: Procedure, run_dir: Path, store: RunStore, bench: Bench | None,
                     clock: Any, generation: int, outputs: bool, estimate_noise: bool, key: LabKey | None = None) -> RunOutcome:
    """The measured run's analysis, its typed results and every output file; with the lab's ``key``,
    signature.json (written last, over results.json's SHA-256 and every digest it records)."""
    simulated = bench is not None
    store.set_meta({"status": "measured", "finished_utc": _now()})
    meta = store.meta()
    try:
        analysis = method.analyse(proc, store, bench, estimate_noise)
    except DataContradiction as exc:
        store.close()
        raise AnalysisFailed(f"check FAILED: {exc}; no results and no certificate written; every reading is in "
                             f"{run_dir / RunStore.FILENAME}") from exc
    except (ValueError, np.linalg.LinAlgError) as exc:
        store.close()
        raise AnalysisFailed(f"the readings are complete but the solvers could not use them: {exc}; "
                             f"every reading is in {run_dir / RunStore.FILENAME}") from exc
    if analysis.recommended is None:
        store.close()
        failures = "; ".join(f"{n}: {st.message}" for n, st in analysis.solver_status.items())
        raise AnalysisFailed(f"the readings are complete but the solvers could not use them: no estimator ran ({failures}); "
                             f"every reading is in {run_dir / RunStore.FILENAME}")
    undeclared = sorted({analysis.recommended, *analysis.solver_status} - set(method.estimators))
    if undeclared:
        store.close()
        raise AnalysisFailed(f"the method {method.name} names the estimator {undeclared[0]!r}, which it does not declare "
                             f"(its estimators: {', '.join(method.estimators) or 'none'}); every reading is in "
                             f"{run_dir / RunStore.FILENAME}")
    events = [Event(**e) for e in store.events()]
    virtual = isinstance(clock, VirtualClock)
    try:
        info = RunInfo(
            schema_version=SCHEMA_VERSION,
            rtcal_version=__version__,
            method=proc.method,
            procedure=ProcedureRef(name=proc.name, path=meta.get("procedure_path", ""),
                                   standards=list(proc.evaluation.standards) if proc.evaluation is not None
                                   and proc.evaluation.standards else None),
            metadata=RunMetadata.model_validate(proc.metadata.model_dump(exclude={"machine_identity"})),
            seed=int(meta["seed"]) if simulated else None,
            instruments="simulated in process" if simulated else {
                f: redact_tokens(getattr(proc.instruments, f).address) for f in proc.instruments.present()},
            bench=(meta.get("scenario_path") or IDEAL_BENCH) if simulated else None,
            started_utc=meta.get("started_utc"),
            finished_utc=_virtual_end(meta.get("started_utc"), clock.now_s()) if virtual else meta.get("finished_utc"),
            starts=generation + 1,
            measurement_duration_s=round(clock.now_s(), 1),
            clock="virtual" if virtual else "real",
            simulation=simulation_of(meta, simulated),
        )
        evaluation = evaluation_of(analysis) if method.positioning_deviation else None  # the method says what its result is
        log = RunLog(evaluation=evaluation, skipped_readings=len(store.skipped_plan_indices()),
                     faults=sum(1 for e in events if e.kind == "fault"), events=events,
                     conformity=conformity_of(proc, analysis, evaluation),
                     control=control_record(proc, method, simulated, meta.get("operator_address", ""),
                                            len(store.rejected_attempts())),
                     digests=digests_of(store),
                     signature=Signature(algorithm="ed25519", signer=key.signer, key_fingerprint=key.fingerprint)
                     if key is not None and outputs else None)
        results = assemble(info, analysis, log, method.results_model)
    except ValidationError as exc:  # a value beyond what results.json admits: the readings stay, the file is not written
        store.close()
        first = exc.errors()[0]
        raise AnalysisFailed(f"the results cannot be written: {'.'.join(map(str, first['loc']))}: {first['msg']}; "
                             f"every reading is in {run_dir / RunStore.FILENAME}") from exc
    counted = store.instrument_readings()
    if not outputs:
        store.set_meta({"status": "solved"})
        store.close()
        return RunOutcome(run_dir, results, counted)
    # the documents' modules load here, not at import: `rtcal validate` imports this module
    from rtcal.deliverables.certificate import build_certificate, write_certificate_json
    from rtcal.deliverables.report import write_html, write_markdown, write_pdf

    method_outputs = method.outputs(results)
    try:
        with staged_outputs(run_dir) as out:  # written aside, renamed into place: planted links are replaced, not followed
            if results.positioning_deviations is not None:  # the table every method hands downstream, for spreadsheets too
                PositioningDeviations.from_model(results.positioning_deviations).write_csv(out / "positioning_deviations.csv")
            method_outputs.write_files(out)
            certificate = build_certificate(results, out, method)  # one document, laid out three times
            write_markdown(certificate, out / "report.md")
            write_html(certificate, out / "report.html")
            write_pdf(certificate, out / "report.pdf")
            write_certificate_json(certificate, out / "certificate.json")
            # last: results.json records the digest of every file above as written (the certificate shows none)
            results = with_deliverable_digests(results, deliverable_digests(out))
            write_results(out, results)
            if key is not None:  # the lab's signature over what the run hands over: results.json and every digest in it
                document = signed_document(key, results_digest(results), *signature_digests(results), _now())
                (out / SIGNATURE_FILENAME).write_text(json.dumps(document, indent=1) + "\n", encoding="utf-8")
        if key is None and os.path.lexists(run_dir / SIGNATURE_FILENAME):  # an earlier start's, over results now replaced
            os.unlink(run_dir / SIGNATURE_FILENAME)
    except BaseException as exc:  # measured and solved, the results not (all) written: a resume writes them
        if not isinstance(exc, KeyboardInterrupt):  # (an interruption is recorded by the caller)
            _stop(store, "measured", exc)
        raise
    # only now: `resume` of a solved run changes nothing; the store records which results.json it has
    store.set_meta({"status": "solved", "engine_state": "finished", RESULTS_DIGEST_KEY: results_digest(results)})
    store.close()
    return RunOutcome(run_dir, results, counted)


SIMULATORS_KEY = "simulators"
"""The store's meta key of the instruments that answered from rtcal's simulators, over every start (JSON)."""
REHEARSED_KEY = "rehearsed"
"""The store's meta key set when any start of the run was a rehearsal (`--rehearse`)."""


def _record_simulators(store: RunStore, devices: dict[str, Any]) -> None:
    """Each instrument whose identity reply says SIMULATED (rtcal's protocol simulators: drivers/interfaces.py
    SIMULATED_MARK), added to those of earlier starts: a run resumed on real instruments stays marked."""
    from drivers.errors import InstrumentError
    from drivers.interfaces import SIMULATED_MARK

    found = _simulators(store.meta().get(SIMULATORS_KEY, "{}"))
    for name, device in devices.items():
        try:
            said = str(device.identity())
        except InstrumentError:
            said = ""
        if SIMULATED_MARK in said:
            found[name] = said[:1000]
    store.set_meta({SIMULATORS_KEY: json.dumps(found, sort_keys=True)})


def _simulators(text: str) -> dict[str, str]:
    try:
        data = json.loads(text)
    except ValueError:
        data = None
    if not isinstance(data, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
        return {"(store)": f"its record of simulated instruments is not rtcal's ({text[:60]!r}): taken as simulated"}
    return data


def simulation_of(meta: dict[str, str], in_process: bool) -> Simulation | None:
    """Why the run is no calibration, from the store: in process, instruments (the machine's nameplate,
    the simulated operator) that said they were rtcal's simulators, a rehearsal; None: none of these."""
    from drivers.interfaces import SIMULATED_MARK

    simulators = _simulators(meta.get(SIMULATORS_KEY, "{}"))
    if meta.get("operator_address"):  # only `rtcal sim serve` serves an operator that carries out the steps
        simulators["operator"] = f"rtcal's simulated operator at {redact_tokens(meta['operator_address'])}"
    if IDENTITY_KEY in meta:
        try:
            plate = {k: v for k, v in json.loads(meta[IDENTITY_KEY]).items() if isinstance(v, (str, int))}
        except (ValueError, AttributeError):
            plate = {}
        if any(SIMULATED_MARK in str(v) for v in plate.values()):
            simulators["machine"] = ", ".join(f"{k} {v}" for k, v in sorted(plate.items()))[:1000]
    rehearsed = meta.get(REHEARSED_KEY) == "1"
    if not (in_process or simulators or rehearsed):
        return None
    return Simulation(in_process=in_process, simulators=simulators, rehearsed=rehearsed,
                      statement=simulation_statement(in_process, sorted(simulators), rehearsed))


def simulation_statement(in_process: bool, simulators: list[str], rehearsed: bool) -> str:
    """The marking every page of the certificate and the console carry, in one line."""
    what = "SIMULATED" if in_process or simulators else ""
    what = " AND ".join(x for x in (what, "REHEARSED" if rehearsed else "") if x)
    why = []
    if in_process:
        why.append("every instrument and the table were simulated in process on a model bench")
    if simulators:
        why.append(f"{', '.join(simulators)} answered from rtcal's simulators (rtcal sim serve)")
    if rehearsed:
        why.append("a rehearsal (--rehearse): the simulated operator carried out the operator's steps")
    return f"{what} — NOT A CALIBRATION: {'; '.join(why)}"


def _record_interruption(store: RunStore, t_s: float, exc: KeyboardInterrupt, status: str, when: str) -> None:
    """Ctrl-C, a signal, outside the engine (which records its own): an ``abort`` event saying
    ``when``, and ``status``; the store closed."""
    try:
        store.add_event(t_s, "abort", f"{exc or 'interrupted by SIGINT (Ctrl-C)'} {when}")
    except Exception:  # noqa: BLE001 — the disk refused it (or the store was closed): the status still tries
        pass
    try:
        _stop(store, status, exc)
    except sqlite3.ProgrammingError:  # closed: the results were written whole just before
        pass


def with_deliverable_digests(results: RunResults, digests: dict[str, str]) -> RunResults:
    """``results`` whose ``digests`` also record the deliverables' (validated as the file will be read)."""
    assert results.digests is not None  # a run's results always carry its store's digests
    block = results.digests.model_copy(update={"deliverables_sha256": digests})
    return type(results).model_validate({**dict(results), "digests": type(block).model_validate(block.model_dump())})


def _stop(store: RunStore, status: str, exc: BaseException) -> None:
    """Record why the run stopped and close the store. On a full disk the status goes into the
    space the store reserved; if even that is refused the stored status stays as it was (a
    resume treats every run that is not solved alike) and the error says so."""
    if not store.set_final_meta({"status": status, "error": repr(exc)}):
        note = f"(the status `{status}` could not be recorded in {store.path}: the disk refused it)"
        exc.__notes__ = [*getattr(exc, "__notes__", []), note]  # BaseException.add_note is Python 3.11's; pyproject says 3.10
    store.close()
