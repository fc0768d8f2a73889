"""Every file a command writes goes through here: written where nobody else can reach it, then
renamed into place.

A writer that opens ``out/compare.png`` by name follows a symbolic link planted there and
overwrites the link's target. Here every file is first written into a fresh private folder
(``mkdtemp``: new, mode 700, so nothing can be planted in it) beside its destination, and then
renamed onto its name: a rename replaces whatever entry has that name — a planted link itself,
never its target — and a reader never sees half a file. A full disk (ENOSPC) is a failure of
the machine (exit 1), not of the input; the other errors of a destination are the user's (exit 2).
"""

from __future__ import annotations

import errno
import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

STAGING_PREFIX = ".outputs-"  # a folder of this name left in a directory is a killed writer's; removable
DISK_FAILURES = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EIO, errno.EFBIG})


class OutputRefused(Exception):
    """A destination the user must change (exit 2): a directory where a file goes, a missing folder."""


def is_disk_failure(exc: BaseException) -> bool:
    """A full disk, an exceeded quota or an I/O error: the machine failed, not the input."""
    return isinstance(exc, OSError) and exc.errno in DISK_FAILURES


@contextmanager
def staged_outputs(directory: Path) -> Iterator[Path]:
    """A private folder to write files into; on success each is renamed into ``directory``.

    On any failure nothing is renamed and the folder is removed (a killed process leaves it:
    :func:`remove_stale_staging` clears it). OutputRefused if ``directory`` is not a folder one
    can write in, or a file would replace a directory.
    """
    directory = Path(directory)
    try:
        staging = Path(tempfile.mkdtemp(prefix=STAGING_PREFIX, dir=directory))
    except OSError as exc:
        if is_disk_failure(exc):
            raise
        raise OutputRefused(f"{directory}: cannot write there ({exc.strerror or exc})") from None
    try:
        yield staging
        for entry in sorted(staging.iterdir()):
            target = directory / entry.name
            if target.is_dir() and not target.is_symlink():
                raise OutputRefused(f"{target} is a directory; move it away (nothing was written there)")
            os.replace(entry, target)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


@contextmanager
def output_file(path: Path) -> Iterator[Path]:
    """A path to write one file to (for writers that take a path: matplotlib, reportlab, csv);
    on success the file replaces ``path`` — a planted link included, never its target."""
    path = Path(path)
    if not path.name or path.name in (".", ".."):
        raise OutputRefused(f"{path}: not a file name")
    with staged_outputs(path.parent) as staging:
        yield staging / path.name


def write_output(path: Path, data: str | bytes) -> Path:
    """Write ``data`` (text as UTF-8) to ``path`` through :func:`output_file`; returns ``path``."""
    with output_file(path) as tmp:
        tmp.write_bytes(data.encode("utf-8") if isinstance(data, str) else data)
    return Path(path)


def remove_stale_staging(directory: Path) -> list[str]:
    """Remove the staging folders killed writers left in ``directory`` (call while holding it:
    a live writer's folder must not vanish); returns their names. Links are left alone."""
    removed = []
    for entry in os.scandir(directory):
        if entry.name.startswith(STAGING_PREFIX) and entry.is_dir(follow_symlinks=False):
            shutil.rmtree(entry.path, ignore_errors=True)
            removed.append(entry.name)
    return removed
