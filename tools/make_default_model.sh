#!/usr/bin/env bash
# Rebuild models/default.pt, the model the `predictor` node loads when model_path is "".
#
#   bash tools/make_default_model.sh [OUT_DIR]     (default OUT_DIR: out/default_model)
#
# Deterministic (for the same OUT_DIR, which the metadata records): the dataset split (--seed 0), the training seeds (0..4) and the torch threads (1) are
# fixed, so the same bags and software give the same weights (the model_id in models/README.md).
# Data: the shipped bags with the sea (bags/training + bags/sea_trial; calm/ twins are skipped).
# Held out: the 20 deg / 700 rpm sea-trial turn (test split, never seen in training or early stopping).
# Recipe: the seed 000 DNN, NTF features, tanh, 2 x 100, Table 5 defaults; an ensemble of 5 so the
# node can publish the prediction spread. About 5-10 minutes on 2 CPU cores.
set -euo pipefail

REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
OUT=${1:-out/default_model}  # relative to the repository: it is recorded in the model metadata
REPLAY=${REPLAY:-"$REPO/.venv/bin/replay"}
HELD_OUT="turning_circle_stbd_20deg_700rpm"
cd "$REPO"
mkdir -p "$OUT" models

"$REPLAY" dataset bags/training bags/sea_trial --features NTF --dt 0.5 --seed 0 \
    --test "$HELD_OUT" --val 0.2 --output "$OUT/dataset.npz" --json "$OUT/dataset.json"
"$REPLAY" train "$OUT/dataset.npz" --activation tanh --ensemble 5 --seed 0 --threads 1 \
    --output "$OUT/default.pt" --json "$OUT/train.json"
"$REPLAY" evaluate bags/sea_trial/"$HELD_OUT" --model "$OUT/default.pt" --json "$OUT/evaluate_held_out.json"
cp "$OUT/default.pt" "$REPO/models/default.pt"
echo "wrote $REPO/models/default.pt (details in $OUT)"
