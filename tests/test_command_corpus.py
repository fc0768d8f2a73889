"""Hostile invocations of every command other than run/validate: each exits 2 with one line
that names where the mistake is (or 1, with the reason, for a damaged store or a full disk),
within 30 s, never a traceback.

The cases are run in process (one `main` call each, against one set of prepared files and run
directories); a handful also through `python -m rtcal.cli` to see what a shell sees. Each case
is (arguments, exit status, a text the message must hold): the text names the path or option at
fault, so a message that does not say where fails the test.
"""

from __future__ import annotations

import errno
import os
import shutil
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rtcal.cli import main
from rtcal.deliverables.deviations import MAX_CSV_BYTES

FANUC = ["--detection-unit-deg", "0.0001", "--first-point", "0"]  # a FANUC table has no default for either (issue 46)

REPO = Path(__file__).resolve().parents[1]
ABBE = REPO / "procedures" / "encoder_abbe_error.yaml"
TRACER = REPO / "procedures" / "laser_tracer_multistation.yaml"
SMALL = REPO / "tests" / "data" / "small_multistation.yaml"
HEADER = "target_deg,direction,run,deviation_arcsec,uncertainty_arcsec\n"
SECONDS = 30.0

# name: (arguments, exit status, text the message holds); {w} is the prepared folder
CASES: dict[str, tuple[list[str], int, str]] = {
    # evaluate: what a deviation table can be instead
    "evaluate_missing": (["evaluate", "{w}/nothing.csv"], 2, "{w}/nothing.csv: cannot read"),
    "evaluate_empty": (["evaluate", "{w}/empty.csv"], 2, "{w}/empty.csv:1: empty file"),
    "evaluate_header_only": (["evaluate", "{w}/header_only.csv"], 2, "{w}/header_only.csv: no rows"),
    "evaluate_binary": (["evaluate", "{w}/garbage.csv"], 2, "{w}/garbage.csv:"),
    "evaluate_overflow": (["evaluate", "{w}/huge.csv"], 2, "{w}/huge.csv: row 1: deviation_arcsec 1e+200 lies beyond"),
    "evaluate_nan": (["evaluate", "{w}/nan.csv"], 2, "{w}/nan.csv:3: target, deviation and uncertainty must be finite"),
    "evaluate_far_target": (["evaluate", "{w}/far_target.csv"], 2, "{w}/far_target.csv: row 2: target_deg"),
    "evaluate_direction": (["evaluate", "{w}/direction2.csv"], 2, "{w}/direction2.csv:2: direction must be 1"),
    "evaluate_duplicate": (["evaluate", "{w}/duplicate.csv"], 2, "{w}/duplicate.csv: target 0°, direction +1, run 1"),
    "evaluate_symlink_to_text": (["evaluate", "{w}/passwd.csv"], 2, "{w}/passwd.csv:1: header must name"),
    "evaluate_fifo": (["evaluate", "{w}/fifo.csv"], 2, "{w}/fifo.csv: cannot read: a device, pipe or socket"),
    "evaluate_device": (["evaluate", "/dev/zero"], 2, "/dev/zero: cannot read: a device, pipe or socket"),
    "evaluate_oversized": (["evaluate", "{w}/sparse.csv"], 2, f"{{w}}/sparse.csv: {MAX_CSV_BYTES + 1} bytes"),
    "evaluate_run_without_results": (["evaluate", "{w}/nostore"], 2, "{w}/nostore: not a run directory with a readable results.json"),
    "evaluate_results_is_a_folder": (["evaluate", "{w}/results_folder"], 2, "{w}/results_folder/results.json: not a regular file"),
    "evaluate_standard": (["evaluate", "{w}/good.csv", "--standard", "iso9999"], 2, "argument --standard: invalid choice"),
    # compensate: numbers and destinations
    "compensate_step_zero": (["compensate", "{w}/abbe", "--format", "fanuc", *FANUC, "--out", "{w}/c", "--step-deg", "0"], 2, "--step-deg 0"),
    "compensate_step_nan": (["compensate", "{w}/abbe", "--format", "fanuc", *FANUC, "--out", "{w}/c", "--step-deg", "nan"], 2, "--step-deg nan"),
    "compensate_step_uneven": (["compensate", "{w}/abbe", "--format", "fanuc", *FANUC, "--out", "{w}/c", "--step-deg", "7"], 2, "--step-deg 7"),
    "compensate_step_huge": (["compensate", "{w}/abbe", "--format", "fanuc", *FANUC, "--out", "{w}/c", "--step-deg", "1e308"], 2, "--step-deg 1e+308"),
    "compensate_step_text": (["compensate", "{w}/abbe", "--format", "fanuc", *FANUC, "--out", "{w}/c", "--step-deg", "x"], 2, "argument --step-deg"),
    "compensate_gap_nan": (["compensate", "{w}/abbe", "--format", "fanuc", *FANUC, "--out", "{w}/c", "--max-gap-deg", "nan"], 2, "--max-gap-deg nan"),
    "compensate_gap_negative": (["compensate", "{w}/abbe", "--format", "fanuc", *FANUC, "--out", "{w}/c", "--max-gap-deg", "-1"], 2, "--max-gap-deg -1"),
    "compensate_range_huge": (["compensate", "{w}/abbe", "--format", "linuxcnc", "--out", "{w}/c", "--range-deg", "0", "1e300"], 2, "--range-deg 0 1e+300"),
    "compensate_range_backwards": (["compensate", "{w}/abbe", "--format", "linuxcnc", "--out", "{w}/c", "--range-deg", "90", "0"], 2, "--range-deg 90 0"),
    "compensate_unit_zero": (["compensate", "{w}/abbe", "--format", "fanuc", "--first-point", "0", "--out", "{w}/c", "--detection-unit-deg", "0"], 2, "--detection-unit-deg 0"),
    "compensate_first_point": (["compensate", "{w}/abbe", "--format", "fanuc", "--detection-unit-deg", "0.0001", "--out", "{w}/c", "--first-point", "-5"], 2, "choose --first-point"),
    "compensate_axis_newline": (["compensate", "{w}/abbe", "--format", "siemens-lec", "--out", "{w}/c", "--axis", "C\n1"], 2, "--axis 'C\\n1'"),
    "compensate_out_folder": (["compensate", "{w}/abbe", "--format", "fanuc", *FANUC, "--out", "{w}/nostore"], 2, "{w}/nostore is a directory"),
    "compensate_out_nowhere": (["compensate", "{w}/abbe", "--format", "fanuc", *FANUC, "--out", "{w}/missing/c.txt"], 2, "{w}/missing: cannot write there"),
    "compensate_one_target": (["compensate", "{w}/one_target.csv", "--format", "fanuc", *FANUC, "--out", "{w}/c"], 2, "{w}/one_target.csv: the positive direction"),
    "compensate_format": (["compensate", "{w}/abbe", "--format", "mazak", "--out", "{w}/c"], 2, "argument --format: invalid choice"),
    # compare
    "compare_missing_a": (["compare", "{w}/nothing", "{w}/abbe", "--out", "{w}/o"], 2, "{w}/nothing: cannot read"),
    "compare_missing_b": (["compare", "{w}/abbe", "{w}/nothing", "--out", "{w}/o"], 2, "{w}/nothing: cannot read"),
    "compare_two_methods": (["compare", "{w}/abbe", "{w}/ms", "--out", "{w}/o"], 2, "{w}/abbe is a run of encoder_abbe_error, {w}/ms of laser_tracer_multistation"),
    "compare_nothing_shared": (["compare", "{w}/good.csv", "{w}/shifted.csv", "--out", "{w}/o"], 2, "share no target"),
    "compare_out_is_a_file": (["compare", "{w}/abbe", "{w}/abbe", "--out", "{w}/good.csv"], 2, "--out {w}/good.csv: exists and is not a directory"),
    "compare_out_under_a_file": (["compare", "{w}/abbe", "{w}/abbe", "--out", "{w}/good.csv/o"], 2, "--out {w}/good.csv/o: cannot create"),
    "compare_binary": (["compare", "{w}/garbage.csv", "{w}/abbe"], 2, "{w}/garbage.csv:"),
    "compare_fifo": (["compare", "{w}/abbe", "{w}/fifo.csv"], 2, "{w}/fifo.csv: cannot read"),
    # export
    "export_missing": (["export", "{w}/nothing"], 2, "{w}/nothing: not a run directory (no such directory)"),
    "export_a_file": (["export", "{w}/good.csv"], 2, "{w}/good.csv: not a run directory (not a directory)"),
    "export_no_store": (["export", "{w}/nostore"], 2, "{w}/nostore: not a run directory (no run.sqlite)"),
    "export_store_link": (["export", "{w}/store_link"], 2, "{w}/store_link/run.sqlite is not a regular file"),
    "export_store_folder": (["export", "{w}/store_folder"], 2, "{w}/store_folder/run.sqlite is not a regular file"),
    "export_store_empty": (["export", "{w}/store_empty"], 2, "{w}/store_empty/run.sqlite holds no procedure, no reading"),
    "export_store_garbage": (["export", "{w}/store_garbage", "--out", "{w}/xg"], 1, "{w}/store_garbage/run.sqlite is damaged"),
    "export_store_truncated": (["export", "{w}/truncated", "--out", "{w}/xt"], 1, "{w}/truncated/run.sqlite is damaged"),
    "export_out_is_a_file": (["export", "{w}/abbe", "--out", "{w}/good.csv"], 2, "--out {w}/good.csv: exists and is not a directory"),
    # resume
    "resume_missing": (["resume", "{w}/nothing"], 2, "{w}/nothing: no such directory; nothing to resume"),
    "resume_a_file": (["resume", "{w}/good.csv"], 2, "{w}/good.csv: not a directory; nothing to resume"),
    "resume_no_store": (["resume", "{w}/nostore"], 2, "{w}/nostore: not a run directory (no run.sqlite)"),
    "resume_store_link": (["resume", "{w}/store_link"], 2, "{w}/store_link/run.sqlite is not a regular file"),
    "resume_store_garbage": (["resume", "{w}/store_garbage"], 2, "{w}/store_garbage/run.sqlite is damaged"),
    "resume_store_truncated": (["resume", "{w}/truncated"], 2, "{w}/truncated/run.sqlite is damaged"),
    "resume_store_empty": (["resume", "{w}/store_empty"], 2, "start the run again with `rtcal run … --out {w}/store_empty`"),
    "resume_method_edited": (["resume", "{w}/edited_method"], 2, "{w}/edited_method/run.sqlite: its `method` is 'bogus'"),
    "resume_seed_edited": (["resume", "{w}/edited_seed"], 2, "{w}/edited_seed/run.sqlite: its `seed` is '-1'"),
    "resume_instruments_edited": (["resume", "{w}/edited_instruments"], 2, "{w}/edited_instruments/run.sqlite: its `instruments`"),
    "resume_rows_twice": (["resume", "{w}/rows_twice"], 2, "{w}/rows_twice/run.sqlite holds "),
    "resume_instruments_unknown": (["resume", "{w}/abbe", "--instruments", '{"stagee": "modbus-tcp://127.0.0.1:1"}'], 2, "--instruments:1:1: stagee: not an instrument rtcal knows; did you mean `stage`?"),
    "resume_instruments_not_json": (["resume", "{w}/abbe", "--instruments", "{stage"], 2, "--instruments: not a JSON object"),
    "resume_instruments_no_file": (["resume", "{w}/abbe", "--instruments", "{w}/nothing.json"], 2, "--instruments: {w}/nothing.json"),
    # uncertainty
    "uncertainty_seed_negative": (["uncertainty", str(ABBE), "--seed", "-1"], 2, "argument --seed: -1 is outside"),
    "uncertainty_seed_text": (["uncertainty", str(ABBE), "--seed", "abc"], 2, "argument --seed: 'abc' is not a whole number"),
    "uncertainty_workers_negative": (["uncertainty", str(ABBE), "--workers", "-1"], 2, "--workers -1: must lie in 1"),
    "uncertainty_workers_zero": (["uncertainty", str(ABBE), "--workers", "0"], 2, "--workers 0: must lie in 1"),
    "uncertainty_workers_beyond_cores": (["uncertainty", str(ABBE), "--workers", "4096"], 2, "--workers 4096: must lie in 1"),
    "uncertainty_workers_beyond_large": (["uncertainty", str(ABBE), "--workers", "100000", "--large"], 2, "--workers 100000: must lie in 1 … 256"),
    "uncertainty_scheduler_scheme": (["uncertainty", str(ABBE), "--scheduler", "foo://bar"], 2, "--scheduler 'foo://bar': expected"),
    "uncertainty_scheduler_port": (["uncertainty", str(ABBE), "--scheduler", "tcp://127.0.0.1"], 2, "--scheduler 'tcp://127.0.0.1': expected"),
    "uncertainty_scheduler_bad_port": (["uncertainty", str(ABBE), "--scheduler", "tcp://127.0.0.1:99999"], 2, "--scheduler 'tcp://127.0.0.1:99999'"),
    "uncertainty_trials_one": (["uncertainty", str(ABBE), "--trials", "1"], 2, "--trials must lie in 2..100000"),
    "uncertainty_trials_absurd": (["uncertainty", str(ABBE), "--trials", "1000000000"], 2, "--trials must lie in 2..100000"),
    "uncertainty_procedure_missing": (["uncertainty", "{w}/nothing.yaml"], 2, "{w}/nothing.yaml:1:1: (file): cannot read"),
    "uncertainty_procedure_folder": (["uncertainty", "{w}/nostore"], 2, "{w}/nostore:1:1: (file): cannot read: a directory"),
    "uncertainty_procedure_binary": (["uncertainty", "{w}/garbage.csv"], 2, "{w}/garbage.csv:2:118: (file): not UTF-8 text"),
    "uncertainty_out_is_a_file": (["uncertainty", str(ABBE), "--trials", "2", "--workers", "1", "--out", "{w}/good.csv"], 2, "--out {w}/good.csv: exists and is not a directory"),
    # plan
    "plan_missing": (["plan", "{w}/nothing.yaml"], 2, "{w}/nothing.yaml:1:1: (file): cannot read"),
    "plan_empty": (["plan", "{w}/empty.csv"], 2, "{w}/empty.csv:"),
    "plan_scenario_missing": (["plan", str(ABBE), "--scenario", "{w}/nothing.yaml"], 2, "{w}/nothing.yaml:1:1: (file): cannot read"),
    "plan_optimize_wrong_method": (["plan", str(ABBE), "--optimize", "{w}/o.yaml"], 2, f"--optimize: {ABBE} is a procedure of encoder_abbe_error"),
    "plan_optimize_itself": (["plan", "{w}/tracer.yaml", "--optimize", "{w}/tracer.yaml"], 2, "--optimize {w}/tracer.yaml: that is the procedure itself"),
    "plan_optimize_and_json": (["plan", str(TRACER), "--json", "--optimize", "{w}/o.yaml"], 2, "--json and --optimize: choose one"),
    # solve, schema, sim serve
    "solve_missing": (["solve", "stations", "{w}/nothing.csv", "--step-deg", "30"], 2, "{w}/nothing.csv:1:1: (file): cannot read"),
    "solve_binary": (["solve", "stations", "{w}/garbage.csv", "--step-deg", "30"], 2, "{w}/garbage.csv: not UTF-8 text"),
    "solve_three_stations": (["solve", "stations", "{w}/stations3.csv", "--step-deg", "30"], 2, "{w}/stations3.csv: 3 stations"),
    "solve_nan_station": (["solve", "stations", "{w}/stations_nan.csv", "--step-deg", "30"], 2, "{w}/stations_nan.csv:3: X, Y and Z must be finite"),
    "solve_step_nan": (["solve", "stations", "{w}/stations.csv", "--step-deg", "nan"], 2, "--step-deg must lie in (0, 180)"),
    "solve_first_huge": (["solve", "stations", "{w}/stations.csv", "--step-deg", "30", "--first-deg", "1e308"], 2, "--first-deg must be finite"),
    "solve_step_missing": (["solve", "stations", "{w}/stations.csv"], 2, "the following arguments are required: --step-deg"),
    "schema_unknown_option": (["schema", "--bench"], 2, "unrecognized arguments: --bench"),
    "schema_extra_argument": (["schema", "procedure.yaml"], 2, "unrecognized arguments: procedure.yaml"),
    "sim_serve_scenario_missing": (["sim", "serve", "--scenario", "{w}/nothing.yaml"], 2, "{w}/nothing.yaml:1:1: (file): cannot read"),
    "sim_serve_scenario_is_procedure": (["sim", "serve", "--scenario", str(ABBE)], 2, f"{ABBE}:"),
    "sim_serve_seed": (["sim", "serve", "--seed", "-3"], 2, "argument --seed: -3 is outside"),
    "sim_serve_serial": (["sim", "serve", "--serial", "usb"], 2, "argument --serial: invalid choice"),
}


def _csv(rows: list[str]) -> str:
    return HEADER + "".join(r + "\n" for r in rows)


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> Path:
    """Two finished runs, and every kind of file and run directory the cases name."""
    w = tmp_path_factory.mktemp("hostile")
    assert main(["run", str(ABBE), "--out", str(w / "abbe")]) == 0
    assert main(["run", str(SMALL), "--out", str(w / "ms")]) == 0
    good = [f"{t},{d},{r},{0.5 * d + t / 100:.3f},0.1" for t in (0, 90, 180, 270) for d in (1, -1) for r in (1, 2)]
    files = {
        "good.csv": _csv(good), "shifted.csv": _csv([r.replace("0,", "5,", 1) for r in good[:1]] + ["45,1,1,0,0.1"]),
        "empty.csv": "", "header_only.csv": HEADER, "huge.csv": _csv(["0,1,1,1e200,0.1", "90,1,1,-1e200,0.1"]),
        "nan.csv": _csv(["0,1,1,0,0.1", "90,1,1,nan,0.1"]), "far_target.csv": _csv(["0,1,1,0,0.1", "1e9,1,1,0,0.1"]),
        "direction2.csv": _csv(["0,2,1,0,0.1"]), "duplicate.csv": _csv(["0,1,1,0,0.1", "0,1,1,0.5,0.1"]),
        "one_target.csv": _csv(["0,1,1,0,0.1", "0,1,2,0.2,0.1"]),
        "stations.csv": "X,Y,Z\n" + "".join(f"{x},{y},0\n" for x, y in ((65, 0), (0, 65), (-65, 0), (0, -65))),
        "stations3.csv": "X,Y,Z\n1,0,0\n0,1,0\n-1,0,0\n", "stations_nan.csv": "X,Y,Z\n1,0,0\nnan,1,0\n",
    }
    for name, text in files.items():
        (w / name).write_text(text, encoding="utf-8")
    (w / "garbage.csv").write_bytes(bytes(range(256)) * 8)
    (w / "passwd.csv").symlink_to(w / "stations.csv")  # a link to a file of another kind
    os.mkfifo(w / "fifo.csv")
    with (w / "sparse.csv").open("wb") as fh:  # larger than any deviation table is read, yet takes no disk
        fh.truncate(MAX_CSV_BYTES + 1)
    shutil.copy(TRACER, w / "tracer.yaml")
    shutil.copytree(REPO / "procedures" / "scenarios", w / "scenarios")
    (w / "nostore").mkdir()
    (w / "results_folder" / "results.json").mkdir(parents=True)
    (w / "store_link").mkdir()
    (w / "store_link" / "run.sqlite").symlink_to(w / "abbe" / "run.sqlite")
    (w / "store_folder" / "run.sqlite").mkdir(parents=True)
    (w / "store_empty").mkdir()
    (w / "store_empty" / "run.sqlite").write_bytes(b"")
    (w / "store_garbage").mkdir()
    (w / "store_garbage" / "run.sqlite").write_bytes(os.urandom(9000))
    store = w / "abbe" / "run.sqlite"
    for name, sql in (("truncated", None), ("edited_method", "UPDATE meta SET value = 'bogus' WHERE key = 'method'"),
                      ("edited_seed", "UPDATE meta SET value = '-1' WHERE key = 'seed'"),
                      ("edited_instruments", "UPDATE meta SET value = '{\"stage\": 5}' WHERE key = 'instruments'"),
                      ("rows_twice", "INSERT INTO readings SELECT NULL, t_s, instrument, quantity, value, unit, point, "
                                     "station, sample, segment, commanded_angle_deg, commanded_x_mm, commanded_y_mm, "
                                     "commanded_z_mm, seating, run, direction, plan_index, attempt, context FROM readings")):
        (w / name).mkdir()
        shutil.copy(store, w / name / "run.sqlite")
        if sql is None:
            os.truncate(w / name / "run.sqlite", store.stat().st_size * 2 // 3)
        else:
            with sqlite3.connect(w / name / "run.sqlite") as db:
                db.execute(sql)
    return w


def _fill(w: Path, args: list[str]) -> list[str]:
    return [a.replace("{w}", str(w)) for a in args]


def _invoke(argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as exc:  # argparse's own mistakes
        return int(exc.code)


def test_corpus_is_large_and_covers_every_command():
    assert len(CASES) >= 60
    commands = {args[0] for args, _, _ in CASES.values()}
    assert commands >= {"evaluate", "compensate", "compare", "export", "resume", "uncertainty", "plan", "solve", "schema", "sim"}


@pytest.mark.parametrize("name", sorted(CASES))
def test_hostile_invocation_is_refused_where_it_is_wrong(world, name, capsys):
    args, code, text = CASES[name]
    started = time.monotonic()
    got = _invoke(_fill(world, args))
    seconds = time.monotonic() - started
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert got == code, (got, err)
    assert "Traceback" not in err and seconds < SECONDS, (seconds, err)
    assert text.replace("{w}", str(world)) in lines[0], lines
    if code == 2:
        assert len(lines) == 1, lines  # one line: what and where


def test_a_damaged_store_is_salvaged_not_touched(world):
    """The damaged stores the corpus exported and resumed are byte for byte what they were."""
    assert (world / "truncated" / "run.sqlite").stat().st_size == (world / "abbe" / "run.sqlite").stat().st_size * 2 // 3
    assert not any(p.name.endswith(("-wal", "-shm")) for p in (world / "truncated").iterdir())


@pytest.mark.parametrize("command", ["export", "compensate", "compare", "uncertainty"])
def test_a_full_disk_is_a_failure_not_a_mistake(world, command, capsys, monkeypatch):
    """ENOSPC while writing a command's file: exit 1, one line saying the disk refused, no traceback."""
    import rtcal.outputs

    def full(*_, **__):
        raise OSError(errno.ENOSPC, "No space left on device")

    argv = {"export": ["export", "{w}/abbe", "--out", "{w}/full"],
            "compensate": ["compensate", "{w}/abbe", "--format", "fanuc", *FANUC, "--out", "{w}/full.txt"],
            "compare": ["compare", "{w}/abbe", "{w}/abbe", "--out", "{w}/full"],
            "uncertainty": ["uncertainty", str(ABBE), "--trials", "2", "--workers", "1", "--out", "{w}/full"]}[command]
    if command == "uncertainty":  # the trials themselves write their stores where the disk is not full
        import rtcal.planning.montecarlo as mc

        monkeypatch.setattr(mc, "run_trials", lambda specs, *_: iter([_fake_trial(k) for k in range(len(specs))]))
    monkeypatch.setattr(rtcal.outputs.tempfile, "mkdtemp", full)
    assert _invoke(_fill(world, argv)) == 1
    err = capsys.readouterr().err
    assert "rtcal: the disk refused a write" in err and "No space left on device" in err and "Traceback" not in err, err


def _fake_trial(k: int) -> dict:
    return {"index": k, "recommended": "abbe", "labels": ["0", "15"],
            "per_estimator": {"abbe": {"error": [0.0, 0.1 * k], "u": [0.0, 0.2], "status": "converged"}}}


SHELL = ["evaluate_device", "export_store_truncated", "uncertainty_seed_negative"]


def test_through_the_shell(world):
    """A handful through `python -m rtcal.cli`, in a process limited to 2 GB, plus `sim serve` on a
    host that cannot be bound: the same exit statuses, no traceback."""
    import resource

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))

    runs = [(name, _fill(world, CASES[name][0]), CASES[name][1]) for name in SHELL]
    runs.append(("sim_serve_host", ["sim", "serve", "--host", "no-such-host.invalid"], 2))
    for name, argv, code in runs:
        done = subprocess.run([sys.executable, "-m", "rtcal.cli", *argv], capture_output=True, text=True, timeout=SECONDS,
                              preexec_fn=limit, cwd=world)
        assert done.returncode == code and "Traceback" not in done.stderr, (name, done.returncode, done.stderr[-500:])
