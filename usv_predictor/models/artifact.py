"""The model artifact: ONE TorchScript file (a closed-loop rollout) whose extra file carries the metadata.

This module is the file format only; each model family (models/dnn.py, models/greybox.py, models/hybrid.py)
builds its rollout module and its metadata and writes them through export_module(). Every family's scripted
module has the same interface (what the node, evaluate and diagnose call; loading needs torch only):

    forward(state (B, 4) [u, v, r, psi], controls (B, H, C) in the vessel's control layout) -> (E, B, H, 6)

    out[e, b, k] = [u, v, r, x_n, y_e, psi] at time (k+1) dt after the start, by ensemble member e;
    positions in NED relative to the start position (0, 0), psi continuous (not wrapped).
    controls[:, k] is the control at step k (physics/actuators.py names its columns: `control_layout`).
    E = ensemble size (1 for a single model).

Metadata (extra file `metadata.json`, format `usv_predictor.model/1`): see REQUIRED_KEYS and export_module().
The vessel (extra file `vessel.json`): the whole description of the vessel the model was made for, as its vessel file
reads (physics/vessel.vessel_to_dict: geometry, hull, actuators, ...), canonical JSON whose sha256 is the metadata's
`vessel_sha256`; a model can then be used where its vessel file is not installed (models/loading.model_vessel).
Artifacts written before it carry the vessel's name only (`vessel`), looked up among the presets.
"""
from __future__ import annotations

import contextlib
import datetime
import hashlib
import io
import json
import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping

import numpy as np
import torch
from torch import nn

import usv_predictor
from usv_predictor.atomic import json_text, write_bytes_atomic
from usv_predictor.bounded import parse_json, regular_file
from usv_predictor.errors import ConfigError, ModelError, OutputError
from usv_predictor.physics.vessel import (Vessel, check_vessel_name, description_sha256, description_text,
                                          vessel_from_dict, vessel_to_dict)

FORMAT = "usv_predictor.model/1"
MODEL_FILE_BYTES = 1 << 40  # bounded by the disk, not by us (bytes)
METADATA_FILE = "metadata.json"
VESSEL_FILE = "vessel.json"  # the embedded vessel description
VESSEL_DIGEST_KEY = "vessel_sha256"  # metadata key: sha256 of VESSEL_FILE's text
OUTPUT_LAYOUT = ("u", "v", "r", "x_n", "y_e", "psi")
DEFAULT_HORIZON_STEPS = 120
REQUIRED_KEYS = ("format", "model_type", "model_id", "feature_set", "feature_names", "state_layout", "control_layout",
                 "output_layout", "dt", "horizon_steps", "normalisation", "vessel", "training_data_sha256",
                 "software_version", "created_utc", "ensemble_size", "architecture", "training", "units")
UNITS = {"u": "m/s", "v": "m/s", "r": "rad/s", "psi": "rad", "x_n": "m", "y_e": "m", "delta": "rad", "rpm": "rpm",
         "dt": "s", "time": "s"}
EXPECT_UNITS = {"dt": "s"}  # units shown in mismatch messages
# ----------------------------------------------------------------------------- file

@contextlib.contextmanager
def quiet_jit() -> Iterator[None]:
    """TorchScript is the artifact format on purpose (DESIGN.md: one file, torch-only loading);
    torch >= 2.9 warns on every script/save/load call that it is deprecated."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r".*torch\.jit.*deprecated", category=DeprecationWarning)
        yield


@dataclass(frozen=True)
class ModelArtifact:
    path: Path
    metadata: dict[str, Any]
    module: torch.jit.ScriptModule  # the file's rollout, as exported
    vessel_description: dict[str, Any] | None = None  # the embedded vessel file (None: an artifact of before)
    # what predict() runs: the file's module, or a faster form of it that models/loading.py checked equal
    # (a DNN's numpy or TorchScript fused rollout, models/dnn): called as the module is, (B, 4), (B, H, C) tensors ->
    # (E, B, H, 6); `inference_note` says which and why
    inference: Callable[[torch.Tensor, torch.Tensor], torch.Tensor] | None = None
    inference_note: str = "the file's rollout"

    @property
    def embedded_vessel(self) -> Vessel | None:
        """The Vessel the artifact embeds (checked when loaded), None for an artifact that names its vessel only."""
        if self.vessel_description is None:
            return None
        return vessel_from_dict(self.vessel_description, source=f"model {self.path} ({VESSEL_FILE})")

    @property
    def runner(self) -> Callable[[torch.Tensor, torch.Tensor], torch.Tensor]:
        """The module predictions run: `inference` when set, else the file's module."""
        return self.module if self.inference is None else self.inference

    @property
    def dt(self) -> float:
        return float(self.metadata["dt"])

    @property
    def model_id(self) -> str:
        return str(self.metadata["model_id"])

    @property
    def ensemble_size(self) -> int:
        return int(self.metadata["ensemble_size"])

    @property
    def accepts_reference(self) -> bool:
        """Whether the module's forward takes a third argument, the reference state of a rudder_only grey box
        (models/greybox.py); learned models and grey boxes exported before it do not."""
        try:
            names = [argument.name for argument in self.module.forward.schema.arguments]  # self, state, controls, ...
        except AttributeError:
            return False
        return names[3:4] == ["reference"]

    def predict(self, state: np.ndarray, controls: np.ndarray, reference: np.ndarray | None = None) -> np.ndarray:
        """(E, B, H, 6) [u, v, r, x_n, y_e, psi] from state (B, 4) and controls (B, H, C), C the columns of the
        model's control_layout (2 for rudder and engine speed, 1 for rudder_only), float64 numpy; reference (B, 4):
        the state whose straight running sets a rudder_only grey box's engine speed (given only where
        accepts_reference; None: the start state)."""
        state = np.asarray(state, dtype=np.float64)
        controls = np.asarray(controls, dtype=np.float64)
        if reference is not None:
            reference = np.asarray(reference, dtype=np.float64)
            if reference.shape != state.shape or not self.accepts_reference:
                raise ModelError(f"model {self.path}: a reference state must be (B, 4) like the state and the model "
                                 f"must accept one (a grey box), got {reference.shape}")
        width = len(self.metadata.get("control_layout") or (0, 0))
        if state.ndim != 2 or state.shape[1] != 4 or controls.ndim != 3 or controls.shape[2] != width \
                or controls.shape[0] != state.shape[0]:
            raise ModelError(f"model {self.path}: predict needs state (B, 4) and controls (B, H, {width}), "
                             f"got {state.shape} and {controls.shape}")
        try:
            with torch.inference_mode():
                if reference is None:
                    out = self.runner(torch.from_numpy(state), torch.from_numpy(controls))
                else:  # a grey box's (accepts_reference): its own module or the compiled kernel of it
                    out = self.runner(torch.from_numpy(state), torch.from_numpy(controls), torch.from_numpy(reference))
            return out.double().numpy()
        except MODEL_RUN_ERRORS as err:
            raise ModelError(f"model {self.path} fails when run: {failure_reason(err)}") from err


# what a model's code can raise when called: torch.jit.Error (what a TorchScript `raise` becomes: not a
# RuntimeError) and the Python exceptions of an eager module or of TorchScript's own checks
MODEL_RUN_ERRORS = (torch.jit.Error, RuntimeError, ValueError, TypeError, IndexError, KeyError, AttributeError,
                    AssertionError)


def failure_reason(err: BaseException) -> str:
    """What a model's code raised, in one line: the last line of a TorchScript error (its first lines are the
    interpreter's preamble and the code), without the `builtins.` prefix."""
    lines = [line.strip() for line in str(err).splitlines() if line.strip()]
    return lines[-1].removeprefix("builtins.") if lines else type(err).__name__


def check_runs(artifact: ModelArtifact) -> None:
    """One two-step rollout from 1 m/s ahead with the controls at zero: a model whose code raises, that answers in
    another shape than (E, 1, 2, 6), or with NaN/inf, is a ModelError at load time ("model X fails when run: ...")
    instead of a traceback in the middle of a run."""
    controls = np.zeros((1, 2, len(artifact.metadata["control_layout"])))
    out = artifact.predict(np.array([[1.0, 0.0, 0.0, 0.0]]), controls)
    expected = (artifact.ensemble_size, 1, 2, len(OUTPUT_LAYOUT))
    if out.shape != expected:
        raise ModelError(f"model {artifact.path} fails when run: it returns shape {out.shape}, expected {expected} "
                         "(ensemble, batch, steps, [u, v, r, x_n, y_e, psi])")
    if not np.all(np.isfinite(out)):
        raise ModelError(f"model {artifact.path} fails when run: its rollout from 1 m/s ahead is not finite (NaN/inf)")


def weights_digest(module: nn.Module) -> str:
    """sha256 over the module's tensors (name, dtype, shape, bytes), in name order."""
    h = hashlib.sha256()
    for name, tensor in sorted(module.state_dict().items()):
        t = tensor.detach().cpu().contiguous()
        h.update(f"{name}|{t.dtype}|{tuple(t.shape)}|".encode())
        h.update(t.numpy().tobytes())
    return h.hexdigest()


VOLATILE_TRAINING_KEYS = ("time_s",)  # under `training`: how long the run took (s), not what it made


def model_id(module: nn.Module, metadata: Mapping[str, Any]) -> str:
    """Short sha256 of the weights and the metadata, without model_id, created_utc and the training's wall time
    (training.time_s): the same data, recipe and software give the same id (models/README.md)."""
    stable = {k: v for k, v in metadata.items() if k not in ("model_id", "created_utc")}
    if isinstance(stable.get("training"), Mapping):
        stable["training"] = {k: v for k, v in stable["training"].items() if k not in VOLATILE_TRAINING_KEYS}
    h = hashlib.sha256(weights_digest(module).encode())
    h.update(json.dumps(stable, sort_keys=True).encode())
    return h.hexdigest()[:16]


def export_module(path: str | Path, module: nn.Module, metadata: Mapping[str, Any],
                  vessel: Vessel | None = None) -> ModelArtifact:
    """Script `module` (any rollout with the forward contract above) and write it with its metadata.

    Fills format, software_version, created_utc and model_id; the other REQUIRED_KEYS must be given. vessel: the
    vessel description the model was made for (its vessel file, before any identification: what a user passes as
    --vessel), embedded as VESSEL_FILE with its digest in the metadata and its name as `vessel`.
    Serialised in memory, then written atomically (temporary file in the target folder, then os.replace);
    metadata holding NaN or infinity is a ModelError naming the field.
    """
    path = Path(path)
    meta = dict(metadata)
    meta.update(format=FORMAT, software_version=usv_predictor.__version__,
                created_utc=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"))
    extra: dict[str, str] = {}
    if vessel is not None:
        description = vessel_to_dict(vessel)
        extra[VESSEL_FILE] = description_text(description)
        meta.update(vessel=vessel.name, **{VESSEL_DIGEST_KEY: description_sha256(description)})
    elif VESSEL_DIGEST_KEY in meta:  # copied from another model's metadata: the file would not load (its digest names
        #                              a description it does not carry), so nothing is written
        raise ModelError(f"model {path}: metadata has {VESSEL_DIGEST_KEY} (copied from another model?) but no vessel "
                         "is given: pass vessel= (the description it digests, e.g. the other model's embedded_vessel)")
    meta["model_id"] = model_id(module, meta)
    missing = [k for k in REQUIRED_KEYS if k not in meta]
    if missing:
        raise ModelError(f"model {path}: metadata lacks {missing}")
    check_metadata(meta, f"model {path}: metadata")
    with quiet_jit():
        scripted = module if isinstance(module, torch.jit.ScriptModule) else torch.jit.script(module.eval())
    try:
        text = json_text(meta, f"model {path}: metadata")
    except OutputError as err:
        raise ModelError(str(err)) from err
    # Into memory first: torch's file writer aborts the process (SIGABRT) when the disk is full or the file-size
    # limit is hit, leaving its temporary file behind; the bytes then go through the atomic writer, which fails
    # with one line and removes its temporary file.
    buffer = io.BytesIO()
    with quiet_jit():
        torch.jit.save(scripted, buffer, _extra_files={METADATA_FILE: text, **extra})
    write_bytes_atomic(path, buffer.getvalue(), ModelError, "model")
    return load_artifact(path)


def export_like(path: str | Path, module: nn.Module, like: ModelArtifact, **changes: Any) -> ModelArtifact:
    """export_module of `module` as a model like `like`: its metadata updated by `changes` (export_module fills
    format, software_version, created_utc, model_id and the vessel's keys anew) and the vessel description it embeds
    (without which the copied vessel_sha256 is refused). For a model file that differs from an existing one in its
    code or in named fields: a test's failing model, a benchmark's larger ensemble."""
    return export_module(path, module, {**like.metadata, **changes}, vessel=like.embedded_vessel)


# ----------------------------------------------------------------------------- loading

def _lookup(metadata: Mapping[str, Any], dotted: str) -> Any:
    value: Any = metadata
    for part in dotted.split("."):
        if not isinstance(value, Mapping) or part not in value:
            raise KeyError(dotted)
        value = value[part]
    return value


def _same(have: Any, want: Any) -> bool:
    if isinstance(have, bool) or isinstance(want, bool):
        return have == want
    if isinstance(have, (int, float)) and isinstance(want, (int, float)):
        return math.isclose(float(have), float(want), rel_tol=1e-9, abs_tol=1e-12)
    if isinstance(have, (list, tuple)) and isinstance(want, (list, tuple)):
        return len(have) == len(want) and all(_same(a, b) for a, b in zip(have, want))
    if isinstance(have, Mapping) and isinstance(want, Mapping):
        return have.keys() == want.keys() and all(_same(have[k], want[k]) for k in have)
    return have == want


def _show(key: str, value: Any) -> str:
    unit = EXPECT_UNITS.get(key)
    if unit and isinstance(value, (int, float)) and not isinstance(value, bool):
        return f"{value:g} {unit}"
    return json.dumps(value) if isinstance(value, str) else str(value)


def metadata_differences(metadata: Mapping[str, Any], expect: Mapping[str, Any]) -> list[str]:
    """['dt: model 0.25 s, config 0.5 s', ...] for each expected key (dotted for nested) that differs."""
    out = []
    for key, want in expect.items():
        try:
            have = _lookup(metadata, key)
        except KeyError:
            out.append(f"{key}: model has none, config {_show(key, want)}")
            continue
        if not _same(have, want):
            out.append(f"{key}: model {_show(key, have)}, config {_show(key, want)}")
    return out


def read_metadata(path: str | Path) -> tuple[torch.jit.ScriptModule, dict[str, Any]]:
    """The scripted module and its metadata, checked for format and required keys (ModelError otherwise)."""
    module, metadata, _ = read_files(path)
    return module, metadata


def read_files(path: str | Path) -> tuple[torch.jit.ScriptModule, dict[str, Any], dict[str, Any] | None]:
    """The scripted module, its metadata (checked for format and required keys) and its embedded vessel description
    (checked against its digest and loadable as a vessel; None when the metadata has no `vessel_sha256`: an artifact
    of before); ModelError naming the file otherwise."""
    path = Path(path)
    if not path.is_file():
        if os.path.lexists(path) or path.exists():  # a FIFO (torch would block on it), a device, a link loop
            regular_file(path, "model file", ModelError, MODEL_FILE_BYTES)
        raise ModelError(f"model file {path} does not exist")
    extra = {METADATA_FILE: "", VESSEL_FILE: ""}
    try:
        with quiet_jit():
            module = torch.jit.load(str(path), map_location="cpu", _extra_files=extra)
    except (RuntimeError, ValueError, OSError, EOFError) as err:
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise ModelError(f"model file {path} is not a readable TorchScript model (corrupt or "
                         f"truncated?): {first}") from err
    text = extra[METADATA_FILE]
    if not text:
        raise ModelError(f"model file {path} has no {METADATA_FILE} (not a usv_predictor model?)")
    metadata = parse_json(text, f"model file {path}: {METADATA_FILE}", ModelError)
    if not isinstance(metadata, dict) or metadata.get("format") != FORMAT:
        found = metadata.get("format") if isinstance(metadata, dict) else type(metadata).__name__
        raise ModelError(f"model file {path}: format {found!r}, expected {FORMAT!r}")
    missing = [k for k in REQUIRED_KEYS if k not in metadata]
    if missing:
        raise ModelError(f"model file {path}: {METADATA_FILE} lacks {missing}")
    check_metadata(metadata, f"model file {path}: {METADATA_FILE}")
    return module, metadata, _embedded_description(path, metadata, extra[VESSEL_FILE])


def _texts(value: Any, non_empty: bool = False) -> bool:
    return isinstance(value, list) and all(isinstance(x, str) for x in value) and (bool(value) or not non_empty) \
        and len(set(value)) == len(value)


def _whole(value: Any, low: int) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= low


def _positive(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value > 0


# metadata key -> (check, what it must be): every key the loaders, the node and the commands read, checked before use
METADATA_FIELDS: dict[str, tuple[Callable[[Any], bool], str]] = {
    "model_type": (lambda v: isinstance(v, str) and bool(v), "a non-empty text"),
    "model_id": (lambda v: isinstance(v, str) and bool(v), "a non-empty text"),
    "feature_set": (lambda v: isinstance(v, str), "a text"),
    "feature_names": (_texts, "a list of distinct texts"),
    "state_layout": (_texts, "a list of distinct texts"),  # descriptive: the forward contract fixes both layouts
    "output_layout": (_texts, "a list of distinct texts"),
    "control_layout": (lambda v: _texts(v, non_empty=True), "a non-empty list of distinct control names"),
    "dt": (_positive, "a finite number of seconds > 0"),
    "horizon_steps": (lambda v: _whole(v, 1), "an integer >= 1"),
    "ensemble_size": (lambda v: _whole(v, 1), "an integer >= 1"),
    "normalisation": (lambda v: isinstance(v, dict), "a mapping"),
    "architecture": (lambda v: isinstance(v, dict), "a mapping"),
    "training": (lambda v: isinstance(v, dict), "a mapping"),
    "units": (lambda v: isinstance(v, dict), "a mapping"),
    "vessel": (lambda v: isinstance(v, str) and bool(v), "a vessel name"),
    "training_data_sha256": (lambda v: v is None or isinstance(v, str), "a text or null"),
    "software_version": (lambda v: isinstance(v, str), "a text"),
    "created_utc": (lambda v: isinstance(v, str), "a text"),
    "actuator_layout": (lambda v: isinstance(v, str), "a text"),  # optional: artifacts of before have none
    VESSEL_DIGEST_KEY: (lambda v: isinstance(v, str), "a text"),  # optional likewise
}


def check_metadata(metadata: Mapping[str, Any], source: str) -> None:
    """Every field of METADATA_FIELDS present in `metadata` has its type (and range), the vessel name is no path;
    ModelError naming the first field that is not ("SOURCE: ensemble_size = 'five' must be an integer >= 1")."""
    for key, (valid, expected) in METADATA_FIELDS.items():
        if key in metadata and not valid(metadata[key]):
            shown = repr(metadata[key])
            shown = shown if len(shown) <= 80 else f"{shown[:80]}..."
            raise ModelError(f"{source}: {key} = {shown} must be {expected}")
    try:
        check_vessel_name(metadata.get("vessel"), f"{source}: vessel")
    except ConfigError as err:
        raise ModelError(str(err)) from None


def _embedded_description(path: Path, metadata: Mapping[str, Any], text: str | bytes) -> dict[str, Any] | None:
    digest = metadata.get(VESSEL_DIGEST_KEY)
    if digest is None:
        return None
    if not text:
        raise ModelError(f"model file {path}: its metadata has {VESSEL_DIGEST_KEY} but the file has no {VESSEL_FILE}")
    raw = text.encode() if isinstance(text, str) else bytes(text)
    if hashlib.sha256(raw).hexdigest() != digest:
        raise ModelError(f"model file {path}: {VESSEL_FILE} does not match its digest {VESSEL_DIGEST_KEY} "
                         "(modified or corrupt)")
    try:
        description = parse_json(raw, f"model file {path}: {VESSEL_FILE}", ConfigError)
        vessel = vessel_from_dict(description, source=f"model file {path} ({VESSEL_FILE})")
    except ConfigError as err:
        raise ModelError(f"model file {path}: {VESSEL_FILE} is not a vessel description: {err}") from err
    if vessel.name != metadata.get("vessel"):
        raise ModelError(f"model file {path}: {VESSEL_FILE} describes vessel {vessel.name!r}, its metadata names "
                         f"{metadata.get('vessel')!r}")
    return description


def load_artifact(path: str | Path, expect: Mapping[str, Any] | None = None) -> ModelArtifact:
    """Load a model file; ModelError naming the file and every field that differs from `expect`."""
    module, metadata, description = read_files(path)
    if expect:
        diffs = metadata_differences(metadata, expect)
        if diffs:
            raise ModelError(f"model {path} does not match the configuration: {'; '.join(diffs)}")
    module.eval()
    return ModelArtifact(Path(path), metadata, module, description)
