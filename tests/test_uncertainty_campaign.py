"""The uncertainty campaign (`pytest -m campaign`, about 15 min on 2 cores): on the shipped benches
and on benches made for this check (tests/data/mc: CMM point noise, CMM scale and squareness,
error motions within stated bounds, negative station-major runs with a poor stage, two tracer
mounts, seed 001 with repeated runs, closure, no environment sensor with the air drawn in its stated ranges),
200 simulated runs each, the systematic errors drawn balanced (`--balanced`: antithetic pairs whose second
moments match the stated ones exactly, so the draws add no sampling noise to the squared errors). Per
target, the reported 1σ of the recommended estimator must lie within 0.8–1.25× its RMS error against
truth: with 200 trials the RMS is known to ±5 % (1σ), so a correct budget passes every target with
room, and a budget 20 % off fails."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rtcal.cli import main

REPO = Path(__file__).resolve().parents[1]
MC = REPO / "tests" / "data" / "mc"
PROCEDURES = REPO / "procedures"

CASES = [
    ("shipped_seed000", PROCEDURES / "laser_tracer_multistation.yaml", None),
    ("shipped_seed001", PROCEDURES / "encoder_abbe_error.yaml", None),
    ("closure", PROCEDURES / "polygon_closure.yaml", None),
    ("length_noise", MC / "length_noise.yaml", None),
    ("point_noise", MC / "point_noise.yaml", None),
    ("cmm_geometry", MC / "cmm_geometry.yaml", None),
    ("error_motions", MC / "error_motions.yaml", None),
    ("station_major", MC / "station_major.yaml", None),
    ("second_mount", MC / "second_mount.yaml", None),
    ("abbe_runs", MC / "abbe_runs.yaml", PROCEDURES / "scenarios" / "abbe_bench.yaml"),
    ("air_drift", MC / "air_drift.yaml", None),
]


@pytest.mark.campaign
@pytest.mark.parametrize("name, procedure, scenario", CASES, ids=[c[0] for c in CASES])
def test_reported_sigma_matches_the_errors_per_target(tmp_path, name, procedure, scenario):
    out = tmp_path / name
    args = ["uncertainty", str(procedure), "--trials", "200", "--balanced", "--out", str(out)]
    assert main(args + (["--scenario", str(scenario)] if scenario else [])) == 0
    s = json.loads((out / "uncertainty.json").read_text())
    assert s["failed_trials"] == 0
    rec = s["estimators"][s["recommended"]]
    ratios = [r for r in rec["ratio"][1:] if r is not None]
    assert ratios and all(0.8 <= r <= 1.25 for r in ratios), (s["recommended"], rec["ratio"])
    for other, e in s["estimators"].items():  # every estimator honest, with more room for the weak one
        assert all(0.7 <= r <= 1.4 for r in e["ratio"][1:] if r is not None), (other, e["ratio"])
