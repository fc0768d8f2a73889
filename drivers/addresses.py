"""Instrument address strings: the one notation for where an instrument is.

- ``modbus-tcp://HOST:PORT?unit=1&steps_per_rev=10000&gear=36`` — a stepper drive over Modbus TCP
- ``modbus-rtu:///dev/ttyUSB0?unit=1&baud=115200&steps_per_rev=...`` — the same over RS-485
- ``ipp://HOST:PORT`` — a CMM speaking I++ DME (default port 1294); ``?home=1`` lets a run home it
- ``/dev/ttyUSB0`` or ``socket://HOST:PORT`` (``?model=sylvac&baud=4800&bytesize=7&parity=E&stopbits=2``) — a
  serial instrument; framing options the address leaves out are the model's defaults
- ``sim-operator://HOST:PORT?token=…`` — the simulated operator of a protocol-simulator bench
- ``linuxcncrsh://HOST:PORT?axis=C&joint=0&take_control=1`` — a LinuxCNC controller's rotary axis (A, B or C) over its
  linuxcncrsh text interface (default port 5007; model ``linuxcnc``)

``model=`` names the product whose protocol the driver speaks (drivers/models.py; an installed
plugin can add one); without it each kind has its one built-in product.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from urllib.parse import parse_qsl, urlsplit

from drivers.errors import AddressError
from drivers.models import find_model

# every option an address may carry: (lowest, highest, whole number) — a person's bounds, checked
# when the address is parsed so a procedure fails validation, not the drive set-up mid-run
OPTIONS: dict[str, tuple[float, float, bool]] = {
    "unit": (1, 247, True),  # Modbus unicast ids
    "steps_per_rev": (1, 10_000_000, True),
    "gear": (1e-3, 100_000, False),
    "speed_deg_per_s": (1e-6, 3600, False),
    "speed_mm_per_s": (1e-6, 10_000, False),  # LinuxCNC machine tool: the feed of a move of the held point
    "baud": (50, 10_000_000, True),
    "counts_per_rev": (1, 2**40, True),
    "bytesize": (7, 8, True),  # serial framing: data bits
    "stopbits": (1, 2, True),
    "home": (0, 1, True),  # a CMM (I++) or a LinuxCNC joint: 1 lets rtcal home an unhomed machine (else refused)
    "joint": (0, 15, True),  # LinuxCNC: the rotary axis's joint number
    "move_timeout_s": (0.1, 3600, False),  # LinuxCNC: the longest wait for one move
    "take_control": (0, 1, True),  # LinuxCNC: 1 lets rtcal take control from any other linuxcncrsh console
}
ROTARY_AXES = "ABC"  # LinuxCNC's rotary axis letters (X Y Z U V W are linear)
# options whose value is text: a pattern it must match and what to call it in a message
TEXT_OPTIONS: dict[str, tuple[str, str]] = {
    "model": (r"[a-z0-9][a-z0-9._-]{0,63}", "a model name such as sylvac or oriental-az"),
    "parity": (r"[NEO]", "N, E or O"),
    "token": (r"[A-Za-z0-9_-]{8,128}", "8 to 128 letters, digits, - or _"),
    "thermometer": (r"[^\s]{1,500}", "the address of a thermometer (socket://HOST:PORT or a device path)"),
    "mount_thermometer": (r"[^\s]{1,500}", "the address of a second thermometer, its probe 2 on the tracer's mount "
                                           "(socket://HOST:PORT or a device path)"),
    "axis": (r"[XYZABCUVWxyzabcuvw]|[1-9][0-9]?", "an axis letter X Y Z A B C U V W (LinuxCNC, e.g. C) or an axis "
                                                  "number 1 … 99 (PI GCS, e.g. 1)"),
}


@dataclass(frozen=True)
class Address:
    scheme: str  # modbus-tcp, modbus-rtu, ipp, serial, sim-operator, linuxcncrsh
    host: str = ""
    port: int = 0
    path: str = ""  # device path for serial and modbus-rtu; the URL for socket://
    options: dict[str, str] = field(default_factory=dict)

    def option(self, name: str, default: float) -> float:
        if name not in self.options:
            return float(default)
        return check_option(name, self.options[name], OPTIONS.get(name) or _model_option(self.options, name))

    def text(self, name: str, default: str = "") -> str:
        """A text option (model, parity, token, thermometer), or ``default``."""
        return self.options.get(name, default)


def check_option(name: str, text: str, bounds: tuple[float, float, bool] | None = None) -> float:
    """The option's value, or AddressError naming it and its bounds."""
    lo, hi, whole = bounds or OPTIONS[name]
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


def _model_option(options: dict[str, str], name: str) -> tuple[float, float, bool] | None:
    """The bounds of an option the address's model declares for itself (a plugin's own options)."""
    if "model" not in options:
        return None
    try:
        return find_model(options["model"]).options.get(name)
    except AddressError:
        return None


def _options(query: str) -> dict[str, str]:
    try:
        pairs = parse_qsl(query, strict_parsing=bool(query), max_num_fields=32)
    except ValueError as exc:
        raise AddressError(f"options {redact_tokens(query[:80])!r}: {exc}") from None
    options = dict(pairs)
    if len(options) != len(pairs):
        raise AddressError(f"options {redact_tokens(query[:80])!r}: an option given twice")
    if "model" in options:
        check_text("model", options["model"])
        find_model(options["model"])  # an unknown model is refused here, where the address is read
    for name, text in options.items():
        if name in TEXT_OPTIONS:
            check_text(name, text)
        elif name in OPTIONS:
            check_option(name, text)
        elif (bounds := _model_option(options, name)) is not None:
            check_option(name, text, bounds)
        else:
            raise AddressError(f"unknown option {name!r} (known: {', '.join([*OPTIONS, *TEXT_OPTIONS])})")
    for name in ("thermometer", "mount_thermometer"):
        if name in options and parse_address(options[name]).scheme != "serial":
            raise AddressError(f"option {name}={options[name][:60]!r}: a serial or socket:// address")
    if "steps_per_rev" in options or "gear" in options:
        check_step(float(options.get("steps_per_rev", DEFAULT_STEPS_PER_REV)), float(options.get("gear", DEFAULT_GEAR)),
                   ("steps_per_rev", "gear"))
    return options


def check_text(name: str, text: str) -> str:
    """A text option's value, or AddressError saying what it must be."""
    pattern, what = TEXT_OPTIONS[name]
    if not re.fullmatch(pattern, text):
        shown = REDACTED if name == "token" else repr(text[:40])  # a token is never echoed, not even a wrong one
        raise AddressError(f"option {name}={shown}: must be {what}")
    return text


def check_take_control(address: Address) -> None:
    """A LinuxCNC address that will move the table says ``take_control=1``: ``set enable`` takes control
    from any other linuxcncrsh console, and linuxcncrsh cannot tell whether one holds it."""
    if address.scheme == "linuxcncrsh" and address.option("take_control", 0) != 1:
        raise AddressError("a LinuxCNC stage that rtcal moves needs take_control=1 in its address: rtcal takes control "
                           "of the machine (linuxcncrsh `set enable`) from any other linuxcncrsh console — an operator's, "
                           "a cell controller's — which then loses it silently, and linuxcncrsh cannot tell whether one "
                           "holds it; add take_control=1 once no one else commands the machine over linuxcncrsh")


REDACTED = "…"  # what a stored address carries in place of a token's value
_TOKEN_VALUE = re.compile(r"(token=)[^&\s\"'#\\]*")
MAX_ADDRESS_CHARS = 2000


def redact_tokens(text: str) -> str:
    """``text`` with the value of every ``token=`` replaced by ``…``: what the store, results, report
    and logs hold of an address, so a copy of a run directory commands nothing."""
    return _TOKEN_VALUE.sub(lambda m: m.group(1) + REDACTED, text)


def _shown(text: str) -> str:
    """An address as a message shows it: tokens redacted, bounded."""
    text = redact_tokens(text)
    return repr(text if len(text) <= 120 else text[:120] + "…")


def _check_characters(text: str) -> None:
    """ASCII only, no control characters: a full-width digit or a look-alike host is no address."""
    for i, c in enumerate(text):
        if not c.isascii() or not c.isprintable():
            raise AddressError(f"{_shown(text)}: character {i + 1} (U+{ord(c):04X}) is not a printable ASCII character; "
                               "addresses are written in ASCII")


def _split(text: str):
    """urlsplit, with its refusals (a bracket left open, a bad port) as AddressError; credentials refused."""
    try:
        parts = urlsplit(text)
    except ValueError as exc:
        raise AddressError(f"{_shown(text)}: malformed address ({exc}); e.g. modbus-tcp://HOST:PORT") from None
    try:
        parts.port  # noqa: B018 — raises ValueError for a port that is no number or beyond 65535
    except ValueError:
        raise AddressError(f"{_shown(text)}: bad port (1 to 65535)") from None
    if "@" in parts.netloc:
        raise AddressError(f"{_shown(text)}: credentials (user:password@) in an address are refused: rtcal would store "
                           "them with the run; an instrument's password is not part of its address")
    return parts


def parse_address(text: str) -> Address:
    text = text.strip()
    if not text:
        raise AddressError("empty address")
    if len(text) > MAX_ADDRESS_CHARS:
        raise AddressError(f"{_shown(text)}: an address of {len(text)} characters; at most {MAX_ADDRESS_CHARS}")
    _check_characters(text)
    if text.startswith(("/", "socket://", "rfc2217://", "loop://")):
        url, _, query = text.partition("?")
        if url.startswith(("socket://", "rfc2217://")):
            net = _split(url)
            if not net.hostname or net.port is None or net.path not in ("", "/"):
                raise AddressError(f"{_shown(text)}: needs HOST:PORT (e.g. socket://10.0.0.5:4001)")
        return Address("serial", path=url, options=_options(query))
    parts = _split(text)
    options = _options(parts.query)
    if parts.scheme in ("modbus-tcp", "ipp", "sim-operator", "linuxcncrsh"):
        default_port = {"modbus-tcp": 502, "ipp": 1294, "sim-operator": 0, "linuxcncrsh": 5007}[parts.scheme]
        try:
            port = default_port if parts.port is None else parts.port
        except ValueError:
            raise AddressError(f"{_shown(text)}: bad port (1 to 65535)") from None
        if parts.port == 0:
            raise AddressError(f"{_shown(text)}: port 0 is no port (1 to 65535)")
        if not parts.hostname or not port:
            raise AddressError(f"{_shown(text)}: needs HOST:PORT")
        if parts.path not in ("", "/") or parts.fragment:
            raise AddressError(f"{_shown(text)}: nothing may follow HOST:PORT but ?options")
        if parts.scheme == "linuxcncrsh" and options.get("axis", "C").upper() not in ROTARY_AXES:
            # G0 <letter> moves the letter's axis whatever joint= says: a linear letter moves a slide, not the table
            raise AddressError(f"option axis={options['axis']!r}: a LinuxCNC rotary axis is A, B or C (X Y Z U V W are "
                               "linear: rtcal would move a slide and report it as the table)")
        return Address(parts.scheme, host=parts.hostname, port=port, options=options)
    if parts.scheme == "modbus-rtu":
        if not parts.path:
            raise AddressError(f"{_shown(text)}: needs a device path, e.g. modbus-rtu:///dev/ttyUSB0")
        return Address("modbus-rtu", path=parts.path, options=options)
    raise AddressError(f"{_shown(text)}: unknown kind of address (modbus-tcp://, modbus-rtu://, ipp://, linuxcncrsh://, /dev/..., "
                       "socket://)")
