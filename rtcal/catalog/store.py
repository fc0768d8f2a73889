"""The catalogue's database: one URL (a SQLite file by default, or PostgreSQL through psycopg 3),
migrated on connect by the shipped Alembic migrations, one transaction per run added.

Every message names the database with its password hidden (:func:`safe_name`); a server that does
not answer fails within :data:`CONNECT_TIMEOUT_S` + :data:`STATEMENT_TIMEOUT_S` (< 30 s)."""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from sqlalchemy import Connection, Engine, create_engine, event, select, text
from sqlalchemy.engine import URL, make_url
from sqlalchemy.exc import ArgumentError, DBAPIError, SQLAlchemyError

from rtcal.catalog.schema import calibrations

ENV = "RTCAL_CATALOG"
CONNECT_TIMEOUT_S = 10
STATEMENT_TIMEOUT_S = 15
MIGRATIONS = Path(__file__).with_name("migrations")
ADVISORY_LOCK = 42302  # one migration at a time on a shared PostgreSQL (any number; ours)


class CatalogError(Exception):
    """The database cannot be reached or fails: exit 1, one line naming it without its password."""


class CatalogUsage(ValueError):
    """A URL rtcal cannot use: exit 2."""


def default_location() -> str:
    """``RTCAL_CATALOG``, else catalog.sqlite under the user's data folder (XDG_DATA_HOME)."""
    if os.environ.get(ENV):
        return os.environ[ENV]
    base = Path(os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share")
    return str(base / "rtcal" / "catalog.sqlite")


def database_url(location: str | None) -> URL:
    """A file path or ``sqlite:///`` URL, or ``postgresql://`` (mapped to psycopg 3's driver)."""
    location = location or default_location()
    if "://" not in location:
        path = Path(location).expanduser()
        path.parent.mkdir(parents=True, exist_ok=True)
        return URL.create("sqlite", database=str(path))
    try:
        url = make_url(location)
    except ArgumentError:
        raise CatalogUsage(f"{safe_text(location)}: not a database URL (postgresql://user:password@host:port/db or a "
                           "SQLite file)") from None
    if url.drivername in ("postgresql", "postgres", "postgresql+psycopg"):
        return url.set(drivername="postgresql+psycopg")
    if url.drivername == "sqlite":
        return url
    raise CatalogUsage(f"{safe_name(url)}: rtcal's catalogue is on SQLite or PostgreSQL (postgresql://…), not "
                       f"{url.drivername}")


def safe_name(url: URL) -> str:
    return url.render_as_string(hide_password=True)


def safe_text(text_: str, url: URL | None = None) -> str:
    """``text_`` with the URL's password replaced (a driver's message may quote the connection)."""
    if url is not None and url.password:
        text_ = text_.replace(str(url.password), "***")
    return " ".join(text_.split())


def _engine(url: URL) -> Engine:
    if url.get_backend_name() == "postgresql":
        return create_engine(url, connect_args={
            "connect_timeout": CONNECT_TIMEOUT_S,
            "options": f"-c statement_timeout={STATEMENT_TIMEOUT_S * 1000} -c lock_timeout={STATEMENT_TIMEOUT_S * 1000}",
            "keepalives": 1, "keepalives_idle": 5, "keepalives_interval": 2, "keepalives_count": 3,
        }, pool_pre_ping=True)
    engine = create_engine(url, connect_args={"timeout": STATEMENT_TIMEOUT_S})

    @event.listens_for(engine, "connect")
    def _sqlite_connect(dbapi_conn: Any, _record: Any) -> None:
        dbapi_conn.isolation_level = None  # transactions are ours (BEGIN IMMEDIATE below), not pysqlite's
        dbapi_conn.execute("PRAGMA journal_mode=WAL")  # one fsync per add, and readers never wait for a writer

    @event.listens_for(engine, "begin")
    def _sqlite_begin(conn: Connection) -> None:
        conn.exec_driver_sql("BEGIN IMMEDIATE")  # the writer's lock up front: concurrent adds wait, never deadlock

    return engine


def _migrate(conn: Connection) -> None:
    """Bring the schema to the newest migration (Alembic, run here on our own connection)."""
    from alembic import command
    from alembic.config import Config

    if conn.dialect.name == "postgresql":
        conn.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": ADVISORY_LOCK})
    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS))
    cfg.attributes["connection"] = conn
    command.upgrade(cfg, "head")


class Catalog:
    """An open catalogue (``with Catalog(location) as cat``)."""

    before_commit: Callable[[], None] | None = None  # tests stop the server here: nothing may be left half-written

    def __init__(self, location: str | None = None) -> None:
        self.url = database_url(location)
        self.name = safe_name(self.url)
        self.engine = _engine(self.url)
        with self._failures("cannot be opened"):
            with self.engine.begin() as conn:
                _migrate(conn)

    def __enter__(self) -> Catalog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.engine.dispose()

    @contextmanager
    def _failures(self, doing: str) -> Iterator[None]:
        try:
            yield
        except (DBAPIError, SQLAlchemyError, OSError) as exc:
            cause = getattr(exc, "orig", None) or exc
            first = safe_text(str(cause).strip().splitlines()[0] if str(cause).strip() else type(cause).__name__, self.url)
            raise CatalogError(f"catalogue {self.name} {doing}: {first[:200]}") from None

    def add(self, entry: dict[str, Any]) -> bool:
        """Insert one entry in one transaction; False when its run id was there already (nothing changes)."""
        if self.engine.dialect.name == "postgresql":
            from sqlalchemy.dialects.postgresql import insert
        else:
            from sqlalchemy.dialects.sqlite import insert  # type: ignore[assignment]
        stmt = insert(calibrations).values(**entry).on_conflict_do_nothing(index_elements=["run_id"]) \
            .returning(calibrations.c.run_id)
        with self._failures("failed while adding a run (nothing of it was written)"):
            with self.engine.begin() as conn:
                inserted = conn.execute(stmt).first() is not None
                if Catalog.before_commit is not None:
                    Catalog.before_commit()
        return inserted

    def history(self, serial_number: str, axis: str | None = None, with_results: bool = False) -> list[dict[str, Any]]:
        """A machine's (axis's) entries, oldest first."""
        cols = [c for c in calibrations.c if with_results or c.name != "results"]
        q = select(*cols).where(calibrations.c.serial_number == serial_number)
        if axis is not None:
            q = q.where(calibrations.c.axis == axis)
        q = q.order_by(calibrations.c.axis, calibrations.c.measured_utc)
        with self._failures("cannot be read"), self.engine.connect() as conn:
            return [dict(r._mapping) for r in conn.execute(q)]

    def machines(self) -> list[dict[str, Any]]:
        """Every entry's history columns, by machine axis and time (what ``list`` summarises)."""
        cols = [c for c in calibrations.c if c.name != "results"]
        q = select(*cols).order_by(calibrations.c.serial_number, calibrations.c.axis, calibrations.c.measured_utc)
        with self._failures("cannot be read"), self.engine.connect() as conn:
            return [dict(r._mapping) for r in conn.execute(q)]

    def count(self) -> int:
        with self._failures("cannot be read"), self.engine.connect() as conn:
            return int(conn.execute(text("SELECT count(*) FROM calibrations")).scalar_one())


def now_utc() -> str:
    return datetime.now(timezone.utc).isoformat()


def dumps(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"))
