"""Issue 40, items 8 and 9: a catalogue one entry cannot break, and one nobody else can read.

Item 8: flat or barely rising trends give "beyond 100 years", never an OverflowError; every field
is checked at add; an odd entry already in a catalogue is listed and left out of trends; a serial
with `$…$` is drawn as text; JSON output is strict. Item 9: the page refuses a foreign Host and
warns when bound beyond loopback; in-memory SQLite refused; a password given as `?password=`
hidden; a malformed URL one line; a read-only catalogue readable; serial numbers normalised (on
add, by migration 0002, and on reading a catalogue not yet migrated); a missing --db file refused
for reading, never created."""

from __future__ import annotations

import hashlib
import http.client
import json
import math
import os
import random
import re
import shutil
import sqlite3
import subprocess
import sys
from contextlib import closing
from pathlib import Path

import pytest

from rtcal.catalog.entry import entry_of
from rtcal.catalog.history import BEYOND, fleet, history_document, next_due, trend
from rtcal.catalog.store import MIGRATIONS, Catalog
from rtcal.cli import main
from rtcal.methods import read_results
from tests.catalog_entries import older_catalogue
from tests.test_catalog import _cli, _row, db, finished_run, postgres, rig_outbox  # noqa: F401  (fixtures)

REPO = Path(__file__).resolve().parents[1]


def _strict(text: str):
    """JSON as a strict parser reads it: NaN and Infinity refused."""
    def refuse(name: str):
        raise ValueError(f"not JSON: {name}")
    return json.loads(text, parse_constant=refuse)


def _entry(run: Path, **changes) -> dict:
    """The catalogue row of ``run`` with ``changes`` (its own run id), as an older rtcal or a hand
    may have left it: not checked."""
    row = entry_of(run, read_results(run), check=False)
    row.update(changes)
    row["run_id"] = hashlib.sha256(json.dumps(sorted(changes.items()), default=str).encode()).hexdigest()[:32]
    return row


def _insert(db_: str, *rows: dict) -> None:
    with Catalog(db_, write=True) as cat:
        for r in rows:
            assert cat.add(r)


def _at(days: float) -> str:
    return _row(days, 0)["measured_utc"]


def _full(rows: list[dict]) -> list[dict]:
    return [{**r, "serial_number": "S", "axis": "C", "machine": "", "customer": "", "verdict": "pass"} for r in rows]


# -- item 8 --------------------------------------------------------------------------------------

def test_flat_and_barely_rising_trends_are_beyond_100_years_not_an_overflow():
    rng = random.Random(40)
    for _ in range(300):  # three equal E at three dates: the fit's slope is 0 give or take rounding
        e, u = round(rng.uniform(1, 50), 2), round(rng.uniform(0.2, 3), 2)
        rows = [_row(d, e, u=u) for d in sorted(round(rng.uniform(0, 1500), 2) for _ in range(3))]
        t = trend(rows)
        assert t["E_reaches_limit_utc"] is None and t["E_reaches_limit"] in (BEYOND, "not on this trend (E does not rise)")
        assert next_due(rows) is not None and history_document(_full(rows))["C"]["trend"] == t and fleet(_full(rows))
    slow = [_row(0, 20.0), _row(365.25, 20.0001)]  # 0.0001″ a year: 400 000 years to the limit
    assert trend(slow)["E_reaches_limit"] == BEYOND and trend(slow)["E_reaches_limit_utc"] is None
    assert next_due(slow) == "2021-12-31"  # a year after the last
    over = [_row(0, 70, u=0.28), _row(324.29, 70, u=0.28), _row(411.18, 70, u=0.28)]  # flat and over its limit (60″)
    assert next_due(over) == over[-1]["measured_utc"][:10]  # due now, whatever the slope's last bit
    assert fleet(_full(slow))[0]["next_due"] == "2021-12-31"


def test_an_odd_entry_already_in_the_catalogue_breaks_no_list(finished_run, tmp_path, capsys):
    db_ = str(tmp_path / "old.sqlite")
    good = _entry(finished_run, measured_utc=_at(0))
    odd = [_entry(finished_run, measured_utc="yesterday"), _entry(finished_run, measured_utc="0001-01-01T00:00:00"),
           _entry(finished_run, measured_utc=_at(30), E_arcsec=math.nan, E_U_arcsec=math.inf)]
    _insert(db_, good, *odd)
    assert main(["catalog", "list", "--db", db_, "--json"]) == 0
    listed = _strict(capsys.readouterr().out)
    assert [m["calibrations"] for m in listed] == [4]
    assert main(["catalog", "history", "--serial", good["serial_number"], "--db", db_, "--json"]) == 0
    entries = _strict(capsys.readouterr().out)
    assert len(entries) == 4 and any(e["E_arcsec"] is None for e in entries)  # NaN written as null
    assert main(["catalog", "history", "--serial", good["serial_number"], "--db", db_]) == 0
    assert main(["catalog", "history", "--serial", good["serial_number"], "--db", db_,
                 "--plot", str(tmp_path / "h.png")]) == 0
    assert (tmp_path / "h.png").stat().st_size > 5000
    from rtcal.catalog.page import _page

    assert "yesterday" in _page(db_, good["serial_number"])


@pytest.mark.parametrize("field, value, says", [
    ("started_utc", "yesterday", "start time"),
    ("started_utc", "2024-13-45T00:00:00", "start time"),
    ("started_utc", "1900-01-01T00:00:00+00:00", "before 1970"),
    ("started_utc", "2999-01-01T00:00:00+00:00", "in the future"),
    ("finished_utc", "soon", "end time"),
    ("serial_number", "SN\u202e1", "U+202E"),
    ("serial_number", "S" * 101, "longer than 100"),
    ("serial_number", "  ", "serial number"),
    ("E", math.nan, "E_arcsec"),
    ("E", math.inf, "E_arcsec"),
])
def test_every_field_is_checked_at_add(finished_run, tmp_path, monkeypatch, capsys, field, value, says):
    from rtcal.catalog import entry as entry_module

    results = read_results(finished_run)
    if field in ("started_utc", "finished_utc"):
        results = results.model_copy(update={field: value})
    elif field == "serial_number":
        results = results.model_copy(update={"metadata": results.metadata.model_copy(update={field: value})})
    else:
        iso = results.evaluation.iso230_2.model_copy(update={field: value})
        results = results.model_copy(update={"evaluation": results.evaluation.model_copy(update={"iso230_2": iso})})
    monkeypatch.setattr(entry_module, "verified", lambda _run: (results, "unsigned"))  # as if verify had passed it
    db_ = tmp_path / "c.sqlite"
    assert main(["catalog", "add", str(finished_run), "--allow-simulated", "--db", str(db_)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and says in err and "cannot go into the catalogue" in err, err
    assert not db_.exists()  # nothing written


def test_an_added_time_is_kept_in_utc(finished_run, tmp_path, monkeypatch):
    from rtcal.catalog import entry as entry_module

    results = read_results(finished_run).model_copy(update={"started_utc": "2024-05-01T14:00:00+02:00"})
    monkeypatch.setattr(entry_module, "verified", lambda _run: (results, "unsigned"))
    db_ = str(tmp_path / "c.sqlite")
    assert main(["catalog", "add", str(finished_run), "--allow-simulated", "--db", db_]) == 0
    with Catalog(db_) as cat:
        assert [r["measured_utc"] for r in cat.machines()] == ["2024-05-01T12:00:00+00:00"]


def test_a_serial_with_dollars_is_drawn_as_text(finished_run, tmp_path):
    db_ = str(tmp_path / "c.sqlite")
    serial = r"SN $\frac{$-7"  # matplotlib's mathtext would fail on it (a traceback, no plot)
    _insert(db_, _entry(finished_run, serial_number=serial, measured_utc=_at(0)),
            _entry(finished_run, serial_number=serial, measured_utc=_at(400)))
    r = _cli("catalog", "history", "--serial", serial, "--db", db_, "--plot", str(tmp_path / "h.png"))
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr[-2000:]
    assert (tmp_path / "h.png").stat().st_size > 5000
    from rtcal.deliverables.figures import plt

    fig, ax = plt.subplots()
    title = ax.set_title(serial)
    assert not title.get_parse_math()  # every plot of rtcal: text as written
    plt.close(fig)


# -- item 9 --------------------------------------------------------------------------------------

def _serve(db_: str, live: str) -> tuple[subprocess.Popen, str, list[str]]:
    proc = subprocess.Popen([sys.executable, "-m", "rtcal.cli", "view", "--catalog", "--db", db_, "--live", live],
                            cwd=REPO, stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(REPO)})
    lines = []
    for _ in range(20):
        line = proc.stderr.readline()
        lines.append(line)
        if m := re.search(r"catalog view: http://\S+:(\d+)/", line):
            return proc, m.group(1), lines
    proc.kill()
    raise AssertionError(f"no URL printed: {lines}")


def _get(port: str, host_header: str, path: str = "/api/catalog") -> int:
    conn = http.client.HTTPConnection("127.0.0.1", int(port), timeout=20)
    conn.request("GET", path, headers={"Host": host_header})
    status = conn.getresponse().status
    conn.close()
    return status


def test_the_catalogue_page_refuses_a_foreign_host_and_warns_beyond_loopback(finished_run, tmp_path):
    db_ = str(tmp_path / "c.sqlite")
    assert main(["catalog", "add", str(finished_run), "--allow-simulated", "--db", db_]) == 0
    proc, port, lines = _serve(db_, "127.0.0.1:0")
    try:
        assert _get(port, f"127.0.0.1:{port}") == 200 and _get(port, f"localhost:{port}", "/") == 200
        assert _get(port, "attacker.example") == 400 and _get(port, "attacker.example", "/?serial=SIM-230-2") == 400
    finally:
        proc.terminate()
        proc.wait(20)
    assert not any("warning" in line for line in lines)
    proc, port, lines = _serve(db_, "0.0.0.0:0")
    try:
        assert _get(port, "anything.example") == 200  # reachable from the lab's network, as it warns
    finally:
        proc.terminate()
        proc.wait(20)
    assert any(line.startswith("rtcal: warning: the catalogue page listens on 0.0.0.0") for line in lines), lines


@pytest.mark.parametrize("url", ["sqlite://", "sqlite:///:memory:"])
def test_an_in_memory_catalogue_is_refused(finished_run, url):
    for argv in (["add", str(finished_run), "--allow-simulated"], ["list"], ["history", "--serial", "SIM-230-2"]):
        r = _cli("catalog", *argv, "--db", url)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "in-memory" in r.stderr, r.stderr


def test_a_malformed_url_is_one_line_and_hides_its_password():
    for url in ("postgresql://[::1", "postgresql://rtcal:hunter2secret@[::1"):
        r = _cli("catalog", "list", "--db", url)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr, r.stderr
        assert "hunter2secret" not in r.stderr and "not a database URL" in r.stderr


def test_a_password_given_as_a_query_parameter_is_hidden(postgres, finished_run):
    assert _cli("catalog", "add", str(finished_run), "--allow-simulated", "--db", postgres.create_database("query")).returncode == 0
    base = f"postgresql://rtcal_test@127.0.0.1:{postgres.port}"
    r = _cli("catalog", "list", "--db", f"{base}/query?password={postgres.password}")
    assert r.returncode == 0 and "SIM-230-2" in r.stdout, r.stderr  # the password works there …
    for url in (f"{base}/nosuchdb?password={postgres.password}", f"{base}/query?password={postgres.password}x"):
        r = _cli("catalog", "list", "--db", url)  # … and a failing one is named without it
        assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert postgres.password not in r.stderr + r.stdout and "password=***" in r.stderr, r.stderr


def _read_only_disk(folder: Path) -> list[str]:
    """A command prefix that runs rtcal with ``folder`` on a read-only disk: as root, the folder
    bind-mounted read-only onto itself in a mount namespace of its own (gone with the process);
    otherwise the folder and its files made read-only (chmod), which binds a user who is not root."""
    if os.geteuid() != 0:
        for path in folder.iterdir():
            path.chmod(0o444)
        folder.chmod(0o555)
        return []
    if shutil.which("unshare") is None:
        pytest.skip("root without unshare(1): no read-only disk to test on")
    script = f'mount --bind "{folder}" "{folder}" && mount -o remount,bind,ro "{folder}" && exec "$@"'
    return ["unshare", "-m", "--propagation", "private", "sh", "-c", script, "sh"]


def test_a_catalogue_on_a_read_only_disk_is_read_as_it_is(finished_run, tmp_path):
    folder = tmp_path / "disk"
    folder.mkdir()
    db_ = folder / "lab.sqlite"
    assert main(["catalog", "add", str(finished_run), "--allow-simulated", "--db", str(db_)]) == 0  # written in WAL mode
    with closing(sqlite3.connect(db_)) as conn:
        assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert sorted(p.name for p in folder.iterdir()) == ["lab.sqlite"]  # closed: no -wal, no -shm left
    before = db_.read_bytes()
    prefix = _read_only_disk(folder)
    try:
        for argv, shows in ((["list", "--json"], '"serial_number": "SIM-230-2"'),
                            (["history", "--serial", "SIM-230-2"], "next due")):
            r = subprocess.run([*prefix, sys.executable, "-m", "rtcal.cli", "catalog", *argv, "--db", str(db_)],
                               capture_output=True, text=True, timeout=120, cwd=REPO,
                               env={**os.environ, "PYTHONPATH": str(REPO)})
            assert r.returncode == 0 and shows in r.stdout, r.stderr
    finally:
        folder.chmod(0o755)
    assert db_.read_bytes() == before and sorted(p.name for p in folder.iterdir()) == ["lab.sqlite"]


def test_a_missing_catalogue_is_refused_for_reading_never_created(tmp_path):
    missing = tmp_path / "typo.sqlite"
    for argv in (["catalog", "list"], ["catalog", "history", "--serial", "SN"], ["view", "--catalog", "--live", "127.0.0.1:0"]):
        r = _cli(*argv, "--db", str(missing), timeout=60)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "no catalogue there" in r.stderr, r.stderr
        assert not missing.exists()


SPELLINGS = ("Acme Ré 7", "Acme Re\u0301  7 ", " Acme\u00a0Ré 7")  # NFC, NFD with doubled and trailing space, NBSP


def test_one_machine_typed_three_ways_has_one_history(db, finished_run, monkeypatch, capsys):
    from rtcal.catalog import entry as entry_module

    base = read_results(finished_run)
    for k, serial in enumerate(SPELLINGS):
        results = base.model_copy(update={"started_utc": _at(200 * k),
                                          "metadata": base.metadata.model_copy(update={"serial_number": serial,
                                                                                       "certificate_number": f"N-{k}"})})
        monkeypatch.setattr(entry_module, "verified", lambda _run, r=results: (r, "unsigned"))
        assert main(["catalog", "add", str(finished_run), "--allow-simulated", "--db", db]) == 0
    capsys.readouterr()
    assert main(["catalog", "list", "--db", db, "--json"]) == 0
    assert [(m["serial_number"], m["calibrations"]) for m in _strict(capsys.readouterr().out)] == [("Acme Ré 7", 3)]
    for serial in SPELLINGS:
        assert main(["catalog", "history", "--serial", serial, "--db", db, "--json"]) == 0
        assert len(_strict(capsys.readouterr().out)) == 3


def test_entries_from_before_normalising_are_one_history_read_as_they_are_and_after_migration(finished_run, tmp_path):
    """A catalogue an older rtcal wrote (revision 0001, names as typed): read without migrating it
    (normalised on reading), then migrated by the next add (0002 normalises the entries themselves)."""
    path = tmp_path / "old.sqlite"
    older_catalogue(path, "0001", [_entry(finished_run, serial_number=serial, measured_utc=_at(200 * k))
                                   for k, serial in enumerate(SPELLINGS)])
    assert _cli("catalog", "history", "--serial", SPELLINGS[0], "--db", str(path)).returncode == 0
    with closing(sqlite3.connect(path)) as conn:
        assert conn.execute("SELECT version_num FROM alembic_version").fetchone()[0] == "0001"  # reading migrated nothing
    r = _cli("catalog", "list", "--db", str(path), "--json")
    assert [(m["serial_number"], m["calibrations"]) for m in _strict(r.stdout)] == [("Acme Ré 7", 3)], r.stderr
    with Catalog(str(path), write=True):  # what `catalog add` opens: migrated to the newest
        pass
    with closing(sqlite3.connect(path)) as conn:
        assert {r[0] for r in conn.execute("SELECT serial_number FROM calibrations")} == {"Acme Ré 7"}
        assert conn.execute("SELECT version_num FROM alembic_version").fetchone()[0] == _newest_migration()


def _newest_migration() -> str:
    from alembic.config import Config
    from alembic.script import ScriptDirectory

    from rtcal.catalog.store import MIGRATIONS

    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS))
    return ScriptDirectory.from_config(cfg).get_current_head() or ""
