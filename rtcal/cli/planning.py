"""``rtcal plan``, ``uncertainty`` and ``solve``: before anything moves — the predicted uncertainty
and duration of a plan, the Monte Carlo that checks the reported uncertainty, and solvers on files."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rtcal.cli.common import EXIT_FAILED, EXIT_OK, UserError, make_folder, seed
from rtcal.run.inputs import read_stations_csv
from rtcal.outputs import output_file, write_output

if TYPE_CHECKING:
    from rtcal.planning.levers import Outcome, Proposal
    from rtcal.planning.montecarlo import TrialSpec
    from rtcal.planning.reports import PlanPrediction, UncertaintySummary
    from rtcal.procedure.models import Procedure
    from simulators.scenario import Scenario


def cmd_plan(args: argparse.Namespace) -> int:
    """Predicted 1σ per target and the duration of a procedure, before anything moves; what its
    uncertainty is made of and what each lever would do; the shortest plan for a target U."""
    from rtcal.planning.reports import optimize_refusal, plan_prediction, plan_proposal
    from rtcal.methods import METHODS, load_procedure
    from rtcal.run.runner import check_plan_on_bench, resolve_scenario

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
    refusal = optimize_refusal(path, proc) if args.optimize else None
    if refusal:
        raise UserError(f"--optimize: {refusal}")
    scenario, _ = resolve_scenario(path, proc, Path(args.scenario) if args.scenario else None)
    check_plan_on_bench(path, proc, scenario, METHODS[proc.method])
    plan, lever_outcomes = plan_prediction(path, proc, scenario, levers=not args.no_levers,
                                           max_radius_mm=args.max_radius_mm)
    proposal = written = None
    if args.target_u is not None:
        plan.proposal, proposal, written = plan_proposal(path, proc, scenario, args.target_u, args.margin,
                                                         args.max_radius_mm, Path(args.out), bool(args.scenario))
    if args.json:
        print(plan.to_json())
    else:
        _print_plan(path, plan, lever_outcomes)
        if proposal is not None:
            _print_proposal(args, proposal, written)
    if args.optimize:
        from rtcal.planning.reports import optimized_points

        try:
            print(optimized_points(path, proc, scenario, Path(args.optimize)))
        except ValueError as exc:
            raise UserError(f"--optimize: {exc}") from None
    return EXIT_FAILED if proposal is not None and proposal.best is None else EXIT_OK


def _print_plan(path: Path, plan: PlanPrediction, lever_outcomes: list[Outcome]) -> None:
    from rtcal.methods.planner import Candidate
    from rtcal.planning import levers as lv

    hours = plan.measurement_duration_s / 3600
    print(f"{path}: {plan.raw_readings} planned readings, about {plan.measurement_duration_s:.0f} s ({hours:.1f} h) of "
          "motions, settling and readings; predicted 1σ from the stated noise:")
    for name, e in plan.estimators.items():
        rec = " (recommended)" if name == plan.recommended else ""
        print(f"{name}{rec}: RMS {e.rms_predicted_sigma_arcsec}″")
        print("  target    " + " ".join(f"{t:>8}" for t in plan.targets[1:]))
        print("  1σ / ″    " + " ".join(f"{v:8.3f}" for v in e.predicted_sigma_arcsec[1:]))
    if plan.expanded_uncertainty_max_arcsec is None:  # no angular estimate: the method's notes say what it predicts
        for note in plan.lever_notes:
            print(f"  ({note})")
        return
    top = ", ".join(f"{d.source} {100 * d.share:.0f} %" for d in plan.dominant_sources[:4])
    print(f"U (k = 2) of {plan.recommended}: at most {plan.expanded_uncertainty_max_arcsec:.2f}″; its variance: {top}")
    if lever_outcomes:
        print("levers, each alone (predicted the same way):")
        as_written = lv.Outcome(Candidate({}, {}), plan.recommended, plan.expanded_uncertainty_max_arcsec,
                                plan.measurement_duration_s, plan.raw_readings)
        for line in lv.table_lines([("as written", as_written)] + [("; ".join(o.plan.changes), o) for o in lever_outcomes]):
            print(line)
    for note in plan.lever_notes:
        print(f"  ({note})")


def _print_proposal(args: argparse.Namespace, proposal: Proposal, written: list[Path] | None) -> None:
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


MAX_WORKERS = 256  # with --large: beyond the cores, e.g. when trials wait on I/O


def workers(requested: int | None, large: bool) -> int:
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


def check_scheduler(address: str) -> None:
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


def cmd_uncertainty(args: argparse.Namespace) -> int:
    """Monte Carlo of the procedure on the simulated bench: reported 1σ against the errors made."""
    from rtcal.planning.reports import uncertainty_summary
    from rtcal.run.runner import default_run_dir

    n_workers = _uncertainty_workers(args)
    path, proc, scenario = _simulated_procedure(args)
    out = Path(args.out) if args.out else default_run_dir("uncertainty")
    trial_seed = scenario.seed if args.seed is None else args.seed
    specs = _trial_specs(args, path, proc, scenario, trial_seed, out)
    make_folder(out, "--out")
    trials = _run_trials(specs, n_workers, args.scheduler)
    ok = [t for t in trials if "failed" not in t]
    if not ok:
        print(f"rtcal: every trial failed; the first: {trials[0]['failed']}", file=sys.stderr)
        return EXIT_FAILED
    summary = uncertainty_summary(trials, path, proc, args.scenario, trial_seed, not args.fixed_systematics, args.balanced)
    data = summary.model_dump()
    _write_uncertainty(out, summary, data, f"{proc.name or path.stem}: reported 1σ against the errors of {len(ok)} "
                       "simulated runs")
    _print_uncertainty(summary, data, len(ok), out)
    return EXIT_OK


def _uncertainty_workers(args: argparse.Namespace) -> int:
    """The options that need no file, checked first so that a mistake costs no loading: --trials,
    --workers (returned: how many), --scheduler."""
    if not 2 <= args.trials <= 100_000:
        raise UserError("--trials must lie in 2..100000")
    n_workers = workers(args.workers, args.large)
    if args.scheduler:
        check_scheduler(args.scheduler)
    return n_workers


def _simulated_procedure(args: argparse.Namespace) -> tuple[Path, Procedure, Scenario]:
    """The procedure and its bench, refused before any trial unless every instrument is simulated
    (the Monte Carlo knows the truth only on the simulated bench) and the plan fits the bench."""
    from rtcal.methods import METHODS, load_procedure
    from rtcal.run.runner import check_plan_on_bench, resolve_scenario

    path = Path(args.procedure)
    proc = load_procedure(path)
    if not proc.instruments.all_sim():
        raise UserError(f"{path}: the Monte Carlo runs on the simulated bench: every instrument must be `backend: sim`")
    scenario, _ = resolve_scenario(path, proc, Path(args.scenario) if args.scenario else None)
    check_plan_on_bench(path, proc, scenario, METHODS[proc.method])
    return path, proc, scenario


def _trial_specs(args: argparse.Namespace, path: Path, proc: Procedure, scenario: Scenario, trial_seed: int,
                 out: Path) -> list[TrialSpec]:
    """Every trial's spec, drawn before any runs: a --balanced draw that cannot be made is the
    user's mistake (exit 2), not a failed trial."""
    from rtcal.planning import montecarlo

    if args.balanced and args.fixed_systematics:
        raise UserError("--balanced and --fixed-systematics: choose one (--balanced is how the systematic errors are drawn)")
    try:
        return montecarlo.plan_trials(path, proc, scenario, args.trials, trial_seed, out, not args.fixed_systematics,
                                      args.balanced)
    except ValueError as exc:
        raise UserError(f"--balanced: {exc}") from None


def _run_trials(specs: list[TrialSpec], n_workers: int, scheduler: str | None) -> list[dict[str, Any]]:
    """The trials' results, with a bar on a terminal; a Dask scheduler that cannot be reached is the
    user's address to correct (exit 2), a local OSError is not."""
    from tqdm import tqdm

    from rtcal.planning import montecarlo

    trials = []
    bar = tqdm(total=len(specs), desc="trials", unit="trial", disable=not sys.stderr.isatty(), file=sys.stderr)
    try:
        for result in montecarlo.run_trials(specs, n_workers, scheduler):
            trials.append(result)
            bar.update()
    except OSError as exc:
        if not scheduler:
            raise
        raise UserError(f"--scheduler {scheduler}: cannot reach the Dask scheduler: {exc}") from None
    finally:
        bar.close()
    return trials


def _write_uncertainty(out: Path, summary: UncertaintySummary, data: dict[str, Any], title: str) -> None:
    """uncertainty.json and uncertainty.png, each written whole or not at all (:func:`write_output`)."""
    from rtcal.planning import montecarlo

    write_output(out / "uncertainty.json", summary.to_json())
    with output_file(out / "uncertainty.png") as png:
        montecarlo.plot_summary(data, title, png)


def _print_uncertainty(summary: UncertaintySummary, data: dict[str, Any], n_ok: int, out: Path) -> None:
    """Per estimator the overall figures, then a row per target (any number of targets fits)."""
    from rtcal.planning import montecarlo

    print(f"{n_ok} trials ({summary.failed_trials} failed), systematics {summary.systematics}")
    for name, e in summary.estimators.items():
        rec = " (recommended)" if name == summary.recommended else ""
        o = e.overall
        print(f"{name}{rec}: RMS error {o.rms_error_arcsec}″, RMS reported 1σ {o.rms_reported_sigma_arcsec}″,\n"
              f"  ratio per target {o.ratio_min}–{o.ratio_max} (each ± about {1 / (2 * e.trials) ** 0.5:.0%} from "
              f"{e.trials} trials); U (k = 2) covers {o.coverage_k2:.1%} of the errors"
              + ("" if e.residual_test_failed is None else f"; residual test failed in {e.residual_test_failed:.0%} of the trials"))
        for line in montecarlo.table_lines(summary.targets, data["estimators"][name]):
            print(line)
    r = summary.recommended_estimate
    if r is not None:
        quoted = "" if r.coverage_k2_quoted is None else f", {r.coverage_k2_quoted:.1%} where it passed"
        print(f"recommended, trial by trial ({', '.join(f'{k} {v}' for k, v in r.estimators.items())}): U (k = 2) covers "
              f"{r.coverage_k2:.1%}{quoted}; RMS 1σ / RMS error {r.ratio}; bias {r.mean_error_arcsec:+.3f}″ (largest "
              f"{r.largest_mean_error_arcsec:+.3f}″); residual test failed in {r.residual_test_failed:.0%} (said on the "
              "certificate)")
    print(f"results in {out}/ (uncertainty.json, uncertainty.png)")


def cmd_solve_stations(args: argparse.Namespace) -> int:
    from rtcal.solvers.paper000 import station_chain_json

    stations = read_stations_csv(Path(args.file))
    if not 0 < args.step_deg < 180:
        raise UserError("--step-deg must lie in (0, 180)")
    if not abs(args.first_deg) <= 36000:
        raise UserError("--first-deg must be finite and within ±36000")
    try:
        out = station_chain_json(stations, args.first_deg, args.step_deg)
    except ValueError as exc:  # numpy's LinAlgError is one
        raise UserError(f"{args.file}: stations do not define a plane and a circle: {exc}") from None
    print(json.dumps(out, indent=2))
    return EXIT_OK


def add_plan(sub: Any) -> None:
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
                                                         "beside it, FILE.bench.yaml, when the plan moves the tracer or "
                                                         "the bench lies outside FILE's folder)")
    plan.add_argument("--margin", type=float, default=0.1,
                      help="with --target-u: plan for this fraction below the target (default 0.1: room for what the "
                           "prediction does not hold and for the Monte Carlo that verifies it)")
    plan.add_argument("--max-radius-mm", type=float,
                      help="the furthest from the axis the table lets the tracer sit, mm (default: twice where the "
                           "procedure has it)")
    plan.set_defaults(func=cmd_plan)


def add_uncertainty(sub: Any) -> None:
    unc = sub.add_parser("uncertainty", help="Monte Carlo: run a procedure N times on the simulated bench and set the "
                                            "reported 1σ beside the errors against truth, per estimator and target")
    unc.add_argument("procedure", help="procedure YAML file (every instrument `backend: sim`)")
    unc.add_argument("--scenario", help="bench scenario YAML (replaces the procedure's `bench`)")
    unc.add_argument("--trials", type=int, default=30, help="number of simulated runs (default 30)")
    unc.add_argument("--seed", type=seed, help="seed of the trials (default: the scenario's)")
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
    unc.set_defaults(func=cmd_uncertainty)


def add_solve(sub: Any) -> None:
    solve = sub.add_parser("solve", help="run a solver on data files")
    solve_sub = solve.add_subparsers(dest="solver", required=True)
    st = solve_sub.add_parser("stations", help="plane, circle and deviations from station centres (CSV X,Y,Z)")
    st.add_argument("file", help="CSV of station centres with columns X, Y, Z in mm, one row per station in order")
    st.add_argument("--step-deg", type=float, required=True, help="nominal angle between adjacent stations")
    st.add_argument("--first-deg", type=float, default=0.0, help="nominal angle of the first station")
    st.set_defaults(func=cmd_solve_stations)
