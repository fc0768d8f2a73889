"""Issue 36, drivers that are trusted too readily: a plugin that is not its kind's interface (8), a
Sylvac that keeps sending (6), a PI controller's motion error and long moves (5)."""

from __future__ import annotations

import socket
import threading
import time

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


class _Flooding:
    """A Sylvac that sends readings on its own, without end (continuous output left on), until closed."""

    def __init__(self):
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.sent_bytes = 0
        threading.Thread(target=self._serve, daemon=True).start()

    def url(self) -> str:
        return f"socket://127.0.0.1:{self.listener.getsockname()[1]}"

    def _serve(self) -> None:
        conn, _ = self.listener.accept()
        with conn:
            try:
                while True:
                    conn.sendall(b" 0.0123\r" * 128)
                    self.sent_bytes += 1024
            except OSError:
                return


def test_a_sylvac_that_keeps_sending_ends_the_probe_within_a_bound(capsys):
    flood = _Flooding()
    start = time.monotonic()
    err = _one_line(capsys, 1, ["probe", "dial_indicator", f"{flood.url()}?model=sylvac", "--timeout-s", "1"])
    took_s = time.monotonic() - start
    flood.listener.close()
    assert "keeps sending after MM" in err and "dial_indicator" in err, err
    assert took_s < 3.0, took_s  # the loop after MM had no deadline: it read as long as the indicator sent
