"""Sylvac and ELCOMAT as their references say (issue 27): `rtcal probe` against emulators written
from the OPTO-RS manual and dls-controls/elcomat3000 (tests/emulators) — a Sylvac in mm, in inches,
echoing, refusing mm; an ELCOMAT with one axis valid."""

from __future__ import annotations

import json

import pytest

from rtcal.cli import main
from tests import emulators as emu
from tests.emulators import Emulator


def _probe(capsys, kind: str, address: str) -> tuple[int, dict | None, str]:
    code = main(["probe", kind, address, "--json", "--timeout-s", "1"])
    out, err = capsys.readouterr()
    return code, (json.loads(out) if code == 0 else None), err


@pytest.mark.parametrize("inch,echo", [(False, False), (True, False), (True, True), (False, True)])
def test_probe_sylvac_reads_mm_whatever_its_display(capsys, inch, echo):
    with Emulator(emu.sylvac_opto_rs(inch=inch, echo=echo, displacement_mm=-0.0123)) as device:
        code, r, err = _probe(capsys, "dial_indicator", f"{device.url()}?model=sylvac")
    assert code == 0, err
    assert r["reading"] == {"displacement_mm": pytest.approx(-0.0123, abs=1e-12)}  # not -0.00048 (inches as mm)
    assert device.requests[:2] == [b"MM", b"UNI?"]


def test_probe_sylvac_that_stays_in_inches_is_refused_naming_the_unit(capsys):
    with Emulator(emu.sylvac_opto_rs(inch=True, accepts_mm=False)) as device:
        code, _, err = _probe(capsys, "dial_indicator", f"{device.url()}?model=sylvac")
    assert code == 1 and err.count("\n") == 1
    assert "inches" in err and "mm" in err


@pytest.mark.parametrize("digit,reading", [("1", {"x_arcsec": 12.34, "y_arcsec": None}),
                                           ("2", {"x_arcsec": None, "y_arcsec": -5.67})])
def test_probe_elcomat_with_one_axis_valid(capsys, digit, reading):
    with Emulator(emu.elcomat_one_axis(digit), b"\n") as device:
        code, r, err = _probe(capsys, "autocollimator", f"{device.url()}?model=elcomat")
    assert code == 0, err
    assert r["reading"] == reading
    assert r["identity"].startswith("Möller-Wedel ELCOMAT, serial number 30123")


def test_a_run_needing_the_invalid_axis_gets_a_fault():
    from drivers.addresses import parse_address
    from drivers.errors import InstrumentFault
    from drivers.serial_instruments import ElcomatAutocollimator

    with Emulator(emu.elcomat_one_axis("2"), b"\n") as device:
        autocollimator = ElcomatAutocollimator(parse_address(f"{device.url()}?model=elcomat"), 1.0)
        try:
            with pytest.raises(InstrumentFault, match="X axis not valid"):
                autocollimator.read_arcsec()  # what the Abbe run reads: X, about the table axis
        finally:
            autocollimator.close()
