"""The two real USV records: identify, predict, compare, diagnose (every figure of docs/results/real_usv.md).

Dalian twin-thruster USV (../shared/data/raw/usv_2345vor_dalian, closed-loop path following, ~4 and ~3 minutes):
  `replay convert` both runs; for each direction (identify on the circle, predict the sine; and the reverse)
  - the grey box identified from the one run (`replay identify --vessel docs/vessels/dalian_usv.yaml --prior fix
    --blocks 4`: the run cut in 4 pieces for cross-validation), the assumed vessel file's grey box unidentified,
    a learned model (the seed 000 network, NTF features, trained on the same run with the same recipe as
    `replay train`) and two naive baselines from the start state (constant velocity; constant speed and turn rate),
    each evaluated on the other run: open-loop position error after 10 / 30 / 60 s (every 5 s a start, as
    `replay evaluate`);
  - the circle's radius: each model predicts the circle run open loop from t = 40 s (after the approach) to its end
    with the recorded commands; a circle fitted to the predicted track against the 22.5 m the GNSS track makes;
  - `replay diagnose --dt 0.2 --horizon 20 --stride 5` of both runs (at 0.5 s the rollout of this 1.2 m boat is
    unstable in yaw beyond ~0.3 rad/s) against the vessel file and against each identified grey box, and the gain
    of the extended model on the held-out run.
Fuzhou rudder USV (../shared/data/raw/usv_alexandersson2022_fuzhou, a 30 deg zig-zag at sea, no propeller data):
  the grey box of docs/vessels/fuzhou_usv.yaml (rudder_only: the engine speed of each piece from its approach speed)
  identified on the first half of the zig-zag (two pieces for cross-validation; --prior none refuses, --prior fix),
  and the first-order Nomoto yaw model T r_dot + r = K delta + b that a noisy zig-zag of heading and rudder does
  support (least squares on the smoothed r, r_dot), the held-out second half predicted by each (closed loop from its
  first state, open loop 10 / 30 s) against the naive baselines; the steady turning radius at 22 deg rudder from the
  Nomoto model of the whole record at the speed of its turns, its uncertainty from 400 draws of (a1, a2, a3) from
  their estimated covariance, beside the MMG grey box's (identified, and the vessel file's) simulated radius.
The low-order family (`--only low_order`, models/nomoto.py, fitting/nomoto_fit.py): Fuzhou, the Nomoto model (first
  and second order) fitted by output error on the first half, the held-out half predicted (open loop 10 / 30 s,
  closed-loop heading) beside the grey box (prior fix, two pieces) and the naive baselines; `--family auto`'s choice
  on the whole record; the turning circle at 22 deg rudder of the model of the whole record at its approach speed,
  with its jackknife 95 % interval. Dalian, both directions (identify on one run, predict the other): the Nomoto model
  beside the grey box (prior fix, 4 blocks) and the baselines (open loop 10 / 30 / 60 s) and the circle's radius.
Why the Dalian models turn the circle as they do (`--only circle`, circle_radius_study): what the circle run shows (its
  radius, mean turn, a current from its speed over ground, the turn command by heading sector) and, for the Nomoto
  model and the grey box identified on each run, the circle replayed open loop with its recorded commands against the
  turn of its mean command held (a turning test's constant command), and the drift v / r each model makes in that
  turn against the drift of the run it was identified on.
Run: .venv/bin/python benchmarks/real_usv.py [--raw ../shared/data/raw] [--work /tmp/real_usv] [--json out.json]
Deterministic (seeded training, no random state elsewhere); ~3 minutes on one core.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DALIAN_VESSEL = REPO / "docs" / "vessels" / "dalian_usv.yaml"
FUZHOU_VESSEL = REPO / "docs" / "vessels" / "fuzhou_usv.yaml"
DT = 0.2  # (s) the step of every Dalian model (the GNSS fixes come at ~4.6 Hz)
FUZHOU_DT = 0.5  # (s) the step of the Fuzhou models: the record is interpolated at 0.5 s
HORIZONS = (10.0, 30.0, 60.0)  # (s) open-loop horizons
STEADY_FROM_S = 40.0  # (s) the circle run has converged onto its path by then (twin_thruster_research.md sec. 3.7)
FUZHOU_RUDDER_DEG = 22.0  # (deg) the turning circle asked for
DRAWS = 400  # coefficient draws for the turning radius uncertainty




class ConstantVelocity:
    """Naive baseline: the start state's u, v held, no turn (heading constant)."""

    turn = False

    def __init__(self, dt: float = DT) -> None:
        self.dt = dt
        self.metadata = {"dt": dt, "model_id": "constant-velocity", "model_type": "baseline: constant velocity"}

    def predict(self, state: np.ndarray, controls: np.ndarray) -> np.ndarray:  # (B, 4), (B, H, C) -> (1, B, H, 6)
        return _constant(state, controls.shape[1], self.dt, turn=self.turn)


class ConstantTurn(ConstantVelocity):
    """Naive baseline: the start state's u, v and r held (a circle at constant speed and turn rate)."""

    turn = True

    def __init__(self, dt: float = DT) -> None:
        super().__init__(dt)
        self.metadata = {"dt": dt, "model_id": "constant-turn", "model_type": "baseline: constant speed and turn rate"}


def _constant(state: np.ndarray, steps: int, dt: float, turn: bool) -> np.ndarray:
    """(1, B, H, 6) [u, v, r, x_n, y_e, psi] for body velocities held from the start (exact integral of
    eta_dot = R(psi) nu with psi = psi0 + r t: Fossen 2021 eq. 2.40)."""
    u, v, r, psi0 = (state[:, k][:, None] for k in range(4))  # (B, 1)
    r = r if turn else np.zeros_like(r)
    t = dt * np.arange(1, steps + 1)[None, :]  # (1, H)
    psi = psi0 + r * t
    small = np.abs(r) < 1e-9
    safe = np.where(small, 1.0, r)
    ic = np.where(small, t * np.cos(psi0), (np.sin(psi) - np.sin(psi0)) / safe)  # int cos(psi) dt
    is_ = np.where(small, t * np.sin(psi0), (np.cos(psi0) - np.cos(psi)) / safe)  # int sin(psi) dt
    x = u * ic - v * is_
    y = u * is_ + v * ic
    shape = np.broadcast_to
    out = np.stack([shape(u, x.shape), shape(v, x.shape), shape(r, x.shape), x, y, psi], axis=-1)
    return out[None]


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def convert_records(raw: Path, work: Path) -> Path:
    from usv_predictor.replay.convert import convert

    bags = work / "bags"
    convert([raw / "usv_2345vor_dalian", raw / "usv_alexandersson2022_fuzhou"], bags, overwrite=True, progress=log)
    return bags


def recordings(bag: Path, layout: str, dt: float = DT) -> list:
    from usv_predictor.physics.actuators import actuator_layout
    from usv_predictor.replay.recordings import load_recordings

    return load_recordings([bag], dt, layout=actuator_layout(layout), warn=lambda _: None)


def train_network(train: list, out: Path, vessel: str) -> object:
    """The seed 000 network on one run (NTF, 2 x 100 tanh, Table 5 recipe without a validation split), exported."""
    from usv_predictor.data.recording import recording_layout
    from usv_predictor.fitting.training import TrainingConfig, samples_from_recordings, train_dnn
    from usv_predictor.models.artifact import load_artifact
    from usv_predictor.models.dnn import DnnConfig, export

    layout = recording_layout(train)
    config = DnnConfig.for_features("NTF", layout)
    recipe = TrainingConfig(epochs=300, patience=None, seed=0, threads=1)
    result = train_dnn(config, samples_from_recordings(train, "NTF"), None, recipe)
    export(out, result.models, config, dt=DT, vessel=vessel, training_data_sha256="0" * 64,
           training=_strict(result.summary()), dtype="float64")
    return load_artifact(out)


def open_loop(model: object, recs: list) -> dict[str, float]:
    from usv_predictor.analysis.evaluation import evaluate

    result = evaluate(model, recs, "gnss", HORIZONS, 5.0)
    loop = result.recordings[0].open_loop
    return {f"{h.horizon_s:g}s": {"mean_m": h.mean_m, "p95_m": h.p95_m, "starts": h.count} for h in loop.horizons}


def circle_radius(model: object, circle) -> dict[str, float]:
    """Radius (m) of the circle fitted to the model's open-loop track of the circle run from t = STEADY_FROM_S."""
    from usv_predictor.analysis import metrics

    k = int(round(STEADY_FROM_S / circle.dt))
    state = circle.state()[k:k + 1]
    pred = model.predict(state, circle.controls[None, k:-1])  # (E, 1, H, 6)
    x, y, psi = pred[0, 0, :, 3], pred[0, 0, :, 4], pred[0, 0, :, 5]
    if np.ptp(np.unwrap(psi)) < math.radians(90.0):
        return {"radius_m": math.inf, "heading_change_deg": float(np.degrees(np.ptp(psi)))}
    t = circle.dt * np.arange(1, len(x) + 1)
    fit = metrics.steady_turning_radius(t, x, y, psi, start_change_deg=0.0, drift_velocity_mps=(0.0, 0.0),
                                        refine_drift=False)
    return {"radius_m": fit.radius_m, "heading_change_deg": float(np.degrees(np.ptp(np.unwrap(psi))))}


def measured_circle(circle) -> float:
    from usv_predictor.analysis import metrics

    k = int(round(STEADY_FROM_S / circle.dt))
    fit = metrics.steady_turning_radius(circle.t_s[k:], circle.position[k:, 0], circle.position[k:, 1], circle.psi[k:],
                                        start_change_deg=0.0, drift_velocity_mps=(0.0, 0.0), refine_drift=False)
    return fit.radius_m


def dalian(bags: Path, work: Path) -> dict:
    from usv_predictor.analysis.diagnosis_run import calm_water_model
    from usv_predictor.models.artifact import load_artifact
    from usv_predictor.models.greybox import greybox_predictor
    from usv_predictor.physics.vessel import load_vessel
    from usv_predictor.replay.diagnose import DiagnoseRequest, diagnose_bags
    from usv_predictor.replay.identify import IdentifyRequest, identify_bags

    vessel = load_vessel(DALIAN_VESSEL)
    runs = {name: recordings(bags / f"dalian_{name}", "twin_thrusters") for name in ("circle", "sine")}
    circle = runs["circle"][0]
    out: dict = {"measured_circle_radius_m": measured_circle(circle), "directions": {}}
    log(f"Dalian: measured circle radius {out['measured_circle_radius_m']:.2f} m")
    identified = {}
    for train, test in (("circle", "sine"), ("sine", "circle")):
        log(f"Dalian: identify on the {train}, predict the {test}")
        path = work / f"dalian_greybox_{train}.pt"
        ident = identify_bags(IdentifyRequest((bags / f"dalian_{train}",), path, prior="fix", dt=DT, blocks=4),
                              vessel, progress=log)
        identified[train] = path
        models = {
            "grey box identified": load_artifact(path),
            "grey box of the vessel file (assumed, not identified)": greybox_predictor(vessel, DT),
            "learned (seed 000 network)": train_network(runs[train], work / f"dalian_dnn_{train}.pt", vessel.name),
            "constant velocity": ConstantVelocity(),
            "constant speed and turn rate": ConstantTurn(),
        }
        direction = {"identification": {c["name"]: {k: c[k] for k in ("estimate", "ci95", "prior", "status")}
                                        for c in ident["identification"]["coefficients"]},
                     "notes": ident["identification"]["notes"],
                     "cross_validation": ident["identification"]["cross_validation"],
                     "open_loop": {}, "circle_radius_m": {}}
        for label, model in models.items():
            direction["open_loop"][label] = open_loop(model, runs[test])
            direction["circle_radius_m"][label] = circle_radius(model, circle)
            e = direction["open_loop"][label]
            log(f"  {label:55s} open loop 10/30/60 s: {e['10s']['mean_m']:6.2f} {e['30s']['mean_m']:6.2f} "
                f"{e['60s']['mean_m']:6.2f} m   circle radius {direction['circle_radius_m'][label]['radius_m']:.1f} m")
        out["directions"][f"{train} -> {test}"] = direction
    out["diagnose"] = {}
    both = [bags / "dalian_circle", bags / "dalian_sine"]
    for label, model in (("vessel file", None), ("identified on the circle", identified["circle"]),
                         ("identified on the sine", identified["sine"])):
        log(f"Dalian: diagnose both runs against the {label}")
        d = diagnose_bags(DiagnoseRequest(tuple(both), dt=DT, horizon_s=20.0, stride_s=5.0),
                          calm_water_model(str(DALIAN_VESSEL), model),
                          progress=log)  # 0.5 s: RK4 unstable in yaw (analysis/diagnosis_steps.py)
        out["diagnose"][label] = {"cause": d["cause"], "parameters": d["parameters"], "message": d["message"],
                                  "additional_causes": d["additional_causes"], "gain": d["gain"],
                                  "evidence": [{k: e[k] for k in ("hypothesis", "heldout_loss", "gain_vs_none",
                                                                  "evidence_vs_none", "fold_parameters")}
                                               for e in d["evidence"]]}
    return out


class NomotoPredictor:
    """First-order Nomoto yaw model (Nomoto et al. 1957; Fossen 2021 eq. 7.38) T r_dot + r = K delta + b, with the
    start's speed over ground held along the heading: what a noisy zig-zag of heading and rudder supports."""

    def __init__(self, k: float, t: float, b: float, dt: float) -> None:
        self.k, self.t, self.b, self.dt = k, t, b, dt  # (1/s), (s), (rad/s)
        self.metadata = {"dt": dt, "model_id": "nomoto", "model_type": "first-order Nomoto (identified)"}

    def predict(self, state: np.ndarray, controls: np.ndarray) -> np.ndarray:  # (B, 4), (B, H, 1) -> (1, B, H, 6)
        batch, steps = controls.shape[0], controls.shape[1]
        speed = np.hypot(state[:, 0], state[:, 1])  # (B,)
        r, psi = state[:, 2].copy(), state[:, 3].copy()
        x, y = np.zeros(batch), np.zeros(batch)
        out = np.empty((1, batch, steps, 6))
        decay = math.exp(-self.dt / self.t)
        for k in range(steps):
            target = self.k * controls[:, k, 0] + self.b  # steady yaw rate of this rudder (rad/s)
            r_next = target + (r - target) * decay  # exact over the step, rudder held
            psi_next = psi + target * self.dt + (r - target) * self.t * (1.0 - decay)
            mid = 0.5 * (psi + psi_next)
            x, y = x + speed * np.cos(mid) * self.dt, y + speed * np.sin(mid) * self.dt  # midpoint rule
            r, psi = r_next, psi_next
            out[0, :, k] = np.column_stack([speed, np.zeros(batch), r, x, y, psi])
        return out


def fit_nomoto(recordings_: list) -> dict:
    """Least squares r_dot = a1 delta + a2 + a3 r on the smoothed yaw rate and its derivative (data/smoother.py), then
    K = -a1 / a3, T = -1 / a3, b = -a2 / a3; the covariance of (a1, a2, a3) widened by n / n_eff for autocorrelated
    residuals (as fitting/identification.effective_samples)."""
    from usv_predictor.data.smoother import smooth_recording
    from usv_predictor.fitting.identification import effective_samples

    rows, target, groups = [], [], []
    for g, rec in enumerate(recordings_):
        smoothed = smooth_recording(rec)
        edge = int(round(2.0 / rec.dt))
        r, r_dot = smoothed.nu[edge:-edge, 2], smoothed.nu_dot[edge:-edge, 2]
        delta = rec.controls[edge:-edge, 0]
        rows.append(np.column_stack([delta, np.ones_like(r), r]))
        target.append(r_dot)
        groups.append(np.full(len(r), g))
    a, y, groups_ = np.vstack(rows), np.concatenate(target), np.concatenate(groups)
    theta, *_ = np.linalg.lstsq(a, y, rcond=None)
    residual = y - a @ theta
    sigma2 = float(residual @ residual) / (len(y) - 3)
    cov = np.linalg.inv(a.T @ a) * sigma2 * len(y) / effective_samples(residual, groups_)
    a1, a2, a3 = theta
    return {"K_per_s": float(-a1 / a3), "T_s": float(-1.0 / a3), "b_rad_s": float(-a2 / a3), "theta": theta.tolist(),
            "cov": cov.tolist(), "samples": int(len(y))}


def nomoto_radius(theta: np.ndarray, speed: float, delta: float) -> float:
    """Steady radius (m) U / |r_ss| with r_ss = K delta + b = -(a1 delta + a2) / a3."""
    rate = -(theta[0] * delta + theta[1]) / theta[2]
    return speed / abs(rate) if rate != 0.0 else math.inf


def fuzhou(bags: Path, work: Path) -> dict:
    import torch

    from usv_predictor.analysis import metrics
    from usv_predictor.analysis.evaluation import WithoutReference, evaluate
    from usv_predictor.errors import ConfigError, NotIdentifiableError
    from usv_predictor.fitting import hybrid_fit, identification
    from usv_predictor.models.artifact import load_artifact
    from usv_predictor.models.greybox import greybox_predictor
    from usv_predictor.physics.dynamics import ManoeuvringModel
    from usv_predictor.physics.manoeuvres import TurningCircle
    from usv_predictor.physics.simulator import simulate
    from usv_predictor.physics.vessel import load_vessel
    from usv_predictor.replay.recordings import slice_recording

    vessel = load_vessel(FUZHOU_VESSEL)
    (whole,) = recordings(bags / "fuzhou_zigzag_30", "rudder_only", FUZHOU_DT)
    half = len(whole) // 2
    first = slice_recording(whole, 0, half, "fuzhou_first_half")
    second = slice_recording(whole, half, len(whole), "fuzhou_second_half")
    pieces = [slice_recording(first, 0, half // 2, "fuzhou_first_half~1"),
              slice_recording(first, half // 2, half, "fuzhou_first_half~2")]
    out: dict = {"first_half_s": first.duration_s, "second_half_s": second.duration_s}
    try:
        identification.identify(vessel, pieces, structure="mmg", prior="none")
        out["prior_none"] = "identified without a prior"
    except NotIdentifiableError as err:
        out["prior_none"] = str(err)
    log("Fuzhou: identify on the first half (prior fix)")
    result = identification.identify(vessel, pieces, structure="mmg", prior="fix", progress=log)
    out["identification"] = {c.name: {"estimate": c.estimate, "ci95": list(c.ci95), "prior": c.prior,
                                      "status": c.status} for c in result.coefficients()}
    out["engine_speeds"] = result.to_json()["actuators"]
    out["notes"] = list(result.notes)
    module = hybrid_fit.greybox_module(result, FUZHOU_DT)
    path = work / "fuzhou_greybox.pt"
    hybrid_fit.export_identified(str(path), module, result, dt=FUZHOU_DT, training_data_sha256="0" * 64)
    rpm = float(np.median([e["engine_speed_rpm"] for e in out["engine_speeds"].values()]))
    held_rpm = load_artifact(path)
    held_rpm.module.engine_speed_rpm.data = torch.tensor([rpm], dtype=torch.float64)  # the engine setting identified
    nomoto = fit_nomoto(pieces)
    out["nomoto"] = nomoto
    log(f"Fuzhou: Nomoto K {nomoto['K_per_s']:.3f} 1/s, T {nomoto['T_s']:.2f} s, b {nomoto['b_rad_s']:+.4f} rad/s")
    models = {"grey box identified (engine speed from each start's speed)": WithoutReference(load_artifact(path)),
              "grey box identified (engine speed of the half's approach)": load_artifact(path),
              f"grey box identified (the identified engine setting, {rpm:.0f} rpm)": held_rpm,
              "grey box of the vessel file (assumed, not identified)": greybox_predictor(vessel, FUZHOU_DT),
              "first-order Nomoto (identified)": NomotoPredictor(nomoto["K_per_s"], nomoto["T_s"], nomoto["b_rad_s"],
                                                                 FUZHOU_DT),
              "constant velocity": ConstantVelocity(FUZHOU_DT), "constant speed and turn rate": ConstantTurn(FUZHOU_DT)}
    out["held_out_half"] = {}
    for label, model in models.items():
        ev = evaluate(model, [second], "gnss", (10.0, 30.0), 5.0).recordings[0]
        out["held_out_half"][label] = {
            "open_loop": {f"{h.horizon_s:g}s": {"mean_m": h.mean_m, "p95_m": h.p95_m} for h in ev.open_loop.horizons},
            "closed_loop_rmse": ev.state_rmse, "zigzag": None if ev.zigzag is None else ev.zigzag.errors,
        }
        log(f"  {label:62s} open loop 10/30 s: " + " ".join(f"{h.mean_m:6.2f}" for h in ev.open_loop.horizons)
            + f" m; closed-loop psi rmse {ev.state_rmse.get('psi_deg', math.nan):.1f} deg")
    # the turning circle at 22 deg rudder: the Nomoto model of the whole record (four pieces), the speed in its turns
    quarters = np.linspace(0, len(whole), 5).round().astype(int)
    everything = fit_nomoto([slice_recording(whole, int(a), int(b), f"fuzhou~{k + 1}")
                             for k, (a, b) in enumerate(zip(quarters[:-1], quarters[1:]))])
    out["nomoto_whole_record"] = everything
    turning = np.abs(whole.controls[:, 0]) > math.radians(20.0)
    speed = float(np.median(np.hypot(whole.nu[turning, 0], whole.nu[turning, 1])))  # the speed in the turns
    delta = math.radians(FUZHOU_RUDDER_DEG)
    theta, cov = np.array(everything["theta"]), np.array(everything["cov"])
    rng = np.random.default_rng(2026)
    drawn = rng.multivariate_normal(theta, cov, size=DRAWS)
    radii = {}
    for side, sign in (("starboard", 1.0), ("port", -1.0)):
        nominal = nomoto_radius(theta, speed, sign * delta)
        samples = np.array([nomoto_radius(th, speed, sign * delta) for th in drawn if th[2] < 0.0])
        radii[side] = {"radius_m": nominal, "p2_5_m": float(np.percentile(samples, 2.5)),
                       "p97_5_m": float(np.percentile(samples, 97.5)), "radius_over_L": nominal / vessel.geometry.L_pp}
    out["turning_circle_22deg_nomoto"] = {"speed_in_turns_mps": speed, "draws": DRAWS, **radii}

    def mmg_radius(v) -> float:
        try:
            traj = simulate(ManoeuvringModel(v), TurningCircle(FUZHOU_RUDDER_DEG, rpm, duration_s=150.0))
        except ConfigError:
            return math.nan  # diverged
        fit = metrics.steady_turning_radius(traj.t_s, traj.eta[:, 0], traj.eta[:, 1], traj.psi_unwrapped,
                                            start_change_deg=180.0, drift_velocity_mps=(0.0, 0.0), refine_drift=False)
        return fit.radius_m

    out["turning_circle_22deg_mmg"] = {
        "engine_speed_rpm": rpm, "identified_radius_m": mmg_radius(result.vessel),
        "vessel_file_radius_m": mmg_radius(vessel),
        "free_coefficients": [c.name for c in result.fit.coefficients() if c.status == "identified"],
    }
    log(f"Fuzhou: Nomoto of the whole record K {everything['K_per_s']:.3f} 1/s, T {everything['T_s']:.2f} s")
    log(f"Fuzhou: turning radius at 22 deg (Nomoto, {speed:.2f} m/s): starboard {radii['starboard']['radius_m']:.2f} m "
        f"({radii['starboard']['p2_5_m']:.2f}-{radii['starboard']['p97_5_m']:.2f}), port "
        f"{radii['port']['radius_m']:.2f} "
        f"m ({radii['port']['p2_5_m']:.2f}-{radii['port']['p97_5_m']:.2f}); MMG identified "
        f"{out['turning_circle_22deg_mmg']['identified_radius_m']:.2f} m, vessel file "
        f"{out['turning_circle_22deg_mmg']['vessel_file_radius_m']:.2f} m")
    return out


def _nomoto_model(fit, vessel, path: Path, dt: float) -> object:
    from usv_predictor.models.loading import load_model
    from usv_predictor.models.nomoto import export_nomoto

    export_nomoto(str(path), fit.coefficients, vessel, dt, training_data_sha256="0" * 64, identification=fit.to_json())
    return load_model(str(path), dt=dt)


def _fit_record(fit) -> dict:
    return {"coefficients": {e.name: {"estimate": e.estimate, "ci95": list(e.ci95)} for e in fit.estimates},
            "notes": list(fit.notes), "windows": fit.windows}


def low_order(bags: Path, work: Path) -> dict:
    """The low-order family on both records (module docstring)."""
    from usv_predictor.analysis.evaluation import evaluate
    from usv_predictor.data.recording import held_reference
    from usv_predictor.fitting.nomoto_fit import NomotoFitOptions, fit_nomoto
    from usv_predictor.models.artifact import load_artifact
    from usv_predictor.models.nomoto import describe
    from usv_predictor.physics.vessel import load_vessel
    from usv_predictor.replay.identify import IdentifyRequest, identify_bags
    from usv_predictor.replay.low_order import LowOrderRequest, compare_families
    from usv_predictor.replay.recordings import slice_recording

    out: dict = {"fuzhou": {}, "dalian": {"directions": {}}}
    vessel = load_vessel(FUZHOU_VESSEL)
    (whole,) = recordings(bags / "fuzhou_zigzag_30", "rudder_only", FUZHOU_DT)
    half = len(whole) // 2
    first = slice_recording(whole, 0, half, "fuzhou_first_half")
    second = slice_recording(whole, half, len(whole), "fuzhou_second_half")
    request = LowOrderRequest((bags / "fuzhou_zigzag_30",), work / "unused.pt", str(FUZHOU_VESSEL), family="auto",
                              dt=FUZHOU_DT, prior="fix", blocks=2)
    chosen, why, candidates = compare_families(request, vessel, [whole], progress=log)
    out["fuzhou"]["auto"] = {"chosen": chosen, "why": why, "held_out": candidates}
    log(f"Fuzhou auto: {why}")
    models = {}
    for order in (1, 2):
        started = time.perf_counter()
        fit = fit_nomoto([first], NomotoFitOptions(order=order))
        out["fuzhou"][f"nomoto_{order}_first_half"] = {**_fit_record(fit), "fit_s": time.perf_counter() - started}
        log(f"Fuzhou first half: {describe(fit.coefficients, fit.intervals())}")
        models[f"Nomoto order {order} (output error, first half)"] = _nomoto_model(
            fit, vessel, work / f"fuzhou_nomoto_{order}.pt", FUZHOU_DT)
    grey = work / "fuzhou_low_order_greybox.pt"
    pieces = [slice_recording(first, 0, half // 2, "fuzhou_first_half~1"),
              slice_recording(first, half // 2, half, "fuzhou_first_half~2")]
    from usv_predictor.fitting import hybrid_fit, identification

    result = identification.identify(vessel, pieces, structure="mmg", prior="fix")
    hybrid_fit.export_identified(str(grey), hybrid_fit.greybox_module(result, FUZHOU_DT), result, dt=FUZHOU_DT,
                                 training_data_sha256="0" * 64)
    models["grey box (prior fix, first half)"] = load_artifact(grey)
    models["constant velocity"] = ConstantVelocity(FUZHOU_DT)
    models["constant speed and turn rate"] = ConstantTurn(FUZHOU_DT)
    out["fuzhou"]["held_out_half"] = {}
    for label, model in models.items():
        ev = evaluate(model, [second], "gnss", (10.0, 30.0), 5.0).recordings[0]
        out["fuzhou"]["held_out_half"][label] = {
            "open_loop": {f"{h.horizon_s:g}s": {"mean_m": h.mean_m, "p95_m": h.p95_m, "starts": h.count}
                          for h in ev.open_loop.horizons},
            "closed_loop_psi_rmse_deg": ev.state_rmse.get("psi_deg"), "diverged": ev.open_loop.diverged}
        log(f"  {label:50s} open loop 10/30 s: " + " ".join(f"{h.mean_m:6.2f}" for h in ev.open_loop.horizons)
            + f" m; closed-loop psi rmse {ev.state_rmse.get('psi_deg', math.nan):.1f} deg")
    fit = fit_nomoto([whole], NomotoFitOptions(order=1))
    approach = held_reference(whole)
    out["fuzhou"]["nomoto_1_whole_record"] = _fit_record(fit)
    circle = {}
    for side, sign in (("starboard", 1.0), ("port", -1.0)):
        turn = fit.turning_circle(sign * math.radians(FUZHOU_RUDDER_DEG), float(approach[0]))
        circle[side] = {**turn, "radius_over_L": turn["radius_m"] / vessel.geometry.L_pp}
        log(f"Fuzhou turning circle at {FUZHOU_RUDDER_DEG:g} deg {side}: {turn['radius_m']:.2f} m "
            f"[{turn['radius_ci95_m'][0]:.2f}, {turn['radius_ci95_m'][1]:.2f}], drift {turn['drift_deg']:.1f} deg")
    from usv_predictor.data.smoother import smooth_recording

    rate = np.abs(smooth_recording(whole).nu[:, 2])  # the yaw rates the zig-zag passes through (rad/s)
    out["fuzhou"]["turning_circle_22deg"] = {"approach_speed_mps": float(approach[0]), **circle,
                                             "record_yaw_rate_p95_rad_s": float(np.percentile(rate, 95)),
                                             "record_yaw_rate_max_rad_s": float(rate.max())}

    dalian_vessel = load_vessel(DALIAN_VESSEL)
    runs = {name: recordings(bags / f"dalian_{name}", "twin_thrusters") for name in ("circle", "sine")}
    out["dalian"]["measured_circle_radius_m"] = measured_circle(runs["circle"][0])
    for train, test in (("circle", "sine"), ("sine", "circle")):
        fit = fit_nomoto(runs[train], NomotoFitOptions(order=1))
        log(f"Dalian {train}: {describe(fit.coefficients, fit.intervals())}")
        path = work / f"dalian_low_order_greybox_{train}.pt"
        identify_bags(IdentifyRequest((bags / f"dalian_{train}",), path, prior="fix", dt=DT, blocks=4), dalian_vessel,
                      progress=lambda _: None)
        direction = {"nomoto": _fit_record(fit), "open_loop": {}, "circle_radius_m": {}}
        models = {"Nomoto order 1 (output error)": _nomoto_model(fit, dalian_vessel, work / f"dalian_nomoto_{train}.pt",
                                                                 DT),
                  "grey box identified (prior fix, 4 blocks)": load_artifact(path),
                  "constant velocity": ConstantVelocity(), "constant speed and turn rate": ConstantTurn()}
        for label, model in models.items():
            direction["open_loop"][label] = open_loop(model, runs[test])
            direction["circle_radius_m"][label] = circle_radius(model, runs["circle"][0])
            e = direction["open_loop"][label]
            log(f"  {train} -> {test} {label:45s} open loop 10/30/60 s: {e['10s']['mean_m']:6.2f} "
                f"{e['30s']['mean_m']:6.2f} {e['60s']['mean_m']:6.2f} m   circle radius "
                f"{direction['circle_radius_m'][label]['radius_m']:.1f} m")
        out["dalian"]["directions"][f"{train} -> {test}"] = direction
    return out


HELD_S = 400.0  # (s) a held command's turn is simulated this long; its circle fitted after 180 deg of heading change
HEADING_SECTORS = 8  # the circle run's headings in this many sectors (the controller's command by heading)


def held_command_circle(model: object, circle) -> dict[str, float]:
    """The turning circle of the circle run's mean command held (a turning test's definition: a constant command),
    from the state at t = STEADY_FROM_S: radius (m) of the circle fitted after 180 deg of heading change, and the
    steady u, v, r at the end."""
    from usv_predictor.analysis import metrics

    k = int(round(STEADY_FROM_S / circle.dt))
    command = circle.controls[k:].mean(axis=0)  # (C,)
    steps = int(round(HELD_S / circle.dt))
    pred = model.predict(circle.state()[k:k + 1], np.broadcast_to(command, (1, steps, command.size)).copy())
    x, y, psi = pred[0, 0, :, 3], pred[0, 0, :, 4], np.unwrap(pred[0, 0, :, 5])
    if np.ptp(psi) < math.radians(360.0):
        return {"radius_m": math.inf, "u_mps": float(pred[0, 0, -1, 0]), "v_mps": float(pred[0, 0, -1, 1]),
                "r_rad_s": float(pred[0, 0, -1, 2])}
    t = circle.dt * np.arange(1, steps + 1)
    fit = metrics.steady_turning_radius(t, x, y, psi, start_change_deg=180.0, drift_velocity_mps=(0.0, 0.0),
                                        refine_drift=False)
    u, v, r = (float(pred[0, 0, -1, j]) for j in range(3))
    return {"radius_m": fit.radius_m, "u_mps": u, "v_mps": v, "r_rad_s": r, "drift_per_yaw_rate_m": v / r}


def replay_turn(model: object, circle) -> dict[str, float]:
    """The model's open-loop replay of the circle run from t = STEADY_FROM_S with the recorded (closed-loop) commands:
    the fitted circle's radius, and the mean speed and yaw rate (U / r, m: the radius the mean turn would make)."""
    k = int(round(STEADY_FROM_S / circle.dt))
    pred = model.predict(circle.state()[k:k + 1], circle.controls[None, k:-1])
    u, v, r = pred[0, 0, :, 0], pred[0, 0, :, 1], pred[0, 0, :, 2]
    quarters = [float(q.mean()) for q in np.array_split(r, 4)]
    speed = float(np.hypot(u, v).mean())
    return {"radius_m": circle_radius(model, circle)["radius_m"], "mean_r_rad_s": float(r.mean()),
            "mean_speed_mps": speed, "speed_over_mean_r_m": speed / float(r.mean()),
            "mean_r_by_quarter_rad_s": quarters}


def circle_record(circle) -> dict:
    """What the circle run itself shows: the radius, the mean turn, a current (the speed over ground modulated once
    per revolution: SOG = a + c cos(COG - theta), c the current's speed toward theta), the turn command and yaw rate
    by heading sector (a yaw moment fixed in the earth frame, a wind's or a sea's, shows as a command that varies with
    the heading at a constant yaw rate)."""
    k = int(round(STEADY_FROM_S / circle.dt))
    t, pos = circle.t_s[k:], circle.position[k:]
    vel = np.gradient(pos, t, axis=0)  # (T, 2) over ground, NED (m/s)
    sog, cog = np.hypot(vel[:, 0], vel[:, 1]), np.arctan2(vel[:, 1], vel[:, 0])
    basis = np.column_stack([np.ones_like(cog), np.cos(cog), np.sin(cog)])
    (a, c_n, c_e), *_ = np.linalg.lstsq(basis, sog, rcond=None)
    u, v, r = circle.nu[k:, 0], circle.nu[k:, 1], circle.nu[k:, 2]
    steering = circle.controls[k:, 0] - circle.controls[k:, 1]  # port - starboard (+ turns to starboard)
    propulsion = circle.controls[k:].mean(axis=1)
    heading = np.angle(np.exp(1j * circle.psi[k:]))
    edges = np.linspace(-math.pi, math.pi, HEADING_SECTORS + 1)
    sectors = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (heading >= lo) & (heading < hi)
        sectors.append({"heading_deg": [math.degrees(lo), math.degrees(hi)], "samples": int(m.sum()),
                        "steering": float(steering[m].mean()), "r_rad_s": float(r[m].mean()),
                        "u_mps": float(u[m].mean())})
    return {"radius_m": measured_circle(circle), "mean_r_rad_s": float(r.mean()), "mean_u_mps": float(u.mean()),
            "speed_over_mean_r_m": float(np.hypot(u, v).mean() / r.mean()),
            "current_from_sog_mps": math.hypot(c_n, c_e),
            "current_toward_deg": math.degrees(math.atan2(c_e, c_n)) % 360.0,
            "mean_steering": float(steering.mean()), "mean_propulsion": float(propulsion.mean()),
            "steering_p5_p95": np.percentile(steering, [5, 95]).tolist(), "by_heading": sectors}


def drift_per_yaw_rate(rec) -> float:
    """(m) the least-squares slope of v on r of the smoothed run (data/smoother.py), with an intercept."""
    from usv_predictor.data.smoother import smooth_recording

    nu = smooth_recording(rec).nu
    basis = np.column_stack([np.ones(len(nu)), nu[:, 2]])
    (_, slope), *_ = np.linalg.lstsq(basis, nu[:, 1], rcond=None)
    return float(slope)


def circle_radius_study(bags: Path, work: Path) -> dict:
    """Why the models identified on one Dalian run turn the circle as they do (`--only circle`): the circle run's own
    record (circle_record), and for the Nomoto model and the grey box identified on each run the open-loop replay of
    the circle with its recorded commands (the radius of `--only low_order`), the turn of the circle's mean command
    held (held_command_circle; the Nomoto model's steady turn with its jackknife interval), and the drift each model
    makes in that turn against the drift of the run it was identified on."""
    from usv_predictor.fitting.nomoto_fit import NomotoFitOptions, fit_nomoto
    from usv_predictor.models.artifact import load_artifact
    from usv_predictor.physics.vessel import load_vessel
    from usv_predictor.replay.identify import IdentifyRequest, identify_bags

    vessel = load_vessel(DALIAN_VESSEL)
    runs = {name: recordings(bags / f"dalian_{name}", "twin_thrusters")[0] for name in ("circle", "sine")}
    circle = runs["circle"]
    record = circle_record(circle)
    out: dict = {"circle_run": record, "identified_on": {}}
    log(f"Dalian circle: {record['radius_m']:.2f} m, mean r {record['mean_r_rad_s']:.4f} rad/s, current from the "
        f"speed over ground {record['current_from_sog_mps']:.3f} m/s")
    for train in ("sine", "circle"):
        rec = runs[train]
        fit = fit_nomoto([rec], NomotoFitOptions(order=1))
        path = work / f"dalian_circle_study_greybox_{train}.pt"
        ident = identify_bags(IdentifyRequest((bags / f"dalian_{train}",), path, prior="fix", dt=DT, blocks=4),
                              vessel, progress=lambda _: None)
        steady = fit.turning_circle(record["mean_steering"], fit.coefficients.u_0
                                    + fit.coefficients.u_p * record["mean_propulsion"], record["mean_propulsion"])
        entry = {"data_drift_per_yaw_rate_m": drift_per_yaw_rate(rec), "models": {},
                 "yaw_rate_p5_p95_rad_s": np.percentile(rec.nu[:, 2], [5, 95]).tolist(),
                 "yaw_rate_max_rad_s": float(np.abs(rec.nu[:, 2]).max()),
                 "greybox_notes": ident["identification"]["notes"]}
        for label, model in (("Nomoto order 1 (output error)", fit), ("grey box identified (prior fix, 4 blocks)",
                                                                       load_artifact(path))):
            entry["models"][label] = {"replay": replay_turn(model, circle), "held": held_command_circle(model, circle)}
        entry["models"]["Nomoto order 1 (output error)"]["steady_turn"] = {
            "radius_m": steady["radius_m"], "radius_ci95_m": list(steady["radius_ci95_m"]),
            "k_v_m": fit.coefficients.k_v}
        for label, m in entry["models"].items():
            log(f"  from the {train}: {label:45s} replay {m['replay']['radius_m']:5.1f} m (U / mean r "
                f"{m['replay']['speed_over_mean_r_m']:5.1f} m), held command {m['held']['radius_m']:5.1f} m, drift "
                f"v / r {m['held'].get('drift_per_yaw_rate_m', math.nan):+.2f} m (data "
                f"{entry['data_drift_per_yaw_rate_m']:+.2f} m)")
        out["identified_on"][train] = entry
    return out


def _strict(x: object) -> object:
    """JSON-safe copy: non-finite floats as null, numpy scalars as floats, tuples as lists."""
    if isinstance(x, dict):
        return {str(k): _strict(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_strict(v) for v in x]
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--raw", type=Path, default=REPO.parent / "shared" / "data" / "raw")
    parser.add_argument("--work", type=Path, default=Path("/tmp/real_usv"))
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--only", choices=("dalian", "fuzhou", "low_order", "circle"), default=None)
    args = parser.parse_args()
    import torch

    torch.set_num_threads(1)
    args.work.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    bags = convert_records(args.raw, args.work)
    result = {}
    if args.only in (None, "dalian"):
        result["dalian"] = dalian(bags, args.work)
    if args.only in (None, "fuzhou"):
        result["fuzhou"] = fuzhou(bags, args.work)
    if args.only in (None, "low_order"):
        result["low_order"] = low_order(bags, args.work)
    if args.only in (None, "circle"):
        result["circle"] = circle_radius_study(bags, args.work)
    result["seconds"] = time.perf_counter() - started
    text = json.dumps(_strict(result), indent=2)
    if args.json:
        args.json.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
