"""The model artifact: TorchScript closed-loop rollout (seed 000 Fig. 3) against an eager numpy reference,
kinematics on analytic cases, metadata round trip, mismatch and corrupt-file errors, torch-only loading."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import usv_predictor
from usv_predictor.data.features import FEATURE_SETS, features
from usv_predictor.errors import ModelError
from usv_predictor.models.artifact import (
    FORMAT,
    METADATA_FILE,
    REQUIRED_KEYS,
    export_module,
    load_artifact,
    metadata_differences,
)
from usv_predictor.models.dnn import DnnConfig, DnnModel, export, fit_normalisation

DT = 0.5


def _member(feature_set: str, seed: int, activation: str = "tanh", increment: bool = True,
            depth: int | None = None) -> DnnModel:
    """A random network (seed; `depth` hidden layers, DnnConfig's default when None) with data-like normalisation
    (shared) and non-trivial batch-norm statistics."""
    rng = np.random.default_rng(0)
    n = 200
    state = np.column_stack([rng.normal(5, 1, n), rng.normal(0, .3, n), rng.normal(0, .1, n), rng.uniform(-9, 9, n)])
    controls = np.column_stack([rng.normal(0, .3, n), rng.normal(650, 30, n)])
    x = features(feature_set, state, controls)
    y = state[:, :3] + rng.normal(0, .05, (n, 3))
    config = DnnConfig.for_features(feature_set, width=12, activation=activation, ceiling=1.5,
                                    predict_increment=increment, **({} if depth is None else {"depth": depth}))
    torch.manual_seed(seed)
    model = DnnModel(config, fit_normalisation(x, y, increment))
    with torch.no_grad():
        for block in model.hidden:
            block[1].running_mean.normal_(0.0, 0.3)
            block[1].running_var.uniform_(0.5, 2.0)
            block[1].weight.normal_(1.0, 0.2)
            block[1].bias.normal_(0.0, 0.2)
        model.head.weight.mul_(0.3)  # a gentle model, so a long rollout stays physical
    return model.eval()


def _reference(model: DnnModel, feature_set: str, state: np.ndarray, controls: np.ndarray, dt: float) -> np.ndarray:
    """Step by step in numpy + the eager float64 network: features.py each step, trapezoidal kinematics."""
    net = DnnModel(model.config)
    net.load_state_dict(model.state_dict())
    net = net.double().eval()

    def ned(nu: np.ndarray, psi: np.ndarray) -> np.ndarray:
        c, s = np.cos(psi), np.sin(psi)
        return np.column_stack([nu[:, 0] * c - nu[:, 1] * s, nu[:, 0] * s + nu[:, 1] * c])

    nu, psi, pos = state[:, :3].copy(), state[:, 3].copy(), np.zeros((len(state), 2))
    out = np.zeros(controls.shape[:2] + (6,))
    for k in range(controls.shape[1]):
        x = features(feature_set, np.column_stack([nu, psi]), controls[:, k])
        with torch.no_grad():
            nxt = net(torch.from_numpy(x)).numpy()
        psi_next = psi + 0.5 * dt * (nu[:, 2] + nxt[:, 2])
        pos = pos + 0.5 * dt * (ned(nu, psi) + ned(nxt, psi_next))
        nu, psi = nxt, psi_next
        out[:, k] = np.column_stack([nu, pos, psi])
    return out


def _inputs(batch: int = 3, horizon: int = 30, seed: int = 5) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    state = np.column_stack([rng.normal(5, .5, batch), rng.normal(0, .2, batch), rng.normal(0, .05, batch),
                             rng.uniform(-4, 4, batch)])
    controls = np.stack([np.column_stack([np.full(horizon, rng.normal(0, .3)) + rng.normal(0, .02, horizon),
                                          np.full(horizon, rng.normal(650, 30))]) for _ in range(batch)])
    return state, controls  # (B, 4), (B, H, 2)


def _export(path: Path, members: list[DnnModel], **kwargs) -> object:
    kwargs = {"dt": DT, "vessel": "jari_usv", "training_data_sha256": "ab" * 32, **kwargs}
    return export(path, members, members[0].config, **kwargs)


@pytest.mark.parametrize("feature_set", sorted(FEATURE_SETS))
@pytest.mark.parametrize("activation, increment", [("tanh", True), ("clipped_relu", True), ("tanh", False)])
def test_rollout_equals_step_by_step_reference(tmp_path: Path, feature_set: str, activation: str,
                                               increment: bool) -> None:
    members = [_member(feature_set, seed, activation, increment) for seed in (1, 2)]
    artifact = _export(tmp_path / "m.pt", members, dtype="float64")
    state, controls = _inputs()
    got = artifact.predict(state, controls)
    assert got.shape == (2, 3, 30, 6)
    for e, member in enumerate(members):
        np.testing.assert_allclose(got[e], _reference(member, feature_set, state, controls, DT), rtol=0, atol=1e-5)
    assert np.abs(got[0] - got[1]).max() > 1e-3  # the members are different networks


def test_float32_rollout_is_close_to_the_reference(tmp_path: Path) -> None:
    member = _member("NTF", 3)
    artifact = _export(tmp_path / "m.pt", [member])  # default float32: the node's latency budget
    assert artifact.metadata["dtype"] == "float32"
    state, controls = _inputs(horizon=120)
    np.testing.assert_allclose(artifact.predict(state, controls)[0], _reference(member, "NTF", state, controls, DT),
                               rtol=1e-4, atol=2e-3)


def _constant_motion_model(u: float, increment: bool) -> DnnModel:
    """A network whose output is exactly [u, 0, 0] (absolute) or 'no change' (increment)."""
    model = _member("NTF", 0, increment=increment)
    with torch.no_grad():
        model.head.weight.zero_()
        model.head.bias.zero_()
        model.y_std.fill_(1.0)
        model.y_mean.copy_(torch.tensor([0.0 if increment else u, 0.0, 0.0]))
    return model


@pytest.mark.parametrize("increment", [True, False])
@pytest.mark.parametrize("psi_deg, direction",
                         [(0.0, (1.0, 0.0)), (90.0, (0.0, 1.0)), (-135.0, (-0.5 ** 0.5, -0.5 ** 0.5))])
def test_straight_line_kinematics(tmp_path: Path, increment: bool, psi_deg: float,
                                  direction: tuple[float, float]) -> None:
    u = 4.0
    artifact = _export(tmp_path / "m.pt", [_constant_motion_model(u, increment)], dtype="float64")
    psi = math.radians(psi_deg)
    out = artifact.predict(np.array([[u, 0.0, 0.0, psi]]), np.tile([0.1, 650.0], (1, 10, 1)))[0, 0]  # (H, 6)
    steps = np.arange(1, 11)
    np.testing.assert_allclose(out[:, 0:3], np.tile([u, 0.0, 0.0], (10, 1)), atol=1e-12)
    np.testing.assert_allclose(out[:, 3], u * DT * steps * direction[0], atol=1e-9)  # x_n advances u dt cos psi
    np.testing.assert_allclose(out[:, 4], u * DT * steps * direction[1], atol=1e-9)  # y_e advances u dt sin psi
    np.testing.assert_allclose(out[:, 5], psi, atol=1e-12)  # psi continuous, not wrapped


def test_heading_is_integrated_from_r_and_not_wrapped(tmp_path: Path) -> None:
    r = 0.2  # rad/s, held by an increment model that predicts no change
    artifact = _export(tmp_path / "m.pt", [_constant_motion_model(0.0, True)], dtype="float64")
    out = artifact.predict(np.array([[3.0, 0.0, r, 3.0]]), np.tile([0.0, 650.0], (1, 60, 1)))[0, 0]
    np.testing.assert_allclose(out[:, 5], 3.0 + r * DT * np.arange(1, 61), atol=1e-9)  # beyond pi: continuous
    # a steady turn: the track is a circle of radius u / r through the start, centre to starboard
    radius = 3.0 / r
    centre = np.array([-radius * math.sin(3.0), radius * math.cos(3.0)])  # NED, starboard of heading 3 rad
    np.testing.assert_allclose(np.hypot(*(out[:, 3:5] - centre).T), radius, rtol=2e-3)


def test_metadata_round_trip(tmp_path: Path) -> None:
    members = [_member("NAF", 1), _member("NAF", 2)]
    artifact = _export(tmp_path / "m.pt", members, training={"best_epoch": [7, 9], "val_loss": [0.1, 0.2]},
                       horizon_steps=60)
    meta = load_artifact(tmp_path / "m.pt").metadata
    assert set(REQUIRED_KEYS) <= set(meta)
    assert meta["format"] == FORMAT
    assert meta["model_type"] == "dnn"
    assert meta["feature_set"] == "NAF"
    assert meta["feature_names"] == list(FEATURE_SETS["NAF"])
    assert meta["state_layout"] == ["u", "v", "r", "psi"]
    assert meta["control_layout"] == ["delta", "rpm"]
    assert meta["output_layout"] == ["u", "v", "r", "x_n", "y_e", "psi"]
    assert meta["dt"] == DT
    assert meta["horizon_steps"] == 60
    assert meta["vessel"] == "jari_usv"
    assert meta["ensemble_size"] == 2
    assert meta["software_version"] == usv_predictor.__version__
    assert meta["training_data_sha256"] == "ab" * 32
    assert meta["training"]["best_epoch"] == [7, 9]
    assert DnnConfig.from_dict(meta["architecture"]) == members[0].config
    np.testing.assert_allclose(meta["normalisation"]["feature_std"], members[0].x_std.numpy(), rtol=1e-6)
    assert meta["normalisation"]["target"] == "increment"
    assert meta["units"]["dt"] == "s"
    assert len(meta["model_id"]) == 16
    assert meta["model_id"] == artifact.model_id
    again = _export(tmp_path / "again.pt", members, training={"best_epoch": [7, 9], "val_loss": [0.1, 0.2]},
                    horizon_steps=60)
    assert again.model_id == artifact.model_id  # same weights and metadata: same id (created_utc left out)
    other = _export(tmp_path / "other.pt", members[:1])
    assert other.model_id != artifact.model_id
    assert sorted(os.listdir(tmp_path)) == ["again.pt", "m.pt", "other.pt"]  # no temporary files left


def test_model_id_leaves_out_the_training_wall_time_only(tmp_path: Path) -> None:
    """A rebuild of the same model takes another time (training.time_s, kept in the file): same id (models/README.md,
    the shipped model's determinism); a different best epoch or loss under `training` is another id."""
    members = [_member("NTF", 1)]
    training = {"best_epoch": [7], "val_loss": [0.1], "time_s": 6.7}
    first = _export(tmp_path / "a.pt", members, training=training)
    slower = _export(tmp_path / "b.pt", members, training={**training, "time_s": 11.0})
    assert load_artifact(tmp_path / "b.pt").metadata["training"]["time_s"] == 11.0  # kept, only not hashed
    assert slower.model_id == first.model_id
    for changed in ({"best_epoch": [8]}, {"val_loss": [0.11]}):
        assert _export(tmp_path / "c.pt", members, training={**training, **changed}).model_id != first.model_id


def test_mismatch_names_the_file_and_every_field(tmp_path: Path) -> None:
    path = tmp_path / "m.pt"
    _export(path, [_member("NTF", 1)], dt=0.25, vessel="other_usv")
    load_artifact(path, expect={"dt": 0.25, "vessel": "other_usv", "architecture.width": 12})  # matches
    with pytest.raises(ModelError) as err:
        load_artifact(path, expect={"dt": 0.5, "vessel": "jari_usv", "feature_set": "NTF"})
    message = str(err.value)
    assert str(path) in message
    assert "dt: model 0.25 s, config 0.5 s" in message
    assert 'vessel: model "other_usv", config "jari_usv"' in message
    assert "feature_set" not in message  # only what differs
    assert metadata_differences({"dt": 0.5}, {"ensemble_size": 3}) == ["ensemble_size: model has none, config 3"]


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # torch.jit.script/save called here directly
def test_missing_corrupt_and_foreign_files(tmp_path: Path) -> None:
    with pytest.raises(ModelError, match=r"does not exist"):
        load_artifact(tmp_path / "none.pt")
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"not a model at all")
    with pytest.raises(ModelError, match=r"garbage\.pt is not a readable TorchScript model"):
        load_artifact(garbage)
    good = tmp_path / "good.pt"
    _export(good, [_member("F0", 1)])
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(ModelError, match=r"truncated\.pt"):
        load_artifact(truncated)
    foreign = tmp_path / "foreign.pt"
    torch.jit.save(torch.jit.script(torch.nn.Linear(2, 2)), str(foreign))
    with pytest.raises(ModelError, match=f"foreign.pt has no {METADATA_FILE}"):
        load_artifact(foreign)
    other_format = tmp_path / "format.pt"
    torch.jit.save(torch.jit.script(torch.nn.Linear(2, 2)), str(other_format),
                   _extra_files={METADATA_FILE: json.dumps({"format": "something/2"})})
    with pytest.raises(ModelError, match=r"format 'something/2', expected 'usv_predictor.model/1'"):
        load_artifact(other_format)


def test_export_refuses_incomplete_metadata_and_leaves_no_file(tmp_path: Path) -> None:
    from usv_predictor.models.dnn import DnnRollout

    with pytest.raises(ModelError, match="lacks"):
        export_module(tmp_path / "m.pt", DnnRollout([_member("F0", 1)], DT), {"model_type": "dnn"})
    assert list(tmp_path.iterdir()) == []


def test_predict_checks_shapes(tmp_path: Path) -> None:
    artifact = _export(tmp_path / "m.pt", [_member("F0", 1)])
    with pytest.raises(ModelError, match=r"\(B, 4\)"):
        artifact.predict(np.zeros((1, 3)), np.zeros((1, 5, 2)))
    with pytest.raises(torch.jit.Error, match="controls must be"):
        artifact.module(torch.zeros(2, 4), torch.zeros(1, 5, 2))


def test_loads_with_torch_only_in_a_subprocess(tmp_path: Path) -> None:
    path = tmp_path / "m.pt"
    artifact = _export(path, [_member("NTF", 1)])
    state, controls = _inputs(batch=1, horizon=12)
    expected = artifact.predict(state, controls)
    script = (
        "import json, sys, torch\n"
        f"extra = {{'{METADATA_FILE}': ''}}\n"
        "m = torch.jit.load(sys.argv[1], _extra_files=extra)\n"
        "meta = json.loads(extra['metadata.json'])\n"
        "out = m(torch.tensor(json.loads(sys.argv[2])), torch.tensor(json.loads(sys.argv[3])))\n"
        "print(json.dumps({'format': meta['format'], 'dt': meta['dt'], 'out': out.tolist(),\n"
        "                  'imported': sorted(k for k in sys.modules if k.startswith('usv_predictor'))}))\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    done = subprocess.run([sys.executable, "-W", "ignore", "-c", script, str(path), json.dumps(state.tolist()),
                           json.dumps(controls.tolist())], capture_output=True, text=True, cwd=tmp_path, env=env,
                          timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert result["imported"] == []
    assert result["format"] == FORMAT
    assert result["dt"] == DT
    np.testing.assert_allclose(np.array(result["out"]), expected, rtol=1e-6, atol=1e-6)
