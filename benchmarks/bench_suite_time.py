"""Time per unknown boat of two checkouts side by side, and whether they answer the same: the boats of
benchmarks/bench_unknown_boats.py (same --seed, --layout, indices) run one at a time in a fresh process of each
checkout, old and new alternately (the order swapped every boat, so a drift of the machine's speed falls on both).

Prints per boat: the hidden effect, both answers (cause; the largest relative difference of their parameters), the
wall time of each (its own process: start-up, numba's cache load, simulate, vessel init, identify, diagnose) and the
new/old ratio, the phases (simulate / identify / diagnose, s) and the load average before the pair; then the medians,
the totals and the answers counted (right / within tolerance / model_mismatch / confident wrong) per checkout.

Run: nice -n 10 .venv/bin/python benchmarks/bench_suite_time.py --old /work/main --boats 6
     (--old: a checkout with its own .venv; the new one is this checkout)
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]
EXCLUDED = ("model_mismatch", "inconclusive", "unexplained", "identify_failed")  # no confident answer


def run_boat(root: Path, index: int, args: argparse.Namespace) -> tuple[dict, float]:
    """One boat in a fresh process of the checkout at `root`: its JSON line and the process's wall time (s)."""
    with tempfile.TemporaryDirectory(prefix="suite_time_") as work:
        out = Path(work) / "boat.jsonl"
        argv = [str(root / ".venv" / "bin" / "python"), str(root / "benchmarks" / "bench_unknown_boats.py"),
                "--layout", args.layout, "--seed", str(args.seed), "--first", str(index), "--boats", "1",
                "--jsonl", str(out)]
        started = time.perf_counter()
        done = subprocess.run(argv, cwd=root, capture_output=True, text=True)
        wall = time.perf_counter() - started
        if done.returncode != 0 or not out.exists():
            sys.exit(f"{root}: boat {index} failed (exit {done.returncode}):\n{done.stderr[-2000:]}")
        return json.loads(out.read_text().splitlines()[0]), wall


def parameter_difference(a: dict, b: dict) -> float:
    """The largest relative difference of two answers' parameters (0 for none; inf when their keys differ)."""
    if set(a) != set(b):
        return math.inf
    return max((abs(a[k] - b[k]) / max(abs(a[k]), abs(b[k]), 1e-12) for k in a), default=0.0)


def counts(results: list[dict]) -> str:
    right = [r for r in results if r["cause"] == r["truth"]]
    within = [r for r in right if r["truth"] == "none" or r["within_tolerance"]]
    mismatch = sum(r["cause"] == "model_mismatch" for r in results)
    wrong = sum(r["cause"] != r["truth"] and r["cause"] not in EXCLUDED for r in results)
    return (f"right {len(right)}/{len(results)}, within tolerance {len(within)}, model_mismatch {mismatch}, "
            f"confident wrong {wrong}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--old", type=Path, required=True, help="the other checkout (with its .venv)")
    parser.add_argument("--layout", default="rudder_propeller")
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--first", type=int, default=0)
    parser.add_argument("--boats", type=int, default=6)
    args = parser.parse_args()
    checkouts = {"old": args.old.resolve(), "new": HERE}
    results: dict[str, list[dict]] = {"old": [], "new": []}
    walls: dict[str, list[float]] = {"old": [], "new": []}
    print(f"old {checkouts['old']}, new {checkouts['new']}; layout {args.layout}, seed {args.seed}, boats "
          f"{args.first}..{args.first + args.boats - 1}, {os.cpu_count()} cores", flush=True)
    print("| boat | hidden | old answer | new answer | parameters differ | old s | new s | new/old | "
          "old sim/ident/diag | new sim/ident/diag | load |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for index in range(args.first, args.first + args.boats):
        load = os.getloadavg()[0]
        order = ("old", "new") if index % 2 == 0 else ("new", "old")
        pair = {}
        for name in order:
            pair[name] = run_boat(checkouts[name], index, args)
        for name, (result, wall) in pair.items():
            results[name].append(result)
            walls[name].append(wall)
        old, new = pair["old"][0], pair["new"][0]
        differ = parameter_difference(old["parameters"], new["parameters"])
        phases = {name: "/".join(f"{pair[name][0]['seconds'][k]:.0f}" for k in ("simulate", "identify", "diagnose"))
                  if "simulate" in pair[name][0].get("seconds", {}) else "-" for name in pair}
        print(f"| {index} | {old['truth']} | {old['cause']} | {new['cause']} | {differ:.1e} | {pair['old'][1]:.0f} | "
              f"{pair['new'][1]:.0f} | {pair['new'][1] / pair['old'][1]:.2f} | {phases['old']} | {phases['new']} | "
              f"{load:.1f} |", flush=True)
    print()
    for name in ("old", "new"):
        print(f"{name}: median {np.median(walls[name]):.1f} s a boat, total {sum(walls[name]):.0f} s; "
              f"{counts(results[name])}")
    ratios = np.array(walls["new"]) / np.array(walls["old"])
    print(f"new/old per boat: median {np.median(ratios):.2f}, total {sum(walls['new']) / sum(walls['old']):.2f}; "
          f"same cause on {sum(o['cause'] == n['cause'] for o, n in zip(results['old'], results['new']))}/"
          f"{len(ratios)} boats; load average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
