"""Issue 42, item 5: the trend of an axis's location errors in the catalogue. `rtcal catalog add` files an R-test's
ISO 230-7 location errors (symbol, axis, value, U, k) in the table of migration 0005, on SQLite and on a real
PostgreSQL; `rtcal catalog history --serial S` prints each location error's values with U over time (and --json);
a catalogue of revision 0004 that already holds an R-test gets its location errors from the stored results text."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from rtcal.catalog.entry import entry_of, verified
from rtcal.catalog.store import Catalog
from rtcal.cli import main
from rtcal.deliverables.rounding import u_text, value_text
from rtcal.methods import read_results
from tests.catalog_entries import older_catalogue
from tests.test_catalog import db, postgres, rig_outbox  # noqa: F401  (fixtures)

REPO = Path(__file__).resolve().parents[1]
PROCEDURE = REPO / "procedures" / "rtest_trunnion.yaml"
SCENARIO = REPO / "procedures" / "scenarios" / "rtest_trunnion.yaml"
SERIAL = yaml.safe_load(PROCEDURE.read_text())["metadata"]["serial_number"]
MOVED = {"X0C_um": -30.0, "Z0A_um": -25.0, "B0C_arcsec": 8.0}  # the second run's truth less the first's


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory) -> tuple[Path, Path]:
    """Two simulated R-tests of one machine: the shipped scenario's truth, then a truth moved by MOVED."""
    base = tmp_path_factory.mktemp("rtest_catalog")
    scenario = yaml.safe_load(SCENARIO.read_text())
    for symbol, change in MOVED.items():
        scenario["machine"]["location_errors"][symbol] += change
    (base / "moved.yaml").write_text(yaml.safe_dump(scenario, sort_keys=False))
    first, second = base / "first", base / "second"
    assert main(["run", str(PROCEDURE), "--out", str(first)]) == 0
    assert main(["run", str(PROCEDURE), "--scenario", str(base / "moved.yaml"), "--out", str(second)]) == 0
    return first, second


def _history(capsys, db_: str, *more: str) -> str:
    capsys.readouterr()
    assert main(["catalog", "history", "--serial", SERIAL, "--db", db_, *more]) == 0
    return capsys.readouterr().out


def test_each_location_error_is_filed_and_its_history_shows_it_over_time(db, two_runs, capsys):  # noqa: F811
    first, second = two_runs
    assert main(["catalog", "add", "--allow-simulated", str(first), str(second), "--db", db]) == 0
    entries = json.loads(_history(capsys, db, "--json"))
    assert [Path(e["run_dir"]).name for e in entries] == ["first", "second"]
    measured = [read_results(run).location_errors for run in two_runs]  # type: ignore[attr-defined]
    for e, run in zip(entries, measured):
        filed = e["location_errors_iso230_7"]
        assert set(filed) == set(run) and len(filed) == 8
        for symbol, x in run.items():
            assert filed[symbol] == {"axis": x.axis, "value": pytest.approx(x.value), "coverage_factor": x.coverage_factor,
                                     "expanded_uncertainty": pytest.approx(x.expanded_uncertainty)}
    # the trend is the machine's: what moved between the runs moved by the truth's change, within U
    before, after = (e["location_errors_iso230_7"] for e in entries)
    for symbol in before:
        change = after[symbol]["value"] - before[symbol]["value"]
        U = after[symbol]["expanded_uncertainty"] + before[symbol]["expanded_uncertainty"]
        assert abs(change - MOVED.get(symbol, 0.0)) <= U, (symbol, change, U)
    text = _history(capsys, db)
    line = next(ln for ln in text.splitlines() if ln.strip().startswith("X0C"))
    a, b = (run["X0C_um"] for run in measured)
    assert line.strip().startswith("X0C (µm, axis C):")
    assert line.index(f"{value_text(a.value, a.expanded_uncertainty, '+')} ± {u_text(a.expanded_uncertainty)}") < \
        line.index(f"{value_text(b.value, b.expanded_uncertainty, '+')} ± {u_text(b.expanded_uncertainty)}")
    assert sum(ln.startswith("  ") and "axis" in ln for ln in text.splitlines()) == 8
    assert main(["catalog", "verify", "--db", db]) == 0


def test_a_catalogue_of_revision_0004_gets_its_r_tests_location_errors_when_migrated(two_runs, tmp_path):
    """The R-test filed before the table existed: migration 0005 reads its location errors from the stored results
    text; the run added after it files its own."""
    first, second = two_runs
    path = tmp_path / "older.sqlite"
    results, signature = verified(first)
    older_catalogue(path, "0004", [entry_of(first, results, signature)])
    with Catalog(str(path)) as cat:
        assert not cat.locations and cat.location_errors_of([e["run_id"] for e in cat.machines()]) == []
    assert main(["catalog", "add", "--allow-simulated", str(second), "--db", str(path)]) == 0
    with Catalog(str(path)) as cat:
        runs = [e["run_id"] for e in cat.history(SERIAL)]
        filed = cat.location_errors_of(runs)
    assert len(runs) == 2 and {(e["run_id"], e["symbol"]) for e in filed} == {(r, s) for r in runs for s in results.location_errors}  # type: ignore[attr-defined]
    stored = {e["symbol"]: e["value"] for e in filed if e["run_id"] == runs[0]}
    assert stored == pytest.approx({s: x.value for s, x in results.location_errors.items()})  # type: ignore[attr-defined]


def test_the_filed_location_errors_are_append_only_and_verify_deep_names_an_edit(two_runs, tmp_path, capsys):
    """The table refuses UPDATE and DELETE (as the rest of the record); a hand that drops the triggers and edits a
    value is named by `catalog verify --deep`, which checks the rows against the entry's hashed results text."""
    import shutil
    import sqlite3
    from contextlib import closing

    path = tmp_path / "catalog.sqlite"
    assert main(["catalog", "add", "--allow-simulated", str(two_runs[0]), "--db", str(path)]) == 0
    assert main(["catalog", "verify", "--deep", "--db", str(path)]) == 0
    with closing(sqlite3.connect(path)) as conn:
        for sql in ("UPDATE location_errors SET value = 0", "DELETE FROM location_errors"):
            with pytest.raises(sqlite3.IntegrityError, match="append-only"):
                conn.execute(sql)
    edited = tmp_path / "edited.sqlite"
    shutil.copy(path, edited)
    with closing(sqlite3.connect(edited)) as conn, conn:
        for (trigger,) in conn.execute("SELECT name FROM sqlite_master WHERE type = 'trigger'").fetchall():
            conn.execute(f"DROP TRIGGER {trigger}")
        conn.execute("UPDATE location_errors SET value = value + 5 WHERE symbol = 'X0C_um'")
    capsys.readouterr()
    assert main(["catalog", "verify", "--deep", "--db", str(edited)]) == 1
    said = capsys.readouterr()
    assert "its filed location errors are not its results text's" in said.out + said.err
