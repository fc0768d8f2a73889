"""``rtcal view`` and ``control``: a run's live view, and pausing, resuming or aborting it."""

from __future__ import annotations

import argparse
from typing import Any

from rtcal.cli.common import EXIT_FAILED, UserError


def cmd_live(args: argparse.Namespace) -> int:
    """`rtcal view` and `rtcal control` (rtcal.live.commands)."""
    from rtcal.live import commands

    if args.command == "view":
        if args.catalog:
            return _view_catalog(args)
        if args.run_dir is None:
            raise UserError("view: give a run directory, or --catalog for the calibration catalogue")
        return commands.view(args.run_dir, args.live)
    return commands.control(args.run_dir, args.action, args.token, getattr(args, "step", None))


def _view_catalog(args: argparse.Namespace) -> int:
    """`rtcal view --catalog`: the catalogue's fleet page (rtcal/catalog/page.py)."""
    import signal
    import sys

    from rtcal.catalog.page import serve_catalog
    from rtcal.catalog.store import CatalogError, CatalogUsage
    from rtcal.live.server import LiveSpecError, parse_live_spec

    try:
        host, port = parse_live_spec(args.live) if args.live is not None else ("127.0.0.1", 0)
    except LiveSpecError as exc:
        raise UserError(str(exc)) from None

    def stop(*_: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, stop)
    try:
        return serve_catalog(args.db, host, port or 0)
    except CatalogUsage as exc:
        raise UserError(str(exc)) from None
    except OSError as exc:  # the port is taken, or the host is not this computer's
        raise UserError(f"view --catalog: cannot listen on {args.live or 'a free port'}: {exc.strerror or exc}") from None
    except CatalogError as exc:
        print(f"rtcal: {exc}", file=sys.stderr)
        return EXIT_FAILED


def add_view(sub: Any) -> None:
    view = sub.add_parser("view", help="serve a run's live view read-only (in progress or finished) until Ctrl-C")
    view.add_argument("run_dir", nargs="?", help="the run directory (what `run --out` wrote)")
    view.add_argument("--catalog", action="store_true", help="serve the calibration catalogue's fleet page instead "
                                                              "(machines, last calibration, verdict, next due; history)")
    view.add_argument("--db", help="with --catalog: the catalogue (as `rtcal catalog --db`; default $RTCAL_CATALOG)")
    view.add_argument("--live", metavar="[HOST:]PORT", help="where to serve (default 127.0.0.1:8765, or any free port; "
                                                           "PORT 0: any free port; another host than 127.0.0.1 is warned of)")
    view.set_defaults(func=cmd_live)


def _step(text: str) -> int:
    """--step: a positive integer, or argparse's own one-line error (exit 2)."""
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"{text!r} is not an operator step (a number from 1)")
    return int(text)


def add_control(sub: Any) -> None:
    from rtcal.live.control import COMMANDS

    ctl = sub.add_parser("control", help="pause, resume or abort the run in progress in a run directory, or confirm "
                                         "the operator step it waits for (needs its control token)")
    ctl.add_argument("run_dir", help="the run directory of a run in progress")
    ctl.add_argument("action", choices=COMMANDS, help="what to ask of the run's engine")
    ctl.add_argument("--step", type=_step, metavar="N",
                     help="with confirm: only if operator step N waits (the number the live page and the run's "
                          "console show), so a late confirm never answers the next step")
    ctl.add_argument("--token", help="the control token the run printed (or the environment variable "
                                     "RTCAL_CONTROL_TOKEN, which other users cannot see in the process list)")
    ctl.set_defaults(func=cmd_live)
