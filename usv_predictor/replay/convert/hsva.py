"""The HSVA reader of replay/convert: KVLCC2 free-running zig-zags, HSVA for SIMMAN 2008, MODEL scale (1:45.714, L_pp 7
m, 0.05 s). The data contradict SOURCE.txt's column header in two places, both detected from the data: the 7th column
(labelled p) is the yaw rate - it equals d(psi)/dt - and the 8th (labelled r) is not; u, v are earth-fixed dx0/dt,
dy0/dt. The reader picks the column that IS d(psi)/dt and the velocity frame the positions prove, and refuses a file
where neither fits.
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from usv_predictor.errors import DatasetError
from usv_predictor.frames import ned_to_body, wrap_angle
from usv_predictor.records import NS_PER_S
from usv_predictor.replay.convert.common import (
    KVLCC2_LPP_FULL_M,
    KVLCC2_LPP_MODEL_M,
    Format,
    Manoeuvre,
    ScaleInfo,
    _check_range,
    _check_time,
    _check_track_follows_heading,
    _first_side,
    _parse_table,
    _read_text,
    _velocity_frame,
    _yaw_rate_column,
)

HSVA_LAMBDA = 45.714  # model scale 1:45.714 (SOURCE.txt)
HSVA_DT_S = 0.05  # (s)


HSVA_COLUMNS = ("time", "x0", "y0", "psi", "u", "v", "p", "r", "delta", "rev", "thrust", "torque")
HSVA_HEADER_LINES = 4
_HSVA_NAME = re.compile(r"HSVA_CPMC_KVLCC2_Z_(\d+)_(\d+)(?:_([SP]))?$", re.IGNORECASE)
_HSVA_TITLE = re.compile(r"Z\s*(\d+)\D{1,3}?/\s*(\d+)")


def read_hsva(path: Path) -> Manoeuvre:
    """One HSVA KVLCC2 zig-zag (.dat, cp1252), model scale kept; see the module docstring for the columns."""
    path = Path(path)
    lines = _read_text(path, "cp1252").splitlines()
    if not lines:
        raise DatasetError(f"{path}: empty file, expected the HSVA header and data")
    if "HSVA" not in lines[0] or len(lines) < HSVA_HEADER_LINES:
        raise DatasetError(f"{path}:1: expected the HSVA header ('HSVA, experimental data ...', 4 lines), "
                           f"found {lines[0].strip()[:60]!r}")
    title = _HSVA_TITLE.search(lines[2])
    named = _HSVA_NAME.match(path.stem)
    if title is None:
        raise DatasetError(f"{path}:3: expected the zig-zag title like 'Z10°/5°', found {lines[2].strip()!r}")
    rudder_deg, check_deg = float(title.group(1)), float(title.group(2))
    if named and (float(named.group(1)), float(named.group(2))) != (rudder_deg, check_deg):
        raise DatasetError(f"{path}:3: title says Z{rudder_deg:g}/{check_deg:g} but the file name says "
                           f"Z_{named.group(1)}_{named.group(2)}")
    a = _parse_table(path, lines[HSVA_HEADER_LINES:], HSVA_HEADER_LINES + 1, HSVA_COLUMNS, str.split,
                     allow_trailing_blank=True)
    first = HSVA_HEADER_LINES + 1
    t_s = a[:, 0] - a[0, 0]
    _check_time(path, a[:, 0], first, HSVA_DT_S, "time")
    x, y, psi_deg, c_u, c_v = a[:, 1], a[:, 2], a[:, 3], a[:, 4], a[:, 5]
    _check_range(path, "u", np.hypot(c_u, c_v), 0.5, 2.0, "model-scale speed in m/s (~1.18)")
    _check_range(path, "rev", a[:, 9], 5.0, 20.0, "propeller speed in rps (~10.23)")
    _check_range(path, "delta", np.abs(a[:, 8]), 0.0, 40.0, "rudder angle in deg")
    half = 5  # 0.25 s either side
    yaw_column = _yaw_rate_column(path, t_s, psi_deg, {"p": a[:, 6], "r": a[:, 7]}, half)
    psi_unwrapped = np.radians(np.unwrap(psi_deg, period=360.0))
    frame = _velocity_frame(path, t_s, x, y, psi_unwrapped, c_u, c_v, half, tolerance_mps=0.02)
    u, v = ned_to_body(c_u, c_v, psi_unwrapped) if frame == "earth" else (c_u, c_v)
    course_deg = _check_track_follows_heading(path, t_s, x, y, psi_unwrapped, half, 30.0)
    delta = -np.radians(a[:, 8])  # the file's delta is positive to PORT
    side = named.group(3) if named and named.group(3) else None
    first_side = _first_side(delta, math.radians(0.5))
    if side and first_side != {"S": "starboard", "P": "port"}[side.upper()]:
        raise DatasetError(f"{path}: file name says first rudder to {side}, the rudder column goes {first_side} first")
    name = f"hsva_z_{int(rudder_deg):02d}_{int(check_deg):02d}" + (f"_{side.lower()}" if side else "")
    return Manoeuvre(
        name=name, source="hsva", path=path, t_s=t_s, x_n=x.copy(), y_e=y.copy(), psi=wrap_angle(psi_unwrapped),
        u=u, v=v, r=np.radians(a[:, 6 if yaw_column == "p" else 7]), delta=delta, rpm=a[:, 9] * 60.0,
        scale=ScaleInfo("model", HSVA_LAMBDA, KVLCC2_LPP_MODEL_M, KVLCC2_LPP_FULL_M),
        rudder_amplitude_deg=rudder_deg, check_angle_deg=check_deg, first_side=first_side,
        notes={
            "columns": "time[s] x0[m] y0[m] psi[deg] u v col7 col8 delta[deg] rev[rps] thrust[N] torque[Nm]",
            "yaw_rate_column": f"column labelled {yaw_column!r} in SOURCE.txt is d(psi)/dt and is used as r "
                               "(the data contradict the SOURCE.txt labels p/r)",
            "velocity_frame": f"u, v columns are {frame}-fixed"
                              + (" (dx0/dt, dy0/dt), rotated into the body by psi" if frame == "earth" else ""),
            "rudder_sign": "file delta positive to port; written delta = -file delta (positive to starboard)",
            "rpm": "propeller rpm = rev[rps] * 60",
            "axes": "tank x0 -> north, y0 -> east (y0 and psi both positive to starboard)",
            "course_minus_heading_median_deg": f"{course_deg:.2f}",
        },
    )


FORMAT = Format(
    "hsva", lambda p: [read_hsva(p)], lambda name: name.upper().startswith("HSVA_") and name.lower().endswith(".dat"),
    "HSVA_*.dat",
    "no explicit data licence; research use. Cite SIMMAN 2008 (Stern et al. 2011) and the HSVA report "
    "(A. Cura Hochbaum, 2006). Do not commit the raw files into a repository.",
    epoch_ns=1_136_073_600 * NS_PER_S,  # 2006-01-01 00:00 UTC (year of the HSVA report): the files carry no date
    datum_deg=(53.5680, 10.0110),  # HSVA, Hamburg (nominal, NOT measured): lat/lon = datum + the tank track
)
