"""A reference instrument's new calibration, and how a method takes it into a run it already made.

When an autocollimator's or polygon's certificate comes back changed, or the instrument was found
out of tolerance, the lab must say which calibrations it touched and what they would have said
(ISO/IEC 17025 7.10). ``rtcal catalog reassess`` reads the new certificate (:class:`InstrumentCalibration`,
a YAML file), finds the runs that used the instrument, and re-evaluates each from its stored
readings through its method's analysis. What a new calibration changes is the method's to say: a
method offers it as its ``recalibration`` member (:class:`Recalibration`); a method without one
cannot be re-evaluated, and the catalogue says so by name rather than guessing.
"""

from __future__ import annotations

import datetime
import re
from collections.abc import Mapping
from typing import Annotated, Any, Protocol, runtime_checkable

from pydantic import BaseModel, ConfigDict, Field, field_validator


class CannotRecalibrate(Exception):
    """This run's analysis does not take that part of the instrument's calibration (the message says why)."""


def _date(text: str) -> str:
    if not text:
        return text
    if not re.fullmatch(r"\d{4}-\d{2}-\d{2}", text):
        raise ValueError(f"{text[:40]!r} is not a date: write it as YYYY-MM-DD (e.g. 2026-03-31)")
    datetime.date.fromisoformat(text)
    return text


def _plain(text: str) -> str:
    if any(ord(c) < 32 or 0x7F <= ord(c) < 0xA0 for c in text):
        raise ValueError("holds a control character")
    return " ".join(text.split())


class InstrumentCalibration(BaseModel):
    """A reference instrument's new calibration certificate, as ``catalog reassess --certificate``
    reads it. Every number is what the new certificate states; a key left out is a part of the
    calibration that did not change (the runs keep what they applied)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    instrument: str = Field(min_length=1, max_length=200, description="the instrument's id as the runs name it "
                                                                      "(metadata.instruments.<role>.id)")
    certificate_number: str = Field(min_length=1, max_length=100, description="the new certificate's number")
    calibrated_by: str = Field("", max_length=200, description="who issued it")
    calibration_date: str = Field("", max_length=10, description="when it was calibrated, YYYY-MM-DD")
    calibration_due: str = Field("", max_length=10, description="its next due date, YYYY-MM-DD")
    scale_error_ppm: float | None = Field(None, ge=-1e5, le=1e5, description=(
        "the instrument's scale error as found, ppm: an indication is 1 + e times the true value (the run's readings "
        "are divided by it)"))
    scale_u_ppm: float | None = Field(None, ge=0.0, le=1e5, description="standard uncertainty of that scale, ppm")
    u_arcsec: float | None = Field(None, ge=0.0, le=3600.0, description="expanded uncertainty (k = 2) of an indication, arcsec")
    corrections_arcsec: list[Annotated[float, Field(ge=-3600.0, le=3600.0)]] | None = Field(
        None, min_length=1, max_length=3600, description="per position its error, arcsec (a polygon: one per face, in order)")
    corrections_u_arcsec: float | None = Field(None, ge=0.0, le=3600.0, description="1σ of each correction, arcsec")
    out_of_tolerance_since: str = Field("", max_length=10, description=(
        "found out of tolerance: the date from which the runs that used it are suspect, YYYY-MM-DD (empty: it was not)"))

    _dates = field_validator("calibration_date", "calibration_due", "out_of_tolerance_since")(
        lambda cls, text: _date(text))
    _texts = field_validator("instrument", "certificate_number", "calibrated_by")(lambda cls, text: _plain(text))

    def changes(self) -> list[str]:
        """What the certificate changes, in words (empty: only a new number and dates)."""
        out = []
        if self.scale_error_ppm is not None:
            out.append(f"scale error {self.scale_error_ppm:+g} ppm")
        if self.scale_u_ppm is not None:
            out.append(f"scale u {self.scale_u_ppm:g} ppm")
        if self.u_arcsec is not None:
            out.append(f"U {self.u_arcsec:g}″ (k = 2)")
        if self.corrections_arcsec is not None:
            out.append(f"{len(self.corrections_arcsec)} corrections ({min(self.corrections_arcsec):+.2f}″ … "
                       f"{max(self.corrections_arcsec):+.2f}″)")
        if self.corrections_u_arcsec is not None:
            out.append(f"u of each correction {self.corrections_u_arcsec:g}″")
        if self.out_of_tolerance_since:
            out.append(f"out of tolerance since {self.out_of_tolerance_since}")
        return out


@runtime_checkable
class Recalibration(Protocol):
    """A method's ``recalibration``: what of its reference instruments' calibrations its analysis
    applies, and the run as it would have been with a new one."""

    def applied(self, proc: Any, meta: Mapping[str, str]) -> dict[str, str]:
        """Per instrument role (metadata.instruments' keys), what of its calibration the run's analysis
        applied, in words (``proc``: the stored procedure; ``meta``: the store's meta)."""
        ...

    def recalibrated(self, proc: Any, meta: Mapping[str, str], role: str,
                     calibration: InstrumentCalibration) -> tuple[Any, dict[str, str]]:
        """The procedure and the store's meta entries the analysis reads, as they would have been with
        ``calibration`` for the instrument in ``role`` (CannotRecalibrate: its analysis does not take
        what the certificate changes)."""
        ...
