"""The Abbe method's own checks (seed 001): the encoder against the commanded motion, the face in view
seen near square, the autocollimator against the encoder, the two dial indicators against each other
and against themselves. A failure is a :class:`~rtcal.engine.checks.Contradiction`, never a result."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from rtcal.api import DESCRIPTIONS, Contradiction, combined_sigma

if TYPE_CHECKING:
    from rtcal.methods.abbe.procedure import EncoderAbbeError
    from rtcal.api import Reading


def check_face(x_arcsec: float, tolerance_arcsec: float, command_deg: float) -> None:
    """The face the commanded angle puts in view is seen square (within the tolerance)."""
    if not abs(x_arcsec) <= tolerance_arcsec:
        raise Contradiction("autocollimator", f"the face at {command_deg:g}° is seen {x_arcsec:+.1f}″ from square (tolerance "
                                              f"{tolerance_arcsec:g}″, verification.autocollimator_tolerance_arcsec): the "
                                              "table is not where it was commanded, or the polygon is not seated as stated")


class EncoderCheck:
    """The encoder moves as commanded: its reading minus the command stays within a tolerance of
    what it was at the start's first visit (an incremental counter's zero is arbitrary)."""

    def __init__(self, tolerance_arcsec: float, pitch_deg: float = 0.0, face_still_arcsec: float = 0.0):
        """``pitch_deg``: the polygon's, ``face_still_arcsec``: how far apart two readings of one face by
        an autocollimator that did not move may be (its noise): together they say when a face seen
        square is no evidence that the table turned (item 7 of issue 36)."""
        self.tolerance_arcsec = tolerance_arcsec
        self.pitch_deg, self.face_still_arcsec = pitch_deg, face_still_arcsec
        self.offset_deg: float | None = None
        self.first_command_deg = 0.0
        self.previous: tuple[float, float, float | None] | None = None  # the last request's (encoder, command, face)
        self.suspect: str | None = None  # stale or frozen, found once (issue 26)
        self.came_from: tuple[float, float, float | None] | None = None  # the last request at another command

    def _nothing_turned(self, face_arcsec: float | None, command_deg: float,
                        previous: tuple[float, float, float | None]) -> str:
        """Why the table may not have turned at all ("" if the autocollimator shows it did): the step
        is whole faces — a face square in view whether the table turned or not — and the face reads
        what it read at the previous request, within its noise."""
        step = abs(command_deg - previous[1]) / self.pitch_deg if self.pitch_deg > 0 else 0.5
        x_before = previous[2]
        if face_arcsec is None or x_before is None or abs(step - round(step)) > 1e-6:
            return ""
        if not abs(face_arcsec - x_before) <= self.face_still_arcsec:
            return ""
        return (f"the encoder and the autocollimator both read what they read at {previous[1]:g}°, the target before (the "
                f"face {face_arcsec - x_before:+.2f}″ from it): the table did not turn — a face square to the "
                f"autocollimator cannot tell a {abs(command_deg - previous[1]):g}° turn from none ({self.pitch_deg:g}° "
                "faces). The drive did not move the table (stuck, or not enabled) — or it did, the encoder's count is "
                "frozen or stale, and this face happens to read as the last one")

    def _faces_off(self, apart_deg: float) -> str:
        """The other cause when the encoder is whole faces from the command: a face square to the
        autocollimator cannot tell a table that many faces off (a drive that did not move it) from
        one where it was commanded ("" when the gap is no whole number of faces)."""
        if not self.pitch_deg > 0:
            return ""
        faces = round(apart_deg / self.pitch_deg)
        if faces == 0 or abs(apart_deg - faces * self.pitch_deg) * 3600.0 > self.tolerance_arcsec:
            return ""
        return (f" — or the stage did not turn the table as commanded: the encoder reads {abs(faces)} "
                f"{'face' if abs(faces) == 1 else 'faces'} ({abs(faces) * self.pitch_deg:g}°) from the command, and a face "
                "square to the autocollimator cannot tell a whole face from none (the drive stuck, or not enabled)")

    def check(self, encoder_deg: float, command_deg: float, table_seen: bool = False, face_arcsec: float | None = None) -> None:
        """``table_seen``: the autocollimator saw the face the command puts in view square, so the
        table did turn; an encoder that disagrees is then the encoder's fault, and one that fits
        the previous request (stale) or repeats itself (frozen) stays suspect for the run — unless
        the face reads as it did then too (``face_arcsec``): then nothing turned, and the stage is named."""
        offset = encoder_deg - command_deg
        previous, self.previous = self.previous, (encoder_deg, command_deg, face_arcsec)
        if previous is not None and previous[1] != command_deg:  # a retried visit comes from where the one before came
            self.came_from = previous
        if self.suspect is not None:
            raise Contradiction("encoder", f"at {command_deg:g}°: {self.suspect}")
        if self.offset_deg is None:
            self.offset_deg, self.first_command_deg = offset, command_deg
            return
        apart_deg = (offset - self.offset_deg + 180.0) % 360.0 - 180.0
        if not abs(apart_deg) * 3600.0 <= self.tolerance_arcsec and table_seen and previous is not None:
            lag_deg = (encoder_deg - previous[1] - self.offset_deg + 180.0) % 360.0 - 180.0
            stood = encoder_deg == previous[0] or abs(lag_deg) * 3600.0 <= self.tolerance_arcsec
            # a retried visit's previous request is its own failed attempt: where the table stood before is came_from's
            back = self.came_from
            stayed = back is not None and (encoder_deg == back[0] or abs((encoder_deg - back[1] - self.offset_deg + 180.0)
                                                                         % 360.0 - 180.0) * 3600.0 <= self.tolerance_arcsec)
            why = self._nothing_turned(face_arcsec, command_deg, back) if (stood or stayed) and back else ""
            if why:
                raise Contradiction("stage", f"at {command_deg:g}°: {why}")
            if encoder_deg == previous[0]:
                self.suspect = (f"the encoder repeats {encoder_deg:.6f}° while the table turned (the autocollimator sees the "
                                "commanded face square): a frozen counter or buffer")
            elif abs(lag_deg) * 3600.0 <= self.tolerance_arcsec:
                self.suspect = (f"the encoder reads where the previous request was ({lag_deg * 3600:+.0f}″ from it) while the "
                                "autocollimator sees the commanded face square: its replies are one request behind (stale)")
            if self.suspect is not None:
                raise Contradiction("encoder", f"at {command_deg:g}°: {self.suspect}")
            raise Contradiction("encoder", f"the encoder is {apart_deg * 3600:+.0f}″ from the commanded motion while the "
                                           "autocollimator sees the commanded face square (tolerance "
                                           f"{self.tolerance_arcsec:g}″, verification.encoder_tolerance_arcsec): it misreads"
                                           + self._faces_off(apart_deg))
        if not abs(apart_deg) * 3600.0 <= self.tolerance_arcsec:
            commanded = command_deg - self.first_command_deg
            raise Contradiction("stage", f"the encoder turned {commanded + apart_deg:.4f}° where {commanded:.4f}° was "
                                         f"commanded since the first visit: {apart_deg * 3600:+.0f}″ apart (tolerance "
                                         f"{self.tolerance_arcsec:g}″, verification.encoder_tolerance_arcsec): the table is "
                                         "not where it was commanded, or the encoder misreads")


# -- Instruments checked against each other (issue 26): pure objects fed each visit's readings with
# their context; the plan calls them where it checks a visit's readings.
def _wrap_arcsec(deg: float) -> float:
    """An angle difference in (−180°, 180°], in arcsec."""
    return ((deg + 180.0) % 360.0 - 180.0) * 3600.0


class AutocollimatorEncoderCheck:
    """The autocollimator against the encoder at every visit where a face is in view.

    Both see the same table: the autocollimator its angle from the face's nominal (the command),
    the encoder its angle plus its own error, so their difference d = x − (encoder − command) is
    the encoder's error (the method's subject: smooth, the same at the same target), the face's
    error and constants (the encoder's zero, the polygon's seating) — the table's positioning
    error and repeatability cancel. Hence:

    - at a target already seen in this seating (another run, the other direction) d agrees with
      what it was there within ``same_tolerance_arcsec(n)``: 5σ of the difference's noise
      (the instruments' stated noise and digits) plus the stated ``drift_arcsec``;
    - along a pass d changes from one visit to the next by no more than twice the stated bounds
      of the encoder's and the faces' errors, plus the noise (``neighbour_tolerance_arcsec``);
    - a reply that fits the previous request's visit and not this one's is stale (a buffer one
      step behind); the same value again where the motion says it must change is frozen. Either
      stays suspect for the rest of the run: a retaken visit would hide it (its previous request
      is the same target).
    """

    def __init__(self, sigma_arcsec: float, drift_arcsec: float, encoder_bound_arcsec: float, face_bound_arcsec: float):
        self.sigma_arcsec = sigma_arcsec
        self.drift_arcsec = drift_arcsec
        self.neighbour_tolerance_arcsec = 5.0 * sigma_arcsec * np.sqrt(2.0) + drift_arcsec + 2.0 * (encoder_bound_arcsec + face_bound_arcsec)
        self.seen: dict[tuple[int, float], dict[int, float]] = {}  # (seating, target) → {visit: d}
        self.last_in_pass: dict[tuple[int, int, int], tuple[float, float]] = {}  # (seating, run, direction) → (target, d)
        self.previous: tuple[float, float, tuple[int, float]] | None = None  # last request: (x, encoder − command, key)
        self.suspect: str | None = None  # stale or frozen, found once: every later visit is rejected

    def same_tolerance_arcsec(self, n: int) -> float:
        """Against the mean of n earlier visits of the target: 5σ of the difference plus the drift."""
        return 5.0 * self.sigma_arcsec * float(np.sqrt(1.0 + 1.0 / n)) + self.drift_arcsec

    def _reference(self, key: tuple[int, float]) -> tuple[float, int] | None:
        values = self.seen.get(key)
        return (float(np.mean(list(values.values()))), len(values)) if values else None

    def check(self, x_arcsec: float, encoder_deg: float, command_deg: float, seating: int, run: int, direction: int,
              visit: int) -> None:
        """One visit's readings (means over samples); raises Contradiction("autocollimator", …)."""
        e = _wrap_arcsec(encoder_deg - command_deg)
        d = x_arcsec - e
        key = (seating, round(command_deg % 360.0, 6))
        previous, self.previous = self.previous, (x_arcsec, e, key)
        where = f"the face at {command_deg:g}°"
        if self.suspect is not None:
            raise Contradiction("autocollimator", f"{where}: {self.suspect}")
        ref = self._reference(key)
        if previous is not None and previous[2] != key:
            x_prev, e_prev, key_prev = previous
            ref_prev = self._reference(key_prev)
            if ref is not None and ref_prev is not None:
                expected_change = (e + ref[0]) - (e_prev + ref_prev[0])
                tol = self.same_tolerance_arcsec(min(ref[1], ref_prev[1])) * np.sqrt(2.0)
            else:
                expected_change, tol = e - e_prev, self.neighbour_tolerance_arcsec
            if x_arcsec == x_prev and abs(expected_change) > tol:
                self.suspect = (f"the autocollimator repeats {x_arcsec:+.2f}″ where the encoder says its reading must change by "
                                f"{expected_change:+.1f}″ (more than {tol:.2g}″): a frozen display or buffer")
                raise Contradiction("autocollimator", f"{where}: {self.suspect}")
            if ref is not None and ref_prev is not None:
                same_tol = self.same_tolerance_arcsec(ref[1])
                lag = abs(x_arcsec - e_prev - ref_prev[0])
                if abs(d - ref[0]) > same_tol and lag <= self.same_tolerance_arcsec(ref_prev[1]):
                    self.suspect = (f"the autocollimator's reading {x_arcsec:+.2f}″ fits the previous request's position "
                                    f"({lag:.2f}″ off) and not this one's ({d - ref[0]:+.2f}″ off, tolerance {same_tol:.2g}″): "
                                    "its replies are one request behind (a stale buffer)")
                    raise Contradiction("autocollimator", f"{where}: {self.suspect}")
        if ref is not None:
            tol = self.same_tolerance_arcsec(ref[1])
            if not abs(d - ref[0]) <= tol:
                raise Contradiction("autocollimator", f"{where} is seen {x_arcsec:+.2f}″ with the encoder {e:+.2f}″ from the "
                                    f"command: their difference is {d - ref[0]:+.2f}″ from the {ref[1]} earlier visit(s) of "
                                    f"this target (tolerance {tol:.2g}″: 5σ of their stated noise, verification."
                                    "cross_check_drift_arcsec): the autocollimator misreads (stale, frozen) or the polygon moved")
        pass_key = (seating, run, direction)
        last = self.last_in_pass.get(pass_key)
        if last is not None and not abs(d - last[1]) <= self.neighbour_tolerance_arcsec:
            raise Contradiction("autocollimator", f"{where}: the autocollimator − encoder difference changed by "
                                f"{d - last[1]:+.1f}″ since {last[0]:g}° in this pass (tolerance "
                                f"{self.neighbour_tolerance_arcsec:.3g}″: twice verification.encoder_error_bound_arcsec and "
                                "face_error_bound_arcsec, plus 5σ): the autocollimator misreads, or the polygon moved")
        self.seen.setdefault(key, {})[visit] = d
        self.last_in_pass[pass_key] = (command_deg, d)


def inch_digit_um(digit_um: float) -> float:
    """What one digit of the same indicator set to inches reads as when its number is taken for mm,
    µm: its inch digit is the 1-2-5 step at or above the mm digit / 25.4 (1 µm → 0.00005 in → 0.05)."""
    inches = digit_um * 1e-3 / 25.4
    decade = 10.0 ** np.floor(np.log10(inches))
    step = next(k for k in (1.0, 2.0, 5.0, 10.0) if k * decade >= inches * (1 - 1e-9))
    return float(step * decade * 1e3)


class IndicatorCheck:
    """A dial indicator's reading within its stated range; and, when its display digit is stated,
    not an inch display read as mm: ``UNIT_EVIDENCE`` nonzero readings in a row off its digit and
    each on the grid an inch display's digits make when read as mm (1/25.4 of the displacement).
    One reading off the digit is not enough: a simulated bench without quantisation shows any
    value; four in a row on that grid happen by chance to about 1 in 10⁶."""

    UNIT_EVIDENCE = 4
    GRID_TOLERANCE = 0.02  # of the grid step

    def __init__(self, range_um: float, digit_um: float):
        self.range_um = range_um
        self.digit_um = digit_um
        self.inch_grid_um = inch_digit_um(digit_um) if digit_um > 0 else 0.0
        self.in_a_row: dict[str, int] = {}

    @staticmethod
    def _on_grid(value: float, step: float, tolerance: float) -> bool:
        k = value / step
        return abs(k - round(k)) <= tolerance

    def check(self, instrument: str, y_um: float) -> None:
        if not abs(y_um) <= self.range_um:
            raise Contradiction(instrument, f"reads {y_um:+.1f} µm, beyond the ±{self.range_um:g} µm the shaft may move "
                                            "(verification.indicator_range_um): misread, or not touching the shaft")
        if self.digit_um <= 0 or y_um == 0.0:
            return
        inch_like = (not self._on_grid(y_um, self.digit_um, self.GRID_TOLERANCE)
                     and self._on_grid(y_um, self.inch_grid_um, self.GRID_TOLERANCE))
        self.in_a_row[instrument] = self.in_a_row.get(instrument, 0) + 1 if inch_like else 0
        if self.in_a_row[instrument] >= self.UNIT_EVIDENCE:
            raise Contradiction(instrument, f"reads {y_um:+.4g} µm: {self.UNIT_EVIDENCE} readings in a row not in its "
                                            f"{self.digit_um:g} µm digits (uncertainty.indicator_resolution_um) but in steps "
                                            f"of {self.inch_grid_um:g}: its display is in inches, its number read as mm "
                                            "(25.4× too small); set it to mm")


class IndicatorRepeatCheck:
    """Each dial indicator at a target already seen (another run, the other direction, another
    seating of the polygon: the indicators touch the shaft, not the polygon) reads what it read there within ``tolerance_um(n)``: 5σ of the difference (its
    stated noise and digit), a digit (two roundings), plus the stated ``drift_um``. The shaft's
    radial and tilt motion is a function of the angle, the same at each visit; an indicator that
    creeps or slips on its stand is not — and the encoder error predicted from both indicators
    would carry its creep into the certificate's Abbe part, so it is checked here as the
    autocollimator is (:class:`AutocollimatorEncoderCheck`)."""

    def __init__(self, sigma_um: float, digit_um: float, drift_um: float):
        self.sigma_um, self.digit_um, self.drift_um = sigma_um, digit_um, drift_um
        self.seen: dict[tuple[str, float], dict[int, float]] = {}  # (indicator, target) → {visit: mean}

    def tolerance_um(self, n: int) -> float:
        """Against the mean of n earlier visits of the target."""
        return 5.0 * self.sigma_um * float(np.sqrt(1.0 + 1.0 / n)) + self.digit_um + self.drift_um

    def check(self, instrument: str, y_um: float, command_deg: float, visit: int) -> None:
        key = (instrument, round(command_deg % 360.0, 6))  # the shaft's, whatever the polygon's seating
        earlier = {k: v for k, v in self.seen.get(key, {}).items() if k != visit}  # a retaken visit replaces its own
        if earlier:
            ref, tol = float(np.mean(list(earlier.values()))), self.tolerance_um(len(earlier))
            if not abs(y_um - ref) <= tol:
                raise Contradiction(instrument, f"at {command_deg:g}° reads {y_um:+.2f} µm, {y_um - ref:+.2f} µm from its "
                                                f"{len(earlier)} earlier visit(s) of this target (tolerance {tol:.2g} µm: 5σ "
                                                "of its stated noise, a digit, verification.indicator_drift_um): the "
                                                "indicator creeps or slipped on its stand; the tilt and radial motion — "
                                                "and the encoder error predicted from them — would be wrong")
        self.seen.setdefault(key, {})[visit] = y_um


def abbe_cross_checks(proc: EncoderAbbeError) -> tuple[AutocollimatorEncoderCheck, IndicatorCheck, IndicatorRepeatCheck]:
    """The cross-checks of an encoder Abbe-error (or ISO 230-2) procedure, with its stated figures."""
    v, u = proc.verification, proc.uncertainty
    sigma = v.cross_check_noise_arcsec or combined_sigma((u.autocollimator_noise_arcsec, u.autocollimator_resolution_arcsec),
                                                         (u.encoder_noise_arcsec, u.encoder_resolution_arcsec)) or 0.3
    indicator_sigma = combined_sigma((u.indicator_noise_um, u.indicator_resolution_um)) or 0.3
    return (AutocollimatorEncoderCheck(sigma, v.cross_check_drift_arcsec, v.encoder_error_bound_arcsec, v.face_error_bound_arcsec),
            IndicatorCheck(v.indicator_range_um, u.indicator_resolution_um),
            IndicatorRepeatCheck(indicator_sigma, u.indicator_resolution_um, v.indicator_drift_um))


def check_abbe_visit(ac: AutocollimatorEncoderCheck, indicators: IndicatorCheck, repeats: IndicatorRepeatCheck,
                     readings: list[Reading], command_deg: float, seating: int, run: int, direction: int, visit: int) -> None:
    """One visit's readings (the store's Reading objects) through the cross-checks; each quantity as
    its kind's description names it (drivers/interfaces.py)."""
    displacement = DESCRIPTIONS["dial_indicator"]["y_um"].quantity()
    face, angle = DESCRIPTIONS["autocollimator"]["x_arcsec"].quantity(), DESCRIPTIONS["encoder"]["angle_deg"].quantity()
    shaft: dict[str, list[float]] = {}
    for r in readings:
        if r.quantity == displacement:
            indicators.check(r.instrument, r.value)
            shaft.setdefault(r.instrument, []).append(r.value)
    for instrument, values in sorted(shaft.items()):
        repeats.check(instrument, float(np.mean(values)), command_deg, visit)
    x = [r.value for r in readings if r.quantity == face]
    encoder = [r.value for r in readings if r.quantity == angle]
    if x and encoder:  # the mean of the encoder's samples, across 0°/360° too
        mean_deg = encoder[0] + float(np.mean([_wrap_arcsec(e - encoder[0]) for e in encoder])) / 3600.0
        ac.check(float(np.mean(x)), mean_deg, command_deg, seating, run, direction, visit)
