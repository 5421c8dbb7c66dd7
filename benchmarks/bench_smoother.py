#!/usr/bin/env python3
"""The EKF/RTS smoother's compiled loops (new) against its numpy loops (old), in one run, and Ctrl-C inside them.

    nice -n 10 python benchmarks/bench_smoother.py [--repeats 7] [--interrupts 60]

time        per shipped recording of bags/training (read at identify's 0.2 s), the smoother at the noise model
            identification tunes: old and new alternately `--repeats` times, medians in ms and old / new, and the
            largest difference of the smoothed states (relative to each column's largest value).
interrupts  `--interrupts N` Ctrl-C's (_thread.interrupt_main: what SIGINT does to the main thread) at random moments
            of a loop over the recordings' compiled smoothing (first 0-0.3 s): how each surfaced, KeyboardInterrupt
            or SystemError (the failure data/smoother.py's compiled entries are written to avoid).
The load average is printed before and after.
"""
from __future__ import annotations

import _thread
import argparse
import collections
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from usv_predictor.data.smoother import measurements, smooth_measurements, tune  # noqa: E402
from usv_predictor.replay.identify import identification_recordings  # noqa: E402


def _timed(z: np.ndarray, dt: float, config, compiled: bool):
    started = time.perf_counter()
    out = smooth_measurements(z, dt, config, compiled=compiled)
    return time.perf_counter() - started, out


def bench_time(recordings, repeats: int) -> None:
    print(f"{'recording':36s} {'samples':>7s} {'old ms':>8s} {'new ms':>8s} {'old/new':>8s} {'max rel diff':>12s}")
    for rec in recordings:
        z = measurements(rec)
        config = tune(z, rec.dt).config  # warms the compiled loops too
        old, new, diff = [], [], 0.0
        for _ in range(repeats):
            t_old, a = _timed(z, rec.dt, config, compiled=False)
            t_new, b = _timed(z, rec.dt, config, compiled=True)
            old.append(t_old)
            new.append(t_new)
            scale = np.maximum(np.max(np.abs(a.state), axis=0), 1e-12)
            diff = max(diff, float(np.max(np.max(np.abs(a.state - b.state), axis=0) / scale)))
        o, n = float(np.median(old)), float(np.median(new))
        print(f"{rec.name:36s} {len(z):7d} {1e3 * o:8.1f} {1e3 * n:8.2f} {o / n:8.1f} {diff:12.1e}")


def bench_interrupts(recordings, count: int) -> None:
    rng = np.random.default_rng(0)
    tally: collections.Counter = collections.Counter()
    for _ in range(count):
        timer = threading.Timer(float(rng.uniform(0.0, 0.3)), _thread.interrupt_main)
        timer.start()
        try:
            while True:
                for rec in recordings:
                    smooth_measurements(measurements(rec), rec.dt)
        except KeyboardInterrupt:
            tally["KeyboardInterrupt"] += 1
        except SystemError as err:
            tally[f"SystemError (caused by {type(err.__cause__).__name__})"] += 1
        finally:
            timer.join()
    print(f"{count} interrupts inside the compiled smoother: {dict(tally)}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--interrupts", type=int, default=0)
    args = parser.parse_args()
    print(f"load before: {os.getloadavg()}")
    recordings = identification_recordings([ROOT / "bags" / "training"], 0.2)
    bench_time(recordings, args.repeats)
    if args.interrupts:
        bench_interrupts(recordings, args.interrupts)
    print(f"load after: {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
