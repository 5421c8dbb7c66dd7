"""Converted manoeuvres -> rosbag2: the stamps, the default input topics' signals, the provenance (custom_data),
the summary, one bag per manoeuvre (write_manoeuvre_bag) and `convert`, what `replay convert` does (every file read
first, then one bag each).
"""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from usv_predictor.errors import DatasetError
from usv_predictor.frames import LocalTangentPlane
from usv_predictor.records import NS_PER_S, Signal
from usv_predictor.replay.convert.common import CONVERSION_VERSION, GRAVITY, Manoeuvre, _file_digest, centred_derivative
from usv_predictor.replay.convert.formats import DATUM_DEG, EPOCH_NS, LICENCE, find_sources, read_manoeuvres


def time_ns(m: Manoeuvre) -> np.ndarray:
    """Stamps: the source's nominal epoch + the file's time base, int ns, strictly increasing."""
    epoch = EPOCH_NS[m.source] if m.epoch_ns is None else int(m.epoch_ns)
    t_ns = epoch + np.round(m.t_s * NS_PER_S).astype(np.int64)
    if np.any(np.diff(t_ns) <= 0):
        raise DatasetError(f"{m.path}: time base is not strictly increasing at nanosecond resolution")
    return t_ns


def to_signals(m: Manoeuvre) -> dict[str, Signal]:
    """role -> Signal for the default input topics (no ground truth: measured data have none).

    imu: yaw_rate = r; accel_x/accel_y = specific force from a smoothing differentiation of u, v
    (centred over +-0.5 s): a_x = du/dt - r v, a_y = dv/dt + r u; accel_z = -g; heading NaN (orientation
    absent, REP-145), as the simulator writes it. gnss: measured fixes when the source has them, else
    the track about the source's nominal datum (DATUM_DEG). engine_rpm only when rpm is measured; rudder_angle
    only with a rudder; thruster_port / thruster_starboard (field command) for twin thrusters. With `fix`, gnss
    carries only the rows of a fix.
    """
    t_ns = time_ns(m)
    dt = float(np.median(np.diff(m.t_s)))
    half = max(1, int(round(0.5 / dt)))
    a_x = centred_derivative(m.t_s, m.u, half) - m.r * m.v
    a_y = centred_derivative(m.t_s, m.v, half) + m.r * m.u
    n = len(t_ns)
    signals = {
        "imu": Signal(t_ns, np.column_stack([m.r, a_x, a_y, np.full(n, -GRAVITY), np.full(n, np.nan)]),
                      ("yaw_rate", "accel_x", "accel_y", "accel_z", "heading")),
        "velocity": Signal(t_ns, np.column_stack([m.u, m.v, m.r]), ("u", "v", "r")),
        "heading": Signal(t_ns, m.psi[:, None].copy(), ("psi",)),
    }
    if m.delta is not None:
        signals["rudder_angle"] = Signal(t_ns, m.delta[:, None].copy(), ("delta",))
    if m.thrusters is not None:
        signals["thruster_port"] = Signal(t_ns, m.thrusters[0][:, None].copy(), ("command",))
        signals["thruster_starboard"] = Signal(t_ns, m.thrusters[1][:, None].copy(), ("command",))
    if m.rpm is not None:
        signals["engine_rpm"] = Signal(t_ns, m.rpm[:, None].copy(), ("rpm",))
    if m.lat_deg is not None and m.lon_deg is not None:
        lat, lon = m.lat_deg, m.lon_deg
    else:
        lat, lon = LocalTangentPlane(*DATUM_DEG[m.source]).to_geodetic(m.x_n, m.y_e)
    signals["gnss"] = Signal(t_ns, np.column_stack([lat, lon, np.zeros(n)]), ("lat", "lon", "alt"))
    if m.fix is not None:  # positions only where the receiver delivered them
        sig = signals["gnss"]
        signals["gnss"] = Signal(sig.t_ns[m.fix], sig.values[m.fix], sig.fields)
    return signals


def custom_data(m: Manoeuvre, command: str = "replay convert") -> dict[str, str]:
    """Provenance written into the bag's metadata (all strings)."""
    from usv_predictor import __version__

    datum = "measured fixes" if m.lat_deg is not None else "nominal datum %.4f,%.4f (arbitrary)" % DATUM_DEG[m.source]
    out = {
        "generator": "usv_predictor replay convert", "version": __version__, "conversion_version": CONVERSION_VERSION,
        "command": command, "source": m.source, "source_file": m.path.name, "source_sha256": _file_digest(m.path),
        "licence": LICENCE[m.source], "manoeuvre": m.name, "manoeuvre_type": m.kind,
        "scale": m.scale.scale, "scale_factor": repr(m.scale.scale_factor), "L_pp_m": repr(m.scale.L_pp_m),
        "full_scale_L_pp_m": repr(m.scale.full_scale_L_pp_m),
        "conventions": ("NED, body FRD, psi clockwise from north, " + (
            "delta > 0 turns to starboard; engine_rpm carries PROPELLER rpm" if m.delta is not None else
            "thruster commands normalised to [-1, 1] (+ ahead), port = the thruster at body y < 0")
                        + "; no ground truth"),
        "epoch_ns": str(EPOCH_NS[m.source] if m.epoch_ns is None else m.epoch_ns), "gnss": datum,
        "notes": json.dumps(dict(m.notes), sort_keys=True),
    }
    if m.delta is not None and m.kind == "zigzag":
        out["zigzag"] = json.dumps({"rudder_deg": m.rudder_amplitude_deg, "check_deg": m.check_angle_deg,
                                    "first_side": m.first_side})
    out.update(m.extra)
    return out


def summarise(m: Manoeuvre) -> dict:
    speed = np.hypot(m.u, m.v)
    psi = m.psi[np.isfinite(m.psi)]
    out = {
        "manoeuvre": m.name, "manoeuvre_type": m.kind, "source": m.source, "file": str(m.path),
        "samples": len(m.t_s),
        "duration_s": m.duration_s, "rate_hz": m.rate_hz, "scale": m.scale.scale,
        "speed_mps": [float(speed.min()), float(speed.max())],
        "rudder_deg": None if m.delta is None else [float(np.degrees(m.delta.min())), float(np.degrees(m.delta.max()))],
        "rpm": None if m.rpm is None else [float(m.rpm.min()), float(m.rpm.max())],
        "heading_range_deg": float(np.degrees(np.ptp(np.unwrap(psi)))),
    }
    if m.thrusters is not None:
        out["thruster_commands"] = {side: [float(c.min()), float(c.max())] for side, c in zip(("port", "starboard"),
                                                                                              m.thrusters)}
    if m.fix is not None:
        out["fixes"] = int(m.fix.sum())
    return out


def write_manoeuvre_bag(path: Path, m: Manoeuvre, specs: Mapping[str, object], *, storage: str = "sqlite3",
                        overwrite: bool = False, command: str = "replay convert") -> int:
    """Write the bag of one manoeuvre (atomic, bagio); specs: role -> TopicSpec. Returns the message count."""
    from usv_predictor.replay.bagio import write_bag

    signals = to_signals(m)
    streams = [(specs[role], signal) for role, signal in signals.items()]
    write_bag(Path(path), streams, storage=storage, metadata=custom_data(m, command), overwrite=overwrite)
    return int(sum(len(s) for _, s in streams))


def convert(inputs: Sequence[Path], output: Path, *, fmt: str = "auto", storage: str = "sqlite3",
            overwrite: bool = False, command: str = "replay convert",
            progress: Callable[[str], None] = lambda _: None) -> dict:
    """`replay convert`: every manoeuvre file of `inputs` (directories or files, format `fmt`) -> one bag each
    in `output`, with the config's input topics. Every file is read first, so a bad one fails before any write."""
    from usv_predictor.config import load_predictor_config
    from usv_predictor.replay.bagio import config_topic_specs, prepare_outputs

    manoeuvres = [m for path, f in find_sources(inputs, fmt) for m in read_manoeuvres(path, f)]
    names: dict[str, Path] = {}
    for m in manoeuvres:
        if m.name in names:
            raise DatasetError(f"{m.path} and {names[m.name]} both convert to bag {m.name!r}; convert them separately")
        names[m.name] = m.path
    prepare_outputs(output, [output / m.name for m in manoeuvres], overwrite)
    specs = config_topic_specs(load_predictor_config(), include_ground_truth=False)
    results = []
    for k, m in enumerate(manoeuvres):
        started = time.perf_counter()
        path = output / m.name
        messages = write_manoeuvre_bag(path, m, specs, storage=storage, overwrite=overwrite, command=command)
        results.append(summarise(m) | {"bag": str(path), "messages": messages})
        progress(f"[{k + 1}/{len(manoeuvres)}] {path}  {m.duration_s:.0f} s at {m.rate_hz:.2f} Hz, {messages} messages "
                 f"({time.perf_counter() - started:.2f} s)")
    return {"bags": results, "conversion_version": CONVERSION_VERSION, "output": str(output)}
