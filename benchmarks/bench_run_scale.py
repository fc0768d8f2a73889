"""How the whole `rtcal run` grows with its readings (issue 43): the shipped seed-000 procedure with its CMM grid
and stations grown, each size in its own process, on the shipped bench.

    python benchmarks/bench_run_scale.py [--sizes 4,6,8,10,36x10] [--kill] [--store] [--methods]

Prints, per size, the planned lengths, the wall time, CPU time and peak memory of the process (os.wait4), the
time per length, the ratios to the shipped size (4³ points × 11 stations, 704 lengths), and the CPU time each
length added since the size before costs (the fixed cost of a run — imports, the report — apart). ``--kill``: the largest size
is also killed (SIGKILL) once half its lengths are stored, `rtcal resume`d and `rtcal verify`ed, each timed, and
every planned length checked present once. ``--store``: 36 000 readings written through the run store one
transaction each (as the engine commits them), its done set read back and its digest taken. ``--methods``: the
Abbe and ISO 230-2 procedures as shipped and with 5× their targets and runs. The machine's load average is
printed before and after: on a shared machine the figures move with it.

Goals (issue 43, 2 cores): 8³ × 11 ≤ 12× the shipped run's time and ≤ 600 MB; 36 stations × 10³ points exit 0
in ≤ 600 s and ≤ 2 GB; the time per length flat within 2× from 704 to 36 000 lengths.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHIPPED = REPO / "procedures" / "laser_tracer_multistation.yaml"
GRID = "layers: 4\n  columns: 4\n  rows: 4"
STATIONS = "  first_angle_deg: -145\n  step_deg: 30\n  count: 11"


def grown(folder: Path, k: int, stations: int) -> Path:
    """The shipped procedure with a k × k × k grid and ``stations`` stations (11: as shipped, else 360°/stations apart)."""
    text = SHIPPED.read_text(encoding="utf-8")
    assert GRID in text and STATIONS in text, "the shipped procedure's grid or stations changed: update this benchmark"
    text = text.replace(GRID, f"layers: {k}\n  columns: {k}\n  rows: {k}")
    if stations != 11:
        step = 360.0 / stations
        text = text.replace(STATIONS, f"  first_angle_deg: {-180 + step / 2:g}\n  step_deg: {step:g}\n  count: {stations}")
    path = folder / f"grid{k}x{stations}.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def child(args: list[str], env: dict[str, str] | None = None) -> tuple[int, float, float, float]:
    """(exit status, wall s, peak resident MB, CPU s: user + system) of `rtcal ARGS` in its own process."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "rtcal.cli", *args], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            env=env)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    if proc.stderr is not None:
        err = proc.stderr.read().decode(errors="replace")
        proc.stderr.close()
        if os.waitstatus_to_exitcode(status) not in (0, -signal.SIGKILL):
            print(err[-2000:], file=sys.stderr)
    return os.waitstatus_to_exitcode(status), wall, usage.ru_maxrss / 1024.0, usage.ru_utime + usage.ru_stime


def stored(db: Path) -> int:
    try:
        with sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1.0) as c:
            return int(c.execute("SELECT COUNT(DISTINCT plan_index) FROM readings").fetchone()[0])
    except sqlite3.Error:
        return 0


def load() -> str:
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.1f} {five:.1f} {fifteen:.1f} on {os.cpu_count()} CPUs"


def run_sizes(folder: Path, sizes: list[tuple[int, int]]) -> list[tuple[str, int, float, float, float]]:
    rows = []
    for k, m in sizes:
        procedure = grown(folder, k, m)
        lengths = k**3 * m
        code, wall, peak, cpu = child(["run", str(procedure), "--out", str(folder / f"run{k}x{m}")])
        rows.append((f"{k}³ × {m}", lengths, wall, peak, cpu))
        print(f"  {k}³ points × {m} stations: {lengths} lengths, exit {code}, {wall:.1f} s ({cpu:.1f} s CPU), {peak:.0f} MB, "
              f"{1e3 * wall / lengths:.2f} ms per length; {load()}", flush=True)
    return rows


def kill_and_resume(folder: Path, k: int, m: int) -> None:
    """SIGKILL at half the lengths, then resume and verify: every planned length present once."""
    procedure = grown(folder, k, m)
    run_dir = folder / f"killed{k}x{m}"
    db = run_dir / "run.sqlite"
    planned = k**3 * m
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "rtcal.cli", "run", str(procedure), "--out", str(run_dir)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    while proc.poll() is None and stored(db) < planned // 2:
        time.sleep(0.5)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    at_kill = stored(db)
    print(f"  killed after {time.perf_counter() - t0:.1f} s with {at_kill} of {planned} lengths stored", flush=True)
    code, wall, peak, cpu = child(["resume", str(run_dir)])
    with sqlite3.connect(db) as c:
        rows = c.execute("SELECT plan_index, COUNT(*) FROM readings WHERE instrument = 'laser_tracer' AND "
                         "plan_index IS NOT NULL AND quantity <> 'skipped' GROUP BY plan_index").fetchall()
    whole = sorted(i for i, _ in rows) == list(range(planned)) and all(n == 1 for _, n in rows)
    print(f"  rtcal resume: exit {code}, {wall:.1f} s ({cpu:.1f} s CPU), {peak:.0f} MB; every planned length present once: "
          f"{whole}", flush=True)
    code, wall, peak, cpu = child(["verify", str(run_dir)])
    print(f"  rtcal verify: exit {code}, {wall:.1f} s ({cpu:.1f} s CPU), {peak:.0f} MB", flush=True)


def store_alone(folder: Path, readings: int = 36000) -> None:
    """The run store at scale without instruments: one transaction per reading as the engine commits them (a
    simulation's: to the OS), the done set read back, the digest the results record."""
    sys.path.insert(0, str(REPO))
    from rtcal.run.integrity import digests_of
    from rtcal.store.runstore import Reading, RunStore

    run_dir = folder / "store"
    run_dir.mkdir()
    store = RunStore.create(run_dir, {"method": "laser_tracer_multistation"})
    store.sync_each_commit(to_disk=False)
    t0 = time.perf_counter()
    for k in range(readings):
        point, station = divmod(k, 36)
        store.add_readings([Reading(float(k), "laser_tracer", "length_mm", 1000.0 + k * 1e-3, "mm", point=point,
                                    station=station, segment=0, plan_index=k, attempt=store.new_attempt()),
                            Reading(float(k), "cmm", "position_x_mm", 700.0, "mm", point=point, station=station,
                                    plan_index=k, attempt=k)])
    written = time.perf_counter() - t0
    t0 = time.perf_counter()
    done = len(store.done_plan_indices())
    read = time.perf_counter() - t0
    t0 = time.perf_counter()
    digests_of(store)
    digest = time.perf_counter() - t0
    store.close()
    print(f"  {readings} readings written one transaction each in {written:.1f} s ({1e3 * written / readings:.2f} ms each); "
          f"done set read back ({done}) in {read:.2f} s; digest in {digest:.2f} s", flush=True)


def methods(folder: Path) -> None:
    """The Abbe and ISO 230-2 procedures as shipped and with 5× their targets and runs."""
    import yaml

    shutil.copytree(REPO / "procedures" / "scenarios", folder / "scenarios", dirs_exist_ok=True)
    # 5 × 12 ISO targets need a polygon of 60 faces: the shipped bench's with its face errors repeated (mean removed)
    bench = yaml.safe_load((folder / "scenarios" / "abbe_bench.yaml").read_text(encoding="utf-8"))
    errors = [bench["polygon"]["face_errors_arcsec"][k % 24] for k in range(60)]
    bench["polygon"].update(faces=60, face_errors_arcsec=[round(e - sum(errors) / 60, 6) for e in errors])
    (folder / "scenarios" / "abbe_bench_60.yaml").write_text(yaml.safe_dump(bench, sort_keys=False), encoding="utf-8")
    for name, grow in (("encoder_abbe_error", lambda d: d["steps"].update(steps_per_face=5 * d["steps"]["steps_per_face"],
                                                                            runs=5 * d["steps"]["runs"])),
                       ("iso230_2_polygon", lambda d: (d["steps"].update(targets_deg=[6 * k for k in range(60)],
                                                                         runs=5 * d["steps"]["runs"]),
                                                       d["polygon"].update(faces=60),
                                                       d.update(bench="scenarios/abbe_bench_60.yaml")))):
        data = yaml.safe_load((REPO / "procedures" / f"{name}.yaml").read_text(encoding="utf-8"))
        shipped = folder / f"{name}.yaml"
        shipped.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True), encoding="utf-8")
        grow(data)
        big = folder / f"{name}_5x.yaml"
        big.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True), encoding="utf-8")
        results = []
        for label, path in (("as shipped", shipped), ("5× targets and runs", big)):
            code, wall, peak, cpu = child(["run", str(path), "--out", str(folder / f"{path.stem}-run")])
            db = folder / f"{path.stem}-run" / "run.sqlite"
            n = stored(db)
            results.append((n, wall, cpu))
            print(f"  {name} {label}: {n} planned readings, exit {code}, {wall:.1f} s ({cpu:.1f} s CPU), {peak:.0f} MB, "
                  f"{1e3 * wall / max(n, 1):.1f} ms per reading", flush=True)
        (n0, w0, c0), (n1, w1, c1) = results
        print(f"  {name}: {n1 / n0:.0f}× the readings in {w1 / w0:.1f}× the time, {c1 / c0:.1f}× the CPU (per reading "
              f"{w1 / n1 / (w0 / n0):.2f}× the time, {c1 / n1 / (c0 / n0):.2f}× the CPU)", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="4,6,8,10,36x10",
                        help="grids k (k³ points, 11 stations) or MxK (M stations, K³ points), comma-separated")
    parser.add_argument("--kill", action="store_true", help="kill the largest size at half, resume and verify it")
    parser.add_argument("--store", action="store_true", help="the run store alone at 36 000 readings")
    parser.add_argument("--methods", action="store_true", help="the Abbe and ISO procedures as shipped and at 5×")
    args = parser.parse_args()
    print(load(), flush=True)
    with tempfile.TemporaryDirectory(prefix="bench-scale-") as tmp:
        folder = Path(tmp)
        shutil.copytree(REPO / "procedures" / "scenarios", folder / "scenarios")
        sizes = [((int(p.split("x")[1]), int(p.split("x")[0])) if "x" in p else (int(p), 11)) for p in args.sizes.split(",")]
        rows = run_sizes(folder, sizes)
        if rows:
            base = next((r for r in rows if r[1] == 704), rows[0])
            print("\n| grid × stations | lengths | wall s | × shipped | CPU s | peak MB | ms per length | × shipped per length "
                  "| CPU ms per added length |")
            print("|---|---|---|---|---|---|---|---|---|")
            previous = None
            for label, n, wall, peak, cpu in rows:
                added = "" if previous is None else f"{1e3 * (cpu - previous[1]) / (n - previous[0]):.2f}"
                print(f"| {label} | {n} | {wall:.1f} | {wall / base[2]:.1f} | {cpu:.1f} | {peak:.0f} | {1e3 * wall / n:.2f} | "
                      f"{(wall / n) / (base[2] / base[1]):.2f} | {added} |", flush=True)
                previous = (n, cpu)
        if args.kill:
            k, m = sizes[-1]
            print(f"\nkilled at half and resumed: {k}³ points × {m} stations", flush=True)
            kill_and_resume(folder, k, m)
        if args.store:
            print("\nthe run store alone", flush=True)
            store_alone(folder)
        if args.methods:
            print("\nthe other methods", flush=True)
            methods(folder)
    print(load(), flush=True)


if __name__ == "__main__":
    main()
