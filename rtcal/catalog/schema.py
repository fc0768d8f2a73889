"""The catalogue's one schema (SQLAlchemy Core), the same on SQLite and PostgreSQL.

A row per finished run, keyed by the run's id; the numbers a history needs are columns (indexed by
machine axis and time, so a history is one index range), the whole results.json a text column."""

from __future__ import annotations

import unicodedata

from sqlalchemy import Column, Float, Index, Integer, MetaData, String, Table, Text

metadata = MetaData()

PARAMETERS = ("E", "M", "B", "R", "A")  # ISO 230-2, each with its expanded U (k = 2)
VDI = ("Pa", "P", "Ps_max", "U_max")  # VDI/DGQ 3441 (results.json gives them without a U)
NAMES = ("serial_number", "axis", "machine", "customer", "certificate_number")  # kept as normal_text
VERDICTS = ("pass", "fail", "undecided", "none")
STATES = ("as_found", "as_left", "")  # what a run says it measured: before or after an adjustment ("": it does not say)
ORIGINS = ("run", "reissue")  # an entry of a run, or a superseding certificate a reassessment issued from its readings


def normal_text(text: str) -> str:
    """A name as the catalogue keeps it and looks it up: Unicode NFC, each run of white space one
    space, none at the ends — so a serial number typed two ways is one machine with one history.
    (Migration 0002 brought older entries to it; keep the two alike.)"""
    return " ".join(unicodedata.normalize("NFC", text).split())

calibrations = Table(
    "calibrations", metadata,
    Column("run_id", String(64), primary_key=True),
    Column("serial_number", String(100), nullable=False),
    Column("axis", String(50), nullable=False),
    Column("machine", String(200), nullable=False),
    Column("customer", String(200), nullable=False),
    Column("method", String(100), nullable=False),
    Column("measured_utc", String(40), nullable=False),
    Column("finished_utc", String(40), nullable=False),
    Column("certificate_number", String(100), nullable=False),
    Column("verdict", String(20), nullable=False),
    *[Column(f"{p}_arcsec", Float) for p in PARAMETERS],
    *[Column(f"{p}_U_arcsec", Float) for p in PARAMETERS],
    *[Column(f"{p}_limit_arcsec", Float) for p in PARAMETERS],
    *[Column(f"vdi_{p}_arcsec", Float) for p in VDI],
    Column("location_errors", Text, nullable=False),  # JSON: the method's location errors with U
    Column("digests", Text, nullable=False),  # JSON: results.json's digests of readings, events, procedure
    Column("run_dir", Text, nullable=False),  # where the readings stay
    Column("added_utc", String(40), nullable=False),
    Column("results", Text, nullable=False),  # the whole results.json
    Column("simulated", Text, nullable=False, server_default=""),  # why it is no calibration ("": it is one)
    Column("signature", Text, nullable=False, server_default="unsigned"),  # its signature when added
    # revision 0004: a lab's programme (docs/catalog.md)
    Column("test", String(200), nullable=False, server_default=""),  # the test as its procedure names it
    Column("site", String(100), nullable=False, server_default=""),
    Column("rig", String(100), nullable=False, server_default=""),
    Column("state", String(20), nullable=False, server_default=""),  # STATES: declared by the run
    Column("replaces", String(100), nullable=False, server_default=""),  # the certificate number this one replaces
    Column("supersedes", String(64)),  # the run id of the entry this one replaces (null: none)
    Column("origin", String(20), nullable=False, server_default="run"),  # ORIGINS
    Column("added_by", String(100), nullable=False, server_default=""),
    Column("results_sha256", String(64), nullable=False, server_default=""),  # of the results text
    Column("certificate_key", String(100)),  # the certificate number, unique (null: empty, or an older duplicate)
)
Index("ix_calibrations_history", calibrations.c.serial_number, calibrations.c.axis, calibrations.c.measured_utc)
Index("ux_calibrations_certificate", calibrations.c.certificate_key, unique=True)

instruments = Table(
    "instruments", metadata,  # the reference instruments each entry used (ISO/IEC 17025 6.5, 7.10)
    Column("run_id", String(64), primary_key=True),
    Column("role", String(50), primary_key=True),  # its key in the procedure's metadata.instruments
    Column("instrument_id", String(200), nullable=False),
    Column("kind", String(50), nullable=False),
    Column("certificate_number", String(100), nullable=False),
    Column("issuer", String(200), nullable=False),
    Column("due", String(40), nullable=False),
    Column("correction", Text, nullable=False),  # what of its calibration the run applied, in words
    Column("measured_utc", String(40), nullable=False),  # the entry's, so that `used-by --since` is one index range
    Column("site", String(100), nullable=False, server_default=""),
)
Index("ix_instruments_used_by", instruments.c.instrument_id, instruments.c.measured_utc)

audit = Table(
    "audit", metadata,  # every add, supersede, reassessment, retirement and policy change: a hash chain
    Column("seq", Integer, primary_key=True, autoincrement=False),  # 1, 2, 3, … (a gap is a deleted row)
    Column("at_utc", String(40), nullable=False),
    Column("who", String(100), nullable=False),
    Column("action", String(20), nullable=False),
    Column("subject", String(300), nullable=False),
    Column("site", String(100), nullable=False, server_default=""),
    Column("reason", Text, nullable=False),
    Column("detail", Text, nullable=False),  # JSON
    Column("prev_hash", String(64), nullable=False),
    Column("hash", String(64), nullable=False),
)

policies = Table(
    "policies", metadata,  # the interval policy file, each version kept
    Column("version", Integer, primary_key=True, autoincrement=False),
    Column("at_utc", String(40), nullable=False),
    Column("who", String(100), nullable=False),
    Column("text", Text, nullable=False),
    Column("sha256", String(64), nullable=False),
)

retirements = Table(
    "retirements", metadata,  # a machine axis taken out of the programme: kept, never deleted
    Column("serial_number", String(100), primary_key=True),
    Column("axis", String(50), primary_key=True),
    Column("at_utc", String(40), primary_key=True),
    Column("who", String(100), nullable=False),
    Column("reason", Text, nullable=False),
)

location_errors = Table(
    "location_errors", metadata,  # revision 0005: an entry's ISO 230-7 location errors (the R-test's), one row each
    Column("run_id", String(64), primary_key=True),
    Column("symbol", String(40), primary_key=True),  # as results.json keys it, its unit in it: X0C_um, B0A_arcsec
    Column("axis", String(10), nullable=False),  # the rotary axis it locates (A, C)
    Column("value", Float, nullable=False),  # in the symbol's unit
    Column("expanded_uncertainty", Float, nullable=False),  # U, same unit
    Column("coverage_factor", Float, nullable=False),  # k
    Column("measured_utc", String(40), nullable=False),  # the entry's
    Column("site", String(100), nullable=False, server_default=""),  # the entry's (a rig's row-level policy)
)

usage = Table(
    "usage", metadata,  # a machine's hours of use (ILAC-G24 method 3), given or read from its control
    Column("serial_number", String(100), primary_key=True),
    Column("at_utc", String(40), primary_key=True),
    Column("hours", Float, nullable=False),
    Column("source", String(300), nullable=False),
)
