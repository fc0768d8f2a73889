"""The one `rtcal resume` hint every message prints: a command that works as printed for that run.

A wired run's simulated operator (and any address with a ``token=``) is stored with its token
redacted, so a bare `rtcal resume RUN` of such a run is refused; the hint names ``--instruments``
as the user gave it — the file by its name, inline JSON as typed, or, where that JSON holds a token,
the placeholder ADDRESSES (a token is printed nowhere). The clock needs no flag: `resume` goes on
on the clock kind stored with the run.
"""

from __future__ import annotations

import os
import shlex
import sqlite3
from contextlib import closing
from pathlib import Path

from drivers.addresses import REDACTED, redact_tokens

OPERATOR_TOKEN_ENV = "RTCAL_OPERATOR_TOKEN"
"""Where `resume` finds the simulated operator's token when --instruments does not give it."""

STORE_FILENAME = "run.sqlite"  # RunStore.FILENAME (store.py imports this module)
PLACEHOLDER = "ADDRESSES"
PLACEHOLDER_NOTE = (f"{PLACEHOLDER}: the simulator's addresses, the JSON `rtcal sim serve` printed or the file it went to")


def _needs_addresses(run_dir: Path) -> bool:
    """Whether the stored run lacks a token `resume` needs: an address stored redacted whose token
    neither the environment (the operator's) nor anything else gives back. Read-only; False when the
    store cannot be read (the resume then says what is wrong with it)."""
    path = run_dir / STORE_FILENAME
    if not path.is_file():
        return False
    try:
        with closing(sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=0.5)) as db:
            meta = dict(db.execute("SELECT key, value FROM meta WHERE key IN ('operator_address', 'instruments')"))
    except sqlite3.Error:
        return False
    redacted = f"token={REDACTED}"
    operator = redacted in meta.get("operator_address", "") and not os.environ.get(OPERATOR_TOKEN_ENV)
    return operator or redacted in meta.get("instruments", "")


def resume_hint(run_dir: str | Path, instruments: str | None = None, *, instruments_failed: bool = False,
                needs_addresses: bool = False) -> str:
    """"`rtcal resume RUN_DIR [--instruments …]` goes on" for the run in ``run_dir``.

    ``instruments``: the ``--instruments`` text this command was given (None: none); without it the
    store says whether addresses must be given again. ``instruments_failed``: the run stopped because an
    instrument stopped answering, so the command works once the instruments answer at those addresses
    again. ``needs_addresses``: the caller knows addresses must be given (a refused resume)."""
    command = f"rtcal resume {shlex.quote(str(run_dir))}"
    note = ""
    if instruments is not None and not needs_addresses:
        if not instruments.lstrip().startswith("{"):  # a file (what parse_instruments_option reads): named, never read here
            command += f" --instruments {shlex.quote(instruments)}"
            if instruments_failed:
                note = (f" once the instruments answer at the addresses in {instruments} again (a restarted "
                        f"`rtcal sim serve` prints new ones: write them to {instruments})")
        elif redact_tokens(instruments) == instruments:  # inline JSON without a token: as typed
            command += f" --instruments {shlex.quote(instruments)}"
            if instruments_failed:
                note = " once the instruments answer at those addresses again"
        else:
            command += f" --instruments {PLACEHOLDER}"
            note = f" ({PLACEHOLDER_NOTE})"
    elif needs_addresses or _needs_addresses(Path(run_dir)):
        command += f" --instruments {PLACEHOLDER}"
        note = f" ({PLACEHOLDER_NOTE})"
    return f"`{command}` goes on{note}"
