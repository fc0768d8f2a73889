"""Procedures: YAML files validated by pydantic, with located errors.

The names below load on first use (PEP 562): importing ``rtcal.procedure.yamlfile`` for its
error type must not load every model and the simulated bench (that cost every command 0.5 s)."""

from __future__ import annotations

from typing import Any

__all__ = ["Procedure", "load_procedure", "load_scenario", "procedure_schema"]


def __getattr__(name: str) -> Any:
    if name in ("load_procedure", "load_scenario", "procedure_schema"):
        from rtcal.procedure import loader

        return getattr(loader, name)
    if name == "Procedure":
        from rtcal.procedure import models

        return getattr(models, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
