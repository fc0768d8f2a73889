"""The error every layer may raise for a mistake in what the user gave (a file, a value): the CLI prints
it as one line and exits 2."""

from __future__ import annotations


class UserError(Exception):
    """A mistake the user can fix; printed as one line, exit code 2."""
