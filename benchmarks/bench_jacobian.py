"""`diagnose` with the Levenberg-Marquardt Jacobian from one kernel call (analysis.diagnosis.PerturbedBatch: every
parameter's perturbation a block of rows) against one rollout per parameter (the loop it replaced), alternately in
one process on the same segments, with the answers compared.

The day: a preset's `diagnosis` programme (turns and zig-zags both ways) simulated with one hidden effect and sensor
noise, resampled at the preset's diagnosis step. Prints each repeat's seconds of both forms, their medians and the
ratio, and whether cause, parameters and every fold's held-out loss are the same.

Run: nice -n 10 .venv/bin/python benchmarks/bench_jacobian.py --repeats 5 [--vessel jari_usv] [--effect wind]
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np


def day(vessel_name: str, effect: str):
    from usv_predictor.analysis.diagnosis_steps import diagnosis_steps
    from usv_predictor.analysis.hidden_effects import draw
    from usv_predictor.data.recording import recording_from_signals
    from usv_predictor.physics.dynamics import ManoeuvringModel
    from usv_predictor.physics.manoeuvres import programme
    from usv_predictor.physics.scenario import make_scenario
    from usv_predictor.physics.sensors import measure
    from usv_predictor.physics.simulator import simulate
    from usv_predictor.physics.vessel import load_vessel

    vessel = load_vessel(vessel_name)
    layout = vessel.actuator_layout
    truth = draw(np.random.default_rng(7), effect, layout.name)
    scenario = make_scenario(vessel, {truth.effect: truth.parameters} if truth.effect != "none" else {})
    steps = diagnosis_steps(vessel)
    model = ManoeuvringModel(vessel)
    recordings = []
    for k, manoeuvre in enumerate(programme("diagnosis", layout)):
        traj = simulate(model, manoeuvre, scenario.environment, heading_deg=40.0 + 37.0 * k, faults=scenario.faults,
                        seed=k)
        signals = measure(traj, scenario.environment, scenario.sensor_spec, scenario.faults, seed=100 + k)
        recordings.append(recording_from_signals(signals, steps.dt, name=manoeuvre.name, layout=layout))
    return vessel, recordings, steps, truth


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vessel", default="jari_usv")
    parser.add_argument("--effect", default="wind")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    import torch

    from usv_predictor.analysis import diagnosis as dg

    torch.set_num_threads(1)
    vessel, recordings, steps, truth = day(args.vessel, args.effect)
    seg = dg.make_segments(recordings, steps.horizon_s, steps.stride_s)
    batched_class = dg.PerturbedBatch
    forms = {"one rollout per parameter": lambda *_: None, "one kernel call (batched)": batched_class}
    seconds: dict[str, list[float]] = {name: [] for name in forms}
    answers: dict[str, object] = {}
    rollout = dg.compiled_rollout(vessel, steps.dt)
    dg.diagnose(recordings, vessel, horizon_s=steps.horizon_s, stride_s=steps.stride_s, segments=seg,
                rollout=rollout)  # warm: numba's cache, the pool's threads
    print(f"{args.vessel}, hidden {truth.effect} {dict(truth.parameters)}; {len(seg)} segments of "
          f"{steps.horizon_s:g} s at dt {steps.dt:g} s; load average {os.getloadavg()[0]:.1f}")
    for repeat in range(args.repeats):
        for name in (forms if repeat % 2 == 0 else reversed(forms)):
            dg.PerturbedBatch = forms[name]
            started = time.perf_counter()
            found = dg.diagnose(recordings, vessel, horizon_s=steps.horizon_s, stride_s=steps.stride_s,
                                segments=seg, rollout=rollout)
            seconds[name].append(time.perf_counter() - started)
            answers[name] = (found.cause, found.parameters, [e.heldout_loss for e in found.evidence])
        print(f"repeat {repeat}: " + ", ".join(f"{n} {s[-1]:.2f} s" for n, s in seconds.items()), flush=True)
    dg.PerturbedBatch = batched_class
    old, new = (np.median(s) for s in seconds.values())
    print(f"median: one rollout per parameter {old:.2f} s, batched {new:.2f} s, ratio old/new {old / new:.2f}; "
          f"load average at the end {os.getloadavg()[0]:.1f}")
    (c0, p0, l0), (c1, p1, l1) = answers.values()
    same = c0 == c1 and p0 == p1 and l0 == l1
    print(f"answer: {c1} {p1}; the same cause, parameters and held-out losses bit for bit: {same}")


if __name__ == "__main__":
    main()
