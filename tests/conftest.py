"""Shared fixtures: the paper's reference tables from ../shared/reference."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
REFERENCE = REPO.parent / "shared" / "reference" / "paper000_tables.json"


@pytest.fixture(scope="session")
def paper_tables() -> dict:
    if not REFERENCE.exists():
        pytest.skip(f"paper tables not found at {REFERENCE}")
    return json.loads(REFERENCE.read_text())
