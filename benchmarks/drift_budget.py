"""Where the shipped sea trial's drift comes from, and how well eq. 27-29 can measure it (issue 15's drift distance).

    .venv/bin/python benchmarks/drift_budget.py [--seeds 5] [--json out/drift_budget.json]

Two parts, both on seed 000 Table 3's six starboard turns (a)-(f) as `bags/make_bags.sh` simulates them (the
programme's seeds 2021 + 1000 k and approach headings 37 k deg, the `--sea rizhao` of physics/scenario.py):

1. The sea, part by part: each turn re-simulated with the sea's parts switched on in turn (current alone; current +
   wind without gusts; current + waves; all without gusts; all with the current held at its first direction; the whole
   sea), the drift of eq. 27-28 (distance, speed = distance / period, direction toward) taken on the TRUE track (no
   sensor): which part of the sea makes the drift, whether the current's slow turn (0.002 deg/s) or the gusts matter
   for it, and how much the drift differs from turn to turn.
2. The metric's own noise: each turn simulated with `--seeds` sensor / gust seeds (the first is the shipped bag's),
   written as a bag and read back at 0.2 s as the study reads it; the TRUE track scored like a model's prediction
   against the raw GNSS track and against the smoothed measurements (analysis.evaluation.reference_tracks): what a
   perfect model would get. Per seed the largest |error| over the six turns (as the study's tables), then the mean
   and the worst over the seeds.

Deterministic (fixed seeds). This is the simulator's truth, used to explain the study's numbers, never to fit.
"""
from __future__ import annotations

import argparse
import dataclasses
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

PROGRAMME_SEED = 2021  # bags/make_bags.sh: replay simulate --programme sea_trial --seed 2021
SEED_STEP = 1000  # replay.simulate: the k-th manoeuvre of a programme gets seed + 1000 k
OTHER_SEED_STEP = 7919  # the extra sensor / gust seeds of part 2: seed + 7919 s (a prime: no overlap with the above)
APPROACH_S = 10.0  # the turns' straight approach before the rudder (s): eq. 27-28 count heading from the execute
TURNS = "abcdef"


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def sea_parts(full):
    """The sea's parts (name -> physics.environment.Environment) of the shipped trial's sea `full`."""
    return {
        "current": dataclasses.replace(full, wind_speed=0.0, gust_std=0.0, wave_height=0.0),
        "current + wind": dataclasses.replace(full, wave_height=0.0, gust_std=0.0),
        "current + waves": dataclasses.replace(full, wind_speed=0.0, gust_std=0.0),
        "all, no gusts": dataclasses.replace(full, gust_std=0.0),
        "all, current not turning": dataclasses.replace(full, current_turn_rate_deg_s=0.0),
        "whole sea (the bags)": full,
    }


def part_one() -> dict:
    """Drift of the true track per turn and sea part."""
    from usv_predictor.analysis import metrics
    from usv_predictor.physics import manoeuvres as mv
    from usv_predictor.physics.dynamics import ManoeuvringModel
    from usv_predictor.physics.scenario import RIZHAO_SEA, make_scenario
    from usv_predictor.physics.simulator import simulate
    from usv_predictor.physics.vessel import load_vessel
    from usv_predictor.replay.simulate import HEADING_STEP_DEG

    jari = load_vessel("jari_usv")
    model = ManoeuvringModel(jari)
    full = make_scenario(jari, {k: dict(v) for k, v in RIZHAO_SEA.items()}).environment
    out: dict = {}
    for k, turn in enumerate(mv.sea_trial_turns()):
        for part, env in sea_parts(full).items():
            traj = simulate(model, turn, env, heading_deg=HEADING_STEP_DEG * k, dt=0.05, output_rate_hz=10.0,
                            seed=PROGRAMME_SEED + SEED_STEP * k)
            t = (traj.t_ns - traj.t_ns[0]) / 1e9
            keep = t >= APPROACH_S
            d = metrics.drift(t[keep], traj.eta[keep, 0], traj.eta[keep, 1], traj.eta[keep, 2])
            out.setdefault(TURNS[k], {})[part] = {"distance_m": d.distance_m, "speed_mps": d.speed_mps,
                                                  "period_s": d.period_s, "direction_deg": d.direction_deg}
        log(f"part 1: turn ({TURNS[k]}) {turn.name}")
    return out


def part_two(seeds: int) -> dict:
    """The true track scored against GNSS and smoothed references, per turn and seed."""
    from usv_predictor.analysis import evaluation as ev
    from usv_predictor.physics import manoeuvres as mv
    from usv_predictor.physics.scenario import RIZHAO_SEA, make_scenario
    from usv_predictor.replay.identify import identification_recordings
    from usv_predictor.replay.simulate import SimulationRequest, simulate_bag

    from usv_predictor.physics.vessel import load_vessel

    jari = load_vessel("jari_usv")
    scenario = make_scenario(jari, {k: dict(v) for k, v in RIZHAO_SEA.items()})
    rows: dict = {}
    root = Path(tempfile.mkdtemp(prefix="drift_budget_"))
    try:
        for k, turn in enumerate(mv.sea_trial_turns()):
            for s in range(seeds):
                seed = PROGRAMME_SEED + SEED_STEP * k + OTHER_SEED_STEP * s
                path = root / f"{turn.name}_{s}"
                simulate_bag(path, turn, scenario, SimulationRequest(output=root, vessel=jari, seed=seed), seed=seed,
                             index=k)
                rec = identification_recordings([path], 0.2)[0]
                truth = ev.reference_series(rec, "truth")
                execute = ev.classify(rec).execute_time_s - float(rec.t_s[0])
                for reference in ("gnss", "smoothed"):
                    tracks = ev.reference_tracks(rec, reference)
                    prediction = ev.Prediction(name=rec.name, reference=reference, t_s=rec.t_s - rec.t_s[0],
                                               controls=rec.controls, measured=tracks.measured, predicted=truth,
                                               predicted_std=np.zeros_like(truth), layout=rec.layout)
                    c = ev.compare_turning(prediction, execute)
                    rows.setdefault(reference, {}).setdefault(TURNS[k], []).append({
                        "radius_pct": c.errors["turning_radius_rel_pct"],
                        "angle_deg": c.errors["drift_direction_abs_deg"],
                        "distance_pct": c.errors["drift_distance_rel_pct"],
                        "measured_distance_m": c.measured["drift_distance_m"],
                        "true_distance_m": c.predicted["drift_distance_m"]})
                shutil.rmtree(path, ignore_errors=True)
            log(f"part 2: turn ({TURNS[k]}) {turn.name}, {seeds} seeds")
    finally:
        shutil.rmtree(root, ignore_errors=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=5, help="sensor / gust seeds per turn in part 2 (default 5)")
    parser.add_argument("--json", type=Path, help="write the numbers here")
    args = parser.parse_args(argv)
    if args.seeds < 1:
        print(f"drift_budget: --seeds {args.seeds}: expected a whole number >= 1", file=sys.stderr)
        return 2
    started = time.perf_counter()
    one = part_one()
    parts = list(next(iter(one.values())))
    print("Part 1: drift of the true track (eq. 27 distance m / speed m/s, period s, direction toward deg)")
    print("| turn | " + " | ".join(parts) + " |")
    print("|---" * (len(parts) + 1) + "|")
    for turn, by_part in one.items():
        print(f"| ({turn}) | " + " | ".join(f"{p['distance_m']:.2f} m / {p['speed_mps']:.3f} m/s, "
                                             f"{p['period_s']:.1f} s, {p['direction_deg']:.0f} deg"
                                             for p in by_part.values()) + " |")
    two = part_two(args.seeds)
    print(f"\nPart 2: the true track scored as a model (per seed the largest |error| over the six turns; mean and "
          f"worst over {args.seeds} seeds; seed 0 = the shipped bags)")
    print("| reference | radius (%) | drift angle (deg) | drift distance (%) | seed 0 |")
    print("|---|---|---|---|---|")
    for reference, by_turn in two.items():
        cells, first = [], []
        for key in ("radius_pct", "angle_deg", "distance_pct"):
            per_seed = [max(abs(by_turn[t][s][key]) for t in by_turn) for s in range(args.seeds)]
            cells.append(f"{np.mean(per_seed):.2f} (worst {max(per_seed):.2f})")
            first.append(f"{per_seed[0]:.2f}")
        print(f"| {reference} | " + " | ".join(cells) + " | " + " / ".join(first) + " |")
    for reference, by_turn in two.items():
        print(f"{reference}, drift distance error per turn (seeds): " + "; ".join(
            f"({t}) " + " ".join(f"{r['distance_pct']:+.1f}" for r in rows) for t, rows in by_turn.items()))
    if args.json is not None:
        from usv_predictor.replay.cli import write_json_atomic

        write_json_atomic(args.json, {"sea_parts": one, "metric_noise": two, "seeds": args.seeds,
                                      "time_s": time.perf_counter() - started})
    log(f"done in {time.perf_counter() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
