"""Two marks per entry (issue 40): whether the run calibrated nothing (`simulated`: its statement, empty for
a calibration) and what its signature was when it was added (`signature`)."""

import sqlalchemy as sa
from alembic import op

revision = "0003"
down_revision = "0002"


def upgrade() -> None:
    with op.batch_alter_table("calibrations") as batch:  # SQLite adds columns in place; batch mode is for the rest
        batch.add_column(sa.Column("simulated", sa.Text, nullable=False, server_default=""))
        batch.add_column(sa.Column("signature", sa.Text, nullable=False, server_default="unsigned"))
