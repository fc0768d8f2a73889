"""What a method's planner works on (``Method.planner``, used by `rtcal plan`): a candidate plan as the
procedure's and the bench's YAML data, and the changes that made it, in words."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Candidate:
    """A candidate: the procedure's and the bench's YAML data, and what was changed, in words."""

    procedure: dict[str, Any]
    bench: dict[str, Any]
    changes: tuple[str, ...] = ()
