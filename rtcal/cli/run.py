"""``rtcal run``, ``resume``, ``check`` and ``probe``: measuring, and the instruments before it."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Callable

from drivers.addresses import redact_tokens
from drivers.errors import InstrumentError
from rtcal.cli.common import (EXIT_FAILED, EXIT_INTERRUPTED, EXIT_NOT_CONVERGED, EXIT_OK, UserError, disk_failure,
                              one_line, parse_instruments_option, seed)
from rtcal.outputs import OutputRefused, is_disk_failure


def _how_to_go_on(run_dir: str, instruments: str | None = None, instruments_failed: bool = False) -> str:
    """Where the readings are and the resume command for this run (rtcal/store/hint.py)."""
    from rtcal.store.hint import resume_hint

    if (Path(run_dir) / "run.sqlite").is_file():
        return (f"every reading taken so far is in {run_dir}/run.sqlite; "
                f"{resume_hint(run_dir, instruments, instruments_failed=instruments_failed)}")
    return "nothing was measured"


def _say_still_moving(exc: BaseException) -> None:
    """The machines the engine's safe stop did not see at rest (its WARNING notes), said on the console."""
    for note in getattr(exc, "__notes__", ()):
        if note.startswith("WARNING: "):
            print(f"rtcal: {note}", file=sys.stderr, flush=True)


def out_of_descriptors(exc: BaseException) -> bool:
    """The process (EMFILE) or the system (ENFILE) has no file descriptor left, anywhere in the chain of
    causes: the computer's fault during a run, not the user's input."""
    import errno

    seen: set[int] = set()
    found: BaseException | None = exc
    while found is not None and id(found) not in seen:
        seen.add(id(found))
        if isinstance(found, OSError) and found.errno in (errno.EMFILE, errno.ENFILE):
            return True
        found = found.__cause__ or found.__context__
    return False


def _execute(start: Callable[[], Any], run_dir: str, instruments: str | None = None) -> int:
    """Run or resume; print the outcome, or what went wrong and how to go on (``instruments``: the
    --instruments text given, for the resume command)."""
    from rtcal.methods.protocol import PreparationError
    from rtcal.results import ResultsError
    from rtcal.run.rundir import RunDirError
    from rtcal.engine.engine import PlanError
    from rtcal.engine.signals import routed
    from rtcal.run.runner import AnalysisFailed

    try:
        with routed():  # `kill`, SIGHUP (a closed SSH session), SIGQUIT …: each stops like Ctrl-C, status recorded
            outcome = start()
    except (FileExistsError, PreparationError, RunDirError, ResultsError, OutputRefused) as exc:
        raise UserError(str(exc)) from None
    except (AnalysisFailed, PlanError, InstrumentError, OSError, KeyboardInterrupt) as exc:
        code = _ended_without_results(exc, run_dir, instruments)
        if code is None:  # not one a run ends with: the traceback is the report
            raise
        return code
    _print_outcome(outcome, run_dir)
    return _exit_code(outcome.results)


def _ended_without_results(exc: BaseException, run_dir: str, instruments: str | None) -> int | None:
    """What a run that ended without results says, and its exit code (None: an error no run ends with)."""
    from rtcal.engine.engine import PlanError
    from rtcal.run.runner import AnalysisFailed

    if isinstance(exc, AnalysisFailed):
        print(f"rtcal: {redact_tokens(str(exc))}", file=sys.stderr)
        return EXIT_FAILED
    if isinstance(exc, PlanError):  # the method's mistake: the run stopped safely, `failed`, with an event saying it
        print(f"rtcal: the method's plan cannot be carried out: {redact_tokens(str(exc))}; every reading taken is in "
              f"{run_dir}; the run's method must be fixed before it can go on", file=sys.stderr)
        return EXIT_FAILED
    if isinstance(exc, InstrumentError):
        print(f"rtcal: instrument error: {redact_tokens(str(exc))}", file=sys.stderr)
        _say_still_moving(exc)
        print(f"rtcal: {_how_to_go_on(run_dir, instruments, instruments_failed=True)}", file=sys.stderr)
        return EXIT_FAILED
    if isinstance(exc, OSError):
        return _computer_failed(exc, run_dir, instruments)
    if isinstance(exc, KeyboardInterrupt):  # Ctrl-C, a signal, an abort from the page or `rtcal control`
        why = str(exc) if str(exc).startswith(("interrupted by", "aborted by")) else "interrupted"
        try:  # after SIGHUP the terminal may be gone: the status is recorded, the exit code still says it
            print(f"\nrtcal: {why}; {_how_to_go_on(run_dir, instruments)}",
                  file=sys.stderr, flush=True)
            _say_still_moving(exc)
        except OSError:
            pass
        return EXIT_INTERRUPTED
    return None


def _computer_failed(exc: OSError, run_dir: str, instruments: str | None) -> int | None:
    """Out of file descriptors or of disk space: the computer's fault, said with how to go on (None: another OSError)."""
    if out_of_descriptors(exc):
        print(f"rtcal: this process ran out of file descriptors ({exc.strerror or exc}): close what holds them "
              "(`ulimit -n` is the limit)", file=sys.stderr)
        print(f"rtcal: {_how_to_go_on(run_dir, instruments)}", file=sys.stderr)
        return EXIT_FAILED
    if not is_disk_failure(exc):
        return None
    print(disk_failure(exc, run_dir), file=sys.stderr)
    for note in getattr(exc, "__notes__", ()):
        print(f"rtcal: {note}", file=sys.stderr)
    print(f"rtcal: {_how_to_go_on(run_dir, instruments)} once there is space", file=sys.stderr)
    return EXIT_FAILED


def _print_outcome(outcome: Any, run_dir: str) -> None:
    """A finished run's console: what was taken, the summary, the files, and what it is (simulated, signed)."""
    from rtcal.methods import METHODS
    from rtcal.deliverables.certificate import marking, signature_line
    from rtcal.deliverables.report import console_lines
    from rtcal.run.runner import IDEAL_BENCH

    results = outcome.results
    if outcome.finished:
        print(f"run already finished: {run_dir} was measured and solved ({results.raw_readings} planned readings, "
              f"{outcome.instrument_readings} instrument readings stored); nothing was taken or written "
              f"(`rtcal verify {run_dir}` recomputes its results from its readings)")
    else:
        print(f"run complete: {results.raw_readings} planned readings taken, {outcome.instrument_readings} instrument "
              "readings stored")
    if results.bench == IDEAL_BENCH:
        print(f"note: {IDEAL_BENCH}")
    for line in METHODS[results.method].outputs(results).summary() + console_lines(results):
        print(line)
    files = ", ".join(sorted(p.name for p in outcome.run_dir.iterdir() if not p.name.startswith((".", "run.sqlite-"))))
    print(f"results in {outcome.run_dir}/ ({files})")
    if marking(results):  # a run that calibrated nothing says so last, where the eye lands
        print(marking(results))
    print(signature_line(results))
    for other in certificates_numbered_alike(outcome.run_dir):
        print(f"rtcal: warning: {other} carries the same certificate number: give each certificate its own "
              "(`rtcal run --certificate-number NUMBER`, or metadata.certificate_number)", file=sys.stderr)


def _exit_code(results: Any) -> int:
    """0, or EXIT_NOT_CONVERGED (said on stderr) when the recommended estimator did not converge."""
    rec = results.recommended
    status = results.solver_status.get(rec) if rec else None
    if rec and status is not None and status.status != "converged":
        print(f"rtcal: the recommended estimator {rec} did not converge ({status.message}); "
              "readings and results are kept", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return EXIT_OK


def certificate_number(text: str) -> str:
    """--certificate-number: what metadata.certificate_number accepts, or argparse's one-line error (exit 2)."""
    import unicodedata

    if not text.strip() or len(text) > 100:
        raise argparse.ArgumentTypeError("a certificate number is 1 to 100 characters")
    if any(unicodedata.category(c) in ("Cc", "Cf", "Cs", "Co") for c in text):
        raise argparse.ArgumentTypeError("no control or invisible formatting characters in a certificate number")
    return text


def certificates_numbered_alike(run_dir: Path, limit: int = 200) -> list[Path]:
    """Other runs beside ``run_dir`` (the same parent folder, at most ``limit`` looked at) whose
    certificate.json carries this run's certificate number: a certificate's number must be unique."""
    def number(path: Path) -> str:
        try:
            return str(json.loads(path.read_text(encoding="utf-8"))["header"]["certificate_number"] or "")
        except (OSError, ValueError, KeyError, TypeError):
            return ""

    own = number(run_dir / "certificate.json")
    if not own:
        return []
    others = sorted(p for p in run_dir.resolve().parent.iterdir() if p.is_dir() and p != run_dir.resolve())[:limit]
    return [p / "certificate.json" for p in others if number(p / "certificate.json") == own]


def _run_control(live: str | None) -> Any:
    """Every run's control socket and token, and with --live its web page (rtcal.live.attach)."""
    from rtcal.live.attach import RunControl
    from rtcal.live.server import LiveSpecError

    try:
        return RunControl(live)
    except LiveSpecError as exc:
        raise UserError(str(exc)) from None


def _real_controller_in_real_time(addresses: dict[str, str] | None, virtual_clock: bool) -> None:
    """A real controller (LinuxCNC) moves in real time: a virtual clock would read before it settles."""
    stage = str((addresses or {}).get("stage", ""))
    if virtual_clock and stage.startswith("linuxcncrsh://"):
        raise UserError("--virtual-clock: the stage is a real LinuxCNC (linuxcncrsh://), which moves in real time; "
                        "drop --virtual-clock (the procedure's settle_time_s may be short)")


def _unsigned_where_checked() -> None:
    """A warning before a run that will be written unsigned where the lab checks signatures."""
    import os

    from rtcal.run.signing import LAB_KEY_ENV, LAB_PUBLIC_KEYS_ENV

    if os.environ.get(LAB_PUBLIC_KEYS_ENV) and not os.environ.get(LAB_KEY_ENV):
        print(f"rtcal: warning: {LAB_PUBLIC_KEYS_ENV} is set but {LAB_KEY_ENV} is not: this run is written unsigned, and "
              "refused wherever the lab's keys are checked", file=sys.stderr)


def cmd_run(args: argparse.Namespace) -> int:
    from rtcal.run.runner import default_run_dir, run_procedure

    addresses = parse_instruments_option(args.instruments) if args.instruments else None
    _real_controller_in_real_time(addresses, args.virtual_clock)
    out = args.out or str(default_run_dir(Path(args.procedure).stem))
    if args.catalog is not None:
        from rtcal.cli.catalog import check_location

        check_location(args.catalog)
    _unsigned_where_checked()
    control = _run_control(args.live)
    code = _execute(lambda: run_procedure(args.procedure, args.scenario, args.seed, out, addresses=addresses,
                                          virtual_clock=args.virtual_clock, large=args.large, on_engine=control,
                                          certificate_number=args.certificate_number, rehearse=args.rehearse,
                                          item_state=args.item_state), out,
                    args.instruments)
    if args.catalog is not None and code == EXIT_OK:
        from rtcal.cli.catalog import file_finished_run

        return file_finished_run(Path(out), args.catalog, args.allow_simulated)
    return code


def cmd_resume(args: argparse.Namespace) -> int:
    from rtcal.run.runner import resume_run

    addresses = parse_instruments_option(args.instruments) if args.instruments else None
    _real_controller_in_real_time(addresses, bool(args.virtual_clock))  # None: the run's own clock, checked there
    _unsigned_where_checked()
    control = _run_control(args.live)
    return _execute(lambda: resume_run(args.run_dir, addresses=addresses, virtual_clock=args.virtual_clock,
                                       on_engine=control, rehearse=args.rehearse), args.run_dir, args.instruments)


def cmd_probe(args: argparse.Namespace) -> int:
    """Connect to one instrument, identify it, take one reading (rtcal/run/commission.py)."""
    from rtcal.run.commission import format_probe, probe

    if not 0.01 <= args.timeout_s <= 600:
        raise UserError("--timeout-s must lie in 0.01..600")
    if args.kind == "machine":
        return _probe_machine(args)
    try:
        result = probe(args.kind, args.address, args.timeout_s)
    except InstrumentError as exc:
        print(f"rtcal: {args.kind} at {args.address}: {one_line(exc)}", file=sys.stderr)
        return EXIT_FAILED
    print(format_probe(result, args.json))
    return EXIT_OK


def _probe_machine(args: argparse.Namespace) -> int:
    """`rtcal probe machine opc.tcp://HOST:PORT[?machine=NAME|serial=SN]` or `http://AGENT:PORT/DEVICE`: the
    machine's identification (OPC 40001-1, or an MTConnect agent's probe), each value printable and bounded
    (JSON escapes what is not ASCII)."""
    from drivers.machine_identity import read_machine_identity
    from drivers.opcua_identity import shown

    if not args.address.startswith(("opc.tcp://", "http://", "https://")):
        raise UserError(f"{args.address[:80]}: a machine's identification is read over OPC UA (opc.tcp://HOST:PORT) or "
                        "from an MTConnect agent (http://HOST:PORT/DEVICE)")
    try:
        ident = read_machine_identity(args.address, args.timeout_s)
    except InstrumentError as exc:
        print(f"rtcal: machine at {args.address}: {one_line(exc)}", file=sys.stderr)
        return EXIT_FAILED
    if args.json:
        print(json.dumps(ident))
    else:
        print("\n".join(f"{k}: {'' if v is None else shown(str(v), 200)}" for k, v in ident.items()))
    return EXIT_OK


def cmd_check(args: argparse.Namespace) -> int:
    """Probe every instrument a procedure needs and check the readings against its ranges."""
    from rtcal.methods import load_procedure
    from rtcal.run.commission import check, format_table
    from rtcal.run.runner import with_addresses

    proc = load_procedure(Path(args.procedure))
    addresses = parse_instruments_option(args.instruments) if args.instruments else {}
    if addresses:
        proc = with_addresses(proc, addresses)  # refuses a name that is no instrument, as `run` does
    rows = check(proc, addresses, addresses.get("operator", ""))
    print(format_table(rows))
    failed = [r for r in rows if r.status == "FAILED"]
    for r in failed:
        print(f"rtcal: {r.instrument}: {one_line(r.detail)}", file=sys.stderr)
    counted = [r for r in rows if r.status != "standard"]  # a reference standard in calibration is not probed
    print(f"{len(counted) - len(failed)} of {len(counted)} ready" + ("" if failed else ": the rig can run this procedure"))
    return EXIT_FAILED if failed else EXIT_OK


REHEARSE_HELP = ("rehearse the operator steps on simulators: each waits for a person (Enter, the page's Done, "
                 "`rtcal control RUN_DIR confirm`), then the simulated operator (`operator` in --instruments) does it")


def add_run(sub: Any) -> None:
    run = sub.add_parser("run", help="run a procedure and write a run directory")
    run.add_argument("procedure", help="procedure YAML file")
    run.add_argument("--scenario", help="bench scenario YAML (replaces the procedure's `bench`)")
    run.add_argument("--seed", type=seed, help="seed of the run's random generator (default: the scenario's)")
    run.add_argument("--out", help="run directory (default: runs/<time>-<procedure>)")
    run.add_argument("--instruments", help="JSON object (or file) of instrument addresses, e.g. what `rtcal sim serve` "
                                           "prints; replaces the procedure's instrument section")
    run.add_argument("--virtual-clock", action="store_true",
                     help="do not wait settle times in real time (for protocol simulators, never for hardware)")
    run.add_argument("--large", action="store_true",
                     help="accept a plan beyond 100 000 readings (up to 2 000 000; takes hours and GBs)")
    run.add_argument("--live", metavar="[HOST:]PORT", help="serve the run's live view from this process (PORT 0: any free "
                                                          "port; 127.0.0.1 unless HOST is given)")
    run.add_argument("--certificate-number", type=certificate_number, metavar="NUMBER",
                     help="this run's certificate number (replaces the procedure's metadata.certificate_number: a "
                          "procedure serves many runs, each certificate needs its own)")
    run.add_argument("--rehearse", action="store_true", help=REHEARSE_HELP)
    state = run.add_mutually_exclusive_group()
    state.add_argument("--as-found", dest="item_state", action="store_const", const="as_found",
                       help="the item as received, before any adjustment (sets metadata.item_state; the certificate says so)")
    state.add_argument("--as-left", dest="item_state", action="store_const", const="as_left",
                       help="the item after adjustment or compensation (metadata.item_state)")
    run.add_argument("--catalog", metavar="URL", help="when the run is finished, add it to this catalogue (a SQLite file "
                                                     "or postgresql://…) and send what waits in the rig's outbox")
    run.add_argument("--allow-simulated", action="store_true", help="with --catalog: file the run even though it "
                                                                     "calibrated nothing (every listing marks it SIMULATED)")
    run.set_defaults(func=cmd_run)


def add_resume(sub: Any) -> None:
    resume = sub.add_parser("resume", help="continue an interrupted run: every planned reading not yet stored, once")
    resume.add_argument("run_dir", help="the directory of an interrupted run (what `run --out` wrote)")
    resume.add_argument("--instruments", help="new instrument addresses (JSON object or file), e.g. of a restarted simulator")
    clock = resume.add_mutually_exclusive_group()
    clock.add_argument("--virtual-clock", action="store_true", default=None,
                       help="as for `run` (default: the clock the run was started on)")
    clock.add_argument("--real-clock", dest="virtual_clock", action="store_false",
                       help="go on in real time although the run was started with --virtual-clock")
    resume.add_argument("--live", metavar="[HOST:]PORT", help="as for `run`")
    resume.add_argument("--rehearse", action="store_true", help=REHEARSE_HELP)
    resume.set_defaults(func=cmd_resume)


def add_probe(sub: Any) -> None:
    from drivers.kinds import KINDS

    pr = sub.add_parser("probe", help="connect to one instrument, identify it where its protocol allows, take one "
                                      "reading and print it; exit 1 if it does not answer or answers wrongly")
    pr.add_argument("kind", choices=(*KINDS.names(), "machine"), help="the kind of instrument (machine: the machine's OPC "
                                                               "40001-1 identification at opc.tcp://HOST:PORT, one of "
                                                               "several chosen by ?machine=NAME or ?serial=SN; or its "
                                                               "MTConnect agent's probe at http://HOST:PORT/DEVICE)")
    pr.add_argument("address", help="its address, e.g. socket://10.0.0.5:4001?model=sylvac or ipp://cmm:1294 "
                                    "(model= picks the product; docs/protocols/)")
    pr.add_argument("--json", action="store_true",
                    help='print one JSON object {"kind", "address", "model", "identity", "reading"}')
    pr.add_argument("--timeout-s", type=float, default=2.0, help="deadline of each request, s (default 2)")
    pr.set_defaults(func=cmd_probe)


def add_check(sub: Any) -> None:
    ck = sub.add_parser("check", help="probe every instrument a procedure needs and check the readings against its "
                                      "ranges (stage limits, CMM volume): one table of what is ready")
    ck.add_argument("procedure", help="procedure YAML file")
    ck.add_argument("--instruments", help="instrument addresses (JSON object or file, e.g. what `rtcal sim serve` "
                                          "printed); replaces the procedure's")
    ck.set_defaults(func=cmd_check)
