"""The malformed-file corpus (tests/data/bad): every file exits 2 with `file:line:column: field: message`.

Each file's first line says what is expected: ``# expect: LINE FIELD :: TEXT`` — LINE counted
in the file without that comment line (its body), FIELD the reported field, TEXT a part of the
message.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from rtcal.cli import main

CORPUS = sorted((Path(__file__).parent / "data" / "bad").glob("*.yaml"))
EXPECT = re.compile(r"# expect: (\d+) (\S+) :: ?(.*)")


def test_corpus_is_large_enough():
    assert len(CORPUS) >= 30


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
    if not path.name.startswith("s"):
        assert main(["run", str(path), "--out", str(tmp_path / "run")]) == 2
        assert not (tmp_path / "run").exists(), "a bad procedure must not start a run"
