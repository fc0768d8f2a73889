"""The ``rtcal`` command line: argument parsing and dispatch only. User mistakes exit 2 with a
located message, never a traceback.

One module per command group; each has an ``add_<command>(sub)`` that declares the command's
arguments and a ``cmd_<command>(args)`` that calls into the package and prints. To add a command,
write both in its group's module and list its ``add_`` in ``COMMANDS`` below (the order of
``rtcal --help``)."""

from __future__ import annotations

import argparse
import os
import sys
from typing import Any, Callable

from drivers.addresses import AddressError, redact_tokens
from drivers.errors import InstrumentError
from rtcal import __version__
from rtcal.cli import catalog, files, keys, live, planning, results, run, sim
from rtcal.cli.common import (EXIT_FAILED, EXIT_INTERRUPTED, EXIT_NOT_CONVERGED, EXIT_OK, EXIT_USAGE, MAX_SEED, Parser,
                              UserError, disk_failure, json_text, parse_instruments_option)
from rtcal.cli.common import seed as _seed
from rtcal.cli.planning import MAX_WORKERS, read_stations_csv
from rtcal.cli.planning import check_scheduler as _check_scheduler
from rtcal.cli.planning import workers as _workers
from rtcal.cli.results import read_deviation_table, run_label
from rtcal.outputs import OutputRefused, is_disk_failure
from rtcal.procedure.yamlfile import FileProblems

__all__ = ["EXIT_FAILED", "EXIT_INTERRUPTED", "EXIT_NOT_CONVERGED", "EXIT_OK", "EXIT_USAGE", "MAX_SEED", "MAX_WORKERS",
           "UserError", "build_parser", "json_text", "main", "parse_instruments_option", "read_deviation_table",
           "read_stations_csv", "run_label", "_check_scheduler", "_seed", "_workers"]

COMMANDS: tuple[Callable[[Any], None], ...] = (
    run.add_run, run.add_resume,
    planning.add_uncertainty,
    results.add_evaluate, results.add_compensate, results.add_compare, results.add_export, results.add_verify,
    planning.add_plan,
    sim.add_sim,
    run.add_probe, run.add_check,
    files.add_validate, files.add_schema,
    planning.add_solve,
    live.add_view, live.add_control,
    catalog.add_catalog,
    keys.add_key,
)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="rtcal", description="Angular positioning calibration of rotary tables.")
    parser.add_argument("--version", action="version", version=f"rtcal {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for add in COMMANDS:
        add(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
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
            print(disk_failure(exc), file=sys.stderr)
            return EXIT_FAILED
        print(f"rtcal: {exc.filename or ''}{': ' if exc.filename else ''}{exc.strerror or exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("rtcal: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
