"""`rtcal sim serve`'s choices, each product once, without importing the simulators: the stage (as
SimulatorHub's ``stage`` and ``stage_model``), the environment sensor, and how serial instruments
and the Modbus drive are reached (simulators/servers/hub.py)."""

from __future__ import annotations

STAGES: dict[str, dict[str, str]] = {
    "oriental-az": {"stage": "modbus", "stage_model": "oriental-az"},  # an Oriental AZ drive over Modbus
    "pi-gcs": {"stage": "modbus", "stage_model": "pi-gcs"},  # a PI controller, GCS on a serial line
    "linuxcnc": {"stage": "linuxcnc", "stage_model": "oriental-az"},  # a real LinuxCNC started headless
}
DEFAULT_STAGE = "oriental-az"
ENVIRONMENT_MODELS = ("vaisala-ptu300", "vaisala-ptb330")
SERIAL_TRANSPORTS = ("pty", "tcp")
MODBUS_TRANSPORTS = ("tcp", "rtu")
