"""Issue 33: `rtcal catalog` on a real SQLite file and a real PostgreSQL server (started here, never
a mock): verified runs only, one transaction per run, idempotent and concurrent adds, a server that
is down or drops mid-add, no password anywhere, and a machine axis's history with E's trend."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest

from rtcal.catalog.history import next_due, pairs, trend
from rtcal.catalog.store import Catalog
from rtcal.cli import main
from rtcal.deliverables.conformity import parameter_uncertainties
from rtcal.deliverables.rounding import u_text, value_text
from rtcal.methods import read_results
from tests.postgres_server import PostgresServer, binaries

REPO = Path(__file__).resolve().parents[1]
PROCEDURE = REPO / "procedures" / "iso230_2_verification.yaml"
SERIAL = "SIM-230-2"
OUTBOX = Path(tempfile.mkdtemp(prefix="rtcal-outbox-"))  # a rig's outbox in the tests: never the user's own


@pytest.fixture(autouse=True)
def rig_outbox(monkeypatch):
    """Every test's rig keeps its outbox in a folder of its own, never the user's."""
    monkeypatch.setenv("RTCAL_OUTBOX", str(OUTBOX))


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("catalog") / "run"
    assert main(["run", str(PROCEDURE), "--virtual-clock", "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def postgres():
    if binaries() is None:
        pytest.skip("PostgreSQL's binaries are not installed (Debian's postgresql package)")
    server = PostgresServer()
    server.start()
    yield server
    server.remove()


@pytest.fixture(params=["sqlite", "postgresql"])
def db(request, tmp_path) -> str:
    if request.param == "sqlite":
        return str(tmp_path / "catalog.sqlite")
    server = request.getfixturevalue("postgres")
    return server.create_database(f"t{time.monotonic_ns()}")


def _cli(*argv: str, env: dict[str, str] | None = None, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "rtcal.cli", *argv], capture_output=True, text=True, timeout=timeout,
                          cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO), "RTCAL_OUTBOX": str(OUTBOX), **(env or {})})


def _count(db: str) -> int:
    if "://" not in db and not Path(db).exists():  # a refused add creates no file (and reading one is refused)
        return 0
    with Catalog(db) as cat:
        return cat.count()


def _password(db: str) -> str | None:
    return db.split(":")[2].split("@")[0] if db.startswith("postgresql://") else None


def test_a_run_is_added_once_and_its_history_lists_it(db, finished_run, capsys):
    assert main(["catalog", "add", "--allow-simulated", str(finished_run), "--db", db]) == 0
    assert main(["catalog", "add", "--allow-simulated", str(finished_run), "--db", db]) == 0  # again: nothing changes
    out = capsys.readouterr().out
    assert "added to" in out and "already in" in out
    assert _count(db) == 1
    assert main(["catalog", "history", "--serial", SERIAL, "--axis", "C", "--db", db, "--json"]) == 0
    history = json.loads(capsys.readouterr().out)
    results = json.loads((finished_run / "results.json").read_text())
    assert len(history) == 1
    entry = history[0]
    for key in ("run_id", "serial_number", "axis", "measured_utc", "method", "E_arcsec", "E_U_arcsec", "verdict"):
        assert key in entry
    assert entry["E_arcsec"] == results["evaluation"]["iso230_2"]["E"]
    assert entry["verdict"] == results["conformity"]["verdict"]
    assert entry["digests"] == results["digests"]
    assert entry["E_U_arcsec"] > 0 and entry["run_dir"] == str(finished_run.resolve())
    with Catalog(db) as cat:  # the whole results.json is kept
        assert json.loads(cat.history(SERIAL, "C", with_results=True)[0]["results"]) == results
    assert main(["catalog", "list", "--db", db, "--json"]) == 0
    fleet = json.loads(capsys.readouterr().out)
    assert [(m["serial_number"], m["axis"], m["calibrations"]) for m in fleet] == [(SERIAL, "C", 1)]
    assert fleet[0]["next_due"] > entry["measured_utc"][:10]
    password = _password(db)
    assert password is None or password not in capsys.readouterr().err


def _tampered(run: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "tampered"
    shutil.copytree(run, copy)
    data = json.loads((copy / "results.json").read_text())
    data["evaluation"]["iso230_2"]["E"] -= 5.0
    (copy / "results.json").write_text(json.dumps(data))
    return copy


def test_a_tampered_or_unfinished_run_is_refused_and_nothing_is_written(db, finished_run, tmp_path):
    bad = _tampered(finished_run, tmp_path)
    unfinished = tmp_path / "unfinished"
    shutil.copytree(finished_run, unfinished)
    (unfinished / "results.json").unlink()
    for run, code in ((bad, 1), (unfinished, 2)):
        r = _cli("catalog", "add", "--allow-simulated", str(finished_run), str(run), "--db", db)
        assert r.returncode == code, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr and str(run) in r.stderr
    assert _count(db) == 0  # the good run before the bad one is not written either


def test_two_processes_adding_the_same_run_make_one_entry(db, finished_run):
    procs = [subprocess.Popen([sys.executable, "-m", "rtcal.cli", "catalog", "add", "--allow-simulated", str(finished_run), "--db", db],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO,
                              env={**os.environ, "PYTHONPATH": str(REPO)}) for _ in range(2)]
    outs = [p.communicate(timeout=120) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    assert _count(db) == 1


def test_a_database_that_is_down_fails_in_one_line_without_the_password_and_works_when_back(postgres, finished_run):
    db = postgres.create_database("down")
    postgres.stop()
    try:
        t0 = time.monotonic()
        r = _cli("catalog", "add", "--allow-simulated", str(finished_run), "--db", db)
        assert r.returncode == 1 and time.monotonic() - t0 < 30
        assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
        assert f"127.0.0.1:{postgres.port}/down" in r.stderr and postgres.password not in r.stderr + r.stdout
    finally:
        postgres.start()
    assert _cli("catalog", "add", "--allow-simulated", str(finished_run), "--db", db).returncode == 0
    assert _count(db) == 1


def test_a_server_that_drops_mid_add_leaves_nothing_and_the_add_works_again(postgres, finished_run, monkeypatch, capsys):
    db = postgres.create_database("drops")
    assert _count(db) == 0  # migrated: the add below only inserts
    monkeypatch.setattr(Catalog, "before_commit", staticmethod(lambda: postgres.stop("immediate")))
    try:
        t0 = time.monotonic()
        assert main(["catalog", "add", "--allow-simulated", str(finished_run), "--db", db]) == 1
        assert time.monotonic() - t0 < 30
    finally:
        postgres.start()
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "nothing of it was written" in err and postgres.password not in err
    monkeypatch.setattr(Catalog, "before_commit", None)
    assert _count(db) == 0
    assert main(["catalog", "add", "--allow-simulated", str(finished_run), "--db", db]) == 0
    assert _count(db) == 1


def test_the_default_catalogue_is_a_sqlite_file_named_by_rtcal_catalog(finished_run, tmp_path):
    path = tmp_path / "env" / "lab.sqlite"
    r = _cli("catalog", "add", "--allow-simulated", str(finished_run), env={"RTCAL_CATALOG": str(path)})
    assert r.returncode == 0, r.stderr
    assert path.is_file() and _count(str(path)) == 1
    home = tmp_path / "home"
    r = _cli("catalog", "add", "--allow-simulated", str(finished_run), env={"RTCAL_CATALOG": "", "HOME": str(home), "XDG_DATA_HOME": ""})
    assert r.returncode == 0 and (home / ".local/share/rtcal/catalog.sqlite").is_file()


def _row(days: float, e: float, u: float = 1.0, limit: float = 60.0) -> dict:
    t = datetime(2020, 1, 1, tzinfo=timezone.utc) + timedelta(days=days)
    return {"run_id": f"r{days}", "measured_utc": t.isoformat(), "E_arcsec": e, "E_U_arcsec": u, "E_limit_arcsec": limit}


def test_the_trend_is_a_weighted_line_that_leaves_out_as_left_runs():
    # as found drifts 4″/year from 40″; each year a compensation (as left, 3 days later) brings E to 20″
    rows = []
    for year in range(4):
        rows += [_row(365.25 * year, 40 + 4 * year), _row(365.25 * year + 3, 20)]
    assert pairs(rows) == [(0, 1), (2, 3), (4, 5), (6, 7)]
    t = trend(rows)
    assert t["runs_fitted"] == 4 and t["E_trend_arcsec_per_year"] == pytest.approx(4.0, abs=1e-6)
    five_years = datetime(2020, 1, 1, tzinfo=timezone.utc) + timedelta(days=5 * 365.25)  # 40 + 4·5 = 60
    assert abs(datetime.fromisoformat(t["E_reaches_limit_utc"]) - five_years) < timedelta(minutes=1)
    # U of b from the runs' u = 0.5: Var(b) = Σw/det
    x = [0, 1, 2, 3]
    s, sx, sxx = 4 * 4.0, 4.0 * sum(x), 4.0 * sum(v * v for v in x)
    assert t["E_trend_U_arcsec_per_year"] == pytest.approx(2 * (s / (s * sxx - sx * sx)) ** 0.5, abs=1e-4)
    assert next_due(rows) == "2024-01-03"  # a year after the last run (2023-01-03): the limit (2024-12-31) is later
    beyond = [_row(0, 50), _row(365.25, 58), _row(730.5, 66)]  # over its limit at the last run: due then
    assert next_due(beyond) == beyond[-1]["measured_utc"][:10]
    heavy = [_row(0, 40, u=0.1), _row(365.25, 50, u=100.0), _row(730.5, 40, u=0.1)]  # a weight counts
    assert abs(trend(heavy)["E_trend_arcsec_per_year"]) < 0.01


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed")
def test_the_catalog_page_shows_the_fleet_and_a_machines_history_in_chromium(finished_run, tmp_path):
    import re

    sync_api = pytest.importorskip("playwright.sync_api")
    db = str(tmp_path / "catalog.sqlite")
    assert main(["catalog", "add", "--allow-simulated", str(finished_run), "--db", db]) == 0
    proc = subprocess.Popen([sys.executable, "-m", "rtcal.cli", "view", "--catalog", "--db", db, "--live", "127.0.0.1:0"],
                            cwd=REPO, stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        url = None
        for _ in range(20):
            if m := re.search(r"catalog view: (http://\S+)", proc.stderr.readline()):
                url = m.group(1)
                break
        assert url, "no URL printed"
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
            page = browser.new_page()
            page.goto(url)
            row = page.locator("#fleet tr.machine")
            assert row.count() == 1
            text = row.first.inner_text()
            results = json.loads((finished_run / "results.json").read_text())
            assert SERIAL in text and results["conformity"]["verdict"] in text
            page.click(f"text={SERIAL}")
            page.wait_for_selector("#history tr.run")
            assert page.locator("#history tr.run").count() == 1
            u_e = parameter_uncertainties(read_results(finished_run))["E"]  # E ± U as the certificate rounds them
            shown = f'{value_text(results["evaluation"]["iso230_2"]["E"], u_e)} ± {u_text(u_e)}'
            assert shown in page.locator("#history").inner_text(), shown
            page.screenshot(path=str(tmp_path / "catalog.png"), full_page=True)
            browser.close()
    finally:
        proc.terminate()
        proc.wait(20)
    assert proc.returncode == 0
