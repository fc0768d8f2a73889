"""Outputs checked against the store: digests that bind results.json and run.sqlite together.

results.json records (``digests``) a SHA-256 of the store's readings and events and one of the
procedure, bench and seed the results were computed from; the store records (meta
``results_sha256``) the SHA-256 of the results.json the run wrote. An edit to either file is
found by every command that reads a run (:func:`check_run`), and ``rtcal verify`` recomputes the
results from the store. results.json also records (``digests.deliverables_sha256``, schema 1.3) the
SHA-256 of every other file the run wrote — certificate.json, report.md/.html/.pdf,
positioning_deviations.csv, the figures — taken after they were written and before results.json
was: ``rtcal verify`` checks each (:func:`check_deliverables`). No digest covers a path: a run
directory copied elsewhere stays valid.

Digests catch accidents, not someone who recomputes them: with the lab's key configured a run is
signed (signature.json, rtcal/run/signing.py) and :func:`check_run` checks the signature against the
lab's public keys (:func:`check_signature`); a file that claims an older ``schema_version`` than its
``rtcal_version`` writes is refused (:func:`schema_set_back`).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import sqlite3
import stat
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Iterable, Literal, Mapping
from urllib.parse import quote

from pydantic import BaseModel, ConfigDict, Field

from drivers.addresses import redact_tokens
from rtcal.results.io import FILENAME as RESULTS_FILENAME, ResultsError, results_json
from rtcal.results.model import DELIVERABLE_DIGESTS_SINCE, SCHEMA_WRITTEN_SINCE, STORE_DIGESTS_SINCE, Digests, RunResults
from rtcal.run.signing import (LAB_KEY_ENV, LAB_PUBLIC_KEYS_ENV, MAX_SIGNATURE_BYTES, SIGNATURE_FILENAME, PublicKey,
                               signature_valid, trusted_keys)
from rtcal.store.runstore import CONTEXT, EVENT_COLUMNS, READING_COLUMNS, RunStore

RESULTS_DIGEST_KEY = "results_sha256"  # store meta: the digest of the results.json the run wrote
# what of the store's metadata the results were computed from (paths and times are left out: a copy stays valid)
PROCEDURE_KEYS = ("method", "procedure_yaml", "instruments", "scenario_yaml", "seed")


class IntegrityError(ResultsError):
    """results.json and run.sqlite do not match (exit 2): the message names the mismatch."""


def _rows_digest(rows: Iterable[tuple], count: list[int]) -> str:
    h = hashlib.sha256()
    for row in rows:
        h.update(json.dumps(list(row), ensure_ascii=True, allow_nan=True).encode())
        h.update(b"\n")
        count[0] += 1
    return h.hexdigest()


def store_digests(db: sqlite3.Connection) -> Digests:
    """The digests of a store's readings, events and procedure, through any connection to it."""
    readings, events = [0], [0]
    has_context = any(row[1] == CONTEXT for row in db.execute("PRAGMA table_info(readings)"))
    reading_rows = db.execute(f"SELECT {', '.join(READING_COLUMNS)}{', ' + CONTEXT if has_context else ''} FROM readings "
                              "ORDER BY id")
    # a row's declared context is covered where it has one; a row without (every row before context columns) is
    # digested as it always was, so a run's digest does not change with the store's schema
    readings_sha = _rows_digest((row[:-1] if has_context and row[-1] is None else row for row in reading_rows), readings)
    events_sha = _rows_digest(db.execute(f"SELECT {', '.join(EVENT_COLUMNS)} FROM events ORDER BY id"), events)
    meta = dict(db.execute("SELECT key, value FROM meta"))
    procedure = {k: redact_tokens(meta.get(k, "")) for k in PROCEDURE_KEYS}
    procedure_sha = hashlib.sha256(json.dumps(procedure, sort_keys=True).encode()).hexdigest()
    return Digests(algorithm="sha256", readings_sha256=readings_sha, readings=readings[0], events_sha256=events_sha,
                   events=events[0], procedure_sha256=procedure_sha)


def digests_of(store: RunStore) -> Digests:
    return store_digests(store._db)  # noqa: SLF001 — the store's own connection, inside the run's lock


def results_digest(results: RunResults) -> str:
    """The SHA-256 of the results.json text :func:`rtcal.results.write_results` writes for ``results``."""
    return hashlib.sha256(results_json(results).encode("utf-8")).hexdigest()


def _file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def deliverable_digests(folder: Path) -> dict[str, str]:
    """The SHA-256 of every file written into ``folder`` (its path there, ``/``-separated) but
    results.json, which records them: what the run's deliverables are, as written."""
    folder = Path(folder)
    found = {}
    for path in sorted(folder.rglob("*")):
        name = path.relative_to(folder).as_posix()
        if path.is_file() and not path.is_symlink() and name != RESULTS_FILENAME:
            found[name] = _file_sha256(path)
    return found


def check_deliverables(run_dir: str | Path, results: RunResults) -> list[tuple[str, str]]:
    """Each deliverable results.json records a digest of, and what it is now: ``as written``,
    ``EDITED`` (its bytes are not those the run wrote), ``missing`` or ``not a regular file``
    (a link or a folder in its place). Empty when the file records no deliverables (before 1.3)."""
    run_dir = Path(run_dir)
    recorded = results.digests.deliverables_sha256 if results.digests is not None else None
    status = []
    for name, digest in sorted((recorded or {}).items()):
        path = run_dir / name
        if not os.path.lexists(path):
            status.append((name, "missing"))
        elif path.is_symlink() or not path.is_file():
            status.append((name, "not a regular file"))
        else:
            status.append((name, "as written" if _file_sha256(path) == digest else "EDITED"))
    return status


def _version(results: RunResults) -> tuple[int, int]:
    major, _, minor = results.schema_version.partition(".")
    return int(major), int(minor)


def _release(text: str) -> tuple[int, int, int] | None:
    m = re.match(r"(\d{1,6})\.(\d{1,6})\.(\d{1,6})(?![\d.])", text)
    return (int(m.group(1)), int(m.group(2)), int(m.group(3))) if m else None


def schema_set_back(results: RunResults, path: Path) -> str:
    """Why a results.json whose ``schema_version`` is older than what the rtcal it names (``rtcal_version``)
    writes is not rtcal's, or "": a schema set back by hand would exempt the file from the digests
    its real schema requires (SCHEMA_WRITTEN_SINCE)."""
    release = _release(results.rtcal_version)
    if release is None:
        return f"{path}: its rtcal_version {results.rtcal_version[:40]!r} is not a version rtcal writes: not a file rtcal wrote"
    least = max((schema for since, schema in SCHEMA_WRITTEN_SINCE if release >= since), default=(1, 0))
    if _version(results) < least:
        return (f"{path}: claims schema_version {results.schema_version}, yet rtcal {results.rtcal_version} writes "
                f"{least[0]}.{least[1]} or later: its schema_version was set back by hand; not a file rtcal wrote")
    return ""


def missing_digests(results: RunResults, path: Path) -> str:
    """Why a results.json that should carry digests but carries none is not rtcal's, or "": a file
    of schema 1.2 or later always records its store's, one of 1.3 or later its deliverables', and none
    claims an older schema than its rtcal writes (:func:`schema_set_back`)."""
    if schema_set_back(results, path):
        return schema_set_back(results, path)
    version = results.schema_version
    if results.digests is None and _version(results) >= STORE_DIGESTS_SINCE:
        return (f"{path}: records no digests of its run's store, yet its schema_version {version} is one rtcal always "
                "writes them in: not a file rtcal wrote")
    if results.digests is not None and results.digests.deliverables_sha256 is None \
            and _version(results) >= DELIVERABLE_DIGESTS_SINCE:
        return (f"{path}: records no digests of its certificate, reports and CSV, yet its schema_version {version} is "
                "one rtcal always writes them in: not a file rtcal wrote")
    return ""


def _read_only(path: Path) -> sqlite3.Connection:
    """The store opened read-only: checking a run changes no byte of it."""
    mode = "mode=ro" if os.path.lexists(f"{path}-wal") else "immutable=1"
    return sqlite3.connect(f"file:{quote(str(path.absolute()))}?{mode}", uri=True, timeout=10.0)


def check_run(run_dir: str | Path, results: RunResults, keys: Mapping[str, PublicKey] | None = None) -> list[str]:
    """Refuse (IntegrityError, naming the mismatch) a results.json that does not match its run's
    store, or whose signature the lab's keys (``keys``; default: those configured, rtcal/run/signing.py)
    do not confirm. Returns warnings: a file from before schema 1.2 without a store cannot be checked."""
    warnings = _check_store(Path(run_dir), results)
    check_signature(Path(run_dir), results, keys)
    return warnings


@dataclass(frozen=True)
class SignatureStatus:
    """What a run's signature is: ``valid`` (checked against a lab key), ``unchecked`` (signed, no lab key
    configured to check it with) or ``unsigned``; ``text`` says it in a line."""

    state: str
    text: str
    signer: str = ""
    fingerprint: str = ""


class _SignatureFile(BaseModel):
    """signature.json as rtcal writes it (rtcal/run/signing.py), read strictly."""

    model_config = ConfigDict(extra="forbid", strict=True)
    format: Literal["rtcal-run-signature/1"]
    algorithm: Literal["ed25519"]
    signer: Annotated[str, Field(min_length=1, max_length=200)]
    key_fingerprint: Annotated[str, Field(pattern=r"^SHA256:[A-Za-z0-9+/]{43}$")]
    signed_utc: Annotated[str, Field(max_length=40)]
    results_sha256: Annotated[str, Field(pattern=r"^[0-9a-f]{64}$")]
    digests: dict[str, Any]
    deliverables_sha256: dict[Annotated[str, Field(max_length=1000)], Annotated[str, Field(pattern=r"^[0-9a-f]{64}$")]]
    signature: Annotated[str, Field(max_length=200)]


def _signature_file(path: Path) -> dict[str, Any]:
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOFOLLOW)
    except OSError as exc:
        raise IntegrityError(f"{path}: cannot be read ({exc.strerror or exc}): the run's signature cannot be checked") from None
    with os.fdopen(fd, "rb") as fh:
        if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
            raise IntegrityError(f"{path}: not a regular file: not the signature rtcal wrote")
        data = fh.read(MAX_SIGNATURE_BYTES + 1)
    try:
        if len(data) > MAX_SIGNATURE_BYTES:
            raise ValueError("too large")
        document = json.loads(data)
        _SignatureFile.model_validate(document)
    except (ValueError, RecursionError, UnicodeDecodeError) as exc:  # pydantic's ValidationError is a ValueError
        raise IntegrityError(f"{path}: not a signature rtcal wrote ({' '.join(str(exc).split())[:160]})") from None
    return dict(document)


def signature_digests(results: RunResults) -> tuple[dict[str, Any], dict[str, str]]:
    """What a signature covers besides results.json's own SHA-256: its digests of the store, and of every deliverable."""
    digests = results.digests.model_dump(mode="json", exclude={"deliverables_sha256"}) if results.digests else {}
    deliverables = dict(results.digests.deliverables_sha256 or {}) if results.digests else {}
    return digests, deliverables


def check_signature(run_dir: Path, results: RunResults, keys: Mapping[str, PublicKey] | None = None) -> SignatureStatus:
    """The run's signature against the lab's public keys (``keys``; default: those configured). Refused
    (IntegrityError, one line): a run unsigned where a lab key is configured, signed by a key that is not
    the lab's, a signature that does not verify, a results.json or a digest other than the ones signed."""
    run_dir = Path(run_dir)
    keys = trusted_keys() if keys is None else keys
    path, results_path = run_dir / SIGNATURE_FILENAME, run_dir / RESULTS_FILENAME
    claim = results.signature
    present = os.path.lexists(path)
    if claim is None and not present:
        if keys:
            raise IntegrityError(f"{run_dir}: unsigned (no {SIGNATURE_FILENAME}, results.json names no signer), yet the "
                                 f"lab's keys are configured ({LAB_PUBLIC_KEYS_ENV}, {LAB_KEY_ENV}): a run the lab did "
                                 "not sign is refused where it signs its runs")
        return SignatureStatus("unsigned", "unsigned: no lab key was configured when the run was written (RTCAL_LAB_KEY)")
    if claim is None:
        raise IntegrityError(f"{path}: a signature, yet {results_path} names no signer: the results were replaced")
    if not present:
        raise IntegrityError(f"{results_path}: names the signer {claim.signer!r} (key {claim.key_fingerprint}), but "
                             f"{path} is missing: the signature was removed (copy the whole run folder)")
    document = _signature_file(path)
    if (document["signer"], document["key_fingerprint"]) != (claim.signer, claim.key_fingerprint):
        raise IntegrityError(f"{path}: signed by {document['key_fingerprint']}, yet {results_path} names "
                             f"{claim.key_fingerprint}: not this run's signature")
    who = f"signed by {claim.signer} with key {claim.key_fingerprint}"
    if not keys:
        return SignatureStatus("unchecked", f"{who}: NOT checked, no lab public key is configured ({LAB_PUBLIC_KEYS_ENV})",
                               claim.signer, claim.key_fingerprint)
    key = keys.get(claim.key_fingerprint)
    if key is None:
        raise IntegrityError(f"{path}: {who}, which is not one of the lab's keys ({LAB_PUBLIC_KEYS_ENV}): a forgery, or "
                             "another laboratory's run")
    if not signature_valid(document, key):
        raise IntegrityError(f"{path}: its signature does not verify with the lab's key {key.fingerprint}: the signature "
                             "or what it covers was edited; a forgery")
    actual = hashlib.sha256(results_path.read_bytes()).hexdigest()
    if document["results_sha256"] != actual:
        raise IntegrityError(f"{results_path}: not the file the lab signed (sha256 {actual[:12]}…, signed "
                             f"{document['results_sha256'][:12]}…): edited after the run, its digests recomputed; a forgery")
    digests, deliverables = signature_digests(results)
    if (document["digests"], document["deliverables_sha256"]) != (digests, deliverables):
        raise IntegrityError(f"{results_path}: its digests are not those the lab signed: a forgery")
    return SignatureStatus("valid", f"{who}: valid (checked against the lab's key)", claim.signer, claim.key_fingerprint)


def _check_store(run_dir: Path, results: RunResults) -> list[str]:
    """The store half of :func:`check_run`."""
    path, store_path = run_dir / RESULTS_FILENAME, run_dir / RunStore.FILENAME
    if not store_path.is_file() or store_path.is_symlink():
        if missing_digests(results, path):
            raise IntegrityError(missing_digests(results, path))
        if results.digests is not None:
            raise IntegrityError(f"{path}: records digests of its run's store, but {store_path} is missing: the results "
                                 "cannot be checked against the readings (copy the whole run directory)")
        return [f"{path} carries no digests (written before schema 1.2) and has no {RunStore.FILENAME} beside it: "
                "it is not checked against any readings"]
    try:
        with closing(_read_only(store_path)) as db:
            recorded = db.execute("SELECT value FROM meta WHERE key = ?", (RESULTS_DIGEST_KEY,)).fetchone()
            found = store_digests(db) if results.digests is not None else None
    except sqlite3.DatabaseError as exc:
        raise IntegrityError(f"{store_path}: cannot be read to check {path} against it ({exc})") from None
    actual = hashlib.sha256(path.read_bytes()).hexdigest()
    if recorded is None:
        if results.digests is not None:
            raise IntegrityError(f"{store_path}: holds no digest of the results.json its run wrote, yet {path} records "
                                 "digests: the store was edited or belongs to another run")
        if missing_digests(results, path):
            raise IntegrityError(missing_digests(results, path))
        return [f"{path} was written before schema 1.2: it carries no digests and is not checked against {store_path}"]
    if recorded[0] != actual:
        raise IntegrityError(f"{path}: does not match the digest {store_path} recorded when the run wrote it "
                             f"(sha256 {actual[:12]}…, recorded {recorded[0][:12]}…): the file was edited after the run; "
                             f"`rtcal verify {run_dir}` recomputes the results from the readings")
    if results.digests is None:
        raise IntegrityError(f"{path}: records no digests of the store, which recorded this file's: not a file rtcal wrote")
    if missing_digests(results, path):
        raise IntegrityError(missing_digests(results, path))
    mismatch = compare_digests(results.digests, found)
    if mismatch:
        raise IntegrityError(f"{store_path}: {mismatch} do not match the digest {path} records: the store was edited "
                             "after the results were computed from it")
    return []


def compare_digests(recorded: Digests, found: Digests | None) -> str:
    """What differs ("its readings (1200 now, 1201 recorded)"), or "" when all match."""
    if found is None:
        return "its readings"
    parts = []
    if (recorded.readings_sha256, recorded.readings) != (found.readings_sha256, found.readings):
        parts.append(f"its readings ({found.readings} now, {recorded.readings} recorded)")
    if (recorded.events_sha256, recorded.events) != (found.events_sha256, found.events):
        parts.append(f"its events ({found.events} now, {recorded.events} recorded)")
    if recorded.procedure_sha256 != found.procedure_sha256:
        parts.append("its procedure, bench or seed")
    return " and ".join(parts)
