"""The R-test as a method (rtcal/methods/rtest/, issue 42): `rtcal run procedures/rtest_trunnion.yaml` on the
simulated trunnion machine recovers the scenario's true location errors within their U, writes them under
`location_errors` with the certificate's ISO 230-7 table and the control's corrected kinematics; a set-up that
cannot separate a location error refuses to report it and says why; `rtcal plan` predicts each U before anything
moves; the method's folder uses rtcal only through rtcal.api (and rtcal.solvers for its mathematics)."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import pytest
import yaml

from rtcal.cli import main
from rtcal.compensation.linuxcnc_kins import LinuxCncTrtFormat
from rtcal.methods import load_procedure, read_results
from rtcal.methods.rtest.method import RTestMethod, RTestPlanner, predict
from rtcal.methods.rtest.results import RTestResults
from rtcal.solvers.rtest import LOCATION_SYMBOLS

REPO = Path(__file__).resolve().parents[1]
PROCEDURE = REPO / "procedures" / "rtest_trunnion.yaml"
SCENARIO = REPO / "procedures" / "scenarios" / "rtest_trunnion.yaml"


@pytest.fixture(scope="module")
def shipped_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("rtest") / "run"
    assert main(["run", str(PROCEDURE), "--out", str(out)]) == 0
    return out


def test_the_shipped_r_test_recovers_the_true_location_errors_within_u(shipped_run):
    results = read_results(shipped_run)
    assert isinstance(results, RTestResults) and results.truth is not None
    truth = yaml.safe_load(SCENARIO.read_text())["machine"]["location_errors"]
    assert set(results.location_errors) == set(LOCATION_SYMBOLS)
    for symbol, e in results.location_errors.items():
        assert 0 < e.expanded_uncertainty < 5.0, (symbol, e)  # µm and arcsec: an R-test's, not a guess
        assert abs(e.value - truth[symbol]) <= 2 * e.expanded_uncertainty, (symbol, e.value, truth[symbol], e.expanded_uncertainty)
        assert results.truth.location_errors[symbol] == pytest.approx(truth[symbol])
    within = sum(abs(e.value - truth[s]) <= e.expanded_uncertainty for s, e in results.location_errors.items())
    assert within >= 7, within
    # the structural parameters of a table are refused, each with why
    assert {"Z0C_um", "X0A_um", "C0C_arcsec", "A0A_arcsec"} <= set(results.not_determined)
    assert results.residual_test is not None and results.residual_test.passed
    path = results.sphere_path
    assert max(path.after_um) * 5 <= max(path.before_um), (max(path.before_um), max(path.after_um))
    assert max(results.nest_calibration.direction_u_deg) < 0.1


def test_the_run_writes_the_controls_kinematics_with_the_measured_lines(shipped_run):
    """The LinuxCNC pins written for this run move C's rot point and A's offsets by the measured offsets, with the
    signs of docs/rtest.md: the pins the truth would give are within the measured U."""
    results = read_results(shipped_run)
    assert isinstance(results, RTestResults)
    truth = yaml.safe_load(SCENARIO.read_text())["machine"]["location_errors"]
    fmt = LinuxCncTrtFormat()
    written = fmt.parse((shipped_run / "compensation" / "linuxcnc-xyzac-trt.hal").read_text())
    nominal = {"x-rot-point": 0.0, "y-rot-point": 0.0, "z-rot-point": 0.0, "y-offset": 0.0, "z-offset": -50.0}
    assert results.control_records["linuxcnc-xyzac-trt"] == nominal
    from rtcal.compensation.kinematics import LocationErrors
    ideal = fmt.parse(fmt.write(nominal, LocationErrors.of(truth)).text)
    U = {s: e.expanded_uncertainty for s, e in results.location_errors.items()}
    assert abs(written["x-rot-point"] - ideal["x-rot-point"]) * 1e3 <= 2 * U["X0C_um"]
    assert abs(written["z-offset"] - ideal["z-offset"]) * 1e3 <= 2 * U["Z0A_um"]
    assert abs(written["y-offset"] - ideal["y-offset"]) * 1e3 <= 2 * U["Y0C_um"]
    assert abs(written["x-rot-point"] - nominal["x-rot-point"]) * 1e3 > 30  # it did move (X0C is 40 µm)
    carr = (shipped_run / "compensation" / "siemens-tc-carr.mpf").read_text()
    assert "$TC_CARR" in carr
    assert (shipped_run / "compensation" / "fanuc-tcp-table.txt").read_text().strip()
    cert = json.loads((shipped_run / "certificate.json").read_text())
    text = json.dumps(cert, ensure_ascii=False)
    assert "location errors of the rotary axes (ISO 230-7)" in text and "Not determined with this set-up" in text
    assert "X0C" in text and "C0A" in text
    assert main(["verify", str(shipped_run)]) == 0


def _variant(tmp_path: Path, **changes: object) -> Path:
    data = yaml.safe_load(PROCEDURE.read_text())
    for key, value in changes.items():
        section, _, field = key.partition("__")
        if field:
            data[section][field] = value
        else:
            data[section] = value
    data["bench"] = str(SCENARIO)
    path = tmp_path / "rtest.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_c_turned_alone_reports_only_what_it_separates_and_says_why_not_the_rest(tmp_path):
    path = _variant(tmp_path, tests={"c_angles_deg": [0, 45, 90, 135, 180, 225, 270, 315], "a_angles_deg": [],
                                     "tilt_deg": None, "both_directions": False})
    assert main(["run", str(path), "--scenario", str(SCENARIO), "--out", str(tmp_path / "run")]) == 0
    results = read_results(tmp_path / "run")
    assert isinstance(results, RTestResults)
    assert set(results.location_errors) == {"X0C_um", "A0C_arcsec"}
    refused = results.not_determined
    assert {"Y0C_um", "B0C_arcsec", "Y0A_um", "Z0A_um", "B0A_arcsec", "C0A_arcsec"} <= set(refused)
    assert "cannot be separated" in refused["Y0C_um"] and "Y0A" in refused["Y0C_um"]
    assert "no pose" in refused["Z0A_um"]
    # the plan said so before anything moved
    proc = load_procedure(path)
    predicted = predict(proc)
    assert set(predicted.U) == {"X0C_um", "A0C_arcsec"}
    assert set(predicted.identifiability.refused) == set(refused) - {"Z0C_um", "X0A_um", "C0C_arcsec", "A0A_arcsec"}


def test_rtcal_plan_predicts_each_u_near_what_the_run_reports(shipped_run):
    proc = load_procedure(PROCEDURE)
    predicted = predict(proc)
    results = read_results(shipped_run)
    assert isinstance(results, RTestResults)
    for symbol, e in results.location_errors.items():
        assert predicted.U[symbol] == pytest.approx(e.expanded_uncertainty, rel=0.25), symbol
    notes = RTestPlanner().notes(proc)
    assert notes[0].startswith("predicted U (k = 2) of each location error: X0C")
    assert any(n.startswith("not determined with this set-up: C0C") for n in notes)


@pytest.mark.parametrize("change, words", [
    ({"instruments": {"machine": {"backend": "sim"}, **{f"nest_indicator_{i}": {"kind": "dial_indicator", "backend": "sim"}
                                                      for i in (1, 2, 3)}}}, "machine.kind"),
    ({"compensation": {"records": {"linuxcnc-xyzac-trt": {"x-rot-point": 0.1, "y-rot-point": 0.0, "z-rot-point": 0.0,
                                                          "y-offset": 0.0, "z-offset": -50.0}}}}, "100.0 µm from `kinematics`"),
    ({"tests": {"c_angles_deg": [0, 30, 30]}}, "each angle once"),
])
def test_a_wrong_procedure_is_one_line_and_exit_2(tmp_path, capsys, change, words):
    path = _variant(tmp_path, **change)
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err, err


def test_the_method_folder_uses_rtcal_only_through_its_public_face():
    folder = REPO / "rtcal" / "methods" / "rtest"
    wrong = []
    for path in folder.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            for name in names:
                top = name.split(".")[0]
                if top in ("drivers", "simulators") or (top == "rtcal" and not (
                        name in ("rtcal", "rtcal.api") or name.startswith(("rtcal.solvers", "rtcal.methods.rtest")))):
                    wrong.append(f"{path.name}: {name}")
    assert wrong == []


def test_rtcal_plan_prints_the_prediction_before_anything_moves(capsys):
    assert main(["plan", str(PROCEDURE), "--no-levers"]) == 0
    out = capsys.readouterr().out
    assert "71 planned readings" in out
    assert "predicted U (k = 2) of each location error: X0C" in out and "C0A" in out
    assert "not determined with this set-up: Z0C" in out and "not determined with this set-up: A0A" in out


def test_the_certificate_says_what_the_r_test_measured_and_leaves_out_what_it_did_not(shipped_run):
    """Page 1's subtitle names the location errors of A and C (ISO 230-7) and C's deviation, the standards applied
    begin with ISO 230-7; Annex C's periodic error (a positioning test) is absent from the certificate, report.md,
    report.html and report.pdf, and so is the method section's sentence on positioning-test figures. The method's
    declared flag decides it: the same results certified as a positioning method's carry the section again."""
    import pymupdf

    from rtcal.deliverables.certificate import Certificate, build_certificate
    from rtcal.methods.rtest.method import RTestMethod

    cert = Certificate.model_validate_json((shipped_run / "certificate.json").read_text())
    assert cert.header.subtitle.startswith("Location errors of the rotary axes A and C (ISO 230-7)")
    assert "angular positioning deviation of C" in cert.header.subtitle
    standards = next(i.value for i in cert.identification.items if i.label == "Standards applied")
    assert standards.startswith("ISO 230-7") and "ISO 10791-6" in standards
    assert cert.periodic_error is None
    assert not any("positioning-test" in p or "Annex C" in p for p in cert.method.paragraphs)
    pdf = " ".join(page.get_text() for page in pymupdf.open(shipped_run / "report.pdf").pages())
    for text in ((shipped_run / "report.md").read_text(), (shipped_run / "report.html").read_text(), pdf):
        assert "Periodic positioning error" not in text and "Annex C" not in text
    assert "Location errors of the rotary axes A and C" in " ".join(pymupdf.open(shipped_run / "report.pdf")[0].get_text().split())

    class AsPositioning(RTestMethod):
        positioning_deviation = True

    again = build_certificate(read_results(shipped_run), shipped_run, AsPositioning())
    assert again.periodic_error is not None and again.periodic_error.statement.startswith("Not tested")


# -- the sphere at two heights (sphere.second_position_mm) --------------------------------------------------------
TWO_HEIGHTS = REPO / "procedures" / "rtest_two_heights.yaml"


@pytest.fixture(scope="module")
def two_heights_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("rtest2") / "run"
    assert main(["run", str(TWO_HEIGHTS), "--out", str(out)]) == 0
    return out


def test_two_heights_recover_the_eight_within_u_and_shrink_the_tilts_u(two_heights_run, shipped_run):
    """The tests repeated with the sphere 120 mm higher: every location error within its U of the truth, the second
    set-up's offset found, and the four tilts (A0C, B0C of C; B0A, C0A of A) with a smaller U than one height gives
    (the second height is a lever arm of its own for them)."""
    two, one = read_results(two_heights_run), read_results(shipped_run)
    assert isinstance(two, RTestResults) and isinstance(one, RTestResults)
    truth = yaml.safe_load(SCENARIO.read_text())["machine"]
    for symbol, e in two.location_errors.items():
        assert abs(e.value - truth["location_errors"][symbol]) <= e.expanded_uncertainty, (symbol, e)
    assert set(two.location_errors) == set(LOCATION_SYMBOLS)
    U2 = {s: e.expanded_uncertainty for s, e in two.location_errors.items()}
    U1 = {s: e.expanded_uncertainty for s, e in one.location_errors.items()}
    for symbol in ("A0C_arcsec", "B0C_arcsec", "B0A_arcsec", "C0A_arcsec"):
        assert U2[symbol] < U1[symbol], (symbol, U2[symbol], U1[symbol])
    assert U2["C0A_arcsec"] < 0.7 * U1["C0A_arcsec"] and U2["A0C_arcsec"] < 0.95 * U1["A0C_arcsec"], (U2, U1)
    second = two.sphere.second
    assert second is not None and second.position_mm == [150.0, 0.0, 200.0]
    for found, u, true in zip(second.setup_um, second.setup_u_um, truth["sphere"]["setup_offsets_um"][1]):
        assert abs(found - true) <= 3 * u, (second.setup_um, truth["sphere"]["setup_offsets_um"][1])
    assert len(two.sphere_path.before_um) == 2 * len(one.sphere_path.before_um)
    assert two.residual_test is not None and two.residual_test.passed
    assert one.sphere.second is None and "second" not in json.loads((shipped_run / "results.json").read_text())["sphere"]


def test_each_height_corrects_its_own_drift(tmp_path):
    """A warming through the run (τ = 1000 s; the operator's move of the sphere included): each height's repeated
    first pose measures its own part of it, and the location errors stay within U."""
    scenario = yaml.safe_load(SCENARIO.read_text())
    scenario["machine"]["drift"] = {"amplitude_um": [30.0, -20.0, 40.0], "time_constant_s": 1e3}
    (tmp_path / "scenario.yaml").write_text(yaml.safe_dump(scenario))
    assert main(["run", str(TWO_HEIGHTS), "--scenario", str(tmp_path / "scenario.yaml"), "--out", str(tmp_path / "run")]) == 0
    results = read_results(tmp_path / "run")
    assert isinstance(results, RTestResults) and results.sphere.second is not None
    first, second = results.drift_um, results.sphere.second.drift_um
    assert min(abs(v) for v in second) > 0.5, (first, second)  # the noise alone: ~0.2 µm
    # a warming that slows: the second height, later in the run, drifts less than the first did
    assert all(abs(b) < abs(a) and a * b > 0 for a, b in zip(first, second)), (first, second)
    for symbol, e in results.location_errors.items():
        assert abs(e.value - scenario["machine"]["location_errors"][symbol]) <= e.expanded_uncertainty, (symbol, e)


def test_the_plan_moves_the_sphere_between_the_heights_and_predicts_u(capsys):
    from rtcal.api import Move, OperatorStep

    proc = load_procedure(TWO_HEIGHTS)
    plan = RTestMethod().plan(proc, set())
    groups = [e.group for e in plan.entries]
    assert groups == sorted(groups) and set(groups) == {0, 1}
    entry = next(e for e in plan.entries if e.group == 1)
    steps = list(plan.enter_group(entry, False))
    assert isinstance(steps[0], Move) and isinstance(steps[1], OperatorStep)
    assert "second position" in steps[1].instruction and "Z 200" in steps[1].instruction
    assert steps[1].simulate is not None  # the simulated operator mounts the second set-up
    resumed = RTestMethod().plan(proc, {e.index for e in plan.entries if e.group == 0})
    again = list(resumed.enter_group(entry, True))  # a run resumed at the second position: confirmed, not mounted anew
    assert len(again) == 1 and isinstance(again[0], OperatorStep) and "resumes at the sphere's second position" in \
        again[0].instruction and again[0].simulate is not None
    assert main(["plan", str(TWO_HEIGHTS), "--no-levers"]) == 0
    out = capsys.readouterr().out
    assert "135 planned readings" in out and "predicted U (k = 2) of each location error: X0C" in out


def test_a_second_height_the_scenario_lacks_is_one_line_and_exit_2(tmp_path, capsys):
    scenario = yaml.safe_load(SCENARIO.read_text())
    for key in ("positions_mm", "setup_offsets_um"):
        scenario["machine"]["sphere"][key] = scenario["machine"]["sphere"][key][:1]
    (tmp_path / "scenario.yaml").write_text(yaml.safe_dump(scenario))
    assert main(["run", str(TWO_HEIGHTS), "--scenario", str(tmp_path / "scenario.yaml"), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert "sphere.second_position_mm" in err and "Traceback" not in err, err


@pytest.mark.parametrize("kill_after", [100])  # in the second height's tests (7 calibration + 64 poses at the first)
def test_a_run_killed_at_the_second_height_resumes_onto_the_sphere_and_recovers_the_eight(tmp_path, kill_after):
    """SIGKILL mid-run, `rtcal resume`: the resumed machine goes onto the sphere from above before the sphere path
    (without it the first move strikes the nest), the simulated operator sets the second position up again, and
    the results are as a run without the kill's: each location error within U, the second set-up found."""
    from tests.test_crash_resume import _run_and_kill

    run = tmp_path / "run"
    assert _run_and_kill(["run", str(TWO_HEIGHTS), "--out", str(run)], run / "run.sqlite", kill_after)
    assert main(["resume", str(run)]) == 0
    results = read_results(run)
    assert isinstance(results, RTestResults) and results.sphere.second is not None
    truth = yaml.safe_load(SCENARIO.read_text())["machine"]
    for symbol, e in results.location_errors.items():
        assert abs(e.value - truth["location_errors"][symbol]) <= e.expanded_uncertainty, (symbol, e)
    for found, u, true in zip(results.sphere.second.setup_um, results.sphere.second.setup_u_um,
                              truth["sphere"]["setup_offsets_um"][1]):
        assert abs(found - true) <= 3 * u, results.sphere.second


def test_the_simulated_operator_sets_the_sphere_up_at_a_position_the_scenario_has():
    """`mount_sphere` is one of the bench's operator actions (what `rtcal sim serve`'s operator does on `DO
    mount_sphere [1]`): the machine's sphere is then the second set-up, before or after the machine is made; an index
    the scenario lacks is a ValueError (the hub's `ERR ARG`)."""
    from simulators.bench import Bench
    from simulators.machine_tool import machine_of
    from simulators.scenario import Scenario

    scenario = Scenario.model_validate(yaml.safe_load(SCENARIO.read_text()))
    assert "mount_sphere" in Bench.OPERATOR_ACTIONS
    early, late = Bench(scenario), Bench(scenario)
    early.mount_sphere(1)
    machine_of(late).sphere_centre_mm({"x": 0.0, "y": 0.0, "z": 0.0, "a": 0.0, "c": 0.0})
    late.mount_sphere(1)
    for bench in (early, late):
        centre = machine_of(bench).sphere_centre_mm({"x": 0.0, "y": 0.0, "z": 0.0, "a": 0.0, "c": 0.0})
        assert centre[2] == pytest.approx(200.0, abs=0.1)
    with pytest.raises(ValueError, match="sets up 2"):
        early.mount_sphere(2)
