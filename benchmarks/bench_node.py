#!/usr/bin/env python3
"""Speed of the online predictor: rollout compute, end-to-end latency over DDS, CPU use of the node.

    python benchmarks/bench_node.py [--repeats 2000] [--seconds 10] [--json out/bench_node.json]

1. One 60 s / dt 0.5 s rollout (120 steps, B = 1, the shipped 5-member model), side by side in one run:
   the TorchScript artifact as the node calls it (live.Rollout: preallocated inputs), the same folded
   network as a plain PyTorch eager loop, and as a numpy loop; then an 8-member ensemble, batched in one
   TorchScript call. torch.set_num_threads(1), warm-up first; p50 / p99 over --repeats calls.
2. The node in its own process (`python -m usv_predictor.node`, 10 Hz) fed from this process with IMU at
   200 Hz and the other inputs at their shipped rates (wall clock): end-to-end latency = arrival of
   predicted_path here - its header stamp (the node's clock when the cycle started: state, rollout,
   encoding, DDS); input-to-path = arrival - stamp of the newest IMU message sent before it (includes the
   wait for the next timer tick, up to 1 / rate_hz); CPU of the node process from /proc over the run.
Figures depend on the machine and its load (2 shared cores here): see docs/node.md for the recorded run.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

from usv_predictor.config import package_share_path
from usv_predictor.models.artifact import export_module, load_artifact
from usv_predictor.models.dnn import DnnConfig, DnnModel, DnnRollout
from usv_predictor.node import live

H = 120


def percentiles(seconds: list[float]) -> dict[str, float]:
    ms = np.array(seconds) * 1e3
    return {"p50_ms": float(np.percentile(ms, 50)), "p99_ms": float(np.percentile(ms, 99)), "n": len(ms)}


def timed(fn, repeats: int) -> dict[str, float]:
    for _ in range(20):
        fn()
    out = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        out.append(time.perf_counter() - start)
    return percentiles(out)


def folded(module) -> dict[str, torch.Tensor]:
    names = ("m_s", "w_c", "bias", "head", "phase", "hidden_w", "hidden_b")
    return {n: getattr(module, n).detach().clone() for n in names}


def eager_rollout(p: dict[str, torch.Tensor], state: torch.Tensor, controls: torch.Tensor, dt: float) -> torch.Tensor:
    """The artifact's forward (NTF, tanh) written as a plain eager loop over steps, member by member."""
    members = []
    n_s = p["m_s"].shape[1]
    for e in range(p["m_s"].shape[0]):
        s = torch.cat([state, state[:, 3:4] + p["phase"][e]], dim=1)
        s[:, 4:6] = torch.sin(s[:, 4:6])
        rows = [state]
        for k in range(controls.shape[1]):
            lin = s @ p["m_s"][e] + controls[:, k] @ p["w_c"][e] + p["bias"][e]
            h = torch.tanh(lin[:, n_s:])
            for i in range(p["hidden_w"].shape[1]):
                h = torch.tanh(h @ p["hidden_w"][e, i] + p["hidden_b"][e, i])
            s = lin[:, :n_s] + h @ p["head"][e]
            s[:, 4:6] = torch.sin(s[:, 4:6])
            rows.append(s[:, :4])
        members.append(torch.stack(rows, dim=1))
    return torch.stack(members)  # (E, B, H+1, 4): the positions would follow after the loop


def numpy_rollout(p: dict[str, np.ndarray], state: np.ndarray, controls: np.ndarray) -> np.ndarray:
    n_s = p["m_s"].shape[1]
    out = np.empty((p["m_s"].shape[0], controls.shape[0] + 1, 4))
    for e in range(p["m_s"].shape[0]):
        s = np.concatenate([state, state[3:4] + p["phase"][e, 0]])
        s[4:6] = np.sin(s[4:6])
        out[e, 0] = state
        for k in range(controls.shape[0]):
            lin = s @ p["m_s"][e] + controls[k] @ p["w_c"][e] + p["bias"][e, 0]
            h = np.tanh(lin[n_s:])
            for i in range(p["hidden_w"].shape[1]):
                h = np.tanh(h @ p["hidden_w"][e, i] + p["hidden_b"][e, i, 0])
            s = lin[:n_s] + h @ p["head"][e]
            s[4:6] = np.sin(s[4:6])
            out[e, k + 1] = s[:4]
    return out


def bench_compute(repeats: int, tmp: Path) -> dict:
    torch.set_num_threads(1)
    artifact = load_artifact(package_share_path("models", "default.pt"))
    rollout = live.Rollout(artifact, H)
    state, controls = np.array([5.0, 0.1, 0.02, 0.3]), np.array([0.2, 650.0])
    params = folded(artifact.module)
    t_state = torch.tensor(state[None], dtype=params["m_s"].dtype)
    t_controls = torch.tensor(np.tile(controls, (1, H, 1)), dtype=params["m_s"].dtype)
    np_params = {k: v.double().numpy() for k, v in params.items()}
    np_controls = np.tile(controls, (H, 1))
    with torch.inference_mode():
        reference = rollout(state, controls)[:, :, [0, 1, 2, 5]]
        eager = eager_rollout(params, t_state, t_controls, artifact.dt)[:, 0, 1:].double().numpy()
    numpy_out = numpy_rollout(np_params, state, np_controls)[:, 1:]
    agreement = {"eager_vs_torchscript_max_abs": float(np.abs(eager - reference).max()),
                 "numpy_vs_torchscript_max_abs": float(np.abs(numpy_out - reference).max())}

    def run_eager() -> None:
        with torch.inference_mode():
            eager_rollout(params, t_state, t_controls, artifact.dt)

    results = {
        "torchscript_5": timed(lambda: rollout(state, controls), repeats),
        "eager_5": timed(run_eager, max(50, repeats // 10)),
        "numpy_5": timed(lambda: numpy_rollout(np_params, state, np_controls), max(50, repeats // 10)),
    }
    # 8 untrained members of the same architecture: the cost, not the answer, is measured
    members = [DnnModel(DnnConfig.for_features("NTF")).eval() for _ in range(8)]
    eight = export_module(tmp / "ensemble8.pt", DnnRollout(members, artifact.dt),
                          {**artifact.metadata, "ensemble_size": 8})
    rollout8 = live.Rollout(eight, H)
    results["torchscript_8_batched"] = timed(lambda: rollout8(state, controls), repeats)
    results["agreement"] = agreement
    return results


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def bench_end_to_end(seconds: float) -> dict:
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    import msg_adapters
    from usv_predictor.config import load_predictor_config

    domain = 150 + os.getpid() % 80
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    os.environ.update({"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"})
    process = subprocess.Popen([sys.executable, "-m", "usv_predictor.node", "--ros-args", "-p", "rate_hz:=10.0",
                                "--log-level", "error"], env=env)
    context = Context()
    rclpy.init(context=context, domain_id=domain)
    peer = Node("bench_feeder", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(peer)
    make = msg_adapters.rclpy_factory()
    cfg = load_predictor_config()
    rates = {"imu": 200.0, "velocity": 20.0, "heading": 20.0, "rudder_angle": 10.0, "engine_rpm": 10.0, "gnss": 5.0}
    values = {"imu": (0.02, 0.0, 0.0, -9.81, math.nan), "velocity": (5.0, 0.1, 0.02), "heading": (0.5,),
              "rudder_angle": (0.1,), "engine_rpm": (650.0,), "gnss": (35.38, 119.56, 0.0)}
    pubs, adapters = {}, {}
    for role in rates:
        entry = cfg.input(role)
        pubs[role] = peer.create_publisher(make(entry.ros_type), entry.topic, 10)
        adapters[role] = msg_adapters.get_adapter(role, entry.ros_type, **entry.options)
    arrivals: list[tuple[int, int, int]] = []  # (arrival ns, header stamp ns, newest imu stamp ns)
    last_imu = [0]

    def on_path(msg) -> None:
        now = time.time_ns()
        arrivals.append((now, msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec, last_imu[0]))

    peer.create_subscription(make("nav_msgs/msg/Path"), "predicted_path", on_path, 10)
    deadline = time.monotonic() + 60
    while peer.count_publishers("predicted_path") == 0 and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    next_due = {role: time.monotonic() for role in rates}
    warm_until = time.monotonic() + 2.0
    cpu_start = wall_start = None
    end = warm_until + seconds
    try:
        while time.monotonic() < end:
            now = time.monotonic()
            if cpu_start is None and now >= warm_until:
                cpu_start, wall_start = cpu_seconds(process.pid), now
                arrivals.clear()
            for role, rate in rates.items():
                if now >= next_due[role]:
                    stamp = time.time_ns()
                    pubs[role].publish(adapters[role].encode(stamp, values[role], make, cfg.input(role).frame_id))
                    if role == "imu":
                        last_imu[0] = stamp
                    next_due[role] += 1.0 / rate
            executor.spin_once(timeout_sec=max(0.0, min(next_due.values()) - time.monotonic()))
        cpu = (cpu_seconds(process.pid) - cpu_start) / (time.monotonic() - wall_start)
    finally:
        executor.shutdown()
        peer.destroy_node()
        rclpy.try_shutdown(context=context)
        process.terminate()
        process.wait(timeout=15)
    stamps = np.array(arrivals)
    return {"paths": len(arrivals), "seconds": seconds,
            "path_rate_hz": len(arrivals) / seconds,
            "end_to_end": percentiles(list((stamps[:, 0] - stamps[:, 1]) / 1e9)),
            "input_to_path": percentiles(list((stamps[:, 0] - stamps[:, 2]) / 1e9)),
            "node_cpu_percent_of_one_core": 100.0 * cpu}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=2000)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        result = {"compute": bench_compute(args.repeats, Path(tmp))}
    for name, figures in result["compute"].items():
        if name != "agreement":
            print(f"rollout {name:22s} p50 {figures['p50_ms']:7.3f} ms  p99 {figures['p99_ms']:7.3f} ms  (n={figures['n']})")
    print(f"agreement with the artifact: {result['compute']['agreement']}")
    result["node"] = bench_end_to_end(args.seconds)
    node = result["node"]
    print(f"node at 10 Hz, IMU 200 Hz: {node['paths']} paths in {node['seconds']:g} s; end-to-end p50 "
          f"{node['end_to_end']['p50_ms']:.2f} ms p99 {node['end_to_end']['p99_ms']:.2f} ms; input-to-path p50 "
          f"{node['input_to_path']['p50_ms']:.2f} ms p99 {node['input_to_path']['p99_ms']:.2f} ms; "
          f"CPU {node['node_cpu_percent_of_one_core']:.1f} % of one core")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
