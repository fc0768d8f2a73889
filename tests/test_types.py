"""Static types over the whole tree: mypy as configured in pyproject.toml, and the Python versions
pyproject claims are the ones checked and run."""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("rtcal", "drivers", "simulators")


def _pyproject() -> dict:
    return tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))


def _lowest_python(requires: str) -> tuple[int, int]:
    """(3, 11) from ">=3.11"."""
    m = re.fullmatch(r"\s*>=\s*(\d+)\.(\d+)\s*(,.*)?", requires)
    assert m, f"requires-python {requires!r} does not start with a lowest version"
    return int(m.group(1)), int(m.group(2))


def test_mypy_checks_every_package_at_the_lowest_supported_python():
    """What `python -m mypy` checks is the whole installable tree, for the oldest Python pyproject
    admits, and this interpreter is one pyproject admits."""
    project, config = _pyproject()["project"], _pyproject()["tool"]["mypy"]
    installed = _pyproject()["tool"]["setuptools"]["packages"]["find"]["include"]
    assert sorted(p.rstrip("*") for p in installed) == sorted(PACKAGES)
    assert sorted(config["files"]) == sorted(PACKAGES)
    lowest = _lowest_python(project["requires-python"])
    assert tuple(int(v) for v in config["python_version"].split(".")) == lowest
    assert sys.version_info[:2] >= lowest
    silenced = [o["module"] for o in config.get("overrides", []) if o.get("ignore_errors")]
    assert not silenced, f"modules whose type errors are ignored: {silenced}"


def test_the_type_checker_passes(tmp_path):
    """mypy as configured in pyproject.toml: rtcal, drivers and simulators; strict on the results
    model and the method protocol, and the method classes checked against the protocol
    (rtcal/methods/__init__.py). From a cold cache, as in CI."""
    done = subprocess.run([sys.executable, "-m", "mypy", "--cache-dir", str(tmp_path / "mypy_cache")],
                          cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
    assert "Success: no issues found" in done.stdout
