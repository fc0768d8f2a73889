"""Deprecated: each method's readers moved into its folder (rtcal/methods/<method>/dataset.py), the
conditions' summary to rtcal/methods/conditions.py and the quantity lookup to the store
(:meth:`rtcal.store.runstore.RunStore.quantity_of`). The old names still work for one release, with a
DeprecationWarning; nothing here is imported until a name is asked for."""

from __future__ import annotations

from rtcal.moved import moved

__getattr__ = moved(__name__, {
    "multistation_data": "rtcal.methods.multistation.dataset",
    "abbe_visits": "rtcal.methods.abbe.dataset",
    "abbe_conditions": "rtcal.methods.abbe.dataset",
    "summarise_conditions": "rtcal.methods.conditions",
    "CONDITIONS": "rtcal.methods.conditions",
})
