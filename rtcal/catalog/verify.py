"""``rtcal catalog verify --deep``: beyond the chain (rtcal/catalog/audit.py), each entry's results
text against the hash it was filed with, its filed location errors (revision 0005's table, which the
entry's own hash does not cover) against that text, and its run folder's results.json against that
text (a run folder moved or gone is named; one edited since it was filed is named with the file)."""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from typing import Any

from rtcal.catalog.entry import location_error_rows


def _same(a: dict[str, tuple[float, float]], b: dict[str, tuple[float, float]]) -> bool:
    return a.keys() == b.keys() and all(math.isclose(x, y, rel_tol=1e-12, abs_tol=1e-12)
                                        for k in a for x, y in zip(a[k], b[k]))


def deep_problems(cat: Any) -> list[str]:
    out: list[str] = []
    filed = cat.location_errors_by_run()
    for run_id, text, digest, run_dir in cat.results_texts():
        data = text.encode()
        if digest and hashlib.sha256(data).hexdigest() != digest:
            out.append(f"entry {run_id}: its results text was edited after it was filed")
            continue
        try:
            stated = {r["symbol"]: (r["value"], r["expanded_uncertainty"]) for r in location_error_rows(json.loads(text))}
        except ValueError:
            stated = {}
        if cat.locations and not _same(filed.get(run_id, {}), stated):
            out.append(f"entry {run_id}: its filed location errors are not its results text's (edited, added or deleted "
                       "rows of location_errors)")
        path = Path(run_dir) / "results.json"
        try:
            on_disk = path.read_bytes()
        except OSError as exc:
            out.append(f"entry {run_id}: {path}: not readable ({exc.strerror or exc}): the run folder moved or is gone")
            continue
        if on_disk != data:
            out.append(f"entry {run_id}: {path}: EDITED — not the results.json the entry was filed from")
    return out
