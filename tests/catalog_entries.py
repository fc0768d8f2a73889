"""Synthetic catalogue entries (no run behind them) for the catalogue's tests and benchmarks: what
`rtcal catalog add` files, as Catalog.add takes it."""

from __future__ import annotations

import hashlib
from datetime import datetime, timedelta, timezone
from pathlib import Path


def synthetic(k: int, site: str = "", serial: str | None = None, days: float | None = None) -> dict:
    t = datetime(2020, 1, 1, tzinfo=timezone.utc) + timedelta(days=30 * k if days is None else days)
    row = {"run_id": hashlib.sha256(f"{serial}/{k}/{site}".encode()).hexdigest()[:32],
           "serial_number": serial or f"SN-{k % 5}", "axis": "C",
           "machine": "m", "customer": f"customer {k % 3}", "method": "encoder_abbe_error", "test": "ISO 230-2",
           "measured_utc": t.isoformat(), "finished_utc": t.isoformat(), "certificate_number": f"C-{serial}-{k}-{site}",
           "certificate_key": f"C-{serial}-{k}-{site}", "verdict": "pass", "location_errors": "{}", "digests": "{}",
           "run_dir": f"/runs/{k}", "added_utc": t.isoformat(), "results": "{}", "site": site,
           "results_sha256": hashlib.sha256(b"{}").hexdigest(),
           "instruments": [{"role": "polygon", "instrument_id": f"polygon {k % 2}", "kind": "polygon",
                            "certificate_number": "P", "issuer": "PTB", "due": "2030-01-01", "correction": "faces"}]}
    for p in ("E", "M", "B", "R", "A"):
        row[f"{p}_arcsec"], row[f"{p}_U_arcsec"], row[f"{p}_limit_arcsec"] = 20.0 + k, 1.0, 60.0
    for p in ("Pa", "P", "Ps_max", "U_max"):
        row[f"vdi_{p}_arcsec"] = 1.0
    return row


def rig_main(argv: list[str] | None = None) -> None:
    """One rig of the many-rigs test and benchmark: ``RIG N DB OUTBOX [PAUSE_S]``: N entries added as
    `rtcal catalog add` files them (kept in the outbox when the server is away), then the outbox sent
    until it is empty (at most 240 s); prints each add's outcome and "left K"."""
    import sys
    import time
    from pathlib import Path

    from rtcal.catalog.outbox import file_entry, pending, sync

    args = sys.argv[1:] if argv is None else argv
    rig, n, db, outbox = int(args[0]), int(args[1]), args[2], Path(args[3])
    pause_s = float(args[4]) if len(args) > 4 else 0.3
    for k in range(n):
        state, _ = file_entry(db, synthetic(k, site="s", serial=f"RIG-{rig}"), f"rig {rig}", "", outbox)
        print(state, flush=True)
        time.sleep(pause_s)
    deadline = time.monotonic() + 240
    while pending(outbox) and time.monotonic() < deadline:
        sync(db, outbox)
        time.sleep(0.5)
    print("left", len(pending(outbox)), flush=True)


def older_catalogue(path: Path, revision: str, rows: list[dict]) -> None:
    """A SQLite catalogue as an older rtcal left it: migrated to ``revision`` only, ``rows`` inserted with
    the columns that revision has (the rest of each row dropped)."""
    import sqlite3
    from contextlib import closing

    from alembic import command
    from alembic.config import Config
    from sqlalchemy import create_engine

    from rtcal.catalog.store import MIGRATIONS

    engine = create_engine(f"sqlite:///{path}")
    with engine.begin() as conn:
        cfg = Config()
        cfg.set_main_option("script_location", str(MIGRATIONS))
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, revision)
    engine.dispose()
    with closing(sqlite3.connect(path)) as conn, conn:
        columns = {r[1] for r in conn.execute("PRAGMA table_info(calibrations)")}
        for row in rows:
            kept = {c: v for c, v in row.items() if c in columns}
            conn.execute(f"INSERT INTO calibrations ({', '.join(kept)}) VALUES ({', '.join('?' * len(kept))})",
                         list(kept.values()))
