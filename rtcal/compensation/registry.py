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
from rtcal.compensation.table import CompensationError, CompensationTable
from rtcal.registry import Registry

ENTRY_POINT_GROUP = "rtcal.compensation_formats"
BUILTIN = {"linuxcnc": "rtcal.compensation.linuxcnc:LinuxCncFormat", "siemens-lec": "rtcal.compensation.siemens_lec:SiemensLecFormat",
           "siemens-cec": "rtcal.compensation.siemens_cec:SiemensCecFormat", "fanuc": "rtcal.compensation.fanuc:FanucFormat",
           "heidenhain": "rtcal.compensation.heidenhain:HeidenhainFormat",
           "isg-volcomp": "rtcal.compensation.isg_volcomp:IsgVolcompFormat"}
"""The built-in formats, registered as a plugin's are (by name and ``module:Class``, loaded on first use)."""
# `rtcal compensate`'s own flags: a format's option may not take one
RESERVED_FLAGS = frozenset({"--format", "--out", "--step-deg", "--allow-one-direction", "--max-gap-deg", "--help"})


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


def format_of(name: str, obj: Any, plugin: str) -> CompensationFormat:
    """A format from what its table entry or entry point names (a class is instantiated); an installed one's
    declaration is checked against the formats known before it (:func:`_check`)."""
    fmt = obj() if isinstance(obj, type) and issubclass(obj, CompensationFormat) else obj
    if not isinstance(fmt, CompensationFormat):
        raise TypeError(f"{getattr(obj, '__name__', str(obj)[:60])} is not a CompensationFormat subclass or instance")
    if getattr(fmt, "name", None) != name:
        raise ValueError(f"the entry point is named {name!r}, the format {getattr(fmt, 'name', None)!r}")
    if plugin:
        _check(fmt, [FORMATS[n] for n in BUILTIN] + FORMATS.accepted())
    return fmt


def _entry_points(group: str) -> list[EntryPoint]:
    return sorted(entry_points(group=group), key=lambda e: e.name)  # a clash is the later name's, whatever the order found


FORMATS: Registry[CompensationFormat] = Registry("format", ENTRY_POINT_GROUP, BUILTIN, format_of, _entry_points)
"""Every compensation format by name (built in, and installed plugins')."""


def plugins() -> dict[str, CompensationFormat]:
    """Formats installed packages register (read once per process); a built-in name is never replaced."""
    return FORMATS.plugins()


def formats() -> dict[str, CompensationFormat]:
    """Every usable format by name: the built-ins first, then the plugins'."""
    return {name: FORMATS[name] for name in FORMATS}


def format_names() -> tuple[str, ...]:
    """The names `rtcal compensate --format` and a scenario's ``stage.compensation.format`` accept."""
    return tuple(FORMATS)


def get_format(name: str) -> CompensationFormat:
    """The format of that name; CompensationError listing the known ones (or why a plugin's failed)."""
    if name in FORMATS.builtin_names():
        return FORMATS[name]
    fmt = plugins().get(name)
    if fmt is None and name in FORMATS.broken:
        raise CompensationError(f"format {name!r}: plugin {FORMATS.broken[name]}")
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
