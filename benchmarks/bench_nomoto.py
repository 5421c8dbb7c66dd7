#!/usr/bin/env python3
"""The low-order model's compiled numpy rollout against the TorchScript file it replaces at load time.

    python benchmarks/bench_nomoto.py [--rounds 30] [--json PATH]

A first- and a second-order Nomoto model (models/nomoto.py, rudder_only, dt 0.5 s) are exported as artifacts and loaded
as the node and `replay evaluate` load them (models/loading.load_model: the numpy form is rebuilt from the metadata and
checked equal to the file's module within 1e-9). Then, in alternating rounds, one 60 s prediction (120 steps) is
timed:
  file        the TorchScript file's own rollout, one state (what a low-order model would run without the fast path)
  numpy       the compiled numpy form (NumpyNomotoRollout), one state, called as node/live.Rollout calls it
  file 64     the file's rollout on 64 candidate plans of one start
  numpy 64    the numpy form on the same 64
Medians (and p99) over the rounds in ms, with the ratio file / numpy side by side.
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

STEPS = 120  # 60 s at 0.5 s
DT = 0.5  # (s)


def _time(call, rounds: int) -> tuple[float, float]:
    for _ in range(5):
        call()
    samples = []
    for _ in range(rounds):
        started = time.perf_counter()
        call()
        samples.append(time.perf_counter() - started)
    return float(np.median(samples) * 1e3), float(np.percentile(samples, 99) * 1e3)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=30)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    from usv_predictor.models.loading import load_model
    from usv_predictor.models.nomoto import NomotoCoefficients, export_nomoto
    from usv_predictor.physics.vessel import load_vessel

    torch.set_num_threads(1)
    vessel = load_vessel(Path(__file__).resolve().parents[1] / "docs" / "vessels" / "fuzhou_usv.yaml")
    results = {}
    with tempfile.TemporaryDirectory() as scratch:
        for order in (1, 2):
            c = NomotoCoefficients(order, 0.26, 4.4, 1.0 if order == 2 else 0.0, 0.5 if order == 2 else 0.0, 0.036,
                                   1.7, 1.05, -2.48, "reference")
            path = Path(scratch) / f"nomoto_{order}.pt"
            export_nomoto(str(path), c, vessel, DT, training_data_sha256="0" * 64, identification={})
            model = load_model(str(path), dt=DT)
            one = (torch.tensor([[0.6, 0.0, 0.05, 0.3]], dtype=torch.float64),
                   torch.full((1, STEPS, 1), 0.3, dtype=torch.float64), torch.tensor([[0.6, 0.0, 0.0, 0.3]]).double())
            many = (one[0].expand(64, 4), torch.linspace(-0.5, 0.5, 64, dtype=torch.float64)[:, None, None]
                    .expand(64, STEPS, 1).contiguous(), one[2].expand(64, 4))
            fast = model.inference
            row = {}
            cases = (("file", model.module, one), ("numpy", fast, one), ("file 64", model.module, many),
                     ("numpy 64", fast, many))
            for label, fn, inputs in cases:
                with torch.inference_mode():
                    row[label] = _time(lambda fn=fn, inputs=inputs: fn(*inputs), args.rounds)
            results[f"order {order}"] = row
            print(f"order {order}: " + "; ".join(f"{k} {m:.3f} ms (p99 {p:.3f})" for k, (m, p) in row.items())
                  + f"; file / numpy {row['file'][0] / row['numpy'][0]:.0f}x, 64 plans "
                  f"{row['file 64'][0] / row['numpy 64'][0]:.0f}x")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
