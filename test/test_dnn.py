"""The seed 000 network: shapes, activations (eq. 1-2), batch-norm folding, features on tensors == on arrays."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from usv_predictor.data.features import FEATURE_SETS, features
from usv_predictor.errors import ConfigError
from usv_predictor.frames import wrap_angle
from usv_predictor.models.dnn import ClippedReLU, DnnConfig, DnnModel, fit_normalisation


def _data(feature_set: str, n: int = 256, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    state = np.column_stack([rng.normal(5, 1, n), rng.normal(0, .3, n), rng.normal(0, .1, n), rng.uniform(-9, 9, n)])
    controls = np.column_stack([rng.normal(0, .3, n), rng.normal(650, 30, n)])
    return features(feature_set, state, controls), state[:, :3] + rng.normal(0, .05, (n, 3))


def _model(feature_set: str = "NTF", **kwargs) -> tuple[DnnModel, torch.Tensor]:
    config = DnnConfig.for_features(feature_set, width=16, **kwargs)
    x, y = _data(feature_set)
    torch.manual_seed(0)
    model = DnnModel(config, fit_normalisation(x, y, config.predict_increment))
    with torch.no_grad():  # batch norm statistics and affine parameters away from the identity
        for block in model.hidden:
            if isinstance(block[1], torch.nn.BatchNorm1d):
                block[1].running_mean.normal_()
                block[1].running_var.uniform_(0.5, 2.0)
                block[1].weight.normal_(1.0, 0.2)
                block[1].bias.normal_()
    return model.eval(), torch.as_tensor(x, dtype=torch.float32)


@pytest.mark.parametrize("feature_set", sorted(FEATURE_SETS))
@pytest.mark.parametrize("activation", ["tanh", "clipped_relu"])
def test_shapes_for_every_feature_set_and_activation(feature_set: str, activation: str) -> None:
    model, x = _model(feature_set, activation=activation)
    assert x.shape == (256, len(FEATURE_SETS[feature_set]))
    assert model(x).shape == (256, 3)
    assert model.forward_normalised(x).shape == (256, 3)
    model.train()
    assert model(x[:8]).shape == (8, 3)


def test_paper_defaults() -> None:
    config = DnnConfig()
    assert (config.width, config.depth, config.activation, config.batch_norm) == (100, 2, "tanh", True)
    model = DnnModel(config)
    assert [type(m).__name__ for m in model.hidden[0]] == ["Linear", "BatchNorm1d", "Tanh"]
    assert len(model.hidden) == 2
    assert model.head.out_features == 3


def test_clipped_relu_clips_at_the_ceiling() -> None:
    act = ClippedReLU(2.0)
    out = act(torch.tensor([-3.0, -0.0, 0.5, 2.0, 7.0]))
    assert out.tolist() == [0.0, 0.0, 0.5, 2.0, 2.0]
    # inside a network: every hidden activation lies in [0, ceiling] and some reach it
    model, x = _model("NTF", activation="clipped_relu", ceiling=0.3)
    seen = []
    for block in model.hidden:
        block[2].register_forward_hook(lambda _m, _i, out: seen.append(out.detach()))
    model(x * 10.0)
    values = torch.cat([s.flatten() for s in seen])
    assert values.min() >= 0.0
    assert values.max() == pytest.approx(0.3)
    assert (values == 0.3).any()
    assert (values == 0.0).any()


def test_tanh_hidden_activations_are_bounded_without_clipping() -> None:
    model, x = _model("NTF", activation="tanh")
    seen = []
    model.hidden[0][2].register_forward_hook(lambda _m, _i, out: seen.append(out.detach()))
    model(x)
    assert seen[0].abs().max() < 1.0
    assert (seen[0] < 0).any()


@pytest.mark.parametrize("activation", ["tanh", "clipped_relu"])
def test_fold_batch_norm_gives_equal_outputs(activation: str) -> None:
    model, x = _model("NAF", activation=activation)
    folded = model.fold_batch_norm()
    assert not any(isinstance(m, torch.nn.BatchNorm1d) for m in folded.modules())
    assert any(isinstance(m, torch.nn.BatchNorm1d) for m in model.modules())  # the original is untouched
    torch.testing.assert_close(folded(x), model(x), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("increment", [True, False])
def test_affine_layers_reproduce_the_model(increment: bool) -> None:
    model, x = _model("NTF", predict_increment=increment)
    layers = model.affine_layers()
    h = x.double()
    for w, b in layers[:-1]:
        h = torch.tanh(h @ w.T + b)
    w, b = layers[-1]
    out = h @ w.T + b + (x.double()[:, :3] if increment else 0.0)
    torch.testing.assert_close(out, model.double()(x.double()), rtol=1e-10, atol=1e-10)


def test_increment_target_adds_the_current_motion() -> None:
    model, x = _model("F0", predict_increment=True)
    with torch.no_grad():
        model.head.weight.zero_()
        model.head.bias.zero_()
        model.y_mean.zero_()
    torch.testing.assert_close(model(x), x[:, :3])  # zero increment: the motion carries on
    y = x[:, :3] + 1.0
    torch.testing.assert_close(model.normalised_target(x, y), (1.0 - model.y_mean) / model.y_std.expand(len(x), 3))


def test_normalisation_is_stored_as_buffers_and_survives_state_dict() -> None:
    model, _ = _model("NTF")
    clone = DnnModel(model.config)
    clone.load_state_dict(model.state_dict())
    norm = clone.normalisation()
    assert np.allclose(norm.feature_mean, model.x_mean.numpy())
    assert np.all(norm.feature_std > 0)
    assert {"x_mean", "x_std", "y_mean", "y_std"} <= set(dict(model.named_buffers()))


def test_constant_feature_is_centred_not_divided_by_zero() -> None:
    x, y = _data("F0")
    x[:, 4] = 650.0  # one engine speed in the whole data set
    norm = fit_normalisation(x, y, True)
    assert norm.feature_std[4] == 1.0
    assert norm.feature_mean[4] == 650.0


@pytest.mark.parametrize("feature_set", sorted(FEATURE_SETS))
def test_features_of_tensors_equal_features_of_arrays(feature_set: str) -> None:
    """One implementation, two array types: the training loss (torch) sees what the dataset (numpy) saw."""
    rng = np.random.default_rng(3)
    state = np.column_stack([rng.normal(5, 1, 64), rng.normal(0, .3, 64), rng.normal(0, .1, 64),
                             rng.uniform(-40, 40, 64)])
    state[:6, 3] = [math.pi, -math.pi, 3 * math.pi, 0.0, -1e-12, 2 * math.pi]  # the wrap boundaries
    controls = np.column_stack([rng.normal(0, .3, 64), rng.normal(650, 30, 64)])
    expected = features(feature_set, state, controls)
    got = features(feature_set, torch.from_numpy(state), torch.from_numpy(controls)).numpy()
    assert got.shape == expected.shape
    np.testing.assert_array_max_ulp(got, expected, maxulp=2)
    batched = features(feature_set, torch.from_numpy(state).reshape(8, 8, 4),
                       torch.from_numpy(controls).reshape(8, 8, 2))
    assert batched.shape == (8, 8, len(FEATURE_SETS[feature_set]))


def test_the_one_wrap_helper_is_half_open_on_tensors() -> None:
    wrapped = wrap_angle(torch.tensor([math.pi, -math.pi, 3 * math.pi, 0.5], dtype=torch.float64))
    assert wrapped.tolist() == pytest.approx([-math.pi, -math.pi, -math.pi, 0.5])


@pytest.mark.parametrize("kwargs, field", [
    ({"feature_set": "XYZ"}, "feature_set"),
    ({"n_features": 3}, "n_features"),
    ({"activation": "relu"}, "activation"),
    ({"width": 0}, "width"),
    ({"ceiling": 0.0}, "ceiling"),
])  # fmt: skip
def test_config_errors_name_the_field(kwargs: dict, field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        DnnConfig(**kwargs)


def test_config_round_trips_through_a_dict() -> None:
    config = DnnConfig.for_features("NAF", width=32, activation="clipped_relu", ceiling=4.0)
    assert DnnConfig.from_dict(config.to_dict()) == config
    with pytest.raises(ConfigError, match="unknown DnnConfig field"):
        DnnConfig.from_dict({**config.to_dict(), "dropout": 0.1})
