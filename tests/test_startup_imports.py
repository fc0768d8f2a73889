"""A command pays only for what it uses (issue 36, item 18): `rtcal --help` and `rtcal validate`
load none of the heavy libraries that only solving, plotting or reporting needs. The figures (wall
time against ``import numpy, yaml, pydantic``) are printed by benchmarks/bench_startup.py; here the
cause is checked, which does not depend on the machine's load."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
HEAVY = ("scipy.stats", "scipy.optimize", "scipy.sparse", "matplotlib", "reportlab", "jinja2", "starlette", "sqlalchemy",
         "alembic", "asyncua", "psycopg")
PROBE = """
import json, runpy, sys
sys.argv = ["rtcal", *sys.argv[1:]]
try:
    runpy.run_module("rtcal.cli", run_name="__main__")
except SystemExit:
    pass
print(json.dumps(sorted(m for m in sys.modules if m.split(".")[0] in {"scipy", "matplotlib", "reportlab", "jinja2", "starlette", "sqlalchemy", "alembic", "asyncua", "psycopg"})), file=sys.stderr)
"""


def _loaded(*argv: str) -> set[str]:
    done = subprocess.run([sys.executable, "-c", PROBE, *argv], capture_output=True, text=True, timeout=120, cwd=REPO)
    return set(json.loads(done.stderr.strip().splitlines()[-1]))


@pytest.mark.parametrize("argv", [("--help",), ("validate", "procedures/laser_tracer_multistation.yaml"),
                                  ("validate", "procedures/encoder_abbe_error.yaml")])
def test_command_loads_no_heavy_library(argv):
    loaded = _loaded(*argv)
    heavy = sorted(m for m in loaded if any(m == h or m.startswith(h + ".") for h in HEAVY))
    assert not heavy, f"rtcal {' '.join(argv)} imports {heavy[:6]}"
