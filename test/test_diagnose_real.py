"""`replay diagnose` on the public measured data (../shared/data/raw): what it can and cannot say."""
from __future__ import annotations

import json

from usv_predictor.analysis.diagnosis import EVIDENCE_CAUSE
from usv_predictor.replay.cli import main


def test_fuzhou_sea_trial_is_refused_for_want_of_engine_speed(raw_data_dir, tmp_path, capsys):
    bags = tmp_path / "fuzhou"
    assert main(["convert", str(raw_data_dir / "usv_alexandersson2022_fuzhou"), "--output", str(bags)]) == 0
    assert main(["diagnose", str(bags)]) == 2
    assert "engine_rpm" in capsys.readouterr().err


def test_kvlcc2_zigzags_flag_the_poor_heading_coverage(raw_data_dir, tmp_path):
    source = raw_data_dir / "kvlcc2_hsva_simman2008"
    files = [str(source / f"HSVA_CPMC_KVLCC2_Z_{name}.dat") for name in ("10_10_P", "10_10_S")]
    bags = tmp_path / "hsva"
    assert main(["convert", *files, "--output", str(bags)]) == 0
    out = tmp_path / "d.json"
    assert main(["diagnose", str(bags), "--vessel", "kvlcc2_model", "--hypotheses", "current", "rudder_offset",
                 "--max-causes", "1", "--no-gain", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    # zig-zags about one course: the tool says heading-dependent causes are poorly separated
    assert any("headings cover" in note for note in result["notes"])
    # A towing tank has no current and these two 66 s zig-zags cannot support a cause: the answer is none.
    # The best hypothesis is a "current" along the course (north): the preset's calm-water speed error,
    # which the data cannot tell from a drift; its evidence stays below the threshold of a cause.
    assert result["cause"] == "none"
    assert result["parameters"] == {}
    best = result["evidence"][0]
    assert best["hypothesis"] == "current"
    assert 0.0 < best["evidence_vs_none"] < EVIDENCE_CAUSE
    for fold in best["fold_parameters"]:
        assert abs((fold["direction_to_deg"] + 180.0) % 360.0 - 180.0) < 30.0  # toward the course, 0 deg
        assert fold["speed_mps"] < 0.15
