"""``rtcal validate`` and ``schema``: procedure and scenario files checked, and the JSON Schemas
of what rtcal reads and writes."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from rtcal.cli.common import EXIT_OK, EXIT_USAGE, UserError
from rtcal.procedure.yamlfile import FileProblems


def cmd_validate(args: argparse.Namespace) -> int:
    """Everything `run` checks before the first motion: the file, and the plan against the bench
    it would run on (the procedure's `bench`, or --scenario) — limits, CMM volume, polygon."""
    from rtcal.methods import METHODS, load_procedure
    from rtcal.procedure.loader import bench_path, is_procedure_text
    from simulators.scenario_file import load_scenario
    from rtcal.run.runner import check_plan_on_bench, resolve_scenario
    from rtcal.procedure.yamlfile import read_text

    problems = []
    for name in args.files:
        path = Path(name)
        try:
            text = read_text(path)
            if is_procedure_text(text):
                proc = load_procedure(path, args.large, text)
                due = _due_date_problems(path, proc)  # said with, not instead of, the bench's problems
                try:
                    if proc.instruments.all_sim() or args.scenario:
                        scenario, _ = resolve_scenario(path, proc, Path(args.scenario) if args.scenario else None)
                        check_plan_on_bench(path, proc, scenario, METHODS[proc.method])
                    elif (bench := bench_path(path, proc)) is not None:  # None: the procedure names no bench
                        load_scenario(bench)
                except FileProblems as exc:
                    raise FileProblems(due + list(exc.problems)) from None
                if due:
                    raise FileProblems(due)
            else:
                load_scenario(path)
            print(f"{path}: ok")
        except FileProblems as exc:
            problems += [str(p) for p in exc.problems]
    for p in problems:
        print(p, file=sys.stderr)
    return EXIT_USAGE if problems else EXIT_OK


def _due_date_problems(path: Path, proc: Any) -> list:
    """What `run` refuses today: a reference standard or instrument past its calibration due date."""
    import datetime as _dt

    from rtcal.procedure.yamlfile import problem_at
    from rtcal.run.runner import expired_instruments

    today = _dt.datetime.now(_dt.timezone.utc).date()
    expired = expired_instruments(proc, today)
    return [problem_at(path, ("metadata", "instruments", name, "calibration_due"),
                       f"{due} is past (today {today.isoformat()}): `rtcal run` refuses an instrument past its "
                       "calibration due date; recalibrate it, or use one in calibration")
            for name, due in expired]


def cmd_schema(args: argparse.Namespace) -> int:
    from rtcal.deliverables.certificate import certificate_schema
    from rtcal.planning.reports import plan_schema, uncertainty_schema
    from rtcal.methods import procedure_schema, results_schema
    from simulators.scenario_file import scenario_schema

    chosen = [(flag, schema) for flag, schema in (("--scenario", scenario_schema), ("--results", results_schema),
                                                  ("--plan", plan_schema), ("--uncertainty", uncertainty_schema),
                                                  ("--certificate", certificate_schema))
              if getattr(args, flag[2:])]
    if len(chosen) > 1:
        raise UserError(f"schema: give {' or '.join(flag for flag, _ in chosen)}, not both")
    print(chosen[0][1]() if chosen else procedure_schema())
    return EXIT_OK


def add_validate(sub: Any) -> None:
    val = sub.add_parser("validate", help="check procedure or scenario files as `run` would before moving (limits, CMM "
                                          "volume, polygon, closure); problems as file:line:column, exit 2")
    val.add_argument("files", nargs="+", help="procedure or scenario YAML files")
    val.add_argument("--scenario", help="check procedures against this bench scenario instead of their `bench`")
    val.add_argument("--large", action="store_true", help="as for `run`: accept plans beyond the default size limits")
    val.set_defaults(func=cmd_validate)


def add_schema(sub: Any) -> None:
    schema = sub.add_parser("schema", help="print the JSON Schema of procedure files")
    schema.add_argument("--scenario", action="store_true", help="print the scenario schema instead")
    schema.add_argument("--results", action="store_true", help="print the schema of a run's results.json instead")
    schema.add_argument("--plan", action="store_true", help="print the schema of what `rtcal plan --json` prints instead")
    schema.add_argument("--uncertainty", action="store_true",
                        help="print the schema of the uncertainty.json `rtcal uncertainty` writes instead")
    schema.add_argument("--certificate", action="store_true",
                        help="print the schema of a run's certificate.json (the certificate as one document) instead")
    schema.set_defaults(func=cmd_schema)
