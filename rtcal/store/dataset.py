"""Deprecated: each method's readers moved into its folder (rtcal/methods/<method>/dataset.py), the
conditions' summary to rtcal/methods/conditions.py and the quantity lookup to the store
(:func:`rtcal.store.runstore.stored_quantity`). The old names still work for one release, with a
DeprecationWarning; nothing here is imported until a name is asked for."""

from __future__ import annotations

import importlib
import warnings
from typing import Any

MOVED = {
    "multistation_data": "rtcal.methods.multistation.dataset",
    "abbe_visits": "rtcal.methods.abbe.dataset",
    "abbe_conditions": "rtcal.methods.abbe.dataset",
    "summarise_conditions": "rtcal.methods.conditions",
    "CONDITIONS": "rtcal.methods.conditions",
}


def __getattr__(name: str) -> Any:
    if name not in MOVED:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    warnings.warn(f"rtcal.store.dataset.{name} moved to {MOVED[name]}.{name}; the old name goes in the next release",
                  DeprecationWarning, stacklevel=2)
    return getattr(importlib.import_module(MOVED[name]), name)
