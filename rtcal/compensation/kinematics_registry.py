"""The location-error formats by name (rtcal/compensation/kinematics.py): what a method's outputs and
`rtcal` commands ask for when they write a control's kinematics."""

from __future__ import annotations

from rtcal.compensation.fanuc_tcp import FanucTcpFormat
from rtcal.compensation.kinematics import KinematicsFormat
from rtcal.compensation.linuxcnc_kins import LinuxCncTrtFormat
from rtcal.compensation.siemens_carr import SiemensCarrFormat
from rtcal.compensation.table import CompensationError

KINEMATICS_FORMATS: dict[str, KinematicsFormat] = {f.name: f for f in (LinuxCncTrtFormat(), SiemensCarrFormat(),
                                                                        FanucTcpFormat())}


def kinematics_format(name: str) -> KinematicsFormat:
    """The format of that name; CompensationError listing the known ones."""
    if name not in KINEMATICS_FORMATS:
        raise CompensationError(f"unknown kinematics format {name!r}; one of {', '.join(KINEMATICS_FORMATS)}")
    return KINEMATICS_FORMATS[name]
