"""Confusion matrix of `diagnose` over random hidden effects (the figures of docs/results/diagnosis_matrices.md).

Each draw: one effect of the vessel's vocabulary (or none; the effects that apply to its actuator layout) with
random parameters (usv_predictor.analysis.hidden_effects), the vessel's `diagnosis` trial programme (turning circles
and zig-zags both ways, in its layout's units) simulated with sensor noise, resampled like the replay tool does at
the model step that suits the vessel (analysis.diagnosis_steps), and diagnosed with its segment horizon and stride.
Prints the confusion matrix (rows: truth, columns: named
cause; `?` marks answers that name the truth only as confounded), the parameter errors per effect, how many
draws met the acceptance tolerances, and the time per diagnosis. Deterministic for --seed.
Run: .venv/bin/python benchmarks/bench_diagnosis.py --draws 100 [--vessel otter] [--jobs 2] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np


def one_draw(index: int, seed: int, vessel_name: str = "jari_usv") -> dict:
    import torch

    from usv_predictor.analysis.diagnosis import diagnose
    from usv_predictor.analysis.diagnosis_steps import diagnosis_steps
    from usv_predictor.analysis.hidden_effects import draw, effect_names, within_tolerance
    from usv_predictor.errors import DiagnosisError
    from usv_predictor.data.recording import recording_from_signals
    from usv_predictor.physics.dynamics import ManoeuvringModel
    from usv_predictor.physics.manoeuvres import programme
    from usv_predictor.physics.scenario import make_scenario
    from usv_predictor.physics.sensors import measure
    from usv_predictor.physics.simulator import simulate
    from usv_predictor.physics.vessel import load_vessel

    torch.set_num_threads(1)
    rng = np.random.default_rng([seed, index])
    vessel = load_vessel(vessel_name)
    layout = vessel.actuator_layout
    effects = effect_names(layout.name)
    truth = draw(rng, effects[index % len(effects)], layout.name)  # balanced over the effects
    steps = diagnosis_steps(vessel)  # jari_usv: 0.5 s, 20 s, 5 s
    model = ManoeuvringModel(vessel)
    scenario = make_scenario(vessel, {truth.effect: truth.parameters} if truth.effect != "none" else {})
    recordings = []
    heading0 = rng.uniform(0.0, 360.0)
    for k, manoeuvre in enumerate(programme("diagnosis", layout)):
        traj = simulate(model, manoeuvre, scenario.environment, heading_deg=heading0 + 37.0 * k,
                        faults=scenario.faults, seed=1000 * index + k)
        signals = measure(traj, scenario.environment, scenario.sensor_spec, scenario.faults, seed=1000 * index + 100
                          + k)
        recordings.append(recording_from_signals(signals, steps.dt, name=manoeuvre.name, layout=layout))
    started = time.perf_counter()
    try:
        result = diagnose(recordings, vessel, horizon_s=steps.horizon_s, stride_s=steps.stride_s)
    except DiagnosisError as err:  # a refusal is an answer of the tool: counted in its own column, the run goes on
        return {"index": index, "truth": truth.effect, "truth_parameters": truth.parameters, "cause": "error",
                "confounded_with": [], "parameters": {}, "errors": {}, "within_tolerance": False,
                "seconds": time.perf_counter() - started, "message": str(err)}
    seconds = time.perf_counter() - started
    ok, errors = within_tolerance(truth, result.parameters) if result.cause == truth.effect else (False, {})
    return {"index": index, "truth": truth.effect, "truth_parameters": truth.parameters, "cause": result.cause,
            "confounded_with": list(result.confounded_with), "parameters": result.parameters, "errors": errors,
            "within_tolerance": ok, "seconds": seconds, "message": result.message}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=100)
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--vessel", default="jari_usv", help="vessel preset (its layout's effects are drawn)")
    parser.add_argument("--first", type=int, default=0,
                        help="first draw index (resume a run: each draw is deterministic for (seed, index))")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    from usv_predictor.analysis.hidden_effects import effect_names
    from usv_predictor.physics.vessel import load_vessel

    EFFECTS = effect_names(load_vessel(args.vessel).layout)
    started = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        results = []
        indices = range(args.first, args.draws)
        for r in pool.map(one_draw, indices, [args.seed] * len(indices), [args.vessel] * len(indices)):
            results.append(r)
            print(f"[{args.first + len(results)}/{args.draws}] {r['truth']:15s} -> {r['cause']:15s} "
                  f"{'ok' if r['within_tolerance'] or r['truth'] == r['cause'] == 'none' else '  '} {r['errors']} "
                  f"({r['seconds']:.0f} s)", flush=True)
    # answers beyond the vocabulary: model_mismatch (the calm-water model does not fit), error (a refusal)
    causes = list(EFFECTS) + sorted({r["cause"] for r in results} - set(EFFECTS))
    matrix = np.zeros((len(EFFECTS), len(causes)), dtype=int)
    for r in results:
        matrix[EFFECTS.index(r["truth"]), causes.index(r["cause"])] += 1
    width = max(len(c) for c in causes) + 1
    print("\nconfusion matrix (rows: hidden effect, columns: named cause)")
    print(" " * width + "".join(f"{c[:9]:>10s}" for c in causes))
    for i, effect in enumerate(EFFECTS):
        print(f"{effect:{width}s}" + "".join(f"{n:10d}" for n in matrix[i]))
    for r in results:
        if r["cause"] == "error":
            print(f"draw {r['index']} ({r['truth']} {r['truth_parameters']}): {r['message']}")
    correct = sum(r["truth"] == r["cause"] for r in results)
    print(f"\ncorrect cause: {correct}/{len(results)}")
    for effect in EFFECTS[1:]:
        rows = [r for r in results if r["truth"] == effect and r["cause"] == effect]
        if not rows:
            continue
        keys = rows[0]["errors"].keys()
        spread = ", ".join(f"{k} median |err| {np.median([abs(r['errors'][k]) for r in rows]):.3g}, "
                           f"max {np.max([abs(r['errors'][k]) for r in rows]):.3g}" for k in keys)
        tol = sum(r["within_tolerance"] for r in rows)
        print(f"{effect:15s} {tol}/{len(rows)} within tolerance; {spread}")
    print(f"{args.vessel}: {len(results)} draws, time per diagnosis: median "
          f"{np.median([r['seconds'] for r in results]):.1f} s; whole run {time.perf_counter() - started:.0f} s "
          f"with {args.jobs} job(s)")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"vessel": args.vessel, "results": results, "matrix": matrix.tolist(), "effects": list(EFFECTS),
                       "causes": causes},
                      f, indent=1)


if __name__ == "__main__":
    main()
