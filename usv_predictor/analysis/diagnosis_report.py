"""The diagnosis report: Markdown + PNG plots of the evidence, the tracks and the errors before/after."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from usv_predictor.atomic import atomic_open, write_failure
from usv_predictor.data.recording import Recording
from usv_predictor.errors import PlotError
from usv_predictor.physics.vessel import Vessel


def _fmt(value: Any, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "—"
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return str(value)


def _evidence_plot(out: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    from usv_predictor.analysis.plots import save_figure

    evidence = [e for e in out["evidence"] if e["heldout_loss"] is not None]  # a diverged fit (null) has no bar
    fig = Figure(figsize=(7.0, 3.2))
    ax = fig.add_subplot()
    names = [e["hypothesis"] for e in evidence]
    losses = [e["heldout_loss"] for e in evidence]
    colours = ["tab:red" if n == out["cause"] else ("tab:gray" if n == "none" else "tab:blue") for n in names]
    ax.barh(names[::-1], losses[::-1], color=colours[::-1])
    ax.set_xscale("log")
    ax.set_xlabel("held-out loss (mean squared error in noise units, log scale)")
    ax.set_title(f"Evidence: cause = {out['cause']}")
    fig.tight_layout()
    save_figure(fig, path)


def _track_plots(recordings: Sequence[Recording], vessel: Vessel, fit_terms: dict, path_tracks: Path,
                 path_errors: Path) -> list[dict]:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    from usv_predictor.analysis import evaluation
    from usv_predictor.analysis.diagnosis import extended_rollout
    from usv_predictor.analysis.plots import save_figure
    from usv_predictor.models.greybox import GreyBoxPredictor, greybox_metadata

    dt = recordings[0].dt
    models = {}
    for label, terms in (("calm-water model", {}), ("extended model", fit_terms)):
        rollout = extended_rollout(vessel, dt, terms)
        models[label] = GreyBoxPredictor(rollout, {**greybox_metadata(vessel, rollout), "model_id": label})
    n = len(recordings)
    cols = min(n, 3)
    rows = math.ceil(n / cols)
    tracks = Figure(figsize=(4.2 * cols, 4.0 * rows))
    errors = Figure(figsize=(7.0, 3.4))
    ax_err = errors.add_subplot()
    summary = []
    for i, rec in enumerate(recordings):
        ax = tracks.add_subplot(rows, cols, i + 1)
        row = {"name": rec.name}
        for (label, model), style in zip(models.items(), ("--", "-")):
            pred = evaluation.closed_loop(model, rec)
            if label == "calm-water model":
                ax.plot(pred.measured[:, 4], pred.measured[:, 3], "k.", ms=1.5, label="measured (GNSS)")
            ax.plot(pred.predicted[:, 4], pred.predicted[:, 3], style, lw=1.2, label=label)
            err = np.hypot(*(pred.predicted[:, 3:5] - pred.measured[:, 3:5]).T)
            ax_err.plot(pred.t_s, err, style, lw=1.0, color=f"C{i % 10}",  # one colour per manoeuvre
                        label=(f"{rec.name}" if label != "calm-water model" else None) if n <= 10 else None)
            final = float(err[np.isfinite(err)][-1]) if np.isfinite(err).any() else None
            row[f"{label.split()[0]}_final_position_error_m"] = final
        ax.set_title(rec.name, fontsize=9)
        ax.set_xlabel("east (m)")
        ax.set_ylabel("north (m)")
        ax.set_aspect("equal", adjustable="datalim")
        if i == 0:
            ax.legend(fontsize=7)
        summary.append(row)
    tracks.tight_layout()
    ax_err.set_xlabel("time (s)")
    ax_err.set_ylabel("closed-loop position error (m)")
    ax_err.set_title("Position error, calm-water (dashed) vs extended (solid)")
    if n <= 10:
        ax_err.legend(fontsize=6, ncol=2)
    errors.tight_layout()
    save_figure(tracks, path_tracks)
    save_figure(errors, path_errors)
    return summary


def write_report(directory: Path, out: dict, recordings: Sequence[Recording], vessel: Vessel, result: Any,
                 per_recording: dict | None) -> Path:
    """report.md + evidence.png, tracks.png, errors.png in `directory`; report.md written last, atomically."""
    directory = Path(directory)
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise PlotError(f"cannot write report {directory}: {write_failure(err)}") from err
    _evidence_plot(out, directory / "evidence.png")
    closed = _track_plots(recordings, vessel, result.fit.terms, directory / "tracks.png", directory / "errors.png")
    lines = [f"# Diagnosis: {out['cause']}", "", out["message"] + ".", ""]
    if out["confounded_with"]:
        lines += [f"**Confounded with:** {', '.join(out['confounded_with'])}.", ""]
    calm = out.get("calm_water_fit")
    if calm:
        lines += [f"Calm-water model before any hypothesis: held-out loss {_fmt(calm['heldout_loss'])} "
                  f"(noise units, 1 = "
                  f"errors at the noise scale), track error {_fmt(calm['heldout_track_error_m'])} m after "
                  f"{_fmt(calm['horizon_s'])} s.", ""]
    if out.get("fit_check"):
        lines += [f"Fit check: {out['fit_check']['verdict']} (speed ratio {_fmt(out['fit_check']['speed_ratio'])}, "
                  f"yaw-rate ratio {_fmt(out['fit_check']['yaw_rate_ratio'])}).", ""]
    for reason in out.get("mismatch_reasons", []):
        lines += [f"> model mismatch: {reason}", ""]
    for note in out["notes"]:
        lines += [f"> {note}", ""]
    lines += ["## Named cause", "", "| parameter | estimate | standard error |", "|---|---|---|"]
    for key, value in out["parameters"].items():
        lines.append(f"| {key} | {_fmt(value, 4)} | {_fmt(out['uncertainty'].get(key), 2)} |")
    for extra in out.get("additional_causes", []):
        lines += ["", f"**Further cause: {extra['cause']}** — removes {extra['gain'] * 100:.0f} % more of the held-out "
                  f"error (evidence {extra['evidence']:.1f}): " + ", ".join(
                      f"{k} {_fmt(v, 4)} ± {_fmt(extra['uncertainty'].get(k), 2)}"
                      for k, v in extra["parameters"].items())]
    further = out.get("further_candidate")
    if further:
        lines += ["", f"**Further candidate** — {further['reason']}; fitted beside the named cause(s): " + ", ".join(
            f"{k} {_fmt(v, 4)} ± {_fmt(further['uncertainty'].get(k), 2)}" for k, v in further["parameters"].items())]
    for dropped in out.get("dropped_causes", []):
        lines += ["", f"> {dropped} (backward elimination: every named cause must earn its place given the others)"]
    lines += ["", "## Evidence (held-out manoeuvres, two folds)", "",
              f"Folds: {' / '.join(', '.join(f) for f in out['folds'])}.", "",
              "| hypothesis | held-out loss | share of the calm-water error removed | evidence over calm water | "
              "winner's evidence over it | parameters fitted on fold 1 / fold 2 |", "|---|---|---|---|---|---|"]
    for e in out["evidence"]:
        params = " / ".join(", ".join(f"{k} {_fmt(v, 3)}" for k, v in p.items()) or "—" for p in e["fold_parameters"])
        share = ("— (the fit diverged)" if e["gain_vs_none"] is None
                 else f"{e['gain_vs_none'] * 100:.1f} %{e.get('measured_on', '')}")  # " in x_n, y_e": Effect.channels
        lines.append(f"| {e['hypothesis']} | {_fmt(e['heldout_loss'])} | {share} | "
                     f"{_fmt(e['evidence_vs_none'])} | {_fmt(e['evidence_of_best'])} | {params} |")
    lines += ["", "![evidence](evidence.png)", "", "## What the calm-water model gets wrong", "",
              "| quantity | value |", "|---|---|"]
    for key, value in (out["discrepancy"] or {}).items():
        if isinstance(value, dict):
            value = ", ".join(f"{k} {_fmt(v)}" for k, v in value.items())
        lines.append(f"| {key} | {_fmt(value)} |")
    lines += ["", "![tracks](tracks.png)", "", "![errors](errors.png)", ""]
    lines += ["| manoeuvre | closed-loop final position error, calm-water (m) | extended (m) |", "|---|---|---|"]
    for row in closed:
        lines.append(f"| {row['name']} | {_fmt(row.get('calm-water_final_position_error_m'))} | "
                     f"{_fmt(row.get('extended_final_position_error_m'))} |")
    if out.get("baseline"):
        lines += ["", "## Gain on held-out manoeuvres", "",
                  "Each fold predicted by the extension fitted on the other fold only.", "",
                  "| metric | calm-water | extended | relative improvement |", "|---|---|---|---|"]
        for key, before in out["baseline"].items():
            if key in out["gain"]:
                lines.append(f"| {key} | {_fmt(before)} | {_fmt(out['extended'][key])} | "
                             f"{out['gain'][key] * 100:.0f} % |")
    found = out.get("unexplained")
    if found:
        lines += ["", "## The extension of last resort: a learned residual (unexplained)", "",
                  f"No physical cause was named ({found['replaced']}): the calm-water model + a learned residual "
                  "(GeneralisingResidual ensemble, multi-step loss, bounded) was trained on each fold and measured "
                  "on the other, as a cause is. " + ("Accepted: the answer is `unexplained`." if found["accepted"] else
                                                      "Not accepted: " + "; ".join(found["reasons"]) + "."), "",
                  "| held-out | calm-water | with the learned residual | removed |", "|---|---|---|---|",
                  f"| loss (noise units) | {_fmt(found['calm_water_loss'])} | {_fmt(found['heldout_loss'])} | "
                  f"{_fmt(None if found['gain'] is None else found['gain'] * 100, 3)} % (evidence "
                  f"{_fmt(found['evidence'])}) |",
                  f"| track error at the segment end (m) | {_fmt(found['calm_water_track_error_m'])} | "
                  f"{_fmt(found['heldout_track_error_m'])} | "
                  f"{_fmt(None if found['track_gain'] is None else found['track_gain'] * 100, 3)} % |",
                  f"| open-loop position error after 30 s (m) | {_fmt(found['calm_water_open_loop_30s_m'])} | "
                  f"{_fmt(found['open_loop_30s_m'])} | "
                  f"{_fmt(None if found['open_loop_gain'] is None else found['open_loop_gain'] * 100, 3)} % |"]
    text = "\n".join(lines) + "\n"
    target = directory / "report.md"
    with atomic_open(target, "w", what="report") as f:
        f.write(text)
    return target
