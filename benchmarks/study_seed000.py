"""Seed 000's study (sec. 3.2-3.4, Tables 6-8) on the shipped sea-trial bags, in two protocols.

    .venv/bin/python benchmarks/study_seed000.py [--out out/study_seed000] [--seeds 3] [--figures docs/results/study]
        [--multi-step K]

Models (seed 000 Fig. 1, Table 5 recipe, early stopping on the validation manoeuvre, patience 50):
    NTF clippedReLU, NTF tanh   Table 6 (activation, NTF)
    NTF, NAF, F0, all tanh      Tables 7-8 (input features)
    physics                     the calm-water MMG model of the jari_usv preset (`replay evaluate --model physics`)
    NTF tanh, multi-step K      with --multi-step K: trained on closed-loop rollouts of K steps (issue 15's
                                "network trained with multi-step loss"; not in seed 000)

Data (bags/README.md): bags/sea_trial = the six Table 3 turning tests (a)-(f); bags/training = two zig-zags,
a port turn and a random run, all in the same Rizhao-like sea. The validation split (early stopping) is always
`random_7_675rpm`, never a turning test.

Protocols:
    paper     train on bags/training (less the validation run) + all six turns, then predict each turn
              closed loop from its first state with its recorded controls (seed 000 Fig. 3). The network has
              seen the very samples it predicts: this is what seed 000 did and what its tables measure.
    held-out  leave one turn out: for each turn, a dataset with that turn as its `test` split (training
              gets the other five turns + bags/training), a model trained on it, the turn predicted.
              These numbers say something about generalisation to a new turning test in the same sea.

Every network is trained `--seeds` times (seeds 0..S-1) as the S members of one `replay train --ensemble S`
call (member m is trained exactly as a single network of seed m) and each member is evaluated on its own:
closed-loop metrics of one network vary a lot with its seed, so tables show the mean and spread over seeds.
The ensemble mean track is not used: averaging tracks of slightly different phase shrinks the circle.

Metrics: usv_predictor.analysis.evaluation (GNSS reference): turning radius eq. 29 (drift axis of the measured track),
steady circle fit, drift distance eq. 27, drift angle eq. 28 (X east, Y north, as seed 000 Table 8).
Errors predicted - measured: relative (%) for lengths, absolute (deg) for angles.

Outputs: OUT/study.json (everything, per seed), OUT/tables.md (markdown tables), FIGURES/*.png (two small
figures). Deterministic: fixed seeds, one torch thread, the split is given by names. Prints progress.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SEA_TRIAL = REPO / "bags" / "sea_trial"
TRAINING = REPO / "bags" / "training"
VAL_RUN = "random_7_675rpm"
TESTS = {  # seed 000 Table 3 index -> bag
    "a": "turning_circle_stbd_15deg_650rpm",
    "b": "turning_circle_stbd_15deg_700rpm",
    "c": "turning_circle_stbd_20deg_650rpm",
    "d": "turning_circle_stbd_20deg_700rpm",
    "e": "turning_circle_stbd_25deg_650rpm",
    "f": "turning_circle_stbd_25deg_700rpm",
}
CONFIGS = {  # name -> (feature set, activation)
    "NTF clippedReLU": ("NTF", "clipped_relu"),
    "NTF tanh": ("NTF", "tanh"),
    "NAF tanh": ("NAF", "tanh"),
    "F0 tanh": ("F0", "tanh"),
}
PHYSICS = "physics"
TARGET = {"radius_pct": 2.0, "angle_deg": 2.0, "distance_pct": 5.0}  # the target for the best model
SEED000 = {"radius_pct": 5.44, "angle_deg": 4.84, "distance_pct": 9.09}  # seed 000's max errors (NTF, Tables 7-8)
# seed 000 measured values (Tables 4, 7, 8) for the side-by-side
PAPER_MEASURED = {"radius_m": [12.66, 18.43, 9.95, 13.82, 6.07, 11.15],
                  "drift_angle_deg": [213.54, 235.63, 204.45, 239.43, 186.78, 223.06],
                  "drift_distance_m": [7.60, 8.36, 12.60, 5.21, 9.78, 6.63]}


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def replay(argv: list[str], quiet: bool = True) -> None:
    """Run one `replay` command in this process (same code path as the executable); exit on failure."""
    from usv_predictor.replay import cli

    sink = io.StringIO()
    with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink) if quiet else contextlib.nullcontext():
        code = cli.main(argv)
    if code != 0:
        sys.exit(f"`replay {' '.join(argv)}` failed (exit {code}):\n{sink.getvalue()}")


class Member:
    """One member of an ensemble artifact as a single-network predictor (evaluation.Predictor protocol)."""

    def __init__(self, artifact: Any, index: int) -> None:
        self._artifact, self._index = artifact, index
        self.metadata = dict(artifact.metadata, ensemble_size=1, model_id=f"{artifact.model_id}/member{index}")

    def predict(self, state: np.ndarray, controls: np.ndarray) -> np.ndarray:
        return self._artifact.predict(state, controls)[self._index:self._index + 1]  # (1, B, H, 6)


def angle_error(predicted: float | None, measured: float | None) -> float | None:
    if predicted is None or measured is None:
        return None
    return float((predicted - measured + 180.0) % 360.0 - 180.0)


def turning_row(evaluation: Any) -> dict[str, Any]:
    """The seed 000 numbers of one evaluated turn (eq. 28 angle, errors predicted - measured)."""
    t = evaluation.turning
    if t is None:
        raise SystemExit(f"{evaluation.name} was not classified as a turning circle")
    m, p, e = t.measured, t.predicted, t.errors
    return {
        "measured": {"radius_m": m["turning_radius_m"], "steady_radius_m": m["steady_turning_radius_m"],
                     "drift_angle_deg": m["drift_angle_seed_eq28_deg"], "drift_direction_deg": m["drift_direction_deg"],
                     "drift_distance_m": m["drift_distance_m"]},
        "predicted": {"radius_m": p["turning_radius_m"], "steady_radius_m": p["steady_turning_radius_m"],
                      "drift_angle_deg": p["drift_angle_seed_eq28_deg"],
                      "drift_direction_deg": p["drift_direction_deg"],
                      "drift_distance_m": p["drift_distance_m"]},
        "errors": {"radius_pct": e["turning_radius_rel_pct"], "steady_radius_pct": e["steady_turning_radius_rel_pct"],
                   "angle_deg": angle_error(p["drift_angle_seed_eq28_deg"], m["drift_angle_seed_eq28_deg"]),
                   "distance_pct": e["drift_distance_rel_pct"]},
        "closed_loop_rmse": evaluation.state_rmse,
        "open_loop_30s_m": None if evaluation.open_loop is None else next(
            (h.mean_m for h in evaluation.open_loop.horizons if h.horizon_s == 30.0), None),
        "notes": list(t.notes),
    }


def evaluate_members(artifact_path: Path, recordings: list, seeds: int) -> list[list[dict]]:
    """[member][recording] turning rows of every member of an ensemble artifact."""
    from usv_predictor.analysis import evaluation
    from usv_predictor.models.artifact import load_artifact

    artifact = load_artifact(artifact_path)
    return [[turning_row(evaluation.evaluate_recording(Member(artifact, k), rec, "gnss", (30.0,), 5.0))
             for rec in recordings] for k in range(seeds)]


def train(dataset: Path, out: Path, feature_set: str, activation: str, seeds: int,
          multi_step: int = 1) -> tuple[list[str], dict]:
    argv = ["train", str(dataset), "--output", str(out), "--features", feature_set, "--activation", activation,
            "--ensemble", str(seeds), "--seed", "0", "--threads", "1", "--json", str(out.with_suffix(".json"))]
    if multi_step > 1:
        argv += ["--multi-step", str(multi_step)]
    replay(argv)
    return argv, json.loads(out.with_suffix(".json").read_text())


def _steps_suffix(steps: int) -> str:
    return f"_ms{steps}" if steps > 1 else ""


# ------------------------------------------------------------------ aggregation and tables


def _finite(values: list) -> list[float]:
    return [float(v) for v in values if v is not None and math.isfinite(v)]


def stats(values: list) -> dict[str, float | None]:
    v = _finite(values)
    if not v:
        return {"mean": None, "sd": None, "min": None, "max": None, "max_abs": None, "n": 0}
    return {"mean": float(np.mean(v)), "sd": float(np.std(v)), "min": min(v), "max": max(v),
            "max_abs": max(abs(x) for x in v), "n": len(v)}


def summarise(rows: dict[str, list[dict]]) -> dict[str, Any]:
    """rows: test -> [per-seed row]. Per seed, the max |error| over the six tests; then over seeds."""
    n_seeds = len(next(iter(rows.values())))
    per_seed = []
    for k in range(n_seeds):
        per_seed.append({key: stats([rows[t][k]["errors"][key] for t in rows])["max_abs"]
                         for key in ("radius_pct", "steady_radius_pct", "angle_deg", "distance_pct")})
    out: dict[str, Any] = {"per_seed_max_abs": per_seed}
    for key in ("radius_pct", "steady_radius_pct", "angle_deg", "distance_pct"):
        vals = [s[key] for s in per_seed]
        out[key] = {"mean_of_max_abs": stats(vals)["mean"], "best_seed": min(_finite(vals), default=None),
                    "worst_seed": max(_finite(vals), default=None)}
    out["meets_target"] = [all(s[k] is not None and s[k] <= TARGET[k] for k in TARGET) for s in per_seed]
    return out


def fmt(value: float | None, digits: int = 2, suffix: str = "") -> str:
    return "-" if value is None or not math.isfinite(value) else f"{value:.{digits}f}{suffix}"


def pm(values: list, digits: int = 2, suffix: str = "") -> str:
    s = stats(values)
    if s["mean"] is None:
        return "-"
    if s["n"] == 1:
        return fmt(s["mean"], digits, suffix)
    return f"{s['mean']:.{digits}f} ± {s['sd']:.{digits}f}{suffix}"


def tables(study: dict) -> str:
    letters = list(TESTS)
    head = "| | " + " | ".join(f"({x})" for x in letters) + " |\n|---|" + "---|" * len(letters)
    lines: list[str] = []
    n = study["seeds"]
    physics = study["physics"]
    for proto, title in (("paper", "paper protocol (train on the turns it predicts)"),
                         ("held_out", "held-out protocol (leave one turn out)")):
        res = study["protocols"][proto]
        meas = {t: res["NTF tanh"]["rows"][t][0]["measured"] for t in letters}

        def pred(cfg: str, t: str, key: str, where: str = "predicted") -> list:
            return [r[where][key] for r in res[cfg]["rows"][t]]

        lines += [f"### Table 6, {title}: activation, NTF, test (a), {n} seeds (mean ± sd)", "",
                  "| | measured | NTF clippedReLU (f1) | NTF tanh (f2) |", "|---|---|---|---|"]
        for key, label, _unit in (("drift_angle_deg", "drift angle eq. 28 (deg)", ""),
                                 ("drift_distance_m", "drift distance eq. 27 (m)", ""),
                                 ("radius_m", "turning radius eq. 29 (m)", "")):
            lines.append(f"| {label} | {fmt(meas['a'][key])} | {pm(pred('NTF clippedReLU', 'a', key))} | "
                         f"{pm(pred('NTF tanh', 'a', key))} |")
        for key, label in (("angle_deg", "error of drift angle (deg)"), ("distance_pct", "error of drift distance (%)"),
                           ("radius_pct", "error of radius (%)")):
            lines.append(f"| {label} | | {pm(pred('NTF clippedReLU', 'a', key, 'errors'))} | "
                         f"{pm(pred('NTF tanh', 'a', key, 'errors'))} |")
        lines += ["", f"### Table 7, {title}: turning radius eq. 29 (m), tanh, {n} seeds (mean ± sd)", "", head,
                  "| measured radius (m) | " + " | ".join(fmt(meas[t]["radius_m"]) for t in letters) + " |",
                  "| measured, steady circle fit (m) | " + " | ".join(fmt(meas[t]["steady_radius_m"]) for t in letters)
                  + " |"]
        for cfg in ("F0 tanh", "NAF tanh", "NTF tanh"):
            short = cfg.split()[0]
            lines.append(f"| predicted radius by {short} (m) | "
                         + " | ".join(pm(pred(cfg, t, "radius_m")) for t in letters) + " |")
            lines.append(f"| relative error of radius by {short} | " + " | ".join(
                pm(pred(cfg, t, "radius_pct", "errors"), 2, "%") for t in letters) + " |")
        lines.append("| physics (calm-water MMG) radius (m) | " + " | ".join(
            fmt(physics["rows"][t][0]["predicted"]["radius_m"]) for t in letters) + " |")
        lines.append("| relative error of radius by physics | " + " | ".join(
            fmt(physics["rows"][t][0]["errors"]["radius_pct"], 2, "%") for t in letters) + " |")
        lines += ["",
                  f"### Table 8, {title}: drift angle eq. 28 and drift distance eq. 27, tanh, {n} seeds (mean ± sd)",
                  "", head,
                  "| measured drift angle (deg) | " + " | ".join(fmt(meas[t]["drift_angle_deg"]) for t in letters)
                  + " |"]
        for cfg in ("F0 tanh", "NAF tanh", "NTF tanh"):
            short = cfg.split()[0]
            lines.append(f"| predicted drift angle by {short} (deg) | " + " | ".join(
                pm(pred(cfg, t, "drift_angle_deg")) for t in letters) + " |")
            lines.append(f"| absolute error of angle by {short} (deg) | " + " | ".join(
                pm(pred(cfg, t, "angle_deg", "errors")) for t in letters) + " |")
        lines.append("| physics drift angle (deg) | " + " | ".join(
            fmt(physics["rows"][t][0]["predicted"]["drift_angle_deg"]) for t in letters) + " |")
        lines.append("| measured drift distance (m) | " + " | ".join(fmt(meas[t]["drift_distance_m"]) for t in letters)
                     + " |")
        for cfg in ("F0 tanh", "NAF tanh", "NTF tanh"):
            short = cfg.split()[0]
            lines.append(f"| predicted drift distance by {short} (m) | " + " | ".join(
                pm(pred(cfg, t, "drift_distance_m")) for t in letters) + " |")
            lines.append(f"| relative error of drift distance by {short} | " + " | ".join(
                pm(pred(cfg, t, "distance_pct", "errors"), 1, "%") for t in letters) + " |")
        lines.append("| physics drift distance (m) | " + " | ".join(
            fmt(physics["rows"][t][0]["predicted"]["drift_distance_m"]) for t in letters) + " |")
        lines += ["", f"### Summary, {title}: max |error| over the six tests "
                      f"(target {TARGET['radius_pct']:g} % / {TARGET['angle_deg']:g} deg / "
                      f"{TARGET['distance_pct']:g} %; "
                      f"seed 000: {SEED000['radius_pct']} % / {SEED000['angle_deg']} deg / "
                      f"{SEED000['distance_pct']} %)", "",
                  "| model | radius eq. 29 (%) | radius, circle fit (%) | drift angle (deg) | drift distance (%) "
                  "| meets target (seeds) | mean RMSE u / v (m/s), r (deg/s) | open-loop error at 30 s (m) |",
                  "|---|---|---|---|---|---|---|---|"]
        for cfg in list(res) + [PHYSICS]:
            block = physics if cfg == PHYSICS else res[cfg]
            s = block["summary"]
            rows = [r for t in letters for r in block["rows"][t]]

            def cell(key: str, digits: int = 2) -> str:
                v = s[key]
                if cfg == PHYSICS or n == 1:
                    return fmt(v["worst_seed"], digits)
                return (f"{fmt(v['mean_of_max_abs'], digits)} "
                        f"({fmt(v['best_seed'], digits)}-{fmt(v['worst_seed'], digits)})")

            rmse = " / ".join(fmt(stats([r["closed_loop_rmse"][k] for r in rows])["mean"], d)
                              for k, d in (("u_mps", 3), ("v_mps", 3), ("r_deg_s", 2)))
            label = "physics (calm-water MMG)" if cfg == PHYSICS else cfg
            met = s["meets_target"]
            lines.append(f"| {label} | {cell('radius_pct')} | {cell('steady_radius_pct')} | {cell('angle_deg')} | "
                         f"{cell('distance_pct', 1)} | {sum(met)}/{len(met)} | {rmse} | "
                         f"{fmt(stats([r['open_loop_30s_m'] for r in rows])['mean'])} |")
        lines += ["", f"Cells: mean over {n} seeds of the per-seed maximum (best seed - worst seed)." if n > 1 else "",
                  ""]
    return "\n".join(lines)


def figures(study: dict, recordings: dict, paths: dict, directory: Path) -> list[str]:
    """Two small PNGs: rotated tracks of test (a) (held-out, seed 0) and the held-out drift errors per test."""
    from usv_predictor.analysis import evaluation
    from usv_predictor.analysis.plots import new_figure, rotate_to_drift, save_figure
    from usv_predictor.models.artifact import load_artifact

    directory.mkdir(parents=True, exist_ok=True)
    written = []
    rec = recordings["a"]
    fig = new_figure(5.6, 3.6)
    ax = fig.add_subplot(1, 1, 1)
    measured_dir = study["protocols"]["held_out"]["NTF tanh"]["rows"]["a"][0]["measured"]["drift_direction_deg"]
    first = True
    for cfg, color in (("F0 tanh", "tab:orange"), ("NAF tanh", "tab:green"), ("NTF tanh", "tab:blue")):
        model = Member(load_artifact(paths[("held_out", cfg, "a")]), 0)
        p = evaluation.closed_loop(model, rec, "gnss")
        if first:
            mx, my = rotate_to_drift(p.measured[:, 3] - p.measured[0, 3], p.measured[:, 4] - p.measured[0, 4],
                                     measured_dir)
            ax.plot(mx, my, color="black", linewidth=1.0, label="measured (GNSS)")
            first = False
        px, py = rotate_to_drift(p.predicted[:, 3] - p.measured[0, 3], p.predicted[:, 4] - p.measured[0, 4],
                                 measured_dir)
        ax.plot(px, py, color=color, linewidth=1.1, label=f"{cfg.split()[0]} (held out, seed 0)")
    ax.set_aspect("equal")
    ax.set_xlabel("along the measured drift (m)")
    ax.set_ylabel("across (m)")
    ax.set_title("test (a) 15 deg / 650 rpm, rotated track (seed 000 Fig. 11)", fontsize=9)
    ax.legend(fontsize=7, loc="best")
    ax.grid(alpha=0.3)
    written.append(str(save_figure(fig, directory / "track_a_held_out.png")))

    fig = new_figure(7.0, 3.0)
    letters = list(TESTS)
    x = np.arange(len(letters))
    for i, (key, label) in enumerate((("angle_deg", "drift angle error (deg)"), ("distance_pct", "drift "
                                                                                                 "distance "
                                                                                                 "error (%)"))):
        ax = fig.add_subplot(1, 2, i + 1)
        for j, (cfg,
                color) in enumerate((("F0 tanh", "tab:orange"), ("NAF tanh", "tab:green"), ("NTF tanh", "tab:blue"))):
            rows = study["protocols"]["held_out"][cfg]["rows"]
            vals = [stats([r["errors"][key] for r in rows[t]]) for t in letters]
            mean = [v["mean"] if v["mean"] is not None else np.nan for v in vals]
            sd = [v["sd"] if v["sd"] is not None else 0.0 for v in vals]
            ax.bar(x + (j - 1) * 0.27, mean, 0.27, yerr=sd, color=color, label=cfg.split()[0], capsize=2)
        ax.axhline(0.0, color="black", linewidth=0.6)
        ax.set_xticks(x, [f"({t})" for t in letters])
        ax.set_title(label, fontsize=9)
        ax.grid(alpha=0.3, axis="y")
        if key == "angle_deg":
            ax.set_ylim(-60, 60)
        else:
            ax.set_ylim(-110, 60)
        ax.legend(fontsize=7)
    written.append(str(save_figure(fig, directory / "drift_errors_held_out.png")))
    return written


# ------------------------------------------------------------------ main


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=REPO / "out" / "study_seed000", help="work and result directory")
    parser.add_argument("--seeds", type=int, default=3, help="networks per configuration (seeds 0..S-1, default 3)")
    parser.add_argument("--figures", type=str, default=str(REPO / "docs" / "results" / "study"),
                        help="PNG directory ('' for none)")
    parser.add_argument("--multi-step", type=int, default=1, metavar="K",
                        help="also NTF tanh trained on closed-loop rollouts of K steps (replay train --multi-step K; "
                             "default 1: not trained), a row of its own in the summaries")
    args = parser.parse_args(argv)
    # name -> (feature set, activation, rollout steps of the training loss)
    configs = {name: (features, activation, 1) for name, (features, activation) in CONFIGS.items()}
    if args.multi_step > 1:
        configs[f"NTF tanh, multi-step {args.multi_step}"] = ("NTF", "tanh", args.multi_step)
    started = time.perf_counter()
    from usv_predictor.analysis import evaluation
    from usv_predictor.physics.vessel import load_vessel
    from usv_predictor.replay.recordings import load_recordings

    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    commands: list[str] = []
    log("reading the six sea-trial turns")
    recs = load_recordings([SEA_TRIAL], 0.5, warn=log)
    by_name = {r.name: r for r in recs}
    recordings = {t: by_name[name] for t, name in TESTS.items()}

    log("physics baseline (replay evaluate --model physics)")
    physics_model = evaluation.physics_predictor(load_vessel("jari_usv"), 0.5)
    physics_rows = {t: [turning_row(evaluation.evaluate_recording(physics_model, rec, "gnss", (30.0,), 5.0))]
                    for t, rec in recordings.items()}
    commands.append("replay evaluate bags/sea_trial --model physics")
    study: dict[str, Any] = {"seeds": args.seeds, "tests": TESTS, "validation_run": VAL_RUN, "target": TARGET,
                             "seed000_max_errors": SEED000, "paper_measured": PAPER_MEASURED,
                             "physics": {"rows": physics_rows, "summary": summarise(physics_rows)},
                             "protocols": {}, "commands": commands}
    paths: dict[tuple, Path] = {}
    timing: dict[str, float] = {}

    # (i) paper protocol: one dataset, every turn in training
    t0 = time.perf_counter()
    dataset = out / "paper.npz"
    argv = ["dataset", str(TRAINING), str(SEA_TRIAL), "--output", str(dataset), "--val", VAL_RUN, "--jobs", "1"]
    replay(argv)
    commands.append("replay " + " ".join(argv[:1] + ["bags/training", "bags/sea_trial"] + argv[3:]))
    paper: dict[str, Any] = {}
    for cfg, (features, activation, steps) in configs.items():
        log(f"paper protocol: training {cfg} ({args.seeds} seeds)")
        path = out / f"paper_{features}_{activation}{_steps_suffix(steps)}.pt"
        targv, result = train(dataset, path, features, activation, args.seeds, steps)
        commands.append("replay " + " ".join(targv))
        members = evaluate_members(path, list(recordings.values()), args.seeds)
        rows = {t: [members[k][i] for k in range(args.seeds)] for i, t in enumerate(TESTS)}
        paper[cfg] = {"rows": rows, "summary": summarise(rows), "best_epoch": result["best_epoch"],
                      "train_time_s": result["time_s"]}
        for t in TESTS:
            paths[("paper", cfg, t)] = path
        log(f"  max |err| per seed: {paper[cfg]['summary']['per_seed_max_abs']}")
    study["protocols"]["paper"] = paper
    timing["paper_s"] = time.perf_counter() - t0

    # (ii) held-out protocol: leave one turn out
    t0 = time.perf_counter()
    held: dict[str, Any] = {cfg: {"rows": {}, "best_epoch": {}, "train_time_s": 0.0} for cfg in configs}
    for t, name in TESTS.items():
        dataset = out / f"held_out_{t}.npz"
        argv = ["dataset", str(TRAINING), str(SEA_TRIAL), "--output", str(dataset), "--val", VAL_RUN,
                "--test", name, "--jobs", "1"]
        replay(argv)
        commands.append("replay " + " ".join(argv[:1] + ["bags/training", "bags/sea_trial"] + argv[3:]))
        for cfg, (features, activation, steps) in configs.items():
            log(f"held-out protocol: test ({t}) {name}, training {cfg} ({args.seeds} seeds)")
            path = out / f"held_out_{t}_{features}_{activation}{_steps_suffix(steps)}.pt"
            targv, result = train(dataset, path, features, activation, args.seeds, steps)
            commands.append("replay " + " ".join(targv))
            members = evaluate_members(path, [recordings[t]], args.seeds)
            held[cfg]["rows"][t] = [members[k][0] for k in range(args.seeds)]
            held[cfg]["best_epoch"][t] = result["best_epoch"]
            held[cfg]["train_time_s"] += result["time_s"]
            paths[("held_out", cfg, t)] = path
    for cfg in configs:
        held[cfg]["summary"] = summarise(held[cfg]["rows"])
        log(f"held-out {cfg}: max |err| per seed: {held[cfg]['summary']['per_seed_max_abs']}")
    study["protocols"]["held_out"] = held
    timing["held_out_s"] = time.perf_counter() - t0

    if args.figures:  # a str: Path("") would be "." and write the figures into the working directory
        study["figures"] = figures(study, recordings, paths, Path(args.figures))
    timing["total_s"] = time.perf_counter() - started
    study["timing"] = timing
    from usv_predictor.replay.cli import write_json_atomic

    write_json_atomic(out / "study.json", study)
    text = tables(study)
    (out / "tables.md").write_text(text + "\n", encoding="utf-8")
    print(text)
    log(f"wrote {out / 'study.json'} and {out / 'tables.md'} in {timing['total_s']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
