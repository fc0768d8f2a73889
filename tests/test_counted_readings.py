"""Which readings count is one rule, the store's (issue 41, item 5): per planned reading, the attempt
stored whole, else its last attempt not rejected; a rejected attempt never counts. Every method's
readers ask the store (`RunReadings.counted`) instead of writing the rule again."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from rtcal.store.runstore import REJECTED, SKIPPED, Reading, RunStore, counted_attempts, descriptions_of

REPO = Path(__file__).resolve().parents[1]


def test_the_rule_per_planned_reading():
    chosen = counted_attempts([
        (0, 0, True, False), (0, 1, False, False),  # partial, then whole: the whole one
        (1, 2, False, False), (1, 3, True, False),  # whole, then a later partial (a retake that skipped): the whole one
        (2, 4, True, False), (2, 5, True, False),  # never whole: the last partial one
        (3, 6, False, True),  # rejected only: nothing counts
        (4, 7, True, False), (4, 8, False, True),  # a partial one and a later rejected one: the partial one
        (None, None, False, False),  # a reading outside any planned reading (a check before leaving a group)
    ])
    assert chosen == {0: (1, True), 1: (2, True), 2: (5, False), 4: (7, False), None: (None, True)}


def _reading(t: float, instrument: str, quantity: str, value: float, plan_index: int, attempt: int) -> Reading:
    return Reading(t, instrument, quantity, value, "deg" if instrument != "run" else "", plan_index=plan_index,
                   attempt=attempt, station=plan_index, run=0, direction=1, seating=0,
                   commanded_angle_deg=float(plan_index))


@pytest.fixture
def store(tmp_path: Path):
    from drivers.kinds import describe_kind

    s = RunStore.create(tmp_path, {"method": "encoder_abbe_error", "procedure_yaml": ""})
    s.add_descriptions(descriptions_of("encoder", "encoder", describe_kind("encoder").values()))
    s.add_readings([
        _reading(0.0, "encoder", "angle_deg", 10.0, 0, 0),  # visit 0: partial (the stage's reading skipped) ...
        _reading(0.1, "stage", SKIPPED, 0.0, 0, 0),
        _reading(1.0, "encoder", "angle_deg", 20.0, 1, 1),  # visit 1: whole
        _reading(2.0, "encoder", "angle_deg", 30.0, 2, 2),  # visit 2: rejected (a contradiction) ...
        _reading(2.1, "encoder", REJECTED, 0.0, 2, 2),
        _reading(3.0, "encoder", "angle_deg", 11.0, 0, 3),  # ... visit 0 retaken whole
        _reading(4.0, "encoder", "angle_deg", 31.0, 2, 4),  # ... visit 2 retaken, partial
        _reading(4.1, "run", SKIPPED, 0.0, 2, 4),
    ])
    yield s
    s.close()


def test_the_store_serves_what_counts_in_store_order(store: RunStore):
    assert [(r.plan_index, r.value) for r in store.counted()] == [(1, 20.0), (0, 11.0), (2, 31.0)]
    assert [r.value for r in store.counted("encoder", "angle_deg", whole_only=True)] == [20.0, 11.0]
    assert store.quantity_of("encoder", "angle_deg", "after") == "after_angle_deg"
    assert store.counted("encoder", "angle_deg", "after") == []
    with pytest.raises(KeyError, match="not described"):
        store.quantity_of("encoder", "no_such_field")


def test_the_abbe_reader_takes_one_attempt_per_visit(store: RunStore):
    from rtcal.methods.abbe.dataset import abbe_visits

    visits = abbe_visits(store, [0.0])
    assert visits.commanded_deg.tolist() == [0.0, 1.0, 2.0], "one row per visit, in the plan's order"
    assert visits.encoder_deg.tolist() == [11.0, 20.0, 31.0], "a retaken visit is never averaged with its first attempt"


def test_no_reader_writes_the_rule_again():
    """The rule lives in rtcal/store/runstore.py only: a method's folder or a sample plugin that picks attempts
    by their markers itself would be a second rule (issue 41: it was written three times under two rules)."""
    found = []
    for path in [*(REPO / "rtcal" / "methods").rglob("*.py"), *(REPO / "tests" / "plugins").rglob("*.py")]:
        text = path.read_text(encoding="utf-8")
        if re.search(r"rejected_attempts|\bMARKERS\b|\bSKIPPED\b|\bREJECTED\b|quantity\s*(!=|==)\s*\"(rejected|skipped)\"", text):
            found.append(path.relative_to(REPO).as_posix())
    assert found == []
