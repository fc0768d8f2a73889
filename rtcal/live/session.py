"""What a run starts for remote control and, with ``--live``, for its live view — in one call, so
that every run keeps the contract of issue 24 the same way: a new token, the control socket in
the run directory, the web server if asked for, and with it the two lines on stderr before the
first motion (``live view: URL`` and ``control token: TOKEN``, printed once and written nowhere).
Without ``--live`` there is no token to print: the owner-only socket admits its user's `rtcal control`."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from rtcal.live.control import ControlServer, Controllable, new_token
from rtcal.live.server import FINISHED_LINGER_S, LiveServer


@dataclass
class LiveSession:
    """The control socket (always) and the live server (with ``--live``) of one running engine."""

    token: str | None
    control: ControlServer
    server: LiveServer | None = None

    @property
    def url(self) -> str | None:
        return self.server.url if self.server is not None else None

    def close(self) -> None:
        """Stop the web server (once every page has the run's end) and remove the control socket
        (call it however the run ends)."""
        try:
            if self.server is not None:
                self.server.stop(linger_s=FINISHED_LINGER_S)
        finally:
            self.control.close()

    def __enter__(self) -> "LiveSession":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def start_session(run_dir: Path, engine: Controllable, live: tuple[str, int] | None = None,
                  stream: TextIO | None = None) -> LiveSession:
    """Serve ``engine``'s control socket in ``run_dir`` and, if ``live`` (host, port) is given, the
    live view with control; print the lines the contract names on ``stream`` (stderr). Raises
    OSError if the port cannot be had (nothing is left running then)."""
    out = stream if stream is not None else sys.stderr
    token = new_token() if live is not None else None  # a token only where a page can be reached
    control = ControlServer(Path(run_dir), token, engine)
    control.start()
    server = None
    try:
        if live is not None and token is not None:
            server = LiveServer(Path(run_dir), live[0], live[1], engine, token)
            print(f"live view: {server.start()}", file=out, flush=True)
    except BaseException:
        control.close()
        raise
    if token is not None:
        print(f"control token: {token}", file=out, flush=True)
    return LiveSession(token, control, server)
