"""`rtcal view` and `rtcal control`: arguments in, one line and an exit code out (2 for a mistake,
1 when no engine answers), no traceback."""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path

from rtcal.live.control import COMMANDS, TOKEN_ENV, ControlRefused, NoEngine, send_control
from rtcal.live.server import LiveSpecError, parse_live_spec, serve_view
from rtcal.store.runstore import RunStore

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2


def _fail(message: str, code: int) -> int:
    print(f"rtcal: {message}", file=sys.stderr)
    return code


def view(run_dir: str, live: str | None) -> int:
    """Serve RUN_DIR's live view read-only until Ctrl-C or SIGTERM (exit 0)."""
    directory = Path(run_dir)
    if not directory.is_dir():
        return _fail(f"{run_dir}: no such run directory", EXIT_USAGE)
    if not (directory / RunStore.FILENAME).is_file():
        return _fail(f"{run_dir}: not a run directory (no {RunStore.FILENAME} in it)", EXIT_USAGE)
    try:
        host, port = parse_live_spec(live) if live is not None else ("127.0.0.1", None)
    except LiveSpecError as exc:
        return _fail(str(exc), EXIT_USAGE)

    def stop(*_: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, stop)
    try:
        return serve_view(directory, host, port)
    except OSError as exc:  # the port is taken, the host is not this computer's
        where = f"{host}:{port if port is not None else 'any port'}"
        return _fail(f"--live {where}: cannot listen there: {exc.strerror or exc}", EXIT_USAGE)
    except KeyboardInterrupt:
        return EXIT_OK


def control(run_dir: str, command: str, token: str | None, step: int | None = None) -> int:
    """Send pause, resume, abort or confirm to the engine of RUN_DIR: 0 accepted, 1 no engine, 2 refused
    (a wrong token; a confirm when no operator step waits)."""
    if command not in COMMANDS:
        return _fail(f"unknown command {command!r}: one of {', '.join(COMMANDS)}", EXIT_USAGE)
    token = token if token is not None else os.environ.get(TOKEN_ENV, "")  # a run without --live needs none
    if not Path(run_dir).is_dir():
        return _fail(f"{run_dir}: no such run directory", EXIT_USAGE)
    try:
        send_control(Path(run_dir), token, command, step=step)
    except NoEngine as exc:
        return _fail(str(exc), EXIT_FAILED)
    except ControlRefused as exc:
        if exc.reason == "token" and not token:
            return _fail(f"the run was started with --live: its control token is needed (--token TOKEN or the "
                         f"environment variable {TOKEN_ENV})", EXIT_USAGE)
        return _fail(str(exc), EXIT_USAGE if exc.reason in ("token", "command", "request", "nothing") else EXIT_FAILED)
    print(f"{command}: accepted by the engine of {run_dir}", file=sys.stderr)
    return EXIT_OK
