"""A controller's compensation format as one class: everything rtcal knows about it — its name,
how many points it holds and on what grid, what its values mean (sign), whether it takes
comments, what writing one measured direction both ways does on that controller, the options its
writer takes (with their command-line flags and checks), the largest trim it is written with,
its writer, its strict parser, and how the simulated controller applies it. The registry
(rtcal/compensation/registry.py) holds one instance per format: the built-ins and those
installed packages add through the entry-point group ``rtcal.compensation_formats``."""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from typing import Any, Callable, ClassVar

import numpy as np

from rtcal.compensation.table import CompensationError, CompensationTable

GRID_STEPS_DEG = (90, 60, 45, 40, 36, 30, 24, 20, 18, 15, 12, 10, 9, 8, 7.5, 6, 5, 4.5, 4, 3.6, 3, 2.5, 2, 1.5, 1.25, 1,
                  0.75, 0.5, 0.25)
ASCII = {"″": " arcsec", "°": " deg", "—": "-", "–": "-", "−": "-", "…": "...", "·": "*", "×": "x", "≥": ">=",
         "≤": "<=", "π": "pi", "↑": "up", "↓": "down", "(": "[", ")": "]"}
# the largest trim a format is written with unless it says otherwise, arcsec. None of the built-in
# formats' public references states a limit of the value itself: rtcal's bound is the deviation a
# rotary table has at most (deviations.PLAUSIBLE_DEVIATION_ARCSEC); a trim beyond it would move
# the axis by what no calibration measured
DEFAULT_MAX_TRIM_ARCSEC = 3600.0


def plain_ascii(text: str) -> str:
    """``text`` in a controller's character set: plain ASCII, no parentheses (they end a FANUC comment)."""
    return "".join(ASCII.get(c, c) for c in text).encode("ascii", "replace").decode()


@dataclass(frozen=True)
class FormatOption:
    """An option a format's writer takes besides the table: the writer's ``keyword``, the
    command-line ``flag`` that gives it, and how that flag reads. ``help`` says what it is (shared
    by every format that takes the flag), ``default`` what this format assumes without it.
    ``pattern``: a text option's allowed values (a full match; e.g. an axis name), ``example`` one."""

    keyword: str
    flag: str
    help: str
    default: str = ""
    type: Callable[[str], Any] = str
    nargs: int | None = None
    metavar: tuple[str, ...] | str | None = None
    pattern: str | None = None
    noun: str = "value"
    example: str = ""
    flag_only: bool = False  # a switch (``--listing``): given or not, no value
    required: bool = False  # no default a table could be silently wrong by (FANUC's detection unit): refused without it

    @property
    def dest(self) -> str:
        """The argparse attribute the flag fills (``--detection-unit-deg`` → ``detection_unit_deg``)."""
        return self.flag.lstrip("-").replace("-", "_")

    def missing(self, fmt: str) -> CompensationError:
        """The refusal of a table written without this required option: what it is and an example."""
        return CompensationError(f"{fmt} needs {self.flag}: {self.help} ({self.default})")

    def check(self, fmt: str, value: Any) -> None:
        """A text option against its pattern; CompensationError naming the flag, the value and an example."""
        if self.pattern is not None and not (isinstance(value, str) and re.fullmatch(self.pattern, value)):
            raise CompensationError(f"{self.flag} {value!r} is not a {fmt} {self.noun} (e.g. {self.example})")


def axis_option(pattern: str, default: str) -> FormatOption:
    """``--axis``: the axis's name in the file (as the controller spells its axes)."""
    return FormatOption("axis", "--axis", "axis name in the file", f"default {default}", pattern=pattern, noun="axis name",
                        example=default)


class CompensationFormat:
    """One controller format. A subclass sets the class attributes and defines ``write`` and
    ``parse``; the rest (grid rule, comments, trim limit, option checks) follows from them.

    ``name``: as `rtcal compensate --format` and a scenario's ``stage.compensation.format`` name it.
    ``max_points``: the most entries the controller reads. ``fixed_pitch``: what sets the pitch in
    a format whose points lie at one pitch from 0° (None: any positions, e.g. the measured
    targets). ``sign``: what a value in the file means. ``comment``: the (start, end) of a comment
    line, None if the format takes none (warnings then go to the console only).
    ``one_direction``: what writing one measured direction's values both ways does to the
    machine's reversal compensation. ``options``: what the writer takes besides the table.
    ``max_trim_arcsec``: the largest trim written. ``wraps``: the controller applies the table
    modulo one turn (False: beyond its ends the end trims hold, as LinuxCNC does)."""

    name: ClassVar[str]
    max_points: ClassVar[int]
    fixed_pitch: ClassVar[str | None] = None
    sign: ClassVar[str] = "the trim the controller adds to the command"
    comment: ClassVar[tuple[str, str] | None] = None
    one_direction: ClassVar[str] = "a table with the same values for both directions compensates no reversal"
    options: ClassVar[tuple[FormatOption, ...]] = ()
    max_trim_arcsec: ClassVar[float] = DEFAULT_MAX_TRIM_ARCSEC
    wraps: ClassVar[bool] = True

    def instructions(self, table: CompensationTable, **options: Any) -> list[str]:
        """What the engineer must do on the control for the file to take effect (machine data,
        POWER ON, reference point...), one line each: `rtcal compensate` prints them."""
        return []

    def readings(self, table: CompensationTable, **options: Any) -> list[str]:
        """What rtcal assumes where no manual text it has settles how the control reads the file,
        each with the one-point check that settles it on the machine, as commands an operator
        types (docs/compensation.md): `rtcal compensate` prints them as `unsettled:` lines."""
        return []

    def comment_note(self, **options: Any) -> str | None:
        """None when the file written with ``options`` carries the table's warnings; else why
        it does not (`rtcal compensate` says so beside each warning on the console)."""
        return None if self.comment is not None else f"a {self.name} file takes no comment"

    # ``write(table, **options) -> str``: the file's text for ``table`` (trims, deg), each of the
    # format's ``options`` a keyword with its default (declared so a subclass names its own); it
    # calls ``self.check_points(table)`` first unless, like LinuxCNC's, it checks its lines itself
    write: Callable[..., str]

    def parse(self, text: str, where: str = "") -> CompensationTable:
        """The file back to trims, as the controller reads it; CompensationError, with its line,
        for anything the controller would read otherwise than rtcal meant."""
        raise NotImplementedError

    def load(self, text: str, where: str = "") -> CompensationTable:
        """The table the simulated controller applies: the parsed trims, interpolated linearly
        between entries per approach direction, modulo one turn if the controller wraps."""
        table = self.parse(text, where or self.name)
        return table if table.modulo == self.wraps else replace(table, modulo=self.wraps)

    # -- what follows from the attributes -------------------------------------------------
    @property
    def takes_comments(self) -> bool:
        return self.comment is not None

    def comment_lines(self, table: CompensationTable) -> list[str]:
        """The table's warnings as comment lines (plain ASCII: a controller's character set)."""
        if self.comment is None:
            return []
        start, end = self.comment
        return [f"{start}{plain_ascii(f'rtcal warning: {text}')}{end}" for text in table.warnings]

    def check_points(self, table: CompensationTable, max_points: int | None = None) -> None:
        """The grid rule and the point limit (``max_points``: the control's as configured, else the
        format's): a fixed-pitch format takes only evenly spaced points from 0° (the error names a
        --step-deg that keeps every measured target)."""
        limit = self.max_points if max_points is None else max_points
        if self.fixed_pitch is not None and not table.evenly_spaced:
            step = next((s for s in GRID_STEPS_DEG if 360.0 / s + 1 <= limit
                         and np.allclose(table.positions_deg / s, np.round(table.positions_deg / s), atol=1e-6)), None)
            hint = f"--step-deg {step:g} keeps every measured target" if step else "e.g. --step-deg 5"
            raise CompensationError(
                f"{self.name}: the {table.measured_targets or len(table.positions_deg) - 1} measured targets are not evenly "
                f"spaced from 0°, and the format holds points at one pitch ({self.fixed_pitch}): give --step-deg to resample "
                f"them onto a grid ({hint}; the table then says so), or use a format that takes the measured targets (linuxcnc)")
        if len(table.positions_deg) > limit:
            raise CompensationError(f"{self.name}: {len(table.positions_deg)} points; the {'format' if max_points is None else 'control'}"
                                    f" takes at most {limit} (choose a larger --step-deg)")

    def check_trims(self, table: CompensationTable) -> None:
        """Every trim within ``max_trim_arcsec``; CompensationError naming the worst."""
        for name in ("trim_up_deg", "trim_down_deg"):
            trims = np.asarray(getattr(table, name), float) * 3600.0
            if len(trims) and not (np.all(np.isfinite(trims)) and np.max(np.abs(trims)) <= self.max_trim_arcsec):
                i = int(np.nanargmax(np.where(np.isfinite(trims), np.abs(trims), np.inf)))
                raise CompensationError(f"{self.name}: a trim of {trims[i]:.6g}″ at {float(table.positions_deg[i]):g}° "
                                        f"({name.removeprefix('trim_').removesuffix('_deg')}) lies beyond "
                                        f"±{self.max_trim_arcsec:g}″: no table is written that would move the axis by more "
                                        "than any calibration measures")

    def check_options(self, options: dict[str, Any], flags: dict[str, str]) -> None:
        """Only the options this format takes (``flags``: every known option's flag, for the
        message), each valid."""
        own = {o.keyword: o for o in self.options}
        extra = sorted(set(options) - set(own))
        if extra:
            raise CompensationError(f"{self.name} takes no {', '.join(flags.get(o, o) for o in extra)} "
                                    f"(its options: {', '.join(o.flag for o in self.options)})")
        for option in self.options:
            if option.required and options.get(option.keyword) is None:
                raise option.missing(self.name)
        for keyword, value in options.items():
            own[keyword].check(self.name, value)
