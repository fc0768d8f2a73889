"""Motion helpers shared by every procedure."""

from __future__ import annotations

from typing import Protocol, runtime_checkable


@runtime_checkable
class Turning(Protocol):
    """What an approach needs of a table: where it is, and a move (a rotary stage's interface has both)."""

    def position_deg(self) -> float: ...

    def move_to(self, angle_deg: float, /) -> None: ...


def approach(stage: Turning, target_deg: float, direction: int, overshoot_deg: float) -> None:
    """Move so that the target is reached moving in ``direction`` (+1/−1), as ISO 230-2 asks.

    A move that would arrive the other way first passes the target by ``overshoot_deg``; so
    does a "move" to where the stage already is, since the last approach may have been the
    other way (the turn-around of a bidirectional run).
    """
    here = stage.position_deg()
    arriving = 1 if target_deg > here else -1 if target_deg < here else 0
    if arriving != direction and overshoot_deg > 0:
        stage.move_to(target_deg - direction * overshoot_deg)
    stage.move_to(target_deg)
