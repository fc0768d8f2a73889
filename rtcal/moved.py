"""Names that moved keep working for one release: a module's ``__getattr__`` made here forwards each to where it
went, with a DeprecationWarning saying where (nothing is imported until an old name is asked for)."""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Callable, Mapping
from typing import Any


def moved(module: str, where: Mapping[str, str]) -> Callable[[str], Any]:
    """``__getattr__`` for ``module`` (its ``__name__``) whose names in ``where`` moved there (name → new module)."""

    def __getattr__(name: str) -> Any:
        if name not in where:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        warnings.warn(f"{module}.{name} moved to {where[name]}.{name}; the old name goes in the next release",
                      DeprecationWarning, stacklevel=2)
        return getattr(importlib.import_module(where[name]), name)

    return __getattr__
