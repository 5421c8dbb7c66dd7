"""Cost of the online estimator (fitting/online.py) per call, beside its reference in the same run: one
ManoeuvringModel.derivative call (the float grey box's unit of work) and the node's cycle at 10 Hz (100 ms).

    python benchmarks/bench_online.py [--calls N]

The node's share (node/sea.py LiveSea.observe: the filter step on the dt grid plus setting the grey box's terms,
every cycle at 10 Hz, dt 0.5 s: one cycle in five feeds) is printed beside the cycle's rollout of the same
grey-box TorchScript artifact and of the shipped DNN (live.Rollout, 120 steps), measured in the same run.

Feeds a simulated 20 deg turning circle in a 0.4 m/s current (noiseless truth at 10 Hz and at 2 Hz: the node's rate
and the model step of `replay evaluate --adaptive`) through OnlineEstimator.step and prints p50 / p99 per call.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.timing import best_seconds  # noqa: E402
from usv_predictor.fitting.online import OnlineEstimator  # noqa: E402
from usv_predictor.physics.dynamics import CALM, ManoeuvringModel  # noqa: E402
from usv_predictor.physics.environment import Environment  # noqa: E402
from usv_predictor.physics.manoeuvres import TurningCircle  # noqa: E402
from usv_predictor.physics.simulator import simulate  # noqa: E402
from usv_predictor.physics.vessel import load_vessel  # noqa: E402


def step_times(rate_hz: float, calls: int) -> np.ndarray:
    """(calls,) seconds per OnlineEstimator.step at `rate_hz` on the simulated turn (after 20 warm-up calls)."""
    vessel = load_vessel("jari_usv")
    traj = simulate(ManoeuvringModel(vessel), TurningCircle(20.0, 650.0, duration_s=calls / rate_hz + 5.0),
                    Environment(current_speed=0.4, current_to_deg=135.0))
    every = int(round(100.0 / rate_hz))  # the trajectory is at 100 Hz
    t, nu, psi, levels = traj.t_s[::every], traj.nu[::every], traj.psi_unwrapped[::every], traj.actuators[::every]
    estimator = OnlineEstimator(vessel)
    out = []
    for k in range(min(calls + 20, len(t))):
        start = time.perf_counter()
        estimator.step(float(t[k]), float(nu[k, 0]), float(nu[k, 1]), float(nu[k, 2]), float(psi[k]), levels[k])
        if k >= 20:
            out.append(time.perf_counter() - start)
    return np.array(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=2000, help="calls per rate (default 2000)")
    calls = parser.parse_args().calls
    model = ManoeuvringModel(load_vessel("jari_usv"))
    state = [0.0, 0.0, 0.3, 5.0, 0.1, 0.05, 0.2, 650.0]
    n = 20000
    per_derivative = best_seconds(lambda: [model.derivative(state, 0.2, 650.0, CALM) for _ in range(n)], 5) / n
    print(f"reference: one ManoeuvringModel.derivative {per_derivative * 1e6:.1f} us; the node's cycle at 10 Hz "
          f"100000 us")
    for rate in (10.0, 2.0):
        times = step_times(rate, calls)
        p50, p99 = np.percentile(times, 50) * 1e6, np.percentile(times, 99) * 1e6
        print(f"OnlineEstimator.step at {rate:g} Hz ({len(times)} calls): p50 {p50:.0f} us, p99 {p99:.0f} us = "
              f"{p50 / (per_derivative * 1e6):.0f} derivative calls, {100 * p50 / 1e5:.2f} % of a 10 Hz cycle")
    node_share(min(calls, 1500))


def node_share(cycles: int) -> None:
    """Added cost per node cycle (LiveSea.observe) beside the cycle's rollout, same run."""
    import os
    import tempfile

    import torch

    from usv_predictor.fitting.online import OnlineConfig
    from usv_predictor.models.artifact import export_module, load_artifact
    from usv_predictor.models.greybox import greybox_predictor
    from usv_predictor.models.loading import default_model_path
    from usv_predictor.node.live import LiveState, Rollout
    from usv_predictor.node.sea import LiveSea

    torch.set_num_threads(1)  # as the node's main()
    vessel = load_vessel("jari_usv")
    traj = simulate(ManoeuvringModel(vessel), TurningCircle(20.0, 650.0, duration_s=cycles / 10.0 + 5.0),
                    Environment(current_speed=0.4, current_to_deg=135.0))
    t, nu, psi, levels = traj.t_s[::10], traj.nu[::10], traj.psi_unwrapped[::10], traj.actuators[::10]  # 10 Hz
    with tempfile.TemporaryDirectory() as tmp:
        grey = greybox_predictor(vessel, 0.5)
        artifact = export_module(Path(tmp) / "greybox.pt", grey.rollout, grey.metadata)
        rollouts = {"grey box (TorchScript)": Rollout(artifact, 120, 1),
                    "shipped DNN, 5 members": Rollout(load_artifact(default_model_path()), 120, 5)}
        sea = LiveSea(artifact, "jari_usv", OnlineConfig(), True, 0.5, 10.0)
        observe, fed = [], 0
        for k in range(min(cycles, len(t))):
            state = LiveState(int(round(t[k] * 1e9)), np.array([nu[k, 0], nu[k, 1], nu[k, 2], psi[k]]),
                              np.asarray(levels[k], dtype=float), None, {})
            start = time.perf_counter()
            fed += sea.observe(state) is not None
            observe.append(time.perf_counter() - start)
        observe_us = np.array(observe) * 1e6
        fed_us = np.sort(observe_us)[-fed:]  # the cycles that fed (the others only compare two integers)
        print(f"\nin the node (10 Hz cycles, dt 0.5 s, {len(observe)} cycles, {fed} fed; load "
              f"{' '.join(f'{x:.1f}' for x in os.getloadavg())})")
        print(f"  LiveSea.observe per cycle: mean {observe_us.mean():.0f} us, p50 "
              f"{np.percentile(observe_us, 50):.1f} us; "
              f"per fed cycle p50 {np.percentile(fed_us, 50):.0f} us, p99 {np.percentile(fed_us, 99):.0f} us")
        state, controls = np.array([5.0, 0.1, 0.05, 0.0]), np.array([0.2, 650.0])
        for name, rollout in rollouts.items():
            times = []
            for _ in range(200):
                start = time.perf_counter()
                rollout(state, controls)
                times.append(time.perf_counter() - start)
            p50 = np.percentile(times, 50) * 1e6
            print(f"  the cycle's rollout, {name}: p50 {p50:.0f} us; the estimator adds "
                  f"{observe_us.mean() / p50 * 100:.1f} % "
                  f"on average, {np.percentile(fed_us, 50) / p50 * 100:.1f} % in a cycle that feeds")


if __name__ == "__main__":
    main()
