#!/usr/bin/env bash
# Rebuild the shipped bags exactly (deterministic for the seeds below). Run from the repository root
# after ./run.sh setup:  bash bags/make_bags.sh
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
replay=${REPLAY:-.venv/bin/replay}
"$replay" simulate --programme sea_trial --sea rizhao --calm-twin --seed 2021 --output bags/sea_trial --overwrite
"$replay" simulate --programme training --sea rizhao --calm-twin --seed 2022 --output bags/training --overwrite

# The Otter-class twin-thruster USV (config/vessels/otter.yaml) in a sheltered-water sea that suits a 2 m boat:
# current 0.2 m/s toward 215 deg, wind 4.5 m/s from 135 deg (gusts 0.8 m/s), H_s 0.25 m waves from 140 deg (T_p 2 s).
# One manoeuvre per call (each with its own seed and approach heading), every bag with its calm twin; short runs
# (60-90 s: a 2 m boat turns a circle in about 30 s) keep the set at a few MB.
otter_sea=(--effect current --current-speed 0.2 --current-to 215
           --effect wind --wind-speed 4.5 --wind-from 135 --gust-std 0.8
           --effect wave_drift --wave-height 0.25 --wave-from 140 --wave-period 2)
otter() {  # otter OUTPUT SEED HEADING MANOEUVRE-OPTIONS...
    local output=$1 seed=$2 heading=$3
    shift 3
    "$replay" simulate --vessel otter "$@" "${otter_sea[@]}" --heading "$heading" --calm-twin --seed "$seed" \
        --output "$output" --overwrite
}
rm -rf bags/otter
# sea trial: turning circles both ways at two differential/throttle settings
otter bags/otter/sea_trial 3101 0 --manoeuvre turning-circle --differential 0.4 --throttle 0.6 --side starboard --duration 60
otter bags/otter/sea_trial 3102 90 --manoeuvre turning-circle --differential 0.4 --throttle 0.6 --side port --duration 60
otter bags/otter/sea_trial 3103 180 --manoeuvre turning-circle --differential 0.8 --throttle 0.8 --side starboard --duration 60
otter bags/otter/sea_trial 3104 270 --manoeuvre turning-circle --differential 0.8 --throttle 0.8 --side port --duration 60
# training: zig-zags in differential both ways, a pull-out (a turn, then straight running), a random run
otter bags/otter/training 3201 37 --manoeuvre zigzag --differential 0.4 --check 20 --throttle 0.6 --side starboard --duration 60
otter bags/otter/training 3202 127 --manoeuvre zigzag --differential 0.6 --check 20 --throttle 0.7 --side port --duration 60
otter bags/otter/training 3203 217 --manoeuvre pullout --differential 0.4 --throttle 0.8 --side port --duration 70
otter bags/otter/training 3204 307 --manoeuvre random --differential 0.6 --throttle 0.6 --duration 90
# calm day: the trials docs/your_boat.md "Calm-day trials per layout" lists for twin_thrusters (the `calm_day`
# programme: turns at two differentials, zig-zags, straight runs at two throttles, spins), in calm water
"$replay" simulate --vessel otter --programme calm_day --heading 20 --seed 3301 --output bags/otter/calm_day --overwrite
