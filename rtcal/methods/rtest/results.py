"""results.json of the R-test: the ISO 230-7 location errors of both rotary axes with U (``location_errors``, keyed
by the symbols a scenario states its truth with: X0C_um … C0A_arcsec), what the set-up cannot determine and why,
the nest calibration, the drift, the sphere path before and after compensation, and C's angular positioning
deviation per commanded angle and direction (the estimate ``rtest``, a quantity of its own in arcsec)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from rtcal import api

Symbol = Literal["X0C_um", "Y0C_um", "A0C_arcsec", "B0C_arcsec", "Y0A_um", "Z0A_um", "B0A_arcsec", "C0A_arcsec"]


class LocationError(api.ResultsModel):
    """One location error (ISO 230-7) as the R-test determined it, docs/rtest.md's signs."""

    axis: Literal["A", "C"] = Field(description="the rotary axis it locates")
    value: float = Field(description="the location error, in the unit its symbol names (µm or arcsec)")
    standard_uncertainty: float = Field(ge=0.0, description="u (k = 1), same unit")
    expanded_uncertainty: float = Field(ge=0.0, description="U = k·u, same unit")
    coverage_factor: float = Field(2.0, description="k")
    budget: dict[str, float] = Field(description="u per source (sensors, sphere form, nest calibration, linear axes, "
                                                 "nest zero, drift), same unit")


class NestCalibrationResult(api.ResultsModel):
    """The nest calibration: each sensor's effective direction (the nest matrix's rows) from seven positions."""

    matrix: list[list[float]] = Field(description="the nest matrix S (3 × 3): sensor reading µm per µm of the sphere "
                                                  "centre's displacement, machine frame")
    direction_u_deg: list[float] = Field(description="each sensor direction's standard uncertainty, deg")
    residual_rms_um: float = Field(ge=0.0, description="RMS of the calibration readings less the fit, µm")
    move_mm: float = Field(gt=0.0, description="the calibration's move along each axis, mm")


class SpherePath(api.ResultsModel):
    """|sphere centre − nest zero| per pose of the kinematic tests, µm: as measured (drift corrected, the sphere's
    set-up taken out) and what the compensated location errors leave."""

    a_deg: list[float] = Field(description="A per pose, deg")
    c_deg: list[float] = Field(description="C per pose, deg")
    before_um: list[float] = Field(description="|deviation| before compensation, µm")
    after_um: list[float] = Field(description="|deviation| after the eight location errors are compensated, µm")
    residual_um: list[float] = Field(description="|what the whole model leaves|, µm")


class SecondPosition(api.ResultsModel):
    """The sphere's second position (procedure's `sphere.second_position_mm`), its tests' own set-up and drift."""

    position_mm: list[float] = Field(description="where it was set up, machine coordinates at A = C = 0, mm")
    setup_um: list[float] = Field(description="where it really sat less where the path assumed it, x, y, z, µm")
    setup_u_um: list[float] = Field(description="their standard uncertainties, µm")
    drift_um: list[float] = Field(description="its repeated first pose less its first, x, y, z, µm (corrected linearly)")


class SphereUsed(api.ResultsModel):
    """The sphere as its certificate states it, and where it was set up."""

    OPTIONAL_KEYS = frozenset({"second"})

    radius_mm: float = Field(gt=0.0, description="radius, mm")
    form_um: float = Field(ge=0.0, description="form deviation, peak to valley, µm")
    certificate: str = Field(description="its certificate's number (empty: not stated)")
    position_mm: list[float] = Field(description="where it was set up, machine coordinates at A = C = 0, mm")
    second: SecondPosition | None = Field(None, description=(
        "its second position, when the procedure moved it there (absent: one position; `drift_um`, "
        "`sphere_setup_um` are the first position's)"))


class RTestEstimates(api.NamedSet[api.QuantityEstimate]):
    """``estimates`` of the R-test."""

    rtest: api.QuantityEstimate | None = Field(
        None, description="C's angular positioning deviation per commanded angle and direction, relative to the first "
                          "pose's, arcsec")


class RTestTruth(api.Truth):
    """What the simulated machine really had (a simulated run only)."""

    location_errors: dict[Symbol, float] = Field(description="the scenario's true location errors")


class RTestAnalysis(api.Analysis):
    recommended: Literal["rtest"] | None = Field(description="the estimate to quote")
    estimates: RTestEstimates = Field(description="C's positioning deviation")
    truth: RTestTruth | None = Field(None, description="what the simulated machine really had (absent: a real machine)")
    location_errors: dict[Symbol, LocationError] = Field(description=(
        "the location errors the set-up determines, by symbol (X0C_um, Y0C_um, A0C_arcsec, B0C_arcsec of C; Y0A_um, "
        "Z0A_um, B0A_arcsec, C0A_arcsec of A): value, u, U (k = 2), budget"))
    not_determined: dict[str, str] = Field(description="each location error this set-up cannot determine, and why")
    nest_calibration: NestCalibrationResult = Field(description="the nest calibration")
    drift_um: list[float] = Field(description="the repeated first pose less the first, x, y, z, µm (corrected linearly)")
    sphere_setup_um: list[float] = Field(description="where the sphere really sits less where the path assumed it, µm")
    sphere_setup_u_um: list[float] = Field(description="its standard uncertainty per axis, µm")
    sphere_path: SpherePath = Field(description="the sphere-centre deviation per pose before and after compensation")
    residual_test: api.ResidualTest | None = Field(None, description="the adjustment's χ² test")
    linearisation_um: float = Field(description="how far the linearised model alone would be from the exact one, µm")
    sphere: SphereUsed = Field(description="the sphere and its certificate")
    control_records: dict[str, dict[str, float]] = Field(description=(
        "per location-error format, the control's kinematics as commissioned (the procedure's, or derived from its "
        "`kinematics`): the record the compensation is written from"))


class RTestResults(RTestAnalysis, api.RunResults):
    """results.json of the R-test."""

    method: Literal["rtest"] = Field(description="the calibration method")
