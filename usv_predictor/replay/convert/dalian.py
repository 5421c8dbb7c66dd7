"""The Dalian reader of replay/convert: a small twin-thruster USV (differential thrust, PWM commands), closed-loop path
following at sea, .xlsx (read with openpyxl, imported only here). The x, y columns are NOT metres (11.2 % inflated)
and t is NOT time (a nominal 0.1 s per row): time from DateTime, position from Longitude/Latitude; rows without a new
GNSS fix (about every second row) carry no position or heading measurement; u, v, r are derived by the EKF/RTS
smoother (data/smoother.py) from the fixes and the heading (velocity over ground); PWM_L is the port thruster
(checked on every file: more PWM_L turns to starboard), c = (PWM - 1500) / 500.
"""
from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Mapping

import numpy as np

from usv_predictor.errors import DatasetError
from usv_predictor.frames import LocalTangentPlane, wrap_angle
from usv_predictor.replay.convert.common import (
    MIN_ROWS,
    Format,
    Manoeuvre,
    ScaleInfo,
    _check_range,
    _check_time,
    _check_track_follows_heading,
    centred_derivative,
)

DALIAN_REQUIRED = ("DateTime", "t", "Longitude", "Latitude", "x", "y", "Heading", "course", "Speed", "PWM_L", "PWM_R")
DALIAN_TIME_FORMAT = "%Y-%m-%d %H:%M:%S.%f"
# DateTime read as China Standard Time (UTC+8): the boat ran near Dalian; the file names no zone
DALIAN_UTC_OFFSET_H = 8
PWM_NEUTRAL_US = 1500.0  # (us) thruster command at zero thrust (SOURCE.txt)
PWM_FULL_SCALE_US = 500.0  # (us) command above neutral that means full ahead (1000-2000 us range)
PWM_RANGE_US = (1000.0, 2000.0)  # (us) what a hobby ESC accepts
DALIAN_SMOOTHER_DT_S = 0.05  # (s) grid of the EKF/RTS smoother; a fix is placed on the nearest grid step (<= 25 ms)
DALIAN_MOVING_MPS = 0.3  # (m/s) speed over ground above which course, drift and turn-sign checks use a row
DALIAN_MIN_TURN_CORRELATION = 0.3  # (-) yaw rate vs PWM_L - PWM_R below this: the sides cannot be told (refused)
DALIAN_SPEED_RATIO = (0.9, 1.1)  # smoothed speed over ground / the Speed column accepted as "Speed is m/s"


def _dalian_sheets(path: Path) -> tuple[list[str], list[tuple], dict[str, str]]:
    """(Sheet1 header, Sheet1 data rows, Sheet2 parameters) of a Dalian .xlsx (openpyxl, read-only)."""
    try:
        import openpyxl  # noqa: PLC0415 (lazy: only this reader needs it; `replay --help` stays light)
    except ImportError as err:
        raise DatasetError(f"{path}: reading .xlsx needs openpyxl (pip install openpyxl==3.1.5, "
                           f"requirements.txt)") from err
    try:
        book = openpyxl.load_workbook(path, read_only=True, data_only=True)
    except Exception as err:  # noqa: BLE001 (openpyxl raises zipfile, KeyError, its own InvalidFileException ...)
        raise DatasetError(f"{path}: not a readable .xlsx workbook ({type(err).__name__}: {err})") from err
    try:
        if "Sheet1" not in book.sheetnames:
            raise DatasetError(f"{path}: no sheet 'Sheet1' (the time series); sheets: {book.sheetnames}")
        rows = list(book["Sheet1"].iter_rows(values_only=True))
        params: dict[str, str] = {}
        if "Sheet2" in book.sheetnames:
            sheet2 = list(book["Sheet2"].iter_rows(values_only=True))
            if len(sheet2) >= 2:
                params = {str(k): str(v) for k, v in zip(sheet2[0], sheet2[1]) if k is not None}
    finally:
        book.close()
    if not rows:
        raise DatasetError(f"{path}: Sheet1 is empty, expected a header with {', '.join(DALIAN_REQUIRED)}")
    header = [str(h).strip() if h is not None else "" for h in rows[0]]
    missing = [c for c in DALIAN_REQUIRED if c not in header]
    if missing:
        raise DatasetError(f"{path}: Sheet1 row 1: missing column(s) {', '.join(missing)}; header has "
                           f"{', '.join(header)}")
    data = [r for r in rows[1:] if any(c is not None for c in r)]
    if len(data) < MIN_ROWS:
        raise DatasetError(f"{path}: Sheet1 has only {len(data)} data rows, expected at least {MIN_ROWS}")
    return header, data, params


def _dalian_columns(path: Path, header: list[str], data: list[tuple]) -> tuple[np.ndarray, int, dict[str, np.ndarray]]:
    """(t_s from DateTime (N,), epoch_ns of the first row, numeric columns by name); errors name row and column."""
    import datetime as _dt

    index = {name: header.index(name) for name in DALIAN_REQUIRED}
    zone = _dt.timezone(_dt.timedelta(hours=DALIAN_UTC_OFFSET_H))
    micros = np.empty(len(data), dtype=np.int64)
    for k, row in enumerate(data):
        text = row[index["DateTime"]]
        try:
            stamp = _dt.datetime.strptime(str(text).strip(), DALIAN_TIME_FORMAT).replace(tzinfo=zone)
        except ValueError:
            raise DatasetError(f"{path}: Sheet1 row {k + 2}: column 'DateTime': {text!r} is not a time like "
                               f"'2025-07-24 15:45:54.179' ({DALIAN_TIME_FORMAT})") from None
        micros[k] = int(stamp.timestamp()) * 1_000_000 + stamp.microsecond
    columns: dict[str, np.ndarray] = {}
    for name in DALIAN_REQUIRED[1:]:
        values = np.empty(len(data))
        for k, row in enumerate(data):
            cell = row[index[name]]
            try:
                values[k] = float(cell)
            except (TypeError, ValueError):
                raise DatasetError(f"{path}: Sheet1 row {k + 2}: column {name!r}: {cell!r} is not a number") from None
            if not math.isfinite(values[k]):
                raise DatasetError(f"{path}: Sheet1 row {k + 2}: column {name!r}: {cell!r} is not finite")
        columns[name] = values
    t_s = (micros - micros[0]) / 1e6
    _check_time(path, t_s, 2, None, "DateTime")
    return t_s, int(micros[0]) * 1000, columns


def _new_fixes(col: Mapping[str, np.ndarray]) -> np.ndarray:
    """(N,) bool: rows whose position, heading or speed differs from the previous row's (the log repeats the last
    GNSS message on rows in between: about every second row)."""
    fields = np.column_stack([col["Longitude"], col["Latitude"], col["Heading"], col["Speed"]])
    return np.r_[True, np.any(fields[1:] != fields[:-1], axis=1)]


def _grid_and_smooth(t_s: np.ndarray, x: np.ndarray, y: np.ndarray, psi: np.ndarray, fix: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(grid (G,) s, slot of each fix (F,), smoothed states (G, 9)): the EKF/RTS smoother of data/smoother.py on the
    fixes and the heading alone, on a uniform DALIAN_SMOOTHER_DT_S grid (a fix on its nearest step, a later fix in
    the same step wins), jerk densities tuned by likelihood."""
    from usv_predictor.data.smoother import tune

    dt = DALIAN_SMOOTHER_DT_S
    grid = np.arange(int(np.floor(t_s[-1] / dt)) + 1) * dt
    z = np.full((len(grid), 6), np.nan)
    slots = np.clip(np.round(t_s[fix] / dt).astype(int), 0, len(grid) - 1)
    z[slots, 0], z[slots, 1], z[slots, 2] = x[fix], y[fix], psi[fix]
    return grid, slots, tune(z, dt).state


def read_dalian(path: Path) -> Manoeuvre:
    """A Dalian twin-thruster USV run (.xlsx, Sheet1 time series, Sheet2 path parameters); see the module
    docstring. Every SOURCE.txt statement the data contradict is measured and written into the notes."""
    path = Path(path)
    header, data, params = _dalian_sheets(path)
    t_s, epoch_ns, col = _dalian_columns(path, header, data)
    for side in ("PWM_L", "PWM_R"):
        low, high = PWM_RANGE_US
        outside = np.flatnonzero((col[side] < low) | (col[side] > high))
        if len(outside):
            k = int(outside[0])
            raise DatasetError(f"{path}: Sheet1 row {k + 2}: column {side!r}: {col[side][k]:g} is outside "
                               f"{low:g}-{high:g}; "
                               f"expected a PWM pulse width in microseconds with {PWM_NEUTRAL_US:g} neutral")
    lat, lon = col["Latitude"], col["Longitude"]
    if not (np.all(np.abs(lat) < 90.0) and np.all(np.abs(lon) <= 180.0)):
        raise DatasetError(f"{path}: columns 'Latitude', 'Longitude' are not latitude/longitude in degrees")
    _check_range(path, "Heading", np.abs(col["Heading"]), 0.0, 180.0, "a heading in degrees within (-180, 180]")
    if np.abs(col["Heading"]).max() > 360.0:
        raise DatasetError(f"{path}: column 'Heading' exceeds 360; expected degrees")
    try:
        datum = (float(params["LatitudeStart"]), float(params["LongitudeStart"]))
        datum_note = "Sheet2 LatitudeStart/LongitudeStart (the path's origin)"
    except (KeyError, ValueError):
        datum = (float(lat[0]), float(lon[0]))
        datum_note = "the first fix (Sheet2 has no LatitudeStart/LongitudeStart)"
    plane = LocalTangentPlane(*datum)
    x_all, y_all = plane.to_ned(lat, lon)
    fix = _new_fixes(col)
    psi_fix = np.radians(np.unwrap(col["Heading"][fix], period=360.0))
    tf, xf, yf = t_s[fix], x_all[fix], y_all[fix]
    course_deg = _check_track_follows_heading(path, tf, xf, yf, psi_fix, 4, 30.0)
    # SOURCE.txt says x[m], y[m]: the data say they are a scaled copy of the lon/lat metres (x north, y east)
    scale_xy = float((col["x"] @ x_all + col["y"] @ y_all) / max(x_all @ x_all + y_all @ y_all, 1e-12))
    xy_rms = float(np.sqrt(np.mean((col["x"] - scale_xy * x_all) ** 2 + (col["y"] - scale_xy * y_all) ** 2)))
    psi_rows = np.full(len(t_s), np.nan)
    psi_rows[fix] = psi_fix
    grid, slots, state = _grid_and_smooth(t_s, x_all, y_all, psi_rows, fix)
    u, v, r = state[:, 3], state[:, 4], state[:, 5]
    speed = np.hypot(u, v)
    moving_fix = col["Speed"][fix] > DALIAN_MOVING_MPS
    speed_ratio = float(np.median(speed[slots][moving_fix]) / np.median(col["Speed"][fix][moving_fix]))
    if not DALIAN_SPEED_RATIO[0] <= speed_ratio <= DALIAN_SPEED_RATIO[1]:
        raise DatasetError(f"{path}: column 'Speed': the track from Longitude/Latitude and DateTime moves "
                           f"{speed_ratio:.3f} m/s per unit of Speed; expected 1 (Speed in m/s over ground)")
    # course over ground against the track's, where the boat moves
    cog = np.degrees(np.arctan2(centred_derivative(tf, yf, 4), centred_derivative(tf, xf, 4)))
    course_gap = float(np.median(np.abs(wrap_angle(np.radians(col["course"][fix] - cog))[moving_fix])))
    # the commands hold from their row to the next (zero-order hold) on the grid
    held = np.clip(np.searchsorted(t_s, grid + 1e-9, side="right") - 1, 0, len(t_s) - 1)
    pwm_l, pwm_r = col["PWM_L"][held], col["PWM_R"][held]
    # which thruster is port: more port thrust turns the bow to starboard (r > 0; Fossen 2021 sec. 2.2)
    window = int(round(1.0 / DALIAN_SMOOTHER_DT_S))
    difference = np.convolve(pwm_l - pwm_r, np.ones(2 * window + 1) / (2 * window + 1), mode="same")
    moving = speed > DALIAN_MOVING_MPS
    turn_correlation = float(np.corrcoef(r[moving], difference[moving])[0, 1])
    if not turn_correlation > DALIAN_MIN_TURN_CORRELATION:
        raise DatasetError(f"{path}: columns 'PWM_L', 'PWM_R': the yaw rate correlates {turn_correlation:+.2f} with "
                           f"PWM_L - PWM_R; expected > {DALIAN_MIN_TURN_CORRELATION:g} (PWM_L the port thruster: more "
                           "port thrust turns to starboard)")
    drift_s = float(col["t"][-1] - t_s[-1])
    stem = path.stem.lower()
    kind = "circle" if "circle" in stem else "sine" if "sin" in stem else re.sub(r"[^a-z0-9]+", "_", stem)
    on_grid = np.zeros(len(grid), dtype=bool)
    on_grid[slots] = True
    nan = np.full(len(grid), np.nan)
    x_n, y_e, lat_fix, lon_fix = nan.copy(), nan.copy(), nan.copy(), nan.copy()
    x_n[slots], y_e[slots], lat_fix[slots], lon_fix[slots] = xf, yf, lat[fix], lon[fix]
    return Manoeuvre(
        name=f"dalian_{kind}", source="dalian", path=path, t_s=grid, x_n=x_n, y_e=y_e, psi=wrap_angle(state[:, 2]),
        u=u, v=v, r=r, delta=None, rpm=None, scale=ScaleInfo("full", 1.0, math.nan, math.nan),
        rudder_amplitude_deg=math.nan, check_angle_deg=math.nan, first_side="none", lat_deg=lat_fix,
        lon_deg=lon_fix, thrusters=((pwm_l - PWM_NEUTRAL_US) / PWM_FULL_SCALE_US,
                                    (pwm_r - PWM_NEUTRAL_US) / PWM_FULL_SCALE_US), fix=on_grid, epoch_ns=epoch_ns,
        notes={
            "time": f"DateTime read as UTC+{DALIAN_UTC_OFFSET_H} (no zone in the file); column 't' is a nominal 0.1 s "
                    f"per row, not time: it ends {drift_s:+.1f} s from DateTime (SOURCE.txt calls it t[s])",
            "positions": f"from Longitude/Latitude, local tangent plane at {datum_note} {datum[0]:.8f},{datum[1]:.8f}; "
                         f"columns 'x', 'y' are {scale_xy:.5f} x these metres (rms {xy_rms:.3f} after scaling), "
                         "not metres as SOURCE.txt says (x[m], y[m]): not used",
            "fixes": f"{int(fix.sum())} of {len(fix)} rows carry a new fix (position, heading, speed change; median "
                     f"{float(np.median(np.diff(tf))):.3f} s apart); the others repeat it and are not measurements. "
                     f"Written on a uniform {DALIAN_SMOOTHER_DT_S} s grid: gps/fix at the fixes (each on its nearest "
                     "grid step), everything else at every step",
            "heading": "Heading (deg, clockwise from north) at the fixes; the track follows it (median |course over "
                       f"ground - heading| {course_deg:.2f} deg); the heading topic carries the smoothed heading "
                       "(EKF/RTS) at every grid step, so the tools see no gaps between fixes",
            "course": f"column 'course' is the course over ground of the track (median |difference| "
                      f"{math.degrees(course_gap):.2f} deg); not written",
            "velocity": "u, v, r: EKF/RTS smoother (usv_predictor.data.smoother) on the fixes and heading alone "
                        f"(grid {DALIAN_SMOOTHER_DT_S} s, jerk densities tuned by likelihood); velocity over ground "
                        "(a current is not removed)",
            "speed": f"column 'Speed' is speed over ground in m/s: smoothed speed / Speed = {speed_ratio:.3f}",
            "thrusters": "PWM_L = port, PWM_R = starboard (the yaw rate correlates "
                         f"{turn_correlation:+.2f} with PWM_L - PWM_R: more port thrust turns to starboard); "
                         f"c = (PWM - {PWM_NEUTRAL_US:g}) / {PWM_FULL_SCALE_US:g}, written as "
                         f"thruster_port/thruster_starboard, "
                         "each logged command held until the next row (zero-order hold)",
            "unused": "x, y, t, course, HeadingSet, SpeedSet, w, varsigma_w, Voltage, tracking errors and "
                      "bounds, x_p, y_p",
            "length": "not published (no mass, length, thrusters): L_pp_m nan",
        },
        extra={"path_following": json.dumps(params, sort_keys=True)}, kind="path_following",
    )


FORMAT = Format(
    "dalian", lambda p: [read_dalian(p)], lambda name: name.lower().endswith(".xlsx"),
    "a .xlsx of the Dalian USV",
    "MIT (github.com/2345vor/USV-ASW-NMPC, 'MI Project Contributors'; the same files as 2345vor/MI "
    "datas/ at commit 54d75c029cc43fe2f4443e9449e8ae1cb0a026c9). Do not commit the raw files or bags made "
    "from them into this repository.",
)  # epoch: the file's DateTime (Manoeuvre.epoch_ns)
