"""The one registry of compensation formats: the built-ins below and those installed packages
add through the entry-point group ``rtcal.compensation_formats`` (the entry point's name is the
format's name, its object a :class:`~rtcal.compensation.base.CompensationFormat` subclass or
instance). Everything that names formats — `rtcal compensate`'s ``--format`` choices and option
flags, a scenario's ``stage.compensation.format``, the simulated controller — asks here."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from importlib.metadata import EntryPoint, entry_points
from typing import Any, Callable

from rtcal.compensation.base import CompensationFormat
from rtcal.compensation.fanuc import FanucFormat
from rtcal.compensation.heidenhain import HeidenhainFormat
from rtcal.compensation.isg_volcomp import IsgVolcompFormat
from rtcal.compensation.linuxcnc import LinuxCncFormat
from rtcal.compensation.siemens_cec import SiemensCecFormat
from rtcal.compensation.siemens_lec import SiemensLecFormat
from rtcal.compensation.table import CompensationError, CompensationTable

ENTRY_POINT_GROUP = "rtcal.compensation_formats"
BUILTIN: dict[str, CompensationFormat] = {f.name: f for f in (
    LinuxCncFormat(), SiemensLecFormat(), SiemensCecFormat(), FanucFormat(), HeidenhainFormat(), IsgVolcompFormat())}
# `rtcal compensate`'s own flags: a format's option may not take one
RESERVED_FLAGS = frozenset({"--format", "--out", "--step-deg", "--allow-one-direction", "--max-gap-deg", "--help"})

_plugins: dict[str, CompensationFormat | str] | None = None  # str: why the plugin could not be used


def _check(fmt: CompensationFormat, known: list[CompensationFormat]) -> None:
    """A plugin's declaration, before anything uses it: limits that make sense, and option flags
    that neither clash with the command's own nor mean something else for another format."""
    if not callable(getattr(fmt, "write", None)) or type(fmt).parse is CompensationFormat.parse:
        raise TypeError("a format defines write and parse")
    if not (isinstance(fmt.max_points, int) and fmt.max_points >= 3):
        raise ValueError(f"max_points {fmt.max_points!r}: an integer ≥ 3")
    if not 0.0 < fmt.max_trim_arcsec <= 3600.0:
        raise ValueError(f"max_trim_arcsec {fmt.max_trim_arcsec!r}: in (0, 3600]")
    taken = {o.flag: o for f in known for o in f.options}
    for option in fmt.options:
        if not option.flag.startswith("--") or option.flag in RESERVED_FLAGS or not option.keyword.isidentifier():
            raise ValueError(f"option {option.flag!r} ({option.keyword!r}): a --flag of its own and a keyword")
        other = taken.get(option.flag)
        if other is not None and ((other.keyword, other.type, other.nargs, other.flag_only)
                                  != (option.keyword, option.type, option.nargs, option.flag_only)):
            raise ValueError(f"option {option.flag} means something else for another format")


def _from_entry_point(ep: EntryPoint, known: list[CompensationFormat]) -> CompensationFormat | str:
    """A plugin's format (loaded now: its declaration is checked), or why it cannot be used."""
    try:
        obj = ep.load()
        fmt = obj() if isinstance(obj, type) and issubclass(obj, CompensationFormat) else obj
        if not isinstance(fmt, CompensationFormat):
            raise TypeError(f"{ep.value} is not a CompensationFormat subclass or instance")
        if getattr(fmt, "name", None) != ep.name:
            raise ValueError(f"the entry point is named {ep.name!r}, the format {getattr(fmt, 'name', None)!r}")
        _check(fmt, known)
    except Exception as exc:  # noqa: BLE001 — a broken plugin is reported when its format is asked for, never a crash
        return f"{getattr(ep.dist, 'name', '?')} (failed to load: {exc!r:.200})"
    return fmt


def plugins() -> dict[str, CompensationFormat | str]:
    """Formats installed packages register (read once per process); a built-in name is never replaced."""
    global _plugins
    if _plugins is None:
        found: dict[str, CompensationFormat | str] = {}
        known = list(BUILTIN.values())
        for ep in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
            if ep.name in BUILTIN or ep.name in found:
                continue
            fmt = _from_entry_point(ep, known)
            found[ep.name] = fmt
            if isinstance(fmt, CompensationFormat):
                known.append(fmt)
        _plugins = found
    return _plugins


def formats() -> dict[str, CompensationFormat]:
    """Every usable format by name: the built-ins first, then the plugins'."""
    return {**BUILTIN, **{n: f for n, f in plugins().items() if isinstance(f, CompensationFormat)}}


def format_names() -> tuple[str, ...]:
    """The names `rtcal compensate --format` and a scenario's ``stage.compensation.format`` accept."""
    return tuple(formats())


def get_format(name: str) -> CompensationFormat:
    """The format of that name; CompensationError listing the known ones (or why a plugin's failed)."""
    fmt = BUILTIN.get(name) or plugins().get(name)
    if isinstance(fmt, str):
        raise CompensationError(f"format {name!r}: plugin {fmt}")
    if fmt is None:
        raise CompensationError(f"unknown format {name!r}; one of {', '.join(format_names())}")
    return fmt


# -- the command line: `rtcal compensate`'s format options from the registry -------------
@dataclass(frozen=True)
class CliOption:
    """One format option flag of `rtcal compensate`, merged over the formats that take it:
    ``parser.add_argument(option.flag, **option.argparse_kwargs())``."""

    flag: str
    keyword: str  # what the writers take
    help: str
    type: Callable[[str], Any]
    nargs: int | None
    metavar: tuple[str, ...] | str | None
    formats: tuple[str, ...]
    flag_only: bool = False

    @property
    def dest(self) -> str:
        return self.flag.lstrip("-").replace("-", "_")

    def argparse_kwargs(self) -> dict[str, Any]:
        if self.flag_only:
            return {"help": self.help, "action": "store_const", "const": True, "default": None}
        kwargs: dict[str, Any] = {"help": self.help, "type": self.type}
        if self.nargs is not None:
            kwargs["nargs"] = self.nargs
        if self.metavar is not None:
            kwargs["metavar"] = self.metavar
        return kwargs


def cli_options() -> tuple[CliOption, ...]:
    """Every format option flag, in the registry's order, its help naming the formats that take
    it and what each assumes without it (e.g. "axis name in the file: siemens-lec/siemens-cec
    (default C1), heidenhain (default C)")."""
    by_flag: dict[str, list[tuple[str, Any]]] = {}
    for fmt in formats().values():
        for option in fmt.options:
            by_flag.setdefault(option.flag, []).append((fmt.name, option))
    result = []
    for flag, uses in by_flag.items():
        first = uses[0][1]
        defaults: dict[str, list[str]] = {}
        for name, option in uses:
            defaults.setdefault(option.default, []).append(name)
        parts = [f"{'/'.join(names)}{f' ({default})' if default else ''}" for default, names in defaults.items()]
        result.append(CliOption(flag, first.keyword, f"{first.help}: {', '.join(parts)}", first.type, first.nargs,
                                first.metavar, tuple(name for name, _ in uses), first.flag_only))
    return tuple(result)


def option_flags() -> dict[str, str]:
    """Each writer keyword's command-line flag (``unit_deg`` → ``--detection-unit-deg``)."""
    return {o.keyword: o.flag for o in cli_options()}


def options_given(values: Mapping[str, Any]) -> dict[str, Any]:
    """The writer options a command line gave (``vars(args)``: by each flag's dest), as the writers
    take them (a flag of several values as a tuple); options not given are left out."""
    given = {}
    for option in cli_options():
        value = values.get(option.dest)
        if value is not None:
            given[option.keyword] = tuple(value) if option.nargs is not None else value
    return given


def check_trims(name: str, table: CompensationTable) -> None:
    """Every trim within what format ``name`` is written with; CompensationError naming the worst."""
    get_format(name).check_trims(table)


def write_table(name: str, table: CompensationTable, **options: Any) -> str:
    """The format's file text; an unknown format, a trim beyond its limit, an option the format
    does not take (or a bad value, e.g. an axis name) is a CompensationError."""
    fmt = get_format(name)
    fmt.check_trims(table)
    fmt.check_options(options, option_flags())
    return fmt.write(table, **options)
