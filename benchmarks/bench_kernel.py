#!/usr/bin/env python3
"""The compiled grey-box kernel against the TorchScript file it replaces and against its own arithmetic floor.

    python benchmarks/bench_kernel.py [--rounds 30] [--vessels jari_usv otter] [--baseline REV] [--json PATH]

For each vessel preset the calm-water grey box is exported as a model artifact (a TorchScript file, as `replay
identify` writes one) and loaded as the node and `replay evaluate` load it (models/loading.load_model: the kernel is
built from the file's module and checked equal to it). Then, in alternating rounds, one 60 s prediction (120 steps of
0.5 s, 2 RK4 substeps: 960 derivatives) is timed:
  file       the TorchScript file's own rollout (what ran before the kernel), one state
  eager      the torch twin GreyBoxRollout, eager, one state
  kernel     the compiled kernel (models/kernel_rollout.KernelRollout), one state, called as the node calls it
  kernel 64  the kernel on 64 candidate plans of the same start (the planner's batch)
  64 x2      the same on two threads (KernelRollout(threads=2), the node's candidates_threads: 2)
  hybrid     jari_usv only: the grey box with a 5-member learned residual (GeneralisingResidual 7-32-32-3 tanh, random
             weights), one state, on the kernel
and with --baseline REV (a git revision, e.g. main) the same kernel rows of that revision's physics/kernel.py and
models/kernel_rollout.py (its whole call: the Python side too), built from the same module, in the same rounds,
printed as "old ..." beside them with the old / new ratio;
and the floor of the kernel's arithmetic, estimated two ways:
  derivative  960 calls of the kernel's own derivative in a compiled loop (no integration, no bookkeeping): what the
              equations cost compiled;
  op count    the derivative's transcendental calls and flops counted from physics/kernel.py for the preset's hull
              and layout in calm water, times their unit costs measured here in a compiled loop (a transcendental:
              the mean of sqrt, atan2, exp, sin, cos; a flop: a dependent multiply-add chain).
Medians (and p99) over the rounds, ratios side by side. A noisy machine moves every figure; the ratios in one run hold.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import ModuleType

import numpy as np
import torch
from numba import njit

from usv_predictor.models import loading
from usv_predictor.models.artifact import export_module
from usv_predictor.models.greybox import GreyBoxRollout, greybox_metadata
from usv_predictor.models.hybrid import GeneralisingResidual, ResidualGreyBox
from usv_predictor.models.kernel_rollout import KernelRollout
from usv_predictor.physics import kernel as kn
from usv_predictor.physics.vessel import load_vessel

STEPS, DT, SUBSTEPS = 120, 0.5, 2  # the node's horizon: 60 s
DERIVATIVES = STEPS * SUBSTEPS * 4  # RK4: four a substep
# the derivative's calls and flops in calm water (physics/kernel.py, counted by hand: _derivative and what it calls)
OP_COUNTS = {  # layout: (transcendental calls, flops)
    ("mmg", "rudder_propeller"): (11, 176),  # hull sqrt; rudder atan2, exp, 4 sqrt, sin, cos; psi's cos, sin
    ("small_craft", "twin_thrusters"): (4, 230),  # two thrust pow; psi's cos, sin; 20 cross-flow strips ~ 6 flops each
}


@njit(cache=True)
def _unit_transcendental(n: int) -> float:
    acc, x = 0.0, 0.3
    for _ in range(n):
        x = x * 0.999 + 1e-3
        acc += math.atan2(x, 1.3) + math.sin(x) + math.cos(x) + math.exp(-x) + math.sqrt(x)
    return acc


@njit(cache=True)
def _unit_flop(n: int) -> float:
    x, y = 0.3, 0.7
    for _ in range(n):
        x = x * 0.999 + y  # two dependent flops
        y = y * 0.999 + 1e-3
    return x + y


@njit(cache=True)
def _derivatives(n: int, ki, p) -> float:
    sea = kn._sea_of(p)
    work = np.empty((2, 1))
    acc = 0.0
    for i in range(n):
        delta = 0.1 + 1e-9 * i  # (rad) its cosine and sine in every call: the derivative's whole cost
        kind = (ki[kn.K_HULL], ki[kn.K_LAYOUT], ki[kn.K_RESIDUAL], 1)  # rollout's: one row at a time
        d = kn._derivative(kind, ki, p, sea, 1.0, 0, work, 0.3 + 1e-9 * i, 2.0 + 1e-9 * i, 0.05, 0.02, delta, 600.0,
                           math.cos(delta), math.sin(delta))
        acc += d[3]
    return acc


def baseline_modules(rev: str) -> ModuleType:
    """models/kernel_rollout.py of git revision rev, running that revision's physics/kernel.py (both loaded from a
    folder of this user's in the temporary directory, where numba caches the old kernel between runs)."""
    root = Path(subprocess.run(["git", "rev-parse", "--show-toplevel"], capture_output=True, text=True, check=True,
                               cwd=Path(__file__).parent).stdout.strip())
    folder = Path(tempfile.gettempdir()) / f"usv_predictor-bench-kernel-{rev.replace('/', '_')}"
    folder.mkdir(exist_ok=True)
    modules = {}
    for name, path in (("kernel", "usv_predictor/physics/kernel.py"),
                       ("kernel_rollout", "usv_predictor/models/kernel_rollout.py")):
        text = subprocess.run(["git", "show", f"{rev}:{path}"], capture_output=True, text=True, check=True,
                              cwd=root).stdout
        target = folder / f"baseline_{name}.py"
        if not target.exists() or target.read_text() != text:
            target.write_text(text)
        spec = importlib.util.spec_from_file_location(f"baseline_{name}", target)
        modules[name] = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = modules[name]  # importable by name: numba's cached machine code refers to it
        spec.loader.exec_module(modules[name])
    modules["kernel_rollout"].kn = modules["kernel"]  # the old Python side calls the old kernel
    return modules["kernel_rollout"]


def hybrid_module(vessel) -> ResidualGreyBox:
    """The grey box with a 5-member learned residual of the node's hybrid's size (7-32-32-3 tanh), random weights and
    the features' normalisation about the benchmark's inputs."""
    residual = GeneralisingResidual(vessel.geometry.L_pp, 3.0, members=5, hidden=32, layers=2)
    generator = torch.Generator().manual_seed(3)
    with torch.no_grad():
        for p in [*residual.weights, *residual.biases, residual.head_weight, residual.head_bias]:
            p.copy_(torch.randn(p.shape, generator=generator, dtype=torch.float64) * 0.3)
        residual.in_mean.copy_(torch.tensor([0.0, 0.0, 1.0, 0.0, 600.0, 0.0, 0.0]))
        residual.in_std.copy_(torch.tensor([0.1, 0.2, 0.3, 0.2, 150.0, 0.7, 0.7]))
        residual.z_low.copy_(torch.full((7,), -2.0))
        residual.z_high.copy_(torch.full((7,), 1.5))
        residual.bound.copy_(torch.tensor([0.02, 0.05, 0.03]))
    return ResidualGreyBox(vessel, DT, residual, members=5)


def timed(call, rounds: int) -> list[float]:
    out = []
    for _ in range(rounds):
        started = time.perf_counter()
        call()
        out.append(time.perf_counter() - started)
    return out


def unit_costs() -> tuple[float, float]:
    """(one transcendental call, one flop) in seconds, compiled."""
    _unit_transcendental(10), _unit_flop(10)
    n = 2_000_000
    t = min(timed(lambda: _unit_transcendental(n), 3)) / (5 * n)
    f = min(timed(lambda: _unit_flop(n), 3)) / (4 * n)
    return t, f


def bench(vessel_name: str, rounds: int, folder: Path, old: ModuleType | None) -> dict[str, object]:
    vessel = load_vessel(vessel_name)
    module = GreyBoxRollout(vessel, DT, substeps=SUBSTEPS)
    path = folder / f"{vessel_name}.pt"
    meta = {**greybox_metadata(vessel, module), "horizon_steps": STEPS}
    export_module(path, module, meta, vessel=vessel)
    started = time.perf_counter()
    artifact = loading.load_model(str(path), physics=False)
    load_s = time.perf_counter() - started
    kernel = artifact.runner
    if not isinstance(kernel, KernelRollout):
        raise SystemExit(f"{vessel_name}: the artifact does not run the kernel: {artifact.inference_note}")
    speed = 0.4 * math.sqrt(vessel.geometry.L_pp)  # (m/s)
    state = np.array([[speed, 0.0, 0.0, 0.3]])
    if vessel.layout == "twin_thrusters":
        held = [0.7, 0.4]
    else:
        held = [math.radians(20.0), 600.0]
    controls = np.tile(held, (1, STEPS, 1))  # (1, H, C)
    plans = np.repeat(controls, 64, axis=0) * np.linspace(0.5, 1.0, 64)[:, None, None]  # (64, H, C)
    states = np.repeat(state, 64, axis=0)
    st, ct = torch.from_numpy(state), torch.from_numpy(controls)
    with torch.inference_mode():
        artifact.module(st, ct), module(st, ct)
    two = KernelRollout(artifact.module, live=True, threads=2)
    hybrid = KernelRollout(torch.jit.script(hybrid_module(vessel)), live=True) if vessel_name == "jari_usv" else None
    calls = {"kernel": lambda k: k.rollout(state, controls), "kernel 64": lambda k: k.rollout(states, plans),
             "64 x2": lambda k: k.rollout(states, plans), "hybrid": lambda k: k.rollout(state, controls)}
    runners = {"kernel": kernel, "kernel 64": kernel, "64 x2": two}
    if hybrid is not None:
        runners["hybrid"] = hybrid
    if old is not None:  # the old revision's KernelRollout on the same modules
        olds = {"kernel": old.KernelRollout(artifact.module, live=True)}
        olds.update({"kernel 64": olds["kernel"], "64 x2": old.KernelRollout(artifact.module, live=True, threads=2)})
        if hybrid is not None:
            olds["hybrid"] = old.KernelRollout(hybrid.module, live=True)
        runners.update({f"old {name}": k for name, k in olds.items()})
    repeats = {"kernel": 20, "kernel 64": 3, "64 x2": 3, "hybrid": 2}
    for name, k in runners.items():
        calls[name.removeprefix("old ")](k)  # compiled (or loaded from the cache) before the rounds
    _derivatives(10, kernel.ki, kernel.p)
    times: dict[str, list[float]] = {k: [] for k in ("file", "eager", *runners, "derivative")}
    file_rounds = max(3, rounds // 5)  # the file's rollout takes seconds on a loaded machine
    for k in range(rounds):
        with torch.inference_mode():
            if k < file_rounds:
                times["file"] += timed(lambda: artifact.module(st, ct), 1)
                times["eager"] += timed(lambda: module(st, ct), 1)
        for name in ("kernel", "kernel 64", "64 x2", "hybrid"):  # old and new alternately
            for label in (name, f"old {name}"):
                if label in runners:
                    times[label] += timed(lambda: calls[name](runners[label]), repeats[name])
        times["derivative"] += timed(lambda: _derivatives(DERIVATIVES, kernel.ki, kernel.p), 5)
    transcendental_s, flop_s = unit_costs()
    calls, flops = OP_COUNTS[(vessel.hull_model_name, vessel.layout)]
    floor_s = DERIVATIVES * (calls * transcendental_s + flops * flop_s)
    figures = {name: {"p50_ms": 1e3 * float(np.median(v)), "p99_ms": 1e3 * float(np.percentile(v, 99)), "n": len(v)}
               for name, v in times.items()}
    figures["op count"] = {"p50_ms": 1e3 * floor_s, "p99_ms": 1e3 * floor_s, "n": 0}
    return {"vessel": vessel_name, "hull_model": vessel.hull_model_name, "layout": vessel.layout,
            "load_s": load_s, "figures": figures, "transcendental_ns": 1e9 * transcendental_s, "flop_ns": 1e9 * flop_s,
            "inference_note": artifact.inference_note}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=30)
    parser.add_argument("--vessels", nargs="+", default=["jari_usv", "otter"])
    parser.add_argument("--baseline", help="a git revision whose kernel to time beside this one (e.g. main)")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    old = baseline_modules(args.baseline) if args.baseline else None
    results = []
    with tempfile.TemporaryDirectory() as folder:
        for name in args.vessels:
            results.append(bench(name, args.rounds, Path(folder), old))
    for r in results:
        f = r["figures"]
        print(f"\n{r['vessel']} ({r['hull_model']}, {r['layout']}): one 60 s prediction, {DERIVATIVES} derivatives; "
              f"artifact loaded (kernel built, checked) in {r['load_s']:.2f} s")
        print(f"  unit costs: transcendental {r['transcendental_ns']:.2f} ns, flop {r['flop_ns']:.3f} ns")
        print(f"  {'':14s} {'p50 ms':>10s} {'p99 ms':>10s} {'file / this':>12s} {'this / floor':>13s} "
              f"{'old / new':>11s}")
        floor = f["op count"]["p50_ms"]
        for name in ("file", "eager", "kernel", "kernel 64", "64 x2", "hybrid", "derivative", "op count"):
            for label in (f"old {name}", name):
                if label not in f:
                    continue
                x = f[label]
                ratio = f"{f[label]['p50_ms'] / f[name]['p50_ms']:.2f}" if label.startswith("old") else ""
                speedup = f["file"]["p50_ms"] / x["p50_ms"]
                print(f"  {label:14s} {x['p50_ms']:10.4f} {x['p99_ms']:10.4f} {speedup:12.0f} "
                      f"{x['p50_ms'] / floor:13.2f} {ratio:>11s}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
