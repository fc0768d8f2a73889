"""ISO 230-2 and VDI 3441 evaluation: a hand-worked dataset, a regression test for each of the
four errors of a published evaluator, and agreement with an independent implementation."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rtcal.cli import main
from rtcal.deviations import PositioningDeviations
from rtcal.evaluation import evaluate


def _table(rows: list[tuple[float, int, int, float]]) -> PositioningDeviations:
    a = np.array(rows, float)
    return PositioningDeviations(a[:, 0], a[:, 1].astype(int), a[:, 2].astype(int), a[:, 3], np.full(len(a), np.nan))


# Three targets, three runs each way (arcsec):
#   target   0: ↑ 1, 2, 3  (x̄↑ = 2,  s↑ = 1)   ↓ −1, 0, 1  (x̄↓ = 0,  s↓ = 1)
#   target  90: ↑ 4, 4, 4  (x̄↑ = 4,  s↑ = 0)   ↓  2, 3, 4  (x̄↓ = 3,  s↓ = 1)
#   target 180: ↑ −2, −1, 0 (x̄↑ = −1, s↑ = 1)  ↓ −5, −3, −1 (x̄↓ = −3, s↓ = 2)
HAND = _table([(t, d, r + 1, x) for t, d, xs in (
    (0, 1, (1, 2, 3)), (0, -1, (-1, 0, 1)), (90, 1, (4, 4, 4)), (90, -1, (2, 3, 4)), (180, 1, (-2, -1, 0)), (180, -1, (-5, -3, -1)))
    for r, x in enumerate(xs)])


def test_iso230_2_by_hand():
    r = evaluate(HAND, "iso230-2")
    # B_i = x̄↑ − x̄↓ = 2, 1, 2 → B = max|B_i| = 2, B̄ = 5/3
    # x̄_i = (x̄↑ + x̄↓)/2 = 1, 3.5, −2 → M = 3.5 − (−2) = 5.5
    # E↑ = 4 − (−1) = 5; E↓ = 3 − (−3) = 6; E = max(2, 4, −1, 0, 3, −3) − min(…) = 4 − (−3) = 7
    # R↑_i = 4s↑ = 4, 0, 4 → R↑ = 4; R↓_i = 4, 4, 8 → R↓ = 8
    # R_i = max(2s↑ + 2s↓ + |B_i|, R↑_i, R↓_i) = max(6,4,4), max(3,0,4), max(8,4,8) = 6, 4, 8 → R = 8
    # A↑ = max(x̄↑ + 2s↑) − min(x̄↑ − 2s↑) = max(4, 4, 1) − min(0, 4, −3) = 7
    # A↓ = max(2, 5, 1) − min(−2, 1, −7) = 12; A = max(4, 4, 1, 2, 5, 1) − min(0, 4, −3, −2, 1, −7) = 12
    expected = {"B": 2, "B_mean": 5 / 3, "M": 5.5, "E_up": 5, "E_down": 6, "E": 7, "R_up": 4, "R_down": 8, "R": 8,
                "A_up": 7, "A_down": 12, "A": 12}
    for key, value in expected.items():
        assert r[key] == pytest.approx(value, abs=1e-4), key
    assert [p["B_i"] for p in r["per_target"]] == [2, 1, 2]


def test_iso230_2_1988_by_hand():
    """The 1988 edition: ±3s in A, 6s in R.
    R↑_i = 6, 0, 6 → 6; R↓_i = 6, 6, 12 → 12; R_i = max(3+3+2, 6, 6), max(0+3+1, 0, 6), max(3+6+2, 6, 12) = 8, 6, 12
    A↑ = max(5, 4, 2) − min(−1, 4, −4) = 9; A↓ = max(3, 6, 3) − min(−3, 0, −9) = 15; A = 6 − (−9) = 15."""
    r = evaluate(HAND, "iso230-2:1988")
    for key, value in {"R_up": 6, "R_down": 12, "R": 12, "A_up": 9, "A_down": 15, "A": 15, "E": 7, "B": 2}.items():
        assert r[key] == pytest.approx(value, abs=1e-4), key
    assert any("not confirmed" in n for n in r["notes"])


def test_vdi3441_by_hand():
    """U_j = |x̄↑ − x̄↓| = 2, 1, 2; Ps_j = 6·(s↑ + s↓)/2 = 6, 3, 9; x̄ = 1, 3.5, −2 → Pa = 5.5;
    P = max(x̄ + (U + Ps)/2) − min(x̄ − (U + Ps)/2) = max(5, 5.5, 3.5) − min(−3, 1.5, −7.5) = 13."""
    r = evaluate(HAND, "vdi3441")
    for key, value in {"Pa": 5.5, "P": 13, "Ps_max": 9, "Ps_mean": 6, "U_max": 2, "U_mean": 5 / 3}.items():
        assert r[key] == pytest.approx(value, abs=1e-4), key


def test_regression_mean_divides_by_the_approaches_not_the_targets():
    """Four targets, three approaches each way: dividing Σx by the number of targets (4) would give
    x̄↑ = 4.5 at target 0 instead of 6."""
    rows = [(t, d, r, 6.0 + r * 0.0 + (t / 90.0) * d) for t in (0, 90, 180, 270) for d in (1, -1) for r in (1, 2, 3)]
    per = evaluate(_table(rows), "iso230-2")["per_target"]
    assert [p["mean_up"] for p in per] == [6.0, 7.0, 8.0, 9.0]


def test_regression_up_minus_down():
    """B_i = x̄↑ − x̄↓ (+2, +1, +2 here): swapping the directions flips B̄ to −5/3."""
    r = evaluate(HAND, "iso230-2")
    assert r["B_mean"] == pytest.approx(5 / 3, abs=1e-4)
    assert all(p["B_i"] > 0 for p in r["per_target"])


def test_regression_minimum_in_e():
    """The smallest mean (−3, target 180 ↓) is the last: a minimum taken with the wrong comparison
    (or never updated) gives E = 0 or E = 2 instead of 7."""
    assert evaluate(HAND, "iso230-2")["E"] == pytest.approx(7)


def test_regression_r_is_bidirectional():
    """R = max R_i = 8 here, where R↑ = 4: reporting R↑ as R is caught."""
    r = evaluate(HAND, "iso230-2")
    assert r["R"] == pytest.approx(8) and r["R_up"] == pytest.approx(4)


def test_one_direction_and_one_run():
    one_dir = evaluate(_table([row for row in zip(HAND.target_deg, HAND.direction, HAND.run, HAND.deviation_arcsec) if row[1] > 0]))
    assert one_dir["E_up"] == pytest.approx(5) and one_dir["E"] is None and one_dir["B"] is None and one_dir["A"] is None
    assert any("one direction" in n for n in one_dir["notes"])
    one_run = evaluate(_table([(t, d, 1, x) for t, d, r, x in zip(HAND.target_deg, HAND.direction, HAND.run, HAND.deviation_arcsec) if r == 1]))
    assert one_run["R"] is None and one_run["A"] is None and one_run["E"] is not None
    assert any("one approach" in n for n in one_run["notes"])
    assert evaluate(_table([(0, 1, 1, 1.0), (90, 1, 1, 2.0)]), "vdi3441")["P"] is None


def _independent(rows):
    """ISO 230-2 by the book, in plain loops, written apart from rtcal/evaluation.py."""
    targets = sorted({t for t, _, _, _ in rows})
    up, down = {}, {}
    for t, d, _, x in rows:
        (up if d > 0 else down).setdefault(t, []).append(x)

    def mean(v):
        return sum(v) / len(v)

    def sd(v):
        m = mean(v)
        return math.sqrt(sum((a - m) ** 2 for a in v) / (len(v) - 1))

    mu = {t: mean(up[t]) for t in targets}
    md = {t: mean(down[t]) for t in targets}
    su = {t: sd(up[t]) for t in targets}
    sdn = {t: sd(down[t]) for t in targets}
    B = {t: mu[t] - md[t] for t in targets}
    out = {"E_up": max(mu.values()) - min(mu.values()), "E_down": max(md.values()) - min(md.values())}
    both = list(mu.values()) + list(md.values())
    out["E"] = max(both) - min(both)
    mid = [(mu[t] + md[t]) / 2 for t in targets]
    out["M"] = max(mid) - min(mid)
    out["B"] = max(abs(b) for b in B.values())
    out["B_mean"] = sum(B.values()) / len(B)
    out["R_up"] = max(4 * su[t] for t in targets)
    out["R_down"] = max(4 * sdn[t] for t in targets)
    out["R"] = max(max(2 * su[t] + 2 * sdn[t] + abs(B[t]), 4 * su[t], 4 * sdn[t]) for t in targets)
    out["A_up"] = max(mu[t] + 2 * su[t] for t in targets) - min(mu[t] - 2 * su[t] for t in targets)
    out["A_down"] = max(md[t] + 2 * sdn[t] for t in targets) - min(md[t] - 2 * sdn[t] for t in targets)
    hi = [mu[t] + 2 * su[t] for t in targets] + [md[t] + 2 * sdn[t] for t in targets]
    lo = [mu[t] - 2 * su[t] for t in targets] + [md[t] - 2 * sdn[t] for t in targets]
    out["A"] = max(hi) - min(lo)
    return out


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 8), st.integers(2, 6), st.integers(0, 2**32 - 1))
def test_agrees_with_an_independent_implementation(n_targets, n_runs, seed):
    rng = np.random.default_rng(seed)
    targets = np.sort(rng.choice(np.arange(0, 360, 5), n_targets, replace=False)).astype(float)
    rows = [(float(t), d, r, float(rng.normal(0, 5))) for t in targets for d in (1, -1) for r in range(1, n_runs + 1)]
    ours = evaluate(_table(rows), "iso230-2")
    ref = _independent(rows)
    for key, value in ref.items():
        assert ours[key] == pytest.approx(value, abs=1e-3), key


def test_cli_on_csv_and_run_directory(tmp_path, capsys):
    csv = tmp_path / "d.csv"
    csv.write_text(HAND.to_csv())
    assert main(["evaluate", str(csv)]) == 0
    assert json.loads(capsys.readouterr().out)["E"] == pytest.approx(7)
    run = tmp_path / "run"
    run.mkdir()
    (run / "results.json").write_text(json.dumps({"positioning_deviations": HAND.to_dict()}))
    assert main(["evaluate", str(run), "--standard", "vdi3441"]) == 0
    assert json.loads(capsys.readouterr().out)["P"] == pytest.approx(13)


@pytest.mark.parametrize("text, message", [
    ("target_deg,direction,run,deviation_arcsec\n0,2,1,1\n", "d.csv:2: direction must be"),
    ("angle,x\n1,2\n", "d.csv:1: header must name"),
])
def test_cli_bad_input(tmp_path, capsys, text, message):
    csv = tmp_path / "d.csv"
    csv.write_text(text)
    assert main(["evaluate", str(csv)]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert main(["evaluate", str(tmp_path)]) == 2  # a directory that is not a run
