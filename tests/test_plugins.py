"""Driver plugins: the replay helper rtcal ships for plugin authors, and a sample plugin package
(tests/plugins/acme_bridge) installed into a fresh environment and used there by `rtcal probe`
and by a wired run, with no change to rtcal's code."""

from __future__ import annotations

import base64
import hashlib
import json
import subprocess
import sys
import sysconfig
import tomllib
import zipfile
from pathlib import Path

import pytest

from drivers import factory
from drivers.errors import InstrumentTimeout
from drivers.testing import ExchangeMismatch, replay
from simulators.scenario import Scenario
from simulators.servers.hub import SimulatorHub

REPO = Path(__file__).resolve().parents[1]
PLUGIN = REPO / "tests" / "plugins" / "acme_bridge"


def test_replay_checks_every_byte_and_feeds_the_replies():
    with replay([(b"d\r\n", b"8 30123 15 01 2026 300\r"), (b"a\r\n", b"4 003 12.34 -5.67\r")]) as line:
        autocollimator = factory.open_instrument("autocollimator", "socket://device:1?model=elcomat", 1.0)
        assert autocollimator.read_arcsec() == (12.34, -5.67)
    line.assert_done()
    assert (line.framing["baudrate"], line.framing["bytesize"], line.framing["parity"]) == (19200, 8, "N")


def test_replay_names_the_byte_that_differed():
    with replay([(b"R0E\r\n", b"r0E00000001!\r\n")]):
        with pytest.raises(ExchangeMismatch, match=r"request 1, byte 1: expected b'R' \(0x52\), got b'W' \(0x57\)"):
            factory.open_instrument("encoder", "socket://device:1?model=qsb", 1.0)  # the counter is set up first


def test_replay_silence_and_an_unfinished_exchange():
    with replay([(b"MM\r", None), (b"UNI?\r", b"MM\r"), (b"ID?\r", b"ERR1\r"), (b"?\r", None),
                 (b"?\r", b"+1.0\r")]) as line:
        indicator = factory.open_instrument("dial_indicator", "socket://device:1", 1.0, name="dial_indicator_1")
        with pytest.raises(InstrumentTimeout, match="no reply"):
            indicator.read_um()
    with pytest.raises(ExchangeMismatch, match=r"stopped after request 4 of 5; request 5 \(b'\?\\r'\) never came"):
        line.assert_done()


def test_the_sample_plugin_with_replay():
    sys.path.insert(0, str(PLUGIN))
    try:
        from rtcal_acme_bridge import AcmeBridgeTracer
    finally:
        sys.path.remove(str(PLUGIN))
    from drivers.addresses import parse_address

    with replay([(b"REF\r\n", b"OK REF 0\r\n"), (b"LEN?\r\n", b"LEN 1500.000 0\r\n")]) as line:
        tracer = AcmeBridgeTracer(parse_address("socket://bridge:4001"), 1.0)
        assert tracer.reference() == 0 and tracer.read_length().length_mm == pytest.approx(1.5e-3)
    line.assert_done()


def _wheel(package: Path, out: Path) -> Path:
    """The package's wheel, from its pyproject.toml (a single module and its entry points)."""
    meta = tomllib.loads((package / "pyproject.toml").read_text())["project"]
    name, version = meta["name"].replace("-", "_"), meta["version"]
    module = tomllib.loads((package / "pyproject.toml").read_text())["tool"]["setuptools"]["py-modules"][0]
    info = f"{name}-{version}.dist-info"
    files = {
        f"{module}.py": (package / f"{module}.py").read_bytes(),
        f"{info}/METADATA": f"Metadata-Version: 2.1\nName: {meta['name']}\nVersion: {version}\n".encode(),
        f"{info}/WHEEL": b"Wheel-Version: 1.0\nGenerator: rtcal-tests\nRoot-Is-Purelib: true\nTag: py3-none-any\n",
        f"{info}/entry_points.txt": "".join(f"[{group}]\n" + "".join(f"{k} = {v}\n" for k, v in eps.items())
                                            for group, eps in meta["entry-points"].items()).encode(),
    }
    digest = lambda data: base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()  # noqa: E731
    record = "".join(f"{path},sha256={digest(data)},{len(data)}\n" for path, data in files.items()) + f"{info}/RECORD,,\n"
    wheel = out / f"{name}-{version}-py3-none-any.whl"
    with zipfile.ZipFile(wheel, "w") as z:
        for path, data in {**files, f"{info}/RECORD": record.encode()}.items():
            z.writestr(path, data)
    return wheel


def venv_with_plugin(package: Path, tmp: Path, *more: Path) -> Path:
    """A fresh venv that sees rtcal (and its dependencies) but not the tests' process, with ``package``
    (one of tests/plugins/, and any ``more``) installed into it by pip from its wheel; its python."""
    fresh = tmp / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(fresh)], check=True, timeout=60)
    python = fresh / "bin" / "python"
    site = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    (site / "rtcal_base.pth").write_text(f"import site; site.addsitedir({sysconfig.get_paths()['purelib']!r})\n")
    install = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-index", "--no-compile", "--quiet",
                              "--prefix", str(fresh), *(str(_wheel(p, tmp)) for p in (package, *more))],
                             capture_output=True, text=True, timeout=120)
    assert install.returncode == 0, install.stderr
    return python


@pytest.mark.slow
def test_an_installed_plugin_adds_a_model_for_probe_and_a_wired_run(tmp_path):
    """A fresh venv that sees rtcal (and its dependencies) but not this test's process; the sample
    plugin installed into it with pip from a wheel of tests/plugins/acme_bridge; there `rtcal
    probe` reads a tracer with model=acme-bridge and a wired multistation run uses it."""
    python = venv_with_plugin(PLUGIN, tmp_path)
    with pytest.raises(Exception, match="unknown model 'acme-bridge'"):  # this process has no such plugin
        factory.resolve("laser_tracer", "socket://h:1?model=acme-bridge")

    with SimulatorHub(Scenario(), seed=3, serial="tcp") as hub:
        addresses = dict(hub.addresses, laser_tracer=hub.addresses["laser_tracer"].replace("model=rtcal-line", "model=acme-bridge"))
        probe = subprocess.run([str(python), "-m", "rtcal.cli", "probe", "laser_tracer", addresses["laser_tracer"], "--json"],
                               capture_output=True, text=True, timeout=60, cwd=tmp_path)
        assert probe.returncode == 0, probe.stderr
        result = json.loads(probe.stdout)
        assert result["model"] == "acme-bridge" and result["identity"] == "ACME laser-tracer bridge"
        assert result["reading"] == {"length_mm": 0.0}
        (tmp_path / "a.json").write_text(json.dumps(addresses))
        procedure = REPO / "tests" / "data" / "small_multistation.yaml"
        run = subprocess.run([str(python), "-m", "rtcal.cli", "run", str(procedure), "--instruments", str(tmp_path / "a.json"),
                              "--virtual-clock", "--out", str(tmp_path / "run")], capture_output=True, text=True, timeout=300,
                             cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    results = json.loads((tmp_path / "run" / "results.json").read_text())
    assert results["instruments"]["laser_tracer"].endswith("model=acme-bridge")
    assert results["raw_readings"] > 0 and results["skipped_readings"] == 0, results["skipped_readings"]
    assert results["estimates"][results["recommended"]]["converged"]
