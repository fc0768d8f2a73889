"""Instrument address strings: the one notation for where an instrument is.

- ``modbus-tcp://HOST:PORT?unit=1&steps_per_rev=10000&gear=36`` — a stepper drive over Modbus TCP
- ``modbus-rtu:///dev/ttyUSB0?unit=1&baud=115200&steps_per_rev=...`` — the same over RS-485
- ``ipp://HOST:PORT`` — a CMM speaking I++ DME (default port 1294)
- ``/dev/ttyUSB0`` or ``socket://HOST:PORT`` (``?baud=9600&...``) — a serial ASCII instrument
- ``sim-operator://HOST:PORT`` — the simulated operator of a protocol-simulator bench
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from urllib.parse import parse_qsl, urlsplit


class AddressError(ValueError):
    """An address string that cannot be understood."""


# every option an address may carry: (lowest, highest, whole number) — a person's bounds, checked
# when the address is parsed so a procedure fails validation, not the drive set-up mid-run
OPTIONS: dict[str, tuple[float, float, bool]] = {
    "unit": (1, 247, True),  # Modbus unicast ids
    "steps_per_rev": (1, 10_000_000, True),
    "gear": (1e-3, 100_000, False),
    "speed_deg_per_s": (1e-6, 3600, False),
    "baud": (50, 10_000_000, True),
    "counts_per_rev": (1, 2**40, True),
}


@dataclass(frozen=True)
class Address:
    scheme: str  # modbus-tcp, modbus-rtu, ipp, serial, sim-operator
    host: str = ""
    port: int = 0
    path: str = ""  # device path for serial and modbus-rtu; the URL for socket://
    options: dict[str, str] = field(default_factory=dict)

    def option(self, name: str, default: float) -> float:
        if name not in self.options:
            return float(default)
        return check_option(name, self.options[name])


def check_option(name: str, text: str) -> float:
    """The option's value, or AddressError naming it and its bounds."""
    lo, hi, whole = OPTIONS[name]
    kind = "a whole number" if whole else "a number"
    try:
        value = float(text) if len(text) <= 30 else math.nan
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and lo <= value <= hi and (not whole or value == int(value))):
        raise AddressError(f"option {name}={text[:40]!r}: must be {kind} from {lo:g} to {hi:g}")
    return value


DEFAULT_STEPS_PER_REV, DEFAULT_GEAR = 10000, 36  # a Modbus stage's address without them: 0.001° per step
MAX_STEP_DEG = 1.0  # a drive whose one step turns the table further is no positioning axis (a mistyped ratio)


def check_step(steps_per_rev: float, gear: float, names: tuple[str, str]) -> None:
    """One motor step of at most MAX_STEP_DEG of the table; AddressError (a ValueError) naming the ratio."""
    step_deg = 360.0 / (steps_per_rev * gear)
    if step_deg > MAX_STEP_DEG:
        raise AddressError(f"{names[1]}: one motor step would turn the table {step_deg:g}° (360° / ({names[0]} × "
                           f"{names[1]})); at most {MAX_STEP_DEG:g}°")


def _options(query: str) -> dict[str, str]:
    options = dict(parse_qsl(query))
    for name, text in options.items():
        if name not in OPTIONS:
            raise AddressError(f"unknown option {name!r} (known: {', '.join(OPTIONS)})")
        check_option(name, text)
    if "steps_per_rev" in options or "gear" in options:
        check_step(float(options.get("steps_per_rev", DEFAULT_STEPS_PER_REV)), float(options.get("gear", DEFAULT_GEAR)),
                   ("steps_per_rev", "gear"))
    return options


def parse_address(text: str) -> Address:
    text = text.strip()
    if not text:
        raise AddressError("empty address")
    if text.startswith(("/", "socket://", "rfc2217://", "loop://")):
        url, _, query = text.partition("?")
        return Address("serial", path=url, options=_options(query))
    parts = urlsplit(text)
    options = _options(parts.query)
    if parts.scheme in ("modbus-tcp", "ipp", "sim-operator"):
        default_port = {"modbus-tcp": 502, "ipp": 1294, "sim-operator": 0}[parts.scheme]
        try:
            port = default_port if parts.port is None else parts.port
        except ValueError:
            raise AddressError(f"{text!r}: bad port (1 to 65535)") from None
        if parts.port == 0:
            raise AddressError(f"{text!r}: port 0 is no port (1 to 65535)")
        if not parts.hostname or not port:
            raise AddressError(f"{text!r}: needs HOST:PORT")
        return Address(parts.scheme, host=parts.hostname, port=port, options=options)
    if parts.scheme == "modbus-rtu":
        if not parts.path:
            raise AddressError(f"{text!r}: needs a device path, e.g. modbus-rtu:///dev/ttyUSB0")
        return Address("modbus-rtu", path=parts.path, options=options)
    raise AddressError(f"{text!r}: unknown kind of address (modbus-tcp://, modbus-rtu://, ipp://, /dev/..., socket://)")
