"""Waiting in tests for what another thread or process does: one poll loop, one store count."""

from __future__ import annotations

import sqlite3
import time
from pathlib import Path


def wait_for(predicate, timeout_s: float = 30.0, step_s: float = 0.05):
    """``predicate()``'s first truthy value, polled every ``step_s``; AssertionError after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(step_s)
    raise AssertionError(f"timed out after {timeout_s:g} s")


def stored_plan_indices(db: Path) -> int:
    """Planned readings a run's store holds now (read-only; 0 while it cannot be read yet)."""
    try:
        with sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=0.1) as c:
            return c.execute("SELECT COUNT(DISTINCT plan_index) FROM readings").fetchone()[0]
    except sqlite3.OperationalError:
        return 0
