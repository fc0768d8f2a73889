"""Compensation formats: one class per controller format (rtcal/compensation/base.py), one
module each, and one registry (rtcal/compensation/registry.py) that also takes formats installed
packages add through the entry-point group ``rtcal.compensation_formats``. Making the trims from
a run's deviations is in rtcal/deliverables/compensation.py; docs/compensation.md has the rules
and sign of each built-in format."""

from rtcal.compensation.base import CompensationFormat, FormatOption, axis_option
from rtcal.compensation.registry import (ENTRY_POINT_GROUP, CliOption, check_trims, cli_options, format_names, formats,
                                         get_format, option_flags, options_given, write_table)
from rtcal.compensation.table import CompensationError, CompensationTable, empty, regular_table, sane

__all__ = ["ENTRY_POINT_GROUP", "CliOption", "CompensationError", "CompensationFormat", "CompensationTable", "FormatOption",
           "axis_option", "check_trims", "cli_options", "empty", "format_names", "formats", "get_format", "option_flags",
           "options_given", "regular_table", "sane", "write_table"]
