#!/usr/bin/env python3
"""The floor of the node's 64-candidate answer: the arithmetic of the batched rollout alone, side by side.

    python benchmarks/bench_candidate_floor.py [--rounds 40] [--candidates 64] [--own-blas]

Issue 13 asks for 64 candidate plans of 120 steps answered in <= 10 ms p99. The node's batched rollout
(models/dnn.NumpyDnnRollout._rollout_batch on the shipped models/default.pt: the members stacked, the candidates the
columns) does per step three products (first layer with its bias unit, hidden layer, output head) and two tanh,
then adds, a sine of the heading columns and, after the loop, the kinematics. This times, on the shipped model's own
weight matrices and one step's input of that layout, 120 steps of:
  hidden          the hidden-layer product alone,
  products        the three products,
  products+tanh   the three products and the two tanh (the step without its adds and sine),
  rollout         the whole batched rollout the node calls (NumpyDnnRollout.rollout of B states, numpy only),
with numpy (OpenBLAS, the kernels this environment pins: OPENBLAS_CORETYPE is printed) and with torch (its own BLAS,
MKL in the CPU wheel) on the same memory (torch.from_numpy, out=), one thread each, in alternating rounds.
--own-blas: the same numpy figures again in a child process without OPENBLAS_CORETYPE and OPENBLAS_L2_SIZE (OpenBLAS
picks its kernels itself: AVX-512 on this Zen 5), printed beside them for comparison only: the package never
overrides the environment's choice (docs/results/node_latency.md).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from typing import Callable

import numpy as np
import torch

from usv_predictor.config import package_share_path
from usv_predictor.models import loading
from usv_predictor.models.dnn import NumpyDnnRollout

STEPS = 120  # the node's horizon: 60 s at dt 0.5 s


def floors(candidates: int, rounds: int, with_torch: bool) -> dict[str, dict[str, float]]:
    """p50 / p99 (ms) of 120 steps of each part (module docstring) over `rounds` alternating rounds."""
    torch.set_num_threads(1)
    model = loading.load_model(str(package_share_path("models", "default.pt")), physics=False)
    r = model.inference
    if not isinstance(r, NumpyDnnRollout) or len(r.hidden_t) != 1 or r.clipped:
        raise SystemExit(f"the shipped model is not the usual numpy network (NTF, tanh, depth 2): "
                         f"{model.inference_note}")
    rng = np.random.default_rng(0)
    e, n_s, c = r.ensemble_size, r.n_state, r.n_controls
    first, w, head = r.first_t, r.hidden_t[0], r.head_t  # (E, S + W + 1, S + C + 1), (E, W, W + 1), (E, S, W)
    x = rng.uniform(-1.0, 1.0, (e, n_s + c + 1, candidates)).astype(r.dtype)  # (E, S + C + 1, B): one step's input
    x[:, -1] = 1.0  # its bias unit
    y = np.empty((e, first.shape[1], candidates), dtype=r.dtype)  # (E, S + W + 1, B)
    g = y[:, n_s:]  # (E, W + 1, B): the activations and the bias unit
    z = np.empty((e, w.shape[1], candidates), dtype=r.dtype)  # (E, W, B)
    t = np.empty((e, n_s, candidates), dtype=r.dtype)  # (E, S, B)
    np.matmul(first, x, out=y)
    np.tanh(g, out=g)  # realistic activations for the hidden product
    state = np.tile(np.array([5.0, 0.1, 0.02, 0.3]), (candidates, 1))  # (B, 4)
    controls = np.tile(np.array([0.2, 650.0]), (candidates, STEPS, 1))  # (B, H, 2): 64 rudders
    controls[:, :, 0] = np.linspace(-0.5, 0.5, candidates)[:, None]
    arrays = (first, x, y, g, w, z, head, t)

    def parts_of(library: str, matmul: Callable, tanh: Callable, arrays: tuple) -> dict[str, Callable[[], None]]:
        """120 steps of the hidden product, of the three products and of those with the two tanh, by one library."""
        first, x, y, g, w, z, head, t = arrays

        def steps(activate: bool) -> Callable[[], None]:
            def run() -> None:
                for _ in range(STEPS):
                    matmul(first, x, out=y)
                    if activate:
                        tanh(g, out=g)
                    matmul(w, g, out=z)
                    if activate:
                        tanh(z, out=z)
                    matmul(head, z, out=t)
            return run

        def hidden() -> None:
            for _ in range(STEPS):
                matmul(w, g, out=z)

        return {f"{library} hidden": hidden, f"{library} products": steps(False),
                f"{library} products+tanh": steps(True)}

    parts = {**parts_of("numpy", np.matmul, np.tanh, arrays), "numpy rollout": lambda: r.rollout(state, controls)}
    if with_torch:  # the same memory (torch.from_numpy)
        parts.update(parts_of("torch", torch.matmul, torch.tanh, tuple(torch.from_numpy(a) for a in arrays)))
    times: dict[str, list[float]] = {name: [] for name in parts}
    with torch.inference_mode():
        for _name, run in parts.items():  # warm-up
            run()
        for _ in range(rounds):
            for name, run in parts.items():
                started = time.perf_counter()
                run()
                times[name].append(time.perf_counter() - started)
    return {name: {"p50_ms": float(np.percentile(v, 50) * 1e3), "p99_ms": float(np.percentile(v, 99) * 1e3)}
            for name, v in times.items()}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=40)
    parser.add_argument("--candidates", type=int, default=64)
    parser.add_argument("--own-blas", action="store_true",
                        help="numpy again with OpenBLAS's own kernels (a child process)")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)  # the --own-blas child: JSON out
    args = parser.parse_args()
    if args.child:
        print(json.dumps(floors(args.candidates, args.rounds, with_torch=False)))
        return 0
    load = " ".join(open("/proc/loadavg").read().split()[:3])
    print(f"{time.strftime('%Y-%m-%d %H:%M:%S %Z')}, load {load}, OPENBLAS_CORETYPE "
          f"{os.environ.get('OPENBLAS_CORETYPE', '(unset)')}, {args.candidates} candidates x {STEPS} steps, "
          f"{args.rounds} rounds, one thread")
    found = floors(args.candidates, args.rounds, with_torch=True)
    own: dict[str, dict[str, float]] = {}
    if args.own_blas:
        env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_CORETYPE", "OPENBLAS_L2_SIZE")}
        child = subprocess.run([sys.executable, __file__, "--child", "--rounds", str(args.rounds), "--candidates",
                                str(args.candidates)], env=env, capture_output=True, text=True, check=True)
        own = json.loads(child.stdout)
    print(f"\n{'120 steps, p50 / p99 ms':24s} {'numpy (environment)':>22s} {'torch':>18s}"
          + (f" {'numpy (OpenBLAS own)':>22s}" if own else ""))
    for part in ("hidden", "products", "products+tanh", "rollout"):
        cells = [found.get(f"numpy {part}"), found.get(f"torch {part}")] + ([own.get(f"numpy {part}")] if own else [])
        row = "".join(f" {'-' if f is None else format(f['p50_ms'], '.2f') + ' / ' + format(f['p99_ms'], '.2f'):>20s}  "
                      for f in cells)
        print(f"  {part:22s}{row}")
    print(f"(load at the end {' '.join(open('/proc/loadavg').read().split()[:3])})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
