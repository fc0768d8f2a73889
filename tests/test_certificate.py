"""report.pdf and report.html as a calibration certificate (ISO/IEC 17025:2017 7.8.2.1, 7.8.4.1):
read from the PDF's text with PyMuPDF — every item present, page 1 carrying what a reviewer reads
first, every page ending with "page N of M" — and the order of the sections after it."""

from __future__ import annotations

import re
from pathlib import Path

import pymupdf
import pytest
import yaml

from rtcal.cli import main
from rtcal.methods import read_results

REPO = Path(__file__).resolve().parents[1]
PROCEDURES = REPO / "procedures"
RUNS = {"iso": ("iso230_2_polygon.yaml", 4), "seed000": ("laser_tracer_multistation.yaml", 1),
        "seed001": ("encoder_abbe_error.yaml", 4), "seed001-no-lab": ("encoder_abbe_error.yaml", 4)}


@pytest.mark.parametrize("name", list(RUNS))
def test_report(tmp_path, name):
    """One shipped procedure run end to end, its report read as a reviewer would: each check below."""
    procedure, figures = RUNS[name]
    out, path = tmp_path / "run", PROCEDURES / procedure
    data = yaml.safe_load(path.read_text())
    if name.endswith("no-lab"):  # the procedure without its metadata, its bench given with --scenario
        del data["metadata"]
        path = tmp_path / procedure
        path.write_text(yaml.safe_dump({k: v for k, v in data.items() if k != "bench"}, allow_unicode=True))
    assert main(["run", str(path), "--scenario", str(PROCEDURES / data["bench"]), "--out", str(out)]) == 0
    doc = pymupdf.open(out / "report.pdf")
    assert sum(len(page.get_images()) for page in doc) == figures
    run = (name, read_results(out), [page.get_text() for page in doc], (out / "report.html").read_text(), data)
    every_page_ends_with_page_n_of_m(run)
    sections_in_order(run)
    if name.endswith("no-lab"):
        a_report_without_the_laboratory_is_not_a_certificate(run)
    else:
        a_certificate_carries_every_item(run)


def every_page_ends_with_page_n_of_m(run):
    _, _, pages, _, _ = run
    for n, text in enumerate(pages, start=1):
        assert text.rstrip().endswith(f"page {n} of {len(pages)}"), (n, text.rstrip()[-80:])


def _flat(text: str) -> str:
    return re.sub(r"\s+", " ", text)


def a_certificate_carries_every_item(run):
    """ISO/IEC 17025 7.8.2.1 a)–p) and 7.8.4.1 a)–e) where they apply, from the procedure's
    metadata and the results, on the pages a reviewer looks for them."""
    name, results, pages, html, proc = run
    meta = proc["metadata"]
    page1, text = _flat(pages[0]), _flat("\n".join(pages))
    assert "Calibration certificate" in page1  # a) title
    for key in ("laboratory", "laboratory_address", "certificate_number", "customer", "customer_address", "machine",
                "serial_number"):
        assert _flat(meta[key]) in page1, key  # b) laboratory, certificate, e) customer, g) item
    assert f"axis {meta['axis']}" in page1
    assert "Date of measurement" in page1 and results.started_utc[:10] in page1  # i) dates of the measurement
    assert "Date of issue" in page1  # j) date of issue
    assert "ISO 230-2:2014" in page1 and "VDI/DGQ 3441:1977" in page1  # f) method and standards with edition
    named = text.replace(Path(results.procedure.path).name, "")  # the procedure's file may bear the method's key
    assert results.method not in named and "encoder_abbe_error" not in named  # the method by its name, never its key
    assert ("Laser tracer multi-station method" if name == "seed000" else "autocollimator on a 24-face optical polygon") in page1
    assert "Conditions during the measurement" in page1  # 7.8.4.1 b)
    if name != "seed001":  # the shipped seed-001 procedure has no sensor: "not recorded" (below)
        assert "air temperature / °C" in text and "air pressure / Pa" in text and "air temperature c" not in text
    assert "U (k = 2)" in page1 and "coverage factor k = 2" in page1 and "about 95 %" in page1  # 7.8.4.1 a)
    assert "traceable to the SI" in page1  # 7.8.4.1 c)
    for record in meta["instruments"].values():  # the reference standards and instruments, ids, certificates, due
        assert _flat(record["id"]) in text
        for key in ("certificate_number", "calibration_due"):
            if key in record:
                assert record[key] in text, (key, record)
    if name != "seed000":
        assert "polygon" in text and "reference standard: angle" in text
        assert "not recorded (no environment sensor)" in page1 if name == "seed001" else "air temperature 20" in page1
    assert "relate only to the item calibrated" in page1  # l)
    assert f"Performed by: {meta['performed_by']}" in page1 and f"Approved by: {meta['approved_by']}" in page1  # o)
    assert "Control of the machine" in page1 and "exclusive" in page1  # issue 18: exclusive control, and how checked
    assert "every motion and reading checked against the commands" in page1
    assert "End of certificate." in pages[-1]
    for item in ("Calibration certificate", meta["certificate_number"], meta["laboratory"], "counter(pages)",
                 "relate only to the item calibrated", "Conditions during the measurement", meta["approved_by"]):
        assert item in html, item


def a_report_without_the_laboratory_is_not_a_certificate(run):
    """seed 001's procedure without its metadata names no laboratory, certificate or approver and
    it has no environment sensor: page 1 says it is not a certificate and why, the conditions are
    "not recorded", and Figures 9–12 come in order."""
    name, results, pages, _, _ = run
    page1, text = _flat(pages[0]), _flat("\n".join(pages))
    assert "Calibration report" in page1 and "Not a calibration certificate" in page1
    assert "metadata.laboratory" in page1 and "metadata.approved_by" in page1
    assert "not recorded" in page1 and results.environment is None
    positions = [text.index(f"Figure {n}:") for n in (1, 2, 3, 4)]
    assert positions == sorted(positions)
    assert "End of report." in pages[-1]


def sections_in_order(run):
    _, results, pages, _, _ = run
    text = "\n".join(pages)
    order = [text.index(s) for s in ("Result in brief", "Traceability", "Result: positioning deviation per target and direction",
                                     "VDI/DGQ 3441 parameters", "Uncertainty budget")]
    order += [text.rindex("\nMethod\n")]  # the section; page 1 names the method too
    order += [text.index(s) for s in ("Reference standards and instruments", "min – max over the run", "Run\n")]
    assert order == sorted(order)
    rows = len(results.recommended_estimate().cumulative_deviation_arcsec)
    assert len(re.findall(r"^[↑↓]$", text, re.M)) == rows  # one row per target and direction


def test_what_the_uncertainty_leaves_out_is_on_page_1(tmp_path):
    """A procedure that states no uncertainty of the polygon's certificate: the budget leaves it
    out, and page 1 says so in full (not small print further on)."""
    data = yaml.safe_load((PROCEDURES / "iso230_2_polygon.yaml").read_text())
    data["polygon"]["certificate_uncertainty_arcsec"] = 0
    data.pop("bench")  # given with --scenario: a procedure's bench lies in its own folder
    proc = tmp_path / "iso.yaml"
    proc.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True))
    out = tmp_path / "run"
    assert main(["run", str(proc), "--scenario", str(PROCEDURES / "scenarios" / "abbe_bench.yaml"), "--out", str(out)]) == 0
    left_out = read_results(out).recommended_estimate().uncertainty_budget.not_included
    assert left_out
    page1 = _flat(pymupdf.open(out / "report.pdf")[0].get_text())
    assert "The uncertainty stated does not include:" in page1
    for item in left_out:
        assert _flat(item) in page1


def test_the_pdf_footer_keeps_the_certificate_number_beside_the_page_count():
    """A long laboratory name once cut the footer at 120 characters, under "page N of M" and before the certificate's
    number: the longest part is shortened instead, so the number stays whole and the line fits its room."""
    from rtcal.deliverables.report import fit_footer

    text = ("SIMULATED — NOT A CALIBRATION · Example Metrology Lab GmbH (simulated bench; accreditation D-K-00000-01-00)"
            " · Certificate RT-2026-0042")
    fitted = fit_footer(text, len, 100)
    assert len(fitted) <= 100 and fitted.endswith("· Certificate RT-2026-0042") and fitted.startswith("SIMULATED")
    assert "…" in fitted
    assert fit_footer("Lab · Certificate 7", len, 100) == "Lab · Certificate 7"
