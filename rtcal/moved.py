"""Names that moved keep working for one release: a module's ``__getattr__`` made here forwards each to where it
went, with a DeprecationWarning saying where (nothing is imported until an old name is asked for). A name that
was removed outright may keep a stand-in for one release the same way, its warning saying what replaced it."""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Callable, Mapping
from typing import Any


def moved(module: str, where: Mapping[str, str], removed: Mapping[str, tuple[object, str]] | None = None
          ) -> Callable[[str], Any]:
    """``__getattr__`` for ``module`` (its ``__name__``) whose names in ``where`` moved there (name → new module),
    and whose names in ``removed`` are gone (name → (the stand-in served for one release, what replaced it))."""
    gone = dict(removed or {})

    def __getattr__(name: str) -> Any:
        if name in gone:
            stand_in, replaced_by = gone[name]
            warnings.warn(f"{module}.{name} was removed: {replaced_by}; the name goes in the next release",
                          DeprecationWarning, stacklevel=2)
            return stand_in
        if name not in where:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        warnings.warn(f"{module}.{name} moved to {where[name]}.{name}; the old name goes in the next release",
                      DeprecationWarning, stacklevel=2)
        return getattr(importlib.import_module(where[name]), name)

    return __getattr__
