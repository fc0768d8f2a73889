"""`rtcal compare` and `rtcal export` on real run directories."""

from __future__ import annotations

import csv
import json
import sqlite3
from pathlib import Path

import pytest

from rtcal.cli import main

REPO = Path(__file__).resolve().parents[1]
ABBE = REPO / "procedures" / "encoder_abbe_error.yaml"


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory) -> tuple[Path, Path]:
    base = tmp_path_factory.mktemp("runs")
    for seed in (1, 2):
        assert main(["run", str(ABBE), "--seed", str(seed), "--out", str(base / f"r{seed}")]) == 0
    return base / "r1", base / "r2"


def test_compare_same_stage_twice(two_runs, tmp_path, capsys):
    """The same simulated stage measured twice with fresh noise: the changes are noise, so at most a
    few of the 48 target values may exceed the combined U (k = 2 covers about 95 %: 2.4 expected;
    more than 10 would mean U too small)."""
    capsys.readouterr()
    assert main(["compare", str(two_runs[0]), str(two_runs[1]), "--out", str(tmp_path), "--json"]) == 0
    captured = capsys.readouterr()
    r = json.loads(captured.out)  # stdout is the JSON alone; the file written is named on stderr
    assert f"written: {tmp_path / 'compare.png'}" in captured.err
    assert r["targets_compared"] == 48 and r["targets_changed"] <= 10
    assert set(r["iso230_2"]) >= {"E", "B", "R", "A"} and (tmp_path / "compare.png").stat().st_size > 0
    row = r["per_target"][0]
    assert row["change_arcsec"] == pytest.approx(row["b_arcsec"] - row["a_arcsec"], abs=2e-4)


def test_compare_refuses_unrelated_input(tmp_path, capsys):
    a = tmp_path / "a.csv"
    a.write_text("target_deg,direction,run,deviation_arcsec\n0,1,1,0\n")
    b = tmp_path / "b.csv"
    b.write_text("target_deg,direction,run,deviation_arcsec\n90,1,1,0\n")
    assert main(["compare", str(a), str(b), "--out", str(tmp_path / "o")]) == 2
    assert "share no target" in capsys.readouterr().err


def test_export_writes_every_reading_and_event(two_runs, tmp_path, capsys):
    run = two_runs[0]
    assert main(["export", str(run), "--out", str(tmp_path)]) == 0
    said = capsys.readouterr().out
    assert all(str(tmp_path / name) in said for name in ("readings.csv", "events.csv", "descriptions.csv")), said
    db = sqlite3.connect(run / "run.sqlite")
    with (tmp_path / "readings.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == db.execute("SELECT COUNT(*) FROM readings").fetchone()[0]
    assert {r["instrument"] for r in rows} >= {"encoder", "autocollimator", "dial_indicator_1", "dial_indicator_2"}
    first = db.execute("SELECT value FROM readings ORDER BY id LIMIT 1").fetchone()[0]
    assert float(rows[0]["value"]) == first
    with (tmp_path / "events.csv").open() as fh:
        assert len(list(csv.DictReader(fh))) == db.execute("SELECT COUNT(*) FROM events").fetchone()[0]
    assert main(["export", str(tmp_path / "nothing")]) == 2
