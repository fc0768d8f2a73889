"""Issue 36, drivers that are trusted too readily: a plugin that is not its kind's interface (8), a
Sylvac that keeps sending (6), a PI controller's motion error and long moves (5)."""

from __future__ import annotations

import pytest

from drivers import models
from tests.test_trust_round2 import _one_line


class _NotAnIndicator:
    """A plugin's class that reads like an indicator but does not subclass DialIndicator."""

    kind, model, schemes, name = "dial_indicator", "loose-indicator", ("serial",), "dial_indicator"
    opened = False

    def __init__(self, address, timeout_s: float = 1.0, **context):
        type(self).opened = True

    def identity(self) -> str:
        return "loose"


def test_a_plugin_that_is_not_its_kinds_interface_is_refused_in_one_line(monkeypatch, capsys):
    monkeypatch.setattr(models, "_plugins", {"loose-indicator": models.Model(
        "loose-indicator", "dial_indicator", f"{__name__}:_NotAnIndicator", ("serial",), plugin="rtcal-loose")})
    err = _one_line(capsys, 2, ["probe", "dial_indicator", "socket://127.0.0.1:9?model=loose-indicator"])
    assert "rtcal-loose" in err and f"{__name__}:_NotAnIndicator" in err, err
    assert "is not a DialIndicator" in err and "lacks read_um" in err, err
    assert not _NotAnIndicator.opened  # refused before its constructor opens anything
