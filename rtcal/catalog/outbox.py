"""A rig's outbox: an entry the lab's PostgreSQL could not take now waits here, one file per run, and
``rtcal catalog sync`` (also the end of ``rtcal run --catalog URL``) sends it later.

An add is one transaction keyed by the run's id, so whatever happened to the last attempt — refused
before it began, rolled back when the server went away, or committed with the reply lost — sending
it again makes exactly one entry: it lands, or it is found there already. The file is written
whole (a temporary file, flushed to the disk, renamed) before the add is reported as waiting, and
removed only after the database has it: 0 lost, 0 duplicated (tests/test_catalog_programme.py,
benchmarks/bench_rigs.py).

The outbox is ``$RTCAL_OUTBOX``, else ``outbox/`` under the user's state folder
(``$XDG_STATE_HOME/rtcal``, ``~/.local/state/rtcal``). It holds no database URL (no password)."""

from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rtcal.catalog.store import Catalog, CatalogError, CertificateTaken

ENV = "RTCAL_OUTBOX"


def default_outbox() -> Path:
    if os.environ.get(ENV):
        return Path(os.environ[ENV])
    base = Path(os.environ.get("XDG_STATE_HOME") or Path.home() / ".local" / "state")
    return base / "rtcal" / "outbox"


def _path(outbox: Path, run_id: str) -> Path:
    return outbox / f"{run_id}.json"


def keep(outbox: Path, entry: dict[str, Any], who: str, reason: str) -> Path:
    """The entry written whole into the outbox (flushed to the disk before it is renamed into place)."""
    outbox.mkdir(parents=True, exist_ok=True)
    path = _path(outbox, str(entry["run_id"]))
    fd, tmp = tempfile.mkstemp(dir=outbox, prefix=".pending-", suffix=".json")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump({"entry": entry, "who": who, "reason": reason}, f, ensure_ascii=False)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    try:
        dir_fd = os.open(outbox, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)
    except OSError:
        pass
    return path


def pending(outbox: Path) -> list[Path]:
    """The entries waiting, oldest first."""
    if not outbox.is_dir():
        return []
    return sorted((p for p in outbox.glob("*.json") if not p.name.startswith(".")), key=lambda p: (p.stat().st_mtime, p.name))


def file_entry(location: str | None, entry: dict[str, Any], who: str, reason: str = "",
               outbox: Path | None = None) -> tuple[str, str]:
    """Add one entry: ("added", ""), ("already", "") (its run id was there), or — the database
    unreachable or failing, and an ``outbox`` given — ("waiting", why) (kept in the outbox).
    CertificateTaken and a CatalogError without an outbox go to the caller."""
    try:
        with Catalog(location, write=True) as cat:
            added = cat.add(entry, who=who, reason=reason)
    except CertificateTaken:
        raise
    except CatalogError as exc:
        if outbox is None or not exc.transient:  # refused (a privilege, a policy): sending again would not help
            raise
        keep(outbox, entry, who, reason)
        return "waiting", str(exc)
    if outbox is not None:
        _path(outbox, str(entry["run_id"])).unlink(missing_ok=True)  # an older attempt of it, sent now
    return ("added" if added else "already"), ""


def _set_aside(outbox: Path, path: Path, why: str) -> None:
    """An entry the catalogue will not take, moved to ``refused/`` with the reason beside it (never dropped)."""
    refused = outbox / "refused"
    refused.mkdir(exist_ok=True)
    (refused / f"{path.stem}.why").write_text(why + "\n", encoding="utf-8")
    os.replace(path, refused / path.name)


@dataclass
class Synced:
    added: int = 0
    already: int = 0
    refused: list[str] = field(default_factory=list)
    waiting: int = 0
    failure: str = ""


def sync(location: str | None, outbox: Path) -> Synced:
    """Send every waiting entry, oldest first; stop at the first failure of the database (the rest
    wait). An entry the catalogue refuses (its certificate number taken) is moved to ``refused/``
    beside the outbox with the reason, never dropped."""
    out = Synced()
    files = pending(outbox)
    if not files:
        return out
    try:
        with Catalog(location, write=True) as cat:
            for k, path in enumerate(files):
                try:
                    doc = json.loads(path.read_text(encoding="utf-8"))
                    added = cat.add(doc["entry"], who=str(doc.get("who", "")), reason=str(doc.get("reason", "")))
                except CertificateTaken as exc:
                    _set_aside(outbox, path, str(exc))
                    out.refused.append(f"{path.name}: {exc}")
                    continue
                except (ValueError, KeyError, TypeError) as exc:
                    _set_aside(outbox, path, f"not an entry rtcal wrote ({type(exc).__name__})")
                    out.refused.append(f"{path.name}: not an entry rtcal wrote ({type(exc).__name__})")
                    continue
                except CatalogError as exc:
                    if not exc.transient:  # refused for good: set aside with why, the rest goes on
                        _set_aside(outbox, path, str(exc))
                        out.refused.append(f"{path.name}: {exc}")
                        continue
                    out.failure, out.waiting = str(exc), len(files) - k
                    return out
                path.unlink(missing_ok=True)
                out.added += added
                out.already += not added
    except CatalogError as exc:
        out.failure, out.waiting = str(exc), len(pending(outbox))
    return out
