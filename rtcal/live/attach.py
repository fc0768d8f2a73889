"""Every run's remote control, and with ``--live`` its web page, attached to the run's engine.

Every run (in process or wired) serves its control socket in the run directory, so `rtcal control`
reaches it whether or not it was started with ``--live``. With ``--live`` the same process serves the
live view, whose Pause / Resume / Abort buttons (and Done, when an operator step waits) need the
run's control token: printed once on the console before the first motion, written nowhere else,
and only then (without ``--live`` the owner-only socket admits its user's processes alone).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Callable, TextIO

from rtcal.live.control import Controllable
from rtcal.live.server import parse_live_spec
from rtcal.live.session import start_session


class RunControl:
    """``on_engine`` for :func:`rtcal.run.runner.run_procedure` / ``resume_run``: starts the control socket
    (and the live view) when the engine exists, before anything moves; the closer it returns stops both."""

    def __init__(self, live: str | None = None, stream: TextIO | None = None):
        self.live = parse_live_spec(live) if live is not None else None  # LiveSpecError before anything starts
        self.stream = stream if stream is not None else sys.stderr
        self.url: str | None = None
        self.remote_operator = self.live is not None
        """With --live the run can be reached: an operator step without a terminal waits for a remote confirm."""

    def __call__(self, engine: Controllable, run_dir: Path) -> Callable[[], None]:
        session = start_session(run_dir, engine, self.live, self.stream)
        self.url = session.url
        return session.close
