"""What a run prints at its end: the method's result, the ISO 230-2 parameters, and the faults
and skipped readings (a run with faults never ends on a bare "run complete")."""

from __future__ import annotations

from pathlib import Path

import yaml

from rtcal.cli import main
from rtcal.methods import read_results

REPO = Path(__file__).resolve().parents[1]
ISO = REPO / "procedures" / "iso230_2_polygon.yaml"
BENCH = REPO / "procedures" / "scenarios" / "abbe_bench.yaml"


def test_faults_and_conditions_are_summarised(tmp_path, capsys):
    """15 autocollimator replies lost (each retried) and three environment readings in a row
    (skipped: a visit goes on without its conditions): the console counts them per instrument
    with the actions taken, and the conditions the sensor did record are in the results."""
    scenario = yaml.safe_load(BENCH.read_text())
    scenario["faults"] = [{"instrument": "autocollimator", "kind": "no_reply", "at_request": list(range(7, 7 * 16, 7))},
                          {"instrument": "environment", "kind": "no_reply", "at_request": [10, 11, 12]}]
    bench = tmp_path / "bench.yaml"
    bench.write_text(yaml.safe_dump(scenario, sort_keys=False))
    out = tmp_path / "run"
    assert main(["run", str(ISO), "--scenario", str(bench), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    r = read_results(out)
    assert r.faults == 18 and r.skipped_readings == 0
    assert "18 instrument faults (autocollimator 15, environment 3)" in printed
    assert "actions taken: retry" in printed and "skip 1" in printed
    assert "ISO 230-2:2014: E " in printed
    assert r.environment is not None and r.environment.air_temperature_c is not None
    report = (out / "report.md").read_text()
    assert "faults: 18" in report and "air temperature" in report


def test_execute_reads_in_one_screen():
    """Issue 46 item 9: `rtcal/cli/run.py:_execute` was 85 lines (the run, every way it ends, the console's
    outcome); it is split into named helpers, each under 60 lines (its behaviour: the tests above and
    tests/test_live_end.py, test_live_run.py, test_crash_resume.py)."""
    import ast

    tree = ast.parse((REPO / "rtcal" / "cli" / "run.py").read_text(encoding="utf-8"))
    lengths = {n.name: n.end_lineno - n.lineno + 1 for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}
    assert lengths["_execute"] < 60, lengths["_execute"]
