"""`replay train DATASET.npz --output model.pt`: train the seed 000 network and export the model artifact.

Trains on the dataset's `train` split, early-stops on its `val` split (without one, the training loss
picks the best epoch), and writes one TorchScript file with its metadata (usv_predictor.models.artifact).
The recipe defaults are seed 000 Table 5 (usv_predictor.fitting.training). Progress (member, epoch, losses) goes
to stderr at most every --progress-s seconds; the result (losses, best epoch, time, model_id) to stdout
and --json. The work: usv_predictor.replay.train.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from usv_predictor.replay.options import log, non_negative_float, non_negative_int, positive_float, positive_int

NAME = "train"
HELP = "train the seed 000 motion network on a dataset and export the TorchScript model artifact"
INPUTS = ("dataset",)
OUTPUTS = {"output": "file"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dataset", type=Path, metavar="DATASET.npz", help="dataset written by `replay dataset`")
    parser.add_argument("--output", "-o", type=Path, required=True, metavar="MODEL.pt", help="model artifact to write")
    parser.add_argument("--features", choices=("F0", "NAF", "NTF"), default=None,
                        help="feature set (default: the dataset's; another set is recomputed from its recordings)")
    parser.add_argument("--activation", choices=("tanh", "clipped_relu"), default="tanh",
                        help="hidden activation, seed 000 eq. 2 / eq. 1 (default tanh)")
    parser.add_argument("--ceiling", type=positive_float, default=10.0, help="clippedReLU ceiling (default 10)")
    parser.add_argument("--width", type=positive_int, default=100, help="hidden units per layer (default 100)")
    parser.add_argument("--depth", type=positive_int, default=2, help="hidden layers (default 2)")
    parser.add_argument("--no-batch-norm", action="store_true", help="leave out batch normalisation")
    parser.add_argument("--absolute-target", action="store_true",
                        help="predict [u, v, r] at the next step as in the paper instead of the increment")
    parser.add_argument("--epochs", type=positive_int, default=500, help="maximum epochs (default 500)")
    parser.add_argument("--patience", type=non_negative_int, default=50,
                        help="stop after this many epochs without validation improvement; 0: never (default 50)")
    parser.add_argument("--batch-size", type=positive_int, default=128, help="mini-batch size (default 128)")
    parser.add_argument("--lr", type=positive_float, default=0.005, help="initial learning rate (default 0.005)")
    parser.add_argument("--lr-schedule", choices=("step", "cosine", "constant"), default="step",
                        help="learning-rate decay (default step: x0.5 every 100 epochs)")
    parser.add_argument("--l2", type=non_negative_float, default=1e-4, help="L2 regularisation (default 1e-4)")
    parser.add_argument("--multi-step", type=positive_int, default=1, metavar="K",
                        help="train on closed-loop rollouts of K steps (default 1: one-step, as the paper)")
    parser.add_argument("--ensemble", type=positive_int, default=1, metavar="E", help="ensemble members (default 1)")
    parser.add_argument("--seed", type=non_negative_int, default=0, help="random seed (default 0)")
    parser.add_argument("--threads", type=positive_int, default=1, help="torch threads while training (default 1)")
    parser.add_argument("--vessel", default=None,
                        help="vessel preset or YAML file the bags were recorded on, embedded in the model (its whole "
                             "description); its actuator layout must be the dataset's (default: the config's)")
    parser.add_argument("--horizon-steps", type=positive_int, default=None,
                        help="default prediction horizon in steps recorded in the model (default: the config's)")
    parser.add_argument("--dtype", choices=("float32", "float64"), default="float32",
                        help="arithmetic of the exported rollout (default float32)")
    parser.add_argument("--progress-s", type=non_negative_float, default=2.0,
                        help="seconds between progress lines (default 2)")


class _Throttled:
    """Progress to stderr: at most one line per `every` seconds, and always the member's first epoch."""

    def __init__(self, every: float, epochs: int) -> None:
        self.every = every
        self.epochs = epochs
        self.last = -float("inf")

    def __call__(self, member: int, epoch: int, train_loss: float, val_loss: float | None) -> None:
        now = time.monotonic()
        if epoch == 1 or now - self.last >= self.every:
            self.last = now
            val = "-" if val_loss is None else f"{val_loss:.5g}"
            print(f"member {member} epoch {epoch}/{self.epochs}: train {train_loss:.5g} val {val}", file=sys.stderr)


def run(args: argparse.Namespace) -> dict[str, Any]:
    # heavy imports here: `replay --help` must not import torch
    from usv_predictor.errors import ConfigError
    from usv_predictor.fitting.training import TrainingConfig
    from usv_predictor.models.loading import resolve_vessel
    from usv_predictor.replay.train import Architecture, TrainRequest, train

    if args.patience < 0:
        raise ConfigError(f"--patience {args.patience}: expected >= 0 (0: never stop early)")
    recipe = TrainingConfig(epochs=args.epochs, batch_size=args.batch_size, learning_rate=args.lr,
                            lr_schedule=args.lr_schedule, weight_decay=args.l2, patience=args.patience or None,
                            multi_step=args.multi_step, ensemble=args.ensemble, seed=args.seed, threads=args.threads)
    architecture = Architecture(width=args.width, depth=args.depth, activation=args.activation, ceiling=args.ceiling,
                                batch_norm=not args.no_batch_norm, predict_increment=not args.absolute_target)
    request = TrainRequest(dataset=args.dataset, output=args.output, vessel=resolve_vessel(args.vessel),
                           recipe=recipe, architecture=architecture, features=args.features,
                           horizon_steps=args.horizon_steps, dtype=args.dtype)
    summary = train(request, progress=_Throttled(args.progress_s, recipe.epochs), log=log)
    loss = summary["val_loss"] if summary["monitor"] == "val" else summary["train_loss"]
    print(f"wrote {args.output} (model_id {summary['model_id']}): best epoch {summary['best_epoch']}, "
          f"train loss {summary['train_loss']:.5g}, {summary['monitor']} loss {loss:.5g}, {summary['time_s']:.1f} s")
    return summary
