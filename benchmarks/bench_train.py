"""Benchmark: seed 000's 500-epoch recipe (Table 5) on the shipped sea-trial set, ours vs a plain loop.

    .venv/bin/python benchmarks/bench_train.py [--epochs 500] [--dataset DATASET.npz]

Builds the dataset from bags/sea_trial (6 turning circles, 2 Hz, NTF; val = 1 manoeuvre) unless one is
given, then times in the same run:
  ours, 500 epochs        usv_predictor.fitting.training.train_dnn, patience off (all epochs)
  ours, early stopping    the same with patience 50 (restores the best epoch)
  ours, absolute target   the paper's target [u, v, r]_{k+1} instead of the increment (accuracy check)
  reference               a plain eager loop: DataLoader(TensorDataset, shuffle), torch's default
                          threads, one Adam with weight_decay on everything, no other care
and prints times and validation RMSE of the one-step prediction in physical units (m/s, m/s, rad/s),
so the increment target's gain is measured, not claimed.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]


def build_dataset(out: Path) -> Path:
    from usv_predictor.replay import cli

    code = cli.main(["dataset", str(REPO / "bags" / "sea_trial"), "--output", str(out), "--val", "*20deg_700rpm"])
    if code != 0:
        sys.exit(f"building the dataset failed (exit {code})")
    return out


def rmse(model: torch.nn.Module, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        pred = model.eval()(torch.as_tensor(x, dtype=torch.float32)).double().numpy()
    return np.sqrt(np.mean((pred - y) ** 2, axis=0))  # (3,) u, v, r


def reference_loop(config, train, val, epochs: int) -> tuple[torch.nn.Module, float]:
    """What one writes first: DataLoader, default threads, no RNG/thread care."""
    from torch.utils.data import DataLoader, TensorDataset

    from usv_predictor.models.dnn import DnnModel, fit_normalisation

    torch.manual_seed(0)
    model = DnnModel(config, fit_normalisation(train.x, train.y, config.predict_increment))
    x, y = torch.as_tensor(train.x, dtype=torch.float32), torch.as_tensor(train.y, dtype=torch.float32)
    loader = DataLoader(TensorDataset(x, y), batch_size=128, shuffle=True, drop_last=True)
    optimizer = torch.optim.Adam(model.parameters(), lr=0.005, weight_decay=1e-4)
    schedule = torch.optim.lr_scheduler.StepLR(optimizer, step_size=100, gamma=0.5)
    xv, yv = torch.as_tensor(val.x, dtype=torch.float32), torch.as_tensor(val.y, dtype=torch.float32)
    started = time.perf_counter()
    for _ in range(epochs):
        model.train()
        for xb, yb in loader:
            loss = torch.nn.functional.mse_loss(model.forward_normalised(xb), model.normalised_target(xb, yb))
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        schedule.step()
        model.eval()
        with torch.no_grad():
            torch.nn.functional.mse_loss(model.forward_normalised(xv), model.normalised_target(xv, yv))
    return model, time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--epochs", type=int, default=500)
    parser.add_argument("--dataset", type=Path, default=None)
    args = parser.parse_args()

    from usv_predictor.data.dataset import load_dataset
    from usv_predictor.fitting.training import Samples, TrainingConfig, train_dnn
    from usv_predictor.models.dnn import DnnConfig

    with tempfile.TemporaryDirectory() as tmp:
        path = args.dataset or build_dataset(Path(tmp) / "sea_trial.npz")
        dataset = load_dataset(path)
    tr, va = dataset.split("train"), dataset.split("val")
    train, val = Samples(tr.X, tr.Y), Samples(va.X, va.Y)
    print(f"dataset: {len(train)} training / {len(val)} validation samples, {dataset.feature_set}, dt {dataset.dt} s, "
          f"torch {torch.__version__}, {torch.get_num_threads()} default threads")
    config = DnnConfig.for_features(dataset.feature_set)
    rows = []

    def ours(name: str, cfg: DnnConfig, patience: int | None) -> None:
        result = train_dnn(cfg, train, val, TrainingConfig(epochs=args.epochs, patience=patience))
        m = result.members[0]
        rows.append((name, result.time_s, m.epochs_run, m.best_epoch, rmse(result.models[0], val.x, val.y)))

    ours("ours, all epochs", config, None)
    ours("ours, early stopping (patience 50)", config, 50)
    ours("ours, absolute target (paper), all epochs",
         DnnConfig.for_features(dataset.feature_set, predict_increment=False), None)
    model, seconds = reference_loop(config, train, val, args.epochs)
    rows.append(("reference: DataLoader, default threads", seconds, args.epochs, args.epochs,
                 rmse(model, val.x, val.y)))

    print(f"\n{'run':44s} {'time s':>8s} {'epochs':>7s} {'best':>5s}   val RMSE u, v (m/s), r (deg/s)")
    for name, seconds, run, best, err in rows:
        print(f"{name:44s} {seconds:8.2f} {run:7d} {best:5d}   {err[0]:.4f} {err[1]:.4f} {np.degrees(err[2]):.3f}")
    print(f"\nspeed-up of ours (all epochs) over the reference: {rows[3][1] / rows[0][1]:.1f}x")


if __name__ == "__main__":
    main()
