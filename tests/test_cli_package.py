"""The `rtcal` command as a package (rtcal/cli/): every command listed by `rtcal --help`, the plan's
and the Monte Carlo's JSON as typed documents with schemas, `sim serve --stage` naming the product
(the old spellings still accepted, with a line saying what to write), one address-name check."""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
from pathlib import Path

import jsonschema
import pytest

from rtcal.cli import COMMANDS, UserError, build_parser, main
from rtcal.cli.sim import stage_of
from rtcal.planning.reports import (PlanPrediction, UncertaintySummary, plan_schema, systematics_text,
                                    uncertainty_schema, uncertainty_summary)
from simulators.servers.serve_options import STAGES

REPO = Path(__file__).resolve().parents[1]
ABBE = REPO / "procedures" / "encoder_abbe_error.yaml"


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def test_help_lists_every_command(capsys):
    """`python -m rtcal.cli --help` (the console script's entry) names every command the parser has, each
    with its help line; every add_ in COMMANDS registers one."""
    commands = _subcommands(build_parser())
    assert len(commands) == len(COMMANDS)
    assert set(commands) == {"run", "resume", "uncertainty", "evaluate", "compensate", "compare", "export", "verify",
                             "plan", "sim", "probe", "check", "validate", "schema", "solve", "view", "control", "catalog",
                             "key"}
    done = subprocess.run([sys.executable, "-m", "rtcal.cli", "--help"], capture_output=True, text=True, timeout=120,
                          cwd=REPO)
    assert done.returncode == 0, done.stderr
    listed = {m.group(1) for m in re.finditer(r"^ {4}(\w+) ", done.stdout, re.M)}  # "    run   run a procedure …"
    assert listed == set(commands), listed ^ set(commands)


def _lever(name: str, problem: str | None = None) -> dict:
    row = {"lever": name, "changes": [name], "recommended": "network", "expanded_uncertainty_max_arcsec": 1.5,
           "duration_s": 3600.0, "raw_readings": 120, "sources_rms_arcsec": {"tracer noise": 0.3}}
    return {**row, **({"problem": problem} if problem else {})}


def _plan(**extra) -> dict:
    return {"procedure": "p.yaml", "targets": ["0", "30", "60"], "measurement_duration_s": 1800.5, "raw_readings": 60,
            "recommended": "network",
            "estimators": {"network": {"predicted_sigma_arcsec": [0.0, 0.4, None],
                                       "predicted_expanded_arcsec": [0.0, 0.8, None], "rms_predicted_sigma_arcsec": 0.4,
                                       "budget": {"tracer noise": [0.0, 0.3, None]}}},
            "expanded_uncertainty_max_arcsec": 0.8, "duration_s": 1800.5,
            "dominant_sources": [{"source": "tracer noise", "share": 1.0}],
            "levers": [_lever("2 runs"), _lever("3 seatings", "does not validate")], "lever_notes": ["a note"], **extra}


def test_the_plan_document_keeps_its_json_shape_and_validates_against_its_schema():
    """Keys in their order, `problem` and `proposal` only when there is one, `lever` first in its row;
    the printed JSON is the schema's."""
    data = _plan()
    text = PlanPrediction.model_validate(data).to_json()
    assert text == json.dumps(data, indent=2)
    jsonschema.validate(json.loads(text), json.loads(plan_schema()))
    smallest = {k: v for k, v in _lever("2 runs").items() if k != "lever"}
    proposal = {"target_u_arcsec": 1.0, "margin": 0.1, "reached": False, "smallest": smallest, "plans_predicted": 4,
                "plans_skipped": []}
    data = _plan(proposal=proposal)
    text = PlanPrediction.model_validate(data).to_json()
    assert text == json.dumps(data, indent=2) and '"plan"' not in text and '"written"' not in text
    with pytest.raises(ValueError):
        PlanPrediction.model_validate(_plan(unknown_key=1))  # a misspelt field is refused, not carried along


def _trial(error: float, u: float, recommended: str = "network") -> dict:
    return {"labels": ["0", "30", "60"], "recommended": recommended,
            "per_estimator": {"network": {"error": [0.0, error, -error], "u": [0.0, u, u], "status": "converged"}}}


def test_the_uncertainty_summary_is_what_the_trials_give(tmp_path):
    """uncertainty.json from the trials: RMS error, RMS reported 1σ and their ratio per target, the failed
    trials counted, what was run; valid against its schema."""
    proc = type("P", (), {"bench": None})()
    trials = [_trial(0.3, 0.3), _trial(0.5, 0.3), {"failed": "no"}]
    summary = uncertainty_summary(trials, Path("p.yaml"), proc, None, 7, drawn=True, balanced=True)
    assert (summary.trials, summary.failed_trials, summary.bench, summary.seed) == (3, 1, "ideal", 7)
    rms = (0.3**2 / 2 + 0.5**2 / 2) ** 0.5
    network = summary.estimators["network"]
    assert network.rms_error_arcsec[1] == pytest.approx(rms, abs=1e-4)
    assert network.ratio[1] == pytest.approx(0.3 / rms, abs=1e-3)
    assert network.overall.coverage_k2 == 1.0  # |error| ≤ 2u in every pair
    assert summary.systematics == systematics_text(True, True) and "balanced" in summary.systematics
    assert systematics_text(False, False) == "fixed as in the scenario"
    data = json.loads(summary.to_json())
    assert list(data) == ["trials", "failed_trials", "targets", "estimators", "recommended", "recommended_estimate", "procedure", "bench", "seed",
                          "systematics"]
    jsonschema.validate(data, json.loads(uncertainty_schema()))
    assert UncertaintySummary.model_validate(data) == summary


def test_schema_prints_the_plan_and_uncertainty_schemas(capsys):
    assert main(["schema", "--plan"]) == 0
    assert "expanded_uncertainty_max_arcsec" in json.loads(capsys.readouterr().out)["properties"]
    assert main(["schema", "--uncertainty"]) == 0
    assert "systematics" in json.loads(capsys.readouterr().out)["properties"]
    assert main(["schema", "--plan", "--results"]) == 2
    err = capsys.readouterr().err
    assert "--results or --plan" in err and len(err.strip().splitlines()) == 1


def _serve_args(*argv: str) -> argparse.Namespace:
    return build_parser().parse_args(["sim", "serve", *argv])


@pytest.mark.parametrize("argv, stage, warned", [
    ((), "oriental-az", False),
    (("--stage", "pi-gcs"), "pi-gcs", False),
    (("--stage", "linuxcnc"), "linuxcnc", False),
    (("--stage-model", "pi-gcs"), "pi-gcs", True),  # the old spellings
    (("--stage", "modbus"), "oriental-az", True),
    (("--stage", "modbus", "--stage-model", "pi-gcs"), "pi-gcs", True),
    (("--stage", "linuxcnc", "--stage-model", "oriental-az"), "linuxcnc", False),
])
def test_sim_serve_stage_is_one_option(capsys, argv, stage, warned):
    assert stage_of(_serve_args(*argv)) == stage
    err = capsys.readouterr().err
    assert ("deprecated" in err) == warned and all(line.startswith("rtcal: warning: ") for line in err.splitlines())
    assert set(STAGES) <= set(_subcommands(_subcommands(build_parser())["sim"])["serve"]._option_string_actions["--stage"].choices)


@pytest.mark.parametrize("argv, message", [
    (("--stage", "linuxcnc", "--stage-model", "pi-gcs"), "give one or the other"),
    (("--stage", "oriental-az", "--stage-model", "pi-gcs"), "give --stage alone"),
])
def test_sim_serve_contradicting_stages_are_refused(argv, message):
    with pytest.raises(UserError, match=message):
        stage_of(_serve_args(*argv))


def test_sim_serve_refuses_an_unknown_stage(capsys):
    with pytest.raises(SystemExit) as exc:
        _serve_args("--stage", "oriental")
    assert exc.value.code == 2 and "argument --stage: invalid choice" in capsys.readouterr().err


def test_check_and_run_refuse_an_address_name_alike(capsys):
    """One check of the names in --instruments: `check` says what `run` says, the likely name included."""
    assert main(["check", str(ABBE), "--instruments", '{"stagee": "modbus-tcp://127.0.0.1:1"}']) == 2
    err = capsys.readouterr().err
    assert "--instruments:1:1: stagee: not an instrument rtcal knows; did you mean `stage`?" in err
    assert len(err.strip().splitlines()) == 1
