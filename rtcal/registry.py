"""One registry for every kind of named thing rtcal can be extended with — calibration methods,
instrument kinds, driver models, compensation formats — the built-in ones and those installed packages
add, all loaded the same way and on first use.

A :class:`Registry` is built from a table of the built-in names, each ``name → "module:attribute"`` (the
module is imported when the name is first asked for, as a plugin's is) or, where a thing is plain data
that names its own code (a driver model's record names its driver class), the record itself; and from an
entry-point group that installed packages register in (``name = "module:attribute"``), read once per
process when a name that is not built in is asked for. Every thing, built in or installed, goes through
the same ``make(name, object, plugin)``, which checks it and says in one line what is wrong. A plugin that
fails to load or to pass ``make`` is left out and named in :attr:`Registry.broken`, so a broken package
never stops the others; none replaces a built-in name.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable, Iterator, Mapping
from importlib.metadata import EntryPoint, entry_points
from typing import Any, Generic, TypeVar

T = TypeVar("T")


class NotRegistered(KeyError):
    """A name the registry does not know (or whose plugin is broken); its message is one line to act on."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


def load_target(target: str) -> Any:
    """The object ``"module:attribute"`` names (ImportError/AttributeError as Python raises them)."""
    module, _, attribute = target.partition(":")
    obj: Any = importlib.import_module(module)
    for part in attribute.split(".") if attribute else ():
        obj = getattr(obj, part)
    return obj


class Registry(Mapping[str, T], Generic[T]):
    """Every ``what`` by name: the built-in ones (``builtin``), then installed plugins' (entry-point ``group``).

    ``make(name, obj, plugin)`` turns what a table entry or an entry point names into the registry's thing,
    checking it (``plugin``: the distribution that registered it, "" for a built-in); it raises with a one-line
    reason when ``obj`` is not one. ``find(group)`` lists the group's entry points (default:
    ``importlib.metadata.entry_points``; a module hands its own, so that a test can stand in for installed
    packages). Asking for a built-in name imports that one module only; iterating lists the built-in names
    without importing them and reads the plugins."""

    def __init__(self, what: str, group: str, builtin: Mapping[str, str | T], make: Callable[[str, Any, str], T],
                 find: Callable[[str], Iterable[EntryPoint]] | None = None):
        self.what = what
        self.group = group
        self._table: dict[str, str | T] = dict(builtin)
        self._make = make
        self._find = find if find is not None else (lambda group: entry_points(group=group))
        self._loaded: dict[str, T] = {}
        self._plugins: dict[str, T] | None = None
        self._names: tuple[str, ...] | None = None
        self._accepted: dict[str, T] = {}
        self.broken: dict[str, str] = {}

    def accepted(self) -> list[T]:
        """The plugins accepted so far (while they are read, those before the one ``make`` checks now): what a
        plugin may not contradict."""
        return list(self._accepted.values())

    # -- the built-in ones: one module each, imported when first asked for ------------------------------
    def builtin_names(self) -> tuple[str, ...]:
        return tuple(self._table)

    def is_builtin(self, name: str) -> bool:
        return name in self._table

    def _builtin(self, name: str) -> T:
        if name not in self._loaded:
            target = self._table[name]
            self._loaded[name] = self._make(name, load_target(target), "") if isinstance(target, str) else target
        return self._loaded[name]

    # -- the installed ones: every entry point of the group, read once ----------------------------------
    def plugins(self) -> dict[str, T]:
        """Every plugin that loads and passes ``make`` (read once per process)."""
        if self._plugins is None:
            found: dict[str, T] = {}
            self._accepted = found
            for ep in self._find(self.group):
                dist = getattr(ep.dist, "name", None) or "?"
                if ep.name in found:
                    continue
                if ep.name in self._table:
                    self.broken[ep.name] = f"{dist}: a built-in {self.what}'s name; a plugin never replaces it"
                    continue
                try:
                    found[ep.name] = self._make(ep.name, ep.load(), dist)
                except Exception as exc:  # noqa: BLE001 — a broken plugin is named, never a crash of the others
                    self.broken[ep.name] = f"{dist}: {type(exc).__name__}: {str(exc)[:200]}"
            self._plugins = found
        return self._plugins

    def forget_plugins(self) -> None:
        """Read the entry points again when next asked (a test that stands in for installed packages)."""
        self._plugins, self._names, self.broken = None, None, {}

    # -- the mapping ------------------------------------------------------------------------------------
    def __getitem__(self, name: str) -> T:
        if name in self._table:  # the built-in ones never wait for the plugins
            return self._builtin(name)
        found = self.plugins()
        if name not in found:
            raise NotRegistered(self.unknown(name))
        return found[name]

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and (name in self._table or name in self.plugins())

    def __iter__(self) -> Iterator[str]:
        return iter((*self._table, *self.plugins()))

    def __len__(self) -> int:
        return len(self._table) + len(self.plugins())

    def names(self) -> tuple[str, ...]:
        """Every name, installed ones by their entry points without loading anything (a command's choices: one
        that fails to load is refused, with its reason, when it is used)."""
        if self._names is None:
            extra = [ep.name for ep in self._find(self.group) if ep.name not in self._table]
            self._names = (*self._table, *dict.fromkeys(extra))
        return self._names

    def unknown(self, name: str) -> str:
        """Why ``name`` is not one of these: one line a person can act on."""
        self.plugins()
        if name in self.broken:
            return f"{self.what} {name!r}: its plugin {self.broken[name]}"
        return f"unknown {self.what} {name!r} (known: {', '.join(self)})"


class Lazy(Mapping[str, Any]):
    """``registry``'s things seen through ``view`` (e.g. each method's procedure model), loading only the one
    asked for: what the loader needs of every method to validate a file that names one."""

    def __init__(self, registry: Registry[T], view: Callable[[T], Any]):
        self._registry, self._view = registry, view

    def __getitem__(self, name: str) -> Any:
        return self._view(self._registry[name])

    def __contains__(self, name: object) -> bool:
        return name in self._registry

    def __iter__(self) -> Iterator[str]:
        return iter(self._registry)

    def __len__(self) -> int:
        return len(self._registry)
