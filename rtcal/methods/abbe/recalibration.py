"""What of its reference instruments' calibrations the encoder Abbe-error method (and the ISO test)
applies, and a run as it would have been with a new one (``rtcal catalog reassess``).

The polygon's certificate enters as its face errors (the store's ``polygon_certificate_arcsec``,
fixed before the first motion) and their 1σ (``polygon.certificate_uncertainty_arcsec``); the
autocollimator's as its scale error (each reading divided by 1 + e), the scale's u and the U of an
indication (``uncertainty``). Nothing else of the run changes: the readings are the stored ones."""

from __future__ import annotations

import json
from collections.abc import Mapping

from rtcal.methods.abbe.procedure import EncoderAbbeError
from rtcal.api import CannotRecalibrate, InstrumentCalibration


def _face_errors(meta: Mapping[str, str]) -> list[float] | None:
    try:
        values = json.loads(meta.get("polygon_certificate_arcsec", "null"))
    except ValueError:
        return None
    return [float(v) for v in values] if isinstance(values, list) else None


class AbbeRecalibration:
    """:class:`rtcal.methods.recalibration.Recalibration` of :class:`~rtcal.methods.abbe.method.AbbeMethod`."""

    def applied(self, proc: EncoderAbbeError, meta: Mapping[str, str]) -> dict[str, str]:
        faces = _face_errors(meta)
        u = proc.uncertainty
        polygon = ("none: its face errors were separated from the table's by closure in this run" if faces is None else
                   f"{len(faces)} face errors from its certificate ({min(faces):+.2f}″ … {max(faces):+.2f}″), "
                   f"u {proc.polygon.certificate_uncertainty_arcsec:g}″ each")
        scale = (f"scale error {u.autocollimator_scale_error_ppm:+g} ppm corrected" if u.autocollimator_scale_error_ppm
                 else "no scale error stated (none corrected)")
        autocollimator = (f"{scale}; scale u {u.autocollimator_scale_u_ppm:g} ppm, U "
                          f"{u.autocollimator_calibration_u_arcsec:g}″ of an indication in the budget")
        return {"polygon": polygon, "autocollimator": autocollimator,
                "encoder": "none: the item's own encoder, not a reference",
                "environment": "none: its readings are the conditions reported, not a correction of E",
                "dial_indicator_1": f"scale u {u.indicator_scale_u_ppm:g} ppm in the encoder analysis's budget",
                "dial_indicator_2": f"scale u {u.indicator_scale_u_ppm:g} ppm in the encoder analysis's budget"}

    def recalibrated(self, proc: EncoderAbbeError, meta: Mapping[str, str], role: str,
                     calibration: InstrumentCalibration) -> tuple[EncoderAbbeError, dict[str, str]]:
        c = calibration
        if role == "polygon":
            unused = [k for k in ("scale_error_ppm", "scale_u_ppm", "u_arcsec") if getattr(c, k) is not None]
            if unused:
                raise CannotRecalibrate(f"a polygon's certificate gives face errors (corrections_arcsec) and their u, "
                                        f"not {', '.join(unused)}")
            changes: dict[str, str] = {}
            polygon = proc.polygon
            if c.corrections_arcsec is not None:
                if _face_errors(meta) is None:
                    raise CannotRecalibrate("this run separated the polygon's face errors by closure: its certificate "
                                            "did not enter the result")
                if len(c.corrections_arcsec) != polygon.faces:
                    raise CannotRecalibrate(f"the certificate gives {len(c.corrections_arcsec)} face errors, the run's "
                                            f"polygon has {polygon.faces} faces")
                changes["polygon_certificate_arcsec"] = json.dumps([float(v) for v in c.corrections_arcsec])
            if c.corrections_u_arcsec is not None:
                polygon = polygon.model_copy(update={"certificate_uncertainty_arcsec": c.corrections_u_arcsec})
            return proc.model_copy(update={"polygon": polygon}), changes
        if role == "autocollimator":
            if c.corrections_arcsec is not None or c.corrections_u_arcsec is not None:
                raise CannotRecalibrate("this method corrects an autocollimator by its scale, not by a table of "
                                        "corrections_arcsec")
            update = {k: v for k, v in (("autocollimator_scale_error_ppm", c.scale_error_ppm),
                                        ("autocollimator_scale_u_ppm", c.scale_u_ppm),
                                        ("autocollimator_calibration_u_arcsec", c.u_arcsec)) if v is not None}
            return proc.model_copy(update={"uncertainty": proc.uncertainty.model_copy(update=update)}), {}
        if role.startswith("dial_indicator"):
            raise CannotRecalibrate("the procedure states one scale u for both dial indicators "
                                    "(uncertainty.indicator_scale_u_ppm): a new certificate of one cannot be taken apart")
        raise CannotRecalibrate(f"the {role}'s calibration does not enter this method's E, U or verdict")
