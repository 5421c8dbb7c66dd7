"""Confusion matrix of `diagnose` on boats the tool has never seen, per actuator layout (the figures of
docs/results/unknown_boats.md).

Each boat of --layout (usv_predictor.analysis.unknown_boats.SUITE_LAYOUTS): a random boat drawn around the layout's
presets (draw_boat: rudder_propeller and rudder_only around jari_usv, size class small 3-6 m or large 12-20 m;
twin_thrusters small catamarans 1-3 m around otter, large catamarans 3-6 m around wamv, monohulls 1-6 m; Froude-
scaled, every hull derivative, added mass and interaction factor x U(0.7, 1.3), thrust maps and thruster spacing
drawn where the layout has them), one hidden effect of the layout's vocabulary (or none) with random parameters
(analysis.hidden_effects.draw), then the public pipeline (usv_predictor.replay.unknown_boats.run_unknown_boat):
simulate the layout's calm day and a blind `diagnosis` effect day, delete the truth, `vessel init` from the
owner's data, `identify --prior fix` (rudder boats `--structure mmg --interaction identify`; --interaction fix: as
before the search; twin thrusters `--structure auto`) (or what its cv_warning recommends), `diagnose --model`.
Effects are balanced (boat i hides effect i mod the number of the layout's effects), size classes alternate per
round of them. Prints, per layout, the confusion matrix (rows: truth, columns: named cause; `model_mismatch` and a
fit-check refusal are columns of their own), the parameter hit rate, the confident wrong answers, each
`model_mismatch` with its reasons and the trials identify said would determine its held terms, and the time per
boat. Deterministic for --seed (rudder_propeller boat i: generator [seed, i], as before the other layouts existed;
the others [seed, i, k], k their place in SUITE_LAYOUTS). One JSON line per boat goes to --jsonl as it finishes (a
run stopped early keeps what it did; --summarise FILE prints the tables of such a file). --processes 2 runs the
boats in two processes.

Run: nice -n 10 .venv/bin/python benchmarks/bench_unknown_boats.py --boats 50 --jsonl out/unknown.jsonl
     nice -n 10 .venv/bin/python benchmarks/bench_unknown_boats.py --layout all --boats 50 --processes 2 \
         --jsonl out/unknown_all.jsonl
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


DEFAULT_LAYOUT = "rudder_propeller"


def boat_generator(seed: int, index: int, layout: str) -> np.random.Generator:
    """The random numbers of boat `index` of `layout` (module docstring)."""
    from usv_predictor.analysis.unknown_boats import SUITE_LAYOUTS

    key = tuple(SUITE_LAYOUTS).index(layout)
    return np.random.default_rng([seed, index] if layout == DEFAULT_LAYOUT else [seed, index, key])


def one_boat(index: int, seed: int, workroot: Path, interaction: str = "identify",
             layout: str = DEFAULT_LAYOUT, output_error: str | None = None) -> dict:
    import torch

    from usv_predictor.analysis.hidden_effects import draw
    from usv_predictor.analysis.unknown_boats import SUITE_LAYOUTS, draw_boat
    from usv_predictor.replay.unknown_boats import run_unknown_boat

    torch.set_num_threads(1)
    record = SUITE_LAYOUTS[layout]
    effects = record.effects
    classes = tuple(record.size_classes)
    rng = boat_generator(seed, index, layout)
    size_class = classes[(index // len(effects)) % len(classes)]
    boat = draw_boat(rng, size_class, name=f"boat_{index:03d}", layout=layout)
    truth = draw(rng, effects[index % len(effects)], layout)
    sim_seed = int(rng.integers(0, 2**31 - 2))
    work = workroot / boat.name
    started = time.perf_counter()
    try:
        result = run_unknown_boat(boat, truth, work, sim_seed, interaction=interaction, output_error=output_error)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    result["index"] = index
    result["layout"] = layout
    result["interaction_mode"] = interaction
    result["output_error_mode"] = output_error
    result["wall_s"] = time.perf_counter() - started
    result["factors"] = boat.factors
    result.pop("log", None)
    return result


CONFIDENT_CAUSES_EXCLUDED = ("model_mismatch", "inconclusive", "unexplained", "identify_failed")


def layout_of(result: dict) -> str:
    """The layout of a result line (lines written before the other layouts existed are rudder_propeller's)."""
    return result.get("layout", DEFAULT_LAYOUT)


def held_trials(result: dict) -> list[str]:
    """The trials identify said would determine the terms it held at the description's values (`held[]`)."""
    held = (result.get("identification") or {}).get("held") or []
    return sorted({h["would_determine"] for h in held if h.get("would_determine")})


def summarise(results: list[dict]) -> str:
    """The tables of every layout among `results`, one after the other."""
    layouts = sorted({layout_of(r) for r in results}, key=lambda name: (name != DEFAULT_LAYOUT, name))
    return "\n\n".join(summarise_layout([r for r in results if layout_of(r) == name], name) for name in layouts)


def summarise_layout(results: list[dict], layout: str = DEFAULT_LAYOUT) -> str:
    from usv_predictor.analysis.unknown_boats import SUITE_LAYOUTS

    record = SUITE_LAYOUTS[layout]
    effects = list(record.effects)
    extra = sorted({r["cause"] for r in results} - set(effects), key=lambda c: (c != "model_mismatch", c))
    columns = effects + extra
    matrix = np.zeros((len(effects), len(columns)), dtype=int)
    for r in results:
        matrix[effects.index(r["truth"]), columns.index(r["cause"])] += 1
    lines = [f"{layout}: confusion matrix over {len(results)} unknown boats (rows: hidden effect, columns: named "
             f"cause)", "",
             "| hidden \\ named | " + " | ".join(columns) + " |", "|---" * (len(columns) + 1) + "|"]
    for i, effect in enumerate(effects):
        cells = [(f"**{n}**" if columns[j] == effect else (str(n) if n else "")) for j, n in enumerate(matrix[i])]
        lines.append(f"| {effect} | " + " | ".join(cells) + " |")
    right = [r for r in results if r["cause"] == r["truth"]]
    hits = [r for r in right if r["truth"] == "none" or r["within_tolerance"]]
    confident_wrong = [r for r in results if r["cause"] != r["truth"] and r["cause"] not in CONFIDENT_CAUSES_EXCLUDED]
    confounded = [r for r in confident_wrong if r["truth"] in r.get("confounded_with", [])]
    refused = [r for r in results if r.get("refused")]
    mismatch = [r for r in results if r["cause"] == "model_mismatch"]
    wrong_parameters = [r for r in right if r["truth"] != "none" and not r["within_tolerance"]]
    lines += ["", f"right cause: {len(right)}/{len(results)}; right cause and parameters within tolerance: "
                  f"{len(hits)}/{len(results)} (effects only: "
                  f"{sum(r['truth'] != 'none' for r in hits)}/{sum(r['truth'] != 'none' for r in results)})",
              f"confident wrong answers (a cause or `none` that is not the truth): "
              f"{len(confident_wrong)}/{len(results)}"
              + (f" ({len(confounded)} of them name the truth as confounded: the data cannot tell them apart)"
                 if confounded else "")
              + "".join(f"\n  {r['boat']} ({r['size_class']}, {r['L_pp_m']:.1f} m): {r['truth']} "
                        f"{r['truth_parameters']} -> {r['cause']} {r['parameters']}"
                        + (f", confounded with {', '.join(r['confounded_with'])}" if r.get("confounded_with") else "")
                        for r in confident_wrong),
              f"right cause, parameters beyond the tolerances: {len(wrong_parameters)}"
              + "".join(f"\n  {r['boat']} ({r['size_class']}, {r['L_pp_m']:.1f} m): {r['truth']} "
                        f"{r['truth_parameters']} "
                        f"-> {r['parameters']}" for r in wrong_parameters),
              f"model_mismatch: {len(mismatch)} (of which refused by the fit check: {len(refused)}; the rollout of the "
              f"identified model diverges: "
              f"{sum(any('diverges' in m for m in r['mismatch_reasons']) for r in mismatch)})"]
    for r in [r for r in results if r["cause"] in ("model_mismatch", "unexplained")]:  # no cause: say why
        reasons = "; ".join(r["mismatch_reasons"]) or r.get("message", "")
        lines.append(f"  {r['boat']} ({r['size_class']}, {r['L_pp_m']:.1f} m, {r['truth']} -> {r['cause']}): "
                     f"{reasons[:300]}; "
                     f"held terms would be determined by: {', '.join(held_trials(r)) or 'nothing held'}")
    failed = [r for r in results if r.get("identify_failed")]
    if failed:
        lines.append(f"identify failed: {len(failed)} ({', '.join(r['boat'] for r in failed)})")
    for size in record.size_classes:
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


def _line(r: dict, done: int, total: int) -> str:
    ok = "ok" if r["cause"] == r["truth"] and (r["truth"] == "none" or r["within_tolerance"]) else "  "
    return (f"[{done}/{total}] {layout_of(r)} {r['boat']} {r['size_class']:5s} {r['L_pp_m']:5.1f} m "
            f"{r['truth']:20s} -> {r['cause']:20s} {ok} {r['errors']} ({r['wall_s']:.0f} s)")


def _one_job(job: tuple[str, int, int, str, str, str | None]) -> dict:
    layout, index, seed, root, interaction, output_error = job
    return one_boat(index, seed, Path(root), interaction, layout, output_error)


def main() -> None:
    from usv_predictor.analysis.unknown_boats import SUITE_LAYOUTS

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--layout", choices=(*SUITE_LAYOUTS, "all"), default=DEFAULT_LAYOUT,
                        help=f"the boats' actuator layout, or all of them one after the other (default "
                             f"{DEFAULT_LAYOUT})")
    parser.add_argument("--boats", type=int, default=50, help="boats per layout (default 50)")
    parser.add_argument("--first", type=int, default=0, help="index of the first boat (resume a stopped run)")
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--processes", type=int, default=1, help="boats run in this many processes (default 1)")
    parser.add_argument("--interaction", choices=("identify", "fix"), default="identify",
                        help="identify --interaction of the rudder layouts: the factors searched with the hull "
                             "(default) or the description's (fix: the suite before the search, for comparison)")
    parser.add_argument("--output-error", choices=("on", "off"), default=None,
                        help="identify --output-error for every boat (default: identify's own default per layout)")
    parser.add_argument("--jsonl", type=Path, default=None, help="append one JSON line per boat here")
    parser.add_argument("--summarise", type=Path, nargs="+", default=None, metavar="JSONL",
                        help="only print the tables of a run (several files: the boats of processes run in parallel "
                             "over disjoint --first/--boats ranges)")
    parser.add_argument("--rerun", type=Path, default=None, metavar="JSONL",
                        help="with --summarise: boats re-run later (e.g. with a newer diagnose) replace the same index")
    args = parser.parse_args()
    if args.boats < 1 or args.processes < 1 or args.first < 0:
        parser.error("--boats and --processes must be >= 1, --first >= 0")
    if args.summarise:
        def read(path: Path) -> list[dict]:
            return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]

        results = {(layout_of(r), r["index"]): r for path in args.summarise for r in read(path)}
        rerun = read(args.rerun) if args.rerun else []
        results.update({(layout_of(r), r["index"]): r for r in rerun})
        print(summarise([results[k] for k in sorted(results)]))
        if rerun:
            print(f"re-run: {', '.join(r['boat'] for r in rerun)}")
        return
    layouts = tuple(SUITE_LAYOUTS) if args.layout == "all" else (args.layout,)
    started = time.perf_counter()
    results: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="unknown_boats_") as root:
        jobs = [(layout, index, args.seed, root, args.interaction, args.output_error) for layout in layouts
                for index in range(args.first, args.first + args.boats)]

        def record(r: dict) -> None:
            results.append(r)
            if args.jsonl:
                with args.jsonl.open("a") as f:
                    f.write(json.dumps(r, default=float) + "\n")
            print(_line(r, len(results), len(jobs)), flush=True)

        if args.processes == 1:
            for job in jobs:
                record(_one_job(job))
        else:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor, as_completed

            context = multiprocessing.get_context("spawn")  # a fresh interpreter: no forked torch/numba state
            with ProcessPoolExecutor(args.processes, mp_context=context) as pool:
                for future in as_completed([pool.submit(_one_job, job) for job in jobs]):
                    record(future.result())
    print()
    results.sort(key=lambda r: (layout_of(r), r["index"]))
    print(summarise(results))
    print(f"seed {args.seed}, layouts {', '.join(layouts)}, boats {args.first}..{args.first + args.boats - 1} each, "
          f"interaction {args.interaction}, whole run {time.perf_counter() - started:.0f} s, "
          f"{args.processes} process(es)")


if __name__ == "__main__":
    main()
