"""The catalogue's audit trail: every add, supersede, reassessment, retirement and policy change one
row, chained by hash, so that no row can be edited, deleted or moved without `rtcal catalog verify`
naming it.

A row's hash is SHA-256 of its fields (:data:`ROW_FIELDS` in that order, the previous row's hash
among them) as a canonical JSON list; the first row's previous hash is :data:`GENESIS`. An ``add``
(or ``supersede``) row records the entry's own hash (:func:`entry_hash`: every column of the entry
in :data:`ENTRY_FIELDS` order but the results text, which ``results_sha256`` stands for, and its
reference instruments, sorted), so that an entry edited after it was filed no longer matches the
row that filed it. The database refuses UPDATE and DELETE
on these tables (triggers, migration 0004); the chain finds what a superuser does anyway.

Migration 0004 holds a copy of :func:`canonical`, :func:`entry_hash` and :func:`row_hash` (a
migration stays as it ran): keep the two alike."""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from typing import Any

GENESIS = "0" * 64
ROW_FIELDS = ("seq", "at_utc", "who", "action", "subject", "site", "reason", "detail", "prev_hash")
ACTIONS = ("add", "supersede", "reassess", "retire", "policy", "usage")
ENTRY_HASH_VERSION = 1
ENTRY_FIELDS = (  # version 1: the calibrations columns of revision 0004 but the results text
    "run_id", "serial_number", "axis", "machine", "customer", "method", "measured_utc", "finished_utc",
    "certificate_number", "verdict",
    *[f"{p}_{k}arcsec" for p in ("E", "M", "B", "R", "A") for k in ("", "U_", "limit_")],
    *[f"vdi_{p}_arcsec" for p in ("Pa", "P", "Ps_max", "U_max")],
    "location_errors", "digests", "run_dir", "added_utc", "test", "site", "rig", "state", "replaces", "supersedes",
    "origin", "added_by", "results_sha256", "certificate_key", "simulated", "signature")
INSTRUMENT_FIELDS = ("role", "instrument_id", "kind", "certificate_number", "issuer", "due", "correction")
NUMBERS = frozenset(k for k in ENTRY_FIELDS if k.endswith("_arcsec"))  # the only fields that may be a float


def _plain(value: Any) -> Any:
    """A value as both databases give it back: a non-finite float as null (SQLite keeps NaN as NULL)."""
    return None if isinstance(value, float) and not math.isfinite(value) else value


def canonical(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False)


def entry_hash(entry: dict[str, Any], instruments: list[dict[str, Any]]) -> str:
    """The entry as filed: its columns (:data:`ENTRY_FIELDS`) and its instruments (text only, sorted), hashed."""
    values = [_plain(entry.get(k)) if k in NUMBERS else entry.get(k) for k in ENTRY_FIELDS]
    doc = [values, sorted([str(i.get(k, "")) for k in INSTRUMENT_FIELDS] for i in instruments)]
    return hashlib.sha256(canonical(doc).encode()).hexdigest()


def row_hash(row: dict[str, Any]) -> str:
    """A row's fields (:data:`ROW_FIELDS`, in that order) as a canonical JSON list, hashed."""
    return hashlib.sha256(canonical([row[k] for k in ROW_FIELDS]).encode()).hexdigest()


def chained(seq: int, prev_hash: str, **fields: Any) -> dict[str, Any]:
    """The row that follows ``prev_hash`` at ``seq``, its hash computed."""
    row = {"seq": seq, "prev_hash": prev_hash, **{k: fields[k] for k in ROW_FIELDS if k not in ("seq", "prev_hash")}}
    row["hash"] = row_hash(row)
    return row


@dataclass
class Findings:
    """What :func:`check` found: each problem one line naming the row or entry."""

    rows: int = 0
    entries: int = 0
    problems: list[str] = field(default_factory=list)


def check(rows: list[dict[str, Any]], entries: dict[str, str], out: Findings) -> None:
    """The chain (rows by seq: numbered 1…n, each linked to the one before, each hash its own) and
    every entry against the row that filed it (``entries``: run id → its :func:`entry_hash` now)."""
    prev, filed = GENESIS, {}
    out.rows, out.entries = len(rows), len(entries)
    for k, row in enumerate(rows, start=1):
        where = f"audit row {row['seq']} ({row['action']} {str(row['subject'])[:60]}, {row['at_utc'][:19]})"
        if row["seq"] != k:
            out.problems.append(f"audit row {k} is missing (the next is {row['seq']}): deleted" if row["seq"] > k
                                else f"{where}: numbered out of order")
        if row["prev_hash"] != prev:
            out.problems.append(f"{where}: does not follow the row before it (deleted, inserted or reordered rows)")
        if row_hash(row) != row["hash"]:
            out.problems.append(f"{where}: edited after it was written (its hash is not its own)")
        prev = row["hash"]
        if row["action"] in ("add", "supersede"):
            try:
                detail = json.loads(row["detail"])
                filed[str(detail["run_id"])] = (str(detail["entry_sha256"]), where)
            except (ValueError, KeyError, TypeError):
                out.problems.append(f"{where}: its detail is not what rtcal writes")
    for run_id, now in entries.items():
        if run_id not in filed:
            out.problems.append(f"entry {run_id}: no audit row filed it (inserted behind rtcal's back)")
        elif filed[run_id][0] != now:
            out.problems.append(f"entry {run_id}: edited after {filed[run_id][1]} filed it")
    for run_id, (_, where) in filed.items():
        if run_id not in entries:
            out.problems.append(f"entry {run_id}: {where} filed it and it is gone (deleted)")
