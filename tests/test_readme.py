"""Every command README.md and docs/*.md show runs as written, in order, in a temporary copy of the
repository (README in one copy, each document of docs/ in a fresh one of its own).

The commands are the lines of README's ```sh blocks (a trailing ``\\`` joins lines; a line that is
only a comment is skipped). They run in one bash script, block after block, so a command may use
what an earlier one made (``runs/iso``, ``runs/compensated.yaml``) and a block may start a server
in the background and ``kill %1`` it. ``rtcal`` and ``python`` are this checkout's, on the
simulated bench and its virtual clock. A command that fails stops the test with its line.

A command opts out with a marker comment at its end, which README explains to its reader:

- ``# readme-test: skip (why)`` — it cannot run here: it installs packages, needs real
  instruments at the addresses it names, a browser or a running server, or is the test command;
- ``# readme-test: long (why)`` — it runs, but takes minutes: only with ``pytest -m campaign``.

A comment line carrying a marker opens a block: the marker applies to every command of it.
Every certificate the commands write has its own number (``rtcal run`` warns of one beside another
with the same number: the test fails on that warning).

``--trials N`` above TRIALS is run with TRIALS (unless ``--balanced``, whose minimum is the
procedure's: such a line is marked long). The whole script is bounded by TIMEOUT_S (300 s;
``RTCAL_README_TIMEOUT_S`` overrides it on a loaded machine).
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
DOCS = sorted(p for p in (REPO / "docs").glob("*.md") if "```sh" in p.read_text(encoding="utf-8"))
SAME_NUMBER = re.compile(r"certificate number .*give (each certificate|it) its own")
MARKER = re.compile(r"#\s*readme-test:\s*(skip|long)\b")
TRIALS = 2
# CI's bound is 3 min for the whole README (about 55 s of CPU: 60–70 s on 2 idle cores); on a machine
# others load, RTCAL_README_TIMEOUT_S gives more
TIMEOUT_S = float(os.environ.get("RTCAL_README_TIMEOUT_S", "300"))
COPY_IGNORE = shutil.ignore_patterns(".git", ".venv", "runs", "__pycache__", "*.egg-info", ".pytest_cache", ".mypy_cache",
                                     "node_modules")


def readme_commands(text: str) -> list[tuple[int, str]]:
    """(line number, command) of every command in README's sh blocks, in order; a block's end is
    kept as an empty command so that background jobs can be told apart per block."""
    commands: list[tuple[int, str]] = []
    in_block, pending, start, block_marker = False, "", 0, ""
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not in_block:
            in_block, block_marker = stripped in ("```sh", "```bash", "```shell"), ""
            continue
        if stripped.startswith("```"):
            in_block = False
            commands.append((number, ""))
            continue
        if not pending and (not stripped or stripped.startswith("#")):
            block_marker = stripped if MARKER.search(stripped) else block_marker
            continue
        if block_marker and not MARKER.search(stripped):
            stripped = f"{stripped}   {block_marker}" if not stripped.endswith("\\") else stripped
        if not pending:
            start = number
        if stripped.endswith("\\") and not MARKER.search(stripped):
            pending += stripped[:-1] + " "
            continue
        commands.append((start, pending + stripped))
        pending = ""
    return commands


def marker(command: str) -> str | None:
    found = MARKER.search(command)
    return found.group(1) if found else None


def shrink_trials(command: str) -> str:
    """``--trials N`` (N > TRIALS) → ``--trials TRIALS``: the same command, a small Monte Carlo."""
    if "--balanced" in command:
        return command
    return re.sub(r"--trials\s+(\d+)", lambda m: f"--trials {min(int(m.group(1)), TRIALS)}", command)


def script(commands: list[tuple[int, str]], with_long: bool, name: str = "README.md") -> tuple[str, list[str]]:
    """The bash script that runs the commands, and the ones it leaves out (with their line)."""
    lines = ["set -u"]  # `kill %1` finds a background job without job control, and it stays in our process group
    left_out = []
    for number, command in commands:
        if not command:
            continue
        kind = marker(command)
        if kind == "skip" or (kind == "long" and not with_long):
            left_out.append(f"{name}:{number}: {command}")
            continue
        command = shrink_trials(command)
        shown = shlex.quote(f"{name}:{number}: {command}")
        if command.rstrip().endswith("&"):  # a server for the commands after it: started, checked by them
            lines += [f"echo \"+ [$SECONDS s]\" {shown} >&2", command]
            continue
        lines += [f"echo \"+ [$SECONDS s]\" {shown} >&2",
                  f"{{ {command}\n}} || {{ echo \"command failed (exit $?): \"{shown} >&2; exit 1; }}"]
    return "\n".join(lines) + "\n", left_out


def environment(root: Path) -> dict[str, str]:
    """``rtcal`` and ``python`` of this checkout first on PATH, the copy importable."""
    bin_dir = root / ".readme-bin"
    bin_dir.mkdir()
    (bin_dir / "rtcal").write_text(f'#!/bin/sh\nexec {shlex.quote(sys.executable)} -m rtcal.cli "$@"\n')
    (bin_dir / "rtcal").chmod(0o755)
    for name in ("python", "python3"):
        (bin_dir / name).symlink_to(sys.executable)
    env = dict(os.environ)
    # the copy's bytecode is cached as a user's checkout's is: compiled once, not at every command
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    env.update(PATH=f"{bin_dir}{os.pathsep}{env.get('PATH', '')}", PYTHONPATH=str(root), MPLBACKEND="Agg")
    return env


def run_readme(tmp_path: Path, with_long: bool, timeout_s: float, doc: Path = README) -> subprocess.CompletedProcess:
    root = tmp_path / "repo"
    shutil.copytree(REPO, root, ignore=COPY_IGNORE, symlinks=True)
    text, _ = script(readme_commands(doc.read_text(encoding="utf-8")), with_long, str(doc.relative_to(REPO)))
    (root / ".readme.sh").write_text(text)
    proc = subprocess.Popen(["bash", ".readme.sh"], cwd=root, env=environment(root), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, 9)
        out, _ = proc.communicate()
        pytest.fail(f"{doc.name}'s commands took longer than {timeout_s:.0f} s; the last ones:\n{out[-3000:]}")
    finally:
        try:
            os.killpg(proc.pid, 9)  # a server a block left running
        except ProcessLookupError:
            pass
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, "")


def test_readme_commands_parse():
    """The extraction itself: commands in order, continuation lines joined, markers read, trials shrunk
    (so that a README whose commands all opt out cannot pass silently)."""
    text = ("x\n```sh\n# a comment\nrtcal run a.yaml \\\n  --out runs/a\nrtcal uncertainty p.yaml --trials 200   "
            "# note\npip install -e .   # readme-test: skip (installs)\n```\n```yaml\nnot: a command\n```\n")
    commands = readme_commands(text)
    assert [c for _, c in commands if c] == ["rtcal run a.yaml  --out runs/a", "rtcal uncertainty p.yaml --trials 200   # note",
                                               "pip install -e .   # readme-test: skip (installs)"]
    assert commands[0][0] == 4 and marker(commands[2][1]) == "skip"
    assert shrink_trials(commands[1][1]).startswith(f"rtcal uncertainty p.yaml --trials {TRIALS} ")
    body, left_out = script(commands, with_long=False)
    assert "pip install" not in body and left_out == ["README.md:7: pip install -e .   # readme-test: skip (installs)"]
    block = readme_commands("```sh\n# readme-test: skip (a server)\nserve &\nuse \\\n  it\n```\n")
    assert [marker(c) for _, c in block if c] == ["skip", "skip"]  # a marker on a comment line: the whole block


def test_readme_commands_run(tmp_path):
    """README's commands, in order, in a copy of the repository: each must exit 0."""
    commands = readme_commands(README.read_text(encoding="utf-8"))
    runnable = [c for _, c in commands if c and marker(c) is None]
    assert len(runnable) >= 20, "README shows fewer runnable commands than expected: markers misplaced?"
    done = run_readme(tmp_path, with_long=False, timeout_s=TIMEOUT_S)
    assert done.returncode == 0, done.stdout[-4000:]
    assert not SAME_NUMBER.search(done.stdout), SAME_NUMBER.search(done.stdout)[0]  # each certificate its own number


@pytest.mark.slow
@pytest.mark.campaign  # a minute and more: README's commands run in CI (test_readme_commands_run), docs/'s with -m campaign
@pytest.mark.parametrize("doc", DOCS, ids=[d.name for d in DOCS])
def test_docs_commands_run(tmp_path, doc):
    """Each document's commands, in order, in a fresh copy: each must exit 0 with what the
    document itself made (none may rely on README's runs)."""
    done = run_readme(tmp_path, with_long=False, timeout_s=TIMEOUT_S, doc=doc)
    assert done.returncode == 0, done.stdout[-4000:]
    assert not SAME_NUMBER.search(done.stdout), SAME_NUMBER.search(done.stdout)[0]


@pytest.mark.campaign
def test_readme_long_commands_run(tmp_path):
    """The same with the commands marked long (benchmarks, 200-trial Monte Carlos)."""
    done = run_readme(tmp_path, with_long=True, timeout_s=3600)
    assert done.returncode == 0, done.stdout[-4000:]
