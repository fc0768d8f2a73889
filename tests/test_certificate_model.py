"""The certificate as one typed document (issue 25): built once from the results, written as
certificate.json, and laid out — never re-worded or re-rounded — by the three renderers
(report.md, report.html, report.pdf): a number the document holds reads the same in all three,
a section the document lacks is missing from all three alike."""

from __future__ import annotations

import inspect
import json
import re
from pathlib import Path

import pymupdf
import pytest
from markupsafe import escape

from rtcal.cli import main
from rtcal.deliverables import report
from rtcal.deliverables.certificate import (SECTION_BUILDERS, Certificate, build_certificate, certificate_schema)
from rtcal.deliverables.rounding import u_text, value_text
from rtcal.methods import METHODS, read_results

PROCEDURES = Path(__file__).resolve().parents[1] / "procedures"


def _flat(text: str) -> str:
    return re.sub(r"\s+", " ", text)


@pytest.fixture(scope="module")
def iso_run(tmp_path_factory) -> Path:
    """The shipped ISO 230-2 procedure (acceptance limits, a guarded rule), run once."""
    out = tmp_path_factory.mktemp("cert") / "run"
    assert main(["run", str(PROCEDURES / "iso230_2_polygon.yaml"), "--out", str(out)]) == 0
    return out


def _render(cert: Certificate, run_dir: Path, into: Path) -> tuple[str, str, str]:
    """(report.md, report.html, the PDF's text) of ``cert`` (its figures in ``run_dir``)."""
    into.mkdir(exist_ok=True)
    report.write_markdown(cert, into / "report.md")
    report.write_html(cert, into / "report.html")
    report.write_pdf(cert, into / "report.pdf")
    pdf = "\n".join(page.get_text() for page in pymupdf.open(into / "report.pdf").pages())
    return (into / "report.md").read_text(), (into / "report.html").read_text(), pdf


def test_certificate_json_is_the_document_the_run_rendered(iso_run):
    """certificate.json reads back as the document build_certificate makes from results.json."""
    written = Certificate.model_validate_json((iso_run / "certificate.json").read_text())
    rebuilt = build_certificate(read_results(iso_run), iso_run, METHODS["encoder_abbe_error"])
    assert written.model_dump() == rebuilt.model_dump() and written.figures and written.conformity is not None
    html = (iso_run / "report.html").read_text()
    assert all(str(escape(f.caption)) in html for f in written.figures)


def test_a_number_reads_the_same_in_all_three(iso_run):
    """Each limit's value and U: the strings rounding.py makes from results.json, in report.md's
    table, the HTML's and the PDF's, one row each."""
    results = read_results(iso_run)
    cert = build_certificate(results, iso_run, METHODS["encoder_abbe_error"])
    md, html, pdf = (iso_run / "report.md").read_text(), (iso_run / "report.html").read_text(), _flat(
        "\n".join(p.get_text() for p in pymupdf.open(iso_run / "report.pdf").pages()))
    assert cert.conformity is not None and len(cert.conformity.rows) == len(results.conformity.per_limit) >= 5
    for row, limit in zip(cert.conformity.rows, results.conformity.per_limit.values()):
        value, U = value_text(limit.value_arcsec, limit.expanded_uncertainty_arcsec), u_text(limit.expanded_uncertainty_arcsec)
        assert (row.value_arcsec, row.expanded_uncertainty_arcsec) == (value, U)
        assert f"| {row.symbol} | {value} | {limit.limit_arcsec:g} | {U} |" in md, row.symbol
        assert (f'<td class="num">{limit.limit_arcsec:g}</td><td class="num">{value}</td><td class="num">{U}</td>'
                in html), row.symbol
        assert f"{row.symbol} {_flat(row.parameter)} {limit.limit_arcsec:g} {value} {U} " in pdf, row.symbol


def test_the_renderers_take_every_number_from_the_document(iso_run, tmp_path):
    """A document with numbers no rounding could make: each renderer shows them, none recomputes."""
    cert = build_certificate(read_results(iso_run), iso_run, METHODS["encoder_abbe_error"])
    assert cert.conformity is not None and cert.parameters is not None
    rows = [r.model_copy(update={"value_arcsec": f"77.{i}{i}1", "expanded_uncertainty_arcsec": f"0.{i}{i}3"})
            for i, r in enumerate(cert.conformity.rows, start=1)]
    doctored = cert.model_copy(update={"conformity": cert.conformity.model_copy(update={"rows": rows})})
    md, html, pdf = _render(doctored, iso_run, tmp_path / "doctored")
    for r in rows:
        for text in (md, html, pdf):
            assert r.value_arcsec in text and r.expanded_uncertainty_arcsec in text, r.symbol
    for name in ("write_markdown", "write_html", "write_pdf"):  # layout only: no format spec, no rounding
        source = inspect.getsource(getattr(report, name))
        assert not re.search(r"u_text|value_text|_fmt\(|round\(|:[+]?\.\d[fge]|:g\}", source), name


def test_a_missing_section_is_missing_alike(iso_run, tmp_path):
    """Without conformity, parameters and budget no renderer shows their headings (with them, each
    does); a report that is not a certificate says so in the HTML and the PDF in one wording."""
    cert = build_certificate(read_results(iso_run), iso_run, METHODS["encoder_abbe_error"])
    assert cert.conformity and cert.parameters and cert.budget
    headings = {"conformity": cert.conformity.heading + ":", "parameters": cert.parameters.heading,
                "budget": cert.budget.heading}
    full = _render(cert, iso_run, tmp_path / "full")
    for text in full:
        assert headings["conformity"] in text
    for text in full[1:]:  # the parameters and the budget are the certificate's, not report.md's
        assert headings["parameters"] in text and headings["budget"] in text
    why = "Not a calibration certificate: the procedure's metadata does not give a test reason."
    lacking = cert.model_copy(update={"conformity": None, "parameters": None, "budget": None,
                                      "header": cert.header.model_copy(update={"not_certificate": why})})
    md, html, pdf = _render(lacking, iso_run, tmp_path / "lacking")
    assert headings["conformity"] not in md  # report.md's own budget is the method's body (report_body), kept
    for text in (html, pdf):
        assert all(h not in text for h in headings.values()), [h for h in headings.values() if h in text]
    assert str(escape(why)) in html and why in _flat(pdf)


def test_one_place_adds_a_section():
    """Every section of the document has its builder in SECTION_BUILDERS, and only those."""
    fields = set(Certificate.model_fields) - {"schema_version"}
    assert [n for n, _ in SECTION_BUILDERS] == [n for n in Certificate.model_fields if n in fields]
    schema = json.loads(certificate_schema())
    assert schema["title"] == "rtcal certificate.json" and fields <= set(schema["properties"])
    described = [p for d in schema["$defs"].values() for p in d.get("properties", {}).values() if "description" in p]
    assert any("arcsec" in p["description"] for p in described)
