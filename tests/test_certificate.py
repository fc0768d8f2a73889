"""report.html and report.pdf: they open, lead with the result per target and direction with U, the
ISO 230-2 and VDI 3441 parameters and the figures, and carry the metadata."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pymupdf
import pytest

from rtcal.cli import main

REPO = Path(__file__).resolve().parents[1]
PROCEDURES = REPO / "procedures"


@pytest.mark.parametrize("procedure, figures", [
    ("laser_tracer_multistation.yaml", 1), ("encoder_abbe_error.yaml", 4), ("iso230_2_polygon.yaml", 4)])
def test_report_pages(tmp_path, procedure, figures):
    out = tmp_path / "run"
    assert main(["run", str(PROCEDURES / procedure), "--out", str(out)]) == 0
    results = json.loads((out / "results.json").read_text())
    doc = pymupdf.open(out / "report.pdf")
    text = "\n".join(page.get_text() for page in doc)
    assert doc.page_count >= 2 and sum(len(page.get_images()) for page in doc) == figures
    order = [text.index(f"\n{s}") for s in ("Result: positioning deviation per target and direction", "ISO 230-2 and VDI/DGQ 3441",
                                              "Uncertainty budget", "Method\n", "Instruments\n")]
    assert order == sorted(order), "the result comes first, then the parameters, the budget and the method"
    assert "U (k = 2)" in text and results["procedure"]["name"] in text
    rows = len(results["estimates"][results["recommended"]]["cumulative_deviation_arcsec"])
    assert len(re.findall(r"^[↑↓]$", text, re.M)) == rows  # one row per target and direction
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") == figures and "<th>U (k = 2) / ″</th>" in html
    if results["metadata"]["customer"]:
        assert results["metadata"]["customer"] in text and results["metadata"]["customer"] in html
