"""A model on recorded manoeuvres: what `replay evaluate` and `replay report` do, from a typed EvaluationRequest.

    evaluate_bags    bags -> recordings at the model's step -> usv_predictor.analysis.evaluation (seed 000
                     Tables 7-8 metrics, closed-loop and open-loop errors), with the run's provenance
    evaluate         the same, saved with --output as evaluation.json + evaluation_series.npz (the time series
                     `replay report DIR/evaluation.json` draws from)
    report           an evaluation file or bags -> usv_predictor.analysis.reports.write_report

No bags: the shipped bags/sea_trial (calm twins skipped); no model: the shipped models/default.pt; the model
spec `physics[:VESSEL]` is the calm-water grey box of a preset (usv_predictor.models.loading). Bags are only read.
"""
from __future__ import annotations

import datetime
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from usv_predictor.errors import BagError, ConfigError, EvaluationError

if TYPE_CHECKING:
    from usv_predictor.analysis.evaluation import EvaluationResult
    from usv_predictor.physics.vessel import Vessel

EVALUATION_FILE = "evaluation.json"
SERIES_FILE = "evaluation_series.npz"
ROLLOUT_BUDGET_S = 5.0  # (s) default --rollout-budget: one rollout over the longest open-loop horizon, every member
#                         (the shipped DNN: ~2 ms; a grey box's unfused TorchScript: ~0.4 s); slower is refused at load
REFERENCES = ("gnss", "smoothed", "truth")  # the measured GNSS track and states, the same smoothed (EKF + RTS), or
# the simulator's ground truth (analysis.evaluation.reference_tracks); spelled here so that the CLI's parser does not
# import the analysis (torch): test_evaluation.py proves it equal to analysis.evaluation.REFERENCES


@dataclass(frozen=True)
class EvaluationRequest:
    """Which model on which bags, compared how (EvaluationError for values that cannot be evaluated)."""

    bags: tuple[Path, ...] = ()  # bags or directories of bags; () = the shipped bags/sea_trial
    model: str | None = None  # model spec (usv_predictor.models.loading); None = the shipped model
    dt: float | None = None  # step (s) to resample the bags at; must equal the model's (None: the model's)
    reference: str = "gnss"  # one of REFERENCES
    horizons_s: tuple[float, ...] = (10.0, 30.0, 60.0)  # open-loop horizons (s)
    stride_s: float = 5.0  # time between open-loop start points (s)
    include_calm: bool = False  # also read calm/ twins under bag directories
    config: Path | None = None  # predictor.yaml with the input topics (None: the shipped one)
    # the bags' vessel, resolved once by the command (given_vessel); None: the model's (embedded or its preset), else
    # the config's
    vessel: Vessel | None = None
    adaptive: bool = False  # also run the online estimator and the adaptive open loop (analysis/adaptive.py)
    fit_check: bool = True  # refuse a model that does not fit the bags at all (analysis/fit_check.py)
    scale: float = 1.0  # Froude scale L_bags / L_model: the bags are scaled to the model's size (data/recording.py)
    # (s) the longest a rollout over the longest horizon (or recording, if shorter) may take (models/loading.
    # check_deadline); a slower model file is refused, with the measured time, once the bags are read
    rollout_budget_s: float = ROLLOUT_BUDGET_S

    def __post_init__(self) -> None:
        if not all(math.isfinite(x) and x > 0.0 for x in (self.stride_s, *self.horizons_s)):
            raise EvaluationError(f"--stride {self.stride_s:g} and --horizons "
                                  f"{' '.join(f'{h:g}' for h in self.horizons_s)}"
                                  " must be finite and positive (s)")
        if not self.horizons_s:
            raise EvaluationError("--horizons needs at least one horizon (s)")
        if self.dt is not None and not (math.isfinite(self.dt) and self.dt > 0.0):
            raise EvaluationError(f"--dt {self.dt:g} must be finite and positive (s)")
        if not (math.isfinite(self.rollout_budget_s) and self.rollout_budget_s > 0.0):
            raise EvaluationError(f"--rollout-budget {self.rollout_budget_s:g} must be finite and positive (s)")
        if not (math.isfinite(self.scale) and self.scale > 0.0):
            raise EvaluationError(f"--scale {self.scale:g} must be finite and positive (L_bags / L_model)")
        if self.reference not in REFERENCES:
            raise EvaluationError(f"--reference {self.reference!r}: expected one of {', '.join(REFERENCES)}")


def default_bags() -> list[Path]:
    """The shipped sea-trial bags; BagError when they are missing."""
    from usv_predictor.config import package_share_path

    try:
        return [package_share_path("bags", "sea_trial")]
    except ConfigError as err:
        raise BagError(f"no bags given and the shipped bags/sea_trial is missing: {err}") from err


def _output_apart(request: EvaluationRequest, output: Path | None, writes: Sequence[str]) -> None:
    """The output directory is neither one of the bags read (the shipped ones when none are given) nor inside one,
    and none of the files it writes there (`writes`) is an input."""
    from usv_predictor.atomic import check_outputs

    if output is not None:
        outputs = {"--output": output, **{f"--output ({name})": output / name for name in writes}}
        check_outputs(outputs, [*(request.bags or default_bags()), request.model], {"--output"})


def given_vessel(vessel: str | None, model: str | None = None) -> Vessel | None:
    """`--vessel` resolved once at the command boundary (models/loading.resolve_vessel): a preset or a vessel file; a
    name that is no preset here but the name of the vessel the model file (`model`, None: the shipped one) embeds:
    that description (a model made for a boat whose file is not here); None when none is given."""
    from usv_predictor.models import loading

    if vessel is None:
        return None
    try:
        return loading.resolve_vessel(vessel)
    except ConfigError:
        if Path(vessel).suffix in (".yaml", ".yml") or loading.is_physics(model):
            raise
        from usv_predictor.models.artifact import read_files
        from usv_predictor.physics.vessel import vessel_from_dict

        path = Path(model).expanduser() if model else loading.default_model_path()
        description = read_files(path)[2] if path.is_file() else None
        if description is None or description.get("name") != vessel:
            raise
        return vessel_from_dict(description, source=f"model file {path}")


def evaluation_vessel(vessel: Vessel | None, model: Any, source: str) -> Vessel | None:
    """The vessel the bags are read and the model is checked with: `vessel` (given_vessel; refused in one line when
    the model embeds a description that differs: models/loading.model_vessel), else the description the model embeds,
    else the preset its metadata names; None for a model of before (name only) whose vessel is no preset here and no
    --vessel (the bags are then read with the config's vessel, the fit check has no length)."""
    from usv_predictor.models.loading import model_vessel, resolve_vessel

    if vessel is not None:
        if list(vessel.actuator_layout.control_names) != list(model.metadata.get("control_layout", [])):
            return vessel  # another layout altogether: bags_layout says so, naming both
        return model_vessel(model, vessel, source=f"model {source}")  # resolved already: checked against the model
    try:
        return resolve_vessel(model=model, source=f"model {source}")
    except ConfigError:
        if getattr(model, "embedded_vessel", None) is not None:
            raise
        return None


def bags_layout(vessel: Any, metadata: Mapping[str, Any], source: str, config: Path | None = None) -> Any:
    """The actuator layout the bags are read with: of `vessel` (evaluation_vessel), else of the config's vessel;
    EvaluationError (one line naming both) when the model's control_layout is not that layout's."""
    from usv_predictor.models.loading import resolve_vessel

    preset = vessel if vessel is not None else resolve_vessel(config_path=config)
    layout = preset.actuator_layout
    controls = list(metadata.get("control_layout", []))
    if controls != list(layout.control_names):
        raise EvaluationError(f"model {source} has control_layout {controls} but the bags of vessel {preset.name} have "
                              f"{layout.name} {list(layout.control_names)}: evaluate a model of that layout (or "
                              "give the bags' vessel)")
    return layout


def evaluate_bags(request: EvaluationRequest, progress: Callable[[str], None] = lambda _: None) -> EvaluationResult:
    """The EvaluationResult of the request, its `extra` holding the provenance (time, version, model, data)."""
    import numpy as np

    from usv_predictor import __version__
    from usv_predictor.analysis import evaluation
    from usv_predictor.models import loading
    from usv_predictor.replay.recordings import Pieces, load_recordings

    model = loading.load_model(request.model, dt=request.dt)
    dt = loading.model_dt(model)
    bags = list(request.bags) or default_bags()
    progress(f"model {model.metadata.get('model_id', '?')} ({model.metadata.get('model_type', '?')}), dt {dt:g} s; "
             f"reading {', '.join(map(str, bags))}")
    source = request.model or str(loading.default_model_path())
    vessel = evaluation_vessel(request.vessel, model, source)
    layout = bags_layout(vessel, model.metadata, source, config=request.config)
    recordings = load_recordings(bags, dt, config_path=request.config,
                                 pieces=Pieces(include_calm=request.include_calm, scale=request.scale),
                                 warn=lambda m: progress(f"warning: {m}"), progress=progress, layout=layout,
                                 vessel_name=vessel.name if vessel is not None else "")
    if not recordings:
        raise BagError(f"no usable recording in {', '.join(map(str, bags))} (see the warnings above)")
    if not loading.is_physics(request.model):  # a model file's code: timed over the longest horizon a recording has
        span_s = min(max(request.horizons_s), max(recording.duration_s for recording in recordings))
        loading.check_deadline(model, loading.RolloutDeadline(request.rollout_budget_s,
                                                              max(1, math.ceil(span_s / dt - 1e-9)),
                                                              "replay evaluate (--rollout-budget)"))
    check = model_fit_check(model, recordings, vessel)
    progress(check.summary())
    if request.fit_check:
        from usv_predictor.analysis.fit_check import require_fit

        require_fit(check)
        require_confirmed_scale(check, request.scale)
    result = evaluation.evaluate(model, recordings, request.reference, tuple(request.horizons_s), request.stride_s,
                                 progress=progress)
    if request.adaptive:
        result.extra["adaptive"] = adaptive_section(model, recordings, request, progress)
    result.extra.update({
        "fit_check": check.to_json(),
        "generated_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "software_version": __version__,
        "model_source": request.model or str(loading.default_model_path()),
        "data": {"bags": [str(b) for b in bags], "dt_s": dt, "reference": request.reference,
                 "froude_scale": request.scale,
                 "recordings": [{"name": r.name, "source": r.source, "duration_s": r.duration_s,
                                 "has_gnss": bool(np.isfinite(r.position).any()),
                                 "has_truth": r.truth is not None} for r in recordings]},
    })
    return result


def adaptive_section(model: object, recordings: Sequence[object], request: EvaluationRequest,
                     progress: Callable[[str], None] = lambda _: None) -> dict:
    """`--adaptive`: the online estimator (fitting/online.py) over each recording and the open-loop errors with
    its live estimate in the model's terms (analysis/adaptive.py), beside the plain ones. Tuned by the `online`
    section of the predictor config (--config), as the node is; `online.enabled` is the node's switch only."""
    from dataclasses import asdict

    from usv_predictor.analysis import adaptive
    from usv_predictor.config import load_predictor_config
    from usv_predictor.fitting.online import STATE_NAMES, STATE_UNITS, OnlineConfig

    config = OnlineConfig(**load_predictor_config(request.config).online)  # the node's `online` parameters
    runs = []
    for k, recording in enumerate(recordings):
        progress(f"[{k + 1}/{len(recordings)}] online estimate and adaptive open loop on {recording.name}")
        runs.append(adaptive.adaptive_open_loop(model, recording, request.reference, tuple(request.horizons_s),
                                                request.stride_s, config))
    applied = bool(runs) and runs[0].applied
    return {
        "method": "extended Kalman filter on the float grey box, states " + ", ".join(
            f"{n} ({u})" for n, u in zip(STATE_NAMES, STATE_UNITS)) + " (docs/online.md)",
        "applied": applied,
        "how": ("the live current_ne, yaw_rate_bias and resistance_change are set in the grey box's terms before "
                "each rollout" if applied else adaptive.NOT_APPLIED),
        "config": asdict(config),
        "summary": adaptive.summarise(runs, tuple(request.horizons_s)),
        "recordings": [run.to_json(recording.dt) for run, recording in zip(runs, recordings)],
    }


def model_fit_check(model, recordings: Sequence, vessel: Any = None) -> Any:
    """The fit check (usv_predictor.analysis.fit_check) of a loaded model on the recordings, with the length and top
    speed of `vessel` (default: evaluation_vessel of the model; None: speeds and yaw rates only)."""
    from usv_predictor.analysis.fit_check import check_fit

    meta = model.metadata
    if vessel is None:
        vessel = evaluation_vessel(None, model, str(meta.get("model_id", "?")))
    physics = str(meta.get("model_type", "")).startswith("physics")
    label = (f"the preset {meta.get('vessel')}" if physics
             else f"model {meta.get('model_id', '?')} ({meta.get('model_type', '?')}, vessel "
                  f"{meta.get('vessel', '?')})")
    return check_fit(model, recordings, vessel=vessel, label=label)


def require_confirmed_scale(check: Any, scale: float) -> None:
    """A Froude scale (--scale) is trusted only when the fit check compared the model's steady speed with the scaled
    bags' (a held, settled window): without one only the top-speed check ran, which cannot see a factor in the wrong
    direction (the scaled boat then merely runs slowly). EvaluationError in one line otherwise."""
    if scale != 1.0 and check.speed_ratio is None:
        raise EvaluationError(f"--scale {scale:g}: the scaled bags have no held, settled window (>= 5 s held, settled "
                              "over 10 s) where the fit check can compare the model's steady speed with theirs, so "
                              "the factor cannot be confirmed (a wrong direction only makes the boat slow); give bags "
                              "with a straight run or a held turn, or pass --no-fit-check to proceed anyway")


def save_evaluation(result: EvaluationResult, directory: Path) -> dict:
    """DIR/evaluation.json + DIR/evaluation_series.npz (each written atomically); returns the JSON written."""
    import numpy as np

    from usv_predictor.analysis.evaluation import series_arrays
    from usv_predictor.atomic import atomic_open, write_json_atomic

    with atomic_open(directory / SERIES_FILE, "wb") as out:
        np.savez_compressed(out, **series_arrays(result))
    data = dict(result.to_json(), series_file=SERIES_FILE)
    write_json_atomic(directory / EVALUATION_FILE, data)
    return data


def evaluate(request: EvaluationRequest, output: Path | None = None,
             progress: Callable[[str], None] = lambda _: None) -> dict:
    """The evaluation JSON of `replay evaluate`; with `output`, saved there with its time series."""
    _output_apart(request, output, (EVALUATION_FILE, SERIES_FILE))
    result = evaluate_bags(request, progress)
    if output is None:
        return result.to_json()
    data = save_evaluation(result, output)
    progress(f"wrote {output / EVALUATION_FILE} and {output / SERIES_FILE}")
    return data


def is_evaluation_file(inputs: Sequence[Path]) -> bool:
    """One .json input: an evaluation file of `replay evaluate --output` (anything else: bags)."""
    return len(inputs) == 1 and Path(inputs[0]).suffix == ".json"


def report(request: EvaluationRequest, output: Path, title: str,
           progress: Callable[[str], None] = lambda _: None) -> dict:
    """`replay report`: the report of an evaluation file (request.bags is one .json) or of the bags evaluated as
    `request` says, written into `output`."""
    from usv_predictor.analysis import reports

    _output_apart(request, output, (reports.REPORT_MD, reports.REPORT_JSON))
    if is_evaluation_file(request.bags):
        progress(f"reading evaluation {request.bags[0]}")
        data, predictions = reports.load_evaluation_file(request.bags[0], warn=progress)
    else:
        result = evaluate_bags(request, progress)
        data, predictions = result.to_json(), [r.prediction for r in result.recordings]
    return reports.write_report(data, predictions, output, title, progress)
