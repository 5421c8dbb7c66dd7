#!/usr/bin/env python3
"""Speed of the online predictor, side by side in one run: rollout compute, end-to-end latency over DDS, CPU.

    python benchmarks/bench_node.py [--repeats 2000] [--seconds 10] [--baseline 67fb230] [--json out/bench_node.json]

1. Rollout compute, one 60 s / dt 0.5 s rollout (120 steps) of the shipped 5-member model, torch.set_num_threads(1),
   warm-up first, p50 / p99 over --repeats calls, in alternating rounds so that a change of load hits all alike:
   the node's call now (live.Rollout on the model as models/loading.load_model returns it: the DNN stepped with
   numpy, models/dnn.NumpyDnnRollout), TorchScript's fused rollout (models/dnn.FusedDnnRollout: the node's call
   before) and the file's own rollout; the file's module after torch.jit.freeze, and after freeze +
   optimize_for_inference; the same folded network as a plain eager loop (members one by one, no fused batched
   matmuls) and as a numpy loop (members one by one); the network re-scripted with tanh(x) = 2 sigmoid(2x) - 1; and
   the 64-candidate batch (B = 64, 64 different rudders, one call) for numpy's, numpy's split across two threads
   (the node's candidates_threads 2) and by its first 3 members (candidates_members 3), numpy's row form as it ran
   before 2026-11-26 (row_form_batch), the fused, the file's rollout, freeze and the sigmoid form. The header prints
   OPENBLAS_CORETYPE (numpy's OpenBLAS kernels: this machine's environment sets Haswell, AVX2).
2. The node in its own process at 10 Hz, fed from this process over DDS (loopback, localhost discovery) with the
   inputs as CDR bytes (stamps patched in place: the feeder costs next to nothing), IMU at 200 Hz then at 1 kHz,
   the other inputs at 20/20/10/10/5 Hz; the Path arrives on a raw subscription (its header stamp read from the
   bytes, so the receiver's own deserialisation is not counted). Variants, each a fresh process:
     old      the node of --baseline (git archive of that commit): message objects in and out, rclpy.spin
     events   this node (CDR in and out) with rclpy's EventsExecutor (what main() uses)
     single   this node with the SingleThreadedExecutor
     events-own-blas   this node (EventsExecutor) without OPENBLAS_CORETYPE and OPENBLAS_L2_SIZE: OpenBLAS picks
              its kernels itself (AVX-512 `SkylakeX` on this Zen 5 VM, whose environment pins `Haswell`)
     events-2threads, events-3members, events-2threads-3members   this node (EventsExecutor) with
              candidates_threads:=2 (a candidate batch split across two threads), candidates_members:=3 (answered
              by the first 3 members' mean), or both
   end-to-end = arrival of predicted_path - its header stamp (the node's clock when the cycle started: decoding,
   state, rollout, encoding, DDS); input-to-path = arrival - stamp of the newest IMU message sent before it
   (includes the wait for the next timer tick, up to 1 / rate_hz); CPU of the node process from /proc.
3. Candidate plans (events variant): 64 candidates x 120 steps on candidate_plans at 2 Hz; answer = arrival of
   candidate_predictions (matched by the stamp) - publication of the plans; the node's own figures from
   /diagnostics (compute of the batched rollout, arrival -> published).
Figures depend on the machine and its load (2 shared cores here): the load average is printed with them.
--candidates-thread: only a quick in-process measure (bench_candidates_thread): a cycle due while 64 candidates are
answered, the answer run first on the cycle's thread (as before) or on a worker thread (as the node now does).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import struct
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from usv_predictor.config import package_share_path
from usv_predictor.models import loading
from usv_predictor.models.artifact import export_like, load_artifact
from usv_predictor.models.dnn import DnnConfig, DnnModel, DnnRollout, NumpyDnnRollout, _heading_fold, fused_rollout
from usv_predictor.node import live

H = 120
REPO = Path(__file__).resolve().parents[1]
BASELINE = "67fb230"  # the last commit before issue 13: the message-object node
RATES = {"imu": 200.0, "velocity": 20.0, "heading": 20.0, "rudder_angle": 10.0, "engine_rpm": 10.0, "gnss": 5.0}  # Hz
VALUES = {"imu": (0.02, 0.0, 0.0, -9.81, math.nan), "velocity": (5.0, 0.1, 0.02), "heading": (0.5,),
          "rudder_angle": (0.1,), "engine_rpm": (650.0,), "gnss": (35.38, 119.56, 0.0)}
NS = 1_000_000_000
# --noisy-feed: sensor-like noise (standard deviations in the message's units: m/s, rad/s, m/s^2, deg), so that no
# two fit checks see the same box means (the fit check serves a window whose content it rolled out before, node/fit.py)
NOISE = {"imu": (0.002, 0.05, 0.05, 0.05, 0.0), "velocity": (0.02, 0.02, 0.002), "heading": (0.2,)}
NOISY_VARIANTS = 16  # pre-serialized messages per noisy input, one drawn per send
GC_LOG = "BENCH_GC_LOG"  # environment variable of the node process (--gc-stats): where its gc pauses are written
OWN_BLAS = "events-own-blas"  # variant: this node (EventsExecutor) without OPENBLAS_CORETYPE in its environment
# variants: this node (EventsExecutor) with node parameters of its own (on top of --param), their label
TUNED = {"events-2threads": (("candidates_threads:=2",), "new, candidates on 2 threads"),
         "events-3members": (("candidates_members:=3",), "new, candidates by 3 members"),
         "events-2threads-3members": (("candidates_threads:=2", "candidates_members:=3"),
                                      "new, candidates 2 thr x 3 mem")}


def percentiles(seconds: list[float] | np.ndarray) -> dict[str, float]:
    ms = np.asarray(seconds, dtype=float) * 1e3
    if len(ms) == 0:
        return {"p50_ms": math.nan, "p99_ms": math.nan, "n": 0}
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


def timed_alternating(fns: dict[str, Any], repeats: int, rounds: int = 10) -> dict[str, dict[str, float]]:
    """timed() of several calls in `rounds` alternating rounds of repeats / rounds calls each: on a shared machine a
    change of load then falls on every call alike, and their figures compare."""
    for fn in fns.values():
        for _ in range(20):
            fn()
    out: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(rounds):
        for name, fn in fns.items():
            for _ in range(max(1, repeats // rounds)):
                start = time.perf_counter()
                fn()
                out[name].append(time.perf_counter() - start)
    return {name: percentiles(times) for name, times in out.items()}


def load() -> str:
    return "/".join(f"{x:.2f}" for x in os.getloadavg())


# ----------------------------------------------------------------------------- 1. rollout compute


def folded(module) -> dict[str, torch.Tensor]:
    names = ("m_s", "w_c", "bias", "head", "phase", "hidden_w", "hidden_b")
    return {n: getattr(module, n).detach().clone() for n in names}


def eager_rollout(p: dict[str, torch.Tensor], state: torch.Tensor, controls: torch.Tensor) -> torch.Tensor:
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


def row_form_batch(r: NumpyDnnRollout, state: np.ndarray, controls: np.ndarray) -> np.ndarray:
    """NumpyDnnRollout's candidate form as it ran before 2026-11-26: the B states the rows of x (H + 1, E, B,
    S + C + 1), the first activation on the strided [pre | unit] columns, the output product h head, then the
    member-major kinematics; with the row-form weights `first`, `hidden`, `head` the rollout keeps. What the
    transposed form and the step-major kinematics gain (timed here); test_dnn_fused.py proves the transposed form
    equal to it (any depth, activation and heading columns)."""
    e, b, horizon = r.ensemble_size, state.shape[0], controls.shape[1]
    n_s, c = r.n_state, r.n_controls
    x = np.empty((horizon + 1, e, b, n_s + c + 1), dtype=r.dtype)
    x[0, :, :, :4] = state
    x[0, :, :, 4:n_s] = state[None, :, 3:4] + r.phase[:, None, :]
    r._heading(x[0, :, :, 4:n_s])
    x[:horizon, :, :, n_s: n_s + c] = controls.transpose(1, 0, 2)[:, None]
    x[horizon, :, :, n_s: n_s + c] = 0.0
    x[:, :, :, n_s + c] = 1.0
    y = np.empty((e, b, r.first.shape[2]), dtype=r.dtype)
    s_lin, g = y[..., :n_s], y[..., n_s:]
    layers = [(w, np.empty((e, b, w.shape[2]), dtype=r.dtype)) for w in r.hidden]
    last = layers[-1][1] if layers else g  # (E, B, W): what the head reads
    t = np.empty((e, b, n_s), dtype=r.dtype)
    for x_k, s_next, columns in zip(x[:-1], x[1:, :, :, :n_s], x[1:, :, :, 4:n_s]):
        np.matmul(x_k, r.first, out=y)
        h = r._act(g)
        for w, z in layers:
            np.matmul(h, w, out=z)
            h = r._act(z)
        np.matmul(last, r.head, out=t)
        np.add(t, s_lin, out=s_next)
        r._heading(columns)
    path = x[1:, :, :, :4].transpose(1, 2, 0, 3).astype(np.float64)  # (E, B, H, 4)
    full = np.concatenate([np.broadcast_to(state[None, :, None, :], (e, b, 1, 4)), path], axis=2)
    cos_psi, sin_psi = np.cos(full[..., 3]), np.sin(full[..., 3])
    velocity = np.stack([full[..., 0] * cos_psi - full[..., 1] * sin_psi,
                         full[..., 0] * sin_psi + full[..., 1] * cos_psi], axis=-1)
    out = np.empty((e, b, horizon, 6))
    out[..., 0:3] = path[..., 0:3]
    np.cumsum(0.5 * r.dt * (velocity[:, :, 1:] + velocity[:, :, :-1]), axis=2, out=out[..., 3:5])
    out[..., 5] = path[..., 3]
    return out


class SigmoidTanhRollout(DnnRollout):
    """The artifact's network with tanh(x) computed as 2 sigmoid(2x) - 1 (in place): what the activation costs."""

    def _activation_(self, h: torch.Tensor) -> torch.Tensor:
        if self.clipped:
            return h.clamp_(0.0, self.ceiling)
        return h.mul_(2.0).sigmoid_().mul_(2.0).sub_(1.0)


def rescripted(artifact, cls: type[DnnRollout]) -> torch.jit.ScriptModule:
    """A DnnRollout subclass scripted around the artifact's folded buffers (its constants from the metadata)."""
    source, arch = artifact.module, artifact.metadata["architecture"]
    module = cls.__new__(cls)
    torch.nn.Module.__init__(module)
    module.trig_mode = _heading_fold(artifact.metadata["feature_set"])[0]
    module.n_trig, module.n_controls = source.phase.shape[-1], source.w_c.shape[1]
    module.clipped, module.ceiling = arch["activation"] == "clipped_relu", float(arch["ceiling"])
    module.dt, module.ensemble_size = float(artifact.dt), source.m_s.shape[0]
    for name, buffer in source.named_buffers():
        module.register_buffer(name, buffer.clone())
    return torch.jit.script(module.eval())


def bench_compute(repeats: int, tmp: Path) -> dict:
    torch.set_num_threads(1)
    path = package_share_path("models", "default.pt")
    artifact = load_artifact(path)  # the file's module only (no fusing)
    rollout = live.Rollout(artifact, H)
    numpy_model = loading.load_model(str(path), physics=False)  # what the node and `replay evaluate` load now
    assert isinstance(numpy_model.inference, NumpyDnnRollout), numpy_model.inference_note
    numpy_form = live.Rollout(numpy_model, H)
    # TorchScript's fused rollout: what load_model gave before NumpyDnnRollout (and still gives when numpy's fails)
    fused = live.Rollout(dataclasses.replace(artifact, inference=fused_rollout(artifact)), H)
    state, controls = np.array([5.0, 0.1, 0.02, 0.3]), np.array([0.2, 650.0])
    params = folded(artifact.module)
    t_state = torch.tensor(state[None], dtype=params["m_s"].dtype)
    t_controls = torch.tensor(np.tile(controls, (1, H, 1)), dtype=params["m_s"].dtype)
    np_params = {k: v.double().numpy() for k, v in params.items()}
    np_controls = np.tile(controls, (H, 1))
    frozen = torch.jit.freeze(torch.jit.load(str(path)).eval())
    optimised = torch.jit.optimize_for_inference(torch.jit.freeze(torch.jit.load(str(path)).eval()))
    sigmoid = rescripted(artifact, SigmoidTanhRollout)
    batch_state = t_state.expand(64, 4).contiguous()
    batch_controls = t_controls.expand(64, H, 2).contiguous()
    candidates = np.tile(controls, (64, H, 1))
    candidates[:, :, 0] = np.linspace(-0.5, 0.5, 64)[:, None]  # 64 different rudders
    with torch.inference_mode():
        reference = rollout(state, controls)  # (E, H, 6)
        numpy_out = numpy_form(state, controls)
        fused_out = fused(state, controls)
        numpy_batch = numpy_form.batch(state, candidates)
        fused_batch = fused.batch(state, candidates)
        file_batch = rollout.batch(state, candidates)
        eager = eager_rollout(params, t_state, t_controls)[:, 0, 1:].double().numpy()
        variants = {name: module(t_state, t_controls)[:, 0].double().numpy()
                    for name, module in (("freeze", frozen), ("optimize_for_inference", optimised),
                                         ("sigmoid", sigmoid))}
    numpy_loop = numpy_rollout(np_params, state, np_controls)[:, 1:]
    agreement = {"numpy_vs_torchscript_max_abs": float(np.abs(numpy_out - reference).max()),
                 "numpy_vs_torchscript_64_candidates_max_abs": float(np.abs(numpy_batch - file_batch).max()),
                 "fused_vs_torchscript_max_abs": float(np.abs(fused_out - reference).max()),
                 "fused_vs_torchscript_64_candidates_max_abs": float(np.abs(fused_batch - file_batch).max()),
                 "numpy_vs_fused_64_candidates_max_abs": float(np.abs(numpy_batch - fused_batch).max()),
                 "eager_vs_torchscript_max_abs": float(np.abs(eager - reference[..., [0, 1, 2, 5]]).max()),
                 "numpy_loop_vs_torchscript_max_abs": float(np.abs(numpy_loop - reference[..., [0, 1, 2, 5]]).max()),
                 **{f"{name}_vs_torchscript_max_abs": float(np.abs(out - reference).max()) for name,
                    out in variants.items()}}

    def call(module, s, c):
        def run() -> None:
            with torch.inference_mode():
                module(s, c)
        return run

    def run_eager() -> None:
        with torch.inference_mode():
            eager_rollout(params, t_state, t_controls)

    few = max(50, repeats // 10)
    pair = timed_alternating({"numpy (NumpyDnnRollout: the node's call now)": lambda: numpy_form(state, controls),
                              "fused TorchScript (FusedDnnRollout: before)": lambda: fused(state, controls),
                              "torchscript_5 (the file's rollout)": lambda: rollout(state, controls)},
                             repeats)
    row_form = numpy_model.inference
    agreement["numpy_vs_row_form_64_candidates_max_abs"] = float(
        np.abs(numpy_batch - row_form_batch(row_form, state[None].repeat(64, 0), candidates)).max())
    from concurrent.futures import ThreadPoolExecutor

    helper = ThreadPoolExecutor(max_workers=1)  # candidates_threads 2
    three = live.Rollout(numpy_model, H, ensemble_size=3)  # candidates_members 3
    agreement["numpy_2_threads_vs_one_call_64_candidates_max_abs"] = float(
        np.abs(numpy_form.batch(state, candidates, helper=helper) - numpy_batch).max())
    agreement["numpy_3_members_mean_vs_5_members_mean_64_candidates_max_abs_position_m"] = float(
        np.abs(three.batch(state, candidates).mean(axis=0) - numpy_batch.mean(axis=0))[..., 3:5].max())
    pair_64 = timed_alternating({"batch 64 candidates numpy (the node's call now)":
                                 lambda: numpy_form.batch(state, candidates),
                                 "batch 64 candidates numpy, 2 threads (candidates_threads 2)":
                                 lambda: numpy_form.batch(state, candidates, helper=helper),
                                 "batch 64 candidates numpy, 3 members (candidates_members 3)":
                                 lambda: three.batch(state, candidates),
                                 "batch 64 candidates numpy row form (before)":
                                 lambda: row_form_batch(row_form, state[None].repeat(64, 0), candidates),
                                 "batch 64 candidates fused "
                                 "TorchScript (before)": lambda: fused.batch(state, candidates),
                                 "batch 64 candidates torchscript_5 (the file's)":
                                 lambda: rollout.batch(state, candidates)}, few)
    results = {
        **pair,
        "torchscript_5 jit.freeze": timed(call(frozen, t_state, t_controls), repeats),
        "torchscript_5 freeze+optimize_for_inference": timed(call(optimised, t_state, t_controls), repeats),
        "torchscript_5 tanh as 2 sigmoid(2x) - 1": timed(call(sigmoid, t_state, t_controls), repeats),
        "eager_5 (members looped, no fused bmm)": timed(run_eager, few),
        "numpy_5 (members looped, one at a time)": timed(lambda: numpy_rollout(np_params, state, np_controls), few),
        **pair_64,
        "batch 64 candidates jit.freeze": timed(call(frozen, batch_state, batch_controls), few),
        "batch 64 candidates sigmoid tanh": timed(call(sigmoid, batch_state, batch_controls), few),
    }
    helper.shutdown()
    # 8 untrained members of the same architecture: the cost, not the answer, is measured
    members = [DnnModel(DnnConfig.for_features("NTF")).eval() for _ in range(8)]
    eight = export_like(tmp / "ensemble8.pt", DnnRollout(members, artifact.dt), artifact, ensemble_size=8)
    rollout8 = live.Rollout(eight, H)
    results["torchscript_8 batched members"] = timed(lambda: rollout8(state, controls), repeats)
    results["agreement"] = agreement
    return results


# ----------------------------------------------------------------------------- 2. the node over DDS


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def header_stamp(raw: bytes) -> int:
    """header.stamp of a serialized message that starts with a std_msgs/Header (ns)."""
    sec, nanosec = struct.unpack_from("<iI", raw, 4)
    return sec * NS + nanosec


def serve(executor_name: str, ros_args: list[str]) -> int:
    """This node in this process, spun by the named executor (the 'events' and 'single' variants)."""
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.experimental import EventsExecutor

    from usv_predictor.node import node as predictor_node

    torch.set_num_threads(1)
    rclpy.init(args=["predictor", "--ros-args", *ros_args])
    node = predictor_node.PredictorNode()
    executor = EventsExecutor() if executor_name == "events" else SingleThreadedExecutor()
    pauses = gc_pauses() if os.environ.get(GC_LOG) else None
    try:
        predictor_node.spin(node, executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        if pauses is not None:
            Path(os.environ[GC_LOG]).write_text(json.dumps(pauses))
    return 0


def gc_pauses() -> list[tuple[int, int, float]]:
    """[(wall clock ns at the start, generation, ms)] of every garbage collection from now on (--gc-stats), filled
    by a gc callback."""
    import gc

    pauses: list[tuple[int, int, float]] = []
    started = [0, 0.0]

    def callback(phase: str, info: dict) -> None:
        if phase == "start":
            started[0], started[1] = time.time_ns(), time.perf_counter()
        else:
            pauses.append((started[0], int(info["generation"]), 1e3 * (time.perf_counter() - started[1])))

    gc.callbacks.append(callback)
    return pauses


def gc_summary(pauses: list, start: int, end: int) -> dict[str, Any]:
    """Collections per generation within [start, end] (ns) and their longest pause (ms)."""
    inside = [(gen, ms) for at, gen, ms in pauses if start <= at <= end]
    return {f"gen{g}": {"n": sum(1 for gen, _ in inside if gen == g),
                        "max_ms": round(max([ms for gen, ms in inside if gen == g], default=0.0), 3)} for g in range(3)}


def receive(out: Path) -> int:
    """The receiving end (its own process, so that publishing inputs never delays a reception): raw subscriptions
    record (arrival, header stamp) of every predicted_path and candidate_predictions, the newest IMU stamp, and the
    node's own figures from /diagnostics; written to `out` (JSON) on SIGTERM."""
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node

    import msg_adapters

    make = msg_adapters.rclpy_factory()
    rclpy.init()
    node = Node("bench_receiver")
    paths: list[tuple[int, int, int]] = []  # (arrival ns, header stamp ns, newest imu stamp ns)
    answers: list[tuple[int, int]] = []  # (arrival ns, header stamp ns)
    reports: list[tuple[int, dict[str, dict[str, str]]]] = []  # (arrival ns, status -> figures)
    last_imu = [0]

    def on_imu(raw: bytes) -> None:
        last_imu[0] = header_stamp(raw)

    def on_report(msg: Any) -> None:
        figures = {status.name.split(": ", 1)[-1]: {kv.key: kv.value for kv in status.values
                                                    if "_ms_" in kv.key or kv.key in ("checks", "rollouts_served")}
                   for status in msg.status if status.name.endswith(("prediction", "candidate plans", "fit check"))}
        reports.append((time.time_ns(), figures))

    node.create_subscription(make("nav_msgs/msg/Path"), "predicted_path",
                             lambda raw: paths.append((time.time_ns(), header_stamp(raw), last_imu[0])), 10, raw=True)
    node.create_subscription(make("trajectory_msgs/msg/MultiDOFJointTrajectory"), "candidate_predictions",
                             lambda raw: answers.append((time.time_ns(), header_stamp(raw))), 10, raw=True)
    node.create_subscription(make("sensor_msgs/msg/Imu"), "imu/data", on_imu, 100, raw=True)
    node.create_subscription(make("diagnostic_msgs/msg/DiagnosticArray"), "/diagnostics", on_report, 10)
    executor = EventsExecutor()
    executor.add_node(node)
    try:
        while rclpy.ok():
            executor.spin_once(timeout_sec=0.5)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        out.write_text(json.dumps({"paths": paths, "answers": answers, "reports": reports}))
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


class Feeder:
    """Publishes the inputs as CDR bytes with fresh stamps (paced by sleeping), and the candidate plans."""

    def __init__(self, domain: int, noisy: bool = False) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.node import Node
        from rclpy.serialization import serialize_message

        import msg_adapters
        from usv_predictor.config import load_predictor_config

        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = Node("bench_feeder", context=self.context)
        make = msg_adapters.rclpy_factory()
        cfg = load_predictor_config()
        self.publishers, self.templates, self.stamped = {}, {}, {}
        self.rng = np.random.default_rng(13)
        for role in RATES:
            entry = cfg.input(role)
            adapter = msg_adapters.get_adapter(role, entry.ros_type, **entry.options)
            first = serialize_message(adapter.encode(NS, VALUES[role], make, entry.frame_id))
            second = serialize_message(adapter.encode(2 * NS + 5, VALUES[role], make, entry.frame_id))
            changed = [i for i in range(len(first)) if first[i] != second[i]]
            self.stamped[role] = bool(changed)
            assert not changed or (min(changed) >= 4 and max(changed) < 12), f"{role}: stamp not at bytes 4..12"
            variants = [VALUES[role]]
            if noisy and role in NOISE:  # --noisy-feed: NOISY_VARIANTS messages of each noisy input, one drawn per send
                variants = [tuple(v + self.rng.normal(0.0, sd) for v, sd in zip(VALUES[role], NOISE[role]))
                            for _ in range(NOISY_VARIANTS)]
            self.templates[role] = [bytearray(serialize_message(adapter.encode(NS, values, make, entry.frame_id)))
                                    for values in variants]
            self.publishers[role] = self.node.create_publisher(make(entry.ros_type), entry.topic, 10)
        self.plans = self.node.create_publisher(make("trajectory_msgs/msg/JointTrajectory"), "candidate_plans", 10)
        self.candidates = bytearray(serialize_message(candidates_message(make, 64, H)))

    def publish(self, role: str) -> None:
        variants = self.templates[role]
        buffer = variants[int(self.rng.integers(len(variants)))] if len(variants) > 1 else variants[0]
        if self.stamped[role]:
            struct.pack_into("<iI", buffer, 4, *divmod(time.time_ns(), NS))
        self.publishers[role].publish(bytes(buffer))

    def publish_candidates(self) -> int:
        stamp = time.time_ns()
        struct.pack_into("<iI", self.candidates, 4, *divmod(stamp, NS))
        self.plans.publish(bytes(self.candidates))
        return stamp

    def wait_for(self, processes: list[subprocess.Popen]) -> None:
        """Until the node subscribes to the IMU and the receiver to predicted_path."""
        deadline = time.monotonic() + 90.0
        while (self.node.count_subscribers("imu/data") < 2 or self.node.count_publishers("predicted_path") < 1
               or self.node.count_subscribers("predicted_path") < 1):
            assert all(p.poll() is None for p in processes), "the node or the receiver exited"
            assert time.monotonic() < deadline, "the node did not come up within 90 s"
            time.sleep(0.05)

    def run(self, seconds: float, imu_hz: float, process: subprocess.Popen, candidates_hz: float = 0.0) -> dict:
        """Feed for 2 s of warm-up then `seconds` at these rates; (start ns, end ns) of the measured part, CPU."""
        rates = {**RATES, "imu": imu_hz}
        next_due = {role: time.monotonic() for role in rates}
        plans_due = math.inf if candidates_hz <= 0 else time.monotonic() + 2.0
        warm_until = time.monotonic() + 2.0
        end = warm_until + seconds
        cpu_start = wall_start = start_ns = None
        sent: list[int] = []
        while True:
            now = time.monotonic()
            if now >= end:
                break
            if cpu_start is None and now >= warm_until:
                cpu_start, wall_start, start_ns = cpu_seconds(process.pid), now, time.time_ns()
                sent.clear()
            for role, rate in rates.items():
                while now >= next_due[role]:
                    self.publish(role)
                    next_due[role] += 1.0 / rate
            if now >= plans_due:
                sent.append(self.publish_candidates())
                plans_due += 1.0 / candidates_hz
            time.sleep(max(0.0, min(min(next_due.values()), plans_due, end) - time.monotonic()))
        cpu = (cpu_seconds(process.pid) - cpu_start) / (time.monotonic() - wall_start)
        end_ns = time.time_ns()
        time.sleep(1.0)  # the inputs stop: the node goes stale and stops predicting
        return {"imu_hz": imu_hz, "seconds": seconds, "window_ns": (start_ns, end_ns), "candidates_sent": sent,
                "load": load(), "node_cpu_percent_of_one_core": 100.0 * cpu}

    def close(self) -> None:
        import rclpy

        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def figures(run: dict, received: dict, pauses: list | None = None) -> dict:
    """The run's latencies from what the receiver recorded inside the run's window (and the node's gc pauses)."""
    start, end = run.pop("window_ns")
    if pauses is not None:
        run["gc"] = gc_summary(pauses, start, end)
    sent = run.pop("candidates_sent")
    arrivals = np.array([p for p in received["paths"] if start <= p[0] <= end], dtype=np.int64).reshape(-1, 3)
    run.update(paths=len(arrivals), end_to_end=percentiles((arrivals[:, 0] - arrivals[:, 1]) / 1e9),
               input_to_path=percentiles((arrivals[:, 0] - arrivals[:, 2]) / 1e9))
    reports = [figures for at, figures in received["reports"] if start <= at <= end + NS]
    run["node_reports"] = reports[-1].get("prediction", {}) if reports else {}
    run["fit_check"] = reports[-1].get("fit check", {}) if reports else {}
    if sent:
        answered = {stamp: at for at, stamp in received["answers"]}
        latency = [answered[s] - s for s in sent if s in answered]
        run["candidates"] = {"sent": len(sent), "answered": len(latency),
                             "answer": percentiles(np.array(latency) / 1e9),
                             "node": reports[-1].get("candidate plans", {}) if reports else {}}
    return run


def candidates_message(make, count: int, steps: int, dt: float = 0.5) -> Any:
    """count candidates "c<i>/delta", "c<i>/rpm": rudders from -0.5 to 0.5 rad at 650 rpm, steps points dt apart."""
    msg = make("trajectory_msgs/msg/JointTrajectory")()
    msg.joint_names = [f"c{i}/{control}" for i in range(count) for control in ("delta", "rpm")]
    rudders = np.linspace(-0.5, 0.5, count)
    row = [float(x) for r in rudders for x in (r, 650.0)]
    point, duration = make("trajectory_msgs/msg/JointTrajectoryPoint"), make("builtin_interfaces/msg/Duration")
    msg.points = [point(positions=row, time_from_start=duration(sec=int(k * dt), nanosec=int(round(k * dt % 1 * NS))))
                  for k in range(steps)]
    msg.header.stamp.sec = 1  # patched per publication
    return msg


def baseline_tree(revision: str, tmp: Path) -> Path:
    """The source tree of `revision` (git archive), to run the old node from."""
    target = tmp / f"baseline_{revision}"
    archive = subprocess.run(["git", "-C", str(REPO), "archive", "--format=tar", revision], check=True,
                             capture_output=True).stdout
    target.mkdir()
    archive_path = tmp / "baseline.tar"
    archive_path.write_bytes(archive)
    with tarfile.open(archive_path) as tar:
        tar.extractall(target, filter="data")
    return target


def bench_node(variant: str, seconds: float, tmp: Path, baseline: str, old_candidates: bool = False,
               params: tuple[str, ...] = (), noisy: bool = False, gc_stats: bool = False) -> dict:
    """One variant's node fed over DDS; params: NAME:=VALUE node parameters for every variant (--param); noisy: the
    feed with sensor-like noise (--noisy-feed); gc_stats: the node's garbage collections (this node's variants)."""
    domain = 150 + (os.getpid() + len(variant)) % 80
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    ros_args = ["-p", "rate_hz:=10.0", *(arg for param in params for arg in ("-p", param)), "--log-level", "error"]
    if variant == "old":
        tree = baseline_tree(baseline, tmp)
        command = [sys.executable, "-m", "usv_predictor.node", "--ros-args", *ros_args]
        node_env, cwd = {**env, "PYTHONPATH": str(tree)}, str(tree)
    else:
        executor = "events" if variant == OWN_BLAS or variant in TUNED else variant
        command = [sys.executable, str(Path(__file__).resolve()), "--serve", executor, "--ros-args", *ros_args]
        if variant in TUNED:
            command += [arg for param in TUNED[variant][0] for arg in ("-p", param)]
        node_env, cwd = {**env, "PYTHONPATH": str(REPO)}, str(REPO)
        if gc_stats:
            node_env[GC_LOG] = str(tmp / f"gc_{variant}.json")
        if variant == OWN_BLAS:  # the node with OpenBLAS's own choice of kernels, whatever this environment pins:
            # the pair is set together here (an older OpenBLAS computes wrong results on some CPUs), so unset together
            node_env.pop("OPENBLAS_CORETYPE", None)
            node_env.pop("OPENBLAS_L2_SIZE", None)
    out = tmp / f"received_{variant}.json"
    receiver = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--receive", str(out)],
                                env={**env, "PYTHONPATH": str(REPO)})
    process = subprocess.Popen(command, env=node_env, cwd=cwd)
    feeder = Feeder(domain, noisy)
    runs: dict[str, dict] = {}
    try:
        feeder.wait_for([process, receiver])
        runs["imu_200"] = feeder.run(seconds, 200.0, process)
        runs["imu_1000"] = feeder.run(seconds, 1000.0, process)
        if variant in ("events", OWN_BLAS, *TUNED) or (variant == "old" and old_candidates):
            runs["candidates_64"] = feeder.run(seconds, 200.0, process, candidates_hz=2.0)
    finally:
        feeder.close()
        for child in (process, receiver):
            child.terminate()
            try:
                child.wait(timeout=15)
            except subprocess.TimeoutExpired:
                child.kill()
    received = json.loads(out.read_text())
    if os.environ.get("BENCH_KEEP"):
        Path(os.environ["BENCH_KEEP"]).write_text(json.dumps({"received": received, "runs": runs}))
    gc_log = Path(node_env.get(GC_LOG, tmp / "none"))
    pauses = json.loads(gc_log.read_text()) if gc_log.exists() else None
    return {name: figures(run, received, pauses) for name, run in runs.items()}


def bench_candidates_thread(repeats: int) -> dict:
    """A 10 Hz cycle due while a batch of 64 candidates is being answered, in one process without DDS: the cycle's
    compute (the node's one-state rollout and its Path) started right after the batch's, the batch (batched rollout,
    mean, answer encoded) either run first on the same thread (the node before 2026-11-26) or on a worker thread
    (the node's candidates worker). Latency of each from the common start; alternating, p50 / p99 ms."""
    from concurrent.futures import ThreadPoolExecutor

    from msg_adapters.outputs import candidate_predictions_cdr, path_cdr

    torch.set_num_threads(1)
    model = loading.load_model(str(package_share_path("models", "default.pt")), physics=False)
    rollout = live.Rollout(model, H)
    state, controls = np.array([5.0, 0.1, 0.02, 0.3]), np.array([0.2, 650.0])
    candidates = np.tile(controls, (64, H, 1))
    candidates[:, :, 0] = np.linspace(-0.5, 0.5, 64)[:, None]
    t_ns = 10**18 + np.arange(1, H + 1, dtype=np.int64) * 500_000_000
    names = [f"c{i}" for i in range(64)]

    def answer() -> float:
        out = rollout.batch(state, candidates).mean(axis=0)  # (64, H, 6)
        candidate_predictions_cdr(10**18, t_ns, out[..., 3:6], out[..., 0:3], "odom", names)
        return time.perf_counter()

    def cycle() -> float:
        out = rollout(state, controls).mean(axis=0)  # (H, 6)
        path_cdr(10**18, t_ns, out[:, 3:6], "odom")
        return time.perf_counter()

    worker = ThreadPoolExecutor(max_workers=1)
    times: dict[str, dict[str, list[float]]] = {way: {"cycle": [], "answer": []} for way in ("inline", "worker")}
    answer(), cycle()
    for _ in range(repeats):
        start = time.perf_counter()
        answered = answer()
        cycled = cycle()
        times["inline"]["cycle"].append(cycled - start)
        times["inline"]["answer"].append(answered - start)
        time.sleep(0.005)
        start = time.perf_counter()
        future = worker.submit(answer)
        cycled = cycle()
        times["worker"]["cycle"].append(cycled - start)
        times["worker"]["answer"].append(future.result() - start)
        time.sleep(0.005)
    worker.shutdown()
    return {way: {what: percentiles(values) for what, values in found.items()} for way, found in times.items()}


def main() -> int:
    if "--serve" in sys.argv:  # the node process of a variant (see bench_node)
        index = sys.argv.index("--serve")
        return serve(sys.argv[index + 1], sys.argv[sys.argv.index("--ros-args") + 1:])
    if "--receive" in sys.argv:  # the receiving process (see receive)
        return receive(Path(sys.argv[sys.argv.index("--receive") + 1]))
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=2000)
    parser.add_argument("--seconds", type=float, default=10.0, help="measured seconds per phase (s)")
    parser.add_argument("--baseline", default=BASELINE, help="git revision of the old node ('' to skip it)")
    parser.add_argument("--variants", default="old,events,single")
    parser.add_argument("--skip-compute", action="store_true")
    parser.add_argument("--old-candidates", action="store_true",
                        help="the candidate-plans phase for the old node too (a --baseline that has candidate_plans)")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--param", action="append", default=[], metavar="NAME:=VALUE",
                        help="a node parameter for every variant (repeatable), e.g. fit_check.period_s:=600.0: the "
                             "node without its fit check's rollouts")
    parser.add_argument("--gc-stats", action="store_true",
                        help="count the garbage collections of this node's variants per phase, with "
                             "their longest pause")
    parser.add_argument("--noisy-feed", action="store_true",
                        help="the inputs with sensor-like noise (NOISE): no two fit checks see the same "
                             "window content, "
                             "so none is served from the fit check's cache (the default feed is constant)")
    parser.add_argument("--candidates-thread", action="store_true",
                        help="only: a cycle due during a 64-candidate answer, inline or on a worker (in one process)")
    args = parser.parse_args()
    for param in args.param:
        if ":=" not in param:
            parser.error(f"--param {param!r}: expected NAME:=VALUE (a ROS parameter)")
    if args.candidates_thread:
        print(f"a cycle due while 64 candidates are answered, {args.repeats} rounds alternating, load {load()}")
        found = bench_candidates_thread(args.repeats)
        for way, figures in found.items():
            print(f"  {way:7s} cycle p50 / p99 {figures['cycle']['p50_ms']:6.2f} / {figures['cycle']['p99_ms']:6.2f} ms"
                  f"   answer {figures['answer']['p50_ms']:6.2f} / {figures['answer']['p99_ms']:6.2f} ms")
        print(f"  (load at the end {load()})")
        return 0
    result: dict[str, Any] = {"started": time.strftime("%Y-%m-%d %H:%M:%S %Z"), "load_at_start": load(),
                              "cpu": os.cpu_count()}
    result["openblas_coretype"] = os.environ.get("OPENBLAS_CORETYPE", "(unset: OpenBLAS's own detection)")
    print(f"{result['started']}, {os.cpu_count()} cores, load average (1/5/15 min) {result['load_at_start']}, "
          f"OPENBLAS_CORETYPE {result['openblas_coretype']}")
    with tempfile.TemporaryDirectory() as tmp:
        if not args.skip_compute:
            result["compute"] = bench_compute(args.repeats, Path(tmp))
            print(f"\nrollout, 120 steps (load {load()})              p50 ms   p99 ms")
            for name, figures in result["compute"].items():
                if name != "agreement":
                    print(f"  {name:45s} {figures['p50_ms']:7.3f}  {figures['p99_ms']:7.3f}   (n={figures['n']})")
            print(f"  agreement with the artifact (max abs): {result['compute']['agreement']}")
        variants = [v for v in args.variants.split(",") if v and (v != "old" or args.baseline)]
        result["params"] = list(args.param)
        result["noisy_feed"] = args.noisy_feed
        result["node"] = {v: bench_node(v, args.seconds, Path(tmp), args.baseline, args.old_candidates,
                                        tuple(args.param), args.noisy_feed, args.gc_stats)
                          for v in variants}
    print("\nnode at 10 Hz over DDS; e2e = cycle start -> Path received        p50 / p99 ms      CPU % of one core"
          + (f"; parameters {', '.join(args.param)}" if args.param else "")
          + ("; noisy feed" if args.noisy_feed else ""))
    for variant, runs in result["node"].items():
        label = {"old": f"old ({args.baseline})", "events": "new, EventsExecutor",
                 "single": "new, SingleThreadedExecutor", OWN_BLAS: "new, OpenBLAS's own kernels",
                 **{name: label for name, (_, label) in TUNED.items()}}[variant]
        for _name, run in runs.items():
            print(f"  {label:38s} IMU {run['imu_hz']:6.0f} Hz  e2e {run['end_to_end']['p50_ms']:6.2f} / "
                  f"{run['end_to_end']['p99_ms']:6.2f}  input->path {run['input_to_path']['p50_ms']:6.2f} / "
                  f"{run['input_to_path']['p99_ms']:6.2f}  CPU {run['node_cpu_percent_of_one_core']:5.1f}  "
                  f"({run['paths']} paths, load {run['load']}){'  + candidates' if 'candidates' in run else ''}")
            reported = run["node_reports"]
            if reported:
                print(f"    the node's own figures (last 200 cycles): {reported}")
            if run.get("fit_check"):
                print(f"    its fit check: {run['fit_check']}")
            if "gc" in run:
                print(f"    its garbage collections: {run['gc']}")
            if "candidates" in run:
                c = run["candidates"]
                print(f"    64 candidates x {H} steps at 2 Hz: {c['answered']}/{c['sent']} answered, publish -> answer "
                      f"p50 {c['answer']['p50_ms']:.2f} p99 {c['answer']['p99_ms']:.2f} ms; node: {c['node']}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
