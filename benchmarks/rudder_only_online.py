"""rudder_only: the online estimate of the sea and the adaptive open-loop error against the plain one.

A rudder boat whose propulsion is not logged (layout rudder_only) holds the engine speed of its approach (the held
reference, data.recording.held_reference). Until 2026-11-26 `adaptive_open_loop` gave its rollouts no held
reference and the online estimator (fitting/online.py) took the engine speed of the present, slowing speed at every
step: on a calm turn it settled on a 2 m/s current that is not there. This script prints, in one run, on simulated
bags of the jari_usv preset as a rudder_only boat (650 rpm, not recorded; 20 deg turning circle and 20/20 zig-zag,
120 s, seed 5, sensor noise), in calm water and in a 0.3 m/s current toward 90 deg: the mean open-loop position
error at 10 / 30 s against GNSS (starts every 5 s) of the preset's calm-water grey box, plain (open_loop) and with
the live estimate (adaptive_open_loop), and the estimator's final current against the truth. The numbers before the
fix: the same script on the commit before it (docs/online.md).

    .venv/bin/python benchmarks/rudder_only_online.py [--out DIR]
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from usv_predictor.analysis import adaptive, evaluation
from usv_predictor.models.loading import physics_predictor
from usv_predictor.physics.actuators import actuator_layout
from usv_predictor.physics.vessel import load_vessel
from usv_predictor.replay.recordings import load_recordings
from usv_predictor.replay.simulate import SimulationRequest, simulate

from rudder_only_engine_speed import rudder_only_jari  # benchmarks/: the script's directory is on sys.path

DT = 0.5  # (s) model step
HORIZONS_S = (10.0, 30.0)  # (s) open-loop horizons
CURRENT = (0.3, 90.0)  # (m/s, deg toward)
CASES = {  # name -> (manoeuvre, current or None)
    "turning circle, calm": ("turning-circle", None),
    "turning circle, current": ("turning-circle", CURRENT),
    "zig-zag 20/20, calm": ("zigzag", None),
    "zig-zag 20/20, current": ("zigzag", CURRENT),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None, help="where the bags go (default: a temporary directory)")
    args = parser.parse_args()
    root = args.out or Path(tempfile.mkdtemp(prefix="rudder_only_online_"))
    vessel_file = rudder_only_jari(root)
    vessel = load_vessel(str(vessel_file))
    model = physics_predictor(vessel, DT)
    print(f"jari_usv as rudder_only (650 rpm, not recorded), 120 s, model step {DT:g} s, GNSS reference; "
          f"bags in {root}")
    print(f"{'case':26s} {'open_loop 10/30 s (m)':>22s} {'adaptive 10/30 s (m)':>21s} {'truth':>14s}  final estimate")
    for k, (case, (manoeuvre, current)) in enumerate(CASES.items()):
        bags = root / f"case{k}"
        effects = {} if current is None else {"current": {"current_speed": current[0], "current_to_deg": current[1]}}
        if not bags.exists():
            simulate(SimulationRequest(output=bags, vessel=vessel, vessel_label=str(vessel_file), manoeuvre=manoeuvre,
                                       rudder_deg=20.0, rpm=650.0, duration_s=120.0, dt=0.1, effects=effects, seed=5))
        (rec,) = load_recordings([bags], DT, layout=actuator_layout("rudder_only"), warn=lambda _: None)
        plain = evaluation.open_loop(model, rec, "gnss", HORIZONS_S, 5.0)
        live = adaptive.adaptive_open_loop(model, rec, "gnss", HORIZONS_S, 5.0, vessel=vessel)
        e = live.estimates[-1]
        truth = "calm" if current is None else f"{current[0]:.2f} to {current[1]:.0f}"
        print(f"{case:26s} {' / '.join(f'{h.mean_m:.2f}' for h in plain.horizons):>22s} "
              f"{' / '.join(f'{h.mean_m:.2f}' for h in live.open_loop.horizons):>21s} {truth:>14s}  "
              f"{e.current_speed_m_s:.3f} m/s to {e.current_to_deg:.1f} deg (std {e.current_std_max_m_s:.3f}), "
              f"converged {e.converged}, k_R {100 * e.state[6]:+.1f} %, NIS {e.nis_mean:.2f}, "
              f"{e.rejections} rejected", flush=True)


if __name__ == "__main__":
    main()
