"""Reports: what `replay evaluate`, `replay report` and `replay identify` write besides their JSON.

    evaluation_table            the evaluation as a plain-text table (seed 000 Tables 7-8, one row per test)
    load_evaluation_file        an evaluation.json of `replay evaluate --output` and its time series
    write_report                report.md (seed 000 Tables 6-8 layouts, state and open-loop errors, figures),
                                report.json and the PNG figures (seed 000 Fig. 10-15) of an evaluation
    write_identification_report summary.md (coefficients, CIs, collinearity, CV) and force plots (seed 001 Fig. 13)

Every file is written to a temporary name and renamed (usv_predictor.atomic); report.md is written last.
Numbers come in as JSON (None for undefined) and are printed through `num`.
"""
from __future__ import annotations

import datetime
import math
import os
import re
import zipfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from usv_predictor.analysis.evaluation import COUNT_KEYS, Prediction, predictions_from_arrays
from usv_predictor.atomic import jsonable, write_json_atomic, write_text_atomic
from usv_predictor.bounded import load_json, regular_file
from usv_predictor.errors import EvaluationError

if TYPE_CHECKING:
    from usv_predictor.fitting.identification import IdentificationResult

REPORT_MD = "report.md"
REPORT_JSON = "report.json"
LETTERS = "abcdefghijklmnopqrstuvwxyz"


# ------------------------------------------------------------------ formatting


def num(value: Any, digits: int = 2, suffix: str = "") -> str:
    """A JSON number as the report prints it; '-' when undefined. The test reads tables back through this."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:.{digits}f}{suffix}"


_NUMBER = re.compile(r"^(-|[-+]?\d+(\.\d+)?%?( / [-+]?\d+(\.\d+)?|)?)$")


def table(header: list[str], rows: list[list[str]]) -> list[str]:
    """Markdown table; columns of numbers are right-aligned, text left."""
    numeric = [k > 0 and all(_NUMBER.match(row[k]) for row in rows if k < len(row)) for k in range(len(header))]
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---:" if n else "---" for n in numeric) + "|"]
    out += ["| " + " | ".join(row) + " |" for row in rows]
    return out + [""]


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "recording"


def _model_section(data: dict) -> list[str]:
    model = data.get("model", {})
    rows = [[key, f"`{model[key]}`"] for key in ("model_id", "model_type", "feature_set", "dt") if key in model]
    rows += [[k, f"`{v}`"] for k, v in sorted(model.items())
             if k not in ("model_id", "model_type", "feature_set", "dt")]
    if data.get("model_source"):
        rows.insert(0, ["file", f"`{data['model_source']}`"])
    return ["## Model", ""] + table(["item", "value"], rows)


def _data_section(data: dict, letters: dict[str, str]) -> list[str]:
    lines = ["## Data", "",
             f"Reference: **{data.get('reference', 'gnss')}** "
             + ("(measured GNSS track and measured u, v, r, heading)" if data.get("reference", "gnss") == "gnss"
                else "(ground truth of simulated bags)")
             + f"; step {num(data.get('data', {}).get('dt_s', None), 3)} s.", ""]
    rows = []
    for rec in data["recordings"]:
        rows.append([letters.get(rec["name"], ""), f"`{rec['name']}`", rec.get("manoeuvre_label", ""),
                     num(rec.get("duration_s"), 1), f"`{rec.get('source', '')}`"])
    return lines + table(["test", "recording", "manoeuvre (from the controls)", "duration (s)", "source"], rows)


def _summary_section(data: dict) -> list[str]:
    s = data["summary"]
    rows = [[key, num(value, 3)] for key, value in s.items() if key not in COUNT_KEYS]
    diverged = int(s.get("diverged_recordings") or 0), int(s.get("open_loop_diverged_windows") or 0)
    said = (f" The model's rollout diverged (NaN/inf) on {diverged[0]} recording(s) and in {diverged[1]} open-loop "
            "window(s): their metrics are undefined or left out (the recordings' notes say where)." if any(diverged)
            else "")
    return ["## Summary", "",
            f"{int(s.get('recordings') or 0)} recordings: {int(s.get('turning_circles') or 0)} turning circles, "
            f"{int(s.get('zigzags') or 0)} zig-zags. Errors are predicted - measured: relative (%) for lengths, "
            f"absolute (deg) for angles.{said}", ""] + table(["metric", "value"], rows)


def _turning_tables(turning: list[dict], letters: dict[str, str]) -> list[str]:
    """Seed 000 Table 7 (radius) and Table 8 (drift) layouts: tests as columns."""
    head = ["Test indices"] + [f"({letters[r['name']]})" for r in turning]

    def row(label: str, section: str, key: str, digits: int = 2, suffix: str = "") -> list[str]:
        return [label] + [num(r["turning"][section].get(key), digits, suffix) for r in turning]  # older files: -

    t7 = [row("Measured radius eq. 29 (m)", "measured", "turning_radius_m"),
          row("Predicted radius eq. 29 (m)", "predicted", "turning_radius_m"),
          row("Relative error of radius", "errors", "turning_radius_rel_pct", 2, "%"),
          row("Measured steady-circle radius (m)", "measured", "steady_turning_radius_m"),
          row("Predicted steady-circle radius (m)", "predicted", "steady_turning_radius_m"),
          row("Relative error of steady radius", "errors", "steady_turning_radius_rel_pct", 2, "%")]
    t8 = [row("Measured drift direction (deg, toward)", "measured", "drift_direction_deg"),
          row("Predicted drift direction (deg, toward)", "predicted", "drift_direction_deg"),
          row("Absolute error of angle (deg)", "errors", "drift_direction_abs_deg"),
          row("Measured drift angle, eq. 28 reading (deg)", "measured", "drift_angle_seed_eq28_deg"),
          row("Predicted drift angle, eq. 28 reading (deg)", "predicted", "drift_angle_seed_eq28_deg"),
          row("Measured drift distance (m)", "measured", "drift_distance_m"),
          row("Predicted drift distance (m)", "predicted", "drift_distance_m"),
          row("Relative error of drift distance", "errors", "drift_distance_rel_pct", 2, "%")]
    imo = [row("Measured advance (m)", "measured", "advance_m"),
           row("Predicted advance (m)", "predicted", "advance_m"),
           row("Relative error of advance", "errors", "advance_rel_pct", 2, "%"),
           row("Measured transfer (m)", "measured", "transfer_m"),
           row("Predicted transfer (m)", "predicted", "transfer_m"),
           row("Relative error of transfer", "errors", "transfer_rel_pct", 2, "%"),
           row("Measured tactical diameter (m)", "measured", "tactical_diameter_m"),
           row("Predicted tactical diameter (m)", "predicted", "tactical_diameter_m"),
           row("Relative error of tactical diameter", "errors", "tactical_diameter_rel_pct", 2, "%")]
    return (["### Turning radius (seed 000 Table 7 layout)", ""] + table(head, t7)
            + ["### Drift angle and drift distance (seed 000 Table 8 layout)", "",
               "Drift direction: compass, clockwise from north, the direction the track drifts toward (eq. 28 "
               "averaged as unit vectors); the eq. 28 reading is the same angle measured from east toward north, "
               "as seed 000 Table 4 lists it.", ""] + table(head, t8)
            + ["### IMO turning-circle criteria", ""] + table(head, imo))


def _per_test_section(rec: dict, letter: str, figures: dict[str, list[str]]) -> list[str]:
    """Seed 000 Table 6 layout (original vs predicted) for one test, with its figures."""
    lines = [f"### ({letter}) {rec['manoeuvre_label']} — `{rec['name']}`", ""] if letter else \
        [f"### {rec['manoeuvre_label']} — `{rec['name']}`", ""]
    turning, zigzag = rec.get("turning"), rec.get("zigzag")
    if turning:
        m, p = turning["measured"], turning["predicted"]
        rows = [["Drift direction (deg, toward)", num(m["drift_direction_deg"]), num(p["drift_direction_deg"])],
                ["Drift distance (m)", num(m["drift_distance_m"]), num(p["drift_distance_m"])],
                ["Turning radius eq. 29 (m)", num(m["turning_radius_m"]), num(p["turning_radius_m"])],
                ["Steady-circle radius (m)", num(m["steady_turning_radius_m"]), num(p["steady_turning_radius_m"])],
                ["Advance (m)", num(m["advance_m"]), num(p["advance_m"])],
                ["Tactical diameter (m)", num(m["tactical_diameter_m"]), num(p["tactical_diameter_m"])]]
        lines += table(["Dataset (seed 000 Table 6 layout)", "Original data", "Predicted data"], rows)
    if zigzag:
        m, p, e = zigzag["measured"], zigzag["predicted"], zigzag["errors"]
        rows = [["First overshoot (deg)", num(m["first_overshoot_deg"]), num(p["first_overshoot_deg"]),
                 num(e["first_overshoot_abs_deg"])],
                ["Second overshoot (deg)", num(m["second_overshoot_deg"]), num(p["second_overshoot_deg"]),
                 num(e["second_overshoot_abs_deg"])]]
        lines += table(["Zig-zag (ITTC)", "Measured", "Predicted", "Error (deg)"], rows)
    for figure in figures.get(rec["name"], []):
        lines += [f"![{figure}]({figure})", ""]
    notes = [*rec.get("notes", []), *(turning or {}).get("notes", []), *(zigzag or {}).get("notes", [])]
    lines += [f"- note: {n}" for n in notes] + ([""] if notes else [])
    return lines


def _state_errors_section(data: dict, letters: dict[str, str]) -> list[str]:
    rows = []
    for rec in data["recordings"]:
        e = rec["closed_loop_rmse"]
        rows.append([letters.get(rec["name"], "") or f"`{rec['name']}`", num(e["u_mps"], 3), num(e["v_mps"], 3),
                     num(e["r_deg_s"], 3), num(e["psi_deg"], 2), num(e["position_m"], 2),
                     num(e["final_position_error_m"], 2)])
    return (["## Closed-loop state errors (whole recording, no measurement feedback)", ""]
            + table(["test", "RMSE u (m/s)", "RMSE v (m/s)", "RMSE r (deg/s)", "RMSE heading (deg)",
                     "RMSE position (m)", "final position error (m)"], rows))


def _open_loop_section(data: dict, letters: dict[str, str], figure: str | None) -> list[str]:
    horizons = data.get("open_loop_horizons_s", [])
    rows = []
    for rec in data["recordings"]:
        loop = rec.get("open_loop")
        label = letters.get(rec["name"], "") or f"`{rec['name']}`"
        if not loop:
            rows.append([label, "0"] + ["-"] * len(horizons))
            continue
        by_h = {h["horizon_s"]: h for h in loop["horizons"]}
        rows.append([label, str(loop["start_points"])] + [
            f"{num(by_h[h]['mean_m'])} / {num(by_h[h]['p95_m'])}" if h in by_h else "-" for h in horizons])
    summary = data["summary"]
    rows.append(["all (pooled mean)", ""] + [num(summary.get(f"mean_position_error_after_{h:g}s_m")) for h in horizons])
    lines = ["## Open-loop position error", "",
             "Rollouts from start points every few seconds without measurement feedback; mean / 95th percentile "
             "of the horizontal position error (m) at each horizon.", ""]
    lines += table(["test", "start points"] + [f"after {h:g} s (m)" for h in horizons], rows)
    if figure:
        lines += [f"![open-loop error]({figure})", ""]
    return lines


# ------------------------------------------------------------------ figures and files


def evaluation_table(result: dict) -> str:
    """Seed 000 Tables 7-8 per test (one row each): radius, drift direction, drift distance, open-loop error."""
    horizons = result.get("open_loop_horizons_s", [])
    mid = f"{horizons[len(horizons) // 2]:g}" if horizons else None
    head = (f"{'test':<36} {'kind':<15} | {'radius m':>8} {'pred':>7} {'err':>8} | {'drift deg':>9} {'pred':>7}"
            f" {'err':>7} | {'drift m':>7} {'pred':>6} {'err':>8}" + (f" | OL {mid} s m" if mid else ""))
    lines = [f"model {result['model'].get('model_id', '?')} ({result['model'].get('model_type', '?')}), "
             f"reference {result['reference']}", head, "-" * len(head)]
    for rec in result["recordings"]:
        row = f"{rec['name'][-36:]:<36} {rec['manoeuvre']['kind']:<15} |"
        turning = rec.get("turning")
        if turning:
            m, p, e = turning["measured"], turning["predicted"], turning["errors"]
            row += (f" {num(m['turning_radius_m']):>8} {num(p['turning_radius_m']):>7}"
                    f" {num(e['turning_radius_rel_pct'], 2, '%'):>8} |"
                    f" {num(m['drift_direction_deg']):>9} {num(p['drift_direction_deg']):>7}"
                    f" {num(e['drift_direction_abs_deg']):>7} |"
                    f" {num(m['drift_distance_m']):>7} {num(p['drift_distance_m']):>6}"
                    f" {num(e['drift_distance_rel_pct'], 2, '%'):>8}")
        else:
            row += f" {'':>8} {'':>7} {'':>8} | {'':>9} {'':>7} {'':>7} | {'':>7} {'':>6} {'':>8}"
        if mid:
            loop = rec.get("open_loop") or {}
            row += f" | {num(loop.get(f'position_error_after_{mid}s_m')):>9}"
        lines.append(row)
    s = result["summary"]
    lines.append("-" * len(head))
    lines.append(f"max |rel. error| radius {num(s.get('max_abs_turning_radius_rel_error_pct'), 2, '%')}, "
                 f"max |error| drift direction {num(s.get('max_abs_drift_direction_error_deg'), 2, ' deg')}, "
                 f"max |rel. error| drift distance {num(s.get('max_abs_drift_distance_rel_error_pct'), 2, '%')}")
    lines.append("mean open-loop position error: " + ", ".join(
        f"{h:g} s {num(s.get(f'mean_position_error_after_{h:g}s_m'), 2, ' m')}" for h in horizons))
    for rec in result["recordings"]:  # a diverged rollout has no metric to show: say where it went
        went = rec.get("diverged")
        windows = (rec.get("open_loop") or {}).get("diverged_start_points") or 0
        if went or windows:
            closed = (f"closed loop at {went['at_s']:.1f} s of {went['duration_s']:.1f} s" if went
                      else "closed loop finite")
            lines.append(f"diverged (NaN/inf): {rec['name']} ({rec.get('manoeuvre_label', rec['manoeuvre']['kind'])}): "
                         f"{closed}; open loop {windows} of {(rec.get('open_loop') or {}).get('start_points', 0)} "
                         "windows")
    return "\n".join(lines)


# ------------------------------------------------------------------ evaluation files and reports


class _Optional:
    """A schema entry that may be absent (and, with null=True, null)."""

    def __init__(self, spec: Any, null: bool = False) -> None:
        self.spec = spec
        self.null = null


NUMBER = "number"  # a JSON number or null (undefined); never a bool
TEXT = "text"
_NUMBERS: Any = {str: NUMBER}  # a mapping of any keys to numbers (or nulls)
_COMPARISON = {"measured": _NUMBERS, "predicted": _NUMBERS, "errors": _NUMBERS, "notes": _Optional([TEXT])}
_TURNING_KEYS = ("turning_radius_m", "steady_turning_radius_m", "drift_direction_deg", "drift_distance_m",
                 "advance_m", "tactical_diameter_m")
_RECORDING = {
    "name": TEXT, "manoeuvre_label": TEXT, "manoeuvre": {"kind": TEXT}, "source": _Optional(TEXT),
    "duration_s": _Optional(NUMBER), "notes": _Optional([TEXT]),
    "closed_loop_rmse": {key: NUMBER for key in ("u_mps", "v_mps", "r_deg_s", "psi_deg", "position_m",
                                                 "final_position_error_m")},
    "turning": _Optional(dict(_COMPARISON, measured={key: NUMBER for key in _TURNING_KEYS},
                              predicted={key: NUMBER for key in _TURNING_KEYS}), null=True),
    "zigzag": _Optional(_COMPARISON, null=True),
    "open_loop": _Optional({"start_points": NUMBER, "step_s": NUMBER, "mean_error_by_step_m": [NUMBER],
                            "horizons": [{"horizon_s": NUMBER, "mean_m": NUMBER, "p95_m": NUMBER}]}, null=True),
}
EVALUATION_SCHEMA = {"recordings": [_RECORDING], "summary": _NUMBERS, "model": _Optional({str: object}),
                     "data": _Optional({str: object}), "reference": _Optional(TEXT),
                     "open_loop_horizons_s": _Optional([NUMBER]), "series_file": _Optional(TEXT, null=True)}


def _check_shape(value: Any, spec: Any, where: str) -> None:
    """EvaluationError naming the field (`recordings[0].turning.measured`) whose value does not fit `spec`."""
    def wrong(expected: str) -> EvaluationError:
        found = "null" if value is None else type(value).__name__
        return EvaluationError(f"field {where or '(top level)'} is {found}, expected {expected}")

    if isinstance(spec, _Optional):
        if value is not None or not spec.null:
            _check_shape(value, spec.spec, where)
    elif spec == NUMBER:
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                  or not math.isfinite(value)):
            raise wrong("a finite number or null")
    elif spec == TEXT:
        if not isinstance(value, str):
            raise wrong("a string")
    elif spec is object:
        return
    elif isinstance(spec, list):
        if not isinstance(value, list):
            raise wrong("a list")
        for k, item in enumerate(value):
            _check_shape(item, spec[0], f"{where}[{k}]")
    elif isinstance(spec, dict):
        if not isinstance(value, dict):
            raise wrong("an object")
        if list(spec) == [str]:  # any keys, one kind of value
            for key, item in value.items():
                _check_shape(item, spec[str], f"{where}.{key}" if where else key)
            return
        for key, item_spec in spec.items():
            if key not in value:
                if isinstance(item_spec, _Optional):
                    continue
                raise EvaluationError(f"field {where + '.' if where else ''}{key} is missing")
            _check_shape(value[key], item_spec, f"{where}.{key}" if where else key)


SERIES_FILE_BYTES = 1 << 40  # bounded by the disk, not by us (bytes)


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a JSON number")


def load_evaluation_file(path: Path, warn: Callable[[str], None] = lambda _: None) -> tuple[dict, list | None]:
    """(evaluation JSON, predictions or None when its series file is absent: `warn` says so).

    The file is checked against EVALUATION_SCHEMA first (what the report reads): a null section, a string where a
    number belongs, a missing field is an EvaluationError naming the file and the field."""
    data = load_json(path, "evaluation file", EvaluationError, parse_constant=_no_constant)
    if not isinstance(data, dict) or not isinstance(data.get("recordings"), list) or "summary" not in data:
        raise EvaluationError(f"{path}: not an evaluation file of `replay evaluate` (no 'recordings' and 'summary')")
    try:
        _check_shape(data, EVALUATION_SCHEMA, "")
    except EvaluationError as err:
        raise EvaluationError(f"{path}: not an evaluation file of `replay evaluate`: {err}") from err
    series = data.get("series_file")
    if not series:
        warn(f"warning: {path} names no series file (written by `replay evaluate --output DIR`); no track figures")
        return data, None
    series_path = path.parent / series
    if os.path.lexists(series_path):  # a FIFO or a device would block np.load or never end
        regular_file(series_path, f"the time series of {path}", EvaluationError, SERIES_FILE_BYTES)
    try:
        with np.load(series_path) as arrays:
            loaded = {k: arrays[k] for k in arrays.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as err:
        raise EvaluationError(f"{series_path}: cannot read the time series of {path} ({err})") from err
    names = [r["name"] for r in data["recordings"]]
    return data, predictions_from_arrays(loaded, names, data.get("reference", "gnss"))


def draw_figures(data: dict, predictions: list | None, out: Path, title: str) -> tuple[dict[str, list[str]], list[str]]:
    """PNG figures in `out`; returns ({recording name: [file, ...]}, [summary files])."""
    from usv_predictor.analysis import plots

    per_recording: dict[str, list[str]] = {}
    if predictions is not None:
        for k, (rec, prediction) in enumerate(zip(data["recordings"], predictions)):
            turning = rec.get("turning") or {}
            direction = (turning.get("measured") or {}).get("drift_direction_deg")
            label = rec.get("manoeuvre_label", rec["name"])
            stem = f"{k + 1:02d}_{_slug(rec['name'])}"
            files = {f"track_{stem}.png": plots.track_figure(prediction, f"{rec['name']}: {label}", direction),
                     f"position_{stem}.png": plots.rotated_position_figure(prediction, f"{rec['name']}: {label}",
                                                                           direction),
                     f"states_{stem}.png": plots.states_figure(prediction, f"{rec['name']}: {label}")}
            for name, fig in files.items():
                plots.save_figure(fig, out / name)
            per_recording[rec["name"]] = list(files)
    summary: list[str] = []
    curves = [plots.OpenLoopCurve(rec["name"], rec["open_loop"]["step_s"], rec["open_loop"]["mean_error_by_step_m"],
                                  [(h["horizon_s"], h["mean_m"]) for h in rec["open_loop"]["horizons"]])
              for rec in data["recordings"] if rec.get("open_loop")]
    if curves:
        plots.save_figure(plots.open_loop_figure(curves, title), out / "open_loop.png")
        summary.append("open_loop.png")
    turning = [r for r in data["recordings"] if r.get("turning")]
    if turning:
        rows = [plots.TurningRow(
            f"({LETTERS[k % 26]})",
            (r["turning"]["measured"]["turning_radius_m"], r["turning"]["predicted"]["turning_radius_m"]),
            (r["turning"]["measured"]["drift_direction_deg"], r["turning"]["predicted"]["drift_direction_deg"]),
            (r["turning"]["measured"]["drift_distance_m"], r["turning"]["predicted"]["drift_distance_m"]))
            for k, r in enumerate(turning)]
        plots.save_figure(plots.turning_summary_figure(rows, title), out / "turning_summary.png")
        summary.append("turning_summary.png")
    return per_recording, summary


def render_markdown(data: dict, title: str, figures: dict[str, list[str]], summary_figures: list[str]) -> str:
    turning = [r for r in data["recordings"] if r.get("turning")]
    letters = {r["name"]: LETTERS[k % 26] for k, r in enumerate(turning)}
    model = data.get("model", {})
    lines = [f"# {title}", "",
             f"Generated {data.get('report_generated_utc', '?')} by usv_predictor {data.get('software_version', '?')}"
             f" (evaluation of {data.get('generated_utc', '?')}). Model **{model.get('model_id', '?')}** "
             f"({model.get('model_type', '?')}; features: {model.get('feature_set', '?')}) on "
             f"{len(data['recordings'])} recording(s), reference {data.get('reference', 'gnss')}.", ""]
    lines += _model_section(data) + _data_section(data, letters) + _summary_section(data)
    if turning:
        lines += ["## Turning tests", ""] + _turning_tables(turning, letters)
        if "turning_summary.png" in summary_figures:
            lines += ["![turning summary](turning_summary.png)", ""]
    lines += ["## Tests", ""]
    for rec in data["recordings"]:
        lines += _per_test_section(rec, letters.get(rec["name"], ""), figures)
    if not figures:
        lines += ["(No track figures: the evaluation file came without its time series.)", ""]
    lines += _state_errors_section(data, letters)
    lines += _open_loop_section(data, letters, "open_loop.png" if "open_loop.png" in summary_figures else None)
    return "\n".join(lines)


def write_report(data: Mapping[str, Any], predictions: Sequence[Prediction] | None, out: Path, title: str,
                 progress: Callable[[str], None] = lambda _: None) -> dict:
    """report.md, report.json and the figures of an evaluation (JSON of EvaluationResult.to_json) in `out`.

    predictions: the time series of the recordings (None: no track figures). Returns the command's result.
    """
    data = dict(jsonable(dict(data)),
                report_generated_utc=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"))
    data.pop("series_file", None)
    figures, summary_figures = draw_figures(data, predictions, out, title)
    data["figures"] = {"per_recording": figures, "summary": summary_figures}
    write_json_atomic(out / REPORT_JSON, data)
    write_text_atomic(out / REPORT_MD, render_markdown(data, title, figures, summary_figures))
    progress(f"wrote {out / REPORT_MD}, {out / REPORT_JSON} and "
             f"{sum(map(len, figures.values())) + len(summary_figures)} "
             "figures")
    return {"report": str(out / REPORT_MD), "json": str(out / REPORT_JSON), "figures": data["figures"],
            "summary": data["summary"]}


# ------------------------------------------------------------------ identification


def write_identification_report(directory: Path, result: IdentificationResult, out: Mapping[str, Any]) -> Path:
    """summary.md (coefficients, CIs, collinearity, CV) and forces_<k>.png for each manoeuvre; out: the result of
    `replay identify` (model, model_type, model_id, training_data_sha256)."""
    from usv_predictor.analysis import plots

    lines = [f"# Grey-box identification: {result.vessel.name}", "",
             f"Model `{out['model']}` ({out['model_type']}, id `{out['model_id']}`), structure **{result.structure}**, "
             f"prior policy **{result.fit.prior_policy}**, data sha256 `{out['training_data_sha256'][:16]}`.", "",
             "Manoeuvres: " + ", ".join(d.name for d in result.data), "",
             f"## Coefficients ({'non-dimensional' if result.vessel.hull_model_name == 'mmg' else 'SI'} hull terms, "
             "thrust gains in N; 95 % CI)", "", "| name | estimate | 95 % CI | prior | status |",
             "|---|---|---|---|---|"]
    for c in result.coefficients():
        lines.append(f"| {c.name} | {c.estimate:+.5f} | [{c.ci95[0]:+.5f}, {c.ci95[1]:+.5f}] | {c.prior:+.5f} "
                     f"| {c.status} |")
    used = result.prior_used()
    lines += ["", "Not determined by these manoeuvres; prior used: " + (", ".join(used) if used else "none") + "."]
    if used:
        from usv_predictor.fitting.identification import trials_text

        lines[-1] += f" The trials that would determine them: {trials_text(used, result.trials)}."
    ex = result.excitation()
    if ex["beta_deg_p99"] is not None:
        lines += ["",
                  f"Excitation (99th percentiles): |beta| {ex['beta_deg_p99']:.1f} deg, |v'| {ex['v_prime_p99']:.3f}, "
                      f"|r'| {ex['r_prime_p99']:.3f}: {ex['note']}."]
    lines += ["", "## Collinearity", ""]
    for e in result.fit.equations:
        pairs = ", ".join(f"{a}~{b} ({rho:+.2f})" for a, b, rho in e.collinearity.pairs) or "none"
        lines.append(f"- {e.equation}: condition number {e.collinearity.condition_number:.3g}; |rho| > 0.9: {pairs}")
    lines += ["", "## Cross-validation (leave one manoeuvre out, hull force NMSE)", ""]
    for cv in result.cross_validation:
        per = ", ".join(f"{k} {v:.4f}" for k, v in cv.per_equation.items())
        lines.append(f"- {cv.structure}: {cv.score:.4f} ({per})")
    lines += ["", "## Notes", ""] + [f"- {n}" for n in result.notes] + ["", "## Force decomposition (seed 001 Fig. 13)",
                                                                        ""]
    for k, d in enumerate(result.data):
        name = f"forces_{k}.png"
        plots.save_figure(plots.force_decomposition_figure(result, k), directory / name)
        lines.append(f"![{d.name}]({name})")
    path = directory / "summary.md"
    write_text_atomic(path, "\n".join(lines) + "\n", "report")
    return path
