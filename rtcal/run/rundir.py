"""A run directory: owned by one process at a time, created only where nothing else lives, and
written without following links planted in it.

- :class:`RunLock` is an OS file lock (``flock``) on ``RUN_DIR/.rtcal.lock`` held for the whole
  run or resume; the file names its holder, so a second process can say who has the run.
- :func:`claim_new_run_dir` accepts a ``--out`` that is new, empty, or holds only what a run
  killed before its store existed left behind; anything else is refused. A store is never
  deleted unless SQLite reads it whole and it holds no procedure, no reading and no event.
- :func:`staged_outputs` (rtcal.outputs) writes a run's output files into a fresh private folder
  and renames them into place: a rename replaces a planted symbolic link itself, never its target.
"""

from __future__ import annotations

import datetime as _dt
import fcntl
import os
import socket
import sys
import time
from pathlib import Path

from rtcal.outputs import STAGING_PREFIX, remove_stale_staging, staged_outputs  # noqa: F401 — staged_outputs: the runner's
from drivers.addresses import redact_tokens
from rtcal.methods import read_results
from rtcal.results import RunResults
from rtcal.store.runstore import RunStore, check_store
from rtcal.store.hint import resume_hint

LOCK_NAME = ".rtcal.lock"


class RunDirError(Exception):
    """A run directory the user must change (exit 2)."""


class RunBusy(RunDirError):
    """Another process holds the run directory."""


class RunLock:
    """Exclusive ownership of a run directory by this process until :meth:`release`.

    ``flock`` locks belong to the open file, so the kernel drops the lock when the process
    dies in any way (kill -9 included): a stale lock file never blocks a resume.
    """

    def __init__(self, run_dir: Path):
        self.run_dir = Path(run_dir)
        self.path = self.run_dir / LOCK_NAME
        self._fd: int | None = None

    def acquire(self) -> "RunLock":
        flags = os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0)
        try:
            fd = os.open(self.path, flags, 0o644)
        except OSError as exc:
            raise RunDirError(f"{self.run_dir}: cannot lock the run directory ({exc.strerror or exc})") from None
        # the holder writes its name just after it locks and blanks it as it lets go: a moment's wait
        # names it, or finds the directory free
        deadline = time.monotonic() + 1.0
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                holder = os.pread(fd, 1000, 0).decode("utf-8", errors="replace").strip()
                if holder or time.monotonic() > deadline:
                    os.close(fd)
                    raise RunBusy(f"{self.run_dir} is in use by {holder or 'another process'}; wait for it to end "
                                  "(or stop it), then try again") from None
                time.sleep(0.01)
            except OSError as exc:
                os.close(fd)
                raise RunDirError(f"{self.run_dir}: cannot lock the run directory ({exc.strerror or exc})") from None
        command = " ".join(["rtcal", *sys.argv[1:]]) if sys.argv and sys.argv[0].endswith(("rtcal", "cli.py", "cli/__main__.py")) else "rtcal"
        stamp = _dt.datetime.now().isoformat(timespec="seconds")
        holder = redact_tokens(f"process {os.getpid()} on {socket.gethostname()} (`{command}`, since {stamp})")
        os.ftruncate(fd, 0)
        os.pwrite(fd, holder.encode("utf-8", errors="replace")[:900], 0)
        self._fd = fd
        return self

    def release(self) -> None:
        """Give the directory up (the lock file stays: removing it would race a waiting process)."""
        if self._fd is not None:
            try:
                os.ftruncate(self._fd, 0)
            except OSError:
                pass
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> "RunLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def _leftover(name: str) -> bool:
    """Files a run killed before its store existed leaves behind (ours, safe to replace)."""
    return name in (LOCK_NAME, RunStore.RESERVE_NAME) or name.startswith((RunStore.PARTIAL_PREFIX, STAGING_PREFIX))


def claim_new_run_dir(run_dir: Path) -> RunLock:
    """Create (or take over an empty) ``--out`` directory and lock it for a new run.

    Refused: a path under a file, a name the file system cannot hold, a directory that already
    holds a run (resume it instead), a store that SQLite cannot read whole (it may hold
    readings: it is left as it is) or other files (they would mix with the results).
    """
    run_dir = Path(run_dir)
    if os.path.lexists(run_dir) and not run_dir.is_dir():
        raise RunDirError(f"--out {run_dir}: exists and is not a directory")
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RunDirError(f"--out {run_dir}: cannot create the directory ({exc.strerror or exc})") from None
    lock = RunLock(run_dir).acquire()
    try:
        store = run_dir / RunStore.FILENAME
        if os.path.lexists(store):
            found = check_store(store)
            if found.kind == "run":
                raise RunDirError(f"--out {run_dir}: already holds a run; {resume_hint(run_dir)}, "
                                  "or choose another --out")
            if found.kind != "empty":
                raise RunDirError(f"--out {run_dir}: its {RunStore.FILENAME} {found.detail}; rtcal does not replace "
                                  f"it — {found.advice(run_dir)}; choose another --out")
            for suffix in ("", "-wal", "-shm", "-journal"):  # proven empty: SQLite read it whole, nothing in it
                _unlink(Path(f"{store}{suffix}"))
        others = sorted(n for n in os.listdir(run_dir) if not _leftover(n))
        if others:
            shown = ", ".join(others[:5]) + (", …" if len(others) > 5 else "")
            raise RunDirError(f"--out {run_dir}: not empty and not a run ({shown}); choose a new or empty directory")
        for name in os.listdir(run_dir):
            if name.startswith(RunStore.PARTIAL_PREFIX):
                _unlink(run_dir / name)
        remove_stale_staging(run_dir)
    except BaseException:
        lock.release()
        raise
    return lock


def claim_run_dir(run_dir: Path) -> RunLock:
    """Lock an existing run directory for a resume, and clear what killed writers left in it
    (staging folders of outputs never renamed into place)."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        what = "no such directory" if not os.path.lexists(run_dir) else "not a directory"
        raise RunDirError(f"{run_dir}: {what}; nothing to resume (`rtcal run … --out {run_dir}` starts a run there)")
    if not os.path.lexists(run_dir / RunStore.FILENAME):
        raise RunDirError(f"{run_dir}: not a run directory (no {RunStore.FILENAME}); nothing to resume")
    lock = RunLock(run_dir).acquire()
    try:
        remove_stale_staging(run_dir)
    except BaseException:
        lock.release()
        raise
    return lock


def _unlink(path: Path) -> None:
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass


def stored_results(run_dir: Path) -> RunResults | None:
    """results.json of a finished run, validated, if it is a regular file; else None. One that does
    not validate is a ResultsError naming the field."""
    path = Path(run_dir) / "results.json"
    if path.is_symlink() or not path.is_file():
        return None
    return read_results(run_dir)
