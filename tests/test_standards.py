"""Every standard's figures from one dataset (issue 47, item 1): each label's figures against an
independent implementation written here from the standards' definitions (0.001″), each under its
own title and edition (never one standard's number under another's), UPR beside R↑ and R↓ in
`rtcal evaluate`, the procedure's ``evaluation.standards`` validated and carried to the certificate."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import yaml
from hypothesis import given, settings

from rtcal.cli import main
from rtcal.deliverables.standards import standard_figures
from rtcal.procedure.standards import LABELS, STANDARDS
from rtcal.results.model import Conformity, LimitConformity
from tests.test_evaluation import AGREE, HAND, datasets, from_runs, reference_iso, results_json_with, table

REPO = Path(__file__).resolve().parents[1]


def by_target(rows):
    """{target: {direction: [x, …]}} from (target, direction, run, x) rows."""
    data: dict = {}
    for t, d, _, x in rows:
        data.setdefault(round(t, 9), {1: [], -1: []})[d].append(x)
    return data


def sample_s(xs):
    mean = sum(xs) / len(xs)
    return math.sqrt(sum((x - mean) ** 2 for x in xs) / (len(xs) - 1)) if len(xs) > 1 else None


def reference_upr(rows):
    """UPR: the smaller of R↑ and R↓, R = 4·max_i s_i of that direction (ISO 230-2:2014)."""
    data = by_target(rows)
    per_dir = []
    for d in (1, -1):
        s = [sample_s(data[t][d]) for t in data if data[t][d]]
        if not s or any(v is None for v in s):
            return None
        per_dir.append(4 * max(s))
    return min(per_dir)


def reference_jis_b0182(rows):
    """No. 346 = max_i max(3s↑ + 3s↓ + |x̄↑ − x̄↓|, 6s↑, 6s↓); No. 342 = max_i |x̄↑ − x̄↓| (both directions at every target)."""
    data = by_target(rows)
    r346, r342 = [], []
    for t in data:
        up, down = data[t][1], data[t][-1]
        if not up or not down:
            continue
        b = sum(up) / len(up) - sum(down) / len(down)
        r342.append(abs(b))
        su, sd = sample_s(up), sample_s(down)
        if su is not None and sd is not None:
            r346.append(max(3 * su + 3 * sd + abs(b), 6 * su, 6 * sd))
    return (max(r346) if r346 and len(r346) == len(r342) else None), (max(r342) if r342 else None)


def value(found, symbol, edition=None):
    return next(f.value for f in found.figures if f.symbol == symbol and (edition is None or f.edition == edition))


@settings(max_examples=150, deadline=None)
@given(datasets())
def test_each_labels_figures_agree_with_an_independent_implementation(rows):
    t = table(rows)
    iso, old = reference_iso(rows, 2.0), reference_iso(rows, 3.0)
    symbols = {"E_up": "E↑", "E_down": "E↓", "E": "E", "M": "M", "B": "B", "B_mean": "B̄", "R_up": "R↑", "R_down": "R↓",
               "R": "R", "A_up": "A↑", "A_down": "A↓", "A": "A"}
    upr = reference_upr(rows)
    for label in ("iso230-2", "upr"):
        found = standard_figures(label, t)
        got = value(found, "UPR")
        assert (got is None) == (upr is None) and (upr is None or got == pytest.approx(upr, abs=AGREE)), label
    for label in ("iso230-2", "jis-b6190-2", "gb-t-17421.2"):
        found = standard_figures(label, t)
        for key, symbol in symbols.items():
            got = value(found, symbol)
            assert (got is None) == (key not in iso), (label, key)
            if key in iso:
                assert got == pytest.approx(iso[key], abs=AGREE), (label, key)
    both = standard_figures("iso230-2:1988-vs-2014", t)
    for key, symbol in symbols.items():
        for ref, edition in ((old, "ISO 230-2:1988"), (iso, "ISO 230-2:2014")):
            got = value(both, symbol, edition)
            assert (got is None) == (key not in ref) and (got is None or got == pytest.approx(ref[key], abs=AGREE)), (key, edition)
    r346, r342 = reference_jis_b0182(rows)
    jis = standard_figures("jis-b0182", t)
    for symbol, ref in (("No. 346", r346), ("No. 342", r342)):
        got = value(jis, symbol)
        assert (got is None) == (ref is None) and (ref is None or got == pytest.approx(ref, abs=AGREE)), symbol


def test_hand_worked_upr_and_3s_forms():
    """HAND (tests/test_evaluation.py): s↑ = [1, 2, 0], s↓ = [1, 0, 1], B_i = [2, 3, 3].
    R↑ = 4·2 = 8, R↓ = 4·1 = 4 → UPR = 4; 1988: R↑ = 12, R↓ = 6 (= 4/6 ⇒ 8, 4: the rule holds);
    No. 346 = max(3+3+2, 6, 6 | 6+0+3, 12, 0 | 0+3+3, 0, 6) = max(8, 12, 6) = 12; No. 342 = 3."""
    t = from_runs(HAND)
    assert value(standard_figures("upr", t), "UPR") == pytest.approx(4)
    both = standard_figures("iso230-2:1988-vs-2014", t)
    assert value(both, "R↑", "ISO 230-2:1988") == pytest.approx(12) and value(both, "R↓", "ISO 230-2:1988") == pytest.approx(6)
    assert value(both, "UPR", "ISO 230-2:1988") is None  # not a 1988 figure: never a number under 1988's edition
    jis = standard_figures("jis-b0182", t)
    assert value(jis, "No. 346") == pytest.approx(12) and value(jis, "No. 342") == pytest.approx(3)


def test_never_one_standards_number_under_another_title():
    t = from_runs(HAND)
    editions = {"iso230-2:1988-vs-2014": {"ISO 230-2:1988", "ISO 230-2:2014"}}
    for label in LABELS:
        if STANDARDS[label].needs_limits:
            continue
        found = standard_figures(label, t)
        assert found.title == STANDARDS[label].title
        assert {f.edition for f in found.figures} <= editions.get(label, {STANDARDS[label].edition}), label
        assert all(f.coverage and f.definition for f in found.figures), label
    jis = standard_figures("jis-b6190-2", t)
    assert "JIS B 6190-2" in jis.title and all(f.edition.startswith("JIS B 6190-2") for f in jis.figures)
    assert "GB/T 17421.2" in standard_figures("gb-t-17421.2", t).title


def _conformity(limits: dict[str, tuple[float, float, float, str]]) -> Conformity:
    return Conformity(decision_rule="guarded", rule="", verdict="pass", coverage_factor=2.0, notes=[], per_limit={
        k: LimitConformity(limit_arcsec=lim, value_arcsec=v, expanded_uncertainty_arcsec=u, guard_band_arcsec=u, verdict=verdict)
        for k, (lim, v, u, verdict) in limits.items()})


def test_tur_is_the_limit_over_u_beside_its_verdict():
    c = _conformity({"E": (60.0, 53.46, 0.61, "pass"), "R": (12.0, 11.5, 1.2, "undecided"), "B": (10.0, 1.0, 0.0, "pass")})
    found = standard_figures("asme-b5.64", from_runs(HAND), conformity=c)
    tur = {f.symbol: f for f in found.figures}
    assert tur["TUR (E)"].value == pytest.approx(60.0 / 0.61, abs=AGREE) and tur["TUR (R)"].value == pytest.approx(10.0)
    assert tur["TUR (B)"].value is None and "not defined where U is 0" in " ".join(found.notes)
    assert "undecided" in tur["TUR (R)"].beside and "T = 12″" in tur["TUR (R)"].beside and "T / U" in found.rule
    with pytest.raises(ValueError, match="acceptance limits"):
        standard_figures("asme-b5.64", from_runs(HAND))


def test_evaluate_prints_upr_beside_r_up_and_r_down_with_each_figures_edition(tmp_path, capsys):
    csv = tmp_path / "d.csv"
    csv.write_text(from_runs(HAND).to_csv())
    assert main(["evaluate", str(csv)]) == 0
    out = json.loads(capsys.readouterr().out)
    keys = list(out)
    assert keys.index("R_down") + 1 == keys.index("UPR") == keys.index("R") - 1 and out["UPR"] == pytest.approx(4)
    upr = next(f for f in out["figures"] if f["symbol"] == "UPR")
    assert upr["edition"] == "ISO 230-2:2014" and "smaller of R↑ and R↓" in upr["definition"] and "k = 2" in upr["coverage"]
    assert out["edition"] == "ISO 230-2:2014"
    for label in LABELS:
        code = main(["evaluate", str(csv), "--standard", label])
        captured = capsys.readouterr()
        if STANDARDS[label].needs_limits:  # a TUR needs a verdict: one line, exit 2
            assert code == 2 and "acceptance limits" in captured.err and len(captured.err.strip().splitlines()) == 1
            continue
        assert code == 0, label
        printed = json.loads(captured.out)
        assert all({"edition", "coverage", "definition"} <= set(f) for f in printed["figures"]), label
    assert main(["evaluate", str(csv), "--standard", "iso230-2:2014"]) == 0  # an edition alias
    assert json.loads(capsys.readouterr().out)["UPR"] == pytest.approx(4)
    with pytest.raises(SystemExit):
        main(["evaluate", str(csv), "--standard", "jis-b6190"])
    assert "invalid choice" in capsys.readouterr().err


def test_help_names_every_label(capsys):
    with pytest.raises(SystemExit):
        main(["evaluate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for label in LABELS:
        assert f"{label}: " in text, label


def test_run_directory_gives_u_beside_the_2014_figures(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "results.json").write_text(results_json_with(from_runs(HAND)))
    assert main(["evaluate", str(run), "--standard", "upr"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert [f["symbol"] for f in printed["figures"]] == ["R↑", "R↓", "UPR"] and "4/6" in printed["rule"]


@pytest.mark.parametrize("standards, message", [
    ("[upr, jis-b6190]", "unknown standard 'jis-b6190'"),
    ("[upr, upr]", "upr is named twice"),
    ("[asme-b5.64]", "give `acceptance:` limits"),
])
def test_procedure_standards_are_validated(tmp_path, capsys, standards, message):
    text = (REPO / "procedures" / "iso230_2_polygon.yaml").read_text()
    text = text.split("\nacceptance:")[0] + text[text.index("\nmetadata:"):]  # no acceptance limits
    path = tmp_path / "p.yaml"
    path.write_text(text + f"\nevaluation:\n  standards: {standards}\n")
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert message in err and "evaluation" in err and "Traceback" not in err


def test_the_certificate_carries_the_standards_its_procedure_asks_for(tmp_path):
    """The shipped ISO procedure asking for every label (it has acceptance limits: ASME B5.64's TUR
    has its verdicts): each block under its own title, each figure's edition its standard's."""
    data = yaml.safe_load((REPO / "procedures" / "iso230_2_polygon.yaml").read_text())
    asked = [label for label in LABELS if label not in ("iso230-2", "iso230-2:1988", "vdi3441")]
    data["evaluation"] = {"standards": asked}
    bench = REPO / "procedures" / data.pop("bench")
    path = tmp_path / "iso.yaml"
    path.write_text(yaml.safe_dump(data, allow_unicode=True))
    out = tmp_path / "run"
    assert main(["run", str(path), "--scenario", str(bench), "--out", str(out)]) == 0
    cert = json.loads((out / "certificate.json").read_text())
    blocks = cert["other_standards"]["blocks"]
    assert [b["label"] for b in blocks] == asked and all(b["rows"] for b in blocks)
    for b in blocks:  # each under its own title; every figure's edition that standard's
        assert b["title"] == STANDARDS[b["label"]].title
        allowed = STANDARDS[b["label"]].edition.split(" and ")
        assert all(r["edition"] in allowed and r["coverage"] and r["definition"] for r in b["rows"]), b["label"]
    method = cert["method"]["paragraphs"][-1]
    assert method.startswith("Figures on this certificate: ISO 230-2:2014") and all(
        STANDARDS[label].title in method for label in asked)
    results = json.loads((out / "results.json").read_text())
    assert results["procedure"]["standards"] == asked
    report = (out / "report.md").read_text()
    assert "## Figures to other standards (from the same readings)" in report and "TUR (E)" in report
    shipped = yaml.safe_load((REPO / "procedures" / "iso230_2_polygon.yaml").read_text())["evaluation"]["standards"]
    assert set(shipped) <= set(asked)  # the shipped ISO test asks for some of them itself
