"""The approach rule: every target is reached moving in the procedure's direction."""

from __future__ import annotations

from drivers.interfaces import RotaryStage
from rtcal.engine.motion import approach


class RecordingStage(RotaryStage):
    name = "stage"

    def __init__(self, at: float):
        self.at = at
        self.moves: list[float] = []

    def home(self) -> None: ...
    def stop(self) -> None: ...

    def move_to(self, angle_deg: float) -> None:
        self.moves.append(angle_deg)
        self.at = angle_deg

    def position_deg(self) -> float:
        return self.at


def test_same_direction_goes_straight():
    s = RecordingStage(0.0)
    approach(s, 15.0, +1, 1.0)
    assert s.moves == [15.0]


def test_other_direction_overshoots_first():
    s = RecordingStage(30.0)
    approach(s, 15.0, +1, 1.0)
    assert s.moves == [14.0, 15.0]
    approach(s, 30.0, -1, 1.0)
    assert s.moves[-2:] == [31.0, 30.0]


def test_already_there_still_approaches_in_direction():
    """The turn-around of a bidirectional run: the last approach was the other way."""
    s = RecordingStage(352.5)
    approach(s, 352.5, -1, 1.0)
    assert s.moves == [353.5, 352.5]
