"""Issue 40 item 5: runs nobody can forge. A forger who can write the run folder edits a serial number, a
certificate number, E on certificate.json, or the clock and started_utc, and recomputes every digest by hand
(results.json's, the store's record of it, the deliverables'): the digests alone let each pass `verify` and
`catalog add` (shown here, as the control); with the lab's key configured each is refused in one line.
Also: the key pair (`rtcal key generate`), the signature on page 1 of the certificate, an unsigned run marked
so, and a results.json whose schema_version was set back by hand."""

from __future__ import annotations

import base64
import hashlib
import json
import os
import shutil
import sqlite3
import stat
from pathlib import Path

import pytest

from rtcal.cli import main
from rtcal.run.signing import LAB_KEY_ENV, LAB_PUBLIC_KEYS_ENV, PRIVATE_NAME, PUBLIC_NAME

REPO = Path(__file__).resolve().parents[1]
PROCEDURE = REPO / "procedures" / "iso230_2_verification.yaml"


def _keys(folder: Path, signer: str = "Example Metrology Lab, DAkkS D-K-99999-01-00") -> tuple[Path, Path]:
    assert main(["key", "generate", "--out", str(folder), "--signer", signer]) == 0
    return folder / PRIVATE_NAME, folder / PUBLIC_NAME


@pytest.fixture(scope="module")
def lab(tmp_path_factory) -> dict[str, Path]:
    """The lab's key pair, another lab's, a run signed with the lab's key and one written unsigned."""
    base = tmp_path_factory.mktemp("signing")
    private, public = _keys(base / "keys")
    other_private, other_public = _keys(base / "other", "Another Lab")
    signed, unsigned = base / "signed", base / "unsigned"
    mp = pytest.MonkeyPatch()
    try:
        mp.setenv(LAB_KEY_ENV, str(private))
        assert main(["run", str(PROCEDURE), "--virtual-clock", "--out", str(signed)]) == 0
        mp.delenv(LAB_KEY_ENV)
        assert main(["run", str(PROCEDURE), "--virtual-clock", "--out", str(unsigned), "--certificate-number",
                     "EML-UNSIGNED-1"]) == 0
    finally:
        mp.undo()
    return {"private": private, "public": public, "other_private": other_private, "other_public": other_public,
            "signed": signed, "unsigned": unsigned, "base": base}


@pytest.fixture(autouse=True)
def no_keys(monkeypatch):
    monkeypatch.delenv(LAB_KEY_ENV, raising=False)
    monkeypatch.delenv(LAB_PUBLIC_KEYS_ENV, raising=False)


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def forge(run: Path, results=None, certificate=None, store_meta: dict[str, str] | None = None) -> None:
    """Edit the run as a forger does, then recompute by hand every digest rtcal checks: the deliverables'
    digests in results.json, results.json's digest in the store."""
    data = json.loads((run / "results.json").read_text())
    if certificate is not None:
        doc = json.loads((run / "certificate.json").read_text())
        certificate(doc)
        (run / "certificate.json").write_text(json.dumps(doc, indent=1) + "\n")
        data["digests"]["deliverables_sha256"]["certificate.json"] = _sha(run / "certificate.json")
    if results is not None:
        results(data)
    text = json.dumps(data, indent=2) + "\n"
    (run / "results.json").write_text(text)
    with sqlite3.connect(run / "run.sqlite") as db:
        for key, value in {"results_sha256": hashlib.sha256(text.encode()).hexdigest(), **(store_meta or {})}.items():
            db.execute("UPDATE meta SET value = ? WHERE key = ?", (value, key))


def _serial(data):
    data["metadata"]["serial_number"] = "SN-FORGED-1"


def _certificate_number(data):
    data["metadata"]["certificate_number"] = "EML-2026-9999"


def _e_on_certificate(doc):
    row = next(r for r in doc["result_in_brief"]["rows"] if r["quantity"].startswith("E"))
    row["value_arcsec"] = "1.0″"


def _clock(data):
    data["started_utc"] = "2024-03-01T08:00:00+00:00"
    data["finished_utc"] = "2024-03-01T09:30:00+00:00"
    data["clock"] = "real"


FORGERIES = {
    "serial number": dict(results=_serial),
    "certificate number": dict(results=_certificate_number),
    "E on certificate.json": dict(certificate=_e_on_certificate),
    "clock and started_utc": dict(results=_clock, store_meta={"started_utc": "2024-03-01T08:00:00+00:00"}),
}


def _copy(lab, tmp_path: Path, which: str = "signed") -> Path:
    run = tmp_path / which
    shutil.copytree(lab[which], run)
    return run


@pytest.mark.parametrize("forgery", sorted(FORGERIES))
def test_a_forgery_with_its_digests_recomputed_is_refused_by_verify_and_the_catalogue(lab, tmp_path, capsys, monkeypatch,
                                                                                      forgery):
    run = _copy(lab, tmp_path)
    forge(run, **FORGERIES[forgery])
    # the control: the digests alone cannot tell (that is what a forger counts on)
    assert main(["verify", str(run)]) == 0
    capsys.readouterr()
    monkeypatch.setenv(LAB_PUBLIC_KEYS_ENV, str(lab["public"]))
    assert main(["verify", str(run)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "forgery" in err[0] and "Traceback" not in err[0], err
    db = tmp_path / "catalog.sqlite"
    assert main(["catalog", "add", "--allow-simulated", str(run), "--db", str(db)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "forgery" in err[0] and "refused" in err[0], err
    assert main(["catalog", "add", "--allow-simulated", str(lab["signed"]), "--db", str(db)]) == 0  # the true run
    out = capsys.readouterr().out
    assert "added to" in out and "unsigned" not in out


@pytest.mark.parametrize("command", ["compensate", "evaluate"])
def test_compensate_and_evaluate_refuse_a_forgery_in_one_line(lab, tmp_path, capsys, monkeypatch, command):
    run = _copy(lab, tmp_path)
    forge(run, **FORGERIES["serial number"])
    monkeypatch.setenv(LAB_PUBLIC_KEYS_ENV, str(lab["public"]))
    args = [command, str(run)] + (["--format", "linuxcnc", "--out", str(tmp_path / "comp.txt")] if command == "compensate" else [])
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "forgery" in err[0], err
    assert not (tmp_path / "comp.txt").exists()
    assert main([command, str(lab["signed"])] + args[2:]) == 0  # the true run


def test_a_signature_removed_another_labs_key_or_an_unsigned_run_is_refused_where_the_lab_signs(lab, tmp_path, capsys,
                                                                                                monkeypatch):
    monkeypatch.setenv(LAB_PUBLIC_KEYS_ENV, str(lab["public"]))
    removed = _copy(lab, tmp_path)
    (removed / "signature.json").unlink()
    stripped = _copy(lab, tmp_path / "b")  # the signature and the claim both removed: an unsigned run
    (stripped / "signature.json").unlink()
    forge(stripped, results=lambda d: d.pop("signature"))
    resigned = _copy(lab, tmp_path / "c")  # signed again with another lab's key, the claim edited to match
    from rtcal.run.integrity import signature_digests
    from rtcal.run.signing import load_lab_key, signed_document
    from rtcal.methods import read_results

    other = load_lab_key({LAB_KEY_ENV: str(lab["other_private"])})
    assert other is not None
    forge(resigned, results=lambda d: d.update(signature={"algorithm": "ed25519", "signer": other.signer,
                                                          "key_fingerprint": other.fingerprint}))
    document = signed_document(other, _sha(resigned / "results.json"), *signature_digests(read_results(resigned)), "now")
    (resigned / "signature.json").write_text(json.dumps(document))
    for run, said in ((removed, "signature was removed"), (stripped, "unsigned"), (resigned, "not one of the lab's keys"),
                      (lab["unsigned"], "unsigned")):
        assert main(["verify", str(run)]) == 1, run
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and said in err[0], err
        assert main(["catalog", "add", "--allow-simulated", str(run), "--db", str(tmp_path / "c.sqlite")]) == 1
        assert said in capsys.readouterr().err


def test_the_signature_file_itself_edited_is_refused(lab, tmp_path, capsys, monkeypatch):
    run = _copy(lab, tmp_path)
    doc = json.loads((run / "signature.json").read_text())
    doc["signed_utc"] = "2020-01-01T00:00:00+00:00"
    (run / "signature.json").write_text(json.dumps(doc))
    monkeypatch.setenv(LAB_PUBLIC_KEYS_ENV, str(lab["public"]))
    assert main(["verify", str(run)]) == 1
    assert "does not verify with the lab's key" in capsys.readouterr().err


def test_the_certificate_says_who_signed_and_with_which_key_on_page_1(lab, capsys, monkeypatch):
    import pymupdf as fitz

    signed = json.loads((lab["signed"] / "results.json").read_text())["signature"]
    fingerprint = signed["key_fingerprint"]
    assert lab["public"].read_text().count(fingerprint) == 1  # the key file names the same fingerprint
    certificate = json.loads((lab["signed"] / "certificate.json").read_text())
    line = certificate["sign_off"]["electronic_signature"]
    assert "Example Metrology Lab" in line and fingerprint in line
    with fitz.open(lab["signed"] / "report.pdf") as pdf:
        page_1 = " ".join(pdf[0].get_text().split())
    assert fingerprint in page_1 and "Signed electronically by Example Metrology Lab" in page_1
    assert fingerprint in (lab["signed"] / "report.html").read_text()
    unsigned = json.loads((lab["unsigned"] / "certificate.json").read_text())["sign_off"]["electronic_signature"]
    assert unsigned.startswith("Unsigned")
    monkeypatch.setenv(LAB_PUBLIC_KEYS_ENV, str(lab["public"]))
    assert main(["verify", str(lab["signed"])]) == 0
    assert f"signature: signed by Example Metrology Lab, DAkkS D-K-99999-01-00 with key {fingerprint}: valid" in \
        capsys.readouterr().out


def test_an_unsigned_run_stays_usable_where_no_key_is_configured_and_says_so(lab, tmp_path, capsys):
    run = lab["unsigned"]
    assert not (run / "signature.json").exists() and "signature" not in json.loads((run / "results.json").read_text())
    assert main(["verify", str(run)]) == 0
    assert "signature: unsigned" in capsys.readouterr().out
    assert main(["compensate", str(run), "--format", "linuxcnc", "--out", str(tmp_path / "c.txt")]) == 0
    db = str(tmp_path / "catalog.sqlite")
    assert main(["catalog", "add", "--allow-simulated", str(run), "--db", db]) == 0
    assert "unsigned" in capsys.readouterr().out
    assert main(["catalog", "list", "--db", db]) == 0
    assert "unsigned" in capsys.readouterr().out.splitlines()[1]
    assert main(["catalog", "history", "--serial", "SIM-230-2", "--db", db, "--json"]) == 0
    assert "unsigned" in json.loads(capsys.readouterr().out)[0]["marks"]


def test_key_generate_writes_an_owner_only_private_key_never_printed_never_replaced(tmp_path, capsys):
    assert main(["key", "generate", "--out", str(tmp_path / "k"), "--signer", "Lab"]) == 0
    out = capsys.readouterr().out
    private = tmp_path / "k" / PRIVATE_NAME
    assert stat.S_IMODE(private.stat().st_mode) == 0o600
    body = "".join(line for line in private.read_text().splitlines() if not line.startswith(("-----", "rtcal", "Signer",
                                                                                             "Fingerprint")))
    assert base64.b64decode(body) and body not in out and "PRIVATE KEY" not in out
    before = private.read_bytes()
    assert main(["key", "generate", "--out", str(tmp_path / "k"), "--signer", "Lab"]) == 2
    assert "never replaces a key" in capsys.readouterr().err and private.read_bytes() == before


def test_a_private_key_others_can_read_or_inside_the_run_folder_refuses_the_run(lab, tmp_path, capsys, monkeypatch):
    loose = tmp_path / "loose.key"
    shutil.copyfile(lab["private"], loose)
    os.chmod(loose, 0o644)
    monkeypatch.setenv(LAB_KEY_ENV, str(loose))
    assert main(["run", str(PROCEDURE), "--virtual-clock", "--out", str(tmp_path / "run")]) == 2
    assert "chmod 600" in capsys.readouterr().err and not (tmp_path / "run" / "run.sqlite").exists()
    inside = tmp_path / "run2" / "lab.key"
    inside.parent.mkdir()
    shutil.copyfile(lab["private"], inside)
    os.chmod(inside, 0o600)
    monkeypatch.setenv(LAB_KEY_ENV, str(inside))
    assert main(["run", str(PROCEDURE), "--virtual-clock", "--out", str(tmp_path / "run2")]) == 2
    assert "outside every run folder" in capsys.readouterr().err


def test_compensate_refuses_a_schema_version_set_back_by_hand(lab, tmp_path, capsys):
    """schema_version 1.1 carries no digests: set back by hand, with the digests and the store removed, the
    file would pass as an old one; its rtcal_version says which schema it wrote."""
    run = _copy(lab, tmp_path, "unsigned")
    data = json.loads((run / "results.json").read_text())
    data["schema_version"] = "1.1"
    data.pop("digests")
    data["evaluation"]["iso230_2"]["E"] -= 5.0
    (run / "results.json").write_text(json.dumps(data, indent=2))
    (run / "run.sqlite").unlink()
    assert main(["compensate", str(run), "--format", "linuxcnc", "--out", str(tmp_path / "c.txt")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "set back by hand" in err[0] and data["rtcal_version"] in err[0], err
    assert not (tmp_path / "c.txt").exists()


def test_resume_signs_the_results_it_writes(lab, tmp_path, capsys, monkeypatch):
    """A run stopped before its results, resumed with the lab's key: the resume writes the results and signs them."""
    from rtcal.run.runner import run_procedure

    run_dir = tmp_path / "run"

    def abort_at_once(engine, _run_dir):
        engine.request_abort("the test")
        return None

    with pytest.raises(KeyboardInterrupt):
        run_procedure(PROCEDURE, out_dir=run_dir, show_progress=False, virtual_clock=True, on_engine=abort_at_once)
    assert not (run_dir / "signature.json").exists()
    monkeypatch.setenv(LAB_KEY_ENV, str(lab["private"]))
    assert main(["resume", str(run_dir)]) == 0
    monkeypatch.delenv(LAB_KEY_ENV)
    monkeypatch.setenv(LAB_PUBLIC_KEYS_ENV, str(lab["public"]))
    capsys.readouterr()
    assert main(["verify", str(run_dir)]) == 0
    assert "valid (checked against the lab's key)" in capsys.readouterr().out


def test_the_as_found_as_left_certificate_says_it_is_not_itself_signed(lab, tmp_path):
    """Written from two runs after them, it carries neither run's signature as its own."""
    assert main(["compare", str(lab["signed"]), str(lab["unsigned"]), "--certificate", "--certificate-number",
                 "EML-AFAL-1", "--out", str(tmp_path)]) == 0
    doc = json.loads((tmp_path / "as_found_as_left.json").read_text())
    line = doc["sign_off"]["electronic_signature"]
    assert line.startswith("Not itself signed") and "As found: Signed electronically" in line and "As left: Unsigned" in line
    assert doc["header"]["marking"].startswith("SIMULATED")
