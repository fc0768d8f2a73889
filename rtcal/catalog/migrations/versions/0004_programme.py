"""A lab's programme (issue 45): per entry its test, site, rig, declared as-found/as-left state,
what it replaces, who added it, the hash of its results text and a unique certificate number; the
reference instruments each entry used; the audit trail (a hash chain); interval policies,
retirements and machine hours. Entries already there get their test, instruments (from their
results text; the correction applied is not recorded for them) and one `add` row each in the new
audit trail; of two entries with one certificate number the first added keeps it as its unique
key. Every table is append-only from here (triggers refuse UPDATE and DELETE).

The hash functions are copies of rtcal/catalog/audit.py's as they were at this revision."""

import hashlib
import json
import math
from datetime import datetime, timezone

import sqlalchemy as sa
from alembic import op

revision = "0004"
down_revision = "0003"

GENESIS = "0" * 64
ROW_FIELDS = ("seq", "at_utc", "who", "action", "subject", "site", "reason", "detail", "prev_hash")
ENTRY_FIELDS = (
    "run_id", "serial_number", "axis", "machine", "customer", "method", "measured_utc", "finished_utc",
    "certificate_number", "verdict",
    *[f"{p}_{k}arcsec" for p in ("E", "M", "B", "R", "A") for k in ("", "U_", "limit_")],
    *[f"vdi_{p}_arcsec" for p in ("Pa", "P", "Ps_max", "U_max")],
    "location_errors", "digests", "run_dir", "added_utc", "test", "site", "rig", "state", "replaces", "supersedes",
    "origin", "added_by", "results_sha256", "certificate_key", "simulated", "signature")
INSTRUMENT_FIELDS = ("role", "instrument_id", "kind", "certificate_number", "issuer", "due", "correction")
APPEND_ONLY = ("calibrations", "instruments", "audit", "policies", "retirements", "usage")


def _plain(value):
    return None if isinstance(value, float) and not math.isfinite(value) else value


def _canonical(value):
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False)


def _entry_hash(entry, instruments):
    values = [_plain(entry.get(k)) if k.endswith("_arcsec") else entry.get(k) for k in ENTRY_FIELDS]
    doc = [values, sorted([str(i.get(k, "")) for k in INSTRUMENT_FIELDS] for i in instruments)]
    return hashlib.sha256(_canonical(doc).encode()).hexdigest()


def _row_hash(row):
    return hashlib.sha256(_canonical([row[k] for k in ROW_FIELDS]).encode()).hexdigest()


def _mapping(value):
    return value if isinstance(value, dict) else {}


def _text(value, limit):
    return " ".join(str(value or "").split())[:limit]


def upgrade() -> None:
    for name, kind in (("test", 200), ("site", 100), ("rig", 100), ("state", 20), ("replaces", 100), ("added_by", 100),
                       ("results_sha256", 64)):
        op.add_column("calibrations", sa.Column(name, sa.String(kind), nullable=False, server_default=""))
    op.add_column("calibrations", sa.Column("origin", sa.String(20), nullable=False, server_default="run"))
    op.add_column("calibrations", sa.Column("supersedes", sa.String(64)))
    op.add_column("calibrations", sa.Column("certificate_key", sa.String(100)))
    op.create_table(
        "instruments",
        sa.Column("run_id", sa.String(64), primary_key=True), sa.Column("role", sa.String(50), primary_key=True),
        sa.Column("instrument_id", sa.String(200), nullable=False), sa.Column("kind", sa.String(50), nullable=False),
        sa.Column("certificate_number", sa.String(100), nullable=False), sa.Column("issuer", sa.String(200), nullable=False),
        sa.Column("due", sa.String(40), nullable=False), sa.Column("correction", sa.Text, nullable=False),
        sa.Column("measured_utc", sa.String(40), nullable=False),
        sa.Column("site", sa.String(100), nullable=False, server_default=""))
    op.create_index("ix_instruments_used_by", "instruments", ["instrument_id", "measured_utc"])
    op.create_table(
        "audit",
        sa.Column("seq", sa.Integer, primary_key=True, autoincrement=False), sa.Column("at_utc", sa.String(40), nullable=False),
        sa.Column("who", sa.String(100), nullable=False), sa.Column("action", sa.String(20), nullable=False),
        sa.Column("subject", sa.String(300), nullable=False), sa.Column("site", sa.String(100), nullable=False, server_default=""),
        sa.Column("reason", sa.Text, nullable=False), sa.Column("detail", sa.Text, nullable=False),
        sa.Column("prev_hash", sa.String(64), nullable=False), sa.Column("hash", sa.String(64), nullable=False))
    op.create_table(
        "policies",
        sa.Column("version", sa.Integer, primary_key=True, autoincrement=False), sa.Column("at_utc", sa.String(40), nullable=False),
        sa.Column("who", sa.String(100), nullable=False), sa.Column("text", sa.Text, nullable=False),
        sa.Column("sha256", sa.String(64), nullable=False))
    op.create_table(
        "retirements",
        sa.Column("serial_number", sa.String(100), primary_key=True), sa.Column("axis", sa.String(50), primary_key=True),
        sa.Column("at_utc", sa.String(40), primary_key=True), sa.Column("who", sa.String(100), nullable=False),
        sa.Column("reason", sa.Text, nullable=False))
    op.create_table(
        "usage",
        sa.Column("serial_number", sa.String(100), primary_key=True), sa.Column("at_utc", sa.String(40), primary_key=True),
        sa.Column("hours", sa.Float, nullable=False), sa.Column("source", sa.String(300), nullable=False))
    _backfill()
    op.create_index("ux_calibrations_certificate", "calibrations", ["certificate_key"], unique=True)
    _append_only()


def _backfill() -> None:
    """Every entry already there: its test, results hash, unique certificate key, instruments and an
    `add` row of the new audit trail (oldest added first)."""
    conn = op.get_bind()
    cal = sa.table("calibrations", *(sa.column(n) for n in (*ENTRY_FIELDS, "results")))
    rows = conn.execute(sa.select(cal).order_by(cal.c.added_utc, cal.c.run_id)).mappings().all()
    taken, prev, now = set(), GENESIS, datetime.now(timezone.utc).isoformat()
    ins = sa.table("instruments", *(sa.column(n) for n in (*INSTRUMENT_FIELDS, "run_id", "measured_utc", "site")))
    aud = sa.table("audit", *(sa.column(n) for n in (*ROW_FIELDS, "hash")))
    for seq, r in enumerate(rows, start=1):
        entry = dict(r)
        text = entry.pop("results") or ""
        try:  # the stored text as JSON (a migration reads what older rtcal wrote, whatever it holds)
            stored = _mapping(json.loads(text))
        except ValueError:
            stored = {}
        procedure = _mapping(stored.get("procedure"))
        meta = _mapping(stored.get("metadata"))
        key = entry["certificate_number"] if entry["certificate_number"] and entry["certificate_number"] not in taken else None
        taken.add(entry["certificate_number"])
        changes = {"test": _text(procedure.get("name"), 200), "results_sha256": hashlib.sha256(text.encode()).hexdigest(),
                   "certificate_key": key}
        conn.execute(cal.update().where(cal.c.run_id == entry["run_id"]).values(**changes))
        entry.update(changes, site="", rig="", state="", replaces="", supersedes=None, origin="run", added_by="")
        found = []
        records = _mapping(meta.get("instruments"))
        for role, rec in records.items():
            if not isinstance(rec, dict) or not _text(rec.get("id"), 200):
                continue
            found.append({"role": _text(role, 50), "instrument_id": _text(rec.get("id"), 200), "kind": _text(role, 50),
                          "certificate_number": _text(rec.get("certificate_number"), 100),
                          "issuer": _text(rec.get("calibrated_by"), 200), "due": _text(rec.get("calibration_due"), 40),
                          "correction": "not recorded (filed before catalogue revision 0004)"})
        for i in found:
            conn.execute(ins.insert().values(**i, run_id=entry["run_id"], measured_utc=entry["measured_utc"], site=""))
        row = {"seq": seq, "at_utc": now, "who": "rtcal migration 0004", "action": "add", "subject": entry["run_id"],
               "site": "", "reason": f"filed on {entry['added_utc'][:19]}, before the catalogue kept an audit trail",
               "detail": _canonical({"run_id": entry["run_id"], "entry_sha256": _entry_hash(entry, found),
                                     "entry_hash_version": 1}), "prev_hash": prev}
        row["hash"] = _row_hash(row)
        conn.execute(aud.insert().values(**row))
        prev = row["hash"]


def _append_only() -> None:
    """UPDATE and DELETE refused on every table of the catalogue's record (a superuser can still drop a
    trigger: `rtcal catalog verify` finds what was changed then)."""
    if op.get_bind().dialect.name == "postgresql":
        op.execute("CREATE OR REPLACE FUNCTION rtcal_append_only() RETURNS trigger LANGUAGE plpgsql AS $$ BEGIN "
                   "RAISE EXCEPTION 'rtcal: % is append-only (a correction is a new entry; docs/catalog.md)', TG_TABLE_NAME; "
                   "END $$")
        for table in APPEND_ONLY:
            op.execute(f"CREATE TRIGGER {table}_append_only BEFORE UPDATE OR DELETE ON {table} "
                       "FOR EACH ROW EXECUTE FUNCTION rtcal_append_only()")
            op.execute(f"CREATE TRIGGER {table}_no_truncate BEFORE TRUNCATE ON {table} "
                       "FOR EACH STATEMENT EXECUTE FUNCTION rtcal_append_only()")
        return
    for table in APPEND_ONLY:
        for what in ("UPDATE", "DELETE"):
            op.execute(f"CREATE TRIGGER {table}_no_{what.lower()} BEFORE {what} ON {table} BEGIN "
                       f"SELECT RAISE(ABORT, 'rtcal: {table} is append-only (a correction is a new entry; docs/catalog.md)'); END")
