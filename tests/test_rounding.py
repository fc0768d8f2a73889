"""A number as a certificate states it: significant digits without exponent form (issue 46: `1e+03 ppm`)."""

from __future__ import annotations

import pytest

from rtcal.deliverables.rounding import significant


@pytest.mark.parametrize("value, text", [(1000.0, "1000"), (5000.0, "5000"), (2500.4, "2500"), (100000.0, "100000"),
                                         (0.0123456, "0.0123"), (2.5, "2.5"), (0.3, "0.3"), (-12.345, "-12.3"),
                                         (0.0, "0")])
def test_significant_digits_never_in_exponent_form(value, text):
    assert significant(value) == text
