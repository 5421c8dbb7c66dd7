"""Confusion matrix of `diagnose` on boats the tool has never seen (the figures of docs/results/unknown_boats.md).

Each boat: a random rudder-and-propeller hull around jari_usv (usv_predictor.analysis.unknown_boats.draw_boat: size
class small 3-6 m or large 12-20 m, Froude-scaled, every hull derivative, added mass and interaction factor x
U(0.7, 1.3)), one hidden effect of the vocabulary (or none) with random parameters (analysis.hidden_effects.draw),
then the public pipeline (usv_predictor.replay.unknown_boats.run_unknown_boat): simulate a calm `training` day and a
blind `diagnosis` effect day, delete the truth, `vessel init` from the owner's data, `identify --prior fix --interaction
identify` (--interaction fix: as before the search) (or what
its cv_warning recommends), `diagnose --model`. Effects are balanced (boat i hides effect i mod the number of effects,
nine for this layout), size classes alternate per round of them. Prints the confusion matrix (rows: truth, columns:
named cause; `model_mismatch` and
a fit-check refusal are columns of their own), the parameter hit rate, the confident wrong answers and the time per
boat. Deterministic for --seed. One JSON line per boat goes to --jsonl as it finishes (a run stopped early keeps
what it did; --summarise FILE prints the tables of such a file).

Run: nice -n 10 .venv/bin/python benchmarks/bench_unknown_boats.py --boats 50 --jsonl out/unknown.jsonl
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np


def one_boat(index: int, seed: int, workroot: Path, interaction: str = "identify") -> dict:
    import torch

    from usv_predictor.analysis.hidden_effects import draw, effect_names
    from usv_predictor.analysis.unknown_boats import SIZE_CLASSES, draw_boat
    from usv_predictor.replay.unknown_boats import run_unknown_boat

    torch.set_num_threads(1)
    effects = effect_names("rudder_propeller")
    classes = tuple(SIZE_CLASSES)
    rng = np.random.default_rng([seed, index])
    size_class = classes[(index // len(effects)) % len(classes)]
    boat = draw_boat(rng, size_class, name=f"boat_{index:03d}")
    truth = draw(rng, effects[index % len(effects)], "rudder_propeller")
    sim_seed = int(rng.integers(0, 2**31 - 2))
    work = workroot / boat.name
    started = time.perf_counter()
    try:
        result = run_unknown_boat(boat, truth, work, sim_seed, interaction=interaction)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    result["index"] = index
    result["interaction_mode"] = interaction
    result["wall_s"] = time.perf_counter() - started
    result["factors"] = boat.factors
    result.pop("log", None)
    return result


CONFIDENT_CAUSES_EXCLUDED = ("model_mismatch", "inconclusive", "unexplained", "identify_failed")


def summarise(results: list[dict]) -> str:
    from usv_predictor.analysis.hidden_effects import effect_names

    effects = list(effect_names("rudder_propeller"))
    extra = sorted({r["cause"] for r in results} - set(effects), key=lambda c: (c != "model_mismatch", c))
    columns = effects + extra
    matrix = np.zeros((len(effects), len(columns)), dtype=int)
    for r in results:
        matrix[effects.index(r["truth"]), columns.index(r["cause"])] += 1
    lines = [f"confusion matrix over {len(results)} unknown boats (rows: hidden effect, columns: named cause)", "",
             "| hidden \\ named | " + " | ".join(columns) + " |", "|---" * (len(columns) + 1) + "|"]
    for i, effect in enumerate(effects):
        cells = [(f"**{n}**" if columns[j] == effect else (str(n) if n else "")) for j, n in enumerate(matrix[i])]
        lines.append(f"| {effect} | " + " | ".join(cells) + " |")
    right = [r for r in results if r["cause"] == r["truth"]]
    hits = [r for r in right if r["truth"] == "none" or r["within_tolerance"]]
    confident_wrong = [r for r in results if r["cause"] != r["truth"] and r["cause"] not in CONFIDENT_CAUSES_EXCLUDED]
    refused = [r for r in results if r.get("refused")]
    mismatch = [r for r in results if r["cause"] == "model_mismatch"]
    wrong_parameters = [r for r in right if r["truth"] != "none" and not r["within_tolerance"]]
    lines += ["", f"right cause: {len(right)}/{len(results)}; right cause and parameters within tolerance: "
                  f"{len(hits)}/{len(results)} (effects only: "
                  f"{sum(r['truth'] != 'none' for r in hits)}/{sum(r['truth'] != 'none' for r in results)})",
              f"confident wrong answers (a cause or `none` that is not the truth): "
              f"{len(confident_wrong)}/{len(results)}"
              + "".join(f"\n  {r['boat']} ({r['size_class']}, {r['L_pp_m']:.1f} m): {r['truth']} "
                        f"{r['truth_parameters']} -> {r['cause']} {r['parameters']}" for r in confident_wrong),
              f"right cause, parameters beyond the tolerances: {len(wrong_parameters)}"
              + "".join(f"\n  {r['boat']} ({r['size_class']}, {r['L_pp_m']:.1f} m): {r['truth']} "
                        f"{r['truth_parameters']} "
                        f"-> {r['parameters']}" for r in wrong_parameters),
              f"model_mismatch: {len(mismatch)} (of which refused by the fit check: {len(refused)}; the rollout of the "
              f"identified model diverges: "
              f"{sum(any('diverges' in m for m in r['mismatch_reasons']) for r in mismatch)})"]
    for size in ("small", "large"):
        rows = [r for r in results if r["size_class"] == size]
        if rows:
            lines.append(f"  {size}: {sum(r['cause'] == r['truth'] for r in rows)}/{len(rows)} right, "
                         f"{sum(r['cause'] == 'model_mismatch' for r in rows)} model_mismatch")
    for effect in effects[1:]:
        rows = [r for r in right if r["truth"] == effect]
        if rows:
            keys = rows[0]["errors"].keys()
            spread = ", ".join(f"{k} median |err| {np.median([abs(r['errors'][k]) for r in rows]):.3g}" for k in keys)
            lines.append(f"  {effect:20s} {sum(r['within_tolerance'] for r in rows)}/{len(rows)} within tolerance; "
                         f"{spread}")
    searched = [((r.get("identification") or {}).get("interaction") or {}) for r in results]
    if any(searched):
        lines.append(f"interaction factors identified (the held-out simulation beat the description's): "
                     f"{sum(bool(s.get('accepted')) for s in searched)}/{len(results)} boats")
    walls = [r["wall_s"] for r in results]
    lines.append(f"time per boat: median {np.median(walls):.0f} s, max {np.max(walls):.0f} s (wall, simulate + vessel "
                 f"init + identify + diagnose); load average at the end {os.getloadavg()[0]:.1f}")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--boats", type=int, default=50)
    parser.add_argument("--first", type=int, default=0, help="index of the first boat (resume a stopped run)")
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--interaction", choices=("identify", "fix"), default="identify",
                        help="identify --interaction: the factors searched with the hull (default) or the "
                             "description's (fix: the suite before the search, for comparison)")
    parser.add_argument("--jsonl", type=Path, default=None, help="append one JSON line per boat here")
    parser.add_argument("--summarise", type=Path, nargs="+", default=None, metavar="JSONL",
                        help="only print the tables of a run (several files: the boats of processes run in parallel "
                             "over disjoint --first/--boats ranges)")
    parser.add_argument("--rerun", type=Path, default=None, metavar="JSONL",
                        help="with --summarise: boats re-run later (e.g. with a newer diagnose) replace the same index")
    args = parser.parse_args()
    if args.summarise:
        def read(path: Path) -> list[dict]:
            return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]

        results = {r["index"]: r for path in args.summarise for r in read(path)}
        rerun = read(args.rerun) if args.rerun else []
        results.update({r["index"]: r for r in rerun})
        print(summarise([results[i] for i in sorted(results)]))
        if rerun:
            print(f"re-run: {', '.join(r['boat'] for r in rerun)}")
        return
    started = time.perf_counter()
    results = []
    with tempfile.TemporaryDirectory(prefix="unknown_boats_") as root:
        for index in range(args.first, args.first + args.boats):
            r = one_boat(index, args.seed, Path(root), args.interaction)
            results.append(r)
            if args.jsonl:
                with args.jsonl.open("a") as f:
                    f.write(json.dumps(r, default=float) + "\n")
            ok = "ok" if r["cause"] == r["truth"] and (r["truth"] == "none" or r["within_tolerance"]) else "  "
            print(f"[{len(results)}/{args.boats}] {r['boat']} {r['size_class']:5s} {r['L_pp_m']:5.1f} m "
                  f"{r['truth']:20s} -> {r['cause']:20s} {ok} {r['errors']} ({r['wall_s']:.0f} s)", flush=True)
    print()
    print(summarise(results))
    print(f"seed {args.seed}, boats {args.first}..{args.first + args.boats - 1}, interaction "
          f"{args.interaction}, whole run "
          f"{time.perf_counter() - started:.0f} s, one process")


if __name__ == "__main__":
    main()
