"""The node's fused DNN rollout (models/dnn.NumpyDnnRollout, else FusedDnnRollout, fused when a model is loaded)
computes what the artifact's own rollout and the members stepped one by one compute, within float rounding; old
artifacts keep loading and a DNN file that cannot be fused keeps its own rollout. No timing here
(benchmarks/bench_node.py)."""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from test_artifact import DT, _export, _inputs, _reference
from test_artifact import _member as artifact_member
from usv_predictor.data.features import FEATURE_SETS
from usv_predictor.errors import ModelError
from usv_predictor.models import loading
from usv_predictor.models.artifact import export_module, load_artifact
from usv_predictor.models import dnn
from usv_predictor.models.dnn import (BIAS_UNIT_PRE, NUMPY_FORM, DnnModel, DnnRollout, FusedDnnRollout,
                                      NumpyDnnRollout, _probe, fused_rollout, sigmoid_form)
from usv_predictor.node import live

SHIPPED = Path(__file__).resolve().parents[1] / "models" / "default.pt"
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_node import row_form_batch  # noqa: E402 -- the candidates' former row form, timed there


def _member(feature_set: str, seed: int, activation: str, depth: int, increment: bool = True) -> DnnModel:
    """A random network of `depth` hidden layers with data-like normalisation and batch norm away from identity."""
    return artifact_member(feature_set, seed, activation, increment, depth)


def _loaded(path: Path) -> object:
    """The model as the node and `replay evaluate` load it (models/loading.load_model: fused for a DNN)."""
    return loading.load_model(str(path), physics=False)


@pytest.mark.parametrize("feature_set", sorted(FEATURE_SETS))
@pytest.mark.parametrize("activation, depth, increment", [("tanh", 2, True), ("tanh", 1, True), ("tanh", 3, False),
                                                          ("clipped_relu", 2, True)])
def test_fused_rollout_equals_the_members_stepped_one_by_one(tmp_path: Path, feature_set: str, activation: str,
                                                              depth: int, increment: bool) -> None:
    """float64: the fused ensemble (one batched product per layer for all members, tanh as sigmoid) equals each
    member's own network stepped one at a time (features.py each step, trapezoidal kinematics) and the file's
    rollout to rounding; three members, so a member mixed up with another would show."""
    members = [_member(feature_set, seed, activation, depth, increment) for seed in (1, 2, 3)]
    _export(tmp_path / "m.pt", members, dtype="float64")
    model = _loaded(tmp_path / "m.pt")
    assert model.inference is not None
    assert model.inference_note.startswith("fused")
    state, controls = _inputs(batch=4, horizon=40)
    got = model.predict(state, controls)  # (E, B, H, 6) through the fused rollout
    one = model.predict(state[:1], controls[:1])  # one state: NumpyDnnRollout's one-state form
    assert got.shape == (3, 4, 40, 6)
    assert one.shape == (3, 1, 40, 6)
    for e, member in enumerate(members):
        reference = _reference(member, feature_set, state, controls, DT)
        np.testing.assert_allclose(got[e], reference, rtol=0, atol=1e-9)
        np.testing.assert_allclose(one[e], reference[:1], rtol=0, atol=1e-9)
    with torch.inference_mode():
        own = model.module(torch.from_numpy(state), torch.from_numpy(controls)).numpy()
    np.testing.assert_allclose(got, own, rtol=0, atol=1e-10)
    assert np.abs(got[0] - got[1]).max() > 1e-3 and np.abs(got[1] - got[2]).max() > 1e-3  # different networks


def test_float32_fused_rollout_is_as_close_to_the_members_as_the_files(tmp_path: Path) -> None:
    """float32 (what the node runs): over 120 steps the fused rollout stays within the float32 tolerance of the
    members stepped one by one in float64, as the file's rollout does."""
    members = [_member("NTF", seed, "tanh", 2) for seed in (4, 5)]
    _export(tmp_path / "m.pt", members)
    model = _loaded(tmp_path / "m.pt")
    assert model.metadata["dtype"] == "float32"
    assert model.inference is not None
    state, controls = _inputs(horizon=120)
    got = model.predict(state, controls)
    with torch.inference_mode():
        own = model.module(torch.from_numpy(state), torch.from_numpy(controls)).double().numpy()
    for e, member in enumerate(members):
        reference = _reference(member, "NTF", state, controls, DT)
        np.testing.assert_allclose(got[e], reference, rtol=1e-4, atol=2e-3)
        np.testing.assert_allclose(own[e], reference, rtol=1e-4, atol=2e-3)


def test_sigmoid_form_is_the_same_function_one_step() -> None:
    """One step of the rewritten buffers equals the tanh network's step (float64, exact up to rounding), and the
    rewrite really moved the weights (a no-op rewrite would pass the rollout tests only if tanh == sigmoid)."""
    rollout = DnnRollout([_member("NTF", seed, "tanh", 2) for seed in (1, 2)], DT, torch.float64)
    params = {k: v for k, v in rollout.named_buffers()}
    n_s = params["m_s"].shape[1]
    rewritten = sigmoid_form(params, n_s)
    s = torch.tensor([[[4.0, 0.2, -0.05, 0.3, 0.2, 0.9]]]).double().expand(2, 1, n_s)  # (E, 1, S)
    c = torch.tensor([[[0.1, 640.0]]]).double()  # (1, 1, C)

    def step(p: dict, act) -> torch.Tensor:
        y = s @ p["m_s"] + c @ p["w_c"] + p["bias"]  # (E, 1, S + W)
        h = act(y[..., n_s:])
        for i in range(p["hidden_w"].shape[1]):
            h = act(h @ p["hidden_w"][:, i] + p["hidden_b"][:, i])
        return y[..., :n_s] + h @ p["head"]  # (E, 1, S)

    torch.testing.assert_close(step(rewritten, torch.sigmoid), step(params, torch.tanh), rtol=0, atol=1e-12)
    assert not torch.allclose(rewritten["hidden_w"], params["hidden_w"])


def test_fewer_members_are_the_first_members_of_the_full_ensemble(tmp_path: Path) -> None:
    members = [_member("NAF", seed, "tanh", 2) for seed in (1, 2, 3)]
    artifact = _export(tmp_path / "m.pt", members, dtype="float64")
    buffers = dict(artifact.module.named_buffers())
    arch = artifact.metadata["architecture"]
    two = torch.jit.script(FusedDnnRollout(buffers, feature_set="NAF", activation=arch["activation"],
                                           ceiling=arch["ceiling"], dt=DT, members=2))
    state, controls = _inputs()
    with torch.inference_mode():
        got = two(torch.from_numpy(state), torch.from_numpy(controls)).numpy()
    assert got.shape[0] == 2
    np.testing.assert_allclose(got, artifact.predict(state, controls)[:2], rtol=0, atol=1e-10)


def _shipped_inputs(batch: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Realistic states and controls of the shipped model (jari_usv: rudder rad, rpm), varying along the horizon."""
    rng = np.random.default_rng(seed)
    state = np.column_stack([rng.uniform(0.5, 7.0, batch), rng.uniform(-0.4, 0.4, batch),
                             rng.uniform(-0.15, 0.15, batch), rng.uniform(-math.pi, math.pi, batch)])
    ramp = np.linspace(0.0, 1.0, 120)
    delta = rng.uniform(-0.6, 0.6, (batch, 1)) * ramp + rng.uniform(-0.2, 0.2, (batch, 1))
    rpm = rng.uniform(300.0, 900.0, (batch, 1)) + 0.0 * ramp
    return state, np.stack([delta, rpm], axis=-1)  # (B, 4), (B, 120, 2)


@pytest.mark.parametrize("batch", [1, 64])
def test_shipped_model_fused_equals_its_own_rollout(batch: int) -> None:
    """models/default.pt (its file holds the plain network, as every artifact: the format is unchanged, it is fused
    when loaded): the fused rollout, one state and a 64-candidate batch, against the file's float32 rollout and against
    the file's network run in float64. The fused rollout's error from float64 is of the float32 rollout's own size."""
    model = _loaded(SHIPPED)
    assert model.inference is not None, model.inference_note
    state, controls = _shipped_inputs(batch, seed=batch)
    got = model.predict(state, controls)  # (5, B, 120, 6)
    with torch.inference_mode():
        own = model.module(torch.from_numpy(state), torch.from_numpy(controls)).double().numpy()
        exact = load_artifact(SHIPPED).module.double()(torch.from_numpy(state), torch.from_numpy(controls)).numpy()
    # u, v (m/s), r (rad/s), x_n, y_e (m, 60 s ahead), psi (rad)
    tolerance = np.array([2e-4, 2e-4, 2e-5, 1e-2, 1e-2, 5e-4])
    assert np.all(np.abs(got - own).max(axis=(0, 1, 2)) <= tolerance)
    fused_error = np.abs(got - exact).max(axis=(0, 1, 2))
    own_error = np.abs(own - exact).max(axis=(0, 1, 2))
    assert np.all(fused_error <= 3.0 * own_error + 1e-6), (fused_error, own_error)
    assert np.abs(got.mean(axis=0) - own.mean(axis=0))[..., 3:5].max() <= 5e-3  # the published (mean) track, m


def test_the_node_rollout_runs_the_fused_module() -> None:
    """live.Rollout (the node) and artifact.predict (`replay evaluate`) run the same fused module."""
    model = _loaded(SHIPPED)
    rollout = live.Rollout(model, 120)
    assert rollout.artifact.runner is model.inference
    assert rollout.module is model.inference
    state, held = np.array([5.0, 0.1, 0.02, 0.3]), np.array([0.2, 650.0])
    controls = np.tile(held, (1, 120, 1))
    np.testing.assert_array_equal(rollout(state, held), model.predict(state[None], controls)[:, 0])
    batch = np.tile(held, (8, 120, 1)) + np.linspace(-0.1, 0.1, 8)[:, None, None] * [1.0, 0.0]
    np.testing.assert_array_equal(rollout.batch(state, batch), model.predict(np.tile(state, (8, 1)), batch))


class _HalvedRollout(DnnRollout):
    """A DnnRollout of other semantics (its activations halved): the buffers look like a DnnRollout's, the function
    is another one."""

    def _activation_(self, h: torch.Tensor) -> torch.Tensor:
        return h.tanh_().mul_(0.5)


def test_a_dnn_file_that_cannot_be_fused_keeps_its_own_rollout(tmp_path: Path) -> None:
    members = [_member("NTF", 1, "tanh", 2)]
    good = _export(tmp_path / "good.pt", members, dtype="float64")
    path = tmp_path / "halved.pt"
    export_module(path, _HalvedRollout(members, DT, torch.float64), good.metadata)
    model = _loaded(path)
    assert model.inference is None
    assert "not fused" in model.inference_note
    assert "differs" in model.inference_note
    state, controls = _inputs()
    got = model.predict(state, controls)
    with torch.inference_mode():
        own = model.module(torch.from_numpy(state), torch.from_numpy(controls)).numpy()
    np.testing.assert_array_equal(got, own)  # the file's own rollout runs
    assert np.abs(got - good.predict(state, controls)).max() > 1e-2  # and it is another function than a fused one
    with pytest.raises(ModelError, match="differs from the file's"):
        fused_rollout(load_artifact(path))


def test_probe_inputs_are_the_training_data_statistics() -> None:
    metadata = load_artifact(SHIPPED).metadata
    state, controls = _probe(metadata)
    names, mean = metadata["feature_names"], metadata["normalisation"]["feature_mean"]
    assert controls.shape == (4, metadata["horizon_steps"], 2)
    np.testing.assert_allclose(state[:, 0].mean(), mean[names.index("u")], rtol=1e-12)
    np.testing.assert_allclose(controls[:, 0, 1].mean(), mean[names.index("rpm")], rtol=1e-12)
    assert np.ptp(state[:, 3]) > 5.0  # headings round the circle


def test_the_node_computes_only_the_members_it_uses() -> None:
    """ensemble_size 2 of the shipped 5: the node's module is fused with the first two members only, and its
    predictions are those two members of the full ensemble."""
    model = _loaded(SHIPPED)
    rollout = live.Rollout(model, 120, ensemble_size=2)
    state, held = np.array([5.0, 0.1, 0.02, 0.3]), np.array([0.2, 650.0])
    with torch.inference_mode():
        raw = rollout.module(torch.tensor(state[None], dtype=torch.float32),
                             torch.tensor(np.tile(held, (1, 120, 1)), dtype=torch.float32))
    assert raw.shape[0] == 2  # not five computed and three dropped
    got = rollout(state, held)
    full = model.predict(state[None], np.tile(held, (1, 120, 1)))[:, 0]
    assert got.shape == (2, 120, 6)
    np.testing.assert_allclose(got, full[:2], rtol=0, atol=1e-4)


def test_a_fused_rollout_that_cannot_be_built_leaves_the_next_form_running(tmp_path: Path, monkeypatch) -> None:
    """The forms are tried in turn when a model is loaded (also on a model swap in a running node): numpy's, then
    TorchScript's (compiled from its source file then: that can fail), then the file's own; each model says which
    runs and why the faster ones do not."""
    members = [_member("NTF", 1, "tanh", 2)]
    _export(tmp_path / "m.pt", members, dtype="float64")

    def numpy_broken(*args, **kwargs):
        raise ModelError("model m.pt: the numpy rollout differs from the file's by 1 (a test)")

    def broken(*args, **kwargs):
        raise RuntimeError("compilation failed\nsome TorchScript detail")

    state, controls = _inputs()
    with torch.inference_mode():
        own = load_artifact(tmp_path / "m.pt").module(torch.from_numpy(state), torch.from_numpy(controls)).numpy()
    monkeypatch.setattr(dnn, "numpy_rollout", numpy_broken)
    model = _loaded(tmp_path / "m.pt")
    assert isinstance(model.inference, torch.jit.ScriptModule)
    assert model.inference_note.startswith("fused (models/dnn.FusedDnnRollout")
    assert "(a test)" in model.inference_note
    np.testing.assert_allclose(model.predict(state, controls), own, rtol=0, atol=1e-10)
    monkeypatch.setattr(torch.jit, "script", broken)
    model = _loaded(tmp_path / "m.pt")
    assert model.inference is None
    assert "cannot be built or run: some TorchScript detail" in model.inference_note
    assert "(a test)" in model.inference_note
    np.testing.assert_array_equal(model.predict(state, controls), own)


@pytest.mark.parametrize("batch", [1, 64])
def test_numpy_rollout_equals_the_torchscript_fused_rollout(batch: int) -> None:
    """The shipped float32 model: numpy's rollout (what loads) against TorchScript's FusedDnnRollout (what loaded
    before) and the file's rollout, one state and 64 candidates: each float32 form's error from the float64 network
    is of the same size (numpy's within 3x the larger of the other two's), and numpy's and TorchScript's forms agree
    within float32 rounding amplified by 120 closed-loop steps (the tolerance below, ~1e-4 of each column's scale)."""
    model = _loaded(SHIPPED)
    assert isinstance(model.inference, NumpyDnnRollout)
    assert model.inference_note == NUMPY_FORM
    state, controls = _shipped_inputs(batch, seed=10 + batch)
    got = model.predict(state, controls)  # (5, B, 120, 6)
    scripted = fused_rollout(load_artifact(SHIPPED))
    with torch.inference_mode():
        fused = scripted(torch.from_numpy(state).float(), torch.from_numpy(controls).float()).double().numpy()
        own = model.module(torch.from_numpy(state), torch.from_numpy(controls)).double().numpy()
        exact = load_artifact(SHIPPED).module.double()(torch.from_numpy(state), torch.from_numpy(controls)).numpy()
    tolerance = np.array([1e-3, 2e-4, 5e-5, 1e-2, 1e-2, 5e-4])  # u, v (m/s), r (rad/s), x_n, y_e (m), psi (rad)
    assert np.all(np.abs(got - fused).max(axis=(0, 1, 2)) <= tolerance)
    numpy_error, fused_error, own_error = (np.abs(out - exact).max(axis=(0, 1, 2)) for out in (got, fused, own))
    assert np.all(numpy_error <= 3.0 * np.maximum(fused_error, own_error) + 1e-6), (numpy_error, fused_error, own_error)
    assert np.abs(got[0] - got[1]).max() > 1e-2  # the members differ: not one member copied five times


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_numpy_one_state_form_equals_its_batched_form(tmp_path: Path, dtype: str) -> None:
    """The node's one state runs the block-diagonal one-state form, candidates the stacked form: the same function
    (float64: to rounding; float32: within float32 rounding over 120 steps), for each member."""
    members = [_member("NTF", seed, "tanh", 2) for seed in (1, 2, 3)]
    _export(tmp_path / "m.pt", members, dtype=dtype)
    rollout = _loaded(tmp_path / "m.pt").inference
    state, controls = _inputs(batch=2, horizon=120)
    one = rollout.rollout(state[:1], controls[:1])
    batched = rollout._rollout_batch(state[:1], controls[:1])
    tolerance = 1e-10 if dtype == "float64" else 1e-3
    np.testing.assert_allclose(one, batched, rtol=0, atol=tolerance)
    assert np.abs(one[0] - one[1]).max() > 1e-2  # members differ (a block of one member used for another would show)


def test_numpy_bias_unit_is_exactly_one() -> None:
    """The bias unit's activation is 1 exactly (float32 and float64), so each layer's bias enters its product
    unscaled; a clippedReLU whose ceiling is below 1 has none and is refused (TorchScript's form then runs)."""
    rollout = NumpyDnnRollout.__new__(NumpyDnnRollout)
    rollout.clipped = False
    for dtype in (np.float32, np.float64):
        assert rollout._act(np.array([BIAS_UNIT_PRE], dtype=dtype))[0] == 1.0
    params = dict(DnnRollout([_member("NTF", 1, "clipped_relu", 2)], DT, torch.float32).named_buffers())
    with pytest.raises(ModelError, match="no exact bias unit"):
        NumpyDnnRollout(params, feature_set="NTF", activation="clipped_relu", ceiling=0.5, dt=DT)
    built = NumpyDnnRollout(params, feature_set="NTF", activation="clipped_relu", ceiling=1.5, dt=DT)
    assert built.first[0, -1, -1] == 1.0
    assert built.first.dtype == np.float32


def test_numpy_rollout_refuses_inputs_of_other_shapes() -> None:
    rollout = _loaded(SHIPPED).inference
    with pytest.raises(ValueError, match="controls must be"):
        rollout.rollout(np.zeros((2, 4)), np.zeros((3, 120, 2)))  # another batch
    with pytest.raises(ValueError, match="controls must be"):
        rollout.rollout(np.zeros((2, 4)), np.zeros((2, 120, 3)))  # another layout
    with pytest.raises(ValueError, match="state must be"):
        rollout.rollout(np.zeros((2, 5)), np.zeros((2, 120, 2)))


@pytest.mark.parametrize("feature_set, activation, depth", [("NTF", "tanh", 2), ("NAF", "tanh", 3),
                                                             ("F0", "clipped_relu", 1)])
def test_numpy_transposed_batch_form_equals_the_row_form(tmp_path: Path, feature_set: str, activation: str,
                                                         depth: int) -> None:
    """The candidates' form now runs transposed (the states the columns): in float64 it equals the row form it
    replaced to rounding, for 64 candidates and every member (the usual network's loop and the general one)."""
    members = [_member(feature_set, seed, activation, depth) for seed in (1, 2, 3)]
    _export(tmp_path / "m.pt", members, dtype="float64")
    rollout = _loaded(tmp_path / "m.pt").inference
    assert isinstance(rollout, NumpyDnnRollout)
    state, controls = _inputs(batch=64, horizon=60)
    got = rollout.rollout(state, controls)
    before = row_form_batch(rollout, state, controls)
    assert got.shape == (3, 64, 60, 6)
    np.testing.assert_allclose(got, before, rtol=0, atol=1e-10)
    assert np.abs(got[:, 0] - got[:, 1]).max() > 1e-3  # candidates differ: a column mixed up with another would show


def test_numpy_transposed_batch_form_of_the_shipped_model_is_the_row_forms_within_float32() -> None:
    """models/default.pt (float32), 64 candidates over 120 steps: the transposed form stays within float32 rounding
    of the row form (the bounds of test_numpy_rollout_equals_the_torchscript_fused_rollout)."""
    rollout = _loaded(SHIPPED).inference
    state, controls = _shipped_inputs(64, seed=77)
    got = rollout.rollout(state, controls)
    before = row_form_batch(rollout, state, controls)
    tolerance = np.array([1e-3, 2e-4, 5e-5, 1e-2, 1e-2, 5e-4])  # u, v (m/s), r (rad/s), x, y (m), psi (rad)
    assert np.all(np.abs(got - before).max(axis=(0, 1, 2)) <= tolerance), np.abs(got - before).max(axis=(0, 1, 2))


def _kinematics_as_before(dt: float, state: np.ndarray, path: np.ndarray) -> np.ndarray:
    """NumpyDnnRollout._kinematics in its former member-major form: (E, B, H + 1, ...) arrays."""
    e, b, horizon = path.shape[:3]
    path = path.astype(np.float64)
    full = np.concatenate([np.broadcast_to(state[None, :, None, :], (e, b, 1, 4)), path], axis=2)
    cos_psi, sin_psi = np.cos(full[..., 3]), np.sin(full[..., 3])
    velocity = np.stack([full[..., 0] * cos_psi - full[..., 1] * sin_psi,
                         full[..., 0] * sin_psi + full[..., 1] * cos_psi], axis=-1)
    out = np.empty((e, b, horizon, 6))
    out[..., 0:3] = path[..., 0:3]
    np.cumsum(0.5 * dt * (velocity[:, :, 1:] + velocity[:, :, :-1]), axis=2, out=out[..., 3:5])
    out[..., 5] = path[..., 3]
    return out


@pytest.mark.parametrize("batch", [1, 64])
def test_numpy_kinematics_step_major_equals_the_member_major_form(batch: int) -> None:
    """The positions are integrated step-major now (each quantity one (H + 1, E, B) array): the same operations in
    the same order, so the same numbers, bit for bit, from the batch form's (H, E, S, B) memory as from any view."""
    rollout = _loaded(SHIPPED).inference
    rng = np.random.default_rng(batch)
    x = rng.normal(0.0, 2.0, size=(121, 5, 9, batch)).astype(np.float32)  # as _rollout_batch's x
    path = x[1:, :, :4].transpose(1, 3, 0, 2)  # (E, B, H, 4) view
    state = rng.normal(0.0, 2.0, size=(batch, 4))
    got = rollout._kinematics(state, path)
    np.testing.assert_array_equal(got, _kinematics_as_before(rollout.dt, state, path))
    np.testing.assert_array_equal(got, rollout._kinematics(state, np.ascontiguousarray(path)))
    assert got.shape == (5, batch, 120, 6)
    assert np.abs(got[..., 3:5]).max() > 1.0


@pytest.mark.parametrize("count", [64, 7])
def test_candidates_split_across_two_threads_are_the_whole_batch_within_float32(count: int) -> None:
    """The node's candidates_threads 2 (live.Rollout.batch with a helper): the first half of the batch rolled out on
    another thread, the second here, concatenated in order: within float32 rounding of the whole batch in one call
    (BLAS may block a narrower product otherwise), and as far from the float64 network as the whole batch is."""
    from concurrent.futures import ThreadPoolExecutor

    model = _loaded(SHIPPED)
    rollout = live.Rollout(model, 120)
    _, controls = _shipped_inputs(count, seed=90 + count)
    state = np.array([5.0, 0.1, 0.02, 0.3])
    with ThreadPoolExecutor(max_workers=1) as helper:
        split = rollout.batch(state, controls, helper=helper)  # (5, count, 120, 6)
    whole = rollout.batch(state, controls)
    with torch.inference_mode():
        exact = load_artifact(SHIPPED).module.double()(torch.from_numpy(np.tile(state, (count, 1))),
                                                       torch.from_numpy(controls)).numpy()
    assert split.shape == whole.shape == (5, count, 120, 6)
    tolerance = np.array([1e-3, 2e-4, 5e-5, 1e-2, 1e-2, 5e-4])  # u, v (m/s), r (rad/s), x, y (m), psi (rad)
    assert np.all(np.abs(split - whole).max(axis=(0, 1, 2)) <= tolerance), np.abs(split - whole).max(axis=(0, 1, 2))
    split_error, whole_error = (np.abs(out - exact).max(axis=(0, 1, 2)) for out in (split, whole))
    assert np.all(split_error <= 3.0 * whole_error + 1e-6), (split_error, whole_error)
    assert np.abs(split[:, 0] - split[:, -1]).max() > 1e-2  # candidates differ: halves swapped or mixed would show
    np.testing.assert_array_equal(split[:, count // 2:], rollout.batch(state, controls[count // 2:]))  # the order
