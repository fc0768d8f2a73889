"""The positioning-deviation table: CSV and results.json round trips, located errors."""

from __future__ import annotations

import numpy as np
import pytest

from rtcal.deliverables.deviations import DeviationTableError, PositioningDeviations


def _table() -> PositioningDeviations:
    return PositioningDeviations(np.array([0.0, 90.0, 0.0, 90.0]), np.array([1, 1, -1, -1]), np.array([1, 1, 1, 1]),
                                 np.array([0.0, 1.25, -0.5, 0.75]), np.array([0.1, 0.2, 0.1, np.nan]), estimator="x")


def test_csv_round_trip_keeps_every_value():
    back = PositioningDeviations.parse_csv(_table().to_csv())
    assert back.to_csv() == _table().to_csv()
    assert np.isnan(back.uncertainty_arcsec[3])


def test_model_round_trip():
    back = PositioningDeviations.from_model(_table().to_model())
    np.testing.assert_array_equal(back.deviation_arcsec, _table().deviation_arcsec)
    assert back.estimator == "x"


@pytest.mark.parametrize("text, message", [
    ("", "empty file"),
    ("target_deg,run,deviation_arcsec\n0,1,0\n", "missing direction"),
    ("target_deg,direction,run,deviation_arcsec\n0,2,1,0\n", ":2: direction must be"),
    ("target_deg,direction,run,deviation_arcsec\n0,1,1,abc\n", ":2: expected numbers"),
    ("target_deg,direction,run,deviation_arcsec\n0,1,0,1\n", "runs are numbered from 1"),
    ("target_deg,direction,run,deviation_arcsec\n0,1,1,nan\n", "finite"),
    ("target_deg,direction,run,deviation_arcsec\n0,1,1,1\n0,1,1,2\n", "more than once"),
    ("target_deg,direction,run,deviation_arcsec\n", "no rows"),
])
def test_bad_csv_names_file_and_line(text, message):
    with pytest.raises(DeviationTableError, match=message):
        PositioningDeviations.parse_csv(text, "d.csv")


def test_a_rounding_zero_is_written_without_a_sign():
    """A deviation of −4e-16″ (a reference row, zero but for rounding, whose sign any reordering of the arithmetic
    flips) is 0.0000 in the CSV and 0.0 in results.json, never −0.0000 (issue 43: the structured operators flipped it)."""
    table = PositioningDeviations(np.array([0.0, 90.0]), np.array([1, 1]), np.array([1, 1]), np.array([-4.4e-16, -0.00004]),
                                  np.array([0.3, -1e-9]), estimator="x")
    assert ",-0.0000" not in table.to_csv() and table.to_csv().count(",0.0000") == 3
    model = table.to_model()
    assert all(np.copysign(1.0, v) > 0 for v in model.deviation_arcsec + [model.uncertainty_arcsec[1]])
