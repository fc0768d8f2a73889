"""Environment sensors: a Vaisala PTU300 (pressure, temperature, humidity) or PTB330 (a
barometer), with the table's temperature from an OMEGA iTHX thermometer on the address's
``thermometer=``, and the tracer's mount's from a second iTHX's probe 2 on ``mount_thermometer=`` (an iTHX has two
probes, the first the air's with a PTB330) (docs/protocols/environment.md gives each fact's public source).

At open the driver stops RUN mode (``S``) and turns the factory-default echo off
(``ECHO OFF``, which also ends the ``>`` prompts), each time reading what the unit sends until the
line falls quiet; it then reads the whole ``?`` listing (the first line ``<model> / <version>``,
then ``Key : value`` lines to the last module line, about a second at 4800 baud) and sets
``FORM`` so that ``SEND`` answers with labelled fields and their units. Whatever layout a unit
keeps, the reply is read as labelled fields (``P= 1003.8 hPa``), each number converted from the
unit printed after it; a field without a unit is refused. An echoed command or a ``>`` prompt is
never taken for a reply, should a unit keep echoing.
"""

from __future__ import annotations

import math
import re
import time

from drivers.addresses import Address, AddressError, parse_address
from drivers.errors import InstrumentError, InstrumentFault, InstrumentTimeout
from drivers.interfaces import EnvironmentReading, EnvironmentSensor
from drivers.models import Framing, builtin_framing
from drivers.serial_line import SerialLine

FIELD = re.compile(r"([A-Za-z][A-Za-z0-9]*)\s*=\s*([+-]?\d+(?:\.\d+)?)\s*([^\s=]+(?=\s|$))?")
PRESSURE_PA = {"pa": 1.0, "hpa": 100.0, "mbar": 100.0, "kpa": 1000.0, "bar": 1e5, "bara": 1e5, "psi": 6894.757,
               "psia": 6894.757, "inhg": 3386.389, "mmhg": 133.3224, "torr": 133.3224}
QUIET_S = 0.25  # the line is done talking after this long without a byte (≈ 120 characters at 4800 baud)
MAX_LISTING_LINES = 40  # the `?` listing is about 15 lines
RANGES = {"air_temperature_c": (-40.0, 80.0, "air temperature °C"), "air_pressure_pa": (50000.0, 150000.0, "pressure Pa"),
          "humidity_pct": (0.0, 100.0, "humidity %"), "material_temperature_c": (-40.0, 150.0, "material temperature °C"),
          "mount_temperature_c": (-40.0, 150.0, "mount temperature °C")}


def celsius(value: float, unit: str) -> float:
    u = unit.lstrip("'°").upper()
    if u == "C":
        return value
    if u == "F":
        return (value - 32.0) * 5.0 / 9.0
    if u == "K":
        return value - 273.15
    raise ValueError(unit)


def labelled_fields(name: str, reply: str) -> dict[str, tuple[float, str]]:
    """``P=  1003.8 hPa   T= 17.7 'C`` → {"P": (1003.8, "hPa"), "T": (17.7, "'C")}."""
    fields = {m.group(1).upper(): (float(m.group(2)), m.group(3) or "") for m in FIELD.finditer(reply)}
    if not fields:
        raise InstrumentFault(name, f"unexpected reply {reply[:80]!r}: no labelled fields")
    return fields


def check_ranges(name: str, values: dict[str, float]) -> None:
    for key, value in values.items():
        lo, hi, what = RANGES[key]
        if not math.isnan(value) and not lo <= value <= hi:
            raise InstrumentFault(name, f"{what} {value:g} outside [{lo:g}, {hi:g}]")


class IthxThermometer:
    """OMEGA iTHX (an iServer on TCP): ``*SRTC`` / ``*SRTC2`` → °C of probe 1 / 2, ``*SRH`` → % RH;
    requests and replies end in CR. Probe 1 hangs in the air by the beam, probe 2 touches the table."""

    def __init__(self, address: Address, timeout_s: float, name: str):
        self.name = name
        self.line = SerialLine(name, address, Framing(), timeout_s, b"\r")

    def read(self, command: str) -> float:
        reply = self.line.query(command.encode("ascii") + b"\r").strip()
        try:
            value = float(reply)
        except ValueError:
            raise InstrumentFault(self.name, f"thermometer: {command}: unexpected reply {reply[:40]!r}") from None
        if not math.isfinite(value):
            raise InstrumentFault(self.name, f"thermometer: {command}: {reply[:40]!r} is no temperature")
        return value

    def close(self) -> None:
        self.line.close()


class VaisalaPtu300(EnvironmentSensor):
    name = "environment"
    options: dict[str, tuple[float, float, bool]]
    model, kind, schemes, options = "vaisala-ptu300", "environment", ("serial",), {}
    framing: Framing = builtin_framing("vaisala-ptu300")
    FORM = '"P=" 4.4 P " " U4 " T=" 3.4 T " " U3 " RH=" 3.3 RH " " U3 #r #n'
    MEASURES_AIR = True  # a PTB330 is a barometer: air temperature and humidity come from the thermometer

    def __init__(self, address: Address, timeout_s: float = 1.0, **_: object):
        thermometer, mount_thermometer = address.text("thermometer"), address.text("mount_thermometer")
        if not self.MEASURES_AIR and not thermometer:
            raise AddressError(f"model {self.model} measures pressure only: give the air and table thermometer as "
                               "thermometer=socket://HOST:PORT (an OMEGA iTHX)")
        self.line = SerialLine(self.name, address, self.framing, timeout_s, b"\n")
        self.timeout_s = timeout_s
        self.thermometer: IthxThermometer | None = None
        self.mount_thermometer: IthxThermometer | None = None  # a second iTHX, its probe 2 on the tracer's mount
        self.listing: dict[str, str] = {}
        try:
            self._command_until_quiet(b"S\r")  # RUN mode streams readings: stop it
            self._command_until_quiet(b"ECHO OFF\r")  # factory default ON: echoed commands and > prompts
            self._identity = self._ask_identity()
            answer = self._reply_to(f"FORM {self.FORM}\r".encode())
            self._until_quiet()  # a unit that answers FORM with more than one line
            if "error" in answer.lower() or "unknown" in answer.lower():
                raise InstrumentFault(self.name, f"FORM refused: {answer[:80]!r}")
            if thermometer:
                self.thermometer = IthxThermometer(parse_address(thermometer), timeout_s, self.name)
            if mount_thermometer:
                self.mount_thermometer = IthxThermometer(parse_address(mount_thermometer), timeout_s, self.name)
        except BaseException:
            self.close()
            raise

    def _until_quiet(self, first_wait_s: float | None = None) -> list[str]:
        """Every line the unit sends until it stays silent for QUIET_S (or never starts within ``first_wait_s``)."""
        lines: list[str] = []
        port = self.line.port
        deadline = time.monotonic() + max(10 * self.timeout_s, 5.0)  # a unit that never stops talking
        try:
            port.timeout = QUIET_S if first_wait_s is None else first_wait_s
            pending = b""
            while time.monotonic() < deadline:
                chunk = port.read_until(b"\n", 256)
                if not chunk:
                    break
                port.timeout = QUIET_S
                pending += chunk
                if pending.endswith(b"\n") or len(pending) >= 256:
                    lines.append(pending.decode("ascii", errors="replace").strip("\r\n"))
                    pending = b""
            else:
                raise InstrumentFault(self.name, "the unit does not stop sending (RUN mode that S does not stop?)")
        except (OSError, ValueError) as exc:
            raise InstrumentFault(self.name, f"serial line failed: {exc}") from None
        finally:
            try:
                port.timeout = self.timeout_s
            except (OSError, ValueError):
                pass
        return lines

    def _command_until_quiet(self, request: bytes) -> list[str]:
        self.line.write(request)
        return self._until_quiet(first_wait_s=QUIET_S)

    def _is_echo_or_prompt(self, line: str, request: bytes) -> bool:
        text = line.strip().lstrip(">").strip()
        return not text or text.upper() == request.decode("ascii", errors="replace").strip().upper()

    def _reply_to(self, request: bytes) -> str:
        """The first line that is neither the echoed command nor a prompt (a unit left echoing)."""
        self.line.write(request)
        for _ in range(4):
            line = self.line.read_line(request)
            if not self._is_echo_or_prompt(line, request):
                return line.strip().lstrip(">").strip()
        raise InstrumentFault(self.name, f"no reply to {request!r} but echoes and prompts")

    def _ask_identity(self) -> str:
        """The whole ``?`` listing: ``<model> / <version>`` then ``Key : value`` lines (PTB330 manual p. 83),
        read until the unit falls silent so that none of it is taken for a later reply."""
        first = self._reply_to(b"?\r")
        for line in self._until_quiet()[:MAX_LISTING_LINES]:
            key, colon, value = line.lstrip(">").partition(":")
            if colon:
                self.listing[" ".join(key.split()).lower()] = value.strip()
        model = first.split("/")[0].strip()
        family = self.model.removeprefix("vaisala-").upper()[:5]  # PTU30, PTB33
        if not model.upper().startswith(family):
            raise InstrumentFault(self.name, f"the unit says it is {first[:60]!r}, not a {self.model.removeprefix('vaisala-').upper()} "
                                             f"(model={self.model} in the address)")
        serial = self.listing.get("serial number", "")
        return f"{first}, serial number {serial}" if serial else first

    def identity(self) -> str:
        return self._identity

    def _send(self) -> dict[str, tuple[float, str]]:
        return labelled_fields(self.name, self._reply_to(b"SEND\r"))

    def _pressure_pa(self, fields: dict[str, tuple[float, str]]) -> float:
        if "P" not in fields:
            raise InstrumentFault(self.name, "SEND gave no P field")
        value, unit = fields["P"]
        if unit.lower() not in PRESSURE_PA:
            raise InstrumentFault(self.name, f"pressure unit {unit!r} unknown")
        return value * PRESSURE_PA[unit.lower()]

    def _air(self, fields: dict[str, tuple[float, str]]) -> tuple[float, float]:
        try:
            (t, t_unit), (rh, rh_unit) = fields["T"], fields["RH"]
            if rh_unit.upper() not in ("%RH", "%"):
                raise ValueError(rh_unit)
            return celsius(t, t_unit), rh
        except (KeyError, ValueError) as exc:
            raise InstrumentFault(self.name, f"SEND gave no air temperature and humidity with units ({exc})") from None

    def read(self) -> EnvironmentReading:
        fields = self._send()
        pressure_pa = self._pressure_pa(fields)
        if self.MEASURES_AIR:
            t, rh = self._air(fields)
        elif self.thermometer is not None:
            t, rh = self.thermometer.read("*SRTC"), self.thermometer.read("*SRH")
        else:  # never: a barometer is not opened without its thermometer
            raise InstrumentFault(self.name, "no thermometer for the air temperature and humidity")
        material = self.thermometer.read("*SRTC2") if self.thermometer else math.nan
        mount = self.mount_thermometer.read("*SRTC2") if self.mount_thermometer else math.nan
        values = {"air_temperature_c": t, "air_pressure_pa": pressure_pa, "humidity_pct": rh, "material_temperature_c": material,
                  "mount_temperature_c": mount}
        check_ranges(self.name, values)
        return EnvironmentReading(**values)

    def close(self) -> None:
        for part in (self.line, self.thermometer, self.mount_thermometer):
            if part is not None:
                try:
                    part.close()
                except InstrumentError:
                    pass


class VaisalaPtb330(VaisalaPtu300):
    model = "vaisala-ptb330"
    framing = builtin_framing("vaisala-ptb330")
    FORM = '"P=" 4.4 P " " U4 #r #n'
    MEASURES_AIR = False
