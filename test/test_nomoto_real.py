"""The low-order family on the real Fuzhou zig-zag (../shared/data/raw, read only): `replay identify --family auto`
keeps it over the grey box, and it predicts the held-out half better than every naive baseline at 10 and 30 s; the
model it writes runs in `replay evaluate`. Skipped without the raw data, a failure under CI (conftest.py)."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from replay_helpers import assert_one_line, replay

from usv_predictor.replay import cli

REPO = Path(__file__).resolve().parents[1]
FUZHOU_VESSEL = REPO / "docs" / "vessels" / "fuzhou_usv.yaml"
DT = 0.5  # (s) the record is interpolated at 0.5 s


class Constant:
    """Naive baseline from the start state: body velocities held (turn: and the yaw rate), the exact integral of
    eta_dot = R(psi) nu with psi = psi0 + r t (Fossen 2021 eq. 2.40)."""

    def __init__(self, turn: bool) -> None:
        self.turn = turn
        self.metadata = {"dt": DT, "model_id": f"constant-{'turn' if turn else 'velocity'}", "model_type": "baseline"}

    def predict(self, state: np.ndarray, controls: np.ndarray) -> np.ndarray:  # (B, 4), (B, H, C) -> (1, B, H, 6)
        u, v, r, psi0 = (state[:, k][:, None] for k in range(4))  # (B, 1)
        r = r if self.turn else np.zeros_like(r)
        t = DT * np.arange(1, controls.shape[1] + 1)[None, :]  # (1, H)
        psi = psi0 + r * t
        small = np.abs(r) < 1e-9
        safe = np.where(small, 1.0, r)
        ic = np.where(small, t * np.cos(psi0), (np.sin(psi) - np.sin(psi0)) / safe)
        is_ = np.where(small, t * np.sin(psi0), (np.cos(psi0) - np.cos(psi)) / safe)
        x, y = u * ic - v * is_, u * is_ + v * ic
        b = np.broadcast_to
        return np.stack([b(u, x.shape), b(v, x.shape), b(r, x.shape), x, y, psi], axis=-1)[None]


@pytest.fixture(scope="module")
def fuzhou(raw_data_dir: Path, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("fuzhou")
    assert cli.main(["convert", str(raw_data_dir / "usv_alexandersson2022_fuzhou"), "--output", str(out)]) == 0
    return out / "fuzhou_zigzag_30"


def test_auto_keeps_the_low_order_model_of_the_fuzhou_zigzag_and_it_beats_every_baseline(fuzhou, tmp_path, capsys):
    from usv_predictor.analysis.evaluation import evaluate
    from usv_predictor.physics.vessel import load_vessel
    from usv_predictor.replay.identify import identification_recordings
    from usv_predictor.replay.low_order import halves

    out, report = tmp_path / "fuzhou.pt", tmp_path / "identify.json"
    code, err = replay(capsys, "identify", fuzhou, "--vessel", FUZHOU_VESSEL, "--dt", DT, "--family", "auto",
                       "--prior", "fix", "--output", out, "--json", report)
    assert_one_line(code, err, "identify", allowed=(0,))
    result = json.loads(report.read_text())
    assert result["model_type"] == "nomoto" and result["choice"]["chosen"] == "nomoto"
    assert "auto: nomoto predicts the held-out halves better" in err
    held = result["choice"]["held_out"]
    nomoto = held["nomoto"]["open_loop_m"]
    assert nomoto["30s"] < held["greybox"]["open_loop_m"]["30s"]
    (record,) = identification_recordings([fuzhou], DT, layout=load_vessel(FUZHOU_VESSEL).actuator_layout)
    _, second = halves([record])
    for turn in (False, True):
        baseline = evaluate(Constant(turn), second, "gnss", (10.0, 30.0), 5.0).summary
        assert nomoto["10s"] < baseline["mean_position_error_after_10s_m"], turn
        assert nomoto["30s"] < baseline["mean_position_error_after_30s_m"], turn
    coefficients = {c["name"]: c for c in result["identification"]["coefficients"]}
    lo, hi = coefficients["T1"]["ci95"]
    assert lo < coefficients["T1"]["estimate"] < hi and math.isfinite(hi)
    code, err = replay(capsys, "evaluate", fuzhou, "--model", out, "--horizons", 10, 30)
    assert_one_line(code, err, "evaluate", allowed=(0,))


def test_the_low_order_family_refuses_grey_box_options_in_one_line(fuzhou, tmp_path, capsys):
    code, err = replay(capsys, "identify", fuzhou, "--vessel", FUZHOU_VESSEL, "--dt", DT, "--family", "nomoto",
                       "--hybrid", "--output", tmp_path / "x.pt")
    assert_one_line(code, err, "identify")
    assert code == cli.EXIT_ERROR and "--family nomoto" in err and "--hybrid" in err
    assert not (tmp_path / "x.pt").exists()
