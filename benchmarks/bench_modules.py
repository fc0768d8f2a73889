"""How many of rtcal's own modules (rtcal, drivers, simulators) a command loads (issue 41, item 4: the registry
loads a method on first use, so a command pays for the method it uses only).

    python benchmarks/bench_modules.py [RUN_DIR]

Prints the count for `rtcal --help`, `rtcal validate procedures/laser_tracer_multistation.yaml`, reading a
results.json (RUN_DIR's, else one written now by a short simulated run of tests/data/small_multistation.yaml)
and `import rtcal.methods.abbe.results`, each in a fresh interpreter.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
COUNT = ("import json, sys\nprint(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] in "
         "('rtcal', 'drivers', 'simulators'))))")
CLI = ("import contextlib, io, runpy, sys\nsys.argv = ['rtcal', *{argv!r}]\nwith contextlib.redirect_stdout(io.StringIO()):\n"
       "    try:\n        runpy.run_module('rtcal.cli', run_name='__main__')\n    except SystemExit:\n        pass\n")


def loaded(code: str) -> list[str]:
    done = subprocess.run([sys.executable, "-c", code + "\n" + COUNT], capture_output=True, text=True, cwd=REPO, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    run_dir = Path(sys.argv[1]) if len(sys.argv) > 1 else None
    with tempfile.TemporaryDirectory() as tmp:
        if run_dir is None:
            run_dir = Path(tmp) / "run"
            subprocess.run([sys.executable, "-m", "rtcal.cli", "run", str(REPO / "tests" / "data" / "small_multistation.yaml"),
                            "--out", str(run_dir)], capture_output=True, cwd=REPO, check=True)
        cases = {
            "rtcal --help": CLI.format(argv=["--help"]),
            "rtcal validate procedures/laser_tracer_multistation.yaml":
                CLI.format(argv=["validate", "procedures/laser_tracer_multistation.yaml"]),
            f"reading a results.json ({run_dir.name})": f"from rtcal.methods import read_results\nread_results({str(run_dir)!r})",
            "import rtcal.methods.abbe.results": "import rtcal.methods.abbe.results",
        }
        for label, code in cases.items():
            modules = loaded(code)
            methods = sorted({m.split(".")[2] for m in modules if m.startswith("rtcal.methods.") and m.count(".") >= 2
                              and m.split(".")[2] in ("abbe", "multistation")})
            print(f"{label:60s} {len(modules):4d} project modules (method folders loaded: {', '.join(methods) or 'none'})")


if __name__ == "__main__":
    main()
