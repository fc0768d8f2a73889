"""The catalogue's one schema (SQLAlchemy Core), the same on SQLite and PostgreSQL.

A row per finished run, keyed by the run's id; the numbers a history needs are columns (indexed by
machine axis and time, so a history is one index range), the whole results.json a text column."""

from __future__ import annotations

import unicodedata

from sqlalchemy import Column, Float, Index, MetaData, String, Table, Text

metadata = MetaData()

PARAMETERS = ("E", "M", "B", "R", "A")  # ISO 230-2, each with its expanded U (k = 2)
VDI = ("Pa", "P", "Ps_max", "U_max")  # VDI/DGQ 3441 (results.json gives them without a U)
NAMES = ("serial_number", "axis", "machine", "customer", "certificate_number")  # kept as normal_text
VERDICTS = ("pass", "fail", "undecided", "none")


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
)
Index("ix_calibrations_history", calibrations.c.serial_number, calibrations.c.axis, calibrations.c.measured_utc)
