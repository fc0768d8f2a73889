"""The catalogue at a lab's scale (issues 33, 45): 10 000 synthetic entries (200 machines × 50
calibrations, each with two reference instruments from a pool of 20 polygons and 10 autocollimators)
added one transaction each, as `rtcal catalog add` does (the entry, its instruments, its audit row), to
SQLite and to a PostgreSQL server started here (Debian's postgresql package, fsync on); then a machine
axis's history, an instrument's `used-by` (all its ~500 calibrations, and those of the last year), and
`catalog verify` of the whole audit trail.

    PYTHONPATH=$PWD python benchmarks/bench_catalog.py [--machines 200] [--calibrations 50] [--queries 200]

Prints adds per second, the queries' median and worst times (goal: under 50 ms) and the verify time
(goal: under 1 s).
"""

from __future__ import annotations

import argparse
import hashlib
import random
import statistics
import sys
import tempfile
import time
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rtcal.catalog.schema import PARAMETERS, VDI  # noqa: E402
from rtcal.catalog.store import Catalog, dumps, now_utc  # noqa: E402
from tests.postgres_server import PostgresServer, binaries  # noqa: E402


def synthetic(machine: int, k: int, rng: random.Random) -> dict[str, Any]:
    """One entry: machine ``machine``'s k-th calibration (weekly, E drifting), a results.json of ~2 kB."""
    t = datetime(2020, 1, 1, tzinfo=timezone.utc) + timedelta(days=7 * k, hours=machine % 24)
    e = 20 + 0.5 * k + rng.gauss(0, 1)
    row: dict[str, Any] = {
        "run_id": hashlib.sha256(f"{machine}/{k}".encode()).hexdigest()[:32], "serial_number": f"SN-{machine:04d}",
        "axis": "C", "machine": f"bench machine {machine}", "customer": f"customer {machine % 17}", "method": "encoder_abbe_error",
        "measured_utc": t.isoformat(), "finished_utc": (t + timedelta(hours=2)).isoformat(),
        "certificate_number": f"C-{machine}-{k}", "verdict": "pass", "location_errors": "{}",
        "digests": dumps({"readings_sha256": "0" * 64}), "run_dir": f"/runs/{machine}/{k}", "added_utc": now_utc(),
        "results": (text := dumps({"deviations": [rng.gauss(0, 5) for _ in range(100)]})),
        "results_sha256": hashlib.sha256(text.encode()).hexdigest(), "certificate_key": f"C-{machine}-{k}",
        "test": "ISO 230-2 positioning test", "site": f"site {machine % 3}",
        "instruments": [{"role": role, "instrument_id": f"{role} SN {machine % pool}", "kind": role,
                         "certificate_number": f"K-{role}-{machine % pool}", "issuer": "PTB", "due": "2030-01-01",
                         "correction": "from its certificate"} for role, pool in (("polygon", 20), ("autocollimator", 10))],
    }
    for p in PARAMETERS:
        row[f"{p}_arcsec"], row[f"{p}_U_arcsec"], row[f"{p}_limit_arcsec"] = e, 0.6, 60.0
    for p in VDI:
        row[f"vdi_{p}_arcsec"] = e
    return row


def bench(label: str, location: str, machines: int, calibrations: int, queries: int) -> None:
    rng = random.Random(1)
    rows = [synthetic(m, k, rng) for k in range(calibrations) for m in range(machines)]
    with Catalog(location, write=True) as cat:
        t0 = time.perf_counter()
        for row in rows:
            cat.add(row)
        adds_s = time.perf_counter() - t0
    with Catalog(location) as cat:  # read as `catalog history` reads: nothing written
        assert cat.count() == len(rows)
        times_ms = []
        for _ in range(queries):
            sn = f"SN-{rng.randrange(machines):04d}"
            t0 = time.perf_counter()
            history = cat.history(sn, "C")
            times_ms.append(1000 * (time.perf_counter() - t0))
            assert len(history) == calibrations
        used_ms, recent_ms, used_rows = [], [], 0
        since = (datetime(2020, 1, 1, tzinfo=timezone.utc) + timedelta(days=7 * (calibrations - 10))).date().isoformat()
        for _ in range(queries):
            instrument = f"polygon SN {rng.randrange(20)}"
            t0 = time.perf_counter()
            used = cat.used_by(instrument)
            used_ms.append(1000 * (time.perf_counter() - t0))
            used_rows = len(used)
            t0 = time.perf_counter()
            cat.used_by(instrument, since)
            recent_ms.append(1000 * (time.perf_counter() - t0))
        t0, cpu0 = time.perf_counter(), time.process_time()
        found = cat.audit_check()
        verify_s, verify_cpu_s = time.perf_counter() - t0, time.process_time() - cpu0
        assert not found.problems and found.entries == len(rows), found.problems[:3]
    print(f"{label}: {len(rows)} entries added, {len(rows) / adds_s:.0f} adds/s (one transaction each, with instruments and "
          f"audit row); history of one axis ({calibrations} entries): median {statistics.median(times_ms):.1f} ms, worst "
          f"{max(times_ms):.1f} ms over {queries} queries (goal < 50 ms)")
    print(f"{label}: used-by of one polygon ({used_rows} calibrations): median {statistics.median(used_ms):.1f} ms, worst "
          f"{max(used_ms):.1f} ms; since {since}: median {statistics.median(recent_ms):.1f} ms, worst {max(recent_ms):.1f} ms "
          f"(goal < 50 ms)")
    print(f"{label}: catalog verify: {found.rows} audit rows chained and {found.entries} entries checked in {verify_s:.2f} s "
          f"({verify_cpu_s:.2f} s of this process's CPU; goal < 1 s)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--machines", type=int, default=200)
    ap.add_argument("--calibrations", type=int, default=50)
    ap.add_argument("--queries", type=int, default=200)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        bench("SQLite", str(Path(tmp) / "catalog.sqlite"), args.machines, args.calibrations, args.queries)
    if binaries() is None:
        print("PostgreSQL: not installed (Debian's postgresql package): skipped")
        return
    server = PostgresServer(fsync=True)
    server.start()
    try:
        bench("PostgreSQL", server.create_database("bench"), args.machines, args.calibrations, args.queries)
    finally:
        server.remove()


if __name__ == "__main__":
    main()
