"""``rtcal catalog due``: what is overdue and due soon across the fleet (a lab manager's first ask),
each machine axis with its next due date, the interval method and the data it rests on; retired
axes left out, one site if asked."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone
from typing import Any, Callable

from rtcal.catalog.history import fleet
from rtcal.catalog.intervals import DEFAULT, Policy, next_due, overdue_words
from rtcal.catalog.schema import normal_text


def due_list(cat: Any, within_days: float, site: str | None,
             due: Callable[[str, str, list[dict[str, Any]]], dict[str, Any]],
             today: datetime | None = None) -> list[dict[str, Any]]:
    """The machine axes due on or before today + ``within_days`` (overdue first), each a ``catalog
    list`` row with ``status`` ("overdue since …", "due in N d")."""
    today = today or datetime.now(timezone.utc)
    horizon = (today + timedelta(days=within_days)).date().isoformat()
    out = []
    for m in fleet(cat.machines(), due):
        if m.get("due_retired") or not m["next_due"] or m["next_due"] > horizon:
            continue
        if site is not None and normal_text(m["site"]) != normal_text(site):
            continue
        out.append({**m, "status": overdue_words(m["next_due"], today)})
    return sorted(out, key=lambda m: (m["next_due"], m["serial_number"], m["axis"]))


def due_of(cat: Any) -> Callable[[str, str, list[dict[str, Any]]], dict[str, Any]]:
    """(serial, axis, rows) → the next due date with its method and data, as the catalogue's filed policy
    says (its newest version), with the machine's hours and the axis's retirement."""
    import yaml

    from rtcal.catalog.schema import policies, retirements, usage

    filed = cat.table(policies, "version")
    policy = Policy.model_validate(yaml.safe_load(filed[-1]["text"]) or {}) if filed else DEFAULT
    hours: dict[str, list[tuple[datetime, float]]] = {}
    for r in cat.table(usage, "at_utc"):
        hours.setdefault(r["serial_number"], []).append((datetime.fromisoformat(r["at_utc"]), float(r["hours"])))
    retired = {(r["serial_number"], r["axis"]): r for r in cat.table(retirements, "at_utc")}
    return lambda sn, axis, rows: next_due(rows, policy.of(sn, axis), hours.get(sn), retired.get((sn, axis)))
