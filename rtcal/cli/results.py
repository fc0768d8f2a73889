"""``rtcal evaluate``, ``compensate``, ``compare``, ``export`` and ``verify``: what a run's results
become (tables, certificates, controller files) and whether they still hold."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rtcal.cli.common import EXIT_FAILED, EXIT_OK, UserError, json_text, make_folder, one_line
from rtcal.run.inputs import read_deviation_table
from rtcal.outputs import output_file, write_output

if TYPE_CHECKING:
    from rtcal.deliverables.deviations import PositioningDeviations
    from rtcal.results import RunResults


def cmd_evaluate(args: argparse.Namespace) -> int:
    """A standard's parameters of a positioning test, as JSON: ISO 230-2 (with UPR beside R↑ and R↓),
    its 1988 edition or VDI 3441 keyed by their symbols as results.json holds them, and every
    figure (these and the other labels') with its edition, coverage and definition."""
    from rtcal.deliverables.evaluation import STANDARDS, evaluate
    from rtcal.deliverables.standards import standard_figures, upr
    from rtcal.procedure.standards import standard_named

    table, results = read_deviation_table(args.source)
    try:
        label = standard_named(args.standard).label
        uncertainties, conformity = None, None
        if results is not None:
            from rtcal.deliverables.conformity import parameter_uncertainties

            uncertainties, conformity = parameter_uncertainties(results), results.conformity
        figures = standard_figures(label, table, uncertainties, conformity)
        if label in STANDARDS:  # the keys results.json holds, then the figures in words
            result = evaluate(table, label)
            if label == "iso230-2":  # UPR beside R↑ and R↓
                result = {**{k: v for k, v in result.items() if k not in _AFTER_R_DOWN},
                          "UPR": upr(result), **{k: result[k] for k in _AFTER_R_DOWN}}
            result = {**result, "title": figures.title, "edition": figures.edition,
                      "figures": [f.as_json() for f in figures.figures]}
        else:
            result = figures.as_json()
    except ValueError as exc:
        raise UserError(f"{args.source}: {exc}") from None
    print(json_text(result))
    return EXIT_OK


_AFTER_R_DOWN = ("R", "A_up", "A_down", "A", "per_target", "notes")


def cmd_compensate(args: argparse.Namespace) -> int:
    """A controller's compensation table from a run's (or a CSV's) positioning deviations: at the
    measured targets unless a grid is asked for (--step-deg); a one-direction run only with
    --allow-one-direction; warnings on stderr (and in the file where the format takes comments)."""
    from rtcal.compensation import CompensationError, get_format, options_given, write_table
    from rtcal.deliverables.compensation import table_from_deviations

    table, results = read_deviation_table(args.source)
    try:
        comp = table_from_deviations(table, args.step_deg, args.max_gap_deg, args.allow_one_direction, args.format)
        options = options_given(vars(args))
        for keyword in getattr(get_format(args.format), "run_options", ()):  # options that name a run: its data
            options[keyword] = _iso230_1_errors(keyword, options.get(keyword), results, args.source)
        text = write_table(args.format, comp, **options)
    except CompensationError as exc:
        raise UserError(f"{args.source}: {exc}") from None
    out = write_output(Path(args.out), text)
    worst = max(float(abs(comp.trim_up_deg).max()), float(abs(comp.trim_down_deg).max())) * 3600
    print(f"{args.format} table written to {out} ({len(text.splitlines())} lines): {comp.summary()}, trims up to {worst:.2f}″ "
          "(docs/compensation.md: the format's rules and sign)")
    fmt = get_format(args.format)
    for step in fmt.instructions(comp, **options):  # what to do on the control
        print(f"on the control: {step}")
    for reading in fmt.readings(comp, **options):  # what no manual settles, and the check on the machine
        print(f"unsettled: {reading}")
    note = fmt.comment_note(**options)
    for warning in comp.warnings:
        print(f"rtcal: warning: {warning}{f' (not in {out}: {note})' if note else ''}", file=sys.stderr)
    return EXIT_OK


def _iso230_1_errors(which: str, run: str | None, source: RunResults | None, source_text: str) -> Any:
    """The ISO 230-1 error motions or location errors (``which``) of ``run`` — or of the source run
    when none is named (None: it has none, or the source is a CSV) — as its method's outputs give
    them (``iso230_1_errors()``); a named run without them is a UserError."""
    from rtcal.methods import METHODS

    if run is not None:
        _, results = read_deviation_table(run) if Path(run).is_dir() else (None, None)
        if results is None:
            raise UserError(f"{run}: not a run directory (its results.json gives the {which.replace('_', ' ')})")
    else:
        results = source
    if results is None:
        return None
    found = getattr(METHODS[results.method].outputs(results), "iso230_1_errors", None)
    motions, location = found() if found is not None else (None, None)
    value = motions if which == "error_motions" else location
    if value is None and run is not None:
        raise UserError(f"{run}: its {results.method} run gives no {which.replace('_', ' ')} (error motions: the Abbe "
                        "method's dial indicators or seed 000's second tracer mount; location: seed 000's network)")
    return value


def run_label(path_text: str) -> str:
    """A run as a reader tells it apart: its last two path components (runs/iso, runs/iso-after)."""
    parts = Path(path_text).resolve().parts
    return "/".join(parts[-2:]) if len(parts) > 1 else path_text


def cmd_compare(args: argparse.Namespace) -> int:
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
    if args.certificate:
        _as_found_pair(a[1], b[1], (result["a"], result["b"]))  # refused before anything is written
    out = Path(args.out) if args.out else Path(".")  # the current directory: never inside either run
    make_folder(out, "--out")
    with output_file(out / "compare.png") as png:
        plot_comparison(result, a, b, png)
    result["plot"] = str(out / "compare.png")
    if args.certificate:
        result["certificate"] = _as_found_certificate(args, a[1], b[1], result, out)
    written = [result["plot"]] + ([f"{result['certificate']}.{kind}" for kind in ("pdf", "html", "json")]
                                  if args.certificate else [])
    if args.json:  # stdout is the JSON alone; what was written goes to stderr, still named
        print(json_text(result))
        print("rtcal: written: " + ", ".join(written), file=sys.stderr)
    else:
        print("\n".join(comparison_lines(result) + ["written: " + ", ".join(written)]))
    return EXIT_OK


def cmd_verify(args: argparse.Namespace) -> int:
    """Recompute a run's results from its store and say whether results.json agrees (exit 0 / 1)."""
    from rtcal.results import ResultsError
    from rtcal.run.rundir import RunDirError
    from rtcal.methods import METHODS
    from rtcal.run.verify import ALTERED, verify

    run = Path(args.run_dir)
    if not run.is_dir():
        raise UserError(f"{run}: not a run directory")
    import sqlite3

    try:
        found = verify(run, METHODS)
    except (ResultsError, RunDirError) as exc:
        raise UserError(str(exc)) from None
    except sqlite3.DatabaseError as exc:
        raise UserError(f"{run / 'run.sqlite'}: cannot be read whole ({exc}); `rtcal export {run}` salvages its readings") from None
    except ValueError as exc:  # numpy's LinAlgError is one
        print(f"rtcal: {run}: the solvers could not recompute the results from the readings: {one_line(exc)[:300]}",
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
    for name, status in found.altered_files:
        print(f"rtcal: {run / name}: {status} — {ALTERED[status]}", file=sys.stderr)
    same = found.compared - len(found.differences)
    print(f"{run / 'results.json'}: {same} of {found.compared} values agree with the results recomputed from "
          f"{found.readings} readings in {run / 'run.sqlite'} (to the digits stored)")
    print(f"{run / 'results.json'} and {run / 'run.sqlite'}: digests {'match' if not found.integrity else 'do NOT match'} "
          "(each records the other's)")
    for name, status in found.files:
        print(f"{run / name}: {status}")
    if found.signature is not None:
        print(f"{run}: signature: {found.signature.text if found.signature.state != 'REFUSED' else 'REFUSED (above)'}")
    if found.results is not None and found.results.simulation is not None:
        print(f"{run}: {found.results.simulation.statement}")
    verdict = "agrees" if found.agrees else "does NOT agree"
    print(f"{run} {verdict}: {len(found.differences)} differ of {found.compared} values, {len(found.altered_files)} of {len(found.files)} "
          f"deliverables changed, digests {'match' if not found.integrity else 'do not match'}")
    return EXIT_OK if found.agrees else EXIT_FAILED




def _as_found_pair(found: RunResults | None, left: RunResults | None, labels: tuple[str, str]) -> None:
    """Two runs that can be as found and as left (UserError if not), with a warning when simulated periods overlap."""
    from rtcal.deliverables.as_found import NotAPair, periods_overlap

    if found is None or left is None:
        raise UserError("--certificate: give two run directories (a certificate needs their results.json, not a CSV)")
    try:
        overlap = periods_overlap(found, left, labels)
    except NotAPair as exc:
        raise UserError(f"--certificate: {exc}") from None
    if overlap:  # simulated: said on the certificate, and here
        print(f"rtcal: warning: {overlap}", file=sys.stderr)


def _as_found_certificate(args: argparse.Namespace, found: RunResults | None, left: RunResults | None,
                          result: dict[str, Any], out: Path) -> str:
    """``compare --certificate``: the as-found / as-left certificate of two run directories."""
    from rtcal.deliverables.as_found import as_found_as_left_model
    from rtcal.deliverables.certificate import write_certificate_json
    from rtcal.deliverables.report import write_html, write_pdf

    assert found is not None and left is not None  # cmd_compare checked the pair (_as_found_pair)
    labels = (result["a"], result["b"])
    if args.certificate_number is not None:  # a document of its own: its own number
        left = left.model_copy(update={"metadata": left.metadata.model_copy(update={
            "certificate_number": args.certificate_number})})
    elif left.metadata.certificate_number:
        print(f"rtcal: warning: {out / 'as_found_as_left.pdf'} carries {args.run_b}'s certificate number "
              f"{left.metadata.certificate_number}: give it its own (--certificate-number NUMBER)", file=sys.stderr)
    from rtcal.methods import METHODS

    model = as_found_as_left_model(found, left, result, out, "compare.png", labels, METHODS[left.method])
    with output_file(out / "as_found_as_left.pdf") as pdf:
        write_pdf(model, pdf)
    with output_file(out / "as_found_as_left.html") as html:
        write_html(model, html)
    with output_file(out / "as_found_as_left.json") as doc:
        write_certificate_json(model, doc)
    return str(out / "as_found_as_left")


def cmd_export(args: argparse.Namespace) -> int:
    """Every raw reading and event of a run as CSV, for spreadsheets; from a damaged store, every
    one that can still be read (exit 1: the store is damaged, and the count of what is lost)."""
    from rtcal.store.salvage import salvage_store
    from rtcal.store.runstore import CONTEXT, EVENT_COLUMNS, READING_COLUMNS, RunStore, check_store, write_csv

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
    make_folder(out, "--out")
    readings_csv, events_csv = out / "readings.csv", out / "events.csv"
    if found.kind == "run":
        store = RunStore.open(run)
        try:
            planned, instrument = len(store.done_plan_indices()), store.instrument_readings()
            rows, events = store.export_csv(out)
        finally:
            store.close()
        from rtcal.deliverables.certificate import plural

        markers = f" and {plural(rows - instrument, 'skip marker')}" if rows > instrument else ""
        print(f"{plural(instrument, 'instrument reading')}{markers} ({plural(planned, 'planned reading')} taken) → "
              f"{readings_csv}, {plural(events, 'event')} → {events_csv}, what each quantity is → "
              f"{out / 'descriptions.csv'}")
        return EXIT_OK
    saved = salvage_store(path)  # damaged, or readings without a procedure: read page by page
    write_csv(readings_csv, ("id",) + READING_COLUMNS + (CONTEXT,), ((i, *saved.readings[i]) for i in sorted(saved.readings)))
    write_csv(events_csv, ("id",) + EVENT_COLUMNS, ((i, *saved.events[i]) for i in sorted(saved.events)))
    from rtcal.deliverables.certificate import plural

    print(f"{plural(len(saved.readings), 'salvaged reading')} → {readings_csv}, {plural(len(saved.events), 'salvaged event')} "
          f"→ {events_csv}")
    print(f"rtcal: {path} {found.detail}; salvaged page by page: {saved.summary()}", file=sys.stderr)
    return EXIT_FAILED if found.kind == "damaged" or saved.unreadable_readings else EXIT_OK


def add_evaluate(sub: Any) -> None:
    from rtcal.procedure.standards import ALIASES, LABELS, STANDARDS

    ev = sub.add_parser("evaluate", help="a positioning test's figures to a standard (ISO 230-2 by default), as JSON")
    ev.add_argument("source", help="a run directory (its results.json) or a CSV with the header "
                                   "target_deg,direction,run,deviation_arcsec[,uncertainty_arcsec] (direction 1 or -1, runs from 1)")
    ev.add_argument("--standard", choices=LABELS + tuple(ALIASES), default="iso230-2", metavar="LABEL",
                    help="the standard whose figures to give (default iso230-2), each with its edition, coverage and "
                         "definition: " + "; ".join(f"{s.label}: {s.title}" for s in STANDARDS.values())
                         + f" ({', '.join(ALIASES)}: the same as iso230-2; docs/evaluation.md)")
    ev.set_defaults(func=cmd_evaluate)


def add_compensate(sub: Any) -> None:
    from rtcal.compensation import cli_options, format_names

    comp = sub.add_parser("compensate", help="a controller's compensation table from a run's positioning deviations")
    comp.add_argument("source", help="a run directory or a deviation CSV (as for `rtcal evaluate`)")
    comp.add_argument("--format", required=True, choices=format_names(),
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
    for option in cli_options():
        comp.add_argument(option.flag, **option.argparse_kwargs())
    comp.set_defaults(func=cmd_compensate)


def add_compare(sub: Any) -> None:
    from rtcal.cli.run import certificate_number

    cmp_ = sub.add_parser("compare", help="two runs of one axis side by side: change per target against the combined "
                                          "uncertainty, ISO 230-2 parameters of both, compare.png")
    cmp_.add_argument("run_a", help="the earlier run (directory or deviation CSV)")
    cmp_.add_argument("run_b", help="the later run (directory or deviation CSV)")
    cmp_.add_argument("--out", help="where compare.png goes (default: the current directory)")
    cmp_.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    cmp_.add_argument("--certificate", action="store_true", help="also write the as-found (RUN_A) / as-left (RUN_B) "
                                                                 "certificate: as_found_as_left.pdf, .html and .json under --out")
    cmp_.add_argument("--certificate-number", type=certificate_number, metavar="NUMBER",
                      help="with --certificate: the as-found / as-left certificate's own number (default: the as-left "
                           "run's, with a warning: each certificate needs its own)")
    cmp_.set_defaults(func=cmd_compare)


def add_export(sub: Any) -> None:
    exp = sub.add_parser("export", help="every raw reading and event of a run as CSV (readings.csv, events.csv, descriptions.csv)")
    exp.add_argument("run_dir", help="a run directory (its run.sqlite)")
    exp.add_argument("--out", help="directory for the CSV files (default: the run directory)")
    exp.set_defaults(func=cmd_export)


def add_verify(sub: Any) -> None:
    ver = sub.add_parser("verify", help="recompute a run's results from its readings and check results.json, the store "
                                        "and every deliverable (certificate, reports, CSV, figures) against their "
                                        "digests; says each file's status (exit 0: all agree, 1: a value differs or a "
                                        "file was edited, naming it; 2: not a run directory, or a results.json that is "
                                        "not rtcal's)")
    ver.add_argument("run_dir", help="a run directory (its results.json and run.sqlite)")
    ver.set_defaults(func=cmd_verify)
