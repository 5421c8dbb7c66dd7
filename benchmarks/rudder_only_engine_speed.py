"""rudder_only: the engine speed held per manoeuvre (its approach) against the one of each prediction's start.

A rudder boat whose propulsion is not logged (layout rudder_only) runs its grey box at an equivalent engine speed.
Before 2026-11-25 every prediction held the engine speed that keeps its START speed in straight running, so a
prediction started inside a turn (where the boat has slowed down at the same engine setting) ran slow; now replay
holds the engine speed of the manoeuvre's approach (models/greybox.py `reference`, data.recording.approach_state).

This script prints both side by side, in one run, on simulated bags of the jari_usv preset as a rudder_only boat
(650 rpm, not recorded), the diagnosis programme (turning circles and 20/20 zig-zags both ways), calm water and a
0.5 m/s current: the open-loop position error at 10 / 30 / 60 s (truth reference, starts every 5 s), the fit check's
ratios, for the calm-water preset. "start" is the old rule (a predictor that is given no reference state: exactly
the old code path), "approach" the new one.

    .venv/bin/python benchmarks/rudder_only_engine_speed.py [--dt 0.5] [--out DIR]
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import yaml

from usv_predictor.analysis.evaluation import WithoutReference, evaluate
from usv_predictor.analysis.fit_check import check_fit
from usv_predictor.models.loading import physics_predictor
from usv_predictor.physics.actuators import actuator_layout
from usv_predictor.physics.vessel import load_vessel, vessel_dir
from usv_predictor.replay.cli import main as replay
from usv_predictor.replay.recordings import load_recordings

HORIZONS_S = (10.0, 30.0, 60.0)  # (s) open-loop horizons
CASES = {"calm water": [], "current 0.5 m/s toward 250 deg": ["--effect", "current", "--current-speed", "0.5",
                                                              "--current-to", "250"]}




def rudder_only_jari(root: Path) -> Path:
    """The jari_usv preset as a rudder_only vessel file (its propulsion not logged), written into `root`."""
    root.mkdir(parents=True, exist_ok=True)
    raw = yaml.safe_load((vessel_dir() / "jari_usv.yaml").read_text())
    vessel_file = root / "jari_rudder_only.yaml"
    vessel_file.write_text(yaml.safe_dump({**raw, "name": "jari_rudder_only", "actuator_layout": "rudder_only"}))
    return vessel_file


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dt", type=float, default=0.5, help="model step (s), default 0.5 (diagnose's for jari_usv)")
    parser.add_argument("--out", type=Path, default=None, help="where the bags go (default: a temporary directory)")
    args = parser.parse_args()
    root = args.out or Path(tempfile.mkdtemp(prefix="rudder_only_"))
    vessel_file = rudder_only_jari(root)
    vessel = load_vessel(str(vessel_file))
    print(f"jari_usv as rudder_only (650 rpm, not recorded), diagnosis programme, model step {args.dt:g} s, "
          f"open-loop starts every 5 s, truth reference; bags in {root}")
    header = (f"{'case':34s} {'engine speed of':16s}" + "".join(f" {f'{h:g} s (m)':>9s}" for h in HORIZONS_S)
              + f" {'speed ratio':>12s} {'yaw ratio':>10s} {'fit check':>10s}")
    print(header)
    for k, (case, flags) in enumerate(CASES.items()):
        bags = root / f"case{k}"
        if not bags.exists():
            assert replay(["simulate", "--programme", "diagnosis", "--vessel", str(vessel_file), "--seed", str(11 + k),
                           "--heading", "30", "--blind", *flags, "--output", str(bags)]) == 0
        recordings = load_recordings([bags], args.dt, layout=actuator_layout("rudder_only"), warn=lambda _: None)
        new = physics_predictor(vessel, args.dt)
        for label, predictor in (("start (old)", WithoutReference(new)), ("approach (new)", new)):
            result = evaluate(predictor, recordings, reference="truth", horizons_s=HORIZONS_S)
            fit = check_fit(predictor, recordings, vessel=vessel)
            errors = "".join(f" {result.summary[f'mean_position_error_after_{h:g}s_m']:9.2f}" for h in HORIZONS_S)
            speed = "-" if fit.speed_ratio is None else f"{fit.speed_ratio:.3f}"
            yaw = "-" if fit.yaw_rate_ratio is None else f"{fit.yaw_rate_ratio:.3f}"
            print(f"{case:34s} {label:16s}{errors} {speed:>12s} {yaw:>10s} {fit.verdict:>10s}", flush=True)


if __name__ == "__main__":
    main()
