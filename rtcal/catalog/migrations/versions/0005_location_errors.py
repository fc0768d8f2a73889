"""The trend of an axis's location errors (issue 42): a table of each entry's ISO 230-7 location errors — symbol
(its unit in it, as results.json keys it), axis, value, U and k — filled at `catalog add` from results.json's
``location_errors`` (the R-test's). Entries already there get theirs from their stored results text (an INSERT:
the append-only triggers allow it); the table is append-only like the rest.

:func:`_rows` is a copy of rtcal/catalog/entry.py's ``location_error_rows`` as it was at this revision."""

import json
import math

import sqlalchemy as sa
from alembic import op

revision = "0005"
down_revision = "0004"


def _rows(run_id, measured_utc, doc):
    found = doc.get("location_errors") if isinstance(doc, dict) else None
    out = []
    for symbol, e in (found.items() if isinstance(found, dict) else ()):
        if not isinstance(e, dict):
            continue
        value, U, k = e.get("value"), e.get("expanded_uncertainty"), e.get("coverage_factor", 2.0)
        if not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in (value, U, k)):
            continue
        out.append({"run_id": run_id, "symbol": str(symbol)[:40], "axis": str(e.get("axis", ""))[:10], "value": float(value),
                    "expanded_uncertainty": float(U), "coverage_factor": float(k), "measured_utc": measured_utc})
    return out


def upgrade() -> None:
    table = op.create_table(
        "location_errors",
        sa.Column("run_id", sa.String(64), primary_key=True), sa.Column("symbol", sa.String(40), primary_key=True),
        sa.Column("axis", sa.String(10), nullable=False), sa.Column("value", sa.Float, nullable=False),
        sa.Column("expanded_uncertainty", sa.Float, nullable=False), sa.Column("coverage_factor", sa.Float, nullable=False),
        sa.Column("measured_utc", sa.String(40), nullable=False),
        sa.Column("site", sa.String(100), nullable=False, server_default=""))
    conn = op.get_bind()
    cal = sa.table("calibrations", sa.column("run_id"), sa.column("measured_utc"), sa.column("site"), sa.column("results"))
    for run_id, measured_utc, site, text in conn.execute(sa.select(cal.c.run_id, cal.c.measured_utc, cal.c.site,
                                                                   cal.c.results)):
        try:  # the stored text as JSON (a migration reads what older rtcal wrote, whatever it holds)
            doc = json.loads(text or "")
        except ValueError:
            continue
        rows = [{**r, "site": site or ""} for r in _rows(run_id, measured_utc, doc)]
        if rows:
            conn.execute(table.insert(), rows)
    if conn.dialect.name == "postgresql":  # append-only, as migration 0004 made the others
        op.execute("CREATE TRIGGER location_errors_append_only BEFORE UPDATE OR DELETE ON location_errors "
                   "FOR EACH ROW EXECUTE FUNCTION rtcal_append_only()")
        op.execute("CREATE TRIGGER location_errors_no_truncate BEFORE TRUNCATE ON location_errors "
                   "FOR EACH STATEMENT EXECUTE FUNCTION rtcal_append_only()")
        return
    for what in ("UPDATE", "DELETE"):
        op.execute(f"CREATE TRIGGER location_errors_no_{what.lower()} BEFORE {what} ON location_errors BEGIN "
                   "SELECT RAISE(ABORT, 'rtcal: location_errors is append-only (a correction is a new entry; "
                   "docs/catalog.md)'); END")
