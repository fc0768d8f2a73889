"""Issue 36, item 12: every file a run writes is covered by a digest results.json records; `rtcal
verify` says which files it checked and names an edited one (exit 1); a run's own
positioning_deviations.csv edited after the run is refused by the commands that read a CSV; a
results.json of a schema that always carries digests but carries none is refused."""

from __future__ import annotations

from rtcal.results.model import SCHEMA_VERSION
import hashlib
import json
import os
import shutil
import sqlite3
from pathlib import Path

import pytest

from rtcal.results import SCHEMA_VERSION

from rtcal.cli import main

REPO = Path(__file__).resolve().parents[1]
PROCEDURE = REPO / "procedures" / "iso230_2_polygon.yaml"
DELIVERABLES = ("certificate.json", "report.md", "report.html", "report.pdf", "positioning_deviations.csv",
                "fig10_positioning.png")

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def solved(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("solved") / "iso"
    assert main(["run", str(PROCEDURE), "--out", str(out)]) == 0
    return out


def _copy(run: Path, tmp_path: Path) -> Path:
    target = tmp_path / "copy" / "iso"
    shutil.copytree(run, target, ignore=shutil.ignore_patterns(".rtcal.lock"))
    return target


def _edit_a_digit(path: Path) -> None:
    """One digit changed past the middle of the file (53.46″ → 63.46″): what a forger does."""
    data = bytearray(path.read_bytes())
    i = next(k for k in range(len(data) // 2, len(data)) if 0x30 <= data[k] <= 0x39)
    data[i] = 0x30 + (data[i] - 0x30 + 1) % 10
    path.write_bytes(bytes(data))


def _rewrite_results(run: Path, edit) -> None:
    """results.json edited, and the store's record of it made to match: the whole forgery."""
    data = json.loads((run / "results.json").read_text())
    edit(data)
    text = json.dumps(data, indent=2) + "\n"
    (run / "results.json").write_text(text)
    with sqlite3.connect(run / "run.sqlite") as db:
        db.execute("UPDATE meta SET value = ? WHERE key = 'results_sha256'", (hashlib.sha256(text.encode()).hexdigest(),))


def test_results_record_the_digest_of_every_file_the_run_wrote(solved):
    recorded = json.loads((solved / "results.json").read_text())["digests"]["deliverables_sha256"]
    written = {p.name for p in solved.iterdir() if p.is_file() and p.name not in ("results.json", "run.sqlite")
               and not p.name.startswith(".")}
    assert set(recorded) == written and set(DELIVERABLES) <= written
    for name, digest in recorded.items():
        assert hashlib.sha256((solved / name).read_bytes()).hexdigest() == digest, name


@pytest.mark.parametrize("name", DELIVERABLES)
def test_verify_names_an_edited_deliverable_and_exits_1(solved, tmp_path, capsys, name):
    run = _copy(solved, tmp_path)
    capsys.readouterr()
    assert main(["verify", str(run)]) == 0
    assert f"{run / name}: as written" in capsys.readouterr().out
    _edit_a_digit(run / name)
    assert main(["verify", str(run)]) == 1
    captured = capsys.readouterr()
    assert f"{run / name}: EDITED" in captured.out and f"rtcal: {run / name}: EDITED" in captured.err
    others = [n for n in DELIVERABLES if n != name]
    assert all(f"{run / n}: as written" in captured.out for n in others)
    assert "does NOT agree" in captured.out and "1 of " in captured.out


def test_verify_names_a_missing_or_replaced_deliverable(solved, tmp_path, capsys):
    run = _copy(solved, tmp_path)
    os.unlink(run / "report.pdf")
    (run / "certificate.json").unlink()
    (run / "certificate.json").mkdir()
    capsys.readouterr()
    assert main(["verify", str(run)]) == 1
    err = capsys.readouterr().err
    assert f"{run / 'report.pdf'}: missing" in err and f"{run / 'certificate.json'}: not a regular file" in err


def test_results_of_a_schema_that_writes_digests_but_carrying_none_are_refused(solved, tmp_path, capsys):
    run = _copy(solved, tmp_path)
    _rewrite_results(run, lambda d: d["digests"].pop("deliverables_sha256"))
    for argv in (["evaluate", str(run)], ["verify", str(run)]):
        capsys.readouterr()
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert "records no digests of its certificate" in err and f"schema_version {SCHEMA_VERSION}" in err, err
    # the same file as a 1.2 run wrote it (rtcal 0.1.0 wrote 1.0 to 1.3): read, and verify says what it could not check
    _rewrite_results(run, lambda d: d.update(schema_version="1.2", rtcal_version="0.1.0"))
    assert main(["evaluate", str(run)]) == 0
    capsys.readouterr()
    assert main(["verify", str(run)]) == 0
    assert "those files are not checked" in capsys.readouterr().err
    # a 1.2 file without its store's digests and without a store beside it is not rtcal's either
    _rewrite_results(run, lambda d: d.pop("digests"))
    os.unlink(run / "run.sqlite")
    capsys.readouterr()
    assert main(["evaluate", str(run)]) == 2
    assert "records no digests of its run's store" in capsys.readouterr().err


def test_a_runs_edited_csv_is_refused_naming_both_files(solved, tmp_path, capsys):
    run = _copy(solved, tmp_path)
    csv = run / "positioning_deviations.csv"
    comp = tmp_path / "c.comp"
    assert main(["compensate", str(csv), "--format", "linuxcnc", "--out", str(comp)]) == 0  # as written: used
    comp.unlink()
    lines = csv.read_text().splitlines()
    fields = lines[4].split(",")
    fields[3] = f"{float(fields[3]) - 40:.4f}"  # a deviation 40″ smaller
    lines[4] = ",".join(fields)
    csv.write_text("\n".join(lines) + "\n")
    for argv in (["compensate", str(csv), "--format", "linuxcnc", "--out", str(comp)], ["evaluate", str(csv)]):
        capsys.readouterr()
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert str(csv) in err and str(run / "results.json") in err and "edited" in err and len(err.splitlines()) == 1
    assert not comp.exists()
    own = tmp_path / "mine" / "positioning_deviations.csv"  # the same table as a user's own file: no run beside it
    own.parent.mkdir()
    shutil.copy(csv, own)
    assert main(["compensate", str(own), "--format", "linuxcnc", "--out", str(comp)]) == 0


def test_the_as_found_as_left_certificate_gets_its_own_number(solved, tmp_path, capsys):
    """Issue 36, item 17: a certificate of its own has a number of its own (warned of when not given)."""
    out = tmp_path / "as-left"
    capsys.readouterr()
    assert main(["compare", str(solved), str(solved), "--certificate", "--out", str(out)]) == 0
    assert "give it its own (--certificate-number NUMBER)" in capsys.readouterr().err
    assert main(["compare", str(solved), str(solved), "--certificate", "--certificate-number", "EML-2026-0999",
                 "--out", str(out)]) == 0
    assert "give it its own" not in capsys.readouterr().err
    header = json.loads((out / "as_found_as_left.json").read_text())["header"]
    assert header["certificate_number"] == "EML-2026-0999" and "EML-2026-0999" in header["footer"]
