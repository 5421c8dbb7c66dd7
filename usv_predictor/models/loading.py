"""One way to name and load a model for prediction: the node's `model_path` and the replay tool's `--model`.

A model spec is
    "" or None         the shipped model, models/default.pt in the package share (ModelError saying where it
                       was looked for when there is none);
    "physics[:VESSEL]" the calm-water MMG grey box of a vessel preset (usv_predictor.models.greybox), no file:
                       the physics baseline a learned model must beat at sea (only where `physics=True`);
    anything else      a model artifact file (usv_predictor.models.artifact), checked against `expect`
                       (metadata fields) and `dt` (the step the data is resampled at).
The vessel a model was made for: model_vessel (the description the artifact embeds, else the preset its metadata
names; a given vessel that differs from the embedded one is refused). Every failure is a ModelError naming the file
(or option) and what differs; a model whose code raises when
called (or answers in another shape, or NaN) is "model X fails when run: ..." (artifact.check_runs). torch is
imported only when a model is loaded, so command-line help stays light.

The calls into a model file's code at load time run in a guard thread (call_guarded) while the calling thread waits
with a timeout: a model whose code never returns is refused ("model X did not return within S s") instead of
hanging the caller, and the caller's main thread stays free to run its signal handlers (TorchScript releases the
GIL while it runs; a Python handler cannot run while the main thread itself is inside it). A RolloutDeadline adds a
timed rollout of the caller's horizon: a model slower than its budget (the node's cycle, 1 / rate_hz; `replay
evaluate --rollout-budget`) is refused with the measured time. A guard thread whose call never returns stays
alive, parked in the model's code, until the process ends; such a process must end with os._exit (a normal
interpreter exit aborts with the thread inside torch: "terminate called without an active exception", exit 134):
stuck_guard_threads() counts them.
"""
from __future__ import annotations

import atexit
import os
import sys
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn, Protocol, TypeVar

from usv_predictor import config
from usv_predictor.errors import ConfigError, ModelError
from usv_predictor.errors import ModelDidNotReturn as DidNotReturn
from usv_predictor.errors import ModelLoadAbandoned as Abandoned

if TYPE_CHECKING:
    from usv_predictor.models.artifact import ModelArtifact
    from usv_predictor.models.greybox import GreyBoxPredictor
    from usv_predictor.physics.vessel import Vessel

PHYSICS = "physics"  # the spec of the physics baseline, optionally ":VESSEL"
DEFAULT_MODEL = ("models", "default.pt")  # the shipped model, relative to the package share
DT_TOLERANCE_S = 1e-6  # two steps closer than this are the same step (s)
FIRST_CALL_S = 5.0  # (s) the longest a model's first two-step rollout may take: TorchScript profiles and optimises
#                     its first calls (the shipped DNN's file: 0.4 s here); a model still inside it is refused
GUARD_THREAD = "usv_predictor-model-guard"  # name of the threads call_guarded runs a model's code in
GUARD_POLL_S = 0.05  # (s) how often a guarded wait looks at `abandon` and the clock
TIMED_RUNS = 3  # timed rollouts at most: the best counts (the first may meet a busy core), stopped once one fits
OVERRUN_FACTOR = 4.0  # (-) a timed rollout still running after this many budgets (and FIRST_CALL_S) is given up on

T = TypeVar("T")


@dataclass(frozen=True)
class RolloutDeadline:
    """How long one rollout of the caller's horizon may take: the model is refused at load when it is slower."""

    budget_s: float  # (s) the longest a rollout of `steps` steps (one start state, every member) may take
    steps: int  # (-) steps of the timed rollout: the caller's horizon
    what: str  # what the budget is, in messages ("the node's cycle (1 / rate_hz 10 Hz)")

    def __post_init__(self) -> None:
        if not (self.budget_s > 0.0 and self.budget_s < float("inf")) or self.steps < 1:
            raise ModelError(f"rollout deadline {self.budget_s} s over {self.steps} steps: expected a finite budget "
                             "> 0 s and at least one step")


def call_guarded(fn: Callable[[], T], limit_s: float, what: str, abandon: Callable[[], bool] | None = None) -> T:
    """fn() run in a daemon guard thread while this thread waits, at most `limit_s` (s); its result, or what it raised.

    DidNotReturn "<what> did not return within <limit_s> s" when it runs longer (the thread is left parked in it:
    stuck_guard_threads), Abandoned as soon as abandon() is true. In the main thread the wait is interruptible:
    a signal handler that raises (KeyboardInterrupt, the replay tool's SIGTERM) ends it at once."""
    result: list[Any] = []
    failure: list[BaseException] = []
    done = threading.Event()

    def target() -> None:
        try:
            result.append(fn())
        except BaseException as err:  # noqa: BLE001 - handed to the waiting thread, which raises it
            failure.append(err)
        finally:
            done.set()

    started = time.perf_counter()
    threading.Thread(target=target, name=GUARD_THREAD, daemon=True).start()
    while not done.wait(GUARD_POLL_S):
        if abandon is not None and abandon():
            raise Abandoned(f"{what}: given up, the caller is stopping")
        if time.perf_counter() - started > limit_s:
            raise DidNotReturn(f"{what} did not return within {limit_s:g} s")
    if failure:
        raise failure[0]
    return result[0]


def stuck_guard_threads() -> int:
    """Guard threads still inside a model's code (a call that never returned): the process must end with
    os._exit."""
    return sum(1 for thread in threading.enumerate() if thread.name == GUARD_THREAD and thread.is_alive())


def exit_program(code: int) -> NoReturn:
    """End the process with `code` the way a normal exit would, without the interpreter's teardown: the standard
    streams flushed, the atexit handlers run (logging, the thread pools', multiprocessing's, numba's), then os._exit.
    For a program with a guard thread stuck in a model's code (the teardown aborts with it inside torch, exit 134),
    and for the node, whose teardown of torch alone takes 1.5 s on a loaded 2-core machine (a stop is due in 2 s)."""
    sys.stdout.flush()
    sys.stderr.flush()
    atexit._run_exitfuncs()  # what the interpreter runs at exit before its teardown, which os._exit skips
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def check_deadline(model: ModelArtifact, deadline: RolloutDeadline, abandon: Callable[[], bool] | None = None) -> float:
    """The best of up to TIMED_RUNS rollouts of deadline.steps steps from 1 m/s ahead, controls at zero (s), each
    guarded; ModelError naming the file, the measured time and the budget when even the best is slower."""
    import numpy as np

    state = np.array([[1.0, 0.0, 0.0, 0.0]])  # (1, 4) [u, v, r, engine]
    controls = np.zeros((1, deadline.steps, len(model.metadata["control_layout"])))  # (1, H, C)
    limit_s = max(FIRST_CALL_S, OVERRUN_FACTOR * deadline.budget_s)

    def timed() -> float:
        started = time.perf_counter()
        model.predict(state, controls)
        return time.perf_counter() - started

    best = float("inf")
    for _ in range(TIMED_RUNS):
        try:
            best = min(best, call_guarded(timed, limit_s, f"model {model.path}: a rollout of {deadline.steps} steps",
                                          abandon))
        except DidNotReturn as err:
            raise DidNotReturn(f"{err}: too slow for {deadline.what} (budget {deadline.budget_s:g} s)") from None
        if best <= deadline.budget_s:
            return best
    raise ModelError(f"model {model.path} is too slow for {deadline.what}: a rollout of {deadline.steps} steps takes "
                     f"{best:.3g} s (best of {TIMED_RUNS}), more than its budget of {deadline.budget_s:g} s")


class HasMetadata(Protocol):
    metadata: Mapping[str, Any]


def is_physics(spec: str | None) -> bool:
    """True for "physics" and "physics:VESSEL"."""
    return spec is not None and (spec == PHYSICS or spec.startswith(PHYSICS + ":"))


def default_model_path(option: str = "--model", physics: bool = True) -> Path:
    """The shipped model file; ModelError saying where it was looked for (and what to pass instead) without one."""
    try:
        return config.package_share_path(*DEFAULT_MODEL)
    except ConfigError as err:
        looked = ", ".join(str(root.joinpath(*DEFAULT_MODEL)) for root in config.share_roots())
        instead = (f", pass {option} PATH, or {option} physics for the physics baseline" if physics
                   else f" or set {option} to a model file")
        raise ModelError(f"no shipped model: {'/'.join(DEFAULT_MODEL)} does not exist (looked in {looked}); "
                         f"train one with `replay train`{instead}") from err


def model_dt(model: HasMetadata) -> float:
    """The model's step (s) from its metadata; ModelError when absent or not positive."""
    try:
        dt = float(model.metadata["dt"])
    except (KeyError, TypeError, ValueError) as err:
        raise ModelError(f"model metadata has no numeric 'dt' (s): {err}") from err
    if not dt > 0.0:
        raise ModelError(f"model metadata dt={dt} s must be > 0")
    return dt


def check_dt(model: HasMetadata, dt: float, what: str) -> None:
    """ModelError when the model's step differs from the data's (a model only works at its own dt)."""
    expected = model_dt(model)
    if abs(expected - dt) > DT_TOLERANCE_S:
        raise ModelError(f"model {model.metadata.get('model_id', '?')} has dt={expected:g} s but {what} "
                         f"has dt={dt:g} s; resample the data at {expected:g} s or use a model trained at {dt:g} s")


def physics_predictor(vessel: Vessel, dt: float) -> GreyBoxPredictor:
    """The calm-water physics baseline: the vessel's grey box (usv_predictor.models.greybox), no sea terms.

    It knows nothing of current, wind or waves, so it is the baseline a learned model must beat at sea. The
    recorded rudder angle and engine speed drive it as the actuator states (they are feedback, not commands).
    """
    from usv_predictor.models.greybox import greybox_predictor

    if not dt > 0.0:
        raise ModelError(f"physics predictor step dt={dt} s must be > 0")
    config.FLOAT_RANGES["dt"].check("dt", dt, "physics predictor step")
    return greybox_predictor(vessel, dt)


def resolve_vessel(given: str | Path | Vessel | None = None, *, model: HasMetadata | None = None,
                   config_path: str | Path | None = None, option: str = "--vessel",
                   source: str | None = None) -> Vessel:
    """The one vessel of a command or of the node, resolved once at its boundary; every library function below
    takes the Vessel.

    given: a preset name, a vessel YAML file or a Vessel; None: the model's (the description it embeds, else the
    preset its metadata names) or, without a model, the predictor config's `vessel` (config_path; None: the shipped
    config/predictor.yaml). With a model, a given vessel that differs from the description it embeds is refused
    (model_vessel: `option` and `source` name the given vessel and the model in that message).
    """
    from usv_predictor.physics.vessel import Vessel, load_vessel

    if model is not None:
        return model_vessel(model, given, option=option, source=source)
    if isinstance(given, Vessel):
        return given
    return load_vessel(given if given is not None else config.load_predictor_config(config_path).vessel)


def model_vessel(model: HasMetadata, given: str | Path | Vessel | None = None, *, option: str = "--vessel",
                 source: str | None = None) -> Vessel:
    """The vessel of a loaded model (an artifact or a physics predictor).

    given None: the description the artifact embeds, else (an artifact of before, which names its vessel only) the
    preset of that name (ConfigError naming it and saying to pass --vessel when there is none here).
    given (a preset name, a vessel file or a Vessel): that vessel; a name that is no preset here but the name of the
    embedded vessel is the embedded one (a node whose vessel file is not installed). When the artifact embeds a
    description and the given one differs in any field but the free text, ModelError in one line naming the fields
    (`option` says how the caller names the given vessel, `source` the model).
    """
    from usv_predictor.physics.vessel import (Vessel, description_differences, load_preset, load_vessel,
                                              vessel_preset_exists, vessel_to_dict)

    embedded: Vessel | None = getattr(model, "embedded_vessel", None)
    name = str(model.metadata.get("vessel", ""))
    label = source or f"model {model.metadata.get('model_id', '?')}"
    if given is None:
        if embedded is not None:
            return embedded
        try:
            return load_preset(name)  # a name from a file: a preset or nothing, never a path
        except ConfigError as err:
            raise ConfigError(f"{label} names vessel {name!r} but embeds no description (made before models carried "
                              f"one) and {err}: pass {option} FILE") from None
    if isinstance(given, Vessel):
        vessel = given
    elif embedded is not None and str(given) == embedded.name and not vessel_preset_exists(str(given)):
        return embedded
    else:
        vessel = load_vessel(given)
    if embedded is not None:
        diffs = description_differences(vessel_to_dict(embedded), vessel_to_dict(vessel), ("model", option))
        if diffs:
            shown = "; ".join(diffs[:6]) + (f"; and {len(diffs) - 6} more" if len(diffs) > 6 else "")
            raise ModelError(f"{label} was made for vessel {embedded.name!r} (the description it embeds), {option} "
                             f"{given if not isinstance(given, Vessel) else given.name} differs: {shown}")
    return vessel


def load_model(spec: str | None, *, dt: float | None = None, vessel: str | None = None,
               expect: Mapping[str, Any] | None = None, option: str = "--model", dt_option: str = "--dt",
               physics: bool = True, deadline: RolloutDeadline | None = None,
               abandon: Callable[[], bool] | None = None) -> ModelArtifact | GreyBoxPredictor:
    """The model a spec names (module docstring), checked; ModelError naming the file and what differs.

    dt: the step the data will be resampled at (None: the model's own); for the physics baseline its step
    (None: the config's). vessel: the preset of a bare "physics" (None: the config's). expect: metadata
    fields an artifact must have (usv_predictor.models.artifact.load_artifact). option / dt_option: how the
    caller names the spec and dt in messages (the node: "model_path"). physics=False reads "physics" as a file.
    deadline: a model file slower than it is refused (check_deadline; the physics baseline is the package's own
    code and is not timed). abandon: true when the caller is stopping (the guarded waits end with Abandoned).
    The first call of the file's code (artifact.check_runs) is guarded too, at most max(FIRST_CALL_S, the budget).
    """
    if physics and is_physics(spec):
        assert spec is not None
        name = spec.partition(":")[2] or vessel
        step = dt if dt is not None else config.load_predictor_config().dt
        return physics_predictor(resolve_vessel(name), step)
    path = Path(spec).expanduser() if spec else default_model_path(option, physics)
    if not path.is_file():
        raise ModelError(f"{option} {path}: no such model file")
    try:
        from usv_predictor.models.artifact import check_runs, load_artifact
    except ImportError as err:
        raise ModelError(f"{path}: cannot load model artifacts, usv_predictor.models.artifact is unavailable "
                         f"({err})") from err
    model = load_artifact(path, expect=expect)
    if dt is not None:
        check_dt(model, dt, f"{dt_option} for {path}")
    first_call_s = max(FIRST_CALL_S, deadline.budget_s if deadline is not None else 0.0)
    # a model whose code raises (or never returns) is refused here, naming the file, not in the middle of a run
    call_guarded(lambda: check_runs(model), first_call_s, f"model {path}: its first two-step rollout", abandon)
    fused = with_fused_rollout(model)
    if deadline is not None:
        check_deadline(fused, deadline, abandon)
    return fused


def with_fused_rollout(model: ModelArtifact) -> ModelArtifact:
    """A DNN artifact with its rollout fused for inference, checked equal to the file's own within float rounding, so
    that the node and `replay evaluate` run the same, faster code: the numpy rollout (models/dnn.numpy_rollout,
    NumpyDnnRollout), else the TorchScript one (models/dnn.fused_rollout, FusedDnnRollout). The file is not changed
    (its format neither): an artifact of any version is fused when loaded. A DNN file whose network cannot be fused,
    or whose fused rollout differs from its own, keeps its own module (inference_note says why); a grey box or hybrid
    runs the compiled kernel (with_kernel_rollout), a low-order model its compiled numpy form (with_nomoto_rollout)."""
    import dataclasses

    from usv_predictor.models.dnn import NUMPY_FORM, fused_rollout, numpy_rollout

    if str(model.metadata.get("model_type")) == "nomoto":
        return with_nomoto_rollout(model)
    if str(model.metadata.get("model_type")) != "dnn":
        return with_kernel_rollout(model)
    try:
        return dataclasses.replace(model, inference=numpy_rollout(model), inference_note=NUMPY_FORM)
    except ModelError as err:
        numpy_failure = str(err)
    try:
        fused = fused_rollout(model)
    except ModelError as err:
        return dataclasses.replace(model, inference_note=f"the file's rollout (not fused: {err}; {numpy_failure})")
    return dataclasses.replace(model, inference=fused,
                               inference_note=f"fused (models/dnn.FusedDnnRollout, frozen; {numpy_failure})")


def with_kernel_rollout(model: ModelArtifact) -> ModelArtifact:
    """A grey-box or hybrid artifact predicting with the compiled kernel (models/kernel_rollout.KernelRollout: its
    constants rebuilt from the file's module, as a DNN's fused rollout from its buffers), checked equal to the file's
    own rollout on a probe (kernel_rollout.check_equal); a module the kernel cannot read or that it does not reproduce
    keeps its own rollout, and inference_note says why (the node reports it on /diagnostics). Other families as
    they are."""
    import dataclasses

    from usv_predictor.models.kernel_rollout import KERNEL_FORM, KernelRollout, KernelUnavailable, check_equal

    if not hasattr(model.module, "hull_forces"):  # not a grey box (a learned model of another family)
        return model
    try:
        kernel = KernelRollout(model.module, live=True)  # live: the node's sea estimate sets the module's terms
        check_equal(kernel, model.module, model.metadata)
    except KernelUnavailable as err:
        return dataclasses.replace(model, inference_note=f"the file's rollout (not compiled: {err})")
    return dataclasses.replace(model, inference=kernel, inference_note=KERNEL_FORM)


def with_nomoto_rollout(model: ModelArtifact) -> ModelArtifact:
    """A low-order (Nomoto) artifact predicting with its compiled numpy form (models/nomoto.NumpyNomotoRollout, rebuilt
    from the metadata's coefficients), checked equal to the file's rollout within 1e-9 on a probe
    (nomoto.check_equal); metadata it cannot read, or a form that differs, keeps the file's rollout and
    inference_note says why."""
    import dataclasses

    from usv_predictor.models.nomoto import NUMPY_FORM, check_equal, numpy_form

    try:
        fast = numpy_form(model.metadata, f"model {model.path}")
        check_equal(fast, model.module)
    except (ModelError, ConfigError, KeyError, ValueError) as err:
        return dataclasses.replace(model, inference_note=f"the file's rollout (not compiled: {err})")
    return dataclasses.replace(model, inference=fast, inference_note=NUMPY_FORM)


def warm_up(vessel: Vessel, dt: float) -> float:
    """Compile (or load from numba's cache) the kernel entries (models/kernel_rollout.py) a process may call for this
    vessel whatever its model: the one-row-at-a-time rollout (the fit check's causes, terms per row) of its
    calm-water grey box, and the float model's forces and accelerations (the online estimator). Returns the seconds
    it took (~36 s the first time on a 2-core machine, well under one with a warm cache). The node calls it before
    its first cycle: compiling holds the GIL, and inside a cycle it would stall the node. A grey box's rows side by
    side (an MMG rudder boat's: ~12 s more the first time) are compiled by the node's model check, which predicts."""
    import time

    from usv_predictor.models.greybox import GreyBoxRollout
    from usv_predictor.models.kernel_rollout import KernelRollout
    from usv_predictor.physics.dynamics import ManoeuvringModel

    started = time.perf_counter()
    kernel = KernelRollout(GreyBoxRollout(vessel, dt))
    kernel.warm_up(side_by_side=False)
    model = ManoeuvringModel(vessel)
    model.accelerations(0.0, 1.0, 0.0, 0.0, 0.0, 0.0)
    model.loads(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
    return time.perf_counter() - started
