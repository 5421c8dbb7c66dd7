#!/usr/bin/env bash
# Rebuild the shipped bags exactly (deterministic for the seeds below). Run from the repository root
# after ./run.sh setup:  bash bags/make_bags.sh
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
replay=${REPLAY:-.venv/bin/replay}
"$replay" simulate --programme sea_trial --sea rizhao --calm-twin --seed 2021 --output bags/sea_trial --overwrite
"$replay" simulate --programme training --sea rizhao --calm-twin --seed 2022 --output bags/training --overwrite
