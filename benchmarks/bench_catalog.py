"""The catalogue at a lab's scale (issue 33): 10 000 synthetic entries (200 machines × 50
calibrations) added one transaction each, as `rtcal catalog add` does, to SQLite and to a PostgreSQL
server started here (Debian's postgresql package, fsync on); then a machine axis's history query.

    PYTHONPATH=$PWD python benchmarks/bench_catalog.py [--machines 200] [--calibrations 50] [--queries 200]

Prints adds per second and the history query's median and worst time (goal: under 50 ms).
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
        "results": dumps({"deviations": [rng.gauss(0, 5) for _ in range(100)]}),
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
    print(f"{label}: {len(rows)} entries added, {len(rows) / adds_s:.0f} adds/s (one transaction each); history of one "
          f"axis ({calibrations} entries): median {statistics.median(times_ms):.1f} ms, worst {max(times_ms):.1f} ms "
          f"over {queries} queries (goal < 50 ms)")


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
