"""The Fuzhou reader of replay/convert: 3.6 m rudder-steered USV, 30 deg zig-zag at sea, 0.5 s interpolated. The `speed`
column is in KNOTS, not m/s as SOURCE.txt says: the GNSS track moves 0.51 m per second per unit of speed. The reader
detects the unit from the track (knots or m/s, else error). u, v: over-ground velocity of the GNSS track (centred
difference over 2 s) rotated into the body; r: centred difference of the unwrapped heading over 1 s. No propeller
data: no engine_rpm topic.
"""
from __future__ import annotations

import csv
import math
import re
from pathlib import Path

import numpy as np

from usv_predictor.errors import DatasetError
from usv_predictor.frames import LocalTangentPlane, ned_to_body, wrap_angle
from usv_predictor.records import NS_PER_S
from usv_predictor.replay.convert.common import (
    KNOT,
    Format,
    Manoeuvre,
    ScaleInfo,
    _check_range,
    _check_time,
    _check_track_follows_heading,
    _parse_table,
    _read_text,
    centred_derivative,
)

FUZHOU_REQUIRED = ("time", "lon", "lat", "speed", "heading", "rudder", "psi")
_FUZHOU_NAME = re.compile(r"zigzag_(\d+)", re.IGNORECASE)
FUZHOU_VELOCITY_HALF_WIDTH = 2  # samples: +-1 s at 0.5 s
FUZHOU_YAW_HALF_WIDTH = 1  # samples: +-0.5 s


def read_fuzhou(path: Path) -> Manoeuvre:
    """The Fuzhou USV sea-trial zig-zag (.csv with header); see the module docstring for u, v, r."""
    path = Path(path)
    lines = _read_text(path, "utf-8-sig").splitlines()
    if not lines:
        raise DatasetError(f"{path}: empty file, expected a CSV header with {', '.join(FUZHOU_REQUIRED)}")
    header = [h.strip() for h in next(csv.reader([lines[0]]))]
    missing = [c for c in FUZHOU_REQUIRED if c not in header]
    if missing:
        raise DatasetError(f"{path}:1: missing column(s) {', '.join(missing)}; header has {', '.join(header)}")
    a = _parse_table(path, lines[1:], 2, header, lambda line: next(csv.reader([line]), []), allow_trailing_blank=True)
    col = {name: a[:, header.index(name)] for name in header}
    t_s = col["time"] - col["time"][0]
    _check_time(path, col["time"], 2, None, "time")
    lat, lon = col["lat"], col["lon"]
    if not (np.all(np.abs(lat) < 90.0) and np.all(np.abs(lon) <= 180.0)):
        raise DatasetError(f"{path}: columns 'lat', 'lon' are not latitude/longitude in degrees")
    psi_unwrapped = col["psi"]
    heading_gap = np.abs(wrap_angle(psi_unwrapped - np.radians(col["heading"])))
    if heading_gap.max() > 1e-3:
        k = int(np.argmax(heading_gap))
        raise DatasetError(f"{path}:{k + 2}: columns 'psi' (rad) and 'heading' (deg) disagree by "
                           f"{math.degrees(heading_gap[k]):.2f} deg; expected the same angle in rad and deg")
    plane = LocalTangentPlane(float(lat[0]), float(lon[0]))
    x, y = plane.to_ned(lat, lon)
    if "x0" in col and "y0" in col:
        gap = np.hypot(col["x0"] - x, col["y0"] - y)
        if gap.max() > 10.0:
            k = int(np.argmax(gap))
            raise DatasetError(f"{path}:{k + 2}: columns 'x0', 'y0' are {gap[k]:.1f} m from lat/lon; expected "
                               f"metres north/east of the first fix (within 10 m)")
    if "delta" in col:
        sign_gap = np.abs(col["delta"] + np.radians(col["rudder"]))
        if sign_gap.max() > 1e-3:
            k = int(np.argmax(sign_gap))
            raise DatasetError(f"{path}:{k + 2}: column 'delta' is not -radians('rudder'); expected "
                               f"delta[rad] = -rudder")
    _check_range(path, "rudder", np.abs(col["rudder"]), 0.0, 45.0, "rudder angle in deg")
    # Speed units: SOURCE.txt says m/s; measure the GNSS track to decide between m/s and knots.
    k = 4  # +-2 s
    n = len(t_s)
    track = np.hypot(x[2 * k:] - x[:n - 2 * k], y[2 * k:] - y[:n - 2 * k]) / (t_s[2 * k:] - t_s[:n - 2 * k])
    ratio = float(np.mean(track) / np.mean(col["speed"][k:n - k]))
    if abs(ratio - KNOT) < 0.1:
        speed_unit = "kn"
    elif abs(ratio - 1.0) < 0.15:
        speed_unit = "m/s"
    else:
        raise DatasetError(f"{path}: column 'speed': the GNSS track moves {ratio:.3f} m/s per unit of speed; "
                           f"expected 1 (m/s) or {KNOT:.4f} (knots)")
    u_over_ground, v_over_ground = ned_to_body(
        centred_derivative(t_s, x, FUZHOU_VELOCITY_HALF_WIDTH), centred_derivative(t_s, y, FUZHOU_VELOCITY_HALF_WIDTH),
        psi_unwrapped)
    course_deg = _check_track_follows_heading(path, t_s, x, y, psi_unwrapped, 4, 45.0)
    named = _FUZHOU_NAME.search(path.stem)
    nominal = float(named.group(1)) if named else float(np.round(np.percentile(np.abs(col["rudder"]), 90)))
    delta = np.radians(col["rudder"])  # 'rudder' positive turns to starboard (delta = -rudder is the other sign)
    first_side = "starboard" if delta[np.argmax(np.abs(delta) > math.radians(0.5 * nominal))] > 0 else "port"
    return Manoeuvre(
        name=f"fuzhou_zigzag_{int(nominal):02d}", source="fuzhou", path=path, t_s=t_s, x_n=x, y_e=y,
        psi=wrap_angle(psi_unwrapped), u=u_over_ground, v=v_over_ground,
        r=centred_derivative(t_s, psi_unwrapped, FUZHOU_YAW_HALF_WIDTH), delta=delta, rpm=None,
        scale=ScaleInfo("full", 1.0, 3.6, 3.6), rudder_amplitude_deg=nominal, check_angle_deg=nominal,
        first_side=first_side, lat_deg=lat.copy(), lon_deg=lon.copy(),
        notes={
            "speed_unit": f"column 'speed' is in {speed_unit} (GNSS track / speed = {ratio:.3f}); SOURCE.txt says m/s",
            "velocity": "u, v = over-ground velocity of the GNSS track (centred difference over 2 s) rotated into "
                        "the body by psi; includes the unmeasured current",
            "yaw_rate": "r = centred difference of the unwrapped psi over 1 s (no gyro in the file)",
            "rudder_sign": "delta = radians(rudder), positive to starboard (file 'delta' = -rudder is not used)",
            "rpm": "no propeller data (thrust column all zero): no engine_rpm topic",
            "unused": "xcourse, ycourse, zcourse, rudder_command (meaning unknown)",
            "positions": "x_n, y_e from lat/lon, local tangent plane at the first fix",
            "course_minus_heading_median_deg": f"{course_deg:.2f}",
        },
    )


FORMAT = Format(
    "fuzhou", lambda p: [read_fuzhou(p)], lambda name: name.lower().endswith(".csv") and "zigzag" in name.lower(),
    "a zigzag*.csv of the Fuzhou USV",
    "none stated; research use. Cite Alexandersson, Zhang, Mao, Ringsberg (2022), Ships and Offshore "
    "Structures, doi:10.1080/17445302.2022.2067409. Do not commit the raw file into a repository.",
    epoch_ns=1_640_995_200 * NS_PER_S,  # 2022-01-01 00:00 UTC (year of the publication): the file carries no date
)
