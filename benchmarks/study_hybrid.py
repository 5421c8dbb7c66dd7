"""Issue 15's comparison on the shipped sea trial: the identified grey box against the generalising hybrid (grey box +
learned residual ensemble), in seed 000's two protocols (benchmarks/study_seed000.py, whose network rows are the
reference: same bags, same turns, same metrics).

    .venv/bin/python benchmarks/study_hybrid.py [--out out/study_hybrid] [--members 5] [--epochs 150]

Data: bags/training (two zig-zags, a port turn, the random run random_7_675rpm) and bags/sea_trial (seed 000 Table 3's
six starboard turns (a)-(f)), all in the same Rizhao-like sea (current, wind, waves), read at the identification step
0.2 s.
Models, per protocol and test:
    grey box   `replay identify --vessel jari_usv --structure mmg --prior fix` on the training manoeuvres (the
               calm-water MMG model identified in the sea: what it cannot carry goes to its coefficients or is lost)
    hybrid     the same identification + `--hybrid`: GeneralisingResidual, `--members` members (seeds 0..M-1: each
               its own initial weights and bootstrap of the windows), early stopping on random_7_675rpm held out whole
               (as seed 000's study); every member is evaluated on its own (the table's mean +- sd and worst seed),
               and the ensemble mean ("hybrid, ensemble mean")
Protocols:
    paper      identify / train on bags/training + all six turns, predict each turn (seen data: seed 000's protocol)
    held-out   leave one turn out: identify / train on bags/training + the other five turns, predict the sixth
Prediction: closed loop from the turn's first state with its recorded controls; metrics of analysis.evaluation
(GNSS reference): turning radius (eq. 29), drift angle (eq. 28), drift distance (eq. 27); the open-loop 30 s track
error too. Deterministic (fixed seeds, one torch thread).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

from study_seed000 import SEA_TRIAL, TARGET, TESTS, TRAINING, VAL_RUN, Member, log, summarise, turning_row  # noqa: E402

DT = 0.2  # (s) the identification step (replay identify's default)
VESSEL = "jari_usv"


class Single:
    """A rollout module as a predictor (evaluation.Predictor protocol)."""

    def __init__(self, module: torch.nn.Module, name: str, dt: float) -> None:
        self.module = module
        self.model_id = name
        self.metadata = {"model_id": name, "model_type": name, "dt": dt, "control_layout": ["delta", "rpm"],
                         "ensemble_size": int(getattr(module, "members", 1)), "horizon_steps": 120}

    def predict(self, state: np.ndarray, controls: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return self.module(torch.from_numpy(np.asarray(state, dtype=np.float64)),
                               torch.from_numpy(np.asarray(controls, dtype=np.float64))).numpy()


def fit(training: list, members: int, epochs: int) -> tuple[Any, Any, dict]:
    """(grey box, hybrid, hybrid info) identified / trained on `training`."""
    from usv_predictor.fitting import hybrid_fit, identification
    from usv_predictor.physics.vessel import load_vessel

    result = identification.identify(load_vessel(VESSEL), training, structure="mmg", prior="fix")
    config = hybrid_fit.HybridTraining(members=members, epochs=epochs, validation=(VAL_RUN,))
    hybrid, info = hybrid_fit.train_hybrid(result, training, DT, config, progress=log)
    return hybrid_fit.greybox_module(result, DT), hybrid, info


def rows_of(grey: Any, hybrid: Any, members: int, recordings: list) -> dict[str, list[list[dict]]]:
    """model -> [recording][seed] turning rows."""
    from usv_predictor.analysis.evaluation import evaluate_recording

    single = Single(hybrid, "hybrid", DT)
    out: dict[str, list[list[dict]]] = {"grey box": [], "hybrid (each member)": [], "hybrid, ensemble mean": []}
    for rec in recordings:
        out["grey box"].append([turning_row(evaluate_recording(Single(grey, "grey box", DT), rec, "gnss", (30.0,)))])
        out["hybrid (each member)"].append([turning_row(evaluate_recording(Member(single, k), rec, "gnss", (30.0,)))
                                            for k in range(members)])
        out["hybrid, ensemble mean"].append([turning_row(evaluate_recording(single, rec, "gnss", (30.0,)))])
    return out


def table(title: str, protocol: dict[str, Any]) -> str:
    """Per model: each criterion's max |error| over the turns, per seed (mean +- sd and the worst seed), and the mean
    open-loop 30 s track error over the turns and seeds."""
    lines = [f"### {title}", "", "| model | radius (%) | drift angle (deg) | drift distance (%) | steady radius (%) | "
             "open loop 30 s (m) | meets 2 % / 2 deg / 5 % (seeds) |", "|---|---|---|---|---|---|---|"]
    for name, s in protocol["summary"].items():
        cells = []
        for key in ("radius_pct", "angle_deg", "distance_pct", "steady_radius_pct"):
            finite = [p[key] for p in s["per_seed_max_abs"] if p[key] is not None]
            if len(finite) > 1:
                cells.append(f"{np.mean(finite):.2f} +- {np.std(finite):.2f} (worst {max(finite):.2f})")
            else:
                cells.append(f"{finite[0]:.2f}" if finite else "-")
        loop = [row["open_loop_30s_m"] for seeds in protocol["rows"][name].values() for row in seeds
                if row["open_loop_30s_m"] is not None]
        cells.append(f"{np.mean(loop):.2f}" if loop else "-")
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {sum(s['meets_target'])} of {len(s['meets_target'])} |")
    return "\n".join(lines)


TITLES = {"paper": "paper protocol (every turn in the training data)", "held_out": "held-out protocol (leave one turn out)"}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=REPO / "out" / "study_hybrid")
    parser.add_argument("--members", type=int, default=5, help="hybrid members = seeds (default 5)")
    parser.add_argument("--epochs", type=int, default=150, help="hybrid epochs at most (early stopping)")
    parser.add_argument("--protocols", nargs="+", default=["paper", "held_out"], choices=["paper", "held_out"])
    parser.add_argument("--turns", nargs="+", default=list(TESTS), choices=list(TESTS),
                        help="held-out protocol: the turns left out in turn (default all six)")
    parser.add_argument("--tables", type=Path, help="only print the tables of an earlier run's study.json")
    args = parser.parse_args(argv)
    if args.tables is not None:
        done = json.loads(args.tables.read_text())
        print("\n\n".join(table(TITLES[k], v) for k, v in done["protocols"].items()))
        return 0
    torch.set_num_threads(1)
    started = time.perf_counter()
    from usv_predictor.replay.identify import identification_recordings

    training = identification_recordings([TRAINING], DT)
    turns = {r.name: r for r in identification_recordings([SEA_TRIAL], DT)}
    tests = {t: turns[name] for t, name in TESTS.items()}
    study: dict[str, Any] = {"members": args.members, "epochs": args.epochs, "dt": DT, "target": TARGET,
                             "protocols": {}}
    text = []
    if "paper" in args.protocols:
        log("paper protocol: identify + train on bags/training and the six turns")
        grey, hybrid, info = fit(training + list(tests.values()), args.members, args.epochs)
        rows = rows_of(grey, hybrid, args.members, list(tests.values()))
        per_model = {m: {t: rows[m][i] for i, t in enumerate(tests)} for m in rows}
        study["protocols"]["paper"] = {"info": info, "rows": per_model,
                                       "summary": {m: summarise(r) for m, r in per_model.items()}}
        text.append(table(TITLES["paper"], study["protocols"]["paper"]))
    if "held_out" in args.protocols:
        per_model = {}
        infos = {}
        for t in args.turns:
            rec = tests[t]
            log(f"held-out protocol: turn ({t}) {rec.name} left out")
            others = [r for k, r in tests.items() if k != t]
            grey, hybrid, info = fit(training + others, args.members, args.epochs)
            infos[t] = info
            rows = rows_of(grey, hybrid, args.members, [rec])
            for m in rows:
                per_model.setdefault(m, {})[t] = rows[m][0]
            log(f"  radius error: grey {rows['grey box'][0][0]['errors']['radius_pct']:+.2f} %, hybrid members "
                + ", ".join(f"{r['errors']['radius_pct']:+.2f}" for r in rows["hybrid (each member)"][0]))
        study["protocols"]["held_out"] = {"info": infos, "rows": per_model,
                                          "summary": {m: summarise(r) for m, r in per_model.items()}}
        text.append(table(TITLES["held_out"], study["protocols"]["held_out"]))
    study["time_s"] = time.perf_counter() - started
    args.out.mkdir(parents=True, exist_ok=True)
    from usv_predictor.replay.cli import write_json_atomic

    write_json_atomic(args.out / "study.json", study)
    print("\n\n".join(text))
    log(f"wrote {args.out / 'study.json'} in {study['time_s']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
