"""What of its instruments' calibrations the laser tracer multi-station method applies, and a run as it
would have been with a new one (``rtcal catalog reassess``).

The CMM's calibration enters the budget as the u of each of its scales (``uncertainty.cmm_scale_ppm``);
the network estimates the scales themselves from the readings. The tracer's lengths enter through
their ratios at each station and its stated noise: a certificate's scale or U of the tracer is not an
input this method's analysis takes, and saying so is the honest answer."""

from __future__ import annotations

from collections.abc import Mapping

from rtcal.methods.multistation.procedure import LaserTracerMultistation
from rtcal.api import CannotRecalibrate, InstrumentCalibration


class MultistationRecalibration:
    """:class:`rtcal.methods.recalibration.Recalibration` of the multi-station method."""

    def applied(self, proc: LaserTracerMultistation, meta: Mapping[str, str]) -> dict[str, str]:
        return {"cmm": f"scale u {proc.uncertainty.cmm_scale_ppm:g} ppm per axis in the budget (the network estimates "
                       "the scales themselves)",
                "laser_tracer": "none: its lengths enter as read, its stated noise in the budget",
                "environment": "its readings correct each length for the air's refractive index (as read)"}

    def recalibrated(self, proc: LaserTracerMultistation, meta: Mapping[str, str], role: str,
                     calibration: InstrumentCalibration) -> tuple[LaserTracerMultistation, dict[str, str]]:
        c = calibration
        if role == "cmm":
            if any(getattr(c, k) is not None for k in ("scale_error_ppm", "u_arcsec", "corrections_arcsec")):
                raise CannotRecalibrate("the network estimates the CMM's scales from the readings: only their u "
                                        "(scale_u_ppm) enters the budget")
            update = {} if c.scale_u_ppm is None else {"cmm_scale_ppm": c.scale_u_ppm}
            return proc.model_copy(update={"uncertainty": proc.uncertainty.model_copy(update=update)}), {}
        raise CannotRecalibrate(f"the {role}'s calibration is not an input of this method's analysis")
