"""The walkthrough docs/your_boat.md, run as written (tools/your_boat.py: the doc's ```bash blocks are the commands,
so the doc and this test cannot drift), on the shipped Otter-class bags pretending the boat were unknown: the
vessel description, the identified model, the fit check of evaluate and diagnose, and the node with the boat's own
model fed from an otter bag over DDS (the demo's step 6 runs the same tool)."""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from usv_predictor.models.loading import load_model

from ros_helpers import localhost_env

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tools"))
import your_boat  # noqa: E402  (tools/ is not a package)

# what docs/your_boat.md reports for the example (step 2 and step 3; docs/results/your_boat.md)
IDENTIFIED = {"X_u": -95.6, "N_r": -56.0, "N_rr": -508.0, "thrusters.port.forward_N": 152.5,
              "thrusters.port.reverse_N": 75.1}  # SI
DETERMINED = ("N_r", "N_rr", "thrusters.port.reverse_N", "thrusters.starboard.reverse_N", "thrusters.time_constant_s")
# fit check of evaluate (the sea trial and its calm twin), diagnose of the clean day and of the sea trial
RATIOS = {"evaluation": {"speed_ratio": 0.99, "yaw_rate_ratio": 0.98},
          "clean_day": {"speed_ratio": 0.99, "yaw_rate_ratio": 0.98},
          "diagnosis": {"speed_ratio": 1.08, "yaw_rate_ratio": 1.27}}
RADIUS_TOLERANCE_PCT = 5.0  # the identified calm model's turning radius on the calm twin of the sea trial (%)
# the sea trial's hidden effects (bags/README.md, bags/make_bags.sh) and how near a named one's parameters must be
# (value, tolerance); a wave height is fitted with the description's wave-drift coefficients, the short-wave
# asymptote that `vessel init` calls an upper bound, so it may only be an underestimate: (0, 0.25 m]
SEA_TRUTH = {"current": {"speed_mps": (0.2, 0.05), "direction_to_deg": (215.0, 20.0)},
             "wind": {"speed_mps": (4.5, 1.5), "direction_from_deg": (135.0, 20.0)},
             "wave_drift": {"direction_from_deg": (140.0, 15.0), "significant_height_m": (0.125, 0.125)}}


def near_the_truth(cause: str, parameters: dict[str, float]) -> list[str]:
    """The parameters of a named cause outside SEA_TRUTH's tolerance (angles compared on the circle)."""
    wrong = []
    for name, (truth, tolerance) in SEA_TRUTH[cause].items():
        error = parameters[name] - truth
        if name.endswith("_deg"):
            error = (error + 180.0) % 360.0 - 180.0
        if abs(error) > tolerance:
            wrong.append(f"{cause}.{name} {parameters[name]:.3g} (truth {truth:g} +- {tolerance:g})")
    return wrong


def test_the_doc_goes_from_dimensions_to_the_node_in_six_commands() -> None:
    """vessel init -> identify (the calm day) -> evaluate -> diagnose the clean day and the sea trial -> the node."""
    steps = your_boat.doc_steps()
    assert [step.argv[:2] for step in steps] == [("replay", "vessel"), ("replay", "identify"), ("replay", "evaluate"),
                                                 ("replay", "diagnose"), ("replay", "diagnose"), ("ros2", "run")]
    assert steps[1].argv[2] == "bags/otter/calm_day"
    assert [steps[3].argv[2], steps[4].argv[2]] == ["bags/otter/sea_trial/calm", "bags/otter/sea_trial"]
    config = your_boat.node_config()["predictor"]["ros__parameters"]
    assert config["vessel"] == "my_otter"
    assert config["dt"] == 0.2
    assert config["ensemble_size"] == 1


def test_near_the_truth_names_what_is_off() -> None:
    assert near_the_truth("current", {"speed_mps": 0.22, "direction_to_deg": 205.0}) == []
    assert near_the_truth("wind", {"speed_mps": 4.0, "direction_from_deg": 120.0}) == []
    assert near_the_truth("wave_drift", {"significant_height_m": 0.3, "direction_from_deg": -5.0}) == [
        "wave_drift.direction_from_deg -5 (truth 140 +- 15)",
        "wave_drift.significant_height_m 0.3 (truth 0.125 +- 0.125)"]


@pytest.mark.slow
def test_the_walkthrough_runs_as_written_to_a_node_that_publishes_the_boats_model(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, str(REPO / "tools" / "your_boat.py"), str(tmp_path)], env=localhost_env(7),
                          capture_output=True, text=True, timeout=600)
    output = done.stdout + done.stderr
    assert done.returncode == 0, output[-3000:]
    # 1. the description and 2. the identified model, which embeds it
    assert (tmp_path / "my_otter.yaml").is_file()
    model = load_model(str(tmp_path / "my_otter.pt"), physics=False)
    assert model.metadata["vessel"] == "my_otter"
    assert model.embedded_vessel.name == "my_otter"
    coefficients = {c["name"]: c for c in json.loads((tmp_path / "identify.json").read_text())
                    ["identification"]["coefficients"]}
    for name in DETERMINED:  # the calm day's trials determine the yaw damping, the astern thrust and the motor lag
        assert coefficients[name]["status"] == "identified", name
    for name, reported in IDENTIFIED.items():
        assert coefficients[name]["estimate"] == pytest.approx(reported, rel=0.1), name
    # 3. evaluate and both diagnoses passed the fit check with the doc's ratios
    evaluation = json.loads((tmp_path / "out" / "eval" / "evaluation.json").read_text())
    results = {"evaluation": evaluation, "clean_day": json.loads((tmp_path / "clean_day.json").read_text()),
               "diagnosis": json.loads((tmp_path / "diagnosis.json").read_text())}
    for what, result in results.items():
        assert result["fit_check"]["verdict"] == "fits", what
        for name, reported in RATIOS[what].items():
            assert result["fit_check"][name] == pytest.approx(reported, abs=0.03), (what, name)
    # the calm model's turning radius on the sea trial's calm twin (not used for identification) within 5 %
    calm = {r["name"]: r["turning"]["errors"]["turning_radius_rel_pct"] for r in evaluation["recordings"]
            if r["name"].startswith("calm/")}
    assert len(calm) == 4 and all(abs(e) <= RADIUS_TOLERANCE_PCT for e in calm.values()), calm
    assert results["clean_day"]["cause"] == "none", results["clean_day"]["message"]
    diagnosis = results["diagnosis"]
    named = [(diagnosis["cause"], diagnosis["parameters"]),
             *((c["cause"], c["parameters"]) for c in diagnosis["additional_causes"])]
    for cause, parameters in named:  # the right effect(s), each with its parameters near the truth
        assert cause in SEA_TRUTH, diagnosis["message"]
        assert near_the_truth(cause, parameters) == [], diagnosis["message"]
    assert diagnosis["exported_model"]["path"] == "my_otter_sea.pt" and (tmp_path / "my_otter_sea.pt").is_file()
    # 4. the node ran the boat's own model from the doc's configuration, fed over DDS, and its fit check passed
    config = your_boat.yaml.safe_load((tmp_path / "my_predictor.yaml").read_text())["predictor"]["ros__parameters"]
    assert config["model_path"] == str((tmp_path / "my_otter.pt").resolve())
    paths = re.search(r"^(\d+) paths of (\d+) poses in frame 'odom'", output, re.M)
    assert paths and int(paths.group(1)) >= 10 and int(paths.group(2)) == 300, output[-2000:]  # 60 s / 0.2 s
    assert f"predictor: model: OK loaded {model.model_id}" in output
    fit = re.search(r"predictor: fit check: OK fits: speed ratio ([\d.]+) .*yaw-rate ratio ([\d.]+)", output)
    assert fit, output[-2000:]
    assert 1 / 1.5 < float(fit.group(1)) < 1.5
    assert 0.5 < float(fit.group(2)) < 2.0


def test_a_doc_command_the_runner_does_not_know_is_one_line_and_exit_2(tmp_path: Path, capsys) -> None:
    doc = tmp_path / "doc.md"
    doc.write_text("# x\n\n```bash\nrm -rf /tmp/nothing\n```\n")
    assert your_boat.main([str(tmp_path / "work"), "--doc", str(doc)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert "`rm -rf /tmp/nothing`: a command this runner does not know" in err
