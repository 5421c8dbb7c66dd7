"""The model artifact: ONE TorchScript file (closed-loop rollout) whose extra file carries the metadata.

Scripted module (what the node, evaluate and diagnose call; loading needs torch only):

    forward(state (B, 4) [u, v, r, psi], controls (B, H, 2) [delta rad, rpm]) -> (E, B, H, 6)

    out[e, b, k] = [u, v, r, x_n, y_e, psi] at time (k+1) dt after the start, by ensemble member e;
    positions in NED relative to the start position (0, 0), psi continuous (not wrapped).
    controls[:, k] acts from step k to k+1. E = ensemble size (1 for a single model).

The rollout is seed 000 Fig. 3: the predicted [u, v, r] is fed back and the features (features.py)
are recomputed each step from it and the integrated heading. Kinematics (Fossen 2021 eq. 2.40,
3-DOF) integrated with the trapezoidal rule over each step:

    psi_{k+1} = psi_k + dt/2 (r_k + r_{k+1})
    [x_n, y_e]_{k+1} = [x_n, y_e]_k + dt/2 (R(psi_k) [u_k, v_k] + R(psi_{k+1}) [u_{k+1}, v_{k+1}]),
    R(psi) [u, v] = [u cos psi - v sin psi, u sin psi + v cos psi]   (north, east)

Seed 000 eq. 9 is the rectangle-rule version of the same sums, T sum R(psi_i) [u_i, v_i], written with
x east and y north and with the measured psi_i; for constant velocity and heading both give the same
track, the trapezoidal rule is second-order accurate where eq. 9 is first-order (and a turn at 2 Hz
is coarse). Here psi is not measured but integrated from the predicted r.

For speed (node budget: p99 <= 1.5 ms for B=1, H=120) the network is folded into plain affine maps
(normalisation and batch norm folded, models.dnn.DnnModel.affine_layers) and each step is a few
batched matrix products over the ensemble: the controls' share of the first layer is computed for all
steps before the loop, the state update z_{k+1} = z_k A + c + h W (z = [u, v, r, psi]) folds the
increment and the heading integration into the output layer, positions are integrated after the loop
(they do not feed back).

Metadata (extra file `metadata.json`, format `usv_predictor.model/1`): see REQUIRED_KEYS and export().
"""
from __future__ import annotations

import contextlib
import datetime
import hashlib
import json
import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, List, Mapping, Sequence

import numpy as np
import torch
from torch import nn

import usv_predictor
from usv_predictor.atomic import atomic_path
from usv_predictor.errors import ModelError
from usv_predictor.features import CONTROL_NAMES, FEATURE_UNITS, STATE_NAMES
from usv_predictor.models.dnn import DnnConfig, DnnModel

FORMAT = "usv_predictor.model/1"
METADATA_FILE = "metadata.json"
OUTPUT_LAYOUT = ("u", "v", "r", "x_n", "y_e", "psi")
DEFAULT_HORIZON_STEPS = 120
REQUIRED_KEYS = ("format", "model_type", "model_id", "feature_set", "feature_names", "state_layout", "control_layout",
                 "output_layout", "dt", "horizon_steps", "normalisation", "vessel", "training_data_sha256",
                 "software_version", "created_utc", "ensemble_size", "architecture", "training", "units")
UNITS = {"u": "m/s", "v": "m/s", "r": "rad/s", "psi": "rad", "x_n": "m", "y_e": "m", "delta": "rad", "rpm": "rpm",
         "dt": "s", "time": "s"}
EXPECT_UNITS = {"dt": "s"}  # units shown in mismatch messages
_TRIG = {"F0": 0, "NAF": 1, "NTF": 2}  # how psi enters the features: not, wrapped (1 column), sin/cos (2)


class DnnRollout(nn.Module):
    """Closed-loop rollout of an ensemble of folded seed-000 networks (see the module docstring).

    Step state s = [u, v, r, psi, t] (E, B, 4 + T) where t are the psi features (T = 0 for F0,
    1 wrapped psi for NAF, 2 sin/cos psi for NTF). One step is three batched products:
        [s_lin | pre] = s M + per_step[k]        s_lin: the linear part of the next s (4 + T)
        h = act(pre); h = act(h W_i + b_i) ...   hidden layers (W units)
        s' = s_lin + h head                      next [u, v, r, psi] and the psi-feature argument
        t' = sin(.) or remainder(., 2 pi)        in place on the last T columns
    """

    __constants__ = ["trig_mode", "clipped", "ceiling", "dt", "ensemble_size"]  # TorchScript constants

    def __init__(self, members: Sequence[DnnModel], dt: float, dtype: torch.dtype = torch.float32) -> None:
        super().__init__()
        config = members[0].config
        if any(m.config != config for m in members):
            raise ModelError("ensemble members must share one architecture (DnnConfig)")
        self.trig_mode = _TRIG[config.feature_set]  # = T, the number of psi feature columns
        self.clipped = config.activation == "clipped_relu"
        self.ceiling = float(config.ceiling)
        self.dt = float(dt)
        self.ensemble_size = len(members)
        parts = [self._member_tensors(m, config, float(dt)) for m in members]
        for name in parts[0]:
            self.register_buffer(name, torch.stack([p[name] for p in parts]).to(dtype))

    @staticmethod
    def _member_tensors(model: DnnModel, config: DnnConfig, dt: float) -> dict[str, torch.Tensor]:
        layers = model.affine_layers()  # float64 [(out, in), (out,)] in physical units
        col = {n: i for i, n in enumerate(config.feature_names)}
        w1, b1 = layers[0]  # (W, F), (W,)
        w_out, b_out = layers[-1]  # (3, W), (3,)
        width = w1.shape[0]
        n_trig = _TRIG[config.feature_set]
        s = 4 + n_trig
        inc = 1.0 if config.predict_increment else 0.0
        m_s = torch.zeros(s, s + width, dtype=torch.float64)  # s (1, S) @ m_s -> [s_lin (S) | pre (W)]
        bias = torch.zeros(1, s + width, dtype=torch.float64)
        w_c = torch.zeros(2, s + width, dtype=torch.float64)  # controls (1, 2) @ w_c: their share of pre
        head = torch.zeros(width, s, dtype=torch.float64)
        # next nu = inc * nu + b_out + h w_out; next psi = psi + dt/2 (r + next r)
        m_s[0, 0] = m_s[1, 1] = m_s[2, 2] = inc
        m_s[3, 3] = 1.0
        m_s[2, 3] = (1.0 + inc) * 0.5 * dt
        bias[0, :3] = b_out
        bias[0, 3] = 0.5 * dt * b_out[2]
        head[:, :3] = w_out.T
        head[:, 3] = 0.5 * dt * w_out[2]
        # the psi-feature arguments: copies of the next psi (+ a phase)
        phase = {0: [], 1: [math.pi], 2: [0.0, 0.5 * math.pi]}[n_trig]  # NAF: psi + pi; NTF: sin(psi + [0, pi/2])
        for j, p in enumerate(phase):
            m_s[:, 4 + j] = m_s[:, 3]
            bias[0, 4 + j] = bias[0, 3] + p
            head[:, 4 + j] = head[:, 3]
        # first layer: state, control and psi-feature columns of w1
        first_bias = b1.clone()
        for i, name in enumerate(("u", "v", "r")):
            m_s[i, s:] = w1[:, col[name]]
        for i, name in enumerate(CONTROL_NAMES):
            w_c[i, s:] = w1[:, col[name]]
        if config.feature_set == "NTF":
            m_s[4, s:] = w1[:, col["sin_psi"]]
            m_s[5, s:] = w1[:, col["cos_psi"]]
        elif config.feature_set == "NAF":  # wrapped psi = remainder(psi + pi, 2 pi) - pi: the -pi goes to the bias
            m_s[4, s:] = w1[:, col["psi"]]
            first_bias = first_bias - math.pi * w1[:, col["psi"]]
        bias[0, s:] = first_bias
        hidden = layers[1:-1]
        no_hidden = torch.zeros(0, width, width, dtype=torch.float64), torch.zeros(0, 1, width, dtype=torch.float64)
        return {
            "m_s": m_s, "w_c": w_c, "bias": bias, "head": head,
            "phase": torch.tensor(phase, dtype=torch.float64).reshape(1, n_trig),
            "hidden_w": torch.stack([w.T for w, _ in hidden]) if hidden else no_hidden[0],  # (depth-1, W, W)
            "hidden_b": torch.stack([b[None, :] for _, b in hidden]) if hidden else no_hidden[1],  # (depth-1, 1, W)
        }

    def _activation_(self, h: torch.Tensor) -> torch.Tensor:
        """In place: h is a fresh intermediate, so no new tensor is needed."""
        if self.clipped:
            return h.clamp_(0.0, self.ceiling)
        return h.tanh_()

    def _psi_features_(self, s: torch.Tensor) -> None:
        """In place: the last T columns of s, psi + phase, become the psi features."""
        if self.trig_mode == 2:
            s.narrow(2, 4, 2).sin_()
        elif self.trig_mode == 1:
            s.narrow(2, 4, 1).remainder_(2.0 * math.pi)

    def forward(self, state: torch.Tensor, controls: torch.Tensor) -> torch.Tensor:
        if state.dim() != 2 or state.size(1) != 4:
            raise ValueError("state must be (B, 4) [u, v, r, psi]")
        if controls.dim() != 3 or controls.size(2) != 2 or controls.size(0) != state.size(0):
            raise ValueError("controls must be (B, H, 2) [delta, rpm] with the B of state")
        e = self.ensemble_size
        b = state.size(0)
        horizon = controls.size(1)
        n_s = 4 + self.trig_mode
        z0 = state.to(self.m_s.dtype).unsqueeze(0).expand(e, b, 4)  # (E, B, 4)
        s = torch.cat([z0, z0[:, :, 3:4] + self.phase], dim=2)  # (E, B, S)
        self._psi_features_(s)
        ctrl = controls.to(self.m_s.dtype).reshape(1, b * horizon, 2)
        # the controls' share of every step's first layer, before the loop: H x (E, B, S + W)
        per_step = (torch.matmul(ctrl, self.w_c).reshape(e, b, horizon, -1) + self.bias.unsqueeze(2)).unbind(2)
        hidden_w = self.hidden_w.unbind(1)  # buffers are (E, depth-1, ...): one (E, W, W) per hidden layer
        hidden_b = self.hidden_b.unbind(1)
        sections = [n_s, self.m_s.size(2) - n_s]
        steps: List[torch.Tensor] = []
        for k in range(horizon):
            s_lin, pre = torch.baddbmm(per_step[k], s, self.m_s).split(sections, dim=2)  # (E, B, S), (E, B, W)
            h = self._activation_(pre)
            for i in range(len(hidden_w)):
                h = self._activation_(torch.baddbmm(hidden_b[i], h, hidden_w[i]))  # (E, B, W)
            s = torch.baddbmm(s_lin, h, self.head)  # (E, B, S): [u, v, r, psi] at k+1, psi-feature arguments
            self._psi_features_(s)
            steps.append(s)
        path = torch.stack(steps, dim=2)[..., 0:4]  # (E, B, H, 4)
        full = torch.cat([z0.unsqueeze(2), path], dim=2)  # (E, B, H+1, 4)
        cos_psi = torch.cos(full[..., 3])
        sin_psi = torch.sin(full[..., 3])
        v_north = full[..., 0] * cos_psi - full[..., 1] * sin_psi  # (E, B, H+1)
        v_east = full[..., 0] * sin_psi + full[..., 1] * cos_psi
        velocity = torch.stack([v_north, v_east], dim=-1)  # (E, B, H+1, 2)
        position = torch.cumsum(0.5 * self.dt * (velocity[:, :, 1:] + velocity[:, :, :-1]), dim=2)  # (E, B, H, 2)
        return torch.cat([path[..., 0:3], position, path[..., 3:4]], dim=-1)  # (E, B, H, 6)


# ----------------------------------------------------------------------------- file

@contextlib.contextmanager
def _quiet_jit() -> Iterator[None]:
    """TorchScript is the artifact format on purpose (DESIGN.md: one file, torch-only loading);
    torch >= 2.9 warns on every script/save/load call that it is deprecated."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r".*torch\.jit.*deprecated", category=DeprecationWarning)
        yield


@dataclass(frozen=True)
class ModelArtifact:
    path: Path
    metadata: dict[str, Any]
    module: torch.jit.ScriptModule

    @property
    def dt(self) -> float:
        return float(self.metadata["dt"])

    @property
    def model_id(self) -> str:
        return str(self.metadata["model_id"])

    @property
    def ensemble_size(self) -> int:
        return int(self.metadata["ensemble_size"])

    def predict(self, state: np.ndarray, controls: np.ndarray) -> np.ndarray:
        """(E, B, H, 6) [u, v, r, x_n, y_e, psi] from state (B, 4) and controls (B, H, 2), float64 numpy."""
        state = np.asarray(state, dtype=np.float64)
        controls = np.asarray(controls, dtype=np.float64)
        if state.ndim != 2 or state.shape[1] != 4 or controls.ndim != 3 or controls.shape[2] != 2 \
                or controls.shape[0] != state.shape[0]:
            raise ModelError(f"model {self.path}: predict needs state (B, 4) and controls (B, H, 2), "
                             f"got {state.shape} and {controls.shape}")
        with torch.inference_mode():
            out = self.module(torch.from_numpy(state), torch.from_numpy(controls))
        return out.double().numpy()


def weights_digest(module: nn.Module) -> str:
    """sha256 over the module's tensors (name, dtype, shape, bytes), in name order."""
    h = hashlib.sha256()
    for name, tensor in sorted(module.state_dict().items()):
        t = tensor.detach().cpu().contiguous()
        h.update(f"{name}|{t.dtype}|{tuple(t.shape)}|".encode())
        h.update(t.numpy().tobytes())
    return h.hexdigest()


def model_id(module: nn.Module, metadata: Mapping[str, Any]) -> str:
    """Short sha256 of the weights and the metadata (without model_id and created_utc: reproducible)."""
    stable = {k: v for k, v in metadata.items() if k not in ("model_id", "created_utc")}
    h = hashlib.sha256(weights_digest(module).encode())
    h.update(json.dumps(stable, sort_keys=True).encode())
    return h.hexdigest()[:16]


def export_module(path: str | Path, module: nn.Module, metadata: Mapping[str, Any]) -> ModelArtifact:
    """Script `module` (any rollout with the forward contract above) and write it with its metadata.

    Fills format, software_version, created_utc and model_id; the other REQUIRED_KEYS must be given.
    Written atomically (temporary file in the target folder, then os.replace).
    """
    path = Path(path)
    meta = dict(metadata)
    meta.update(format=FORMAT, software_version=usv_predictor.__version__,
                created_utc=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"))
    meta["model_id"] = model_id(module, meta)
    missing = [k for k in REQUIRED_KEYS if k not in meta]
    if missing:
        raise ModelError(f"model {path}: metadata lacks {missing}")
    with _quiet_jit():
        scripted = module if isinstance(module, torch.jit.ScriptModule) else torch.jit.script(module.eval())
    text = json.dumps(meta, indent=2, sort_keys=True, allow_nan=False)
    with atomic_path(path, ModelError, "model") as tmp, _quiet_jit():
        torch.jit.save(scripted, str(tmp), _extra_files={METADATA_FILE: text})
    return load_artifact(path)


def export(path: str | Path, members: Sequence[DnnModel], config: DnnConfig, *, dt: float, vessel: str,
           training_data_sha256: str, training: Mapping[str, Any] | None = None,
           horizon_steps: int = DEFAULT_HORIZON_STEPS, dtype: str = "float32",
           extra: Mapping[str, Any] | None = None) -> ModelArtifact:
    """Export trained seed-000 networks (one, or an ensemble sharing normalisation) as one artifact."""
    if not members:
        raise ModelError(f"model {path}: no trained network to export")
    if not (dt > 0.0 and math.isfinite(dt)):
        raise ModelError(f"model {path}: dt={dt} s must be > 0")
    if dtype not in ("float32", "float64"):
        raise ModelError(f"model {path}: dtype {dtype!r}, expected 'float32' or 'float64'")
    norm = members[0].normalisation()
    for m in members[1:]:
        other = m.normalisation()
        if not all(np.allclose(a, b) for a, b in zip(norm.to_dict().values(), other.to_dict().values())):
            raise ModelError(f"model {path}: ensemble members were trained with different normalisations")
    module = DnnRollout([m.eval() for m in members], dt, getattr(torch, dtype))
    metadata = {
        "model_type": "dnn",
        "feature_set": config.feature_set,
        "feature_names": list(config.feature_names),
        "feature_units": [FEATURE_UNITS[n] for n in config.feature_names],
        "state_layout": list(STATE_NAMES),
        "control_layout": list(CONTROL_NAMES),
        "output_layout": list(OUTPUT_LAYOUT),
        "dt": float(dt),
        "horizon_steps": int(horizon_steps),
        "normalisation": {**norm.to_dict(), "target": "increment" if config.predict_increment else "absolute"},
        "vessel": vessel,
        "training_data_sha256": training_data_sha256,
        "ensemble_size": len(members),
        "architecture": config.to_dict(),
        "training": dict(training or {}),
        "units": UNITS,
        "dtype": dtype,
        **dict(extra or {}),
    }
    return export_module(path, module, metadata)


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
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"model file {path} does not exist")
    extra = {METADATA_FILE: ""}
    try:
        with _quiet_jit():
            module = torch.jit.load(str(path), map_location="cpu", _extra_files=extra)
    except (RuntimeError, ValueError, OSError, EOFError) as err:
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise ModelError(f"model file {path} is not a readable TorchScript model (corrupt or truncated?): {first}") from err
    text = extra[METADATA_FILE]
    if not text:
        raise ModelError(f"model file {path} has no {METADATA_FILE} (not a usv_predictor model?)")
    try:
        metadata = json.loads(text)
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ModelError(f"model file {path}: {METADATA_FILE} is not valid JSON: {err}") from err
    if not isinstance(metadata, dict) or metadata.get("format") != FORMAT:
        found = metadata.get("format") if isinstance(metadata, dict) else type(metadata).__name__
        raise ModelError(f"model file {path}: format {found!r}, expected {FORMAT!r}")
    missing = [k for k in REQUIRED_KEYS if k not in metadata]
    if missing:
        raise ModelError(f"model file {path}: {METADATA_FILE} lacks {missing}")
    return module, metadata


def load_artifact(path: str | Path, expect: Mapping[str, Any] | None = None) -> ModelArtifact:
    """Load a model file; ModelError naming the file and every field that differs from `expect`."""
    module, metadata = read_metadata(path)
    if expect:
        diffs = metadata_differences(metadata, expect)
        if diffs:
            raise ModelError(f"model {path} does not match the configuration: {'; '.join(diffs)}")
    module.eval()
    return ModelArtifact(Path(path), metadata, module)
