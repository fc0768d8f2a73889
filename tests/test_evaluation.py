"""ISO 230-2 and VDI 3441 evaluation: hand-worked datasets, the four errors of a published
evaluator, degenerate data, the command line, and agreement with an independent plain-loop
implementation on random datasets.

Expected values are worked by hand in the comments and exact in decimal arithmetic; the
results are rounded to 0.0001″, so the tolerance is half of that.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rtcal.cli import main
from rtcal.deliverables.deviations import PositioningDeviations
from rtcal.deliverables.evaluation import evaluate

EXACT = 5e-5  # results are rounded to 0.0001″


def iso230_2(t: PositioningDeviations) -> dict:
    return evaluate(t, "iso230-2")


def vdi3441(t: PositioningDeviations) -> dict:
    return evaluate(t, "vdi3441")


def table(rows: list[tuple[float, int, int, float]]) -> PositioningDeviations:
    a = np.array(rows, float)
    return PositioningDeviations(a[:, 0], a[:, 1].astype(int), a[:, 2].astype(int), a[:, 3], np.full(len(a), 0.1))


def from_runs(data: dict[float, dict[int, list[float]]]) -> PositioningDeviations:
    """{target: {+1: [run 1, run 2, …], -1: […]}} → table."""
    rows = [(t, d, j + 1, x) for t, sides in data.items() for d, xs in sides.items() for j, x in enumerate(xs)]
    return table(rows)


# 3 targets × 2 directions × 3 runs, arcsec.
HAND = {
    0.0: {1: [1, 2, 3], -1: [-1, 0, 1]},
    90.0: {1: [4, 6, 8], -1: [3, 3, 3]},
    180.0: {1: [-2, -2, -2], -1: [-6, -4, -5]},
}
# By hand:
#   x̄↑ = [2, 6, −2]   s↑ = [1, 2, 0]      (e.g. 90°: mean 6, Σ(x−6)² = 4+0+4 = 8, s = √(8/2) = 2)
#   x̄↓ = [0, 3, −5]   s↓ = [1, 0, 1]
#   x̄  = [1, 4.5, −3.5]                   B_i = x̄↑ − x̄↓ = [2, 3, 3]   B = 3   B̄ = 8/3
#   R↑_i = 4s↑ = [4, 8, 0]   R↓_i = [4, 0, 4]
#   R_i = max(2s↑ + 2s↓ + |B_i|, R↑_i, R↓_i) = [max(6,4,4), max(7,8,0), max(5,0,4)] = [6, 8, 5]
#   R↑ = 8, R↓ = 4, R = 8
#   E↑ = 6 − (−2) = 8   E↓ = 3 − (−5) = 8   E = max(all x̄) − min(all x̄) = 6 − (−5) = 11
#   M = 4.5 − (−3.5) = 8
#   A↑: x̄+2s = [4, 10, −2], x̄−2s = [0, 2, −2] → 10 − (−2) = 12
#   A↓: x̄+2s = [2, 3, −3],  x̄−2s = [−2, 3, −7] → 3 − (−7) = 10
#   A = max(10, 3) − min(−2, −7) = 17
HAND_ISO = dict(E_up=8, E_down=8, E=11, M=8, B=3, B_mean=8 / 3, R_up=8, R_down=4, R=8, A_up=12, A_down=10, A=17)


def test_iso230_2_hand_worked():
    out = iso230_2(from_runs(HAND))
    for key, value in HAND_ISO.items():
        assert out[key] == pytest.approx(value, abs=EXACT), key
    pt = out["per_target"]
    assert [r["mean_up"] for r in pt] == pytest.approx([2, 6, -2])
    assert [r["mean_down"] for r in pt] == pytest.approx([0, 3, -5])
    assert [r["mean"] for r in pt] == pytest.approx([1, 4.5, -3.5])
    assert [r["B_i"] for r in pt] == pytest.approx([2, 3, 3])
    assert [r["s_up"] for r in pt] == pytest.approx([1, 2, 0])
    assert [r["s_down"] for r in pt] == pytest.approx([1, 0, 1])
    assert [r["R_up_i"] for r in pt] == pytest.approx([4, 8, 0])
    assert [r["R_i"] for r in pt] == pytest.approx([6, 8, 5])
    assert out["targets"] == 3 and out["unit"] == "arcsec"
    assert out["runs_per_direction"] == {"up": {"min": 3, "max": 3}, "down": {"min": 3, "max": 3}}
    assert out["notes"] == []


def test_iso230_2_1988_uses_three_s():
    # k = 3: R↑_i = 6s↑ = [6, 12, 0], R↓_i = [6, 0, 6]
    #   R_i = max(3s↑ + 3s↓ + |B_i|, …) = [max(8,6,6), max(9,12,0), max(6,0,6)] = [8, 12, 6]  → R = 12
    #   A↑: x̄+3s = [5, 12, −2], x̄−3s = [−1, 0, −2] → 14;  A↓: [3, 3, −2], [−3, 3, −8] → 11;  A = 12 − (−8) = 20
    out = evaluate(from_runs(HAND), "iso230-2:1988")
    expected = dict(E_up=8, E_down=8, E=11, M=8, B=3, B_mean=8 / 3, R_up=12, R_down=6, R=12, A_up=14, A_down=11, A=20)
    for key, value in expected.items():
        assert out[key] == pytest.approx(value, abs=EXACT), key
    assert out["standard"] == "iso230-2:1988"
    assert any("not confirmed" in n for n in out["notes"])


def test_vdi3441_hand_worked():
    # x̄ = [1, 4.5, −3.5], U_j = |B_j| = [2, 3, 3], Ps_j = 6·(s↑+s↓)/2 = [6, 6, 3]
    # Pa = 4.5 − (−3.5) = 8; U_max = 3; U_mean = 8/3; Ps_max = 6; Ps_mean = 15/3 = 5
    # P: x̄ + (U+Ps)/2 = [5, 9, −0.5]; x̄ − (U+Ps)/2 = [−3, 0, −6.5] → 9 − (−6.5) = 15.5
    out = vdi3441(from_runs(HAND))
    expected = dict(Pa=8, P=15.5, Ps_max=6, Ps_mean=5, U_max=3, U_mean=8 / 3)
    for key, value in expected.items():
        assert out[key] == pytest.approx(value, abs=EXACT), key
    assert [r["Ps_j"] for r in out["per_target"]] == pytest.approx([6, 6, 3])
    assert [r["U_j"] for r in out["per_target"]] == pytest.approx([2, 3, 3])


# ---- the four errors of a published open-source evaluator --------------------------------
# Each test checks the correct value and shows, with a plain re-enactment of the error on the
# same data, that the error gives a different value: the test fails on that implementation.

def test_mean_divides_by_approaches_not_by_targets():
    # 2 targets × 4 runs: dividing Σx by m = 2 instead of n = 4 doubles every mean.
    # 0°: ↑ [1, 2, 3, 2] → x̄↑ = 8/4 = 2;  90°: ↑ [5, 5, 5, 5] → 5;  E↑ = 3
    # ↓: [0, 0, 0, 0] → 0 and [4, 4, 4, 4] → 4;  E↓ = 4;  B_i = [2, 1]
    data = {0.0: {1: [1, 2, 3, 2], -1: [0, 0, 0, 0]}, 90.0: {1: [5, 5, 5, 5], -1: [4, 4, 4, 4]}}
    out = iso230_2(from_runs(data))
    assert [r["mean_up"] for r in out["per_target"]] == pytest.approx([2, 5])
    assert out["E_up"] == pytest.approx(3) and out["E_down"] == pytest.approx(4)
    buggy = [sum(xs[1]) / len(data) for xs in data.values()]  # ÷ number of positions
    assert buggy == [4.0, 10.0] and max(buggy) - min(buggy) != pytest.approx(out["E_up"])


def test_up_and_down_are_not_swapped():
    # HAND: B_i = x̄↑ − x̄↓ = [2, 3, 3] > 0, B̄ = 8/3; A↑ = 12 ≠ A↓ = 10.
    # Reading ↑ data as ↓ (the published evaluator's parser swapped them) flips B_i and B̄.
    out = iso230_2(from_runs(HAND))
    assert [r["B_i"] for r in out["per_target"]] == pytest.approx([2, 3, 3])
    assert out["B_mean"] == pytest.approx(8 / 3, abs=EXACT) and out["A_up"] == pytest.approx(12)
    swapped = iso230_2(from_runs({t: {1: s[-1], -1: s[1]} for t, s in HAND.items()}))
    assert swapped["B_mean"] == pytest.approx(-8 / 3, abs=EXACT) and swapped["A_up"] == pytest.approx(10)


def test_minimum_in_E_is_the_minimum_of_both_directions():
    # HAND: min x̄↑ = −2, min x̄↓ = −5 → E = 6 − (−5) = 11 ≥ max(E↑, E↓) = 8.
    # The published error kept the larger of the two minima (a '>' where '<' belongs): 6 − (−2) = 8.
    out = iso230_2(from_runs(HAND))
    assert out["E"] == pytest.approx(11)
    assert out["E"] >= max(out["E_up"], out["E_down"])
    up = [r["mean_up"] for r in out["per_target"]]
    down = [r["mean_down"] for r in out["per_target"]]
    buggy = max(max(up), max(down)) - max(min(up), min(down))
    assert buggy == pytest.approx(8) != out["E"]


def test_R_is_bidirectional_not_R_up():
    # The published evaluator takes the axis's R from the unidirectional repeatabilities only (its
    # code means max(R↑, R↓); as written it reports R↑), dropping 2s↑ + 2s↓ + |B_i|. On data where
    # that term exceeds 4s of either direction, both readings of the error are wrong:
    # 0°:  ↑ [0, 1, 2] (x̄ 1, s 1), ↓ [−4, −3, −2] (x̄ −3, s 1), B_0 = 4
    #      → R_i = max(2 + 2 + 4, 4, 4) = 8
    # 90°: ↑ [5, 5, 5] (x̄ 5, s 0), ↓ [3.5, 4, 4.5] (x̄ 4, s 0.5), B_90 = 1
    #      → R_i = max(0 + 1 + 1, 0, 2) = 2
    # R↑ = max(4, 0) = 4, R↓ = max(4, 2) = 4, R = max(8, 2) = 8 (the standard's formula, by hand),
    # where the error gives 4.
    data = {0.0: {1: [0, 1, 2], -1: [-4, -3, -2]}, 90.0: {1: [5, 5, 5], -1: [3.5, 4, 4.5]}}
    out = iso230_2(from_runs(data))
    assert [r["R_i"] for r in out["per_target"]] == pytest.approx([8, 2], abs=EXACT)
    assert out["R_up"] == pytest.approx(4, abs=EXACT) and out["R_down"] == pytest.approx(4, abs=EXACT)
    assert out["R"] == pytest.approx(8, abs=EXACT)
    # the standard's formula, from rtcal's own per-target statistics
    standard = max(max(2 * r["s_up"] + 2 * r["s_down"] + abs(r["B_i"]), 4 * r["s_up"], 4 * r["s_down"])
                   for r in out["per_target"])
    assert out["R"] == pytest.approx(standard, abs=EXACT)
    # the error, in both readings of its code, gives another value
    for erroneous in (out["R_up"], max(out["R_up"], out["R_down"])):
        assert erroneous != pytest.approx(out["R"], abs=1.0)


def test_published_report_values_are_corrected():
    """A report of the published evaluator (5 positions × 5 cycles): it printed E = 0.01485 mm,
    less than its own E↑ = 0.01505 (impossible: E covers E↑), and R = R↑ = 0.0075. Its x(i,j)
    table is used here in µm (× 1000: results are rounded to 0.0001).

    By hand: x̄↑4 = −45.1/5 = −9.02 (the lowest mean), x̄↓5 = 34.84/5 = 6.968 (the highest)
    → E = 15.988; x̄↑5 = 30.16/5 = 6.032 → E↑ = 15.052. At position 3: s↑ = 1.8756, s↓ = 0.83236,
    B = 2.084 − (−0.854) = 2.938 → R_3 = 2s↑ + 2s↓ + |B| = 8.3539, the largest R_i; R↑ = 4·1.8756.
    Tolerance 0.001: the hand arithmetic carried five significant digits.
    """
    up = [[3.35, 2.33, 1.72, 2.13, 1.72], [-0.26, 0.15, 0.96, 0.56, 0.56], [1.02, -0.4, 2.25, 3.06, 4.49],
          [-8.49, -9.1, -7.88, -9.1, -10.53], [5.83, 6.24, 6.85, 5.62, 5.62]]
    down = [[5.18, 5.18, 4.16, 3.35, 3.14], [-3.72, -3.93, -4.33, -4.13, -4.74], [-1.83, -1.63, -0.2, -0.61, 0.0],
            [-7.68, -8.09, -7.07, -8.09, -8.49], [7.05, 7.25, 7.05, 7.05, 6.44]]
    targets = [15.0, 25.2, 35.4, 45.6, 55.8]
    out = iso230_2(from_runs({t: {1: u, -1: d} for t, u, d in zip(targets, up, down)}))
    assert out["E"] == pytest.approx(15.988, abs=1e-3)
    assert out["E_up"] == pytest.approx(15.052, abs=1e-3)
    assert out["R"] == pytest.approx(8.3539, abs=1e-3)
    assert out["R_up"] == pytest.approx(4 * 1.8756, abs=1e-3)
    assert out["E"] > out["E_up"] and out["R"] > out["R_up"]


# ---- degenerate data ----------------------------------------------------------------------

def test_one_direction_only():
    out = iso230_2(from_runs({t: {1: s[1]} for t, s in HAND.items()}))
    assert out["E_up"] == pytest.approx(8) and out["A_up"] == pytest.approx(12) and out["R_up"] == pytest.approx(8)
    for key in ("E_down", "R_down", "A_down", "E", "M", "B", "B_mean", "R", "A"):
        assert out[key] is None, key
    assert any("one direction only" in n for n in out["notes"])
    vdi = vdi3441(from_runs({t: {-1: s[-1]} for t, s in HAND.items()}))
    # ↓ alone: x̄ = [0, 3, −5] → Pa = 8; Ps = 6s↓ = [6, 0, 6]
    assert vdi["Pa"] == pytest.approx(8) and vdi["Ps_max"] == pytest.approx(6)
    assert vdi["U_max"] is None and vdi["P"] is None


def test_one_run_only_has_no_s():
    out = iso230_2(from_runs({t: {1: s[1][:1], -1: s[-1][:1]} for t, s in HAND.items()}))
    # one run: x̄ are the single values ↑ [1, 4, −2], ↓ [−1, 3, −6] → E = 4 − (−6) = 10
    assert out["E"] == pytest.approx(10) and out["B"] == pytest.approx(max(2, 1, 4))
    for key in ("R_up", "R_down", "R", "A_up", "A_down", "A"):
        assert out[key] is None, key
    assert all(r["s_up"] is None for r in out["per_target"])
    assert any("one approach" in n and "s needs two" in n for n in out["notes"])
    assert vdi3441(from_runs({t: {1: s[1][:1], -1: s[-1][:1]} for t, s in HAND.items()}))["P"] is None


def test_unequal_runs_divide_by_their_own_count():
    # 0° ↑ has 2 runs [1, 3] → x̄ = 2, s = √2; 90° ↑ has 4 runs [6, 6, 6, 6] → x̄ = 6, s = 0
    data = {0.0: {1: [1, 3], -1: [0, 0, 0]}, 90.0: {1: [6, 6, 6, 6], -1: [5]}}
    out = iso230_2(from_runs(data))
    assert [r["mean_up"] for r in out["per_target"]] == pytest.approx([2, 6])
    assert out["per_target"][0]["s_up"] == pytest.approx(math.sqrt(2), abs=EXACT)
    assert out["runs_per_direction"] == {"up": {"min": 2, "max": 4}, "down": {"min": 1, "max": 3}}
    assert out["R_up"] == pytest.approx(4 * math.sqrt(2), abs=EXACT) and out["R_down"] is None and out["R"] is None


def test_missing_deviation_rows_are_skipped_with_a_note():
    t = from_runs(HAND)
    x = t.deviation_arcsec.copy()
    x[0] = np.nan
    out = iso230_2(PositioningDeviations(t.target_deg, t.direction, t.run, x, t.uncertainty_arcsec))
    assert out["per_target"][0]["n_up"] == 2 and out["per_target"][0]["mean_up"] == pytest.approx(2.5)
    assert any("missing" in n for n in out["notes"])


def test_perfectly_repeatable_approaches_have_s_zero_not_missing():
    # every approach identical: s = 0 everywhere, so R_i↑ = 0 and A↑ = E↑ (a value, not "undefined")
    # 0°: ↑ 1, 1 / ↓ 0, 0;  90°: ↑ 4, 4 / ↓ 2, 2 → E↑ = 3, A↑ = 3, B_i = [1, 2], R_i = [1, 2], A = 4 − 0 = 4
    data = {0.0: {1: [1, 1], -1: [0, 0]}, 90.0: {1: [4, 4], -1: [2, 2]}}
    out = iso230_2(from_runs(data))
    assert out["A_up"] == pytest.approx(3) and out["R_up"] == pytest.approx(0)
    assert out["R"] == pytest.approx(2) and out["A"] == pytest.approx(4)
    assert vdi3441(from_runs(data))["P"] == pytest.approx(4)  # x̄ ± U/2: max(0.5+0.5, 3+1) − min(0.5−0.5, 3−1)


def test_a_bound_over_the_axis_needs_every_target():
    # 90° ↓ has one approach: s↓ undefined there, so R↓, A↓, R, A are undefined — not computed
    # from the other targets alone; R↑ and A↑ stand (every ↑ target has s).
    data = {0.0: {1: [1, 3], -1: [0, 2]}, 90.0: {1: [4, 6], -1: [5]}}
    out = iso230_2(from_runs(data))
    assert out["R_down"] is None and out["A_down"] is None and out["R"] is None and out["A"] is None
    assert out["R_up"] == pytest.approx(4 * math.sqrt(2), abs=EXACT)
    assert any("90°" in n and "one approach" in n for n in out["notes"])


def test_unknown_standard():
    with pytest.raises(ValueError, match="unknown standard"):
        evaluate(from_runs(HAND), "iso9283")


# ---- an independent implementation: plain loops, written from the definitions ------------

def reference_iso(rows, k=2.0):
    """ISO 230-2 written again from the definitions with lists and loops (no shared code)."""
    data = {}
    for t, d, _, x in rows:
        data.setdefault(round(t, 9), {1: [], -1: []})[d].append(x)
    stats = {}
    for t in sorted(data):
        for d in (1, -1):
            xs = data[t][d]
            if not xs:
                continue
            mean = sum(xs) / len(xs)
            s = None
            if len(xs) > 1:
                s = (sum((x - mean) ** 2 for x in xs) / (len(xs) - 1)) ** 0.5
            stats[t, d] = (mean, s)
    res = {}
    for d, name in ((1, "up"), (-1, "down")):
        keys = [key for key in stats if key[1] == d]
        if not keys:
            continue
        means = [stats[key][0] for key in keys]
        res["E_" + name] = max(means) - min(means)
        if all(stats[key][1] is not None for key in keys):
            res["R_" + name] = max(2 * k * stats[key][1] for key in keys)
            hi = max(stats[key][0] + k * stats[key][1] for key in keys)
            lo = min(stats[key][0] - k * stats[key][1] for key in keys)
            res["A_" + name] = hi - lo
    if any(key[1] == 1 for key in stats) and any(key[1] == -1 for key in stats):
        allmeans = [v[0] for v in stats.values()]
        res["E"] = max(allmeans) - min(allmeans)
        both = [t for t in data if (t, 1) in stats and (t, -1) in stats]
        if both:
            bidir = [(stats[t, 1][0] + stats[t, -1][0]) / 2 for t in both]
            res["M"] = max(bidir) - min(bidir)
            bs = [stats[t, 1][0] - stats[t, -1][0] for t in both]
            res["B"] = max(abs(b) for b in bs)
            res["B_mean"] = sum(bs) / len(bs)
            if all(stats[t, 1][1] is not None and stats[t, -1][1] is not None for t in both):
                ri = []
                for t, b in zip(both, bs):
                    su, sd = stats[t, 1][1], stats[t, -1][1]
                    ri.append(max(k * su + k * sd + abs(b), 2 * k * su, 2 * k * sd))
                res["R"] = max(ri)
                hi = max(max(stats[t, 1][0] + k * stats[t, 1][1], stats[t, -1][0] + k * stats[t, -1][1]) for t in both)
                lo = min(min(stats[t, 1][0] - k * stats[t, 1][1], stats[t, -1][0] - k * stats[t, -1][1]) for t in both)
                res["A"] = hi - lo
    return res


def reference_vdi(rows):
    data = {}
    for t, d, _, x in rows:
        data.setdefault(round(t, 9), {1: [], -1: []})[d].append(x)
    xs_, us, pss = [], [], []
    for t in data:
        up, dn = data[t][1], data[t][-1]
        if not up or not dn or len(up) < 2 or len(dn) < 2:
            return None
        mu, md = sum(up) / len(up), sum(dn) / len(dn)
        su = (sum((x - mu) ** 2 for x in up) / (len(up) - 1)) ** 0.5
        sd = (sum((x - md) ** 2 for x in dn) / (len(dn) - 1)) ** 0.5
        xs_.append((mu + md) / 2)
        us.append(abs(mu - md))
        pss.append(6 * (su + sd) / 2)
    return {"Pa": max(xs_) - min(xs_), "U_max": max(us), "U_mean": sum(us) / len(us), "Ps_max": max(pss),
            "Ps_mean": sum(pss) / len(pss),
            "P": max(x + (u + p) / 2 for x, u, p in zip(xs_, us, pss)) - min(x - (u + p) / 2 for x, u, p in zip(xs_, us, pss))}


@st.composite
def datasets(draw, both_directions: bool = True):
    targets = draw(st.lists(st.integers(0, 359), min_size=1, max_size=7, unique=True))
    directions = [1, -1] if both_directions else [draw(st.sampled_from([1, -1]))]
    rows = []
    for t in targets:
        angle = t * 1.0 + draw(st.sampled_from([0.0, 0.25, 0.5]))
        for d in directions:
            runs = draw(st.integers(1, 5))
            for j in range(runs):
                x = draw(st.floats(-60, 60, allow_nan=False, allow_infinity=False))
                rows.append((angle, d, j + 1, x))
    return rows


AGREE = 1e-3  # arcsec: the figure for agreement with an independent implementation


@settings(max_examples=300, deadline=None)
@given(datasets(), st.sampled_from([2.0, 3.0]))
def test_iso_agrees_with_independent_implementation(rows, k):
    out = evaluate(table(rows), "iso230-2" if k == 2.0 else "iso230-2:1988")
    ref = reference_iso(rows, k)
    for key in ("E_up", "E_down", "E", "M", "B", "B_mean", "R_up", "R_down", "R", "A_up", "A_down", "A"):
        if key in ref:
            assert out[key] == pytest.approx(ref[key], abs=AGREE), key
        else:
            assert out[key] is None, key


@settings(max_examples=100, deadline=None)
@given(datasets(both_directions=False))
def test_iso_one_direction_agrees(rows):
    out = iso230_2(table(rows))
    ref = reference_iso(rows)
    for key in ("E_up", "E_down", "R_up", "R_down", "A_up", "A_down"):
        assert (out[key] is None) == (key not in ref), key
        if key in ref:
            assert out[key] == pytest.approx(ref[key], abs=AGREE)


@settings(max_examples=200, deadline=None)
@given(datasets())
def test_vdi_agrees_with_independent_implementation(rows):
    ref = reference_vdi(rows)
    out = vdi3441(table(rows))
    if ref is None:  # a target with fewer than two approaches in a direction
        assert out["P"] is None
        return
    for key, value in ref.items():
        assert out[key] == pytest.approx(value, abs=AGREE), key


# ---- the command line -------------------------------------------------------------------

def test_cli_on_csv_and_run_directory(tmp_path, capsys):
    csv = tmp_path / "d.csv"
    csv.write_text(from_runs(HAND).to_csv())
    assert main(["evaluate", str(csv)]) == 0
    assert json.loads(capsys.readouterr().out)["E"] == pytest.approx(11)
    run = tmp_path / "run"
    run.mkdir()
    (run / "results.json").write_text(results_json_with(from_runs(HAND)))
    assert main(["evaluate", str(run), "--standard", "vdi3441"]) == 0
    assert json.loads(capsys.readouterr().out)["P"] == pytest.approx(15.5)
    assert main(["evaluate", str(run), "--standard", "iso230-2:1988"]) == 0
    assert json.loads(capsys.readouterr().out)["A"] == pytest.approx(20)


def results_json_with(table: PositioningDeviations) -> str:
    """A valid results.json (a run validates as a whole) whose positioning deviations are ``table``: one
    as rtcal 0.1.0 wrote them (schema 1.1, before the digests), so no store need stand beside it."""
    from rtcal.results.io import results_json
    from rtcal.methods.multistation.results import MultistationResults

    budget = {"components": [], "combined_arcsec": [0.0], "expanded_arcsec": [0.0], "coverage_factor": 2.0, "not_included": []}
    estimate = {"deviation_arcsec": [], "uncertainty_arcsec": [], "cumulative_deviation_arcsec": [0.0],
                "cumulative_uncertainty_arcsec": [0.0], "cumulative_expanded_uncertainty_arcsec": [0.0],
                "cumulative_covariance_arcsec2": [[0.0]], "uncertainty_budget": budget, "converged": True, "message": "",
                "eq34_sigma_arcsec": 0.0, "algorithm_error_arcsec": 0.0,
                "estimated_noise": {"tracer_length_noise_um_at_1m": 0.0, "cmm_point_noise_um": 0.0},
                "plane": {"a": 0.0, "b": 0.0, "c": 1.0, "e": 0.0}, "projected_stations_mm": [], "center_mm": [0.0, 0.0, 0.0],
                "stations_mm": [], "dead_paths_mm": {}, "rms_residual_um": 0.0}
    results = MultistationResults.model_validate({
        "rtcal_version": "0.1.0", "schema_version": "1.1", "method": "laser_tracer_multistation", "procedure": {"name": "", "path": ""},
        "metadata": {"customer": "", "machine": "", "axis": "", "serial_number": "", "location": "", "operator": "",
                     "certificate_number": "", "instruments": {}},
        "seed": None, "instruments": {}, "bench": None, "started_utc": None, "finished_utc": None, "starts": 1,
        "measurement_duration_s": 0.0, "clock": "real", "nominal_angles_deg": [0.0], "raw_readings": 0,
        "recommended": "shared_dead_path", "solver_status": {"shared_dead_path": {"status": "converged", "message": ""}},
        "estimates": {"shared_dead_path": estimate}, "positioning_deviations": table.to_model(), "evaluation": None,
        "skipped_readings": 0, "faults": 0, "events": [], "environment": None})
    return results_json(results)


@pytest.mark.parametrize("text, message", [
    ("target_deg,direction,run,deviation_arcsec\n0,2,1,1\n", "d.csv:2: direction must be"),
    ("angle,x\n1,2\n", "d.csv:1: header must name"),
    ("target_deg,direction,run,deviation_arcsec\n0,1,1,1\n0,1,1,2\n", "appears more than once"),
])
def test_cli_bad_input(tmp_path, capsys, text, message):
    csv = tmp_path / "d.csv"
    csv.write_text(text)
    assert main(["evaluate", str(csv)]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert main(["evaluate", str(tmp_path)]) == 2  # a directory that is not a run
    assert main(["evaluate", str(tmp_path / "missing.csv")]) == 2
