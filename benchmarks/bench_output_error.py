#!/usr/bin/env python3
"""The output-error stage of identify (fitting/output_error.py) against the equation-error fit alone, in one run.

    nice -n 10 python benchmarks/bench_output_error.py [--cases walkthrough,catamaran,timing] [--json out/oe.json]

walkthrough  docs/your_boat.md's boat: `vessel init`'s description of the Otter (the step-1 command) identified from
             bags/otter/training/calm + bags/otter/sea_trial/calm with --prior fix; printed per stage (old: equation
             error alone; new: + output error): the terms held, the held-out 20 s simulation error of the stage's
             folds, and `replay evaluate` of the exported model on the sea trial and on its calm twin (turning
             radius error per turn, mean open-loop position error after 30 s).
catamaran    the same description and a simulated calm day of the otter preset (the truth: its coefficients are
             known) with the trials docs/your_boat.md asks for, 11 manoeuvres: turns both ways at differentials 0.4
             and 0.8, zig-zags both ways (differential 0.6, 20 deg), straight runs at throttles 0.4 and 0.8, a spin
             each way and an astern run; printed: each yaw-equation term, held or determined, against the truth.
timing       `identify bags/training --vessel jari_usv --prior fix --interaction identify`: seconds of the equation-
             error stages and of the output-error stage (the whole of `replay identify` adds reading and export).
The load average is printed before and after.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from usv_predictor.data.recording import recording_from_signals  # noqa: E402
from usv_predictor.fitting import hybrid_fit  # noqa: E402
from usv_predictor.fitting import identification as idf  # noqa: E402
from usv_predictor.fitting import output_error as oe  # noqa: E402
from usv_predictor.physics.dynamics import ManoeuvringModel  # noqa: E402
from usv_predictor.physics.environment import Environment  # noqa: E402
from usv_predictor.physics.manoeuvres import CommandTurningCircle, CommandZigZag  # noqa: E402
from usv_predictor.physics.sensors import SensorSpec, measure  # noqa: E402
from usv_predictor.physics.simulator import simulate  # noqa: E402
from usv_predictor.physics.vessel import load_vessel  # noqa: E402
from usv_predictor.replay import cli  # noqa: E402
from usv_predictor.replay.identify import identification_recordings  # noqa: E402

DT = 0.2  # (s) identify's default step
OTTER_INIT = ["vessel", "init", "--name", "my_otter", "--layout", "twin_thrusters", "--lpp", "2.0", "--beam", "1.08",
              "--mass", "80", "--draught", "0.2", "--hulls", "2", "--demihull-beam", "0.25", "--thruster-spacing",
              "0.79", "--thruster-x", "-1.0", "--thrust", "1:119.7", "--thrust=-1:-66.7", "--thrust-unit",
              "normalised", "--speed", "1.11", "--at", "0.6"]  # docs/your_boat.md step 1
YAW_TERMS = ("Y_v", "Y_r", "N_v", "N_r", "N_rr", "cross_flow_cd")
CALM_DAY = (  # docs/your_boat.md "What you need", for a twin-thruster boat
    CommandTurningCircle("twin_thrusters", 0.4, 0.6, duration_s=60.0),
    CommandTurningCircle("twin_thrusters", 0.4, 0.6, duration_s=60.0, side=-1),
    CommandTurningCircle("twin_thrusters", 0.8, 0.6, duration_s=60.0),
    CommandTurningCircle("twin_thrusters", 0.8, 0.6, duration_s=60.0, side=-1),
    CommandZigZag("twin_thrusters", 0.6, 20.0, 0.6, duration_s=60.0),
    CommandZigZag("twin_thrusters", 0.6, 20.0, 0.6, duration_s=60.0, side=-1),
    CommandTurningCircle("twin_thrusters", 0.0, 0.4, duration_s=60.0),
    CommandTurningCircle("twin_thrusters", 0.0, 0.8, duration_s=60.0),
    CommandTurningCircle("twin_thrusters", 2.0, 0.0, duration_s=40.0, approach_s=5.0),
    CommandTurningCircle("twin_thrusters", 2.0, 0.0, duration_s=40.0, approach_s=5.0, side=-1),
    CommandTurningCircle("twin_thrusters", 0.0, -0.6, duration_s=40.0, approach_s=5.0),
)


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def description(work: Path) -> Path:
    path = work / "my_otter.yaml"
    if cli.main([*OTTER_INIT, "--output", str(path)]) != 0:
        raise SystemExit("vessel init failed")
    return path


def evaluate_model(result, work: Path, label: str, bags: dict[str, list[Path]]) -> dict:
    """Export the result's grey box and `replay evaluate` it on each set of bags: radius errors (%) and OL 30 s."""
    from usv_predictor.analysis.evaluation import evaluate
    from usv_predictor.models.artifact import load_artifact

    path = work / f"{label}.pt"
    hybrid_fit.export_identified(str(path), hybrid_fit.greybox_module(result, DT), result, dt=DT,
                                 training_data_sha256="0" * 64, model_type="greybox")
    artifact = load_artifact(path)
    out = {}
    for name, paths in bags.items():
        recordings = identification_recordings(paths, DT, layout=result.vessel.actuator_layout)
        report = evaluate(artifact, recordings).to_json()
        out[name] = {"radius_error_pct": {r["name"]: r["turning"]["errors"]["turning_radius_rel_pct"]
                                          for r in report["recordings"] if r.get("turning")},
                     "open_loop_30s_m": [h["mean_m"] for r in report["recordings"]
                                         for h in r["open_loop"]["horizons"] if h["horizon_s"] == 30.0]}
    return out


def walkthrough(work: Path) -> dict:
    vessel = load_vessel(description(work))
    recordings = identification_recordings([ROOT / "bags/otter/training/calm", ROOT / "bags/otter/sea_trial/calm"],
                                           DT, layout=vessel.actuator_layout)
    started = time.perf_counter()
    old = idf.identify(vessel, recordings, prior="fix")
    t_old = time.perf_counter() - started
    new = oe.refine(old, recordings, progress=log)
    t_new = time.perf_counter() - started - t_old
    bags = {"sea_trial": [ROOT / "bags/otter/sea_trial"], "sea_trial_calm": [ROOT / "bags/otter/sea_trial/calm"]}
    out = {"old": {"held": old.prior_used(), "seconds": t_old, **evaluate_model(old, work, "old", bags)},
           "new": {"held": new.prior_used(), "seconds": t_new, "kept": new.output_error["kept"],
                   "heldout_simulation_nmse": new.output_error["heldout_simulation_nmse"],
                   **evaluate_model(new, work, "new", bags)}}
    for label in ("old", "new"):
        r = out[label]
        print(f"walkthrough {label}: held {', '.join(r['held'])}; {r['seconds']:.1f} s")
        for name in bags:
            radius = ", ".join(f"{v:+.1f}" for v in r[name]["radius_error_pct"].values())
            ol = sum(r[name]["open_loop_30s_m"]) / max(len(r[name]["open_loop_30s_m"]), 1)
            print(f"  {name}: radius error % {radius}; open-loop 30 s {ol:.2f} m")
    print(f"walkthrough: kept {out['new']['kept']}, held-out 20 s error {out['new']['heldout_simulation_nmse']}")
    return out


def catamaran(work: Path) -> dict:
    described = load_vessel(description(work))
    truth = load_vessel("otter")
    model, env = ManoeuvringModel(truth), Environment()
    recordings = [recording_from_signals(measure(simulate(model, m, env, seed=i), env, SensorSpec(), seed=i), DT,
                                         name=m.name, layout=truth.actuator_layout) for i, m in enumerate(CALM_DAY)]
    old = idf.identify(described, recordings, prior="fix")
    new = oe.refine(old, recordings, progress=log)
    out = {}
    for label, result in (("old", old), ("new", new)):
        found = {c.name: c for c in result.coefficients()}
        out[label] = {name: {"estimate": found[name].estimate, "status": found[name].status,
                             "truth": float(getattr(truth.small_craft, name))}
                      for name in YAW_TERMS if name in found}
        out[label]["held"] = result.prior_used()
        print(f"catamaran {label}: held {', '.join(result.prior_used()) or 'none'}")
        for name in YAW_TERMS:
            if name in found:
                c = found[name]
                print(f"  {name:14s} {c.estimate:+10.4g} ({c.status}; truth {getattr(truth.small_craft, name):+.4g}, "
                      f"description {c.prior:+.4g})")
        lag = found.get(oe.LAG_NAMES["twin_thrusters"])
        m33, t33 = ManoeuvringModel(result.vessel).m33, ManoeuvringModel(truth).m33  # (kg m^2) yaw inertia + added
        print(f"  yaw damping / inertia N_r / m33 {found['N_r'].estimate / m33:+.3f} 1/s "
              f"(truth {truth.small_craft.N_r / t33:+.3f}), "
              f"N_rr / m33 {found['N_rr'].estimate / m33:+.3f} (truth {truth.small_craft.N_rr / t33:+.3f}); "
              f"thruster time constant {lag.estimate if lag else result.vessel.thrusters.port.time_constant_s:.3g} s "
              f"(truth {truth.thrusters.port.time_constant_s:g} s)")
        out[label]["N_r_per_m33"] = found["N_r"].estimate / m33
        out[label]["N_rr_per_m33"] = found["N_rr"].estimate / m33
    out["kept"] = new.output_error["kept"]
    out["heldout_simulation_nmse"] = new.output_error["heldout_simulation_nmse"]
    print(f"catamaran: kept {out['kept']}, held-out 20 s error {out['heldout_simulation_nmse']}")
    return out


def timing() -> dict:
    vessel = load_vessel("jari_usv")
    recordings = identification_recordings([ROOT / "bags/training"], DT, layout=vessel.actuator_layout)
    started = time.perf_counter()
    old = idf.identify(vessel, recordings, prior="fix", interaction="identify")
    t_old = time.perf_counter() - started
    new = oe.refine(old, recordings)
    t_new = time.perf_counter() - started - t_old
    fit = new.output_error["fit"]
    print(f"timing jari_usv bags/training: equation error (smoother, interaction search, regression) {t_old:.1f} s; "
          f"output error + folds + stability {t_new:.1f} s ({fit['rollouts']} rollouts of the whole fit); "
          f"kept {new.output_error['kept']}")
    return {"equation_error_s": t_old, "output_error_s": t_new, "kept": new.output_error["kept"],
            "heldout_simulation_nmse": new.output_error["heldout_simulation_nmse"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default="walkthrough,catamaran,timing")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    print(f"load average before: {os.getloadavg()}")
    out: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        for case in args.cases.split(","):
            work = Path(tmp) / case
            work.mkdir()
            out[case] = walkthrough(work) if case == "walkthrough" else catamaran(work) if case == "catamaran" \
                else timing()
    print(f"load average after: {os.getloadavg()}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=1, default=str))


if __name__ == "__main__":
    main()
