"""The fit check on bags a model fits, across boat sizes: each vessel preset's own calm-water model against its
`diagnosis` programme simulated with each hidden effect at the top of the suite's range (physics/effects.py, the
direction drawn from the seed), and what the strongest causes the diagnosis knows can do to a right model of that
boat (usv_predictor.analysis.fit_check, Explanation.limits). Prints one row per vessel and effect: the speed and
yaw-rate ratios, the limits each must lie within on that boat (the calm-water allowance or what one cause at the top
of its range makes of a right model, whichever is wider; inf: a cause can stop the boat or its turn), the verdict.
Run: .venv/bin/python benchmarks/fit_check_sizes.py [--vessels jari_usv otter wamv] [--seed 7] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np


def strongest(effect, layout: str, rng: np.random.Generator) -> dict[str, float]:
    """The effect's parameters at the top of their draw range, a compass direction drawn from rng."""
    from usv_predictor.physics import effects as fx

    out = {}
    for p in effect.parameters:
        if p.draw is None:
            continue
        if isinstance(p.draw, fx.Uniform) and p.unit == "deg" and p.draw.high - p.draw.low >= 360.0:
            out[p.name] = float(rng.uniform(0.0, 360.0))
        else:
            extremes = p.draw.extremes
            out[p.name] = float(max(extremes, key=abs) * (rng.choice([-1.0, 1.0]) if len(extremes) > 2 else 1.0))
    return out


def one(vessel_name: str, effect_name: str, seed: int) -> dict:
    import torch

    from usv_predictor.analysis.diagnosis_steps import diagnosis_steps
    from usv_predictor.analysis.fit_check import check_fit
    from usv_predictor.data.recording import recording_from_signals
    from usv_predictor.models.loading import physics_predictor
    from usv_predictor.physics import effects as fx
    from usv_predictor.physics.dynamics import ManoeuvringModel
    from usv_predictor.physics.manoeuvres import programme
    from usv_predictor.physics.scenario import make_scenario
    from usv_predictor.physics.sensors import measure
    from usv_predictor.physics.simulator import simulate
    from usv_predictor.physics.vessel import load_vessel

    torch.set_num_threads(1)
    rng = np.random.default_rng([seed, sum(map(ord, vessel_name + effect_name))])
    vessel = load_vessel(vessel_name)
    layout = vessel.actuator_layout
    parameters = {} if effect_name == "none" else strongest(fx.EFFECTS[effect_name], layout.name, rng)
    scenario = make_scenario(vessel, {effect_name: parameters} if parameters else {})
    dt = diagnosis_steps(vessel).dt
    model = ManoeuvringModel(vessel)
    recordings = []
    heading0 = rng.uniform(0.0, 360.0)
    for k, manoeuvre in enumerate(programme("diagnosis", layout)):
        traj = simulate(model, manoeuvre, scenario.environment, heading_deg=heading0 + 37.0 * k,
                        faults=scenario.faults, seed=seed + k)
        signals = measure(traj, scenario.environment, scenario.sensor_spec, scenario.faults, seed=seed + 100 + k)
        recordings.append(recording_from_signals(signals, dt, name=manoeuvre.name, layout=layout))
    started = time.perf_counter()
    check = check_fit(physics_predictor(vessel, dt), recordings, vessel=vessel, explain_always=True)
    seconds = time.perf_counter() - started
    speed, yaw = check.speed_explanation, check.yaw_rate_explanation
    return {"vessel": vessel_name, "length_m": vessel.geometry.L_pp, "effect": effect_name, "parameters": parameters,
            "verdict": check.verdict, "speed_ratio": check.speed_ratio, "speed_windows": check.speed_windows,
            "speed_limits": None if speed is None else list(speed.limits), "yaw_rate_ratio": check.yaw_rate_ratio,
            "yaw_limits": None if yaw is None else list(yaw.limits),
            "yaw_reversed_below": None if yaw is None else yaw.reversed_below, "windows": len(check.windows),
            "data_speed_mps": check.data_speed_mps, "top_speed_mps": check.top_speed_mps, "seconds": seconds,
            "reasons": list(check.reasons)}


def _fmt(x) -> str:
    return "-" if x is None else ("inf" if math.isinf(x) else f"{x:.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vessels", nargs="+", default=["jari_usv", "otter", "wamv"])
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    from usv_predictor.analysis.hidden_effects import effect_names
    from usv_predictor.physics.vessel import load_vessel

    rows = []
    print("| vessel (L) | effect at the top of its range | speed ratio | speed limits | yaw-rate ratio | yaw limits | "
          "verdict | check s |")
    print("|---|---|---|---|---|---|---|---|")
    for name in args.vessels:
        for effect in effect_names(load_vessel(name).layout):
            r = one(name, effect, args.seed)
            rows.append(r)
            band = lambda b: "-" if b is None else f"{_fmt(b[0])}..{_fmt(b[1])}"  # noqa: E731
            params = ", ".join(f"{k} {v:.3g}" for k, v in r["parameters"].items()) or "-"
            reversed_ = "" if r["yaw_reversed_below"] is None else f" (or <= {r['yaw_reversed_below']:.2g})"
            print(f"| {name} ({r['length_m']:g} m) | {effect} ({params}) | {_fmt(r['speed_ratio'])} "
                  f"({r['speed_windows'] or 'none'}) | {band(r['speed_limits'])} | {_fmt(r['yaw_rate_ratio'])} | "
                  f"{band(r['yaw_limits'])}{reversed_} | {r['verdict']} | {r['seconds']:.1f} |", flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1, default=lambda x: None)


if __name__ == "__main__":
    main()
