"""Simulator speed: 4 minutes of a manoeuvre at 100 Hz output, side by side with a reference.

Prints, for a 240 s turning circle and zig-zag in the Rizhao-like sea (current + gusty wind + waves):
  - the default: RK4 at dt = 0.05 s with cubic-Hermite dense output at 100 Hz,
  - the reference: RK4 stepping at the 100 Hz output rate itself (dt = 0.01 s), same code,
  - the largest position difference between the two (for the zig-zag it includes the autopilot's
    sampling: it reverses the rudder on the integration steps, 20 Hz against 100 Hz),
  - the sensor models and the bag writer, for the whole `replay simulate` cost of one bag.
Run: .venv/bin/python benchmarks/bench_simulator.py [--repeat N]
"""
from __future__ import annotations

import argparse
import dataclasses
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from usv_predictor.physics.dynamics import ManoeuvringModel
from usv_predictor.physics.manoeuvres import TurningCircle, ZigZag
from usv_predictor.physics.scenario import RIZHAO_SEA, make_scenario
from usv_predictor.physics.sensors import measure
from usv_predictor.physics.simulator import simulate
from usv_predictor.physics.vessel import load_vessel


def timed(fn, repeat: int):
    times, result = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    jari = load_vessel("jari_usv")
    model = ManoeuvringModel(jari)
    scenario = make_scenario(jari, RIZHAO_SEA)
    # Gusts are drawn on the integration grid, so they differ between step sizes: compare without them.
    env = dataclasses.replace(scenario.environment, gust_std=0.0)
    print(f"{'manoeuvre (240 s, 100 Hz out)':34s} {'dt=0.05 + Hermite':>18s} {'dt=0.01 reference':>18s} "
          f"{'max |dx| (m)':>13s}")
    for manoeuvre in (TurningCircle(20.0, 650.0, duration_s=240.0), ZigZag(20.0, 20.0, 650.0, duration_s=240.0)):
        fast_t, fast = timed(lambda: simulate(model, manoeuvre, env, dt=0.05), args.repeat)
        ref_t, ref = timed(lambda: simulate(model, manoeuvre, env, dt=0.01), args.repeat)
        gap = float(np.max(np.hypot(*(fast.eta[:, :2] - ref.eta[:, :2]).T)))
        print(f"{manoeuvre.name:34s} {fast_t * 1e3:15.0f} ms {ref_t * 1e3:15.0f} ms {gap:13.4f}")
    traj = simulate(model, TurningCircle(20.0, 650.0, duration_s=240.0), env)
    sense_t, signals = timed(lambda: measure(traj, env, scenario.sensor_spec), args.repeat)
    messages = sum(len(s) for s in signals.values())
    from usv_predictor.config import load_predictor_config
    from usv_predictor.replay.bagio import config_topic_specs, write_bag

    specs = config_topic_specs(load_predictor_config(), include_ground_truth=True)
    streams = [(specs[role], signals[role]) for role in specs if role in signals]
    with tempfile.TemporaryDirectory() as tmp:
        counter = iter(range(1000))
        write_t, _ = timed(lambda: write_bag(Path(tmp) / f"b{next(counter)}", streams), args.repeat)
    print(f"sensor models, 240 s ({messages} samples): {sense_t * 1e3:.0f} ms")
    print(f"bag writer, {messages} messages (sqlite3 + zstd): {write_t * 1e3:.0f} ms ({messages / write_t:,.0f} msg/s)")


if __name__ == "__main__":
    main()
