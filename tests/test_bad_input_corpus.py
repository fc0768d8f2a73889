"""The malformed-file corpus (tests/data/bad): every file exits 2 with `file:line:column: field: message`.

Each file's first line says what is expected: ``# expect: LINE FIELD :: TEXT`` — LINE counted
in the file without that comment line (its body), FIELD the reported field, TEXT a part of the
message.
"""

from __future__ import annotations

import json
import re
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from rtcal.cli import main

SMALL = Path(__file__).parent / "data" / "small_multistation.yaml"
CORPUS = sorted((Path(__file__).parent / "data" / "bad").glob("*.yaml"))
EXPECT = re.compile(r"# expect: (\d+) (\S+) :: ?(.*)")


def test_corpus_is_large_enough():
    assert len(CORPUS) >= 80


def _two_gigabytes() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))


def test_whole_corpus_in_bounded_time_and_memory(tmp_path):
    """Every file through `validate` (one process) and through `run` (one process, file after
    file; a scenario as --scenario), each process limited to 2 GB: every file exit 2, none taking 30 s."""
    files = [str(p) for p in CORPUS]
    done = subprocess.run([sys.executable, "-m", "rtcal.cli", "validate", *files], capture_output=True, text=True,
                          timeout=60, preexec_fn=_two_gigabytes)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert all(f"{f}:" in done.stderr for f in files)
    script = (
        "import contextlib, io, json, sys, time\n"
        "from rtcal.cli import main\n"
        f"SMALL = {str(SMALL)!r}\n"
        "out = {}\n"
        "for k, f in enumerate(sys.argv[2:]):\n"
        "    t = time.monotonic()\n"
        "    with contextlib.redirect_stderr(io.StringIO()) as err:\n"
        "        run = [f] if not f.split('/')[-1].startswith('s') else [SMALL, '--scenario', f]\n"
        "        code = main(['run', *run, '--out', f'{sys.argv[1]}/run{k}'])\n"
        "    out[f] = [code, time.monotonic() - t, 'Traceback' in err.getvalue()]\n"
        "print(json.dumps(out))\n")
    done = subprocess.run([sys.executable, "-c", script, str(tmp_path), *files], capture_output=True, text=True,
                          timeout=300, preexec_fn=_two_gigabytes)
    assert done.returncode == 0, done.stderr[-2000:]
    outcomes = json.loads(done.stdout)
    assert len(outcomes) == len(files)
    for f, (code, seconds, traceback) in outcomes.items():
        assert code == 2 and not traceback and seconds < 30, (f, code, seconds)
    assert not list(tmp_path.iterdir()), "a bad procedure started a run"


@pytest.mark.parametrize("path", CORPUS, ids=[p.name for p in CORPUS])
def test_bad_file_is_located(path, tmp_path, capsys):
    m = EXPECT.fullmatch(path.read_text().splitlines()[0])
    assert m, f"{path.name} has no expectation line"
    line, field, text = int(m.group(1)) + 1, m.group(2), m.group(3)  # +1: the expectation line itself
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    pattern = re.compile(rf"^{re.escape(str(path))}:(\d+):(\d+): (.+?): (.*)$")
    located = [pattern.match(e) for e in err]
    assert err and all(located), err
    assert any(int(x.group(1)) == line and x.group(3) == field and text in x.group(4) for x in located), err
    # `run` refuses it as well, before anything moves: a procedure directly, a scenario as --scenario
    run = ["run", str(path)] if not path.name.startswith("s") else ["run", str(SMALL), "--scenario", str(path)]
    assert main([*run, "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert any((x := pattern.match(e)) and int(x.group(1)) == line and x.group(3) == field for e in err), err
    assert not (tmp_path / "run").exists(), "a bad file must not start a run"
