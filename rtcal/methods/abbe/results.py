"""The encoder Abbe-error method's part of results.json (seed 001): its estimates, truth, analysis and
results model, on the shared blocks of :mod:`rtcal.results.model` (the solvers' estimates among them)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from rtcal.api import (Analysis, Arcsec, Deg, Direction, EnvironmentSummary, Estimate, NamedSet, RunResults, SigmaArcsec,
                       TargetedEstimate, Truth)
from rtcal.results.model import AbbeEstimate

AbbeEstimator = Literal["abbe", "closure"]
"""The method's estimator names (what ``recommended`` and ``solver_status`` may name)."""


class ClosureEstimate(TargetedEstimate):
    """``estimates.closure``: table and polygon errors separated by re-seating the polygon."""

    table_angle_deg: list[Deg] = Field(description="table angle of each table error, degrees")
    direction: list[Direction] = Field(description="approach of each table error: 1 positive, −1 negative")
    table_error_arcsec: list[Arcsec | None] = Field(description="the table's error εz per angle and direction, arcsec")
    table_uncertainty_arcsec: list[SigmaArcsec | None] = Field(description="its 1σ, arcsec")
    face_error_arcsec: list[Arcsec | None] = Field(description="the polygon's face errors, arcsec")
    face_uncertainty_arcsec: list[SigmaArcsec | None] = Field(description="their 1σ, arcsec")
    seating_offset_arcsec: list[Arcsec | None] = Field(description="the zero of each seating, arcsec")
    residual_rms_arcsec: SigmaArcsec = Field(description="RMS of the closure residuals, arcsec")


class AbbeEstimates(NamedSet[Estimate]):
    """``estimates`` of the encoder Abbe-error method."""


    abbe: AbbeEstimate | None = Field(None, description="εz and the encoder's Abbe analysis (absent: it could not run)")
    closure: ClosureEstimate | None = Field(None, description="table and polygon separated by closure (no certificate)")


class AbbeTruth(Truth):
    """What the simulated bench really had (a simulated run only), arcsec."""

    encoder_error_arcsec: list[Arcsec] = Field(description="true systematic encoder error per step, arcsec")
    positioning_error_arcsec: list[Arcsec] = Field(description="true εz per step, arcsec")
    face_error_arcsec: list[Arcsec] = Field(description="the polygon's true face errors, arcsec")


class AbbeAnalysis(Analysis):
    """The encoder Abbe-error method's analysis."""

    recommended: AbbeEstimator | None = Field(
        description="the estimate to quote: converged, and the smallest uncertainty among those that did")
    estimates: AbbeEstimates = Field(description="every estimate that could run, by estimator")
    truth: AbbeTruth | None = Field(None, description="what the simulated bench really had (absent: on instruments)")
    environment: EnvironmentSummary | None = Field(
        None, description="the air and table conditions recorded at the visits (null: no environment sensor) (1.1)")

    @model_validator(mode="after")
    def _closure_from_abbe(self) -> AbbeAnalysis:
        if self.estimates.closure is not None and self.estimates.abbe is None:
            raise ValueError("estimates.closure is separated from the readings estimates.abbe analyses: abbe is missing")
        return self


class AbbeResults(AbbeAnalysis, RunResults):
    """results.json of the encoder Abbe-error method (seed 001)."""

    method: Literal["encoder_abbe_error"] = Field(description="the calibration method")
