"""Many rigs on one PostgreSQL that restarts (issue 45 item 6): RIGS processes each add ENTRIES
finished runs (synthetic entries, as `rtcal catalog add` files them: entry, instruments, audit row)
to one PostgreSQL server started here (fsync on) while it is stopped ("fast" or "immediate", at
random) and started again every few seconds; an add that cannot land waits in its rig's outbox and
the rig sends it (`rtcal catalog sync`'s function) until its outbox is empty.

    PYTHONPATH=$PWD python benchmarks/bench_rigs.py [--rigs 20] [--entries 50] [--seed 45]

Prints how many adds landed at once, waited in an outbox, the restarts, and what the catalogue holds
at the end: entries, distinct run ids, add rows of the audit trail, lost (expected − distinct),
duplicated (entries − distinct), and whether the trail verifies (goal: 0 lost, 0 duplicated).
"""

from __future__ import annotations

import argparse
import random
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from rtcal.catalog.schema import audit  # noqa: E402
from rtcal.catalog.store import Catalog  # noqa: E402
from tests.postgres_server import PostgresServer, binaries  # noqa: E402

RIG = "import sys; sys.path.insert(0, sys.argv[6]); from tests.catalog_entries import rig_main; rig_main(sys.argv[1:6])"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rigs", type=int, default=20)
    ap.add_argument("--entries", type=int, default=50)
    ap.add_argument("--seed", type=int, default=45)
    args = ap.parse_args()
    if binaries() is None:
        print("PostgreSQL: not installed (Debian's postgresql package): nothing to measure")
        return
    rng = random.Random(args.seed)
    server = PostgresServer(fsync=True)
    server.start()
    tmp = Path(tempfile.mkdtemp(prefix="rtcal-rigs-"))
    try:
        db = server.create_database("rigs")
        with Catalog(db, write=True):
            pass
        t0 = time.monotonic()
        procs = [subprocess.Popen([sys.executable, "-c", RIG, str(k), str(args.entries), db, str(tmp / f"outbox{k}"),
                                   str(rng.uniform(0.05, 0.3)), str(REPO)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  text=True, cwd=REPO) for k in range(args.rigs)]
        restarts = 0
        while any(p.poll() is None for p in procs):
            time.sleep(rng.uniform(2.0, 6.0))
            if not any(p.poll() is None for p in procs):
                break
            server.stop(rng.choice(["fast", "immediate"]))
            time.sleep(rng.uniform(0.2, 2.0))
            server.start()
            restarts += 1
        outs = [p.communicate() for p in procs]
        elapsed = time.monotonic() - t0
        states = [line for out, _ in outs for line in out.split("\n")]
        with Catalog(db) as cat:
            rows = cat.machines()
            adds = [a for a in cat.table(audit, "seq") if a["action"] == "add"]
            found = cat.audit_check()
        expected = args.rigs * args.entries
        distinct = len({r["run_id"] for r in rows})
        left = sum(int(line.split()[1]) for line in states if line.startswith("left"))
        failed = [err[-300:] for p, (_, err) in zip(procs, outs) if p.returncode != 0]
        print(f"{args.rigs} rigs × {args.entries} adds, PostgreSQL restarted {restarts} times in {elapsed:.0f} s: "
              f"{states.count('added')} landed at once, {states.count('waiting')} waited in an outbox and were sent later, "
              f"{states.count('already')} found there already; {left} still waiting; rigs failed: {len(failed)}")
        print(f"catalogue: {len(rows)} entries, {distinct} distinct run ids, {len(adds)} add rows in the audit trail; "
              f"lost {expected - distinct}, duplicated {len(rows) - distinct}; verify: "
              f"{'the chain and every entry agree' if not found.problems else found.problems[:3]}")
        for err in failed:
            print(f"rig error: {err}")
    finally:
        server.remove()


if __name__ == "__main__":
    main()
