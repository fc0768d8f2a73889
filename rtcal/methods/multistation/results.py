"""The multi-station method's part of results.json (seed 000): its estimates, truth, analysis and
results model, on the shared blocks of :mod:`rtcal.results.model` (the solvers' estimates among them)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from rtcal.api import Analysis, Arcsec, EnvironmentSummary, Estimate, NamedSet, RunResults, Truth
from rtcal.results.model import AxisLocation, ErrorMotionTarget, NetworkEstimate, PaperEstimate, SharedDeadPathEstimate

MultistationEstimator = Literal["paper", "shared_dead_path", "network"]
"""The method's estimator names (what ``recommended`` and ``solver_status`` may name)."""


class MultistationEstimates(NamedSet[Estimate]):
    """``estimates`` of the multi-station method: every estimator the procedure asked for that could run."""


    paper: PaperEstimate | None = Field(None, description="the printed method: one dead path per station")
    shared_dead_path: SharedDeadPathEstimate | None = Field(
        None, description="all stations solved together, one dead path per tracking segment")
    network: NetworkEstimate | None = Field(
        None, description="one adjustment of everything: stations on one circle, CMM points and geometry")


class StationTruth(Truth):
    """What the simulated stations really had (a simulated run only), signed as the estimates."""

    deviation_arcsec: list[Arcsec] = Field(description="true per-step deviation (systematic part), arcsec")
    realized_deviation_arcsec: list[Arcsec] = Field(
        description="true per-step deviation of the mean actual angle of every visit (includes the repeatability drawn), arcsec")
    positioning_error_arcsec: list[Arcsec] = Field(description="true εz (actual − commanded) per station, arcsec")


class MultistationAnalysis(Analysis):
    """The multi-station method's analysis."""

    recommended: MultistationEstimator | None = Field(
        description="the estimate to quote: converged, and the smallest uncertainty among those that did")
    estimates: MultistationEstimates = Field(description="every estimate that could run, by estimator")
    truth: StationTruth | None = Field(None, description="what the simulated stations really had (absent: on instruments)")
    environment: EnvironmentSummary | None = Field(
        description="the air and table conditions recorded with the lengths (null: no environment sensor)")
    axis_location: AxisLocation | None = Field(
        None, description="the axis's location errors X0C, Y0C, A0C, B0C from the network (absent: no network estimate) (1.2)")
    error_motions: list[ErrorMotionTarget] | None = Field(
        None, description="per target EXC, EYC, EAC, EBC with u, from a second tracer mount (absent: one mount) (1.2)")

    OPTIONAL_KEYS = Analysis.OPTIONAL_KEYS | {"axis_location", "error_motions"}


class MultistationResults(MultistationAnalysis, RunResults):
    """results.json of the laser-tracer multi-station method (seed 000)."""

    method: Literal["laser_tracer_multistation"] = Field(description="the calibration method")

    OPTIONAL_KEYS = RunResults.OPTIONAL_KEYS | MultistationAnalysis.OPTIONAL_KEYS
