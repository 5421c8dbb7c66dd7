"""Training (seed 000 sec. 2.2, Table 5 recipe): learning, reproducibility, early stopping, multi-step,
ensembles, and `replay train` end to end on a tiny simulated dataset. Tiny networks and few epochs."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from usv_predictor.data.dataset import build_dataset, save_dataset
from usv_predictor.data.recording import Recording, recording_from_signals
from usv_predictor.errors import ConfigError, DatasetError
from usv_predictor.fitting.training import (
    Samples,
    TrainingConfig,
    rollout_nu,
    samples_from_recordings,
    train_dnn,
    windows_from_recordings,
)  # fmt: skip
from usv_predictor.models.artifact import load_artifact
from usv_predictor.models.dnn import DnnConfig
from usv_predictor.physics.dynamics import ManoeuvringModel
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.manoeuvres import TurningCircle, ZigZag
from usv_predictor.physics.sensors import measure
from usv_predictor.physics.simulator import simulate
from usv_predictor.physics.vessel import load_vessel
from usv_predictor.replay import cli

TINY = DnnConfig.for_features("NTF", width=16)


@pytest.fixture(scope="module")
def recordings() -> list[Recording]:
    env = Environment(current_speed=0.3, current_to_deg=215.0)
    model = ManoeuvringModel(load_vessel("jari_usv"))
    runs = [TurningCircle(20, 650, duration_s=60), TurningCircle(15, 700, duration_s=60, side=-1),
            ZigZag(20, 20, 650, duration_s=60)]
    return [recording_from_signals(measure(simulate(model, m, env, seed=i), env, seed=i), 0.5, name=m.name)
            for i, m in enumerate(runs)]


@pytest.fixture(scope="module")
def splits(recordings: list[Recording]) -> tuple[Samples, Samples]:
    return samples_from_recordings(recordings[:2], "NTF"), samples_from_recordings(recordings[2:], "NTF")


def _recipe(**kwargs) -> TrainingConfig:
    return TrainingConfig(**{"epochs": 20, "batch_size": 32, "patience": None, **kwargs})


def test_samples_pair_each_step_with_the_next(recordings: list[Recording]) -> None:
    samples = samples_from_recordings(recordings[:1], "NTF")
    rec = recordings[0]
    assert samples.x.shape == (len(rec) - 1, 7)
    assert samples.y.shape == (len(rec) - 1, 3)
    np.testing.assert_array_equal(samples.x[5, :3], rec.nu[5])
    np.testing.assert_array_equal(samples.y[5], rec.nu[6])


def test_training_reduces_the_loss(splits: tuple[Samples, Samples]) -> None:
    result = train_dnn(TINY, *splits, _recipe())
    history = result.members[0].history
    assert len(history) == 20
    assert history[-1][0] < 0.5 * history[0][0]
    assert history[-1][1] < history[0][1]
    assert not result.models[0].training  # handed back in eval mode


def test_training_is_reproducible_for_a_seed(splits: tuple[Samples, Samples]) -> None:
    threads = torch.get_num_threads()
    torch.manual_seed(1234)
    expected_next = torch.rand(3)
    torch.manual_seed(1234)
    a = train_dnn(TINY, *splits, _recipe(epochs=5, seed=7))
    assert torch.equal(torch.rand(3), expected_next)  # the caller's RNG stream is untouched
    assert torch.get_num_threads() == threads
    b = train_dnn(TINY, *splits, _recipe(epochs=5, seed=7))
    c = train_dnn(TINY, *splits, _recipe(epochs=5, seed=8))
    assert a.members[0].history == b.members[0].history
    for key, value in a.models[0].state_dict().items():
        assert torch.equal(value, b.models[0].state_dict()[key]), key
    assert a.members[0].history != c.members[0].history


def test_early_stopping_restores_the_best_weights(splits: tuple[Samples, Samples]) -> None:
    # a high learning rate without decay makes the validation loss wander, so the best epoch is early
    recipe = _recipe(epochs=60, patience=5, learning_rate=0.05, lr_schedule="constant")
    result = train_dnn(TINY, *splits, recipe)
    member = result.members[0]
    val = [v for _, v in member.history]
    assert member.best_epoch == int(np.argmin(val)) + 1
    assert member.val_loss == min(val)
    assert member.epochs_run == member.best_epoch + 5 < 60  # stopped `patience` epochs after the best
    model = result.models[0]
    x, y = (torch.as_tensor(a, dtype=torch.float32) for a in (splits[1].x, splits[1].y))
    with torch.no_grad():
        restored = torch.mean((model.forward_normalised(x) - model.normalised_target(x, y)) ** 2).item()
    assert restored == pytest.approx(member.val_loss, rel=1e-5)


def test_without_validation_the_training_loss_is_monitored(splits: tuple[Samples, Samples]) -> None:
    result = train_dnn(TINY, splits[0], None, _recipe(epochs=3))
    assert result.monitor == "train"
    assert result.val_loss is None
    assert result.n_val == 0
    assert all(m.val_loss is None and all(v is None for _, v in m.history) for m in result.members)
    assert result.summary()["val_loss"] == [None]  # JSON null, not NaN (a NaN once crashed the JSON writer)


def test_learning_rate_decays_stepwise() -> None:
    from usv_predictor.fitting.training import _learning_rate

    recipe = TrainingConfig()
    assert [_learning_rate(recipe, e) for e in (0, 99, 100, 250)] == pytest.approx([0.005, 0.005, 0.0025, 0.00125])
    cosine = TrainingConfig(lr_schedule="cosine", epochs=11)
    assert _learning_rate(cosine, 0) == pytest.approx(0.005)
    assert _learning_rate(cosine, 10) == pytest.approx(5e-5)


def test_windows_follow_the_recording(recordings: list[Recording]) -> None:
    rec = recordings[0]
    w = windows_from_recordings([rec], 4)
    assert w.state0.shape == (len(rec) - 4, 4)
    assert w.controls.shape == (len(rec) - 4, 4, 2)
    np.testing.assert_array_equal(w.state0[3], rec.state()[3])
    np.testing.assert_array_equal(w.controls[3], rec.controls[3:7])
    np.testing.assert_array_equal(w.targets[3], rec.nu[4:8])
    assert w.dt == 0.5


def test_one_step_rollout_equals_the_network(splits: tuple[Samples, Samples], recordings: list[Recording]) -> None:
    model = train_dnn(TINY, *splits, _recipe(epochs=2)).models[0]
    w = windows_from_recordings(recordings[:1], 1)
    state0, controls = torch.as_tensor(w.state0, dtype=torch.float32), torch.as_tensor(w.controls, dtype=torch.float32)
    x = torch.as_tensor(samples_from_recordings(recordings[:1], "NTF").x, dtype=torch.float32)
    with torch.no_grad():
        torch.testing.assert_close(rollout_nu(model, "NTF", state0, controls, 0.5)[:, 0], model(x))


def test_multi_step_training_runs_and_learns(splits: tuple[Samples, Samples], recordings: list[Recording]) -> None:
    k = 4
    result = train_dnn(TINY, *splits, _recipe(epochs=8, multi_step=k),
                       train_windows=windows_from_recordings(recordings[:2], k),
                       val_windows=windows_from_recordings(recordings[2:], k))
    history = result.members[0].history
    assert all(math.isfinite(t) and math.isfinite(v) for t, v in history)
    assert history[-1][0] < history[0][0]
    assert result.summary()["loss"].endswith("rollout_4")
    with pytest.raises(DatasetError, match="windows"):
        train_dnn(TINY, *splits, _recipe(multi_step=k))
    with pytest.raises(ConfigError, match="steps"):
        train_dnn(TINY, *splits, _recipe(multi_step=3), train_windows=windows_from_recordings(recordings[:2], k))


def test_ensemble_members_differ(splits: tuple[Samples, Samples]) -> None:
    result = train_dnn(TINY, *splits, _recipe(epochs=5, ensemble=3, seed=11))
    assert [m.seed for m in result.members] == [11, 12, 13]
    x = torch.as_tensor(splits[1].x, dtype=torch.float32)
    with torch.no_grad():
        predictions = torch.stack([m(x) for m in result.models])  # (E, N, 3)
    assert predictions.std(dim=0).mean() > 0.0


def test_empty_training_set_is_a_clear_error() -> None:
    with pytest.raises(DatasetError, match="no samples"):
        train_dnn(TINY, Samples(np.zeros((0, 7)), np.zeros((0, 3))))
    with pytest.raises(ConfigError, match="columns"):
        train_dnn(TINY, Samples(np.zeros((10, 5)), np.zeros((10, 3))))
    with pytest.raises(ConfigError, match="patience"):
        TrainingConfig(patience=0)


# ------------------------------------------------------------------ replay train


@pytest.fixture(scope="module")
def dataset_file(recordings: list[Recording], tmp_path_factory: pytest.TempPathFactory) -> Path:
    splits = {recordings[0].name: "train", recordings[1].name: "train", recordings[2].name: "val"}
    path = tmp_path_factory.mktemp("data") / "tiny.npz"
    save_dataset(path, build_dataset(recordings, "NTF", splits=splits))
    return path


def test_replay_train_end_to_end(dataset_file: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    model, report = tmp_path / "m.pt", tmp_path / "train.json"
    code = cli.main(["train", str(dataset_file), "--output", str(model), "--epochs", "3", "--width", "8",
                     "--json", str(report), "--progress-s", "0"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "epoch 3/3" in captured.err
    assert "model_id" in captured.out
    summary = json.loads(report.read_text())
    artifact = load_artifact(model, expect={"dt": 0.5, "feature_set": "NTF"})
    assert summary["model_id"] == artifact.model_id
    assert summary["epochs_run"] == [3]
    assert artifact.metadata["training"]["recipe"]["epochs"] == 3
    assert artifact.metadata["architecture"]["width"] == 8
    assert artifact.embedded_vessel == load_vessel("jari_usv")  # the config's vessel, whole, in the model
    assert artifact.predict(np.array([[5.0, 0.0, 0.0, 0.0]]), np.zeros((1, 4, 2)) + [0.0, 650.0]).shape == (1, 1, 4, 6)


def test_replay_train_other_features_multi_step_ensemble(dataset_file: Path, tmp_path: Path) -> None:
    model = tmp_path / "m.pt"
    code = cli.main(["train", str(dataset_file), "--output", str(model), "--epochs", "2", "--width", "8",
                     "--features", "NAF", "--multi-step", "3", "--ensemble", "2", "--activation", "clipped_relu"])
    assert code == 0
    artifact = load_artifact(model)
    assert artifact.metadata["feature_set"] == "NAF"
    assert artifact.ensemble_size == 2
    assert artifact.metadata["training"]["recipe"]["multi_step"] == 3


def test_replay_train_empty_training_split(recordings: list[Recording], tmp_path: Path,
                                           capsys: pytest.CaptureFixture) -> None:
    path = tmp_path / "val_only.npz"
    save_dataset(path, build_dataset(recordings[:1], "NTF", splits={recordings[0].name: "val"}))
    code = cli.main(["train", str(path), "--output", str(tmp_path / "m.pt"), "--epochs", "1"])
    err = capsys.readouterr().err
    assert code == 2
    assert "train split has no samples" in err
    assert str(path) in err
    assert not (tmp_path / "m.pt").exists()
