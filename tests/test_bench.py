"""Bench randomness: every named consumer has its own stream; restarts keep physical facts."""

from __future__ import annotations

import numpy as np

from simulators.bench import Bench
from simulators.scenario import Scenario


def test_named_streams_are_independent():
    """Names that share a prefix or a suffix (both indicators, every fault stream) must not share draws."""
    b = Bench(Scenario(), seed=4)
    names = ["dial_indicator_1", "dial_indicator_2", "faults stage", "faults laser_tracer", "faults cmm",
             "encoder", "autocollimator", "laser_tracer", "stage", "cmm"]
    draws = {n: tuple(b.rng(n).standard_normal(4)) for n in names}
    assert len(set(draws.values())) == len(names)
    seatings = {Bench(Scenario(), seed=4).persistent_rng(f"seating {o!r}").standard_normal() for o in (0.0, 15.0, 45.0, 7.5)}
    assert len(seatings) == 4


def test_generation_changes_noise_but_not_persistent_facts():
    a, b = Bench(Scenario(), seed=4), Bench(Scenario(), seed=4, generation=1)
    assert not np.array_equal(a.rng("stage").standard_normal(3), b.rng("stage").standard_normal(3))
    assert a.persistent_rng("seating 0.0").standard_normal() == b.persistent_rng("seating 0.0").standard_normal()
