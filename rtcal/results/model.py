"""The typed model of results.json: every block a run writes, with units, meanings and bounds.

A method's ``analyse`` returns its :class:`Analysis` (estimates, the recommended one, the
positioning deviations, the truth of a simulated run); the runner adds what it knows of the run
(:class:`RunInfo`) and of its log (:class:`RunLog`) and :func:`assemble` makes the method's
:class:`RunResults`. The fields' descriptions are the published JSON Schema's documentation
(`rtcal schema --results`); keys and meanings are those README's "Results" documents.

Every number is finite and bounded to what is physically meaningful (a deviation within
±10⁷″, a length within ±10⁷ mm, …): a tampered file is refused at the field, before any
consumer computes with it. A key that is absent when it does not apply (``truth`` of a run on
hardware, ``estimates.closure`` without a closure, …) is left out of the file, never null.
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar, Generic, Literal, TypeVar, get_args, get_origin

from pydantic import BaseModel, ConfigDict, Field, SerializerFunctionWrapHandler, model_serializer, model_validator

from rtcal.moved import moved

SCHEMA_VERSION = "1.8"
# the first schema_version whose files carry each digest: a file of that version or later without it
# was not written by rtcal (rtcal/run/integrity.py refuses it)
STORE_DIGESTS_SINCE = (1, 2)
DELIVERABLE_DIGESTS_SINCE = (1, 3)
SCHEMA_WRITTEN_SINCE: tuple[tuple[tuple[int, int, int], tuple[int, int]], ...] = ((0, 2, 0), (1, 4)),
"""(rtcal release, the schema_version it and every later release writes at least): a file that claims
a release and an older schema had its schema_version set back by hand (rtcal/run/integrity.py). Releases
before the first entry wrote 1.0 to 1.3 under one version number, 0.1.0, and are not told apart."""

# -- bounded numbers ------------------------------------------------------------------------------
Arcsec = Annotated[float, Field(ge=-1e7, le=1e7)]
"""An angle of deviation, arcsec (±10⁷″ ≈ ±2778°: far beyond any table)."""
SigmaArcsec = Annotated[float, Field(ge=0.0, le=1e7)]
"""A standard (or expanded) uncertainty, arcsec."""
Arcsec2 = Annotated[float, Field(ge=-1e14, le=1e14)]
"""A covariance, arcsec²."""
Deg = Annotated[float, Field(ge=-1e6, le=1e6)]
"""A commanded or table angle, degrees."""
Mm = Annotated[float, Field(ge=-1e7, le=1e7)]
"""A length or coordinate, mm."""
Um = Annotated[float, Field(ge=-1e9, le=1e9)]
"""A small length, µm."""
Number = Annotated[float, Field(ge=-1e12, le=1e12)]
"""Any other finite quantity (its unit in its name or description)."""
Parameter = Annotated[float, Field(ge=-1e9, le=1e9)]
"""An evaluated parameter (a span of deviations), arcsec."""
Seconds = Annotated[float, Field(ge=-1e10, le=1e10)]
"""A time, s."""
Count = Annotated[int, Field(ge=0, le=1_000_000_000)]
RunNumber = Annotated[int, Field(ge=1, le=1_000_000)]
Direction = Literal[1, -1]
Text = Annotated[str, Field(max_length=100_000)]
Name = Annotated[str, Field(max_length=1_000)]

EstimatorName = Annotated[str, Field(pattern=r"^[a-z][a-z0-9_]{0,63}$")]
"""An estimator's name, as its method declares it (a method's results narrow ``recommended`` and ``solver_status``
to its own names: rtcal/methods/<method>/results.py, a plugin's results model)."""
EstimatorKey = EstimatorName
"""An estimator's name as a key (``solver_status``)."""


class ResultsModel(BaseModel):
    """A block of results.json: known keys only, finite numbers, not changed once made.

    ``OPTIONAL_KEYS`` names the fields that are left out of the file when they are None (a key
    that does not apply), as against a null the file always carries (a value that is missing).
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True, defer_build=True)
    OPTIONAL_KEYS: ClassVar[frozenset[str]] = frozenset()

    @model_serializer(mode="wrap")
    def _leave_out_absent(self, handler: SerializerFunctionWrapHandler) -> Any:
        data = handler(self)
        if isinstance(data, dict):
            for key in self.OPTIONAL_KEYS:
                if data.get(key, 0) is None:
                    del data[key]
        return data


V = TypeVar("V")


class NamedSet(ResultsModel, Generic[V]):
    """A block whose keys are a fixed set of names, each present only when it applies."""

    @classmethod
    def __pydantic_init_subclass__(cls, **kwargs: Any) -> None:
        super().__pydantic_init_subclass__(**kwargs)
        cls.OPTIONAL_KEYS = frozenset(cls.model_fields)

    def items(self) -> list[tuple[str, V]]:
        """The present entries, in the file's order."""
        return [(name, getattr(self, name)) for name in type(self).model_fields if getattr(self, name) is not None]

    def named(self, name: str) -> V | None:
        """The entry called ``name``, if present."""
        return getattr(self, name, None) if name in type(self).model_fields else None

    def names(self) -> list[str]:
        return [name for name, _ in self.items()]


# -- the uncertainty budget and the block every estimate shares ------------------------------------
class BudgetSource(ResultsModel):
    """What one source of an uncertainty budget is (its contribution per target is the budget's own: in arcsec for
    an angular estimate, in the result's unit for a :class:`QuantityEstimate`)."""

    source: Text = Field(description="what the source is (e.g. `tracer length noise`)")
    type: Literal["A", "B"] = Field(description="GUM type: A estimated from the readings, B as the procedure states it")
    input_sigma: Number = Field(description="the source's standard uncertainty (1σ) in `unit`")
    unit: Name = Field(description="unit of `input_sigma` (e.g. `µm`, `″`, `ppm`; several inputs: listed in `note`)")
    estimated_from_data: bool = Field(description="true when `input_sigma` was estimated from this run's readings")
    note: Text = Field(description="what the source covers, or its several inputs")


class BudgetComponent(BudgetSource):
    """One source of the GUM uncertainty budget of an angular estimate."""

    contribution_arcsec: list[SigmaArcsec | None] = Field(
        description="its contribution to the standard uncertainty per target, arcsec (null: not defined)")


class UncertaintyBudget(ResultsModel):
    """The GUM table of an estimate's cumulative deviation."""

    components: list[BudgetComponent] = Field(description="per source: type, input σ and contribution per target")
    combined_arcsec: list[SigmaArcsec | None] = Field(description="combined standard uncertainty u per target, arcsec")
    expanded_arcsec: list[SigmaArcsec | None] = Field(description="expanded uncertainty U = k·u per target, arcsec")
    coverage_factor: Annotated[float, Field(gt=0.0, le=10.0)] = Field(description="k of the expanded uncertainty (2)")
    not_included: list[Text] = Field(description="sources the procedure did not state: the budget is silent on them")


class DeviationBlock(ResultsModel):
    """The keys every estimate has: the cumulative positioning deviation ECC with its u, U,
    covariance and budget, and its per-step differences with their u."""

    deviation_arcsec: list[Arcsec | None] = Field(
        description="per-step differences of the cumulative deviation (seed 000's eq. 33 Δθ), arcsec")
    uncertainty_arcsec: list[SigmaArcsec | None] = Field(
        description="standard uncertainty (1σ) of each per-step difference, arcsec, from the same covariance")
    cumulative_deviation_arcsec: list[Arcsec | None] = Field(
        description="the positioning deviation ECC: actual − commanded angle relative to the first target (0 at the "
                    "first), arcsec; positive: the table turned further than commanded")
    cumulative_uncertainty_arcsec: list[SigmaArcsec | None] = Field(
        description="standard uncertainty u (1σ) of the cumulative deviation per target, arcsec")
    cumulative_expanded_uncertainty_arcsec: list[SigmaArcsec | None] = Field(
        description="expanded uncertainty U (k = 2) of the cumulative deviation per target, arcsec")
    cumulative_covariance_arcsec2: list[list[Arcsec2 | None]] = Field(
        description="covariance of the cumulative deviation, target × target, arcsec²")
    uncertainty_budget: UncertaintyBudget = Field(description="the GUM budget of the cumulative deviation")

    @model_validator(mode="after")
    def _one_row_per_target(self) -> DeviationBlock:
        n = len(self.cumulative_deviation_arcsec)
        if len(self.cumulative_uncertainty_arcsec) != n or len(self.cumulative_expanded_uncertainty_arcsec) != n:
            raise ValueError(f"the cumulative deviation has {n} targets; its u and U must have as many")
        if len(self.cumulative_covariance_arcsec2) != n or any(len(row) != n for row in self.cumulative_covariance_arcsec2):
            raise ValueError(f"the covariance must be {n} × {n} (one row and column per target)")
        if len(self.uncertainty_arcsec) != len(self.deviation_arcsec):
            raise ValueError("deviation_arcsec and uncertainty_arcsec must have as many values")
        return self


class ResidualTest(ResultsModel):
    """The estimator's residuals against its own stated noise model (1.2)."""

    chi2: Annotated[float, Field(ge=0.0)] = Field(description="χ² of the residuals under the stated noise")
    dof: Annotated[int, Field(ge=1)] = Field(description="its degrees of freedom")
    birge_ratio: Annotated[float, Field(ge=0.0)] = Field(description="√(χ²/dof): 1 when the noise is as stated")
    p_value: Annotated[float, Field(ge=0.0, le=1.0)] = Field(description="probability of a χ² this large under the model")
    passed: bool = Field(description="false: residuals the model cannot explain (against the whole budget, with each "
                                     "stated source of few inputs also scored on its own; together a 1 % false-alarm rate); a "
                                     "recommended estimate that failed is still the one quoted, and the certificate says "
                                     "its U is not a coverage interval and why")


class Estimate(DeviationBlock):
    """An estimator's result: the deviation block and how the solver ended."""

    converged: bool = Field(description="whether the solver converged (a linear estimate always does)")
    message: Text = Field(description="how the solver ended, in words")
    residual_test: ResidualTest | None = Field(None, description="its residuals against its stated noise model (1.2; "
                                                                 "none where it has nothing to test)")


class TargetedEstimate(Estimate):
    """An estimate on targets approached from either side (seed 001: target and direction per row)."""

    target_deg: list[Deg] = Field(description="commanded angle of each target, degrees, in the order of the cumulative deviation")
    target_direction: list[Direction] = Field(description="approach of each target: 1 positive (↑), −1 negative (↓)")

    @model_validator(mode="after")
    def _targets_match(self) -> TargetedEstimate:
        n = len(self.cumulative_deviation_arcsec)
        if len(self.target_deg) != n or len(self.target_direction) != n:
            raise ValueError(f"target_deg and target_direction must have one value per target ({n})")
        return self


SigmaNumber = Annotated[float, Field(ge=0.0, le=1e12)]
"""A standard (or expanded) uncertainty of any other quantity (its unit given beside it)."""


class QuantityComponent(BudgetSource):
    """One source of a :class:`QuantityEstimate`'s uncertainty budget, its contribution in the result's unit."""

    contribution: list[SigmaNumber | None] = Field(
        description="its contribution to the standard uncertainty per target, in the result's `unit` (null: not defined)")


class QuantityEstimate(ResultsModel):
    """An estimate of a quantity of its own per target and direction — a runout in µm, a location in mm —, as a
    method declares it: its ``quantity`` in words and its ``unit``, the values with their standard and
    expanded uncertainty and budget. Not an angular positioning deviation: no ISO 230-2 evaluation,
    conformity or compensation follows from it (a method's own results model; the built-in methods' files hold none)."""

    quantity: Name = Field(description="what is estimated, in words (e.g. `radial displacement of the test ball`)")
    unit: Name = Field(description="the unit of every value and uncertainty (e.g. `µm`)")
    target_deg: list[Deg] = Field(description="commanded angle of each target, degrees")
    target_direction: list[Direction] = Field(description="approach of each target: 1 positive (↑), −1 negative (↓)")
    value: list[Number | None] = Field(description="the estimate per target, in `unit` (null: not measured)")
    standard_uncertainty: list[SigmaNumber | None] = Field(description="its standard uncertainty u (1σ) per target")
    expanded_uncertainty: list[SigmaNumber | None] = Field(description="its expanded uncertainty U = k·u per target")
    coverage_factor: Annotated[float, Field(gt=0.0, le=10.0)] = Field(description="k of the expanded uncertainty (2)")
    budget: list[QuantityComponent] = Field(description="per source: type, input σ and contribution per target")
    not_included: list[Text] = Field(description="sources the procedure did not state: the budget is silent on them")
    converged: bool = Field(description="whether the estimator converged (a mean always does)")
    message: Text = Field(description="how the estimator ended, in words")

    @model_validator(mode="after")
    def _one_value_per_target(self) -> QuantityEstimate:
        n = len(self.target_deg)
        for name in ("target_direction", "value", "standard_uncertainty", "expanded_uncertainty"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"{name} has {len(getattr(self, name))} values, target_deg {n}")
        if any(len(c.contribution) != n for c in self.budget):
            raise ValueError(f"each budget contribution has one value per target ({n})")
        return self


# -- the multi-station method (seed 000) --------------------------------------------------------------
class EstimatedNoise(ResultsModel):
    """Noise sizes the estimator found in the readings (Type A)."""

    tracer_length_noise_um_at_1m: Um = Field(description="laser tracer length noise (1σ) at 1 m, µm")
    cmm_point_noise_um: Um = Field(description="CMM point noise (1σ) per coordinate, µm")


class Plane(ResultsModel):
    """The stations' best-fit plane a·x + b·y + c·z = e (eq. 20–24): (a, b, c) its unit normal, e mm."""

    a: Number = Field(description="x component of the plane's unit normal")
    b: Number = Field(description="y component of the plane's unit normal")
    c: Number = Field(description="z component of the plane's unit normal")
    e: Number = Field(description="the plane's distance term, mm")


class StationChainEstimate(Estimate):
    """What the station-based estimators share: stations → plane → circle → angles (eq. 20–36)."""

    eq34_sigma_arcsec: SigmaArcsec = Field(
        description="seed 000's eq. 34 σΔθ: the paper's statistic of the deviations, not an uncertainty, arcsec")
    algorithm_error_arcsec: Arcsec = Field(description="eq. 36: the algorithm's closure error, arcsec")
    estimated_noise: EstimatedNoise = Field(description="noise sizes estimated from the readings")
    plane: Plane = Field(description="the stations' best-fit plane")
    projected_stations_mm: list[list[Mm]] = Field(description="each station projected on the plane, X, Y, Z in mm")
    center_mm: list[Mm] = Field(description="centre of the stations' circle, X, Y, Z in mm")


class PaperEstimate(StationChainEstimate):
    """``estimates.paper``: the printed method, one dead path per station."""

    stations_mm: list[list[Mm]] = Field(description="per station its self-calibrated centre and dead path: X, Y, Z, d in mm")
    station_rms_residual_um: list[Um] = Field(description="RMS length residual of each station's fit, µm")
    station_iterations: list[Count] = Field(description="Levenberg–Marquardt iterations of each station's fit")
    notes: list[Text] = Field(description="where the printed equations and the paper's figures differ, and caveats")


class SharedDeadPathEstimate(StationChainEstimate):
    """``estimates.shared_dead_path``: all stations together, one dead path per tracking segment."""

    stations_mm: list[list[Mm]] = Field(description="station centres, X, Y, Z in mm")
    dead_paths_mm: dict[Annotated[str, Field(pattern=r"^[0-9]{1,9}$")], Mm] = Field(
        description="dead path of each uninterrupted tracking segment (keyed by segment number), mm")
    rms_residual_um: Um = Field(description="RMS length residual, µm")


class CmmError(ResultsModel):
    """One CMM geometry parameter found by the network adjustment."""

    value: Number = Field(description="the parameter's value, in the unit its name ends with (ppm or arcsec)")
    sigma: Number | None = Field(description="its standard uncertainty (1σ), same unit; null: not determined")


class CmmErrors(NamedSet[CmmError]):
    """The CMM's scale and squareness errors, checked against the traceable tracer lengths."""

    scale_x_ppm: CmmError = Field(description="scale error of the X axis, ppm")
    scale_y_ppm: CmmError = Field(description="scale error of the Y axis, ppm")
    scale_z_ppm: CmmError = Field(description="scale error of the Z axis, ppm")
    squareness_xy_arcsec: CmmError = Field(description="squareness error between X and Y, arcsec")
    squareness_xz_arcsec: CmmError = Field(description="squareness error between X and Z, arcsec")
    squareness_yz_arcsec: CmmError = Field(description="squareness error between Y and Z, arcsec")


class ErrorMotions(ResultsModel):
    """The table's synchronous error motions per station, separated by a second tracer mount."""

    note: Text = Field(description="what is and is not seen of the error motions")
    EXC_um: list[Um] = Field(description="radial error motion EXC per station, µm")
    EYC_um: list[Um] = Field(description="radial error motion EYC per station, µm")
    EXC_sigma_um: list[Um] = Field(description="standard uncertainty (1σ) of EXC per station, µm")
    EYC_sigma_um: list[Um] = Field(description="standard uncertainty (1σ) of EYC per station, µm")
    tilt_arcsec: list[Arcsec] = Field(description="the visible tilt error motion per station, arcsec")
    tilt_sigma_arcsec: list[Arcsec] = Field(description="standard uncertainty (1σ) of the tilt per station, arcsec")
    tilt_axis_deg: list[Deg] = Field(description="direction of the axis the visible tilt is about, per station, degrees")
    mounts_mm: list[list[Mm]] = Field(description="the tracer mounts' positions, X, Y, Z in mm")


class NetworkEstimate(Estimate):
    """``estimates.network``: one adjustment of axis, radius, station angles, dead paths, the CMM's
    geometry and the CMM points as weighted observations."""

    OPTIONAL_KEYS = frozenset({"error_motions"})

    estimated_noise: EstimatedNoise = Field(description="noise sizes estimated from the readings")
    cmm_errors: CmmErrors = Field(description="the CMM's scales and squarenesses (the CMM checked as a by-product)")
    axis_point_mm: list[Mm] = Field(description="a point on the rotation axis, X, Y, Z in mm")
    axis_direction: list[Number] = Field(description="the rotation axis' unit direction (x, y, z)")
    radius_mm: Mm = Field(description="radius of the stations' circle, mm")
    stations_mm: list[list[Mm]] = Field(description="station centres, X, Y, Z in mm")
    dead_paths_mm: dict[Annotated[str, Field(pattern=r"^[0-9]{1,9}$")], Mm] = Field(
        description="dead path of each uninterrupted tracking segment (keyed by segment number), mm")
    rms_length_residual_um: Um = Field(description="RMS length residual, µm")
    rms_point_residual_um: Um = Field(description="RMS residual of the CMM points against their reported positions, µm")
    error_motions: ErrorMotions | None = Field(
        None, description="error motions separated by a second tracer mount (only with `second_mount:`)")


SigmaMm = Annotated[float, Field(ge=0.0, le=1e7)]
SigmaUm = Annotated[float, Field(ge=0.0, le=1e9)]

AXIS_CONVENTION = (
    "CMM frame; X0C, Y0C: where the axis average line crosses z = 0; with n the axis direction (pointing up), "
    "A0C = −atan(n_y/n_z) and B0C = atan(n_x/n_z): the right-hand rotations about X and Y that carry +Z onto n")


class AxisLocation(ResultsModel):
    """The rotary axis's location errors (ISO 230-1/230-7 X0C, Y0C, A0C, B0C) from the network's axis line,
    each with its standard uncertainty u (1σ) (1.2)."""

    frame: Text = Field(description="the frame and convention of the values (" + AXIS_CONVENTION + ")")
    x0c_mm: Mm = Field(description="X0C: X where the axis average line crosses z = 0, CMM frame, mm")
    x0c_mm_u: SigmaMm = Field(description="standard uncertainty (1σ) of X0C, mm")
    y0c_mm: Mm = Field(description="Y0C: Y where the axis average line crosses z = 0, CMM frame, mm")
    y0c_mm_u: SigmaMm = Field(description="standard uncertainty (1σ) of Y0C, mm")
    a0c_arcsec: Arcsec = Field(description="A0C = −atan(n_y/n_z): the axis's squareness about X, arcsec")
    a0c_arcsec_u: SigmaArcsec = Field(description="standard uncertainty (1σ) of A0C, arcsec")
    b0c_arcsec: Arcsec = Field(description="B0C = atan(n_x/n_z): the axis's squareness about Y, arcsec")
    b0c_arcsec_u: SigmaArcsec = Field(description="standard uncertainty (1σ) of B0C, arcsec")


class ErrorMotionTarget(ResultsModel):
    """The table's synchronous error motions at one target (ISO 230-7), separated by a second tracer mount:
    the mean (the location) and the once-per-turn part that turns with the table removed (1.2)."""

    target_deg: Deg = Field(description="commanded angle of the target, degrees")
    exc_um: Um = Field(description="EXC: radial error motion in X at the mounts' plane, µm")
    exc_um_u: SigmaUm = Field(description="standard uncertainty (1σ) of EXC, µm")
    eyc_um: Um = Field(description="EYC: radial error motion in Y at the mounts' plane, µm")
    eyc_um_u: SigmaUm = Field(description="standard uncertainty (1σ) of EYC, µm")
    eac_arcsec: Arcsec = Field(description="EAC: tilt error motion about X (right-hand), arcsec")
    eac_arcsec_u: SigmaArcsec = Field(description="standard uncertainty (1σ) of EAC, arcsec (the tilt about the line "
                                                  "joining the mounts is not seen: its part is the stated bound's)")
    ebc_arcsec: Arcsec = Field(description="EBC: tilt error motion about Y (right-hand), arcsec")
    ebc_arcsec_u: SigmaArcsec = Field(description="standard uncertainty (1σ) of EBC, arcsec (as EAC's)")


class Truth(ResultsModel):
    """What the simulated bench really had (a simulated run only), signed as the estimates."""

    cumulative_deviation_arcsec: list[Arcsec] = Field(
        description="true εz at the targets relative to the first target, arcsec (what the estimates' ECC estimates)")


class Range(ResultsModel):
    """The range of one recorded condition over the run."""

    min: Number = Field(description="smallest reading")
    max: Number = Field(description="largest reading")
    mean: Number = Field(description="mean of the readings")


class EnvironmentSummary(NamedSet[Range]):
    """The conditions the environment sensor recorded during the measurement."""


    air_temperature_c: Range | None = Field(None, description="air temperature, °C")
    air_pressure_pa: Range | None = Field(None, description="air pressure, Pa")
    humidity_pct: Range | None = Field(None, description="relative humidity, %")
    material_temperature_c: Range | None = Field(None, description="the table's (material) temperature, °C")
    mount_temperature_c: Range | None = Field(
        None, description="the tracer's mount's temperature (a second probe), °C")


# -- the encoder Abbe-error method (seed 001) ---------------------------------------------------------
class HarmonicTerm(ResultsModel):
    """One order of a harmonic fit: value(θ) = Σ amplitude · sin(order·θ + phase)."""

    order: Annotated[int, Field(ge=1, le=100_000)] = Field(description="harmonic order, per revolution")
    amplitude: Number = Field(description="amplitude, in the unit of the series (arcsec or µm)")
    amplitude_sigma: Number = Field(description="standard uncertainty (1σ) of the amplitude")
    phase_deg: Deg = Field(description="phase, degrees")
    phase_sigma_deg: Annotated[float, Field(ge=0.0, le=1e300)] = Field(
        description="standard uncertainty (1σ) of the phase, degrees (huge when the amplitude is near 0: phase undetermined)")
    significant: bool = Field(description="above the family-wise 1 % threshold, the resolution and what rounding produces")
    threshold: Number = Field(description="amplitude above which this order counts as significant")
    aliased: bool = Field(description="the Nyquist order: only |A·sin φ| is seen, the phase is unknown")
    not_separable_from: list[Annotated[int, Field(ge=1, le=100_000)]] | None = Field(
        None, description="unmodelled orders that, fitted beside it, take its share of the data: the targets cannot "
                          "tell them apart, so the order is not reported significant (absent: separable or not tested)")

    OPTIONAL_KEYS: ClassVar[frozenset[str]] = frozenset({"not_separable_from"})


class HarmonicSeries(NamedSet[list[HarmonicTerm]]):
    """Harmonic fits of the per-step series (a series is absent when no order could be resolved)."""

    positioning_error_arcsec: list[HarmonicTerm] | None = Field(None, description="εz against the reference, arcsec")
    encoder_vs_command_arcsec: list[HarmonicTerm] | None = Field(None, description="encoder − command, arcsec")
    measured_encoder_error_arcsec: list[HarmonicTerm] | None = Field(None, description="measured encoder error, arcsec")
    predicted_encoder_error_arcsec: list[HarmonicTerm] | None = Field(None, description="predicted encoder error, arcsec")
    residual_arcsec: list[HarmonicTerm] | None = Field(None, description="measured − predicted encoder error, arcsec")
    tilt_x_arcsec: list[HarmonicTerm] | None = Field(None, description="tilt εx of the shaft, arcsec")
    radial_y_um: list[HarmonicTerm] | None = Field(None, description="radial motion δy of the shaft, µm")


class HarmonicWarnings(NamedSet[list[Text]]):
    """Per series, what the sampling cannot resolve (absent: nothing to say)."""

    positioning_error_arcsec: list[Text] | None = Field(None, description="warnings of the εz series")
    encoder_vs_command_arcsec: list[Text] | None = Field(None, description="warnings of the encoder − command series")
    measured_encoder_error_arcsec: list[Text] | None = Field(None, description="warnings of the measured encoder error")
    predicted_encoder_error_arcsec: list[Text] | None = Field(None, description="warnings of the predicted encoder error")
    residual_arcsec: list[Text] | None = Field(None, description="warnings of the residual series")
    tilt_x_arcsec: list[Text] | None = Field(None, description="warnings of the tilt series")
    radial_y_um: list[Text] | None = Field(None, description="warnings of the radial motion series")


class AbbeEstimate(TargetedEstimate):
    """``estimates.abbe``: εz against the autocollimator and polygon, and seed 001's encoder analysis per step."""

    random_error_from: Text = Field(description="where the per-visit random error of the reference comes from")
    angle_deg: list[Deg] = Field(description="commanded angle of each step, degrees")
    direction: list[Direction] = Field(description="approach of each step: 1 positive, −1 negative")
    tilt_x_arcsec: list[Arcsec | None] = Field(description="tilt εx of the shaft per step (dial indicators), arcsec")
    radial_y_um: list[Um | None] = Field(description="radial motion δy of the shaft per step, µm")
    predicted_encoder_error_arcsec: list[Arcsec | None] = Field(
        description="encoder error predicted from tilt and radial motion, (δy + Zs·εx)/rE, per step, arcsec")
    predicted_encoder_error_sigma_arcsec: list[SigmaArcsec | None] = Field(description="its 1σ per step, arcsec")
    measured_encoder_error_arcsec: list[Arcsec | None] = Field(
        description="encoder − reference per step (mean over the faces removed), arcsec")
    measured_encoder_error_sigma_arcsec: list[SigmaArcsec | None] = Field(description="its 1σ per step, arcsec")
    residual_arcsec: list[Arcsec | None] = Field(description="measured − predicted encoder error per step, arcsec")
    residual_sigma_arcsec: list[SigmaArcsec | None] = Field(description="its 1σ per step, arcsec")
    positioning_error_arcsec: list[Arcsec | None] = Field(
        description="εz (actual − commanded) per step, relative to the first target of the first direction, arcsec")
    positioning_error_sigma_arcsec: list[SigmaArcsec | None] = Field(description="its 1σ per step, arcsec")
    encoder_vs_command_arcsec: list[Arcsec | None] = Field(description="encoder reading − command per step, arcsec")
    residual_rms_arcsec: SigmaArcsec | None = Field(description="RMS of the residual, arcsec (null: no residual)")
    reversal_arcsec: Arcsec | None = Field(description="reversal ↑ − ↓ from the encoder, arcsec (null: one direction)")
    reversal_reference_arcsec: Arcsec | None = Field(
        description="reversal ↑ − ↓ from the autocollimator, arcsec (null: one direction)")
    repeatability_arcsec: SigmaArcsec | None = Field(
        description="repeatability of εz over the runs (pooled 1σ), arcsec (null: one run)")
    extrapolation_factor: Number = Field(description="a = (Zs − L1)/(L2 − L1): how the indicators extrapolate to the grating")
    face_errors_used_arcsec: list[Arcsec | None] = Field(description="the polygon's face errors the analysis used, arcsec")
    polygon_source: Literal["certificate", "closure"] = Field(description="where the face errors come from")
    harmonics: HarmonicSeries = Field(description="harmonic analysis of the per-step series")
    harmonic_warnings: HarmonicWarnings = Field(description="what the sampling cannot resolve, per series")
    notes: list[Text] = Field(description="the model's assumptions and sign conventions")


# -- what every run has ----------------------------------------------------------------------------
class SolverStatus(ResultsModel):
    """How one estimator ended."""

    status: Literal["converged", "not converged", "failed"] = Field(
        description="`converged`; `not converged` (results kept, flagged); `failed` (could not run, no results)")
    message: Text = Field(description="the solver's message, or why it could not run")


class DeviationTable(ResultsModel):
    """``positioning_deviations``: the table every method hands downstream, one row per
    (target, direction, run); evaluation, compensation and comparison read only this."""

    estimator: Name = Field(description="the estimate the rows come from (the recommended one)")
    target_deg: list[Deg] = Field(description="commanded angle of each row, degrees")
    direction: list[Direction] = Field(description="approach of each row: 1 positive (↑), −1 negative (↓)")
    run: list[RunNumber] = Field(description="run number of each row, from 1")
    deviation_arcsec: list[Arcsec | None] = Field(
        description="deviation x = actual − target, arcsec, relative to the first target of the first direction (null: no reading)")
    uncertainty_arcsec: list[SigmaArcsec | None] = Field(description="its standard uncertainty u (1σ), arcsec (null: unknown)")
    notes: list[Text] = Field(description="what the rows are")

    @model_validator(mode="after")
    def _same_rows(self) -> DeviationTable:
        n = len(self.target_deg)
        for name in ("direction", "run", "deviation_arcsec", "uncertainty_arcsec"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"{name} has {len(getattr(self, name))} rows, target_deg {n}")
        return self


class MinMax(ResultsModel):
    """The fewest and most approaches of a target in one direction."""

    min: Count = Field(description="fewest approaches of a target")
    max: Count = Field(description="most approaches of a target")


class RunsPerDirection(ResultsModel):
    """Approaches per target in each direction."""

    up: MinMax = Field(description="positive approach (↑)")
    down: MinMax = Field(description="negative approach (↓)")


class StandardEvaluation(ResultsModel):
    """What every evaluation states of the table it evaluated."""

    standard: Literal["iso230-2", "iso230-2:1988", "vdi3441"] = Field(description="the standard evaluated")
    unit: Literal["arcsec"] = Field(description="unit of every parameter")
    targets: Count = Field(description="number of targets")
    runs_per_direction: RunsPerDirection = Field(description="approaches per target and direction")
    runs: list[RunNumber] = Field(description="the run numbers in the table")


class IsoTarget(ResultsModel):
    """ISO 230-2 statistics of one target, arcsec (null: not defined)."""

    target_deg: Deg = Field(description="the target, degrees")
    mean_up: Parameter | None = Field(description="mean deviation x̄↑")
    mean_down: Parameter | None = Field(description="mean deviation x̄↓")
    mean: Parameter | None = Field(description="mean bidirectional deviation x̄ = (x̄↑ + x̄↓)/2")
    B_i: Parameter | None = Field(description="reversal value B_i = x̄↑ − x̄↓")
    s_up: Parameter | None = Field(description="estimator of the standard uncertainty s↑")
    s_down: Parameter | None = Field(description="estimator of the standard uncertainty s↓")
    R_up_i: Parameter | None = Field(description="unidirectional repeatability R_i↑")
    R_down_i: Parameter | None = Field(description="unidirectional repeatability R_i↓")
    R_i: Parameter | None = Field(description="bidirectional repeatability R_i")
    n_up: Count = Field(description="approaches ↑")
    n_down: Count = Field(description="approaches ↓")


class Iso230Evaluation(StandardEvaluation):
    """ISO 230-2 parameters of the positioning deviations, arcsec (null: not defined; `notes` say why)."""

    E_up: Parameter | None = Field(description="E↑: unidirectional systematic positional deviation, positive approach")
    E_down: Parameter | None = Field(description="E↓: unidirectional systematic positional deviation, negative approach")
    E: Parameter | None = Field(description="E: bidirectional systematic positional deviation")
    M: Parameter | None = Field(description="M: range of the mean bidirectional positional deviation")
    B: Parameter | None = Field(description="B: reversal value, max |B_i|")
    B_mean: Parameter | None = Field(description="B mean: mean reversal value")
    R_up: Parameter | None = Field(description="R↑: unidirectional repeatability, positive")
    R_down: Parameter | None = Field(description="R↓: unidirectional repeatability, negative")
    R: Parameter | None = Field(description="R: bidirectional repeatability")
    A_up: Parameter | None = Field(description="A↑: unidirectional accuracy, positive")
    A_down: Parameter | None = Field(description="A↓: unidirectional accuracy, negative")
    A: Parameter | None = Field(description="A: bidirectional accuracy")
    per_target: list[IsoTarget] = Field(description="per target its statistics")
    notes: list[Text] = Field(description="what is undefined and why, and what is not confirmed")


class VdiTarget(ResultsModel):
    """VDI/DGQ 3441 statistics of one target, arcsec (null: not defined)."""

    target_deg: Deg = Field(description="the target, degrees")
    mean: Parameter | None = Field(description="mean deviation x̄ of the target")
    U_j: Parameter | None = Field(description="reversal span |x̄↑ − x̄↓|")
    Ps_j: Parameter | None = Field(description="positional scatter 6·(s↑ + s↓)/2")
    n_up: Count = Field(description="approaches ↑")
    n_down: Count = Field(description="approaches ↓")


class VdiEvaluation(StandardEvaluation):
    """VDI/DGQ 3441 parameters of the positioning deviations, arcsec (null: not defined)."""

    Pa: Parameter | None = Field(description="Pa: position deviation")
    P: Parameter | None = Field(description="P: position uncertainty")
    Ps_max: Parameter | None = Field(description="Ps max: positional scatter, largest")
    Ps_mean: Parameter | None = Field(description="Ps mean: positional scatter, mean")
    U_max: Parameter | None = Field(description="U max: reversal span, largest")
    U_mean: Parameter | None = Field(description="U mean: reversal span, mean")
    per_target: list[VdiTarget] = Field(description="per target its statistics")
    notes: list[Text] = Field(description="what is undefined and why, and what is not confirmed")


class Evaluation(ResultsModel):
    """The positioning deviations evaluated as a certificate lists them."""

    iso230_2: Iso230Evaluation = Field(description="ISO 230-2 (1997/2006/2014) parameters")
    vdi3441: VdiEvaluation = Field(description="VDI/DGQ 3441 parameters")


class Event(ResultsModel):
    """One entry of the run's log: a fault, what was done about it, a reference, a resume, …"""

    t_s: Seconds = Field(description="time since the run started (the clock of `clock`), s")
    kind: Name = Field(description="what happened (e.g. `fault`, `retry`, `reacquire`, `skip`, `pause`, `resume`)")
    instrument: Name | None = Field(description="the instrument concerned (null: none)")
    message: Text = Field(description="what happened, in words")


class ProcedureRef(ResultsModel):
    """The procedure the run followed."""

    OPTIONAL_KEYS = frozenset({"standards"})

    name: Name = Field(description="the procedure's title")
    path: Text = Field(description="the procedure file the run started from")
    standards: list[Annotated[str, Field(pattern=r"^[a-z0-9.:-]{1,40}$")]] | None = Field(
        None, max_length=20, description="the labels of the standards whose figures the certificate states besides ISO "
                                         "230-2 and VDI 3441 (the procedure's `evaluation.standards`; absent: none) (1.4)")


class InstrumentRecord(ResultsModel):
    """An instrument as the certificate names it."""

    id: Name = Field(description="make, model and serial number")
    calibration_due: Name = Field(description="its calibration due date (YYYY-MM-DD), or empty")
    certificate_number: Name = Field("", description="the number of its own calibration certificate, or empty (1.1)")
    calibrated_by: Name = Field("", description="who issued that certificate (laboratory, accreditation), or empty (1.1)")


class RunMetadata(ResultsModel):
    """Who and what the calibration is for (the procedure's `metadata:`)."""

    customer: Name = Field(description="the customer")
    machine: Name = Field(description="the machine")
    axis: Name = Field(description="the axis calibrated")
    serial_number: Name = Field(description="the machine's or table's serial number")
    location: Name = Field(description="where it was calibrated")
    operator: Name = Field(description="who calibrated it")
    certificate_number: Name = Field(description="the certificate's number")
    instruments: dict[Name, InstrumentRecord] = Field(description="per instrument and reference standard (polygon): its "
                                                      "id, calibration due date and certificate")
    laboratory: Name = Field("", description="the calibration laboratory and its accreditation (1.1)")
    laboratory_address: Name = Field("", description="the laboratory's address (1.1)")
    customer_address: Name = Field("", description="the customer's address (1.1)")
    date_of_issue: Name = Field("", description="the certificate's date of issue, YYYY-MM-DD (empty: the day the report "
                                                "was written) (1.1)")
    performed_by: Name = Field("", description="who performed the calibration (empty: `operator`) (1.1)")
    approved_by: Name = Field("", description="who authorised the certificate for issue (1.1)")
    traceability: Text = Field("", description="the traceability statement (empty: made from the reference standards' "
                                               "certificates) (1.1)")
    condition_on_receipt: Text = Field("", description="the item's condition on receipt, as the laboratory recorded it "
                                                       "(empty: not recorded) (1.2)")
    item_state: Literal["", "as_found", "as_left"] = Field(
        "", description="what the run measured: `as_found` (before any adjustment), `as_left` (after it), empty: not "
                        "said (1.5)")
    replaces: Name = Field("", description="the number of the certificate this one replaces, or empty (1.5)")


class Simulation(ResultsModel):
    """A run that measured no real item, or rehearsed one: every page of its certificate says so, and
    `rtcal catalog add` refuses it unless told (1.4)."""

    in_process: bool = Field(description="every instrument and the table simulated in this process on a model bench")
    simulators: dict[Name, Text] = Field(
        description="per instrument (and `machine`, `operator`) that answered from rtcal's protocol simulators "
                    "(`rtcal sim serve`, whose identity replies say SIMULATED): what it said it is")
    rehearsed: bool = Field(description="`--rehearse`: a person confirmed each operator step, the simulated operator "
                                        "carried it out")
    statement: Text = Field(description="the marking every page of the certificate and the console carry")


class Signature(ResultsModel):
    """Who signs this run's digests: the laboratory's Ed25519 key (signature.json beside results.json
    holds the signature over this file's SHA-256, its digests and every deliverable's) (1.4)."""

    algorithm: Literal["ed25519"] = Field(description="the signature algorithm")
    signer: Name = Field(description="who the key signs for, as the key file names it")
    key_fingerprint: Annotated[str, Field(pattern=r"^SHA256:[A-Za-z0-9+/]{43}$")] = Field(
        description="SHA256: and the unpadded base64 of the SHA-256 of the raw public key")


class PeriodicTerm(ResultsModel):
    """One harmonic of the tested period, named by its period in degrees and in worm revolutions (1.4)."""

    OPTIONAL_KEYS = frozenset({"period_worm_revolutions"})

    order: Annotated[int, Field(ge=1, le=10_000_000)] = Field(description="cycles per table turn")
    period_deg: Deg = Field(description="its period, degrees (360° / order)")
    period_worm_revolutions: Number | None = Field(None, description="its period in worm revolutions (worm ratio / order; "
                                                                     "absent: the procedure states no worm ratio)")
    amplitude_arcsec: SigmaArcsec = Field(description="amplitude A of A·sin(order·θ + φ), arcsec")
    amplitude_sigma_arcsec: SigmaArcsec = Field(description="its standard uncertainty (1σ), arcsec")
    phase_deg: Annotated[float, Field(ge=-360.0, le=360.0)] = Field(description="phase φ, degrees")
    significant: bool = Field(description="above the family-wise 1 % threshold (rtcal.solvers.harmonics)")
    threshold_arcsec: SigmaArcsec = Field(description="the amplitude above which it counts as significant, arcsec")


class PeriodicError(ResultsModel):
    """The periodic positioning error of a fine-step test over one period and a little more (ISO
    230-2:2014 Annex C, as rtcal reads it: the annex's text was not reached; docs/evaluation.md) (1.4)."""

    definition: Text = Field(description="what the figure is, in words, and what it rests on")
    reference: Text = Field(description="what the table's positioning error at each fine step was read from")
    period_deg: Deg = Field(description="the period tested, degrees")
    worm_ratio: Number | None = Field(description="worm (motor) turns per table turn the procedure states (null: none)")
    start_deg: Deg = Field(description="the first target, degrees")
    step_deg: Deg = Field(description="the fine step, degrees")
    targets_per_period: Count = Field(description="targets within one period (both ends included)")
    trend_degree: Count = Field(description="degree of the slow error removed over the arc, per direction")
    periodic_error_up_arcsec: Parameter | None = Field(description="range over one period of the mean deviation ↑ "
                                                                   "less the slow part, arcsec (null: not measured)")
    periodic_error_down_arcsec: Parameter | None = Field(description="the same ↓, arcsec (null: not measured)")
    periodic_error_arcsec: Parameter = Field(description="the axis's periodic positioning error: the larger of ↑ and ↓")
    expanded_uncertainty_arcsec: SigmaArcsec = Field(description="its U (k = 2), arcsec: 2·√(u² + u²) of its two means")
    expanded_uncertainty_up_arcsec: SigmaArcsec | None = Field(description="U (k = 2) of the ↑ figure, arcsec (null: not measured)")
    expanded_uncertainty_down_arcsec: SigmaArcsec | None = Field(description="U (k = 2) of the ↓ figure, arcsec (null: not measured)")
    harmonics: list[PeriodicTerm] = Field(description="the harmonic analysis at the period's orders")
    target_deg: list[Deg] = Field(description="the curve the figure is the range of: each (direction, target)'s angle")
    direction: list[Direction] = Field(description="its direction")
    residual_arcsec: list[Arcsec] = Field(description="its mean deviation less the slow part, arcsec")
    notes: list[Text] = Field(description="what the figure leaves out and what is not confirmed")


# -- the three parts of a run's results, and the results of each method ------------------------------
class RunInfo(ResultsModel):
    """What the runner knows of every run before its analysis."""

    schema_version: Annotated[str, Field(pattern=r"^1\.[0-9]{1,4}$")] = Field(
        "1.0", description="version of this schema: a minor step adds optional keys, a major one changes keys "
                                    "(absent in files of rtcal before 0.1.0's results model: read as 1.0)")
    rtcal_version: Name = Field(description="the rtcal that wrote the file")
    method: Annotated[str, Field(pattern=r"^[a-z][a-z0-9_]{0,99}$")] = Field(
        description="the calibration method (each method's results narrow it to its name)")
    procedure: ProcedureRef = Field(description="the procedure followed")
    metadata: RunMetadata = Field(description="the report's header: customer, machine, axis, instruments, …")
    seed: Annotated[int, Field(ge=0, le=2**63 - 1)] | None = Field(
        description="seed of the simulated run's random generator (null: a run on instruments)")
    instruments: Literal["simulated in process"] | dict[Name, Text] = Field(
        description="`simulated in process`, or per instrument the address it was reached at")
    bench: Text | None = Field(description="the simulated bench's scenario file, or why it is ideal (null: not simulated)")
    started_utc: Name | None = Field(description="when the run started, ISO 8601 UTC")
    finished_utc: Name | None = Field(description="when the last reading was taken, ISO 8601 UTC")
    starts: Annotated[int, Field(ge=1, le=1_000_000)] = Field(description="how many times the run was started (1 + resumes)")
    measurement_duration_s: Seconds = Field(description="time the measurement took on `clock`, s")
    clock: Literal["virtual", "real"] = Field(description="`virtual`: simulated time (settle waits skipped); `real`: wall clock")
    simulation: Simulation | None = Field(
        None, description="why this run is not a calibration: its instruments were simulated in process or answered "
                          "from rtcal's protocol simulators, or it was rehearsed (absent: real instruments, not "
                          "rehearsed) (1.4)")


def _without_none(annotation: Any) -> Any:
    """``X | None`` → X."""
    args = [a for a in get_args(annotation) if a is not type(None)]
    return args[0] if len(args) == 1 and get_origin(annotation) is not Literal else annotation


class Analysis(ResultsModel):
    """What a method's analysis of the logged readings gives (every method)."""

    OPTIONAL_KEYS = frozenset({"positioning_deviations", "truth", "periodic_error"})

    nominal_angles_deg: list[Deg] = Field(description="commanded angle of each station or step, degrees")
    raw_readings: Count = Field(description="planned readings taken whole")
    recommended: EstimatorName | None = Field(
        description="the estimate to quote: converged, and the smallest uncertainty among those that did")
    solver_status: dict[EstimatorKey, SolverStatus] = Field(
        description="every estimator the procedure asked for, including one that could not run")
    estimates: NamedSet[Any] = Field(description="every estimate, by estimator (each method's: an angular Estimate, or a "
                                                 "QuantityEstimate in its own quantity and unit)")
    positioning_deviations: DeviationTable | None = Field(
        None, description="the recommended estimate as the positioning-deviation table (absent: no estimate)")
    truth: Truth | None = Field(None, description="what the simulated bench really had (absent: a run on instruments)")
    periodic_error: PeriodicError | None = Field(
        None, description="the periodic positioning error of a fine-step test over a period (ISO 230-2:2014 Annex C; "
                          "absent: not tested) (1.4)")

    @model_validator(mode="after")
    def _declared_names(self) -> Analysis:
        """``solver_status`` names only estimators the method declares (its results' ``recommended`` Literal)."""
        names = _without_none(type(self).model_fields["recommended"].annotation)
        declared = get_args(names) if get_origin(names) is Literal else ()
        unknown = [name for name in self.solver_status if declared and name not in declared]
        if unknown:
            raise ValueError(f"solver_status names {unknown[0]!r}, not an estimator of this method ({', '.join(declared)})")
        return self

    @model_validator(mode="after")
    def _status_of_every_estimate(self) -> Analysis:
        missing = [name for name in self.estimates.names() if name not in self.solver_status]
        if missing:
            raise ValueError(f"solver_status has no entry for the estimate {missing[0]}")
        if self.recommended is not None and self.estimates.named(self.recommended) is None:
            raise ValueError(f"recommended names {self.recommended}, which is not among the estimates")
        return self

    def recommended_result(self) -> Estimate | QuantityEstimate | None:
        """The result ``recommended`` names, if any: an angular estimate or a quantity of the method's own."""
        found = None if self.recommended is None else self.estimates.named(self.recommended)
        return found if isinstance(found, (Estimate, QuantityEstimate)) else None

    def recommended_estimate(self) -> Estimate | None:
        """The angular estimate ``recommended`` names, if any (None: the method's result is a quantity of its own,
        :meth:`recommended_result`)."""
        found = self.recommended_result()
        return found if isinstance(found, Estimate) else None

    def target_labels(self) -> list[str]:
        """Each target as ``angle↑`` or ``angle↓``: the recommended estimate's targets, else the
        nominal angles in the direction they were measured."""
        e = self.recommended_result()
        if isinstance(e, (TargetedEstimate, QuantityEstimate)):
            pairs = list(zip(e.target_deg, e.target_direction))
        else:
            angles = self.nominal_angles_deg
            up = len(angles) > 1 and angles[-1] > angles[0]
            pairs = [(a, 1 if up else -1) for a in angles]
        return [f"{t:g}{'↑' if d > 0 else '↓'}" for t, d in pairs]


Verdict = Literal["pass", "fail", "undecided"]


class LimitConformity(ResultsModel):
    """One acceptance limit against its measured parameter (docs/conformity.md)."""

    OPTIONAL_KEYS = frozenset({"target_deg", "direction"})

    limit_arcsec: Annotated[float, Field(gt=0.0, le=1e6)] = Field(description="the limit the procedure states, arcsec")
    value_arcsec: Parameter | None = Field(description="the measured parameter, arcsec (null: not defined by the data)")
    expanded_uncertainty_arcsec: SigmaArcsec | None = Field(
        description="U (k = 2) of the parameter, from the positioning deviations' covariance (null: not defined)")
    guard_band_arcsec: SigmaArcsec = Field(description="the guard band the rule applied: U under `guarded`, 0 under `simple`")
    verdict: Verdict = Field(description="pass, fail or undecided (guarded: within U of the limit; or no value)")
    target_deg: Deg | None = Field(None, description="for the band: the target closest to (or beyond) it, degrees")
    direction: Direction | None = Field(None, description="for the band: that target's approach, 1 ↑ or −1 ↓")


class Conformity(ResultsModel):
    """The procedure's acceptance limits, the decision rule, and the verdict per limit and overall."""

    decision_rule: Literal["simple", "guarded"] = Field(
        description="`simple`: ILAC-G8:09/2019 simple acceptance (pass if value ≤ limit); `guarded`: ISO 14253-1:2017 "
                    "(pass if value ≤ limit − U, fail if value > limit + U, else undecided)")
    rule: Text = Field(description="the decision rule in words, as the certificate states it")
    verdict: Verdict = Field(description="fail if any limit fails, else undecided if any is undecided, else pass")
    coverage_factor: Annotated[float, Field(gt=0.0, le=10.0)] = Field(description="k of every U here (2)")
    per_limit: dict[Annotated[str, Field(pattern=r"^(E|E_up|E_down|M|B|R|R_up|R_down|A|A_up|A_down|band)$")],
                    LimitConformity] = Field(description="per limit (ISO 230-2 symbol, or `band`): limit, value, U, verdict")
    notes: list[Text] = Field(description="how U was made and what it leaves out")


class Control(ResultsModel):
    """Whether rtcal had the machine to itself, and how every motion and reading was checked."""

    instruments: dict[Name, Text] = Field(
        description="per instrument that moves (stage, cmm) and the operator: what access rtcal had and how it is known")
    exclusive: bool | None = Field(
        description="true: every instrument that moves was rtcal's alone (in process, or an exclusive session); null: "
                    "a protocol cannot tell (the checks are then the evidence)")
    checks: list[Text] = Field(description="what every motion and reading was checked against, with the tolerances")
    rejected_attempts: Count = Field(description="readings the checks contradicted: kept, marked rejected, never used")


class Digests(ResultsModel):
    """What binds results.json to its run's store (rtcal/run/integrity.py): digests of the store's
    readings and events and of the procedure, bench and seed the results were computed from. The
    store in turn records the digest of this file; neither covers a path (a copied run stays valid).
    The deliverables' digests are taken after they are written and before results.json is: the
    certificate never shows them, and results.json covers every other file of the run."""

    OPTIONAL_KEYS = frozenset({"deliverables_sha256"})

    algorithm: Literal["sha256"] = Field(description="the digest algorithm (1.2)")
    readings_sha256: Annotated[str, Field(pattern=r"^[0-9a-f]{64}$")] = Field(
        description="of every row of the store's readings table, in order, as JSON lines (1.2)")
    readings: Count = Field(description="how many rows of readings the digest covers (1.2)")
    events_sha256: Annotated[str, Field(pattern=r"^[0-9a-f]{64}$")] = Field(
        description="of every row of the store's events table, in order, as JSON lines (1.2)")
    events: Count = Field(description="how many events the digest covers (1.2)")
    procedure_sha256: Annotated[str, Field(pattern=r"^[0-9a-f]{64}$")] = Field(
        description="of the stored method, procedure text, instrument section (tokens redacted), bench scenario and "
                    "seed (1.2)")
    deliverables_sha256: dict[Annotated[str, Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9._-]{0,199}(/[A-Za-z0-9][A-Za-z0-9._-]{0,199}){0,3}$")],
                              Annotated[str, Field(pattern=r"^[0-9a-f]{64}$")]] | None = Field(
        None, max_length=10_000,
        description="per file the run wrote beside results.json (certificate.json, report.md/.html/.pdf, "
                    "positioning_deviations.csv, the figures, …; its path in the run directory): the SHA-256 of its "
                    "bytes as written; `rtcal verify` checks each (1.3)")


class RunLog(ResultsModel):
    """What the runner adds after the analysis: the evaluation and the run's log."""

    OPTIONAL_KEYS = frozenset({"conformity", "control", "digests", "signature"})

    evaluation: Evaluation | None = Field(description="ISO 230-2 and VDI 3441 parameters (null: no positioning deviations)")
    skipped_readings: Count = Field(description="planned readings a fault policy skipped and no start took again")
    faults: Count = Field(description="instrument faults during the run")
    events: list[Event] = Field(description="the run's log, in order")
    conformity: Conformity | None = Field(
        None, description="the verdict against the procedure's `acceptance:` limits (absent: no limits) (1.1)")
    control: Control | None = Field(
        None, description="exclusive control of the machine and the checks of every motion and reading (1.1)")
    digests: Digests | None = Field(
        None, description="digests of the store's readings, events and procedure these results were computed from; "
                          "every command that reads the run checks them (1.2)")
    signature: Signature | None = Field(
        None, description="the laboratory key that signs this run (signature.json); absent: unsigned, no lab key was "
                          "configured when the run was written (1.4)")


class RunResults(RunLog, Analysis, RunInfo):
    """results.json of any method: the run, its analysis, its log (the fields in that order)."""

    OPTIONAL_KEYS = Analysis.OPTIONAL_KEYS | RunLog.OPTIONAL_KEYS | frozenset({"simulation"})

    @model_validator(mode="after")
    def _names_its_estimate(self) -> RunResults:
        if self.recommended is None:
            raise ValueError("recommended: a run's results name the estimate to quote (null only in a failed analysis, "
                             "which writes no results)")
        return self


def assemble(info: RunInfo, analysis: Analysis, log: RunLog, model: type[RunResults]) -> RunResults:
    """The run's results from its three parts, as the method's results ``model`` (its ``results_model``:
    rtcal.methods.METHODS), validated as the file will be read."""
    fields = {**dict(info), **dict(analysis), **dict(log)}
    return model.model_validate(fields)


# each method declares its estimator names in its own results model
__getattr__ = moved(__name__, {"MultistationEstimator": "rtcal.methods.multistation.results",
                               "AbbeEstimator": "rtcal.methods.abbe.results"})
