"""The catalogue's database: one URL (a SQLite file by default, or PostgreSQL through psycopg 3),
one transaction per run added.

Only a writer (`catalog add`) migrates (the shipped Alembic migrations) and, on SQLite, switches the
file to write-ahead logging: reading (`list`, `history`, the page) writes nothing, so a catalogue on
a read-only disk, or a file the reader may not write, is read as it is — a SQLite file the reader
may not write is opened ``immutable``, which needs no -wal/-shm beside it; a PostgreSQL session is
read-only. A SQLite file that does not exist is refused for reading (not created empty), and an
in-memory one for anything (its entries would vanish at exit).

Every message names the database with its password hidden (:func:`safe_name`: in the userinfo or
as a ``?password=`` parameter); a server that does not answer fails within
:data:`CONNECT_TIMEOUT_S` + :data:`STATEMENT_TIMEOUT_S` (< 30 s)."""

from __future__ import annotations

import json
import os
import re
import sqlite3
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path
from typing import Any
from urllib.parse import quote

from sqlalchemy import Connection, Engine, Table, create_engine, event, inspect, select, text
from sqlalchemy.engine import URL, make_url
from sqlalchemy.exc import ArgumentError, DBAPIError, InterfaceError, OperationalError, SQLAlchemyError

from rtcal.catalog.audit import ENTRY_HASH_VERSION, GENESIS, Findings, chained, check, entry_hash
from rtcal.catalog.schema import audit, calibrations, instruments, location_errors, normal_text

ENV = "RTCAL_CATALOG"
CONNECT_TIMEOUT_S = 10
STATEMENT_TIMEOUT_S = 15
MIGRATIONS = Path(__file__).with_name("migrations")
ADVISORY_LOCK = 42302  # one migration at a time on a shared PostgreSQL (any number; ours)
NORMALISED_SINCE = "0002"  # the migration that brought every entry's names to normal_text
PROGRAMME_SINCE = "0004"  # instruments, the audit trail, policies, retirements, machine hours
LOCATIONS_SINCE = "0005"  # each entry's ISO 230-7 location errors, a row each
AUDIT_LOCK = 42303  # one audit row at a time on a shared PostgreSQL: the chain stays one line
ENTRY_DEFAULTS: dict[str, Any] = {"simulated": "", "signature": "unsigned",
                                  "test": "", "site": "", "rig": "", "state": "", "replaces": "", "supersedes": None,
                                  "origin": "run", "added_by": "", "results_sha256": "", "certificate_key": None}
USED_BY_COLUMNS = ("run_id", "serial_number", "axis", "machine", "customer", "method", "test", "measured_utc",
                   "certificate_number", "verdict", "E_arcsec", "E_U_arcsec", "E_limit_arcsec", "run_dir", "site", "rig",
                   "origin", "supersedes", "replaces")
SECRET = re.compile(r"password", re.IGNORECASE)  # a query parameter whose value is hidden (password, sslpassword)
URL_FORMS = "postgresql://user:password@host:port/db or a SQLite file"


class CatalogError(Exception):
    """The database cannot be reached or fails: exit 1, one line naming it without its password.
    ``transient``: the server could not be reached or went away (a rig's outbox keeps the entry);
    otherwise it refused (a privilege, a row-level policy, a constraint): sending again changes nothing."""

    def __init__(self, message: str, transient: bool = True) -> None:
        super().__init__(message)
        self.transient = transient


class CatalogUsage(ValueError):
    """A URL rtcal cannot use: exit 2."""


def default_location() -> str:
    """``RTCAL_CATALOG``, else catalog.sqlite under the user's data folder (XDG_DATA_HOME)."""
    if os.environ.get(ENV):
        return os.environ[ENV]
    base = Path(os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share")
    return str(base / "rtcal" / "catalog.sqlite")


def database_url(location: str | None, create: bool = False) -> URL:
    """A file path or ``sqlite:///`` URL, or ``postgresql://`` (mapped to psycopg 3's driver).
    ``create``: a SQLite file that does not exist will be made (only a writer asks)."""
    location = location or default_location()
    if "://" not in location:
        url = URL.create("sqlite", database=str(Path(location).expanduser()))
    else:
        try:
            url = make_url(location)
        except (ArgumentError, ValueError):  # e.g. postgresql://[::1 (an IPv6 host without its bracket)
            raise CatalogUsage(f"{masked(location)}: not a database URL ({URL_FORMS})") from None
    if url.drivername in ("postgresql", "postgres", "postgresql+psycopg"):
        return url.set(drivername="postgresql+psycopg")
    if url.drivername != "sqlite":
        raise CatalogUsage(f"{safe_name(url)}: rtcal's catalogue is on SQLite or PostgreSQL (postgresql://…), not "
                           f"{url.drivername}")
    if not url.database or url.database == ":memory:" or url.query.get("mode") == "memory":
        raise CatalogUsage(f"{masked(location)}: an in-memory SQLite database forgets every entry at exit; give a file "
                           "(--db catalog.sqlite)")
    path = Path(url.database).expanduser()
    if create:
        path.parent.mkdir(parents=True, exist_ok=True)
    elif not path.is_file():
        raise CatalogUsage(f"{path}: no catalogue there ({'a folder' if path.is_dir() else 'no such file'}); "
                           "`rtcal catalog add RUN --db FILE` creates one")
    return url.set(database=str(path))


def masked(text_: str) -> str:
    """Text that may hold a database URL with its password (after ``user:``, or ``password=``) as ***."""
    text_ = re.sub(r"(://[^/@\s]*?:)[^@/\s]*@", r"\1***@", text_)
    return " ".join(re.sub(r"((?:^|[?&\s])[A-Za-z_]*password=)[^&\s]*", r"\1***", text_, flags=re.IGNORECASE).split())


def safe_name(url: URL) -> str:
    """The URL as messages name it: its password hidden, in the userinfo or a query parameter."""
    hidden = {k: "***" if SECRET.search(k) else v for k, v in url.query.items()}
    return url.set(query=hidden).render_as_string(hide_password=True).replace("%2A%2A%2A", "***")


def secrets_of(url: URL) -> list[str]:
    found = [str(url.password)] if url.password else []
    for k, v in url.query.items():
        if SECRET.search(k):
            found += [v] if isinstance(v, str) else list(v)
    return [s for s in found if s]


def safe_text(text_: str, url: URL | None = None) -> str:
    """``text_`` with the URL's passwords replaced (a driver's message may quote the connection)."""
    for secret in secrets_of(url) if url is not None else []:
        text_ = text_.replace(secret, "***")
    return masked(text_)


def _sqlite_reader(path: str) -> Callable[[], sqlite3.Connection]:
    """Connections that cannot write: ``mode=ro``; ``immutable`` when this user may not write the
    file or its folder (a read-only disk, another user's catalogue), where a write-ahead-logged file
    could otherwise not be opened at all."""
    writable = os.access(path, os.W_OK) and os.access(os.path.dirname(path) or ".", os.W_OK)
    uri = f"file:{quote(path)}?{'mode=ro' if writable else 'immutable=1'}"
    return lambda: sqlite3.connect(uri, uri=True, timeout=STATEMENT_TIMEOUT_S, check_same_thread=False)


def _engine(url: URL, write: bool) -> Engine:
    if url.get_backend_name() == "postgresql":
        read_only = "" if write else " -c default_transaction_read_only=on"
        return create_engine(url, connect_args={
            "connect_timeout": CONNECT_TIMEOUT_S,
            "options": f"-c statement_timeout={STATEMENT_TIMEOUT_S * 1000} -c lock_timeout={STATEMENT_TIMEOUT_S * 1000}"
                       + read_only,
            "keepalives": 1, "keepalives_idle": 5, "keepalives_interval": 2, "keepalives_count": 3,
        }, pool_pre_ping=True)
    if not write:
        return create_engine("sqlite://", creator=_sqlite_reader(str(url.database)))
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


class CertificateTaken(CatalogUsage):
    """A certificate number another entry carries already (a certificate's number is unique): exit 2."""


class Catalog:
    """An open catalogue (``with Catalog(location) as cat``): read-only unless ``write``, which
    migrates it first (and creates a SQLite file that is not there)."""

    before_commit: Callable[[], None] | None = None  # tests stop the server here: nothing may be left half-written

    def __init__(self, location: str | None = None, write: bool = False) -> None:
        self.url = database_url(location, create=write)
        self.name = safe_name(self.url)
        self.engine = _engine(self.url, write)
        self.empty = False  # no calibrations table yet (a new database nobody has added to)
        self.normalised = True  # every entry's names are normal_text (migration 0002 ran)
        self.programme = True  # instruments, audit trail, policies (migration 0004 ran)
        self.locations = True  # the location errors' table (migration 0005 ran)
        self.present = {c.name for c in calibrations.c}  # the table's columns (fewer in a catalogue not migrated)
        if write:
            with self._failures("cannot be opened"):
                with self.engine.begin() as conn:
                    _migrate(conn)
            return
        with self._failures("cannot be opened"), self.engine.connect() as conn:
            tables = set(inspect(conn).get_table_names())
            self.empty = "calibrations" not in tables
            if not self.empty:  # an older catalogue, read without migrating it, lacks the newer columns
                self.present = {c["name"] for c in inspect(conn).get_columns("calibrations")}
            revision = conn.execute(text("SELECT version_num FROM alembic_version")).scalar() \
                if "alembic_version" in tables else None
            self.normalised = revision is not None and str(revision) >= NORMALISED_SINCE
            self.programme = revision is not None and str(revision) >= PROGRAMME_SINCE
            self.locations = revision is not None and str(revision) >= LOCATIONS_SINCE

    def __enter__(self) -> Catalog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.engine.dispose()

    @contextmanager
    def _failures(self, doing: str) -> Iterator[None]:
        try:
            yield
        except (DBAPIError, SQLAlchemyError, OSError, sqlite3.Error) as exc:
            cause = getattr(exc, "orig", None) or exc
            first = safe_text(str(cause).strip().splitlines()[0] if str(cause).strip() else type(cause).__name__, self.url)
            transient = isinstance(exc, (OperationalError, InterfaceError, OSError, sqlite3.OperationalError)) \
                or not isinstance(exc, DBAPIError)
            raise CatalogError(f"catalogue {self.name} {doing}: {first[:200]}", transient) from None

    @contextmanager
    def writing(self, doing: str) -> Iterator[Connection]:
        """One transaction that may append to the audit trail (on PostgreSQL under the trail's lock,
        so that rigs adding at once chain their rows one after another)."""
        with self._failures(doing), self.engine.begin() as conn:
            if conn.dialect.name == "postgresql":
                conn.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": AUDIT_LOCK})
            yield conn
            if Catalog.before_commit is not None:
                Catalog.before_commit()

    def add(self, entry: dict[str, Any], who: str = "", reason: str = "") -> bool:
        """Insert one entry, its instruments and its audit row in one transaction; False when its run
        id was there already (nothing changes). CertificateTaken: another entry carries its
        certificate number. An entry that ``supersedes`` another is filed as a supersede (``reason``)."""
        entry = {**ENTRY_DEFAULTS, **entry, "added_by": entry.get("added_by") or who or os_user()}
        found = entry.pop("instruments", None) or []
        located = entry.pop("location_error_rows", None) or []  # (an outbox file of an older rtcal has none)
        if self.engine.dialect.name == "postgresql":
            from sqlalchemy.dialects.postgresql import insert
        else:
            from sqlalchemy.dialects.sqlite import insert  # type: ignore[assignment]
        stmt = insert(calibrations).values(**entry).on_conflict_do_nothing(index_elements=["run_id"]) \
            .returning(calibrations.c.run_id)
        try:
            with self.writing("failed while adding a run (nothing of it was written)") as conn:
                if conn.dialect.name == "sqlite" and conn.execute(
                        select(calibrations.c.run_id).where(calibrations.c.run_id == entry["run_id"])).first():
                    return False  # (SQLite would check the unique certificate key before the upsert's own)
                inserted = conn.execute(stmt).first() is not None
                if inserted:
                    rows = [{**i, "run_id": entry["run_id"], "measured_utc": entry["measured_utc"], "site": entry["site"]}
                            for i in found]
                    if rows:
                        conn.execute(instruments.insert(), rows)
                    if located:
                        conn.execute(location_errors.insert(), [{**e, "run_id": entry["run_id"], "site": entry["site"],
                                                                 "measured_utc": entry["measured_utc"]} for e in located])
                    action = "supersede" if entry.get("supersedes") else "add"
                    append(conn, action, entry["run_id"], entry["added_by"], reason or "", entry["site"],
                           {"run_id": entry["run_id"], "entry_sha256": entry_hash(entry, found),
                            "entry_hash_version": ENTRY_HASH_VERSION, "certificate_number": entry["certificate_number"],
                            "supersedes": entry.get("supersedes")})
        except CatalogError as exc:
            if "ux_calibrations_certificate" in str(exc) or "certificate_key" in str(exc):
                raise CertificateTaken(f"certificate number {entry['certificate_number']!r} is already in {self.name} "
                                       "for another run: a certificate's number is unique (`rtcal run "
                                       "--certificate-number NUMBER`)") from None
            raise
        return inserted

    def record(self, action: str, subject: str, who: str, reason: str, detail: dict[str, Any], site: str = "",
               rows: list[tuple[Table, dict[str, Any]]] | None = None) -> None:
        """One audit row (a retirement, a policy, a reassessment, machine hours) and the rows it
        records, in one transaction."""
        with self.writing(f"failed while recording a {action} (nothing of it was written)") as conn:
            for table, values in rows or []:
                conn.execute(table.insert().values(**values))
            append(conn, action, subject, who or os_user(), reason, site, detail)

    def _columns(self, with_results: bool = False) -> list[Any]:
        return [c for c in calibrations.c if c.name in self.present and (with_results or c.name != "results")]

    def _rows(self, q: Any) -> list[dict[str, Any]]:
        """The rows of ``q``, a column the table does not have yet given as its migration fills it."""
        if self.empty:
            return []
        missing = {c.name: getattr(c.server_default, "arg", None) for c in calibrations.c if c.name not in self.present}
        with self._failures("cannot be read"), self.engine.connect() as conn:
            result = conn.execute(q)
            names = list(result.keys())
            return [{**missing, **dict(zip(names, r))} for r in result]

    def history(self, serial_number: str, axis: str | None = None, with_results: bool = False) -> list[dict[str, Any]]:
        """A machine's (axis's) entries, oldest first; the serial number and axis as
        :func:`~rtcal.catalog.schema.normal_text` makes them (in an older catalogue, whatever form
        an entry holds)."""
        serial, axis = normal_text(serial_number), None if axis is None else normal_text(axis)
        q = select(*self._columns(with_results))
        if self.normalised:  # the index answers
            q = q.where(calibrations.c.serial_number == serial)
            if axis is not None:
                q = q.where(calibrations.c.axis == axis)
        rows = [r for r in self._rows(q.order_by(calibrations.c.axis, calibrations.c.measured_utc))
                if normal_text(r["serial_number"]) == serial and (axis is None or normal_text(r["axis"]) == axis)]
        return sorted(rows, key=lambda r: normal_text(r["axis"]))  # stable: each axis oldest first

    def machines(self) -> list[dict[str, Any]]:
        """Every entry's history columns, by machine axis and time (what ``list`` summarises)."""
        return self._rows(select(*self._columns()).order_by(calibrations.c.serial_number, calibrations.c.axis,
                                                            calibrations.c.measured_utc))

    def entry(self, run_id: str, with_results: bool = True) -> dict[str, Any] | None:
        found = self._rows(select(*self._columns(with_results)).where(calibrations.c.run_id == run_id))
        return found[0] if found else None

    def by_certificate(self, number: str) -> list[dict[str, Any]]:
        """The entries that carry this certificate number (one, unless an older catalogue holds two)."""
        return self._rows(select(*self._columns()).where(calibrations.c.certificate_number == normal_text(number)))

    def used_by(self, instrument_id: str, since: str | None = None) -> list[dict[str, Any]]:
        """Every entry that used the instrument (by its id, as the runs name it), oldest first, each with
        the instrument's role, certificate, due date and the correction the run applied (one index range)."""
        if not self.programme:
            return []
        i = instruments.c
        cols = [calibrations.c[n] for n in USED_BY_COLUMNS] + [
            i.role, i.instrument_id, i.kind, i.certificate_number.label("instrument_certificate"), i.issuer,
            i.due.label("instrument_due"), i.correction]
        q = select(*cols).join(calibrations, calibrations.c.run_id == instruments.c.run_id) \
            .where(instruments.c.instrument_id == normal_text(instrument_id))
        if since:
            q = q.where(instruments.c.measured_utc >= since)
        return self._rows(q.order_by(instruments.c.measured_utc))

    def instrument_ids(self, like: str = "", limit: int = 8) -> list[str]:
        """Instrument ids the catalogue knows (those holding ``like``, case-insensitive): what an unknown id is told."""
        if not self.programme:
            return []
        q = select(instruments.c.instrument_id).distinct()
        if like:
            q = q.where(instruments.c.instrument_id.ilike(f"%{like}%"))
        with self._failures("cannot be read"), self.engine.connect() as conn:
            return [str(r[0]) for r in conn.execute(q.order_by(instruments.c.instrument_id).limit(limit))]

    def instruments_of(self, run_ids: list[str]) -> list[dict[str, Any]]:
        if not self.programme or not run_ids:
            return []
        with self._failures("cannot be read"), self.engine.connect() as conn:
            return [dict(r._mapping) for r in conn.execute(select(instruments).where(instruments.c.run_id.in_(run_ids)))]

    def location_errors_of(self, run_ids: list[str]) -> list[dict[str, Any]]:
        """The entries' ISO 230-7 location errors, a row each (none in a catalogue before revision 0005)."""
        if not self.locations or not run_ids:
            return []
        with self._failures("cannot be read"), self.engine.connect() as conn:
            q = select(location_errors).where(location_errors.c.run_id.in_(run_ids))
            return [dict(r._mapping) for r in conn.execute(q.order_by(location_errors.c.measured_utc))]

    def location_errors_by_run(self) -> dict[str, dict[str, tuple[float, float]]]:
        """Every filed location error, run id → symbol → (value, U) (``verify --deep`` checks them)."""
        out: dict[str, dict[str, tuple[float, float]]] = {}
        if not self.locations:
            return out
        with self._failures("cannot be read"), self.engine.connect() as conn:
            le = location_errors.c
            for run_id, symbol, value, U in conn.execute(select(le.run_id, le.symbol, le.value, le.expanded_uncertainty)):
                out.setdefault(str(run_id), {})[str(symbol)] = (float(value), float(U))
        return out

    def table(self, table: Table, order: str) -> list[dict[str, Any]]:
        """Every row of one of the programme's tables (audit, policies, retirements, usage) in ``order``."""
        if not self.programme:
            return []
        with self._failures("cannot be read"), self.engine.connect() as conn:
            return [dict(r._mapping) for r in conn.execute(select(table).order_by(table.c[order]))]

    def audit_check(self) -> Findings:
        """The audit chain, and every entry against the row that filed it (rtcal/catalog/audit.py)."""
        out = Findings()
        if self.empty or not self.programme:
            return out
        def plain(q: Any) -> Iterator[dict[str, Any]]:  # rows as plain dicts (10 000 entries: a mapping's .get is slow)
            result = conn.execute(q)
            names = list(result.keys())
            return (dict(zip(names, r)) for r in result)

        with self._failures("cannot be read"), self.engine.connect() as conn:
            rows = list(plain(select(audit).order_by(audit.c.seq)))
            used: dict[str, list[dict[str, Any]]] = {}
            for r in plain(select(instruments)):
                used.setdefault(r["run_id"], []).append(r)
            entries = {r["run_id"]: entry_hash(r, used.get(r["run_id"], [])) for r in plain(select(*self._columns()))}
        check(rows, entries, out)
        return out

    def results_texts(self) -> Iterator[tuple[str, str, str, str]]:
        """(run id, results text, results_sha256, run folder) of every entry, one at a time (``verify --deep``)."""
        with self._failures("cannot be read"), self.engine.connect() as conn:
            q = select(calibrations.c.run_id, calibrations.c.results, calibrations.c.results_sha256, calibrations.c.run_dir)
            for r in conn.execution_options(stream_results=True).execute(q):
                yield str(r[0]), str(r[1]), str(r[2]), str(r[3])

    def count(self) -> int:
        if self.empty:
            return 0
        with self._failures("cannot be read"), self.engine.connect() as conn:
            return int(conn.execute(text("SELECT count(*) FROM calibrations")).scalar_one())


def append(conn: Connection, action: str, subject: str, who: str, reason: str, site: str, detail: dict[str, Any]) -> None:
    """The next row of the audit trail, chained to the last (the caller holds the trail's lock)."""
    head = conn.execute(select(audit.c.seq, audit.c.hash).order_by(audit.c.seq.desc()).limit(1)).first()
    seq, prev = (int(head[0]) + 1, str(head[1])) if head else (1, GENESIS)
    conn.execute(audit.insert().values(**chained(seq, prev, at_utc=now_utc(), who=who[:100], action=action,
                                                 subject=subject[:300], site=site, reason=reason, detail=dumps(detail))))


def os_user() -> str:
    """Who is acting, when no `--by` says: the operating system's user."""
    import getpass

    try:
        return getpass.getuser()
    except (KeyError, OSError):
        return f"uid {os.getuid()}" if hasattr(os, "getuid") else "unknown"


def now_utc() -> str:
    return datetime.now(timezone.utc).isoformat()


def dumps(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)
