"""What a laboratory may not issue, and one number everywhere (issue 29, items 1, 2, 3, 5):

- a reference standard or instrument past its calibration due date: the run refuses to start;
- a test that departs from ISO 230-2 says so on page 1, and its parameters are not ISO 230-2's;
- U rounded once (two significant digits, rounded up): the same string on page 1, in the
  parameters' table, on the console and in results.json's conformity;
- a simulated run's end is its start plus the virtual clock's time; no developer words on the
  certificate; `compare` prints a table; `check` shows every due date and cuts no word.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import io
import json
import math
import random
import re
from pathlib import Path

import pymupdf
import pytest
import yaml

from rtcal.cli import main
from rtcal.deliverables.certificate import plural
from rtcal.deliverables.rounding import round_up, u_text
from rtcal.methods import read_results

REPO = Path(__file__).resolve().parents[1]
PROCEDURES = REPO / "procedures"
ISO = PROCEDURES / "iso230_2_polygon.yaml"
DEVELOPER_WORDS = ("Seed 0", "seed 0", "Paper 0", "shared_dead_path", "not confirmed against", "metadata.instruments",
                   "verification.", "_arcsec", "eq. 33", "Fig. 9", "Fig. 12")


def _flat(text: str) -> str:
    return re.sub(r"\s+", " ", text)


def _procedure(tmp_path: Path, edit) -> Path:
    """A copy of the ISO procedure with ``edit`` applied to its data, its bench given by path."""
    data = yaml.safe_load(ISO.read_text())
    data["bench"] = str(PROCEDURES / "scenarios" / "abbe_bench.yaml")
    edit(data)
    path = tmp_path / "procedure.yaml"
    data.pop("bench")
    path.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True))
    return path


def _run(args: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(args)
    return code, out.getvalue(), err.getvalue()


def _bench() -> list[str]:
    return ["--scenario", str(PROCEDURES / "scenarios" / "abbe_bench.yaml")]


@pytest.fixture(scope="module")
def iso_run(tmp_path_factory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("iso") / "run"
    code, printed, _ = _run(["run", str(ISO), "--out", str(out)])
    assert code == 0
    return out, printed


def test_expired_standard_refuses_to_start(tmp_path):
    """The autocollimator past its due date yesterday: exit 2, the instrument and its date named, nothing measured."""
    yesterday = (dt.datetime.now(dt.timezone.utc).date() - dt.timedelta(days=1)).isoformat()

    def expire(data):
        data["metadata"]["instruments"]["autocollimator"]["calibration_due"] = yesterday

    path = _procedure(tmp_path, expire)
    code, _, err = _run(["run", str(path), *_bench(), "--out", str(tmp_path / "run")])
    assert code == 2 and "autocollimator" in err and yesterday in err and "calibration_due" in err
    assert not (tmp_path / "run" / "run.sqlite").exists()
    code, printed, err = _run(["check", str(path)])
    assert code == 1 and "autocollimator" in err and yesterday in printed
    code, printed, err = _run(["validate", str(path)])  # validate says what run would refuse, where
    assert code == 2 and "ok" not in printed, printed
    assert re.search(rf":\d+:\d+: metadata\.instruments\.autocollimator\.calibration_due: {yesterday} is past", err), err


def test_check_shows_every_due_date_and_cuts_no_word():
    code, printed, _ = _run(["check", str(PROCEDURES / "encoder_abbe_error.yaml")])
    assert code == 0 and " due " in printed.splitlines()[0]
    meta = yaml.safe_load((PROCEDURES / "encoder_abbe_error.yaml").read_text())["metadata"]["instruments"]
    for name, record in meta.items():
        line = next(x for x in printed.splitlines() if x.startswith(name + " "))
        assert record.get("calibration_due", "–") in line, name
    from rtcal.run.commission import CheckRow, format_table

    detail = ("read 0x00CC: no valid reply (Modbus Error: [Connection] ModbusTcpClient 192.168.0.20:502: Connection "
              "unexpectedly closed without response from device)")
    table = format_table([CheckRow("stage", "oriental-az", "FAILED", detail, calibration_due="2029-01-31")])
    assert max(len(x) for x in table.splitlines()) <= 100
    assert table.split() == ["instrument", "model", "status", "due", "reading", "or", "problem", "identity",
                             "stage", "oriental-az", "FAILED", "2029-01-31", *detail.split()]  # every word whole, in order


def test_u_is_rounded_up_to_two_significant_digits():
    rng = random.Random(29)
    for _ in range(2000):
        value = 10 ** rng.uniform(-3, 3)
        r = round_up(value)
        digits = u_text(value).replace(".", "").lstrip("0")
        assert r >= value * (1 - 1e-6) and r - value < 10 ** (math.floor(math.log10(value)) - 1) * 1.0001, value
        assert len(digits.rstrip("0")) <= 2, (value, u_text(value))  # 0.52, 1.2, 11, 1000 (from 992.6)
        assert u_text(r) == u_text(value)  # rounding once more changes nothing: one string everywhere
    assert [u_text(v) for v in (0.5123, 0.52, 10.4, 1.17, 0.0996)] == ["0.52", "0.52", "11", "1.2", "0.10"]
    assert plural(1, "event") == "1 event" and plural(2, "event") == "2 events" and plural(0, "event") == "0 events"


def test_one_u_on_every_page_and_the_console(iso_run):
    """Each parameter's U on page 1, in the parameters' table, on the console and in results.json's conformity."""
    out, printed = iso_run
    pages = [p.get_text() for p in pymupdf.open(out / "report.pdf")]
    page1, text = _flat(pages[0]), _flat("\n".join(pages))
    results = read_results(out)
    checked = 0
    for symbol, meaning in (("E", "bidirectional systematic positional deviation"), ("M", "range of the mean"),
                            ("B", "reversal value"), ("R", "bidirectional repeatability"), ("A", "bidirectional accuracy")):
        brief = re.search(rf"{symbol}: {meaning}[^″]*? ([\d.]+)″ U ([\d.]+)″", page1)
        table = re.search(rf" {symbol} {meaning}[^0-9]*?([\d.]+) ([\d.]+) ", text[text.index("ISO 230-2:2014 parameters"):])
        console = re.search(rf"\b{symbol} ([\d.]+)″ \(U ([\d.]+)″\)", printed)
        assert brief and table and console, symbol
        stored = results.conformity.per_limit[symbol].expanded_uncertainty_arcsec
        assert brief.group(2) == table.group(2) == console.group(2) == u_text(stored), symbol
        assert brief.group(1) == table.group(1) == console.group(1), symbol
        checked += 1
    assert checked == 5
    assert "Departures from the method none" in page1 and "ISO 230-2:2014: E " in printed


def test_simulated_times_and_customer_words(iso_run):
    out, _ = iso_run
    results = read_results(out)
    start, end = (dt.datetime.fromisoformat(t) for t in (results.started_utc, results.finished_utc))
    assert (end - start).total_seconds() == pytest.approx(results.measurement_duration_s, abs=0.2)
    assert results.measurement_duration_s > 60  # the virtual clock's minutes, not the seconds the simulation took
    pages = [p.get_text() for p in pymupdf.open(out / "report.pdf")]
    page1, text = _flat(pages[0]), _flat("\n".join(pages))
    assert f"{start:%H:%M} – {end:%H:%M} UTC (simulated measurement: virtual clock)" in page1
    assert "20 – 20" in text and "(mean 20" in text  # conditions as min – max
    assert "Condition on receipt" in page1 and "approved for issue electronically by B. Example" in page1
    for word in DEVELOPER_WORDS:
        assert word not in text, word
    figures = [int(n) for n in re.findall(r"Figure (\d+):", text)]
    assert figures == list(range(1, len(figures) + 1)) and len(figures) == 4
    html = (out / "report.html").read_text()
    assert "break-inside: avoid" in html and "break-after: avoid" in html


def test_a_three_run_test_states_its_departure(tmp_path):
    """runs: 3 validates and runs; page 1 says it departs from ISO 230-2 and no parameter is called ISO 230-2's."""
    path = _procedure(tmp_path, lambda data: data["steps"].update(runs=3))
    code, printed, _ = _run(["run", str(path), *_bench(), "--out", str(tmp_path / "run")])
    assert code == 0
    page1 = _flat(pymupdf.open(tmp_path / "run" / "report.pdf")[0].get_text())
    assert "Departures from the method 3 runs per target and direction (ISO 230-2 asks 5)" in page1
    assert "not an ISO 230-2 result" in page1
    text = _flat("\n".join(p.get_text() for p in pymupdf.open(tmp_path / "run" / "report.pdf")))
    assert "ISO 230-2:2014 parameters" not in text and "computed as ISO 230-2 defines them" in text
    assert "ISO 230-2:2014:" not in printed and "positioning parameters computed as ISO 230-2 defines them" in printed


def test_the_demo_labels_no_partial_parameter_as_iso(tmp_path):
    out = tmp_path / "demo"
    code, printed, _ = _run(["run", str(PROCEDURES / "laser_tracer_multistation.yaml"), "--out", str(out)])
    assert code == 0
    pages = [p.get_text() for p in pymupdf.open(out / "report.pdf")]
    page1, text = _flat(pages[0]), _flat("\n".join(pages))
    assert "one direction of approach only" in page1 and "1 run per target and direction" in page1
    assert "ISO 230-2:2014 parameters" not in text and "ISO 230-2:2014:" not in printed
    for word in DEVELOPER_WORDS:
        assert word not in text, word
    u = read_results(out).recommended_estimate().cumulative_expanded_uncertainty_arcsec
    assert f"U ≤ {u_text(max(v for v in u if v is not None))}″" in page1


def test_compare_prints_a_table(iso_run, tmp_path, monkeypatch):
    out, _ = iso_run
    monkeypatch.chdir(tmp_path)
    code, printed, _ = _run(["compare", str(out), str(out)])
    assert code == 0 and (tmp_path / "compare.png").stat().st_size > 0  # the current directory by default
    assert max(len(x) for x in printed.splitlines()) <= 100 and "\\u" not in printed
    assert "0 of 24 target values changed by more than U_c" in printed
    code, printed, _ = _run(["compare", str(out), str(out), "--json", "--out", str(tmp_path / "o")])
    assert code == 0 and json.loads(printed)["targets_compared"] == 24 and (tmp_path / "o" / "compare.png").exists()


def test_as_found_as_left_certificate(iso_run, tmp_path):
    """Two runs of one item as one certificate: both measurements on page 1, the change per target against U_c."""
    out, _ = iso_run
    code, printed, _ = _run(["compare", str(out), str(out), "--certificate", "--out", str(tmp_path)])
    assert code == 0 and "as_found_as_left.pdf" in printed
    pages = [_flat(p.get_text()) for p in pymupdf.open(tmp_path / "as_found_as_left.pdf")]
    assert "As found (before adjustment)" in pages[0] and "As left (after adjustment)" in pages[0]
    assert "0 of 24 beyond U_c" in pages[0] and "Approved by" in pages[0]
    text = " ".join(pages)
    assert "U_c (k = 2) / ″" in text and "End of certificate." in text
    for n, page in enumerate(pages, start=1):
        assert page.rstrip().endswith(f"page {n} of {len(pages)}")


def _table(targets, directions=(1, -1), runs=5):
    import numpy as np

    from rtcal.deliverables.deviations import PositioningDeviations

    rows = [(t, d, r) for r in range(1, runs + 1) for d in directions for t in targets]
    t, d, r = (np.array(c, float) for c in zip(*rows))
    return PositioningDeviations(t, d.astype(int), r.astype(int), np.zeros(len(rows)), np.full(len(rows), 0.1))


def test_departures_from_iso_230_2():
    from rtcal.deliverables.departures import departures, parameters_label

    iso = [0, 15, 45, 90, 105, 150, 180, 210, 240, 270, 315, 330]
    assert departures(_table(iso)) == [] and parameters_label([]) == "ISO 230-2:2014"
    assert departures(_table(iso, directions=(1,))) == ["one direction of approach only (ISO 230-2 asks both)"]
    assert departures(_table(iso, runs=3)) == ["3 runs per target and direction (ISO 230-2 asks 5)"]
    assert any("equally spaced (30°" in d for d in departures(_table(list(range(0, 360, 30)))))
    assert any("180°, 270° are not among" in d for d in departures(_table([0, 20, 50, 90, 130, 200, 290, 340])))
    assert any(d.startswith("3 targets") for d in departures(_table([0, 10, 25])))
    assert parameters_label(["x"]).startswith("positioning parameters computed as ISO 230-2 defines them")


def test_each_certificate_its_own_number(iso_run):
    """A procedure serves many runs: a second run beside the first with the procedure's number is
    warned about; --certificate-number gives this run its own, kept through verify (the stored
    procedure carries it); a number a certificate cannot print is refused (exit 2)."""
    first, _ = iso_run
    own = json.loads((first / "certificate.json").read_text())["header"]["certificate_number"]
    assert own
    code, _, err = _run(["run", str(ISO), "--out", str(first.parent / "again")])
    assert code == 0 and f"{first / 'certificate.json'} carries the same certificate number" in err, err
    code, _, err = _run(["run", str(ISO), "--out", str(first.parent / "numbered"), "--certificate-number", own + "-B"])
    assert code == 0 and "same certificate number" not in err, err
    numbered = json.loads((first.parent / "numbered" / "certificate.json").read_text())["header"]["certificate_number"]
    assert numbered == own + "-B"
    assert _run(["verify", str(first.parent / "numbered")])[0] == 0
    with pytest.raises(SystemExit) as refused:
        main(["run", str(ISO), "--out", str(first.parent / "bad"), "--certificate-number", "EML\u202e-1"])
    assert refused.value.code == 2 and not (first.parent / "bad").exists()


def _measured(results, start: str, end: str, clock: str):
    return results.model_copy(update={"started_utc": start, "finished_utc": end, "clock": clock})


def test_overlapping_measurement_periods_are_no_as_found_as_left_pair(iso_run, tmp_path, monkeypatch, capsys):
    """Issue 46 item 9: two runs whose measurement periods overlap were printed as an as-found / as-left pair.
    Two real measurements that overlap (or come in the other order) are refused before anything is written;
    simulated ones (virtual clocks) are said to overlap, on the certificate's page 1 and on the console."""
    import rtcal.cli.results as cli_results
    from rtcal.deliverables.as_found import NotAPair, periods_overlap

    out, _ = iso_run
    run = read_results(out)
    labels = ("runs/a", "runs/b")
    found = _measured(run, "2026-03-02T08:00:00+00:00", "2026-03-02T11:00:00+00:00", "real")
    assert periods_overlap(found, _measured(run, "2026-03-02T12:00:00+00:00", "2026-03-02T15:00:00+00:00", "real"),
                           labels) == ""  # one after the other: a pair
    for left in (_measured(run, "2026-03-02T10:00:00+00:00", "2026-03-02T13:00:00+00:00", "real"),
                 _measured(run, "2026-03-01T08:00:00+00:00", "2026-03-01T11:00:00+00:00", "real")):
        with pytest.raises(NotAPair):
            periods_overlap(found, left, labels)
        table = cli_results.read_deviation_table(str(out))[0]
        monkeypatch.setattr(cli_results, "read_deviation_table", lambda p, left=left: (table, found if p == "A" else left))
        code, printed, err = _run(["compare", "A", "B", "--certificate", "--out", str(tmp_path / "refused")])
        assert code == 2 and len(err.strip().splitlines()) == 1 and "as-found / as-left pair" in err, err
        assert not (tmp_path / "refused").exists()
    monkeypatch.undo()
    code, printed, err = _run(["compare", str(out), str(out), "--certificate", "--out", str(tmp_path / "simulated")])
    assert code == 0 and "measurement periods" in err
    page1 = _flat(pymupdf.open(tmp_path / "simulated" / "as_found_as_left.pdf")[0].get_text())
    assert "Note: The measurement periods are not those of an as-found / as-left pair" in page1
