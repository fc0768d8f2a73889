"""The ``rtcal`` command line. User mistakes exit 2 with a located message, never a traceback."""

from __future__ import annotations

import argparse
import csv
import json
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.addresses import AddressError, redact_tokens
from drivers.errors import InstrumentError
from rtcal import __version__
from rtcal.outputs import OutputRefused, is_disk_failure, output_file, write_output
from rtcal.procedure.yamlfile import FileProblems, read_bytes

if TYPE_CHECKING:
    from rtcal.deliverables.deviations import PositioningDeviations
    from rtcal.results import RunResults

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_NOT_CONVERGED = 0, 1, 2, 3
EXIT_INTERRUPTED = 130
MAX_SEED = 2**63 - 1


class UserError(Exception):
    """A mistake the user can fix; printed as one line, exit code 2."""


def _interrupt(*_) -> None:
    raise KeyboardInterrupt


def _how_to_go_on(run_dir: str) -> str:
    if (Path(run_dir) / "run.sqlite").is_file():
        return f"every reading taken so far is in {run_dir}/run.sqlite; `rtcal resume {run_dir}` goes on"
    return "nothing was measured"


def _disk_failure(exc: OSError, folder: str | Path | None = None) -> str:
    """One line for a write the disk refused: what, where, and that it is the disk's doing."""
    where = f"{exc.filename}: " if exc.filename else (f"in {folder}: " if folder else "")
    return f"rtcal: the disk refused a write: {where}{exc.strerror or exc}"


def _execute(start, run_dir: str) -> int:
    """Run or resume; print the outcome, or what went wrong and how to go on."""
    import signal

    from rtcal.deliverables.method_outputs import outputs_for
    from rtcal.deliverables.report import console_lines
    from rtcal.methods.protocol import PreparationError
    from rtcal.results import ResultsError
    from rtcal.run.rundir import RunDirError
    from rtcal.run.runner import IDEAL_BENCH, AnalysisFailed

    signal.signal(signal.SIGTERM, _interrupt)  # `kill` stops like Ctrl-C: status recorded, run directory released
    try:
        outcome = start()
    except (FileExistsError, PreparationError, RunDirError, ResultsError, OutputRefused) as exc:
        raise UserError(str(exc)) from None
    except AnalysisFailed as exc:
        print(f"rtcal: {redact_tokens(str(exc))}", file=sys.stderr)
        return EXIT_FAILED
    except InstrumentError as exc:
        print(f"rtcal: instrument error: {redact_tokens(str(exc))}", file=sys.stderr)
        print(f"rtcal: {_how_to_go_on(run_dir)}", file=sys.stderr)
        return EXIT_FAILED
    except OSError as exc:
        if not is_disk_failure(exc):
            raise
        print(_disk_failure(exc, run_dir), file=sys.stderr)
        for note in getattr(exc, "__notes__", ()):
            print(f"rtcal: {note}", file=sys.stderr)
        print(f"rtcal: {_how_to_go_on(run_dir)} once there is space", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        print(f"\nrtcal: interrupted; {_how_to_go_on(run_dir)}", file=sys.stderr)
        return EXIT_INTERRUPTED
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
    for line in outputs_for(results).summary() + console_lines(results):
        print(line)
    files = ", ".join(sorted(p.name for p in outcome.run_dir.iterdir() if not p.name.startswith((".", "run.sqlite-"))))
    print(f"results in {outcome.run_dir}/ ({files})")
    rec = results.recommended
    status = results.solver_status.get(rec) if rec else None
    if rec and status is not None and status.status != "converged":
        print(f"rtcal: the recommended estimator {rec} did not converge ({status.message}); "
              "readings and results are kept", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return EXIT_OK


def _run_control(live: str | None):
    """Every run's control socket and token, and with --live its web page (rtcal.live.attach)."""
    from rtcal.live.attach import RunControl
    from rtcal.live.server import LiveSpecError

    try:
        return RunControl(live)
    except LiveSpecError as exc:
        raise UserError(str(exc)) from None


def _real_controller_in_real_time(addresses: dict | None, virtual_clock: bool) -> None:
    """A real controller (LinuxCNC) moves in real time: a virtual clock would read before it settles."""
    stage = str((addresses or {}).get("stage", ""))
    if virtual_clock and stage.startswith("linuxcncrsh://"):
        raise UserError("--virtual-clock: the stage is a real LinuxCNC (linuxcncrsh://), which moves in real time; "
                        "drop --virtual-clock (the procedure's settle_time_s may be short)")


def _cmd_run(args: argparse.Namespace) -> int:
    from rtcal.run.runner import default_run_dir, run_procedure

    addresses = parse_instruments_option(args.instruments) if args.instruments else None
    _real_controller_in_real_time(addresses, args.virtual_clock)
    out = args.out or str(default_run_dir(Path(args.procedure).stem))
    control = _run_control(args.live)
    return _execute(lambda: run_procedure(args.procedure, args.scenario, args.seed, out, addresses=addresses,
                                          virtual_clock=args.virtual_clock, large=args.large, on_engine=control), out)


def _cmd_resume(args: argparse.Namespace) -> int:
    from rtcal.run.runner import resume_run

    addresses = parse_instruments_option(args.instruments) if args.instruments else None
    _real_controller_in_real_time(addresses, args.virtual_clock)
    control = _run_control(args.live)
    return _execute(lambda: resume_run(args.run_dir, addresses=addresses, virtual_clock=args.virtual_clock,
                                       on_engine=control), args.run_dir)


def parse_instruments_option(text: str) -> dict[str, str]:
    """``--instruments``: a JSON object of name → address, inline or in a file."""
    from rtcal.procedure.yamlfile import read_text

    source = text
    if not text.lstrip().startswith("{"):
        try:
            source = read_text(text)
        except FileProblems as exc:
            raise UserError(f"--instruments: {exc.problems[0].file}: {exc.problems[0].message}") from None
    try:
        data = json.loads(source.strip().splitlines()[0] if source.strip() else "")
    except (json.JSONDecodeError, IndexError) as exc:
        raise UserError(f"--instruments: not a JSON object of instrument addresses ({exc})") from None
    except RecursionError:
        raise UserError("--instruments: not a JSON object of instrument addresses (nested too deeply)") from None
    if not isinstance(data, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
        raise UserError("--instruments: expected a JSON object mapping instrument names to address strings")
    return data


def _cmd_uncertainty(args: argparse.Namespace) -> int:
    """Monte Carlo of the procedure on the simulated bench: reported 1σ against the errors made."""
    from tqdm import tqdm

    from rtcal.planning import montecarlo
    from rtcal.run.runner import check_plan_on_bench, default_run_dir, resolve_scenario
    from rtcal.procedure.loader import load_procedure

    if not 2 <= args.trials <= 100_000:
        raise UserError("--trials must lie in 2..100000")
    workers = _workers(args.workers, args.large)
    if args.scheduler:
        _check_scheduler(args.scheduler)
    path = Path(args.procedure)
    proc = load_procedure(path)
    if not proc.instruments.all_sim():
        raise UserError(f"{path}: the Monte Carlo runs on the simulated bench: every instrument must be `backend: sim`")
    scenario, _ = resolve_scenario(path, proc, Path(args.scenario) if args.scenario else None)
    check_plan_on_bench(path, proc, scenario)
    out = Path(args.out) if args.out else default_run_dir("uncertainty")
    seed = scenario.seed if args.seed is None else args.seed
    if args.balanced and args.fixed_systematics:
        raise UserError("--balanced and --fixed-systematics: choose one (--balanced is how the systematic errors are drawn)")
    try:
        specs = montecarlo.plan_trials(path, proc, scenario, args.trials, seed, out, not args.fixed_systematics,
                                       args.balanced)
    except ValueError as exc:
        raise UserError(f"--balanced: {exc}") from None
    _make_folder(out, "--out")
    trials = []
    bar = tqdm(total=len(specs), desc="trials", unit="trial", disable=not sys.stderr.isatty(), file=sys.stderr)
    try:
        for result in montecarlo.run_trials(specs, workers, args.scheduler):
            trials.append(result)
            bar.update()
    except OSError as exc:
        if not args.scheduler:
            raise
        raise UserError(f"--scheduler {args.scheduler}: cannot reach the Dask scheduler: {exc}") from None
    finally:
        bar.close()
    ok = [t for t in trials if "failed" not in t]
    if not ok:
        print(f"rtcal: every trial failed; the first: {trials[0]['failed']}", file=sys.stderr)
        return EXIT_FAILED
    summary = montecarlo.summarize(trials, ok[0]["labels"])
    summary.update(procedure=str(path), bench=args.scenario or (str(path.parent / proc.bench) if proc.bench else "ideal"),
                   seed=seed, systematics="fixed as in the scenario" if args.fixed_systematics else
                   "drawn from the stated uncertainties" + (" (balanced: moment-matched antithetic pairs)" if args.balanced
                                                            else ""))
    write_output(out / "uncertainty.json", json.dumps(summary, indent=2) + "\n")
    with output_file(out / "uncertainty.png") as png:
        montecarlo.plot_summary(summary, f"{proc.name or path.stem}: reported 1σ against the errors of {len(ok)} "
                                "simulated runs", png)
    print(f"{len(ok)} trials ({summary['failed_trials']} failed), systematics {summary['systematics']}")
    for name, e in summary["estimators"].items():
        rec = " (recommended)" if name == summary["recommended"] else ""
        o = e["overall"]
        print(f"{name}{rec}: RMS error {o['rms_error_arcsec']}″, RMS reported 1σ {o['rms_reported_sigma_arcsec']}″,\n"
              f"  ratio per target {o['ratio_min']}–{o['ratio_max']} (each ± about {1 / np.sqrt(2 * e['trials']):.0%} from "
              f"{e['trials']} trials)")
        for line in montecarlo.table_lines(summary["targets"], e):  # a row per target: any number of targets fits
            print(line)
    print(f"results in {out}/ (uncertainty.json, uncertainty.png)")
    return EXIT_OK


MAX_WORKERS = 256  # with --large: beyond the cores, e.g. when trials wait on I/O


def _workers(requested: int | None, large: bool) -> int:
    """``--workers``: 1 … the machine's cores (more only with --large, up to MAX_WORKERS); default the cores.
    A process per trial beyond the cores only makes each trial slower and takes memory."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    if requested is None:
        return cores
    limit = MAX_WORKERS if large else cores
    if not 1 <= requested <= limit:
        beyond = "" if large else f" (this machine has {cores} cores; --large allows up to {MAX_WORKERS})"
        raise UserError(f"--workers {requested}: must lie in 1 … {limit}{beyond}")
    return requested


SCHEDULER_SCHEMES = ("tcp",)  # tls would need certificates rtcal has no option for


def _check_scheduler(address: str) -> None:
    """``--scheduler``: a Dask scheduler's ``tcp://host:port``, checked before any trial."""
    from urllib.parse import urlsplit

    try:
        parts = urlsplit(address)
        port = parts.port
    except ValueError as exc:
        raise UserError(f"--scheduler {address!r}: not an address ({exc})") from None
    if parts.scheme not in SCHEDULER_SCHEMES or not parts.hostname or port is None or parts.path not in ("", "/"):
        raise UserError(f"--scheduler {address!r}: expected a Dask scheduler's address, "
                        f"{' or '.join(s + '://HOST:PORT' for s in SCHEDULER_SCHEMES)} (e.g. tcp://127.0.0.1:8786)")


def _cmd_plan(args: argparse.Namespace) -> int:
    """Predicted 1σ per target and the duration of a procedure, before anything moves; what its
    uncertainty is made of and what each lever would do; the shortest plan for a target U."""
    from rtcal.planning import levers as lv
    from rtcal.planning.predict import predict
    from rtcal.procedure.loader import load_procedure
    from rtcal.run.runner import check_plan_on_bench, resolve_scenario

    from rtcal.procedure.models import LaserTracerMultistation

    path = Path(args.procedure)
    if args.json and args.optimize:
        raise UserError("--json and --optimize: choose one (--json prints the prediction alone)")
    if args.target_u is not None:
        if args.optimize:
            raise UserError("--optimize and --target-u: choose one")
        if not (0.0 < args.target_u <= 1e6):
            raise UserError(f"--target-u {args.target_u:g}: must be an expanded uncertainty in arcsec, above 0")
        if not args.out:
            raise UserError("--target-u: give --out FILE.yaml for the proposed procedure")
        if not Path(args.out).resolve().parent.is_dir():
            raise UserError(f"--out {args.out}: its folder {Path(args.out).parent} does not exist")
        if not (0.0 <= args.margin < 1.0):
            raise UserError(f"--margin {args.margin:g}: must lie in 0 … 1 (a fraction of the target)")
    elif args.out:
        raise UserError("--out: goes with --target-u (the proposed procedure); --optimize names its own file")
    if args.max_radius_mm is not None and not (0.0 < args.max_radius_mm <= 1e5):
        raise UserError(f"--max-radius-mm {args.max_radius_mm:g}: must lie in 0 … 100000 mm")
    proc = load_procedure(path)
    for option, target in (("--optimize", args.optimize), ("--out", args.out)):
        if target and Path(target).exists() and os.path.samefile(target, path):
            raise UserError(f"{option} {target}: that is the procedure itself; write the new plan to a new file")
    if args.optimize and not isinstance(proc, LaserTracerMultistation):
        raise UserError(f"--optimize: {path} is a procedure of {proc.method}; choosing CMM points is for "
                        "laser_tracer_multistation procedures")
    scenario, _ = resolve_scenario(path, proc, Path(args.scenario) if args.scenario else None)
    check_plan_on_bench(path, proc, scenario)
    plan = predict(path, proc, scenario)
    rec = plan["recommended"]
    predicted = plan["estimators"].get(rec) if rec else None
    expanded = [v for v in (predicted["predicted_expanded_arcsec"][1:] if predicted else []) if v is not None]
    plan["expanded_uncertainty_max_arcsec"] = max(expanded) if expanded else None
    plan["duration_s"] = plan["measurement_duration_s"]
    shares = lv.shares_of(predicted["budget"], predicted["predicted_sigma_arcsec"]) if predicted else {}
    plan["dominant_sources"] = [{"source": k, "share": round(v, 4)} for k, v in sorted(shares.items(), key=lambda kv: -kv[1])]
    base = lv.base_plan(path, scenario)
    lever_outcomes = [] if args.no_levers else [lv.evaluate(p) for p in lv.levers(base, proc, args.max_radius_mm)]
    plan["levers"] = [{"lever": "; ".join(o.plan.changes), **o.summary()} for o in lever_outcomes]
    plan["lever_notes"] = lv.lever_notes(proc)
    proposal = written = None
    if args.target_u is not None:
        proposal = lv.propose(base, proc, args.target_u, args.max_radius_mm, args.margin)
        if proposal.best is not None:
            written = lv.write_proposal(path, base, proposal.best, Path(args.out), args.target_u, bool(args.scenario))
        plan["proposal"] = {
            "target_u_arcsec": args.target_u, "margin": args.margin,
            "reached": proposal.best is not None,
            **({"plan": proposal.best.summary(), "written": [str(w) for w in written or []]} if proposal.best else {}),
            "smallest": proposal.smallest.summary() if proposal.smallest else None,
            "plans_predicted": len(proposal.tried), "plans_skipped": proposal.skipped}
    if args.json:
        print(json.dumps(plan, indent=2))
    else:
        _print_plan(path, plan, lever_outcomes)
        if proposal is not None:
            _print_proposal(args, proposal, written)
    if args.optimize:
        from rtcal.planning.design import optimize_points

        try:
            print(optimize_points(path, proc, scenario, Path(args.optimize)))
        except ValueError as exc:
            raise UserError(f"--optimize: {exc}") from None
    return EXIT_FAILED if proposal is not None and proposal.best is None else EXIT_OK


def _print_plan(path: Path, plan: dict[str, Any], lever_outcomes: list) -> None:
    from rtcal.planning import levers as lv

    hours = plan["measurement_duration_s"] / 3600
    print(f"{path}: {plan['raw_readings']} planned readings, about {plan['measurement_duration_s']:.0f} s ({hours:.1f} h) of "
          "motions, settling and readings; predicted 1σ from the stated noise:")
    for name, e in plan["estimators"].items():
        rec = " (recommended)" if name == plan["recommended"] else ""
        print(f"{name}{rec}: RMS {e['rms_predicted_sigma_arcsec']}″")
        print("  target    " + " ".join(f"{t:>8}" for t in plan["targets"][1:]))
        print("  1σ / ″    " + " ".join(f"{v:8.3f}" for v in e["predicted_sigma_arcsec"][1:]))
    if plan["expanded_uncertainty_max_arcsec"] is None:
        return
    top = ", ".join(f"{d['source']} {100 * d['share']:.0f} %" for d in plan["dominant_sources"][:4])
    print(f"U (k = 2) of {plan['recommended']}: at most {plan['expanded_uncertainty_max_arcsec']:.2f}″; its variance: {top}")
    if lever_outcomes:
        print("levers, each alone (predicted the same way):")
        as_written = lv.Outcome(lv.Plan({}, {}), plan["recommended"], plan["expanded_uncertainty_max_arcsec"],
                                plan["measurement_duration_s"], plan["raw_readings"])
        for line in lv.table_lines([("as written", as_written)] + [("; ".join(o.plan.changes), o) for o in lever_outcomes]):
            print(line)
    for note in plan["lever_notes"]:
        print(f"  ({note})")


def _print_proposal(args: argparse.Namespace, proposal, written: list[Path] | None) -> None:
    from rtcal.planning.levers import format_hours

    goal = args.target_u * (1 - args.margin)
    searched = f"{len(proposal.tried)} plans predicted" + (
        f", {len(proposal.skipped)} with one mount skipped (its error motions alone exceed the target)" if proposal.skipped else "")
    best = proposal.best
    if best is None:
        s = proposal.smallest
        found = (f"the smallest U found is {s.expanded_max_arcsec:.2f}″ ({'; '.join(s.plan.changes) or 'as written'}, "
                 f"{format_hours(s.duration_s)})") if s else "no plan could be predicted"
        print(f"no plan reaches U ≤ {args.target_u:g}″ (k = 2, planned for {goal:.3g}″ with --margin {args.margin:g}): {found}; "
              f"{searched}")
        return
    print(f"proposed for U ≤ {args.target_u:g}″ (k = 2, planned for {goal:.3g}″ with --margin {args.margin:g}): "
          f"{'; '.join(best.plan.changes) or 'the procedure as written'} → U {best.expanded_max_arcsec:.2f}″ "
          f"({best.recommended}), {format_hours(best.duration_s)} of machine time ({best.duration_s:.0f} s, "
          f"{best.raw_readings} planned readings); {searched}")
    print("written: " + ", ".join(str(w) for w in written or []))


def read_deviation_table(path_text: str) -> tuple[PositioningDeviations, RunResults | None]:
    """A run directory's positioning deviations (its results.json, validated) or a deviation CSV;
    mistakes are UserErrors naming the file and, in results.json, the field."""
    from rtcal.deliverables.deviations import DeviationTableError, PositioningDeviations
    from rtcal.results import ResultsError, read_results

    path = Path(path_text)
    try:
        if path.is_dir():
            if not (path / "results.json").exists():
                raise UserError(f"{path}: not a run directory with a readable results.json (a run that was not solved?)")
            from rtcal.run.integrity import check_run

            try:
                results = read_results(path)
                for warning in check_run(path, results):  # refused if it does not match its store
                    print(f"rtcal: warning: {warning}", file=sys.stderr)
            except ResultsError as exc:
                raise UserError(str(exc)) from None
            if results.positioning_deviations is None:
                raise UserError(f"{path / 'results.json'}: no positioning_deviations (the run has no recommended estimate)")
            table = PositioningDeviations.from_model(results.positioning_deviations, str(path / "results.json"))
            table.check_plausible(str(path / "results.json"))
            return table, results
        table = PositioningDeviations.read_csv(path)
        table.check_plausible(str(path))
        return table, None
    except DeviationTableError as exc:
        raise UserError(str(exc)) from None


def json_text(data: Any, indent: str = "") -> str:
    """JSON with a line per key and per row of a table (a list of objects), each line written by
    json's C encoder — ``indent=`` would send the whole document through its pure-Python one,
    which takes seconds for a table of 100 000 rows."""
    inner = indent + "  "
    if isinstance(data, dict) and data:
        items = ",\n".join(f"{inner}{json.dumps(str(k))}: {json_text(v, inner)}" for k, v in data.items())
        return "{\n" + items + "\n" + indent + "}"
    if isinstance(data, list) and data and all(isinstance(v, dict) for v in data):
        return "[\n" + ",\n".join(inner + json.dumps(v) for v in data) + "\n" + indent + "]"
    return json.dumps(data)


def _cmd_evaluate(args: argparse.Namespace) -> int:
    """ISO 230-2 or VDI 3441 parameters of a positioning test, as JSON."""
    from rtcal.deliverables.evaluation import evaluate

    table, _ = read_deviation_table(args.source)
    try:
        result = evaluate(table, args.standard)
    except ValueError as exc:
        raise UserError(f"{args.source}: {exc}") from None
    print(json_text(result))
    return EXIT_OK


def _cmd_compensate(args: argparse.Namespace) -> int:
    """A controller's compensation table from a run's (or a CSV's) positioning deviations: at the
    measured targets unless a grid is asked for (--step-deg); a one-direction run only with
    --allow-one-direction; warnings on stderr (and in the file where the format takes comments)."""
    from rtcal.deliverables.compensation import COMMENT, CompensationError, table_from_deviations, write_table

    table, _ = read_deviation_table(args.source)
    given = {"range_deg": args.range_deg and tuple(args.range_deg), "axis": args.axis, "unit_deg": args.detection_unit_deg,
             "first_point": args.first_point}
    try:
        comp = table_from_deviations(table, args.step_deg, args.max_gap_deg, args.allow_one_direction, args.format)
        text = write_table(args.format, comp, **{k: v for k, v in given.items() if v is not None})
    except CompensationError as exc:
        raise UserError(f"{args.source}: {exc}") from None
    out = write_output(Path(args.out), text)
    worst = max(float(abs(comp.trim_up_deg).max()), float(abs(comp.trim_down_deg).max())) * 3600
    print(f"{args.format} table written to {out} ({len(text.splitlines())} lines): {comp.summary()}, trims up to {worst:.2f}″ "
          "(docs/compensation.md: the format's rules and sign)")
    for warning in comp.warnings:
        where = "" if args.format in COMMENT else f" (not in {out}: a {args.format} file takes no comment)"
        print(f"rtcal: warning: {warning}{where}", file=sys.stderr)
    return EXIT_OK


def run_label(path_text: str) -> str:
    """A run as a reader tells it apart: its last two path components (runs/iso, runs/iso-after)."""
    parts = Path(path_text).resolve().parts
    return "/".join(parts[-2:]) if len(parts) > 1 else path_text


def _cmd_compare(args: argparse.Namespace) -> int:
    """Two runs side by side: the change per target against the combined uncertainty, and a plot."""
    from rtcal.deliverables.comparison import compare, comparison_lines, plot_comparison

    a, b = read_deviation_table(args.run_a), read_deviation_table(args.run_b)
    methods = [r.method if r else None for _, r in (a, b)]
    if None not in methods and methods[0] != methods[1]:
        raise UserError(f"{args.run_a} is a run of {methods[0]}, {args.run_b} of {methods[1]}: compare sets two "
                        "measurements of one kind side by side (give their positioning_deviations.csv to compare "
                        "the tables anyway)")
    result = compare(a, b, (run_label(args.run_a), run_label(args.run_b)))
    if result["targets_compared"] == 0:
        raise UserError(f"{args.run_a} and {args.run_b} share no target and direction: nothing to compare")
    out = Path(args.out) if args.out else Path(".")  # the current directory: never inside either run
    _make_folder(out, "--out")
    with output_file(out / "compare.png") as png:
        plot_comparison(result, a, b, png)
    result["plot"] = str(out / "compare.png")
    if args.certificate:
        result["certificate"] = _as_found_certificate(args, a[1], b[1], result, out)
    written = [result["plot"]] + ([f"{result['certificate']}.pdf", f"{result['certificate']}.html"] if args.certificate else [])
    print(json_text(result) if args.json else "\n".join(comparison_lines(result) + ["written: " + ", ".join(written)]))
    return EXIT_OK


def _cmd_verify(args: argparse.Namespace) -> int:
    """Recompute a run's results from its store and say whether results.json agrees (exit 0 / 1)."""
    from rtcal.results import ResultsError
    from rtcal.run.rundir import RunDirError
    from rtcal.run.verify import verify

    run = Path(args.run_dir)
    if not run.is_dir():
        raise UserError(f"{run}: not a run directory")
    import sqlite3

    try:
        found = verify(run)
    except (ResultsError, RunDirError) as exc:
        raise UserError(str(exc)) from None
    except sqlite3.DatabaseError as exc:
        raise UserError(f"{run / 'run.sqlite'}: cannot be read whole ({exc}); `rtcal export {run}` salvages its readings") from None
    except (ValueError, np.linalg.LinAlgError) as exc:
        print(f"rtcal: {run}: the solvers could not recompute the results from the readings: {_one_line(exc)[:300]}",
              file=sys.stderr)
        return EXIT_FAILED
    for warning in found.warnings:
        print(f"rtcal: warning: {warning}", file=sys.stderr)
    for problem in found.integrity:
        print(f"rtcal: {problem}", file=sys.stderr)
    for where, stored, recomputed in found.differences[:10]:
        print(f"rtcal: {run / 'results.json'}: {where}: stored {str(stored)[:60]}, recomputed from the readings "
              f"{str(recomputed)[:60]}", file=sys.stderr)
    if len(found.differences) > 10:
        print(f"rtcal: … and {len(found.differences) - 10} more differences", file=sys.stderr)
    verdict = "agrees" if found.agrees else "does NOT agree"
    print(f"{run / 'results.json'} {verdict} with the results recomputed from {found.readings} readings in "
          f"{run / 'run.sqlite'} ({found.compared} values compared to the digits stored, "
          f"{len(found.differences)} differ; digests {'match' if not found.integrity else 'do not match'})")
    return EXIT_OK if found.agrees else EXIT_FAILED


def _as_found_certificate(args: argparse.Namespace, found: RunResults | None, left: RunResults | None,
                          result: dict[str, Any], out: Path) -> str:
    """``compare --certificate``: the as-found / as-left certificate of two run directories."""
    from rtcal.deliverables.as_found import as_found_as_left_model
    from rtcal.deliverables.report import write_html, write_pdf

    if found is None or left is None:
        raise UserError("--certificate: give two run directories (a certificate needs their results.json, not a CSV)")
    model = as_found_as_left_model(found, left, result, out, "compare.png", (result["a"], result["b"]))
    with output_file(out / "as_found_as_left.pdf") as pdf:
        write_pdf(model, pdf)
    with output_file(out / "as_found_as_left.html") as html:
        write_html(model, html)
    return str(out / "as_found_as_left")


def _cmd_export(args: argparse.Namespace) -> int:
    """Every raw reading and event of a run as CSV, for spreadsheets; from a damaged store, every
    one that can still be read (exit 1: the store is damaged, and the count of what is lost)."""
    from rtcal.run.salvage import salvage_store
    from rtcal.run.store import EVENT_COLUMNS, READING_COLUMNS, RunStore, check_store, write_csv

    run = Path(args.run_dir)
    path = run / RunStore.FILENAME
    if not run.is_dir():
        raise UserError(f"{run}: not a run directory ({'no such directory' if not os.path.lexists(run) else 'not a directory'})")
    if not os.path.lexists(path):
        raise UserError(f"{run}: not a run directory (no {RunStore.FILENAME})")
    found = check_store(path)
    if found.kind in ("foreign", "empty"):
        raise UserError(f"{path} {found.detail}: nothing to export")
    out = Path(args.out) if args.out else run
    _make_folder(out, "--out")
    readings_csv, events_csv = out / "readings.csv", out / "events.csv"
    if found.kind == "run":
        store = RunStore.open(run)
        try:
            planned, instrument = len(store.done_plan_indices()), store.instrument_readings()
            rows, events = store.export_csv(out)
        finally:
            store.close()
        from rtcal.deliverables.report import plural

        markers = f" and {plural(rows - instrument, 'skip marker')}" if rows > instrument else ""
        print(f"{plural(instrument, 'instrument reading')}{markers} ({plural(planned, 'planned reading')} taken) → "
              f"{readings_csv}, {plural(events, 'event')} → {events_csv}")
        return EXIT_OK
    saved = salvage_store(path)  # damaged, or readings without a procedure: read page by page
    write_csv(readings_csv, ("id",) + READING_COLUMNS, ((i, *saved.readings[i]) for i in sorted(saved.readings)))
    write_csv(events_csv, ("id",) + EVENT_COLUMNS, ((i, *saved.events[i]) for i in sorted(saved.events)))
    from rtcal.deliverables.report import plural

    print(f"{plural(len(saved.readings), 'salvaged reading')} → {readings_csv}, {plural(len(saved.events), 'salvaged event')} "
          f"→ {events_csv}")
    print(f"rtcal: {path} {found.detail}; salvaged page by page: {saved.summary()}", file=sys.stderr)
    return EXIT_FAILED if found.kind == "damaged" or saved.unreadable_readings else EXIT_OK


def _make_folder(folder: Path, option: str) -> None:
    """Create an output folder (and its parents); a path that cannot be one is the user's to change."""
    if os.path.lexists(folder) and not folder.is_dir():
        raise UserError(f"{option} {folder}: exists and is not a directory")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        if is_disk_failure(exc):
            raise
        raise UserError(f"{option} {folder}: cannot create: {exc.strerror or exc}") from None


def _cmd_sim_serve(args: argparse.Namespace) -> int:
    import signal
    import threading

    from rtcal.procedure.loader import load_scenario
    from simulators.scenario import Scenario
    from simulators.servers.hub import SimulatorHub

    scenario = load_scenario(args.scenario) if args.scenario else Scenario()
    if args.host not in ("127.0.0.1", "localhost", "::1"):
        print(f"rtcal: warning: serving on {args.host}, not only on this machine", file=sys.stderr)
    if not 0.1 <= args.ipp_idle_timeout_s <= 86400:
        raise UserError(f"--ipp-idle-timeout-s {args.ipp_idle_timeout_s:g}: must lie in 0.1 … 86400 s")
    if args.stage == "linuxcnc":
        _check_linuxcnc_serve(args, scenario)
        if args.stage_model != "oriental-az":
            raise UserError("--stage-model: the stage is LinuxCNC (--stage linuxcnc); give one or the other")
    elif args.comp:
        raise UserError("--comp: a table for LinuxCNC; give --stage linuxcnc (the simulated controller takes its table "
                        "in the scenario's stage.compensation)")
    hub = SimulatorHub(scenario, seed=args.seed, host=args.host, serial=args.serial, modbus=args.modbus,
                       environment=args.environment, ipp_idle_timeout_s=args.ipp_idle_timeout_s,
                       stage_model=args.stage_model, pace_serial=not args.no_pacing, stage=args.stage, comp=args.comp)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):  # before LinuxCNC starts: a signal then still shuts it down
        signal.signal(sig, lambda *_: stop.set())
    try:
        addresses = hub.start()
    except (RuntimeError, OSError) as exc:
        if args.stage == "linuxcnc":  # the controller failed, not the user's input
            print(f"rtcal: LinuxCNC could not start: {_one_line(exc)}", file=sys.stderr)
            return EXIT_FAILED
        raise UserError(f"simulators could not start: {exc}") from None
    if not stop.is_set():
        print(json.dumps(addresses), flush=True)
    stop.wait()
    hub.stop()
    return EXIT_OK


def _check_linuxcnc_serve(args: argparse.Namespace, scenario) -> None:
    """`sim serve --stage linuxcnc`: LinuxCNC installed, a table it would read whole, no second table."""
    from rtcal.deliverables.compensation import CompensationError, parse_linuxcnc
    from simulators.servers.linuxcnc import available

    why = available()
    if why:
        raise UserError(f"--stage linuxcnc: {why}")
    if scenario.stage.compensation is not None:
        raise UserError("--stage linuxcnc: the scenario loads a table into the simulated controller (stage.compensation); "
                        "LinuxCNC applies the table: give it with --comp and remove it from the scenario")
    if args.comp:
        try:
            parse_linuxcnc(Path(args.comp).read_text(), args.comp)
        except OSError as exc:
            raise UserError(f"--comp {args.comp}: cannot read: {exc.strerror or exc}") from None
        except (CompensationError, UnicodeDecodeError) as exc:
            raise UserError(f"--comp {args.comp}: not a LinuxCNC table (COMP_FILE_TYPE 0): {_one_line(exc)}") from None


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _cmd_probe(args: argparse.Namespace) -> int:
    """Connect to one instrument, identify it, take one reading (rtcal/run/commission.py)."""
    from rtcal.run.commission import format_probe, probe

    if not 0.01 <= args.timeout_s <= 600:
        raise UserError("--timeout-s must lie in 0.01..600")
    try:
        result = probe(args.kind, args.address, args.timeout_s)
    except InstrumentError as exc:
        print(f"rtcal: {args.kind} at {args.address}: {_one_line(exc)}", file=sys.stderr)
        return EXIT_FAILED
    print(format_probe(result, args.json))
    return EXIT_OK


def _cmd_check(args: argparse.Namespace) -> int:
    """Probe every instrument a procedure needs and check the readings against its ranges."""
    from rtcal.run.commission import check, format_table
    from rtcal.procedure.loader import load_procedure
    from rtcal.run.runner import with_addresses

    proc = load_procedure(Path(args.procedure))
    addresses = parse_instruments_option(args.instruments) if args.instruments else {}
    from drivers.factory import KIND_OF

    unknown = sorted(set(addresses) - set(KIND_OF) - {"operator"})
    if unknown:
        raise UserError(f"--instruments: {', '.join(unknown)}: no such instrument (known: {', '.join(KIND_OF)}, operator)")
    if addresses:
        proc = with_addresses(proc, addresses)
    rows = check(proc, addresses, addresses.get("operator", ""))
    print(format_table(rows))
    failed = [r for r in rows if r.status == "FAILED"]
    for r in failed:
        print(f"rtcal: {r.instrument}: {_one_line(r.detail)}", file=sys.stderr)
    counted = [r for r in rows if r.status != "standard"]  # a reference standard in calibration is not probed
    print(f"{len(counted) - len(failed)} of {len(counted)} ready" + ("" if failed else ": the rig can run this procedure"))
    return EXIT_FAILED if failed else EXIT_OK


def _cmd_validate(args: argparse.Namespace) -> int:
    """Everything `run` checks before the first motion: the file, and the plan against the bench
    it would run on (the procedure's `bench`, or --scenario) — limits, CMM volume, polygon."""
    from rtcal.procedure.loader import bench_path, is_procedure_text, load_procedure, load_scenario
    from rtcal.run.runner import check_plan_on_bench, resolve_scenario
    from rtcal.procedure.yamlfile import read_text

    problems = []
    for name in args.files:
        path = Path(name)
        try:
            text = read_text(path)
            if is_procedure_text(text):
                proc = load_procedure(path, args.large, text)
                if proc.instruments.all_sim() or args.scenario:
                    scenario, _ = resolve_scenario(path, proc, Path(args.scenario) if args.scenario else None)
                    check_plan_on_bench(path, proc, scenario)
                elif proc.bench is not None:
                    load_scenario(bench_path(path, proc))
            else:
                load_scenario(path)
            print(f"{path}: ok")
        except FileProblems as exc:
            problems += [str(p) for p in exc.problems]
    for p in problems:
        print(p, file=sys.stderr)
    return EXIT_USAGE if problems else EXIT_OK


def _cmd_schema(args: argparse.Namespace) -> int:
    from rtcal.procedure.loader import procedure_schema, scenario_schema
    from rtcal.results import results_schema

    if args.scenario and args.results:
        raise UserError("schema: give --scenario or --results, not both")
    print(scenario_schema() if args.scenario else results_schema() if args.results else procedure_schema())
    return EXIT_OK


def read_stations_csv(path: Path) -> np.ndarray:
    """Station centres from a CSV with header X,Y,Z (mm), one station per row, in order."""
    import io

    try:
        data = read_bytes(path, 16 * 1024 * 1024)
    except FileProblems as exc:
        raise UserError(str(exc.problems[0])) from None
    try:
        with io.StringIO(data.decode("utf-8-sig"), newline="") as fh:  # -sig: a spreadsheet's byte-order mark
            reader = csv.DictReader(fh)
            fields = [f.strip() for f in (reader.fieldnames or [])]
            if not {"X", "Y", "Z"} <= set(fields):
                raise UserError(f"{path}:1: header must name X,Y,Z (found {','.join(fields) or 'nothing'})")
            rows = []
            for k, row in enumerate(reader, start=2):
                row = {key.strip(): v for key, v in row.items() if key}
                try:
                    xyz = [float(row["X"]), float(row["Y"]), float(row["Z"])]
                except (TypeError, ValueError):
                    raise UserError(f"{path}:{k}: X, Y and Z must be numbers (mm)") from None
                if not all(abs(v) <= 1e6 for v in xyz):  # also false for NaN
                    raise UserError(f"{path}:{k}: X, Y and Z must be finite and within ±1e6 mm")
                rows.append(xyz)
    except UnicodeDecodeError:
        raise UserError(f"{path}: not UTF-8 text") from None
    except csv.Error as exc:
        raise UserError(f"{path}:{reader.line_num}: not CSV: {exc}") from None
    if len(rows) < 4:
        raise UserError(f"{path}: {len(rows)} stations; at least 4 are needed (eq. 2)")
    return np.array(rows)


def _cmd_live(args: argparse.Namespace) -> int:
    """`rtcal view` and `rtcal control` (rtcal.live.commands)."""
    from rtcal.live import commands

    if args.command == "view":
        return commands.view(args.run_dir, args.live)
    return commands.control(args.run_dir, args.action, args.token)


def _cmd_solve_stations(args: argparse.Namespace) -> int:
    from rtcal.solvers.paper000 import PAPER_NOTES, chain_from_stations

    stations = read_stations_csv(Path(args.file))
    if not 0 < args.step_deg < 180:
        raise UserError("--step-deg must lie in (0, 180)")
    if not abs(args.first_deg) <= 36000:
        raise UserError("--first-deg must be finite and within ±36000")
    nominal = np.deg2rad(args.first_deg + args.step_deg * np.arange(len(stations)))
    try:
        chain = chain_from_stations(stations, nominal)
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise UserError(f"{args.file}: stations do not define a plane and a circle: {exc}") from None
    out = {
        "plane": {"a": chain.plane.a, "b": chain.plane.b, "c": chain.plane.c, "e": chain.plane.e},
        "projected_stations_mm": np.round(chain.projected_mm, 6).tolist(),
        "center_mm": np.round(chain.center_mm, 6).tolist(),
        "deviation_arcsec": np.round(chain.deviation_arcsec, 4).tolist(),
        "sigma_arcsec": round(chain.sigma_arcsec, 4),
        "algorithm_error_arcsec": chain.algorithm_error_arcsec,
        "notes": list(PAPER_NOTES),
    }
    print(json.dumps(out, indent=2))
    return EXIT_OK


def _seed(text: str) -> int:
    """``--seed``: a whole number 0 … 2⁶³ − 1 (numpy's generators take no negative seeds)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"{text} is outside 0 … {MAX_SEED}")
    return value


class _Parser(argparse.ArgumentParser):
    """argparse with its mistakes on one line (what, and where to read more), exit 2."""

    def error(self, message: str):
        self.exit(EXIT_USAGE, f"{self.prog}: {message} (see `{self.prog} --help`)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="rtcal", description="Angular positioning calibration of rotary tables.")
    parser.add_argument("--version", action="version", version=f"rtcal {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="run a procedure and write a run directory")
    run.add_argument("procedure", help="procedure YAML file")
    run.add_argument("--scenario", help="bench scenario YAML (replaces the procedure's `bench`)")
    run.add_argument("--seed", type=_seed, help="seed of the run's random generator (default: the scenario's)")
    run.add_argument("--out", help="run directory (default: runs/<time>-<procedure>)")
    run.add_argument("--instruments", help="JSON object (or file) of instrument addresses, e.g. what `rtcal sim serve` "
                                           "prints; replaces the procedure's instrument section")
    run.add_argument("--virtual-clock", action="store_true",
                     help="do not wait settle times in real time (for protocol simulators, never for hardware)")
    run.add_argument("--large", action="store_true",
                     help="accept a plan beyond 100 000 readings (up to 2 000 000; takes hours and GBs)")
    run.add_argument("--live", metavar="[HOST:]PORT", help="serve the run's live view from this process (PORT 0: any free "
                                                          "port; 127.0.0.1 unless HOST is given)")
    run.set_defaults(func=_cmd_run)

    resume = sub.add_parser("resume", help="continue an interrupted run: every planned reading not yet stored, once")
    resume.add_argument("run_dir", help="the directory of an interrupted run (what `run --out` wrote)")
    resume.add_argument("--instruments", help="new instrument addresses (JSON object or file), e.g. of a restarted simulator")
    resume.add_argument("--virtual-clock", action="store_true", help="as for `run`")
    resume.add_argument("--live", metavar="[HOST:]PORT", help="as for `run`")
    resume.set_defaults(func=_cmd_resume)

    unc = sub.add_parser("uncertainty", help="Monte Carlo: run a procedure N times on the simulated bench and set the "
                                            "reported 1σ beside the errors against truth, per estimator and target")
    unc.add_argument("procedure", help="procedure YAML file (every instrument `backend: sim`)")
    unc.add_argument("--scenario", help="bench scenario YAML (replaces the procedure's `bench`)")
    unc.add_argument("--trials", type=int, default=30, help="number of simulated runs (default 30)")
    unc.add_argument("--seed", type=_seed, help="seed of the trials (default: the scenario's)")
    unc.add_argument("--workers", type=int, help="local worker processes, at most one per core unless --large "
                                                 "(default: one per core; 1: in this process)")
    unc.add_argument("--large", action="store_true", help="allow more --workers than the machine has cores")
    unc.add_argument("--scheduler", help="address of a running Dask scheduler (e.g. tcp://127.0.0.1:8786) to run the trials on")
    unc.add_argument("--fixed-systematics", action="store_true",
                     help="keep the scenario's CMM errors and error motions in every trial instead of drawing them from "
                          "the procedure's stated uncertainties (shows this one bench's bias)")
    unc.add_argument("--balanced", action="store_true",
                     help="draw the systematic errors in antithetic pairs whose second moments match the stated ones "
                          "exactly (an even --trials, at least twice the numbers a trial draws), so that sampling of the "
                          "systematics does not decide the ratio")
    unc.add_argument("--out", help="directory for uncertainty.json and uncertainty.png (default: runs/<time>-uncertainty)")
    unc.set_defaults(func=_cmd_uncertainty)

    ev = sub.add_parser("evaluate", help="ISO 230-2 or VDI/DGQ 3441 parameters of a positioning test, as JSON")
    ev.add_argument("source", help="a run directory (its results.json) or a CSV with the header "
                                   "target_deg,direction,run,deviation_arcsec[,uncertainty_arcsec] (direction 1 or -1, runs from 1)")
    ev.add_argument("--standard", choices=["iso230-2", "iso230-2:1988", "vdi3441"], default="iso230-2",
                    help="ISO 230-2 (1997/2006/2014), its 1988 edition (±3s), or VDI/DGQ 3441 (default iso230-2)")
    ev.set_defaults(func=_cmd_evaluate)

    comp = sub.add_parser("compensate", help="a controller's compensation table from a run's positioning deviations")
    comp.add_argument("source", help="a run directory or a deviation CSV (as for `rtcal evaluate`)")
    comp.add_argument("--format", required=True, choices=["linuxcnc", "siemens-lec", "siemens-cec", "fanuc", "heidenhain"],
                      help="the controller's format (docs/compensation.md)")
    comp.add_argument("--out", required=True, help="the table file to write")
    comp.add_argument("--step-deg", type=float,
                      help="resample onto a regular grid every STEP° over one turn (must divide 360; default: none, the "
                           "table's points are the measured targets — formats with a fixed pitch need evenly spaced ones)")
    comp.add_argument("--allow-one-direction", action="store_true",
                      help="write a run measured in one direction with the same values both ways (what that does to the "
                           "machine's backlash compensation depends on the format: docs/compensation.md)")
    comp.add_argument("--max-gap-deg", type=float, default=60.0,
                      help="refuse to interpolate across a gap between measured targets larger than this (default 60°)")
    comp.add_argument("--axis", help="axis name in the file: siemens-lec/-cec (default C1), heidenhain (default C)")
    comp.add_argument("--range-deg", type=float, nargs=2, metavar=("LO", "HI"),
                      help="linuxcnc: the joint's travel to cover (default 0 360; LinuxCNC does not wrap a table)")
    comp.add_argument("--detection-unit-deg", type=float,
                      help="fanuc: the axis's detection unit (default 0.0001, IS-C; 0.001 for IS-B)")
    comp.add_argument("--first-point", type=int, help="fanuc: number of the reference position's point, 3620 (default 0)")
    comp.set_defaults(func=_cmd_compensate)

    cmp_ = sub.add_parser("compare", help="two runs of one axis side by side: change per target against the combined "
                                          "uncertainty, ISO 230-2 parameters of both, compare.png")
    cmp_.add_argument("run_a", help="the earlier run (directory or deviation CSV)")
    cmp_.add_argument("run_b", help="the later run (directory or deviation CSV)")
    cmp_.add_argument("--out", help="where compare.png goes (default: the current directory)")
    cmp_.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    cmp_.add_argument("--certificate", action="store_true", help="also write the as-found (RUN_A) / as-left (RUN_B) "
                                                                 "certificate: as_found_as_left.pdf and .html under --out")
    cmp_.set_defaults(func=_cmd_compare)

    exp = sub.add_parser("export", help="every raw reading and event of a run as CSV (readings.csv, events.csv)")
    exp.add_argument("run_dir", help="a run directory (its run.sqlite)")
    exp.add_argument("--out", help="directory for the CSV files (default: the run directory)")
    exp.set_defaults(func=_cmd_export)

    ver = sub.add_parser("verify", help="recompute a run's results from its readings and check results.json and the "
                                        "store's digests against them (exit 0: they agree, 1: they do not)")
    ver.add_argument("run_dir", help="a run directory (its results.json and run.sqlite)")
    ver.set_defaults(func=_cmd_verify)

    plan = sub.add_parser("plan", help="predict each estimator's 1σ per target and the run's duration before measuring")
    plan.add_argument("procedure", help="procedure YAML file")
    plan.add_argument("--scenario", help="bench scenario YAML for the geometry (replaces the procedure's `bench`)")
    plan.add_argument("--json", action="store_true", help="print the prediction as JSON")
    plan.add_argument("--optimize", metavar="OUT.yaml",
                      help="choose CMM points (D/A-optimal exchange on a grid in the CMM volume) that lower the network "
                           "estimator's predicted 1σ, and write the procedure with them to OUT.yaml")
    plan.add_argument("--no-levers", action="store_true", help="predict the procedure as written only, not each lever")
    plan.add_argument("--target-u", type=float, metavar="ARCSEC",
                      help="propose the shortest plan whose U (k = 2, recommended estimator, worst target) reaches this; "
                           "written to --out (exit 1 when none does)")
    plan.add_argument("--out", metavar="FILE.yaml", help="with --target-u: where the proposed procedure goes (its bench "
                                                         "beside it, FILE.bench.yaml, when the plan moves the tracer)")
    plan.add_argument("--margin", type=float, default=0.1,
                      help="with --target-u: plan for this fraction below the target (default 0.1: room for what the "
                           "prediction does not hold and for the Monte Carlo that verifies it)")
    plan.add_argument("--max-radius-mm", type=float,
                      help="the furthest from the axis the table lets the tracer sit, mm (default: twice where the "
                           "procedure has it)")
    plan.set_defaults(func=_cmd_plan)

    sim = sub.add_parser("sim", help="simulated instruments")
    sim_sub = sim.add_subparsers(dest="sim_command", required=True)
    serve = sim_sub.add_parser("serve", help="serve every instrument over its real protocol around one simulated bench; "
                                             "prints one JSON line of addresses, then serves until interrupted")
    serve.add_argument("--scenario", help="bench scenario YAML (default: an ideal bench)")
    serve.add_argument("--seed", type=_seed, help="seed (default: the scenario's)")
    serve.add_argument("--host", default="127.0.0.1", help="address to bind (default: loopback only)")
    serve.add_argument("--serial", choices=["pty", "tcp"], default="pty",
                       help="serial instruments on pseudo-terminals (default) or TCP sockets (socket:// addresses)")
    serve.add_argument("--modbus", choices=["tcp", "rtu"], default="tcp", help="stage drive over Modbus TCP or RTU")
    serve.add_argument("--stage-model", choices=["oriental-az", "pi-gcs"], default="oriental-az",
                       help="the stage's product: an Oriental AZ drive (Modbus) or a PI controller (GCS on a serial line)")
    serve.add_argument("--no-pacing", action="store_true",
                       help="serial replies at once instead of at each product's baud rate (faster tests)")
    serve.add_argument("--environment", choices=["vaisala-ptu300", "vaisala-ptb330"], default="vaisala-ptu300",
                       help="the environment sensor's model (with an OMEGA iTHX thermometer on its thermometer=)")
    serve.add_argument("--ipp-idle-timeout-s", type=float, default=600.0,
                       help="release an I++ session whose client sends nothing for this long, and close its connection "
                            "(default 600 s; docs/faults.md)")
    serve.add_argument("--stage", choices=["modbus", "linuxcnc"], default="modbus",
                       help="the stage: the simulated Modbus drive (default), or a real LinuxCNC started headless "
                            "(linuxcnc-uspace installed) whose compensated motor position the bench's table follows")
    serve.add_argument("--comp", help="with --stage linuxcnc: a LinuxCNC compensation table (what `rtcal compensate "
                                      "--format linuxcnc` writes) loaded as the joint's COMP_FILE")
    serve.set_defaults(func=_cmd_sim_serve)

    from drivers.models import KINDS

    pr = sub.add_parser("probe", help="connect to one instrument, identify it where its protocol allows, take one "
                                      "reading and print it; exit 1 if it does not answer or answers wrongly")
    pr.add_argument("kind", choices=KINDS, help="the kind of instrument")
    pr.add_argument("address", help="its address, e.g. socket://10.0.0.5:4001?model=sylvac or ipp://cmm:1294 "
                                    "(model= picks the product; docs/protocols/)")
    pr.add_argument("--json", action="store_true",
                    help='print one JSON object {"kind", "address", "model", "identity", "reading"}')
    pr.add_argument("--timeout-s", type=float, default=2.0, help="deadline of each request, s (default 2)")
    pr.set_defaults(func=_cmd_probe)

    ck = sub.add_parser("check", help="probe every instrument a procedure needs and check the readings against its "
                                      "ranges (stage limits, CMM volume): one table of what is ready")
    ck.add_argument("procedure", help="procedure YAML file")
    ck.add_argument("--instruments", help="instrument addresses (JSON object or file, e.g. what `rtcal sim serve` "
                                          "printed); replaces the procedure's")
    ck.set_defaults(func=_cmd_check)

    val = sub.add_parser("validate", help="check procedure or scenario files as `run` would before moving (limits, CMM "
                                          "volume, polygon, closure); problems as file:line:column, exit 2")
    val.add_argument("files", nargs="+", help="procedure or scenario YAML files")
    val.add_argument("--scenario", help="check procedures against this bench scenario instead of their `bench`")
    val.add_argument("--large", action="store_true", help="as for `run`: accept plans beyond the default size limits")
    val.set_defaults(func=_cmd_validate)

    schema = sub.add_parser("schema", help="print the JSON Schema of procedure files")
    schema.add_argument("--scenario", action="store_true", help="print the scenario schema instead")
    schema.add_argument("--results", action="store_true", help="print the schema of a run's results.json instead")
    schema.set_defaults(func=_cmd_schema)

    solve = sub.add_parser("solve", help="run a solver on data files")
    solve_sub = solve.add_subparsers(dest="solver", required=True)
    st = solve_sub.add_parser("stations", help="plane, circle and deviations from station centres (CSV X,Y,Z)")
    st.add_argument("file", help="CSV of station centres with columns X, Y, Z in mm, one row per station in order")
    st.add_argument("--step-deg", type=float, required=True, help="nominal angle between adjacent stations")
    st.add_argument("--first-deg", type=float, default=0.0, help="nominal angle of the first station")
    st.set_defaults(func=_cmd_solve_stations)

    view = sub.add_parser("view", help="serve a run's live view read-only (in progress or finished) until Ctrl-C")
    view.add_argument("run_dir", help="the run directory (what `run --out` wrote)")
    view.add_argument("--live", metavar="[HOST:]PORT", help="where to serve (default 127.0.0.1:8765, or any free port; "
                                                           "PORT 0: any free port; another host than 127.0.0.1 is warned of)")
    view.set_defaults(func=_cmd_live)
    ctl = sub.add_parser("control", help="pause, resume or abort the run in progress in a run directory (needs its "
                                         "control token)")
    ctl.add_argument("run_dir", help="the run directory of a run in progress")
    ctl.add_argument("action", choices=["pause", "resume", "abort"], help="what to ask of the run's engine")
    ctl.add_argument("--token", help="the control token the run printed (or the environment variable "
                                     "RTCAL_CONTROL_TOKEN, which other users cannot see in the process list)")
    ctl.set_defaults(func=_cmd_live)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except FileProblems as exc:
        for p in exc.problems:
            print(p, file=sys.stderr)
        return EXIT_USAGE
    except (UserError, AddressError, OutputRefused) as exc:
        print(f"rtcal: {redact_tokens(str(exc))}", file=sys.stderr)
        return EXIT_USAGE
    except InstrumentError as exc:
        print(f"rtcal: instrument error: {redact_tokens(str(exc))}", file=sys.stderr)
        return EXIT_FAILED
    except BrokenPipeError:  # the reader of our output went away (| head): not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK
    except OSError as exc:  # a file the command reads or writes: the disk's failure (exit 1), else the user's path
        if is_disk_failure(exc):
            print(_disk_failure(exc), file=sys.stderr)
            return EXIT_FAILED
        print(f"rtcal: {exc.filename or ''}{': ' if exc.filename else ''}{exc.strerror or exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("rtcal: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
