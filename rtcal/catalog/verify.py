"""``rtcal catalog verify --deep``: beyond the chain (rtcal/catalog/audit.py), each entry's results
text against the hash it was filed with, and its run folder's results.json against that text (a
run folder moved or gone is named; one edited since it was filed is named with the file)."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any


def deep_problems(cat: Any) -> list[str]:
    out: list[str] = []
    for run_id, text, digest, run_dir in cat.results_texts():
        data = text.encode()
        if digest and hashlib.sha256(data).hexdigest() != digest:
            out.append(f"entry {run_id}: its results text was edited after it was filed")
            continue
        path = Path(run_dir) / "results.json"
        try:
            on_disk = path.read_bytes()
        except OSError as exc:
            out.append(f"entry {run_id}: {path}: not readable ({exc.strerror or exc}): the run folder moved or is gone")
            continue
        if on_disk != data:
            out.append(f"entry {run_id}: {path}: EDITED — not the results.json the entry was filed from")
    return out
