"""`rtcal solve stations`: the paper's Table 2 as a CSV gives Table 3."""

from __future__ import annotations

import json

import numpy as np

from rtcal.cli import main


def test_table2_csv_gives_table3(tmp_path, capsys, paper_tables):
    rows = paper_tables["table2_projected_stations"]["rows"]
    csv = tmp_path / "stations.csv"
    csv.write_text("X,Y,Z\n" + "\n".join(",".join(str(v) for v in r) for r in rows) + "\n")
    assert main(["solve", "stations", str(csv), "--step-deg", "30"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) >= {"plane", "projected_stations_mm", "center_mm", "deviation_arcsec", "sigma_arcsec", "algorithm_error_arcsec"}
    assert np.max(np.abs(np.array(out["deviation_arcsec"]) - paper_tables["table3_deviation_arcsec"]["values"])) < 0.25
    assert np.max(np.abs(np.array(out["center_mm"]) - paper_tables["circle_center"])) < 1e-4


def test_bad_csv_is_a_user_error(tmp_path, capsys):
    csv = tmp_path / "bad.csv"
    csv.write_text("X,Y\n1,2\n")
    assert main(["solve", "stations", str(csv), "--step-deg", "30"]) == 2
    assert "header must name X,Y,Z" in capsys.readouterr().err
    csv.write_text("X,Y,Z\n1,2,x\n3,4,5\n5,6,7\n7,8,9\n")
    assert main(["solve", "stations", str(csv), "--step-deg", "30"]) == 2
    assert "bad.csv:2:" in capsys.readouterr().err
