#!/usr/bin/env python3
"""The fit check's cause rollouts (analysis/fit_check.cause_changes), this tree against --baseline in the same run.

    python benchmarks/bench_fit_causes.py [--baseline 3c270b2] [--repeats 15] [--rounds 3] [--json out/causes.json]

What one check of the node rolls out when the model does not fit (docs/node.md, "The fit check in the node"): the 44
strongest causes and the calm row of the node's vessel (jari_usv, dt 0.5 s) for
  bench     the window the node's check finds on benchmarks/bench_node.py's feed (a held turn, rudder 0.1 rad at
            650 rpm, u 5 m/s: the shipped model turns at 6 deg/s where the feed turns at 1.1, so the causes run),
            built from that feed by live.InputSet.buffered_recording and fit_check.rolled_windows as the node does;
  kept      three windows at once (a straight one of SETTLE_S and two turns, random commands and states, seed 7):
            a check whose kept windows are all new.
Each side runs in its own process (the baseline's from `git archive`, as bench_node.py's old node), warm (two calls
first), as the node calls it (cause_changes' defaults); the two alternate in --rounds rounds of --repeats calls so
that a change of load hits both alike. Printed: ms per call p50 / p99 / max per side and case, the new / old ratio,
and the largest difference of the changes du (m/s) and dr (deg/s) between the two sides (what the verdict reads).
Run with OMP_NUM_THREADS=1 (the node's check runs on one thread); the load average is printed before and after.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DT = 0.5  # (s) the shipped model's step


def bench_window() -> dict:
    """The window the node's check finds on bench_node.py's constant feed after 13 s (10 s of a 200 Hz IMU buffered),
    rolled out by the shipped model (its prediction is not needed here, only what the causes start from)."""
    import msg_adapters
    from bench_node import RATES, VALUES  # the node benchmark's feed: its rates (Hz) and values
    from usv_predictor.analysis import fit_check as fc
    from usv_predictor.config import package_share_path
    from usv_predictor.data.recording import required_roles
    from usv_predictor.models.loading import load_model
    from usv_predictor.node import live
    from usv_predictor.physics.vessel import load_vessel
    from usv_predictor.records import NS_PER_S

    jari = load_vessel("jari_usv")
    roles = (*required_roles(jari.actuator_layout), live.POSITION_ROLE)
    inputs = live.InputSet({role: msg_adapters.ROLE_FIELDS[role] for role in roles}, {role: 1.0 for role in roles},
                           live.LiveSettings(dt=DT, horizon_steps=2), jari.actuator_layout)
    t0 = 10**18
    for t_ns, role in sorted((t0 + int(k * NS_PER_S / rate), role) for role, rate in RATES.items()
                             for k in range(int(13.0 * rate))):
        inputs.add(role, t_ns, list(VALUES[role]), t_ns)
    recording = inputs.buffered_recording(2.0)
    model = load_model(str(package_share_path("models", "default.pt")), physics=False)
    rolled = fc.rolled_windows(model, [recording], jari.actuator_layout)
    assert len(rolled) == 1 and rolled[0].window.kind == "turn", rolled
    r = rolled[0]
    return {"kind": r.window.kind, "state": r.state.tolist(), "controls": r.controls.tolist(), "averaged": r.averaged,
            "reference": None}


def kept_windows() -> list[dict]:
    """Three windows at once: one straight (SETTLE_S), two turns (test_fit_check.py's batch)."""
    rng = np.random.default_rng(7)
    out = []
    for kind, steps in (("straight", int(120.0 / DT)), ("turn", 17), ("turn", 29)):
        held = [0.0 if kind == "straight" else 0.2, 600.0]  # rudder (rad), rpm
        controls = np.tile(held, (steps, 1)) + rng.normal(0.0, 0.01, (steps, 2))  # (H, C)
        state = np.array([4.0, 0.1, 0.02, 1.0]) + rng.normal(0.0, 0.1, 4)  # (4,)
        out.append({"kind": kind, "state": state.tolist(), "controls": controls.tolist(), "averaged": min(20, steps),
                    "reference": None})
    return out


def worker(cases_path: str, repeats: int, out_path: str) -> None:
    """Time cause_changes on every case with the tree on sys.path (this process's): warm, then `repeats` calls."""
    import torch

    from usv_predictor.analysis import fit_check as fc
    from usv_predictor.physics.vessel import load_vessel

    torch.set_num_threads(1)
    cases = json.loads(Path(cases_path).read_text())
    vessel = load_vessel("jari_usv")
    causes = fc.strongest_causes(vessel.actuator_layout.name)
    result = {}
    for name, windows in cases.items():
        rolled = [fc.Rolled(fc.SteadyWindow("bench", w["kind"], 0.0, 1.0, 0.0, 0.0, 5.0, 5.0, 0.0, 0.0),
                            np.array(w["state"]), np.array(w["controls"]), int(w["averaged"]),
                            None if w["reference"] is None else np.array(w["reference"])) for w in windows]
        for _ in range(2):
            du, dr = fc.cause_changes(vessel, DT, rolled, causes)
        times = []
        for _ in range(repeats):
            started = time.perf_counter()
            fc.cause_changes(vessel, DT, rolled, causes)
            times.append(time.perf_counter() - started)
        result[name] = {"ms": [t * 1e3 for t in times], "du": du.tolist(), "dr": dr.tolist()}
    Path(out_path).write_text(json.dumps(result))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--baseline", default="3c270b2", help="git revision of the old side (default 3c270b2)")
    parser.add_argument("--repeats", type=int, default=15, help="calls per side, case and round")
    parser.add_argument("--rounds", type=int, default=3, help="rounds, the two sides alternating")
    parser.add_argument("--json", type=Path, help="write the figures here")
    parser.add_argument("--worker", nargs=3, metavar=("CASES", "REPEATS", "OUT"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        worker(args.worker[0], int(args.worker[1]), args.worker[2])
        return 0
    sys.path.insert(0, str(REPO / "benchmarks"))
    from bench_node import baseline_tree

    loads = [" ".join(Path("/proc/loadavg").read_text().split()[:3])]
    with tempfile.TemporaryDirectory() as tmp_dir:
        tmp = Path(tmp_dir)
        cases = tmp / "cases.json"
        cases.write_text(json.dumps({"bench": [bench_window()], "kept": kept_windows()}))
        trees = {"old": baseline_tree(args.baseline, tmp), "new": REPO}
        times: dict[str, dict[str, list[float]]] = {side: {} for side in trees}
        changes: dict[str, dict] = {}
        for round_ in range(args.rounds):
            for side, tree in trees.items():
                out = tmp / f"{side}_{round_}.json"
                env = {**os.environ, "PYTHONPATH": str(tree), "OMP_NUM_THREADS": "1"}
                subprocess.run([sys.executable, str(Path(__file__).resolve()), "--worker", str(cases),
                                str(args.repeats), str(out)], check=True, env=env, cwd=str(tree))
                for case, figures in json.loads(out.read_text()).items():
                    times[side].setdefault(case, []).extend(figures["ms"])
                    changes.setdefault(side, {})[case] = figures
        loads.append(" ".join(Path("/proc/loadavg").read_text().split()[:3]))
    report = {"baseline": args.baseline, "load_before_after": loads, "cases": {}}
    print(f"fit check's cause rollouts (jari_usv, dt {DT} s, 44 causes + calm), old = {args.baseline}, "
          f"{args.rounds} rounds x {args.repeats} calls; load before / after: {loads[0]} / {loads[1]}")
    for case in times["new"]:
        row = {}
        for side in trees:
            ms = np.array(times[side][case])
            row[side] = {"p50": float(np.percentile(ms, 50)), "p99": float(np.percentile(ms, 99)),
                         "max": float(ms.max()), "calls": len(ms)}
        du = np.abs(np.array(changes["new"][case]["du"]) - np.array(changes["old"][case]["du"]))
        dr = np.abs(np.array(changes["new"][case]["dr"]) - np.array(changes["old"][case]["dr"]))
        row["ratio_p50"] = row["new"]["p50"] / row["old"]["p50"]
        row["max_diff_du_mps"], row["max_diff_dr_deg_s"] = float(du.max()), float(np.degrees(dr.max()))
        report["cases"][case] = row
        print(f"  {case:6s} old p50 / p99 / max {row['old']['p50']:7.1f} / {row['old']['p99']:7.1f} / "
              f"{row['old']['max']:7.1f} ms   new {row['new']['p50']:7.1f} / {row['new']['p99']:7.1f} / "
              f"{row['new']['max']:7.1f} ms   new/old {row['ratio_p50']:.2f}   max |du new - old| "
              f"{row['max_diff_du_mps']:.1e} m/s, |dr| {row['max_diff_dr_deg_s']:.1e} deg/s")
    if args.json:
        from usv_predictor.atomic import write_json_atomic

        args.json.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(args.json, report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
