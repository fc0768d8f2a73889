"""Every entry's names in the one form the catalogue looks them up by (Unicode NFC, white space
collapsed, none at the ends), so a serial number typed two ways is one machine with one history.
Entries added since are kept so (rtcal/catalog/schema.py: normal_text, which this copies: a
migration stays as it ran)."""

import unicodedata

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"

NAMES = ("serial_number", "axis", "machine", "customer", "certificate_number")


def _normal(text: str) -> str:
    return " ".join(unicodedata.normalize("NFC", text).split())


def upgrade() -> None:
    conn = op.get_bind()
    table = sa.table("calibrations", sa.column("run_id"), *(sa.column(n) for n in NAMES))
    for row in conn.execute(sa.select(table)).mappings().all():
        changed = {n: _normal(row[n]) for n in NAMES if row[n] is not None and _normal(row[n]) != row[n]}
        if changed:
            conn.execute(table.update().where(table.c.run_id == row["run_id"]).values(**changed))
