"""Issue 44 item 1: a second material probe on the tracer's mount. The driver reads it from a second iTHX
(`mount_thermometer=`, docs/protocols/environment.md), the simulator from the bench's mount region, the store keeps
it raw beside the table's, and a procedure that states it corrects the lengths with the mount's temperature: the
gradient between the table's sensor and the mount is then measured, not budgeted."""

from __future__ import annotations

import json
import math
import socket
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from rtcal.cli import main
from rtcal.clock import VirtualClock
from rtcal.methods import load_procedure
from rtcal.deliverables.certificate import conditions, conditions_in_brief
from rtcal.methods.conditions import summarise_conditions
from rtcal.methods.multistation.method import failure_causes, on_mount_probe
from rtcal.results.model import EnvironmentSummary
from rtcal.methods.multistation.noise import noise_model
from rtcal.solvers.station_budget import (
    MOUNT_GRADIENT_SOURCE,
    THERMAL_MOUNT_NOISE_SOURCE,
    THERMAL_MOUNT_SENSOR_SOURCE,
    THERMAL_SENSOR_SOURCE,
    mount_gradient_sources,
    sensor_noise_sources,
    table_expansion_sources,
)
from rtcal.solvers.station_data import MountReadings, MultistationData
from simulators.bench import Bench
from simulators.instruments import SimEnvironmentSensor
from simulators.scenario import Scenario
from tests import emulators as emu
from tests.emulators import Emulator, VaisalaEmulator

MC = Path(__file__).resolve().parent / "data" / "mc"


def _mount_ithx(line: bytes, state: dict) -> bytes:
    """A second iTHX whose probe 2 touches the tracer's mount (its probe 1 hangs unused)."""
    return {b"*SRTC": b"20.4\r", b"*SRTC2": b"21.3\r"}.get(line, b"Serial Time Out\r")


def test_a_second_ithx_on_mount_thermometer_is_read_as_the_mounts_temperature(capsys):
    with VaisalaEmulator("PTU300", echo=False) as unit, Emulator(emu.ithx) as table, Emulator(_mount_ithx) as mount:
        code = main(["probe", "environment", f"{unit.url()}?model=vaisala-ptu300&thermometer={table.url()}"
                     f"&mount_thermometer={mount.url()}", "--json", "--timeout-s", "2"])
        out, err = capsys.readouterr()
    assert code == 0, err
    reading = json.loads(out)["reading"]
    assert reading["material_temperature_c"] == pytest.approx(25.1)  # the table: the first iTHX's probe 2
    assert reading["mount_temperature_c"] == pytest.approx(21.3)  # the mount: the second iTHX's probe 2
    assert mount.requests == [b"*SRTC2"]


def test_a_mount_thermometer_that_is_no_address_is_refused(capsys):
    code = main(["probe", "environment", "/dev/ttyUSB1?model=vaisala-ptu300&mount_thermometer=ipp://cmm:1294",
                 "--timeout-s", "1"])
    _, err = capsys.readouterr()
    assert code == 2 and "mount_thermometer=" in err and "Traceback" not in err


def test_the_simulated_mount_probe_reads_the_mount_region_and_leaves_the_other_draws_alone():
    sc = Scenario.model_validate(yaml.safe_load((MC / "gradient_bench.yaml").read_text(encoding="utf-8")))
    clock = VirtualClock()
    with_probe, without = SimEnvironmentSensor(Bench(sc, clock, 3), mount_probe=True), SimEnvironmentSensor(Bench(sc, clock, 3))
    first, first_with = without.read(), with_probe.read()
    assert math.isnan(first.mount_temperature_c) and first_with.mount_temperature_c == pytest.approx(20.0, abs=0.05)
    # the mount's noise is drawn after the sensor's others: the same bench reads the same air and table with or without it
    fields = ("air_temperature_c", "air_pressure_pa", "humidity_pct", "material_temperature_c")
    assert [getattr(first_with, f) for f in fields] == [getattr(first, f) for f in fields]
    clock.sleep(3600.0)
    a = with_probe.read()
    assert a.material_temperature_c == pytest.approx(21.0, abs=0.05)  # the table's sensor: 1 K/h
    assert a.mount_temperature_c == pytest.approx(21.5, abs=0.05)  # the mount's region: as at 1.5 K/h


def _data(table_c: float, mount_c: float | None) -> MultistationData:
    n, m = 4, 3
    full = lambda v: None if v is None else np.full((n, m), v)  # noqa: E731
    other = MountReadings(np.ones((n, m)), np.zeros((n, m)), np.zeros((n, m)), None, None, full(table_c), full(mount_c))
    return MultistationData(np.zeros((n, 3)), np.ones((n, m)), np.zeros((n, m)), np.zeros(m),
                            other_mounts=(other,), material_temperature_c=full(table_c), mount_temperature_c=full(mount_c))


def test_a_stated_mount_probe_corrects_with_the_mounts_temperature_and_budgets_no_gradient():
    one, two = load_procedure(MC / "gradient.yaml"), load_procedure(MC / "gradient_two_sensors.yaml")
    swapped = on_mount_probe(_data(21.0, 21.5), two)
    assert np.all(swapped.material_temperature_c == 21.5) and np.all(swapped.other_mounts[0].material_temperature_c == 21.5)
    assert np.all(on_mount_probe(_data(21.0, 21.5), one).material_temperature_c == 21.0)  # not stated: the table's
    unread = on_mount_probe(_data(21.0, None), two)  # stated but not read (no mount_thermometer=): the table's
    assert np.all(unread.material_temperature_c == 21.0) and unread.mount_temperature_c is None

    radial, offset, frac = np.full(6, 60.0), np.linspace(0.0, 1.5, 6), np.linspace(-1, 1, 6)
    unit, stations = np.tile([1.0, 0.0, 0.0], (6, 1)), np.tile([60.0, 0.0, 0.0], (6, 1))
    names = lambda noise: {s.name for s in mount_gradient_sources(radial, offset, frac, noise)  # noqa: E731
                           + table_expansion_sources(unit, stations, np.zeros(3), np.array([0, 0, 1.0]), offset, noise)
                           + sensor_noise_sources(radial, radial, offset, noise) if s.name.startswith("thermal")}
    assert names(noise_model(one)) >= {MOUNT_GRADIENT_SOURCE, THERMAL_SENSOR_SOURCE}
    on_mount = noise_model(two)
    assert on_mount.material_temperature_sigma_k == 0.05 and on_mount.mount_gradient_share == 0.0
    assert names(on_mount) == {THERMAL_MOUNT_SENSOR_SOURCE, THERMAL_MOUNT_NOISE_SOURCE,
                               "thermal expansion of the table (coefficient)"}
    # the readings carry no mount temperature: the table's sensor, and its gradient line, as without the probe
    fallback = noise_model(two, mount_probe=False)
    assert fallback.mount_gradient_share == 0.5 and fallback.mount_gradient_assumed
    stated = replace(on_mount, mount_gradient_share=0.1)  # a share stated against the mount probe stays a line
    assert MOUNT_GRADIENT_SOURCE in names(stated)


def _hub(**options):
    from simulators.servers.hub import SimulatorHub

    sc = Scenario.model_validate(yaml.safe_load((MC / "gradient_bench.yaml").read_text(encoding="utf-8")))
    return SimulatorHub(sc, seed=3, serial="tcp", pace_serial=False, **options)


def test_sim_serve_serves_the_mount_probe_as_a_second_ithx_on_its_own_port(capsys):
    with _hub() as hub:  # by default: no second iTHX (the readings as a procedure without the probe draws them)
        assert "mount_thermometer=" not in hub.addresses["environment"]
    with _hub(mount_thermometer=True) as hub:
        address = hub.addresses["environment"]
        table, mount = address.split("&thermometer=")[1].split("&mount_thermometer=")
        assert mount.startswith("socket://127.0.0.1:") and mount != table
        hub.bench.clock.sleep(3600.0)  # the table's sensor reads 1 K/h, the mount's region warms as at 1.5 K/h
        code, out, err = main(["probe", "environment", address, "--json", "--timeout-s", "2"]), *capsys.readouterr()
        host, port = mount.removeprefix("socket://").split(":")
        with socket.create_connection((host, int(port)), timeout=2) as s:  # the product's own question, on the wire
            s.sendall(b"*SRTC2\r")
            raw = s.recv(64)
    assert code == 0, err
    reading = json.loads(out)["reading"]
    assert reading["material_temperature_c"] == pytest.approx(21.0, abs=0.15)
    assert reading["mount_temperature_c"] == pytest.approx(21.5, abs=0.15)
    assert raw.endswith(b"\r") and float(raw) == pytest.approx(reading["mount_temperature_c"], abs=0.051)


@pytest.mark.campaign  # ~9 s over the wires; the hub's test above reads the mount probe through its socket in CI
def test_a_procedure_with_the_mount_probe_runs_over_sim_serve_as_in_process(tmp_path):
    """A procedure that states the mount probe, over the hub's wires with mount_thermometer= (a change of addresses):
    the same raw readings as the in-process run of the same bench and seed, and the mount probe's budget lines."""
    from rtcal.run.runner import run_procedure

    text = (MC / "gradient_two_sensors.yaml").read_text(encoding="utf-8")
    procedure = tmp_path / "small.yaml"  # few points and stations: seconds, not minutes, over the wires
    procedure.write_text(text.replace("count: 11", "count: 6").replace("step_deg: 30", "step_deg: 60")
                         .replace("layers: 4", "layers: 2").replace("columns: 4", "columns: 3").replace("rows: 4", "rows: 3")
                         .replace("bench: gradient_bench.yaml\n", ""), encoding="utf-8")
    local = run_procedure(procedure, MC / "gradient_bench.yaml", out_dir=tmp_path / "local", seed=3,
                          show_progress=False).results
    with _hub(mount_thermometer=True) as hub:
        remote = run_procedure(procedure, out_dir=tmp_path / "remote", show_progress=False,
                               addresses=dict(hub.addresses), virtual_clock=True).results
    assert remote.raw_readings == local.raw_readings and remote.truth is None
    for results in (local, remote):  # the lengths corrected with the mount probe's readings: its lines, no gradient's
        names = {c.source for c in results.estimates.named("network").uncertainty_budget.components}
        assert THERMAL_MOUNT_SENSOR_SOURCE in names and MOUNT_GRADIENT_SOURCE not in names
    # the same deviations within their uncertainty: the wire rounds the iTHX's readings to 0.1 K (the product's)
    a, b = (np.array(r.estimates.named("network").cumulative_deviation_arcsec, float) for r in (local, remote))
    u = np.array(local.estimates.named("network").cumulative_expanded_uncertainty_arcsec, float)
    assert np.max(np.abs(a - b)[1:] / u[1:]) < 1.0  # the first target is the reference: 0 ± 0


def test_the_mount_probes_range_is_in_the_results_and_the_certificates_conditions():
    """results.json's environment and the certificate's conditions table give the mount probe's range as the table's."""
    mount = [20.02, 20.31, 20.58]
    groups = [{"air_temperature_c": [20.0], "material_temperature_c": [20.0 + 0.1 * i], "mount_temperature_c": [t]}
              for i, t in enumerate(mount)]
    summary = EnvironmentSummary.model_validate(summarise_conditions(groups))
    assert summary.mount_temperature_c is not None
    assert (summary.mount_temperature_c.min, summary.mount_temperature_c.max) == (min(mount), max(mount))
    assert summary.mount_temperature_c.mean == pytest.approx(sum(mount) / 3, abs=1e-4)

    class Method:  # what the certificate asks of a method: the conditions its results recorded
        def conditions(self, results: object) -> EnvironmentSummary:
            return summary

    rows = dict(conditions(None, Method()))  # type: ignore[arg-type]
    row = [v for k, v in rows.items() if k.startswith("the tracer's mount") and k.endswith("/ °C")]
    assert row == [f"{min(mount):g} – {max(mount):g} (mean {summary.mount_temperature_c.mean:g})"]
    assert f"the tracer's mount's temperature (a second probe) {min(mount):g} – {max(mount):g} °C" in \
        conditions_in_brief(None, Method())  # type: ignore[arg-type]
    # without the probe: no row (the usual sensor)
    assert "mount_temperature_c" not in summarise_conditions([{k: v for k, v in g.items() if k != "mount_temperature_c"}
                                                              for g in groups])


def test_a_failed_test_with_the_mount_probe_names_the_probe_not_the_gradient():
    """What a failed residual test means: with the lengths corrected by the mount probe, the probe not reading the
    mount (within its stated uncertainty); with the table's sensor alone (or the probe not read), the gradient."""
    one, two = load_procedure(MC / "gradient.yaml"), load_procedure(MC / "gradient_two_sensors.yaml")
    probe = lambda causes: [c for c in causes if c.startswith("the probe on the tracer's mount")]  # noqa: E731
    gradient = lambda causes: [c for c in causes if c.startswith("the tracer's mount changes temperature")]  # noqa: E731
    with_probe = failure_causes(two, noise_model(two))
    assert len(probe(with_probe)) == 1 and not gradient(with_probe)
    assert "± 0.05 K" in probe(with_probe)[0]  # the probe's stated mount_temperature_k
    for causes in (failure_causes(one, noise_model(one)), failure_causes(two, noise_model(two, mount_probe=False))):
        assert not probe(causes) and len(gradient(causes)) == 1
    stated = failure_causes(two, replace(noise_model(two), mount_gradient_share=0.1))  # a share stated with the probe
    assert "beyond ± 10% of its change" in probe(stated)[0]
