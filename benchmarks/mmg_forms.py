"""The two MMG forms the grey box departs from Yasukawa & Yoshimura 2015 in, measured on KVLCC2 (docs/kernel.md).

The hull resistance: the paper's -R0' (0.5 rho L d) U^2 against the project's -R0' (0.5 rho L d) u|u|; the rudder
inflow angle: the paper's U beta_R = U atan(-v/u) - l_R r against the project's U sin(beta) - l_R r = -(v + l_R r).
Each variant is the checked-out physics/kernel.py with that one line in the paper's form (the text is replaced in a
copy compiled beside it; the script stops if the line is not found), run with the kvlcc2_model preset's captive-test
coefficients (Yasukawa & Yoshimura 2015, identified with the paper's forms) on:
  - the 13 measured HSVA zig-zags of SIMMAN 2008 (../shared/data/raw/kvlcc2_hsva_simman2008, `replay convert`): the
    whole record simulated from its first measured state with its measured rudder and propeller speed (dt 0.2 s,
    open loop): RMS errors of heading (deg), yaw rate (deg/s) and surge speed (m/s), median over the records;
  - 35 deg turning circles both ways at the zig-zags' approach speed (rudder at the preset's rate from 10 s of
    straight running): advance and tactical diameter against SIMMAN 2008's published 3.1 / 3.2 L (MARIN free
    running), transfer and steady radius as figures.
Run: .venv/bin/python benchmarks/mmg_forms.py [--raw ../shared/data/raw] [--work /tmp/mmg_forms] [--json OUT]
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

from usv_predictor.physics import kernel as kn
from usv_predictor.physics.dynamics import ManoeuvringModel, kernel_constants
from usv_predictor.physics.vessel import load_vessel

sys.path.insert(0, str(Path(__file__).resolve().parent))
import study_turning as st  # noqa: E402 -- the turning criteria and the published figures of the turning study

DT = 0.2  # (s) the HSVA zig-zags' step as the turning study reads them
SUBSTEPS = 2  # RK4 substeps per step
TURN_S = 320.0  # (s, model scale) > 720 deg of heading change
APPROACH_S = st.APPROACH_S  # (s) straight running before the rudder execute
PROJECT_RESISTANCE = "x_h = q * (-p[h] * (1.0 + change) * u_r * abs(u_r) / (U * U) +"
PAPER_RESISTANCE = "x_h = q * (-p[h] * (1.0 + change) * (1.0 if u_r >= 0.0 else u_r * abs(u_r) / (U * U)) +"
PROJECT_INFLOW = "beta_r = -(v_r + p[P_L_R_M] * r)"
PAPER_INFLOW = "beta_r = speed * math.atan2(-v_r, max(u_r, 1e-9)) - p[P_L_R_M] * r"
VARIANTS = {  # name -> the lines replaced in the kernel's source (the paper's forms apply ahead, u > 0)
    "project (u abs(u), U sin beta)": (),
    "paper resistance (U^2)": ((PROJECT_RESISTANCE, PAPER_RESISTANCE),),
    "paper inflow (U beta)": ((PROJECT_INFLOW, PAPER_INFLOW),),
    "both paper forms": ((PROJECT_RESISTANCE, PAPER_RESISTANCE), (PROJECT_INFLOW, PAPER_INFLOW)),
}


def variant_kernel(folder: Path, name: str, replacements: tuple) -> object:
    """physics/kernel.py with the replacements, compiled as its own module."""
    source = Path(kn.__file__).read_text()
    for old, new in replacements:
        if old not in source:
            sys.exit(f"mmg_forms: physics/kernel.py has no line {old!r}: update this study's forms")
        source = source.replace(old, new)
    path = folder / f"kernel_{abs(hash(name)) % 10**8}.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def run(module, ki, p, state: np.ndarray, controls: np.ndarray) -> np.ndarray:
    """(H, 6) of one start state (4,) and controls (H, C) by a kernel module."""
    out = np.empty((1, 1, controls.shape[0], 6))
    module.rollout(state[None].copy(), controls[None].copy(), state[None].copy(), False, ki, p,
                   np.zeros((1, kn.N_TERMS)), np.ones(1), out)
    return out[0, 0]


def zigzag_errors(module, ki, p, recordings: list) -> dict[str, float]:
    rows = []
    for r in recordings:
        pred = run(module, ki, p, r.state()[0], r.controls[1:])
        n = len(pred)
        heading = np.degrees(np.unwrap(pred[:, 5]) - np.unwrap(r.psi[1:n + 1]))
        rows.append((np.sqrt(np.mean(heading**2)), np.degrees(np.sqrt(np.mean((pred[:, 2] - r.nu[1:n + 1, 2])**2))),
                     np.sqrt(np.mean((pred[:, 0] - r.nu[1:n + 1, 0])**2))))
    med = np.median(np.array(rows), axis=0)
    return {"heading_rms_deg": float(med[0]), "yaw_rate_rms_deg_s": float(med[1]), "surge_rms_mps": float(med[2])}


def turn(module, ki, p, vessel, rpm: float, side: int) -> dict[str, float]:
    """35 deg turn from straight running at rpm: the rudder ordered at APPROACH_S, moving at the preset's rate."""
    model = ManoeuvringModel(vessel)
    x0 = model.initial_state(rpm, 0.0)
    t = np.arange(0.0, TURN_S + DT / 2, DT)
    rate = math.radians(vessel.actuators.rudder_rate_deg_s)
    delta = side * np.clip((t - APPROACH_S) * rate, 0.0, math.radians(st.RUDDER_DEG))
    controls = np.column_stack([delta, np.full_like(t, rpm)])
    pred = run(module, ki, p, np.array([x0[3], x0[4], x0[5], 0.0]), controls[1:])
    track = np.vstack([[x0[3], x0[4], x0[5], 0.0, 0.0, 0.0], pred])
    return st.turn_criteria(t, track[:, 3], track[:, 4], np.unwrap(track[:, 5]), APPROACH_S, vessel.geometry.L_pp,
                            drift_free=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--raw", type=Path, default=Path(__file__).resolve().parents[1].parent / "shared/data/raw")
    parser.add_argument("--work", type=Path, default=None, help="where the converted bags go (default: a temporary "
                                                                  "folder)")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    from usv_predictor.replay.convert import convert
    from usv_predictor.replay.identify import identification_recordings

    vessel = load_vessel("kvlcc2_model")
    ki, p = kernel_constants(vessel, DT, SUBSTEPS)
    with tempfile.TemporaryDirectory(prefix="mmg_forms_") as tmp:
        work = args.work or Path(tmp)
        bags_dir = work / "hsva"
        if not bags_dir.is_dir():
            convert([args.raw / "kvlcc2_hsva_simman2008"], bags_dir)
        bags = sorted(b for b in bags_dir.iterdir() if b.is_dir())
        recordings = identification_recordings(bags, DT, layout=vessel.actuator_layout)
        approach = float(np.median([np.hypot(*r.nu[0, :2]) for r in recordings]))
        rpm = st.rpm_for_speed(vessel, approach)
        results = {}
        for name, replacements in VARIANTS.items():
            module = variant_kernel(Path(tmp), name, replacements)
            turns = {side: turn(module, ki, p, vessel, rpm, sign) for side, sign in (("starboard", 1), ("port", -1))}
            results[name] = {"zigzags": zigzag_errors(module, ki, p, recordings), "turns": turns}
    print(f"KVLCC2 preset, {len(recordings)} HSVA zig-zags (approach {approach:.3f} m/s, {rpm:.1f} rpm), dt {DT} s")
    print("| form | heading RMS (deg) | yaw rate RMS (deg/s) | surge RMS (m/s) | advance vs 3.1 L (s / p) | "
          "tactical diameter vs 3.2 L (s / p) | transfer (L) | steady radius (L) |")
    print("|---|---|---|---|---|---|---|---|")
    for name, r in results.items():
        z, t = r["zigzags"], r["turns"]
        pct = {k: " / ".join(f"{100 * (t[s][k] / st.PUBLISHED[k] - 1):+.1f} %" for s in t) for k in st.PUBLISHED}
        print(f"| {name} | {z['heading_rms_deg']:.2f} | {z['yaw_rate_rms_deg_s']:.4f} | {z['surge_rms_mps']:.4f} | "
              f"{pct['advance']} | {pct['tactical_diameter']} | "
              f"{t['starboard']['transfer']:.3f} / {t['port']['transfer']:.3f} | "
              f"{t['starboard']['steady_radius']:.3f} / {t['port']['steady_radius']:.3f} |")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
