"""`replay evaluate` and `replay report` end to end on small simulated bags in tmp_path."""
from __future__ import annotations

import json
import os
import re
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from msg_adapters import ROLE_FIELDS
from usv_predictor.analysis import reports
from usv_predictor.records import Signal
from usv_predictor.replay.bagio import TopicSpec, write_bag
from usv_predictor.replay.cli import main
from usv_predictor.replay.recordings import bag_sha256

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A turning circle in a current and a zig-zag, written by `replay simulate`."""
    root = tmp_path_factory.mktemp("bags")
    common = ["simulate", "--output", str(root), "--effect", "current", "--current-speed", "0.4",
              "--current-to", "215"]
    assert main([*common, "--manoeuvre", "turning-circle", "--rudder", "25", "--duration", "90"]) == 0
    assert main([*common, "--manoeuvre", "zigzag", "--rudder", "20", "--duration", "70", "--seed", "4"]) == 0
    return root


@pytest.fixture(scope="module")
def evaluated(bags: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("evaluation")
    before = {b.name: bag_sha256(b) for b in bags.iterdir()}
    code = main(["evaluate", str(bags), "--model", "physics", "--dt", "0.5", "--reference", "truth",
                 "--output", str(out), "--json", str(out / "result.json")])
    assert code == 0
    assert before == {b.name: bag_sha256(b) for b in bags.iterdir()}  # bags are only read
    return out, json.loads((out / "evaluation.json").read_text())


def test_evaluate_writes_json_series_and_prints_the_table(bags, capsys):
    out = bags.parent / "evaluate_table"
    assert main(["evaluate", str(bags), "--model", "physics", "--reference", "truth", "--output", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "turning_circle_stbd_25deg_650rpm" in printed
    assert "zigzag_20_20_stbd_650rpm" in printed
    assert "max |rel. error| radius" in printed
    data = json.loads((out / "evaluation.json").read_text())
    assert data["series_file"] == "evaluation_series.npz"
    assert (out / "evaluation_series.npz").is_file()
    kinds = {r["name"]: r["manoeuvre"]["kind"] for r in data["recordings"]}
    assert kinds == {"turning_circle_stbd_25deg_650rpm": "turning_circle", "zigzag_20_20_stbd_650rpm": "zigzag"}
    turn = next(r for r in data["recordings"] if r["turning"])
    assert turn["turning"]["measured"]["drift_direction_deg"] == pytest.approx(215.0, abs=2.0)
    radius = turn["turning"]["measured"]["turning_radius_m"]
    assert f"{radius:.2f}" in printed  # the table shows the JSON's numbers
    assert data["model"]["model_id"] == "physics-jari_usv"
    assert data["data"]["dt_s"] == 0.5
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporary files left


def _md_row(markdown: str, label: str) -> list[str]:
    """Cells of the Markdown table row whose first cell is `label`."""
    for line in markdown.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if cells and cells[0] == label:
            return cells[1:]
    raise AssertionError(f"no row {label!r} in the report")


def test_report_from_an_evaluation_file_agrees_with_its_json(evaluated, tmp_path):
    evaluation_dir, _ = evaluated
    out = tmp_path / "report"
    assert main(["report", str(evaluation_dir / "evaluation.json"), "--output", str(out)]) == 0
    markdown = (out / "report.md").read_text()
    data = json.loads((out / "report.json").read_text())
    # model, data and date are named
    assert "physics-jari_usv" in markdown
    assert "calm-water MMG" in markdown
    assert re.search(r"Generated \d{4}-\d\d-\d\dT", markdown)
    assert all(r["source"] in markdown for r in data["recordings"])
    # the same numbers in Markdown and JSON (seed 000 Table 7 and 8 layouts)
    turning = [r for r in data["recordings"] if r["turning"]]
    for label, section, key, suffix in (
        ("Measured radius eq. 29 (m)", "measured", "turning_radius_m", ""),
        ("Predicted radius eq. 29 (m)", "predicted", "turning_radius_m", ""),
        ("Relative error of radius", "errors", "turning_radius_rel_pct", "%"),
        ("Absolute error of angle (deg)", "errors", "drift_direction_abs_deg", ""),
        ("Relative error of drift distance", "errors", "drift_distance_rel_pct", "%"),
    ):
        assert _md_row(markdown, label) == [reports.num(r["turning"][section][key], 2, suffix) for r in turning]
    summary_value = data["summary"]["mean_position_error_after_30s_m"]
    assert _md_row(markdown, "mean_position_error_after_30s_m") == [reports.num(summary_value, 3)]
    # figures: per test track / position / states, plus the open-loop and turning summaries, all real PNGs
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert len(pngs) == 3 * len(data["recordings"]) + 2
    for name in pngs:
        assert (out / name).read_bytes()[:8] == PNG_MAGIC
        assert f"({name})" in markdown
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_report_evaluates_bags_itself(bags, tmp_path):
    out = tmp_path / "direct"
    result = tmp_path / "r.json"
    assert main(["report", str(bags), "--model", "physics", "--output", str(out), "--json", str(result)]) == 0
    assert (out / "report.md").is_file()
    assert (out / "report.json").is_file()
    assert json.loads(result.read_text())["report"] == str(out / "report.md")
    assert json.loads((out / "report.json").read_text())["reference"] == "gnss"


def test_report_files_are_replaced_atomically(evaluated, tmp_path, monkeypatch, capsys):
    evaluation_dir, _ = evaluated
    out = tmp_path / "atomic"
    out.mkdir()
    (out / "report.md").write_text("previous report\n")
    real_replace = os.replace

    def failing_replace(src, dst):
        if Path(dst).name == "report.md":
            raise OSError(28, "No space left on device")
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", failing_replace)
    assert main(["report", str(evaluation_dir / "evaluation.json"), "--output", str(out)]) == 2
    assert "cannot write" in capsys.readouterr().err
    assert (out / "report.md").read_text() == "previous report\n"  # never half written
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_report_without_series_has_tables_but_no_track_figures(evaluated, tmp_path):
    evaluation_dir, data = evaluated
    lonely = tmp_path / "evaluation.json"
    lonely.write_text(json.dumps({k: v for k, v in data.items() if k != "series_file"}))
    out = tmp_path / "tables_only"
    assert main(["report", str(lonely), "--output", str(out)]) == 0
    markdown = (out / "report.md").read_text()
    assert "No track figures" in markdown
    assert "Relative error of radius" in markdown
    assert sorted(p.name for p in out.glob("*.png")) == ["open_loop.png", "turning_summary.png"]


# ------------------------------------------------------------------ errors


def test_missing_model_file_is_named(bags, tmp_path, capsys):
    assert main(["evaluate", str(bags), "--model", str(tmp_path / "nope.pt")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("replay evaluate: error:")
    assert "nope.pt: no such model file" in err


def test_missing_shipped_model_says_so(bags, tmp_path, monkeypatch, capsys):
    import usv_predictor.config as config

    monkeypatch.setattr(config, "share_roots", lambda: (tmp_path,))
    assert main(["evaluate", str(bags)]) == 2
    err = capsys.readouterr().err
    assert "no shipped model: models/default.pt does not exist" in err
    assert "--model" in err


def test_model_whose_dt_differs_from_the_requested_one_is_refused(bags, tmp_path, monkeypatch, capsys):
    model_file = tmp_path / "m.pt"
    model_file.write_bytes(b"stand-in")

    class Loaded:
        metadata = {"dt": 0.25, "model_id": "m25", "model_type": "dnn"}

        def predict(self, state, controls):  # pragma: no cover - refused before use
            raise AssertionError

    fake = types.ModuleType("usv_predictor.models.artifact")
    fake.load_artifact = lambda path, expect=None: Loaded()
    fake.check_runs = lambda model: None  # the dt is checked first: the model is never run
    monkeypatch.setitem(sys.modules, "usv_predictor.models.artifact", fake)
    assert main(["evaluate", str(bags), "--model", str(model_file), "--dt", "0.5"]) == 2
    err = capsys.readouterr().err
    assert "model m25 has dt=0.25 s" in err
    assert "dt=0.5 s" in err


def test_bags_without_the_needed_topics_are_named(tmp_path, capsys):
    t_ns = 1_700_000_000_000_000_000 + np.arange(40, dtype=np.int64) * 100_000_000
    streams = [
        (TopicSpec("heading", "heading", "std_msgs/msg/Float64"),
         Signal(t_ns, np.zeros((40, 1)), ROLE_FIELDS["heading"])),
        (TopicSpec("velocity", "velocity", "geometry_msgs/msg/TwistStamped"),
         Signal(t_ns, np.ones((40, 3)), ROLE_FIELDS["velocity"])),
    ]
    bag = write_bag(tmp_path / "partial", streams)
    assert main(["evaluate", str(bag), "--model", "physics"]) == 2
    err = capsys.readouterr().err
    assert "partial" in err
    assert "no topic 'imu/data'" in err


def test_unknown_reference_is_a_usage_error(bags, capsys):
    assert main(["evaluate", str(bags), "--model", "physics", "--reference", "nonsense"]) == 2
    assert "invalid choice" in capsys.readouterr().err


def test_shipped_artifact_format_is_evaluated(bags, tmp_path):
    """A real artifact file (usv_predictor.models.artifact): a constant-velocity rollout scripted with its metadata."""
    artifact = pytest.importorskip("usv_predictor.models.artifact")
    torch = pytest.importorskip("torch")

    class ConstantVelocity(torch.nn.Module):
        def __init__(self, dt: float) -> None:
            super().__init__()
            self.dt = dt

        def forward(self, state: torch.Tensor, controls: torch.Tensor) -> torch.Tensor:
            steps = controls.shape[1]
            k = torch.arange(1, steps + 1, dtype=state.dtype).unsqueeze(0)  # (1, H)
            psi = state[:, 3:4]
            north = (state[:, 0:1] * torch.cos(psi) - state[:, 1:2] * torch.sin(psi)) * self.dt * k
            east = (state[:, 0:1] * torch.sin(psi) + state[:, 1:2] * torch.cos(psi)) * self.dt * k
            same = state.unsqueeze(1).expand(-1, steps, -1)
            out = torch.stack([same[..., 0], same[..., 1], same[..., 2], north, east, same[..., 3]], dim=-1)
            return out.unsqueeze(0)  # (1, B, H, 6)

    meta = {"model_type": "constant-velocity test", "feature_set": "F0", "feature_names": [], "state_layout": [],
            "control_layout": ["delta", "rpm"], "output_layout": [], "dt": 0.5, "horizon_steps": 120,
            "normalisation": {},
            "vessel": "jari_usv", "training_data_sha256": "0" * 64, "ensemble_size": 1, "architecture": {},
            "training": {}, "units": {}}
    path = tmp_path / "cv.pt"
    loaded = artifact.export_module(path, ConstantVelocity(0.5), meta)
    out = tmp_path / "eval"
    assert main(["evaluate", str(bags / "zigzag_20_20_stbd_650rpm"), "--model", str(path), "--output", str(out)]) == 0
    data = json.loads((out / "evaluation.json").read_text())
    assert data["model"]["model_id"] == loaded.model_id
    assert data["model"]["model_type"] == "constant-velocity test"
    assert data["recordings"][0]["open_loop"]["position_error_after_10s_m"] > 0.0
    assert main(["evaluate", str(bags), "--model", str(path), "--dt", "0.25"]) == 2


def test_the_evaluation_request_refuses_what_cannot_be_evaluated(capsys):
    from usv_predictor.errors import EvaluationError
    from usv_predictor.replay.evaluate import EvaluationRequest

    for fields in ({"stride_s": 0.0}, {"horizons_s": (10.0, -30.0)}):
        with pytest.raises(EvaluationError, match=r"--stride .* and --horizons .* must be finite and positive \(s\)"):
            EvaluationRequest(**fields)
    with pytest.raises(EvaluationError, match="--reference 'radar': expected one of gnss, smoothed, truth"):
        EvaluationRequest(reference="radar")
    assert main(["evaluate", "--model", "physics", "--stride", "-5"]) == 2  # refused before any bag is read
    err = capsys.readouterr().err
    assert err.startswith("replay evaluate: error: argument --stride: '-5' is not a finite number > 0")
    assert "reading" not in err
