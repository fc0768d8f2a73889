"""Issue 45 (a lab's calibration programme on the catalogue) and issue 46 item 7 (the catalogue in a
lab manager's words), on a real SQLite file and a real PostgreSQL server started here.

Reference instruments per entry and `used-by`; `reassess` from the stored readings, with superseding
certificates in new folders; the audit trail and `catalog verify`; declared as-found/as-left; the
due list, sites, retirements; interval methods; the rig's outbox; PostgreSQL roles from
docs/catalog.md; machine identity from an MTConnect agent's probe."""

from __future__ import annotations

import hashlib
import http.server
import json
import re
import secrets
import shutil
import sqlite3
import subprocess
import sys
import threading
import time
from contextlib import closing
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest
import yaml

from rtcal.catalog.audit import GENESIS
from rtcal.catalog.schema import audit
from rtcal.catalog.history import pair_info, trend
from rtcal.catalog.intervals import AxisPolicy, next_due
from rtcal.catalog.store import Catalog
from rtcal.cli import main
from tests.catalog_entries import older_catalogue
from tests.catalog_entries import synthetic as _synthetic
from tests.test_catalog import OUTBOX, _cli, db, postgres, rig_outbox  # noqa: F401  (fixtures)

REPO = Path(__file__).resolve().parents[1]
POLYGON = "Möller-Wedel 24-face polygon SN 4711 (simulated)"
AUTOCOLLIMATOR = "Möller-Wedel ELCOMAT 3000 SN 1234 (simulated)"
ENCODER = "Canon M-1H (the item's encoder)"
SERIAL = "SIM-230-2"
BENCH = REPO / "procedures" / "scenarios" / "abbe_bench.yaml"

PROBE = """<?xml version="1.0" encoding="UTF-8"?>
<MTConnectDevices xmlns="urn:mtconnect.org:MTConnectDevices:2.2">
  <Header creationTime="2026-01-01T00:00:00Z" sender="agent" instanceId="1" version="2.2.0" bufferSize="1024"/>
  <Devices>
    <Device uuid="rt-200-0042" name="{name}" id="d1">
      <Description manufacturer="Parker" model="200RT" serialNumber="{serial}" station="cell 2">Rotary table</Description>
    </Device>{more}
  </Devices>
</MTConnectDevices>"""
LAUGHS = """<?xml version="1.0"?>
<!DOCTYPE lolz [<!ENTITY lol "lol"><!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">]>
<MTConnectDevices><Devices><Device uuid="x" name="x"><Description serialNumber="&lol2;"/></Device></Devices></MTConnectDevices>"""
ERROR = """<?xml version="1.0"?><MTConnectError xmlns="urn:mtconnect.org:MTConnectError:2.2"><Errors>
<Error errorCode="NO_DEVICE">Could not find the device 'NOPE'</Error></Errors></MTConnectError>"""


class _Agent(http.server.BaseHTTPRequestHandler):
    """A static MTConnect agent: the documents a real one answers /DEVICE/probe with."""

    def do_GET(self) -> None:  # noqa: N802 (http.server's name)
        docs = {"/SIM-RT/probe": (200, PROBE.format(name="SIM-RT", serial=SERIAL, more="")),
                "/OTHER/probe": (200, PROBE.format(name="OTHER", serial="XYZ-1", more="")),
                "/probe": (200, PROBE.format(name="SIM-RT", serial=SERIAL, more='\n    <Device uuid="b" name="B" id="d2"/>')),
                "/EVIL/probe": (200, LAUGHS), "/NOPE/probe": (404, ERROR), "/HTML/probe": (200, "<html><body>hi</body></html>")}
        code, body = docs.get(self.path, (404, ERROR))
        data = body.encode()
        self.send_response(code)
        self.send_header("Content-Type", "application/xml")
        self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        self.wfile.write(data)

    def log_message(self, *args: object) -> None:
        pass


@pytest.fixture(scope="module")
def agent():
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Agent)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()


@pytest.fixture(scope="module")
def runs(tmp_path_factory, agent):
    """Two ISO 230-2 runs of one axis against the polygon: as found (its identity from the agent's probe,
    the machine's name left to it) and as left (filed by `rtcal run --catalog`)."""
    root = tmp_path_factory.mktemp("programme")
    proc = yaml.safe_load((REPO / "procedures" / "iso230_2_polygon.yaml").read_text())
    del proc["bench"]  # (given on the command line: a scenario outside the procedure's folder)
    proc["metadata"].update(machine="", machine_identity=f"{agent}/SIM-RT")
    path = root / "as_found.yaml"
    path.write_text(yaml.safe_dump(proc, allow_unicode=True, sort_keys=False))
    found, left, filed = root / "found", root / "left", root / "filed.sqlite"
    assert main(["run", str(path), "--virtual-clock", "--out", str(found), "--as-found", "--certificate-number", "P-AF-1",
                 "--scenario", str(BENCH)]) == 0
    assert main(["run", str(REPO / "procedures" / "iso230_2_polygon.yaml"), "--virtual-clock", "--out", str(left),
                 "--as-left", "--certificate-number", "P-AL-1", "--catalog", str(filed), "--allow-simulated"]) == 0
    return found, left, filed


def _json(capsys, *argv: str):
    capsys.readouterr()  # what earlier commands printed
    assert main(list(argv)) == 0, capsys.readouterr().err
    return json.loads(capsys.readouterr().out)


def _stored_faces(run: Path) -> list[float]:
    with closing(sqlite3.connect(f"file:{run / 'run.sqlite'}?mode=ro", uri=True)) as conn:
        return json.loads(dict(conn.execute("SELECT key, value FROM meta"))["polygon_certificate_arcsec"])


def _certificate(path: Path, **fields) -> Path:
    doc = {"instrument": POLYGON, "certificate_number": "PTB 4.22-2026-007", "calibrated_by": "PTB",
           "calibration_date": "2026-02-01", "calibration_due": "2028-02-28", **fields}
    path.write_text(yaml.safe_dump(doc, allow_unicode=True))
    return path


def _tree(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir()) if p.is_file()}


# -- item 7 and 3: identity over MTConnect; declared as found / as left ------------------------------

def test_the_machine_identity_comes_from_an_mtconnect_probe_and_fills_the_certificate(runs, agent, capsys):
    found, left, filed = runs
    meta = json.loads((found / "results.json").read_text())["metadata"]
    assert meta["machine"] == "Parker 200RT" and meta["serial_number"] == SERIAL  # the probe's, as OPC UA's would
    assert meta["item_state"] == "as_found"
    items = {i["label"]: i["value"] for i in json.loads((found / "certificate.json").read_text())["identification"]["items"]}
    assert items["State of the item"].startswith("as found") and "Parker 200RT" in items["Item calibrated"]
    assert json.loads((left / "results.json").read_text())["metadata"]["item_state"] == "as_left"
    ident = _json(capsys, "probe", "machine", f"{agent}/SIM-RT", "--json")
    assert (ident["manufacturer"], ident["model"], ident["serial_number"], ident["uuid"]) == ("Parker", "200RT", SERIAL,
                                                                                              "rt-200-0042")


@pytest.mark.parametrize("path, says", [("/EVIL", "document type"), ("/probe", "2 devices"), ("/NOPE", "NO_DEVICE"),
                                        ("/HTML", "not an MTConnect probe")])
def test_a_bad_probe_is_one_line_exit_1(agent, path, says):
    r = _cli("probe", "machine", agent + ("" if path == "/probe" else path))
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1 and says in r.stderr, r.stderr


def test_a_probe_naming_another_serial_refuses_the_run_before_anything_moves(agent, tmp_path):
    proc = yaml.safe_load((REPO / "procedures" / "iso230_2_polygon.yaml").read_text())
    del proc["bench"]
    proc["metadata"]["machine_identity"] = f"{agent}/OTHER"
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump(proc, allow_unicode=True))
    r = _cli("run", str(path), "--virtual-clock", "--out", str(tmp_path / "run"), "--scenario", str(BENCH))
    assert r.returncode == 2 and "XYZ-1" in r.stderr and not (tmp_path / "run" / "run.sqlite").exists()
    assert _cli("probe", "machine", "ftp://x/y").returncode == 2


def test_run_catalog_files_the_run_and_pairs_are_named_by_certificate_and_date(runs, capsys):
    found, left, filed = runs
    with Catalog(str(filed)) as cat:
        assert [r["certificate_number"] for r in cat.machines()] == ["P-AL-1"]  # `run --catalog` filed it
    assert main(["catalog", "add", "--allow-simulated", str(found), "--db", str(filed)]) == 0
    capsys.readouterr()
    assert main(["catalog", "history", "--serial", SERIAL, "--db", str(filed)]) == 0
    out = capsys.readouterr().out
    day = json.loads((found / "results.json").read_text())["started_utc"][:10]
    assert re.search(rf"as found P-AF-1 \({day}\) → as left P-AL-1 \({day}\).*declared by the runs", out), out
    assert "ISO 230-2 positioning test of the" in out and "encoder_abbe_error" not in out  # the test, not the method
    history = _json(capsys, "catalog", "history", "--serial", SERIAL, "--db", str(filed), "--json")
    assert [(e["certificate_number"], e["as_found_of"] is not None, e["as_left_of"] is not None) for e in history] == \
        [("P-AF-1", True, False), ("P-AL-1", False, True)]


def test_two_undeclared_runs_within_14_days_are_a_pair_labelled_as_a_guess():
    t = datetime(2024, 1, 1, tzinfo=timezone.utc)
    rows = [{"run_id": "a", "measured_utc": t.isoformat(), "state": ""},
            {"run_id": "b", "measured_utc": (t + timedelta(days=3)).isoformat(), "state": ""},
            {"run_id": "c", "measured_utc": (t + timedelta(days=400)).isoformat(), "state": "as_found"},
            {"run_id": "d", "measured_utc": (t + timedelta(days=430)).isoformat(), "state": "as_left"},  # declared: any gap
            {"run_id": "e", "measured_utc": (t + timedelta(days=800)).isoformat(), "state": "as_left"},
            {"run_id": "f", "measured_utc": (t + timedelta(days=801)).isoformat(), "state": ""}]  # one says, one not: none
    assert [(p.found, p.left, p.declared) for p in pair_info(rows)] == [(0, 1, False), (2, 3, True)]


# -- item 1: instruments and impact --------------------------------------------------------------------

def test_each_entry_records_its_instruments_and_used_by_lists_the_calibrations(db, runs, capsys):
    found, left, _ = runs
    assert main(["catalog", "add", "--allow-simulated", str(found), str(left), "--db", db, "--site", "north", "--by", "A. Tester"]) == 0
    used = _json(capsys, "catalog", "used-by", POLYGON, "--db", db, "--json")
    assert [u["certificate_number"] for u in used] == ["P-AF-1", "P-AL-1"]
    results = json.loads((found / "results.json").read_text())["metadata"]["instruments"]["polygon"]
    assert {(u["role"], u["instrument_certificate"], u["issuer"], u["instrument_due"]) for u in used} == \
        {("polygon", results["certificate_number"], results["calibrated_by"], results["calibration_due"])}
    assert all("24 face errors from its certificate" in u["correction"] for u in used)
    auto = _json(capsys, "catalog", "used-by", AUTOCOLLIMATOR, "--db", db, "--json")
    assert "scale u 1000 ppm" in auto[0]["correction"] and auto[0]["site"] == "north"
    later = (datetime.now(timezone.utc) + timedelta(days=2)).date().isoformat()
    assert _json(capsys, "catalog", "used-by", POLYGON, "--db", db, "--since", later, "--json") == []
    r = _cli("catalog", "used-by", "SN 4711", "--db", db)  # a part of an id is not an id: told the whole one
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and POLYGON in r.stderr


def test_reassess_re_evaluates_from_the_stored_readings_and_issues_superseding_certificates(db, runs, tmp_path, capsys):
    found, left, _ = runs
    assert main(["catalog", "add", "--allow-simulated", str(found), str(left), "--db", db]) == 0
    faces = _stored_faces(found)
    before = {run: _tree(run) for run in (found, left)}
    # the same face errors, or all shifted by one constant (positions are relative to the first target): nothing changes
    for k, values in enumerate((faces, [v + 0.7 for v in faces])):
        doc = _json(capsys, "catalog", "reassess", POLYGON, "--db", db, "--reason", "same", "--json",
                    "--certificate", str(_certificate(tmp_path / f"same{k}.yaml", corrections_arcsec=values)))
        assert [r["changed"] for r in doc["runs"]] == [False, False] and not doc["unreachable"]
        for r in doc["runs"]:
            assert r["new"]["E_arcsec"] == pytest.approx(r["old"]["E_arcsec"], abs=1e-9)
    # one face found 3″ off (the face 45° puts in front, a target of both runs): E moves by at most 3″
    moved = list(faces)
    moved[3] += 3.0
    cert = _certificate(tmp_path / "moved.yaml", corrections_arcsec=moved, corrections_u_arcsec=0.3)
    assert main(["catalog", "reassess", POLYGON, "--db", db, "--certificate", str(cert), "--reason", "face 3 recalibrated",
                 "--issue", "--out", str(tmp_path / "reissued"), "--by", "Q. Manager"]) == 0
    text = capsys.readouterr().out
    assert re.search(r"P-AF-1 \(\d{4}-\d\d-\d\d\) .* → .* CHANGED", text), text
    with Catalog(db) as cat:
        entries = {r["certificate_number"]: r for r in cat.machines()}
        trail = cat.table(audit, "seq")
    for old in ("P-AF-1", "P-AL-1"):
        new = entries[f"{old}-R1"]
        assert 0 < abs(new["E_arcsec"] - entries[old]["E_arcsec"]) <= 3.0 + 1e-6
        assert new["E_U_arcsec"] >= entries[old]["E_U_arcsec"]  # the face errors' u went from 0.1″ to 0.3″
        assert new["origin"] == "reissue" and new["supersedes"] == entries[old]["run_id"] and new["replaces"] == old
        folder = Path(new["run_dir"])
        assert folder.parent == tmp_path / "reissued"
        items = {i["label"]: i["value"] for i in json.loads((folder / "certificate.json").read_text())["identification"]["items"]}
        assert items["Certificate number"] == f"{old}-R1" and f"certificate {old}" in items["Replaces"]
        assert "Replaces" in (folder / "report.html").read_text()
        note = json.loads((folder / "reassessment.json").read_text())
        assert note["reason"] == "face 3 recalibrated" and note["by"] == "Q. Manager"
    assert {run: _tree(run) for run in (found, left)} == before  # the runs: not a byte changed
    assert [(a["action"], a["who"]) for a in trail][-3:] == [("supersede", "Q. Manager")] * 2 + [("reassess", "Q. Manager")]
    assert main(["catalog", "verify", "--db", db]) == 0
    capsys.readouterr()
    assert main(["catalog", "history", "--serial", SERIAL, "--db", db]) == 0
    assert "P-AF-1 (superseded by P-AF-1-R1)" in capsys.readouterr().out
    # the superseded ones are left out of a second reassessment; the reissues cannot be re-evaluated twice, and say why
    doc = _json(capsys, "catalog", "reassess", POLYGON, "--db", db, "--reason", "again", "--json", "--certificate", str(cert))
    assert len(doc["skipped"]) == 2 and len(doc["unreachable"]) == 2 and "reissued" in doc["unreachable"][0]["why"]


def test_a_run_whose_readings_are_gone_or_whose_instrument_does_not_enter_is_named_with_why(runs, tmp_path, capsys):
    found, _, _ = runs
    copy = tmp_path / "moved"
    shutil.copytree(found, copy)
    db_ = str(tmp_path / "c.sqlite")
    assert main(["catalog", "add", "--allow-simulated", str(copy), "--db", db_]) == 0
    (copy / "run.sqlite").unlink()
    doc = _json(capsys, "catalog", "reassess", POLYGON, "--db", db_, "--reason", "r", "--json",
                "--certificate", str(_certificate(tmp_path / "c.yaml", corrections_u_arcsec=0.2)))
    assert doc["runs"] == [] and "run.sqlite: not there" in doc["unreachable"][0]["why"]
    cert = tmp_path / "enc.yaml"
    cert.write_text(yaml.safe_dump({"instrument": ENCODER, "certificate_number": "E-1", "scale_error_ppm": 50}))
    shutil.rmtree(copy)
    shutil.copytree(found, copy)
    doc = _json(capsys, "catalog", "reassess", ENCODER, "--db", db_, "--reason", "r", "--json", "--certificate", str(cert))
    assert "encoder's calibration does not enter" in doc["unreachable"][0]["why"]


def test_an_instrument_out_of_tolerance_marks_the_runs_measured_since(db, runs, tmp_path, capsys):
    found, left, _ = runs
    assert main(["catalog", "add", "--allow-simulated", str(found), str(left), "--db", db]) == 0
    day = json.loads((found / "results.json").read_text())["started_utc"][:10]
    for since, doubted in ((day, 2), ("2999-01-01", 0)):
        cert = _certificate(tmp_path / "oot.yaml", out_of_tolerance_since=since)
        doc = _json(capsys, "catalog", "reassess", POLYGON, "--db", db, "--reason", "found damaged", "--json",
                    "--certificate", str(cert))
        assert sum(r["suspect"] for r in doc["runs"]) == doubted
    assert main(["catalog", "reassess", POLYGON, "--db", db, "--reason", "x", "--certificate", str(_certificate(
        tmp_path / "oot.yaml", out_of_tolerance_since=day))]) == 0
    assert "IN DOUBT: the instrument was out of tolerance since" in capsys.readouterr().out


@pytest.mark.parametrize("content, says", [
    ("instrument: [unclosed", "oot.yaml"),
    (f"instrument: {POLYGON}\ncertificate_number: X\nscale_errr_ppm: 3\n", "scale_errr_ppm"),
    (f"instrument: {POLYGON}\ncertificate_number: X\ncalibration_due: next year\n", "YYYY-MM-DD"),
    (f"instrument: {POLYGON}\ncertificate_number: X\nscale_error_ppm: .nan\n", "scale_error_ppm"),
    ("instrument: Someone else's gauge\ncertificate_number: X\n", "its instrument is"),
])
def test_a_bad_certificate_file_is_one_line_exit_2_and_nothing_written(runs, tmp_path, content, says):
    found, _, _ = runs
    db_ = str(tmp_path / "c.sqlite")
    assert main(["catalog", "add", "--allow-simulated", str(found), "--db", db_]) == 0
    (tmp_path / "oot.yaml").write_text(content)
    with Catalog(db_) as cat:
        rows = len(cat.table(audit, "seq"))
    r = _cli("catalog", "reassess", POLYGON, "--certificate", str(tmp_path / "oot.yaml"), "--reason", "r", "--db", db_)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and says in r.stderr, r.stderr
    r = _cli("catalog", "reassess", POLYGON, "--certificate", str(_certificate(tmp_path / "ok.yaml")), "--db", db_)
    assert r.returncode == 2 and "--reason" in r.stderr  # a reassessment says why
    with Catalog(db_) as cat:
        assert len(cat.table(audit, "seq")) == rows


# -- issue 46 item 7 -------------------------------------------------------------------------------------

def test_a_duplicate_certificate_number_is_refused(db, runs, monkeypatch, capsys):
    from rtcal.catalog import entry as entry_module
    from rtcal.methods import read_results

    found, _, _ = runs
    assert main(["catalog", "add", "--allow-simulated", str(found), "--db", db]) == 0
    other = read_results(found).model_copy(update={"started_utc": "2025-01-01T00:00:00+00:00"})  # another run, same number
    monkeypatch.setattr(entry_module, "verified", lambda _run: (other, "unsigned"))
    assert main(["catalog", "add", "--allow-simulated", str(found), "--db", db]) == 2
    err = capsys.readouterr().err
    assert "P-AF-1" in err and "already in" in err and len(err.strip().splitlines()) == 1
    with Catalog(db) as cat:
        assert cat.count() == 1


def test_an_edited_run_is_refused_naming_the_edited_file(runs, tmp_path):
    found, _, _ = runs
    copy = tmp_path / "edited"
    shutil.copytree(found, copy)
    with open(copy / "report.html", "a", encoding="utf-8") as f:
        f.write("<!-- a later hand -->")
    r = _cli("catalog", "add", "--allow-simulated", str(copy), "--db", str(tmp_path / "c.sqlite"))
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1
    assert f"{copy / 'report.html'}: EDITED" in r.stderr, r.stderr


def test_a_limit_date_in_the_past_is_exceeded_since_and_the_plot_says_what_it_drew(tmp_path):
    t0 = datetime(2015, 1, 1, tzinfo=timezone.utc)
    rows = [{"run_id": f"r{k}", "measured_utc": (t0 + timedelta(days=365.25 * k)).isoformat(), "E_arcsec": 40.0 + 10 * k,
             "E_U_arcsec": 1.0, "E_limit_arcsec": 60.0, "state": "", "serial_number": "S", "axis": "C",
             "verdict": "pass" if 40 + 10 * k <= 60 else "fail", "certificate_number": f"C-{k}"} for k in range(4)]
    t = trend(rows)
    assert t["E_reaches_limit"] == f"exceeded since {t['E_reaches_limit_utc'][:10]}" and t["E_reaches_limit_utc"] < "2018"
    from rtcal.catalog.plot import plot_history

    said = plot_history(rows, tmp_path / "h.png")
    assert said == f"plot: wrote {tmp_path / 'h.png'} (E ± U of 4 calibrations, 1 trend with its band, 1 failure marked)"
    assert (tmp_path / "h.png").stat().st_size > 10_000


# -- item 4: the audit trail ----------------------------------------------------------------------------

def _verify(db_: str) -> subprocess.CompletedProcess:
    return _cli("catalog", "verify", "--db", db_)


def _tampered(base: Path, tmp_path: Path, name: str, *sql: str) -> str:
    path = tmp_path / f"{name}.sqlite"
    shutil.copy(base, path)
    with closing(sqlite3.connect(path)) as conn, conn:
        for (trigger,) in conn.execute("SELECT name FROM sqlite_master WHERE type = 'trigger'").fetchall():
            conn.execute(f"DROP TRIGGER {trigger}")  # what a hand with the file can do
        for statement in sql:
            conn.execute(statement)
    return str(path)


def test_the_audit_trail_finds_and_names_any_edited_deleted_or_reordered_row(tmp_path):
    base = tmp_path / "base.sqlite"
    with Catalog(str(base), write=True) as cat:
        for k in range(6):
            assert cat.add(_synthetic(k), who="rig 1")
        cat.record("policy", "policy version 1", "Q. Manager", "first policy", {"version": 1})
    r = _verify(str(base))
    assert r.returncode == 0 and "7 audit rows chained, 6 entries" in r.stdout, r.stderr
    with closing(sqlite3.connect(base)) as conn:  # the database refuses an edit and a deletion outright
        for sql in ("UPDATE audit SET reason = 'x' WHERE seq = 2", "DELETE FROM audit WHERE seq = 2",
                    "UPDATE calibrations SET E_arcsec = 0", "DELETE FROM calibrations"):
            with pytest.raises(sqlite3.DatabaseError, match="append-only"):
                conn.execute(sql)
    victim = _synthetic(3)["run_id"]
    cases = {
        "edited": (["UPDATE audit SET who = 'nobody' WHERE seq = 3"], "audit row 3 (add"),
        "deleted": (["DELETE FROM audit WHERE seq = 4"], "audit row 4 is missing"),
        "reordered": (["UPDATE audit SET seq = 100 WHERE seq = 2", "UPDATE audit SET seq = 2 WHERE seq = 5",
                       "UPDATE audit SET seq = 5 WHERE seq = 100"], "audit row 2"),
        "entry edited": ([f"UPDATE calibrations SET E_arcsec = 1 WHERE run_id = '{victim}'"], f"entry {victim}: edited"),
        "entry deleted": ([f"DELETE FROM calibrations WHERE run_id = '{victim}'"], f"entry {victim}: audit row 4"),
        "instrument edited": ([f"UPDATE instruments SET certificate_number = 'Q' WHERE run_id = '{victim}'"],
                              f"entry {victim}: edited"),
    }
    for name, (sql, says) in cases.items():
        r = _verify(_tampered(base, tmp_path, name.replace(" ", "_"), *sql))
        assert r.returncode == 1 and says in r.stderr, (name, r.stderr)


def test_on_postgresql_the_trail_refuses_edits_and_verify_names_what_a_superuser_changed(postgres):
    import psycopg

    db_ = postgres.create_database("audit")
    with Catalog(db_, write=True) as cat:
        for k in range(4):
            assert cat.add(_synthetic(k), who="rig")
    dsn = db_.replace("postgresql://", "postgresql://", 1)
    with psycopg.connect(dsn, autocommit=True) as conn:
        for sql in ("UPDATE audit SET reason = 'x'", "DELETE FROM audit", "TRUNCATE calibrations"):
            with pytest.raises(psycopg.errors.RaiseException, match="append-only"):
                conn.execute(sql)
        conn.execute("ALTER TABLE audit DISABLE TRIGGER USER")
        conn.execute("UPDATE audit SET reason = 'rewritten' WHERE seq = 2")
    r = _verify(db_)
    assert r.returncode == 1 and "audit row 2 (add" in r.stderr and "edited after it was written" in r.stderr


# -- item 4: PostgreSQL roles from docs/catalog.md -------------------------------------------------------

def _docs_sql() -> list[str]:
    text = (REPO / "docs" / "catalog.md").read_text()
    block = re.search(r"```sql\n-- rtcal: the lab's roles.*?\n(.*?)```", text, re.S)
    assert block, "docs/catalog.md holds the roles' SQL"
    lines = [ln for ln in block.group(1).splitlines() if not ln.startswith(("\\", "--"))]  # psql's \password, comments
    return [s.strip() for s in re.split(r";\s*\n", "\n".join(lines)) if s.strip()]


def test_the_docs_roles_let_a_rig_only_insert_and_only_for_its_site(postgres, runs, monkeypatch):
    import psycopg

    found, left, _ = runs
    admin = postgres.create_database("lab")
    assert _cli("catalog", "migrate", "--db", admin).returncode == 0
    with psycopg.connect(admin, autocommit=True) as conn:
        for statement in _docs_sql():
            conn.execute(statement)
        password = "rig-" + secrets.token_hex(8)
        conn.execute(f"ALTER ROLE rig_berlin_1 PASSWORD '{password}'")  # (the docs ask it with psql's \password)
    rig = admin.replace(f"rtcal_test:{postgres.password}", f"rig_berlin_1:{password}")
    assert _cli("catalog", "add", "--allow-simulated", str(found), "--db", rig, "--site", "berlin").returncode == 0
    r = _cli("catalog", "add", "--allow-simulated", str(left), "--db", rig, "--site", "munich")
    assert r.returncode == 1 and "row-level security" in r.stderr and not list(OUTBOX.glob("*.json")), r.stderr
    assert _cli("catalog", "add", "--allow-simulated", str(left), "--db", admin, "--site", "munich").returncode == 0  # the lab's own role
    with psycopg.connect(rig, autocommit=True) as conn:
        for sql in ("UPDATE calibrations SET verdict = 'pass'", "DELETE FROM calibrations", "DELETE FROM audit",
                    "UPDATE audit SET reason = ''", "INSERT INTO policies VALUES (9, '', '', '', '')"):
            with pytest.raises(psycopg.errors.InsufficientPrivilege):
                conn.execute(sql)
        assert [r[0] for r in conn.execute("SELECT certificate_number FROM calibrations")] == ["P-AF-1"]  # its site's only
    listed = _cli("catalog", "list", "--db", rig, "--json")
    assert [m["last_certificate"] for m in json.loads(listed.stdout)] == ["P-AF-1"], listed.stderr
    r = _verify(admin)
    assert r.returncode == 0 and "2 audit rows chained" in r.stdout, r.stderr


# -- item 6: many rigs, one PostgreSQL that restarts ----------------------------------------------------

RIG = "import sys; sys.path.insert(0, sys.argv[5]); from tests.catalog_entries import rig_main; rig_main(sys.argv[1:5])"


def test_twenty_rigs_add_while_postgresql_restarts_and_nothing_is_lost_or_doubled(postgres, tmp_path):
    import random

    db_ = postgres.create_database("rigs")
    assert _cli("catalog", "migrate", "--db", db_).returncode == 0
    rigs, each = 20, 5
    procs = [subprocess.Popen([sys.executable, "-c", RIG, str(k), str(each), db_, str(tmp_path / f"outbox{k}"), str(REPO)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO) for k in range(rigs)]
    rng = random.Random(45)
    restarts = 0
    while restarts < 1 or (any(p.poll() is None for p in procs) and restarts < 3):
        time.sleep(rng.uniform(0.5, 3.0))
        postgres.stop(rng.choice(["fast", "immediate"]))
        time.sleep(rng.uniform(0.2, 1.5))
        postgres.start()
        restarts += 1
    outs = [p.communicate(timeout=400) for p in procs]
    assert all(p.returncode == 0 for p in procs), [o[1][-500:] for o in outs if o[1]]
    assert all(o[0].strip().endswith("left 0") for o in outs), outs
    with Catalog(db_) as cat:
        rows = cat.machines()
        adds = [a for a in cat.table(audit, "seq") if a["action"] == "add"]
    assert len(rows) == len({r["run_id"] for r in rows}) == rigs * each  # 0 lost, 0 duplicated
    assert len(adds) == rigs * each and restarts >= 1
    assert _verify(db_).returncode == 0


def test_an_unreachable_postgresql_keeps_the_entry_in_the_outbox_and_sync_sends_it_once(postgres, runs, tmp_path):
    found, _, _ = runs
    db_ = postgres.create_database("away")
    outbox = tmp_path / "outbox"
    env = {"RTCAL_OUTBOX": str(outbox)}
    postgres.stop()
    try:
        r = _cli("catalog", "add", "--allow-simulated", str(found), "--db", db_, env=env)
        assert r.returncode == 1 and "waits in the outbox" in r.stderr and len(r.stderr.strip().splitlines()) == 1
        assert postgres.password not in r.stderr and len(list(outbox.glob("*.json"))) == 1
        assert _cli("catalog", "sync", "--db", db_, env=env).returncode == 1  # still away: it keeps waiting
    finally:
        postgres.start()
    r = _cli("catalog", "sync", "--db", db_, env=env)
    assert r.returncode == 0 and "1 added" in r.stdout and not list(outbox.glob("*.json")), r.stderr
    assert "0 added" in _cli("catalog", "sync", "--db", db_, env=env).stdout
    with Catalog(db_) as cat:
        assert cat.count() == 1


# -- items 2 and 5: intervals, the due list, sites, retirement ------------------------------------------

def _rows(values: list[tuple[float, float, str]], limit: float = 60.0, u: float = 1.0) -> list[dict]:
    t0 = datetime(2020, 1, 1, tzinfo=timezone.utc)
    return [{"run_id": f"r{k}", "measured_utc": (t0 + timedelta(days=d)).isoformat(), "E_arcsec": e, "E_U_arcsec": u,
             "E_limit_arcsec": limit, "state": state, "verdict": "pass" if e <= limit else "fail",
             **{f"{p}_{x}arcsec": None for p in "MBRA" for x in ("", "U_", "limit_")}} for k, (d, e, state) in enumerate(values)]


def test_the_staircase_extends_shortens_and_keeps_by_the_as_found_fraction_of_the_limit():
    policy = AxisPolicy(method="staircase", interval_days=200, min_days=60, max_days=500)
    # 30″ of 60″ (50 % ≤ 80 %): ×1.25 → 250; 54″ (90 %): kept; 70″ (117 %): ×0.5 → 125; as left runs do not count
    rows = _rows([(0, 30, ""), (250, 54, "as_found"), (252, 20, "as_left"), (500, 70, "as_found"), (501, 20, "as_left")])
    due = next_due(rows, policy)
    assert due["method"] == "ILAC-G24 method 1 (staircase)" and due["interval_days"] == 125
    assert due["due"] == (datetime(2020, 1, 1) + timedelta(days=501 + 125)).date().isoformat()
    assert "117%" in due["data"] and "× 0.5" in due["data"]


def test_the_control_chart_finds_the_date_a_known_drift_reaches_the_limit():
    # left at 20″ each time, found 20 + 0.05″/day later (exact data): from the last as-left (20″ ± U 1″, k = 2) the
    # value + 2·u reaches 60″ where 20 + 0.05·t + 2·sqrt(0.5² + 0.5² + (u_rate·t)²) = 60 (u_rate from the periods)
    rows = _rows([(0, 20, "as_found"), (1, 20, "as_left"), (301, 35, "as_found"), (302, 20, "as_left"),
                  (602, 35, "as_found"), (603, 20, "as_left")])
    policy = AxisPolicy(method="control_chart", parameters=["E"], max_days=3000)
    due = next_due(rows, policy)
    rate, u_rate = 15 / 300, (0.5 ** 2 + 0.5 ** 2) ** 0.5 / 300 / 2 ** 0.5  # two equal periods: their mean, u / √2
    days = next(t / 10 for t in range(1, 30000)
                if 20 + rate * t / 10 + 2 * ((0.5 ** 2 + 0.5 ** 2) + (u_rate * t / 10) ** 2) ** 0.5 >= 60)
    expected = (datetime(2020, 1, 1) + timedelta(days=603 + days)).date()
    assert abs((datetime.fromisoformat(due["due"]).date() - expected).days) <= 1, due
    assert due["method"].startswith("ILAC-G24 method 2") and "drift +18.26" in due["data"]


def test_in_use_time_is_the_hours_at_the_rate_the_readings_show():
    rows = _rows([(0, 20, "")])
    t0 = datetime(2020, 1, 1, tzinfo=timezone.utc)
    hours = [(t0 - timedelta(days=10), 900.0), (t0 + timedelta(days=90), 1900.0)]  # 10 h a day; 1000 h at the calibration
    due = next_due(rows, AxisPolicy(method="in_use", interval_hours=2000, max_days=3000), hours)
    assert due["due"] == (t0 + timedelta(days=200)).date().isoformat() and "10.0 h/day" in due["data"]
    none = next_due(rows, AxisPolicy(method="in_use", interval_days=100))
    assert none["due"] == (t0 + timedelta(days=100)).date().isoformat() and "not known" in none["data"]


def test_policy_due_list_sites_and_retirement(tmp_path, capsys):
    db_ = str(tmp_path / "c.sqlite")
    now = datetime.now(timezone.utc)
    with Catalog(db_, write=True) as cat:
        cat.add(_synthetic(1, site="berlin", serial="OLD", days=(now - timedelta(days=400) - datetime(2020, 1, 1, tzinfo=timezone.utc)).days))
        cat.add(_synthetic(2, site="munich", serial="SOON", days=(now - timedelta(days=350) - datetime(2020, 1, 1, tzinfo=timezone.utc)).days))
        cat.add(_synthetic(3, site="berlin", serial="FRESH", days=(now - timedelta(days=10) - datetime(2020, 1, 1, tzinfo=timezone.utc)).days))
    due = _json(capsys, "catalog", "due", "--db", db_, "--json")
    assert [(d["serial_number"], d["status"].split()[0]) for d in due] == [("OLD", "overdue"), ("SOON", "due")]
    assert [d["serial_number"] for d in _json(capsys, "catalog", "due", "--db", db_, "--site", "munich", "--json")] == ["SOON"]
    policy = tmp_path / "policy.yaml"
    policy.write_text("default: {method: fixed, interval_days: 365}\naxes:\n  - {serial_number: SOON, method: staircase, "
                      "interval_days: 400}\n")
    assert _cli("catalog", "policy", str(policy), "--db", db_).returncode == 2  # a policy change says why
    assert main(["catalog", "policy", str(policy), "--db", db_, "--reason", "assessor's advice"]) == 0
    assert "policy version 1 filed" in capsys.readouterr().out
    due = _json(capsys, "catalog", "due", "--db", db_, "--json")
    assert [d["serial_number"] for d in due] == ["OLD"]  # SOON: 50 % of its limit, 400 d × 1.25
    r = _cli("catalog", "retire", "--serial", "OLD", "--axis", "C", "--db", db_)
    assert r.returncode == 2 and "--reason" in r.stderr
    assert main(["catalog", "retire", "--serial", "OLD", "--axis", "C", "--db", db_, "--reason", "scrapped"]) == 0
    assert "its entries are kept" in capsys.readouterr().out
    assert main(["catalog", "due", "--db", db_]) == 0
    assert "nothing overdue" in capsys.readouterr().out
    listed = _json(capsys, "catalog", "list", "--db", db_, "--json")
    assert {m["serial_number"]: m.get("due_retired", False) for m in listed} == {"OLD": True, "SOON": False, "FRESH": False}
    with Catalog(db_) as cat:
        actions = [a["action"] for a in cat.table(audit, "seq")]
    assert actions == ["add", "add", "add", "policy", "retire"]
    bad = tmp_path / "bad.yaml"
    bad.write_text("axes:\n  - {serial_number: X, method: monthly}\n")
    r = _cli("catalog", "policy", str(bad), "--db", db_, "--reason", "r")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "axes[0].method" in r.stderr


def test_the_page_shows_the_due_list_and_finds_serials_customers_and_instruments(tmp_path):
    from rtcal.catalog.page import _page

    db_ = str(tmp_path / "c.sqlite")
    with Catalog(db_, write=True) as cat:
        cat.add(_synthetic(1, site="berlin", serial="OLD-1"))
        cat.add(_synthetic(2, site="berlin", serial="NEW-2", days=(datetime.now(timezone.utc)
                                                                   - datetime(2020, 1, 1, tzinfo=timezone.utc)).days - 5))
    page = _page(db_, None)
    due = page[page.index('id="due"'):page.index("<h2>Fleet")]
    assert "OLD-1" in due and "overdue since" in due and "NEW-2" not in due
    assert "OLD-1" in _page(db_, None, "old").split('id="search"')[1].split("</ul>")[0]
    hits = _page(db_, None, "customer 2").split('id="search"')[1].split("</ul>")[0]
    assert "NEW-2" in hits and "OLD-1" not in hits
    hits = _page(db_, None, "polygon 1").split('id="search"')[1].split("</ul>")[0]
    assert "polygon 1 (polygon) used by C-OLD-1-1-berlin" in hits


def test_the_chain_starts_at_genesis_and_an_older_catalogue_is_brought_into_it(tmp_path):
    """Migration 0004 files every entry an older rtcal added with one `add` row, so verify covers them."""
    path = tmp_path / "old.sqlite"
    old = json.dumps({"procedure": {"name": "old test"}, "metadata": {"instruments": {
        "polygon": {"id": "polygon 9", "certificate_number": "P9", "calibrated_by": "PTB", "calibration_due": ""}}}})
    older_catalogue(path, "0003", [{**_synthetic(k), "results": old} for k in range(3)])
    assert _cli("catalog", "used-by", "polygon 9", "--db", str(path)).returncode == 2  # read as it is: no instruments yet
    assert _cli("catalog", "migrate", "--db", str(path)).returncode == 0
    with Catalog(str(path)) as cat:
        trail = cat.table(audit, "seq")
        assert trail[0]["prev_hash"] == GENESIS and [a["action"] for a in trail] == ["add"] * 3
        assert len(cat.used_by("polygon 9")) == 3 and cat.machines()[0]["test"] == "old test"
    assert _verify(str(path)).returncode == 0


def test_machine_hours_are_read_from_opc_ua_operation_counters_and_drive_in_use_intervals(tmp_path, capsys):
    from simulators.opcua_machine import OpcUaMachine

    db_ = str(tmp_path / "c.sqlite")
    with Catalog(db_, write=True) as cat:
        cat.add(_synthetic(1, serial="HRS-1"))
    machine = OpcUaMachine(hours=1234.5)
    bare = OpcUaMachine()
    try:
        assert main(["catalog", "hours", "--serial", "HRS-1", "--opcua", machine.address, "--at", "2020-03-01",
                     "--db", db_]) == 0
        assert "1234.5 h on 2020-03-01 (OPC UA" in capsys.readouterr().out
        r = _cli("catalog", "hours", "--serial", "HRS-1", "--opcua", bare.address, "--db", db_)
        assert r.returncode == 1 and "no OperationCounters" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    finally:
        machine.close()
        bare.close()
    assert main(["catalog", "hours", "--serial", "HRS-1", "--hours", "1834.5", "--at", "2020-05-30", "--db", db_]) == 0
    policy = tmp_path / "p.yaml"
    policy.write_text("axes:\n  - {serial_number: HRS-1, method: in_use, interval_hours: 1000, max_days: 3000}\n")
    assert main(["catalog", "policy", str(policy), "--reason", "hours", "--db", db_]) == 0
    due = _json(capsys, "catalog", "list", "--db", db_, "--json")[0]
    # 600 h in 90 days (6.67 h/day); the calibration on 2020-01-31 at 1234.5 − 30·6.67 = 1034.5 h; 2034.5 h is 200 h after
    # the reading of 2020-05-30: 30 days later
    assert due["due_method"] == "ILAC-G24 method 3 (in-use time)" and due["next_due"] == "2020-06-29", due


def test_a_run_that_replaces_a_certificate_is_filed_as_a_supersede_with_its_reason(db, runs, monkeypatch, capsys):
    from rtcal.catalog import entry as entry_module
    from rtcal.methods import read_results

    found, _, _ = runs
    assert main(["catalog", "add", "--allow-simulated", str(found), "--db", db]) == 0
    base = read_results(found)
    again = base.model_copy(update={"started_utc": "2026-01-05T00:00:00+00:00", "metadata": base.metadata.model_copy(
        update={"certificate_number": "P-AF-1-B", "replaces": "P-AF-1"})})
    monkeypatch.setattr(entry_module, "verified", lambda _run: (again, "unsigned"))
    assert main(["catalog", "add", "--allow-simulated", str(found), "--db", db]) == 2
    assert "--reason" in capsys.readouterr().err
    assert main(["catalog", "add", "--allow-simulated", str(found), "--db", db, "--reason", "customer's name was misspelt"]) == 0
    assert "(replaces P-AF-1): added to" in capsys.readouterr().out
    with Catalog(db) as cat:
        trail = cat.table(audit, "seq")
        assert [(a["action"], a["reason"]) for a in trail][-1] == ("supersede", "customer's name was misspelt")
    nowhere = again.model_copy(update={"started_utc": "2026-02-05T00:00:00+00:00", "metadata": again.metadata.model_copy(
        update={"certificate_number": "P-AF-1-C", "replaces": "NO-SUCH-1"})})
    monkeypatch.setattr(entry_module, "verified", lambda _run: (nowhere, "unsigned"))
    assert main(["catalog", "add", "--allow-simulated", str(found), "--db", db, "--reason", "r"]) == 2
    assert "NO-SUCH-1" in capsys.readouterr().err


def test_an_autocollimator_found_with_a_scale_error_re_evaluates_its_runs(runs, tmp_path, capsys):
    found, _, _ = runs
    db_ = str(tmp_path / "c.sqlite")
    assert main(["catalog", "add", "--allow-simulated", str(found), "--db", db_]) == 0
    cert = tmp_path / "ac.yaml"
    cert.write_text(yaml.safe_dump({"instrument": AUTOCOLLIMATOR, "certificate_number": "EML-K-2026-001",
                                    "scale_error_ppm": 10_000, "u_arcsec": 0.3}, allow_unicode=True))
    doc = _json(capsys, "catalog", "reassess", AUTOCOLLIMATOR, "--db", db_, "--reason", "r", "--json", "--certificate", str(cert))
    (run,) = doc["runs"]
    old, new = run["old"], run["new"]
    # readings 1 % too large: divided by 1.01, E moves by about 1 % of the readings it rests on, and U grows
    assert run["changed"] and 0 < abs(new["E_arcsec"] - old["E_arcsec"]) < 0.02 * (abs(old["E_arcsec"]) + 60)
    assert new["E_U_arcsec"] > old["E_U_arcsec"]
