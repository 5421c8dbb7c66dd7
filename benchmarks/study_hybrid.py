"""Issue 15's comparison on the shipped sea trial: the identified grey box against the generalising hybrid (grey box +
learned residual ensemble), in seed 000's two protocols (benchmarks/study_seed000.py, whose network rows are the
reference: same bags, same turns, same metrics).

    .venv/bin/python benchmarks/study_hybrid.py [--out out/study_hybrid] [--members 5] [--epochs 150]
        [--protocols paper held_out] [--turns a b c d e f] [--bases identified extended] [--jsonl rows.jsonl]

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
    calm-water preset   the vessel file jari_usv itself (the calm-water model `replay diagnose` starts from)
    extended grey box   what `replay diagnose bags/sea_trial bags/training --export` writes, made from the same
               training manoeuvres: analysis.diagnosis.diagnose against the preset at its suited steps (0.5 s, 20 s
               segments, every hypothesis, up to 2 causes: docs/results/diagnosis_examples.md's diagnosis names current
               + wave drift), the
               named causes refitted on all of them and exported at the study's step 0.2 s (export_extended)
    hybrid on extended `replay identify --hybrid --base extended.pt`: the same residual training (members, epochs,
               validation run) on top of that file's grey box (fitting.hybrid_fit.base_from_artifact,
               train_residual): the physics carries the current and the wave drift, the residual what they leave
               (--bases chooses the base(s): identified = the two rows above, extended = these three)
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
from dataclasses import dataclass
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
    if members == 0:  # the grey box only (--members 0)
        return hybrid_fit.greybox_module(result, DT), None, {}
    config = hybrid_fit.HybridTraining(members=members, epochs=epochs, validation=(VAL_RUN,))
    hybrid, info = hybrid_fit.train_hybrid(result, training, DT, config, progress=log)
    return hybrid_fit.greybox_module(result, DT), hybrid, info


def fit_extended(training: list, training_05: list, members: int, epochs: int, path: Path, max_causes: int = 2
                 ) -> tuple[Any, Any, Any, dict]:
    """(calm-water preset, extended grey box, hybrid on it, info): the diagnosis of `training_05` (the same
    manoeuvres at the diagnosis' suited step 0.5 s) against the preset, its extension exported to `path` at DT, and
    the residual trained on that file's grey box with `training` (what `replay identify --hybrid --base` does).
    The extended grey box and the hybrid are None when the diagnosis names no cause (info says which)."""
    from usv_predictor.analysis import diagnosis as dg
    from usv_predictor.fitting import hybrid_fit, identification
    from usv_predictor.models.artifact import load_artifact
    from usv_predictor.physics.effects import NONE
    from usv_predictor.physics.vessel import load_vessel

    preset = load_vessel(VESSEL)
    calm = hybrid_fit.ResidualGreyBox(preset, DT, hybrid_fit.ZeroResidual())
    started = time.perf_counter()
    diagnosis = dg.diagnose(training_05, preset, horizon_s=20.0, stride_s=5.0, max_causes=max_causes,
                             progress=log)
    info: dict[str, Any] = {"cause": diagnosis.cause, "parameters": diagnosis.parameters,
                            "additional_causes": [a.cause for a in diagnosis.additional_causes],
                            "diagnosis_s": time.perf_counter() - started}
    log(f"  diagnosis: {diagnosis.cause} {diagnosis.parameters} + {info['additional_causes']} "
        f"({info['diagnosis_s']:.0f} s)")
    if diagnosis.cause in (NONE, dg.MODEL_MISMATCH, dg.INCONCLUSIVE):
        return calm, None, None, info
    dg.export_extended(path, preset, diagnosis, DT)
    artifact = load_artifact(path)
    vessel, base = hybrid_fit.base_from_artifact(artifact, preset, training[0])
    info.update(model_type=artifact.metadata["model_type"], terms=base.terms())
    if members == 0:  # the grey boxes only (--members 0)
        return calm, base, None, info
    data = identification.prepare(vessel, training)
    config = hybrid_fit.HybridTraining(members=members, epochs=epochs, validation=(VAL_RUN,))
    hybrid, hybrid_info = hybrid_fit.train_residual(base, vessel, data, training, DT, config, progress=log)
    info.update(hybrid=hybrid_info)
    return calm, base, hybrid, info


def fit_named(training: list, training_05: list, causes: tuple[str, ...], members: int, epochs: int, path: Path
              ) -> tuple[Any, Any, dict]:
    """(grey box, hybrid on it or None, info): the preset extended with `causes` named by the user (no selection:
    e.g. a wind the trial log reports), their terms fitted on `training_05` at the diagnosis' suited segments
    (analysis.diagnosis.fit_hypothesis, 20 s / 5 s at 0.5 s), exported to `path` at DT as export_extended writes an
    extension, and with members > 0 the residual trained on that file's grey box as fit_extended does."""
    from usv_predictor.analysis import diagnosis as dg
    from usv_predictor.fitting import hybrid_fit, identification
    from usv_predictor.models.artifact import export_module, load_artifact
    from usv_predictor.models.greybox import greybox_metadata
    from usv_predictor.physics.vessel import load_vessel

    preset = load_vessel(VESSEL)
    started = time.perf_counter()
    fit = dg.fit_hypothesis(dg.compiled_rollout(preset, training_05[0].dt), dg.make_segments(training_05, 20.0, 5.0),
                            causes)
    terms = {k: [float(x) for x in v] for k, v in fit.terms.items()}
    log(f"  named {'+'.join(causes)}: {terms} ({time.perf_counter() - started:.0f} s)")
    info: dict[str, Any] = {"causes": list(causes), "terms": terms, "fit_s": time.perf_counter() - started}
    rollout = dg.extended_rollout(preset, DT, fit.terms)
    path.parent.mkdir(parents=True, exist_ok=True)
    export_module(path, rollout, greybox_metadata(preset, rollout, model_type=f"greybox+{causes[0]}",
                                                  training={"method": "named causes", "causes": list(causes)}),
                  vessel=preset)
    vessel, base = hybrid_fit.base_from_artifact(load_artifact(path), preset, training[0])
    if members == 0:
        return base, None, info
    config = hybrid_fit.HybridTraining(members=members, epochs=epochs, validation=(VAL_RUN,))
    hybrid, info["hybrid"] = hybrid_fit.train_residual(base, vessel, identification.prepare(vessel, training), training,
                                                       DT, config, progress=log)
    return base, hybrid, info


TRUE_TRACK = "true track (the simulator's ground truth scored as a model: the metric's own noise)"


@dataclass(frozen=True)
class TrackScore:
    """The parts of an evaluation.RecordingEvaluation turning_row reads, for a track that is not a model's."""

    turning: Any
    state_rmse: dict
    open_loop: None = None


def true_track_row(rec: Any, tracks: Any) -> dict:
    """The recording's ground truth (T, 6) scored against the reference like a prediction: what a perfect model
    gets, i.e. the reference's own error on these criteria."""
    from usv_predictor.analysis import evaluation as ev

    truth = ev.reference_series(rec, "truth")
    prediction = ev.Prediction(name=rec.name, reference="truth", t_s=rec.t_s - rec.t_s[0], controls=rec.controls,
                               measured=tracks.measured, predicted=truth, predicted_std=np.zeros_like(truth),
                               layout=rec.layout)
    turning = ev.compare_turning(prediction, ev.classify(rec).execute_time_s - float(rec.t_s[0]))
    return turning_row(TrackScore(turning, ev.state_rmse(prediction)))


def row_name(name: str, reference: str) -> str:
    """The table row of a model against a reference: the GNSS rows keep their names (the earlier tables')."""
    return name if reference == "gnss" else f"{name} [vs {reference}]"


def rows_of(models: dict[str, tuple[Any, int]], recordings: list, references: tuple[str, ...] = ("gnss",)
            ) -> dict[str, list[list[dict]]]:
    """model -> [recording][seed] turning rows; models: row name -> (rollout module, members): a grey box (1) is one
    row, a hybrid of E members gives '<name> (each member)' and '<name>, ensemble mean'; one set per reference
    (row_name), and for the measured references (gnss, smoothed) the true track's row (true_track_row)."""
    from usv_predictor.analysis.evaluation import evaluate_recording, reference_tracks

    out: dict[str, list[list[dict]]] = {}
    for rec in recordings:
        for reference in references:
            tracks = reference_tracks(rec, reference)
            if reference != "truth" and rec.truth is not None:
                out.setdefault(row_name(TRUE_TRACK, reference), []).append([true_track_row(rec, tracks)])
            for name, (module, members) in models.items():
                single = Single(module, name, DT)
                if members == 1:
                    out.setdefault(row_name(name, reference), []).append(
                        [turning_row(evaluate_recording(single, rec, reference, (30.0,), tracks=tracks))])
                    continue
                out.setdefault(row_name(f"{name} (each member)", reference), []).append(
                    [turning_row(evaluate_recording(Member(single, k), rec, reference, (30.0,), tracks=tracks))
                     for k in range(members)])
                out.setdefault(row_name(f"{name}, ensemble mean", reference), []).append(
                    [turning_row(evaluate_recording(single, rec, reference, (30.0,), tracks=tracks))])
    return out


def append_jsonl(path: Path | None, record: dict) -> None:
    """One line per finished (protocol, turn): a run stopped early still leaves its rows."""
    if path is None:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a") as f:
        f.write(json.dumps(record, default=float) + "\n")


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


def fit_models(args: argparse.Namespace, training: list, training_05: list, extended_path: Path
               ) -> tuple[dict[str, tuple[Any, int]], dict]:
    """The study's models fitted on `training` (the bases args.bases asks for): row name -> (module, members)."""
    models: dict[str, tuple[Any, int]] = {}
    info: dict[str, Any] = {}
    if "identified" in args.bases:
        grey, hybrid, info["identified"] = fit(training, args.members, args.epochs)
        models["grey box"] = (grey, 1)
        if hybrid is not None:
            models["hybrid"] = (hybrid, args.members)
    if "extended" in args.bases:
        extended_path.parent.mkdir(parents=True, exist_ok=True)
        calm, base, hybrid, info["extended"] = fit_extended(training, training_05, args.members, args.epochs,
                                                            extended_path, args.max_causes)
        models["calm-water preset"] = (calm, 1)
        if base is not None:
            models["extended grey box"] = (base, 1)
        if hybrid is not None:
            models["hybrid on extended"] = (hybrid, args.members)
        if args.named_causes:
            name = f"grey box + named {' + '.join(args.named_causes)}"
            named, hybrid, info["named"] = fit_named(training, training_05, tuple(args.named_causes),
                                                     args.named_members, args.epochs,
                                                     extended_path.with_name("named_" + extended_path.name))
            models[name] = (named, 1)
            if hybrid is not None:
                models[f"hybrid on {name}"] = (hybrid, args.named_members)
    return models, info


TITLES = {"paper": "paper protocol (every turn in the training data)",
          "held_out": "held-out protocol (leave one turn out)"}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=REPO / "out" / "study_hybrid")
    parser.add_argument("--members", type=int, default=5,
                        help="hybrid members = seeds (default 5; 0: the grey boxes only, no hybrid is trained)")
    parser.add_argument("--epochs", type=int, default=150, help="hybrid epochs at most (early stopping)")
    parser.add_argument("--protocols", nargs="+", default=["paper", "held_out"], choices=["paper", "held_out"])
    parser.add_argument("--turns", nargs="+", default=list(TESTS), choices=list(TESTS),
                        help="held-out protocol: the turns left out in turn (default all six)")
    parser.add_argument("--bases", nargs="+", default=["identified", "extended"], choices=["identified", "extended"],
                        help="the grey boxes (and hybrids on them): identified in the sea, and/or the diagnosed "
                             "extension of the preset (default both)")
    parser.add_argument("--references", nargs="+", default=["gnss"], choices=["gnss", "smoothed", "truth"],
                        help="what the tracks are scored against (analysis.evaluation.reference_tracks): the raw GNSS "
                             "track (default, the earlier tables), the same smoothed (EKF + RTS), the simulator's "
                             "ground truth; each adds its rows, the measured ones with the true track's row")
    parser.add_argument("--max-causes", type=int, default=2, help="the diagnosis' causes at most (default 2)")
    parser.add_argument("--named-causes", nargs="+", default=[], metavar="CAUSE",
                        help="with --bases extended: also the preset extended with these causes, named by the user "
                             "rather than selected by the diagnosis, fitted on the same data (e.g. current wave_drift "
                             "wind: the trial log reports the wind)")
    parser.add_argument("--named-members", type=int, default=0,
                        help="hybrid members on the named-causes grey box (default 0: none trained)")
    parser.add_argument("--jsonl", type=Path, help="append each finished turn's rows to this file (partial results)")
    parser.add_argument("--tables", type=Path, help="only print the tables of an earlier run's study.json")
    parser.add_argument("--tables-jsonl", type=Path, help="only print the held-out table of the turns a --jsonl holds")
    args = parser.parse_args(argv)
    if args.tables is not None:
        done = json.loads(args.tables.read_text())
        print("\n\n".join(table(TITLES[k], v) for k, v in done["protocols"].items()))
        return 0
    if args.tables_jsonl is not None:
        per_model: dict[str, dict[str, list]] = {}
        for line in args.tables_jsonl.read_text().splitlines():
            record = json.loads(line)
            for m, seeds in record["rows"].items():
                per_model.setdefault(m, {})[record["turn"]] = seeds
        turns = sorted({t for rows in per_model.values() for t in rows})
        complete = {m: rows for m, rows in per_model.items() if sorted(rows) == turns}
        print(f"turns: {' '.join(turns)}")
        print(table(TITLES["held_out"], {"rows": complete, "summary": {m: summarise(r) for m, r in complete.items()}}))
        return 0
    torch.set_num_threads(1)
    started = time.perf_counter()
    from usv_predictor.replay.identify import identification_recordings

    training = identification_recordings([TRAINING], DT)
    turns = {r.name: r for r in identification_recordings([SEA_TRIAL], DT)}
    tests = {t: turns[name] for t, name in TESTS.items()}
    if "extended" in args.bases:  # the diagnosis' suited step (analysis.diagnosis_steps: 0.5 s for jari_usv)
        training_05 = identification_recordings([TRAINING], 0.5)
        turns_05 = {r.name: r for r in identification_recordings([SEA_TRIAL], 0.5)}
        tests_05 = {t: turns_05[name] for t, name in TESTS.items()}
    study: dict[str, Any] = {"members": args.members, "epochs": args.epochs, "dt": DT, "target": TARGET,
                             "protocols": {}}
    text = []
    if "paper" in args.protocols:
        log("paper protocol: identify + train on bags/training and the six turns")
        models, info = fit_models(args, training + list(tests.values()),
                                  training_05 + list(tests_05.values()) if "extended" in args.bases else [],
                                  args.out / "extended_paper.pt")
        rows = rows_of(models, list(tests.values()), tuple(args.references))
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
            others_05 = [r for k, r in tests_05.items() if k != t] if "extended" in args.bases else []
            models, info = fit_models(args, training + others, (training_05 + others_05) if others_05 else [],
                                      args.out / f"extended_without_{t}.pt")
            infos[t] = info
            rows = rows_of(models, [rec], tuple(args.references))
            for m in rows:
                per_model.setdefault(m, {})[t] = rows[m][0]
            append_jsonl(args.jsonl, {"protocol": "held_out", "turn": t, "bag": rec.name, "members": args.members,
                                      "epochs": args.epochs, "rows": {m: rows[m][0] for m in rows}, "info": info,
                                      "elapsed_s": time.perf_counter() - started,
                                      "loadavg": Path("/proc/loadavg").read_text().split()[:3]})
            for m in rows:
                log(f"  ({t}) {m}: radius " + ", ".join(f"{r['errors']['radius_pct']:+.2f}" for r in rows[m][0])
                    + " %, drift angle " + ", ".join(f"{r['errors']['angle_deg']:+.1f}" if r['errors']['angle_deg']
                                                     is not None else "-" for r in rows[m][0])
                    + " deg, drift distance " + ", ".join(f"{r['errors']['distance_pct']:+.1f}" for r in rows[m][0])
                    + " %")
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
