"""The calibrations table and its history index (one migration for SQLite and PostgreSQL)."""

import sqlalchemy as sa
from alembic import op

revision = "0001"
down_revision = None

PARAMETERS = ("E", "M", "B", "R", "A")
VDI = ("Pa", "P", "Ps_max", "U_max")


def upgrade() -> None:
    op.create_table(
        "calibrations",
        sa.Column("run_id", sa.String(64), primary_key=True),
        sa.Column("serial_number", sa.String(100), nullable=False),
        sa.Column("axis", sa.String(50), nullable=False),
        sa.Column("machine", sa.String(200), nullable=False),
        sa.Column("customer", sa.String(200), nullable=False),
        sa.Column("method", sa.String(100), nullable=False),
        sa.Column("measured_utc", sa.String(40), nullable=False),
        sa.Column("finished_utc", sa.String(40), nullable=False),
        sa.Column("certificate_number", sa.String(100), nullable=False),
        sa.Column("verdict", sa.String(20), nullable=False),
        *[sa.Column(f"{p}_arcsec", sa.Float) for p in PARAMETERS],
        *[sa.Column(f"{p}_U_arcsec", sa.Float) for p in PARAMETERS],
        *[sa.Column(f"{p}_limit_arcsec", sa.Float) for p in PARAMETERS],
        *[sa.Column(f"vdi_{p}_arcsec", sa.Float) for p in VDI],
        sa.Column("location_errors", sa.Text, nullable=False),
        sa.Column("digests", sa.Text, nullable=False),
        sa.Column("run_dir", sa.Text, nullable=False),
        sa.Column("added_utc", sa.String(40), nullable=False),
        sa.Column("results", sa.Text, nullable=False),
    )
    op.create_index("ix_calibrations_history", "calibrations", ["serial_number", "axis", "measured_utc"])
