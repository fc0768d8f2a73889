"""Each method's own outputs (its files, report sections and console lines), from the typed
results they are made from: the method object makes them (``Method.outputs``). The files every run has (results.json, the positioning deviations,
report.md/html/pdf) are written around them by the runner."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol


class MethodOutputs(Protocol):
    """What a method adds to a run directory, the report and the console, from its results alone.

    Optional members, read with ``getattr`` where present: ``estimate_words()`` (the recommended
    estimate in words), ``iso230_1_errors()`` (the axis's error motions and location errors,
    :mod:`rtcal.compensation.geometry`, for a volumetric compensation table), ``subject()`` (what was
    measured, the certificate's subtitle; "": the recommended result's quantity says it) and
    ``standards_applied()`` (the method's own standards, listed before the GUM on page 1)."""

    def write_files(self, run_dir: Path) -> list[Path]:
        """The method's own files (CSV, figures) into ``run_dir``; returns their paths."""
        ...

    def report_body(self) -> list[str]:
        """The method's sections of report.md (Markdown lines)."""
        ...

    def certificate_figures(self) -> list[tuple[str, str]]:
        """(file name, caption) of the figures the certificate shows, in order."""
        ...

    def method_text(self) -> list[str]:
        """The certificate's paragraphs on the method."""
        ...

    def method_name(self) -> str:
        """The method as the certificate names it, in words (never the procedure's `method:` key)."""
        ...

    def summary(self) -> list[str]:
        """The console lines after a run: the recommended result, then what did not converge."""
        ...

    def certificate_tables(self) -> list[dict[str, Any]]:
        """The method's own tables on the certificate: each a heading, a note, a header and rows."""
        ...


class OutputsBase:
    """What a method's outputs say when they have nothing to say: no files of their own, no report section, no
    figure, no table on the certificate, no console line; the method named by its procedure's ``method:``. A
    subclass gives what it has (at least :meth:`method_name` and :meth:`method_text`, which the certificate
    states)."""

    def write_files(self, run_dir: Path) -> list[Path]:
        return []

    def report_body(self) -> list[str]:
        return []

    def certificate_figures(self) -> list[tuple[str, str]]:
        return []

    def method_text(self) -> list[str]:
        return []

    def method_name(self) -> str:
        return ""

    def summary(self) -> list[str]:
        return []

    def certificate_tables(self) -> list[dict[str, Any]]:
        return []

    def subject(self) -> str:
        return ""

    def standards_applied(self) -> list[str]:
        return []
