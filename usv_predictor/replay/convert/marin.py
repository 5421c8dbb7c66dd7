"""The MARIN reader of replay/convert: KVLCC2 free-running tests, MARIN for SIMMAN 2008, FULL scale (L_pp 320 m): every
manoeuvre type of the format, named by the title line ("Zig-zag manoeuvring for KVLCC2 : 10 / -10", "Turning /
Pull-out manoeuvring for KVLCC2 : 35 (deg)", "Turning manoeuvring ..."). A turning / pull-out file is split at the
instant the rudder leaves its hold into two manoeuvres: the turning circle (approach + steady rudder) and the
pull-out (rudder back to midships). 3 significant digits: the time base is rebuilt as row * 0.13535 s (the time
column must agree within its rounding); positions (10 m steps at 4 km) are rebuilt by integrating the earth-fixed u,
v from the first position.
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np

from usv_predictor.errors import DatasetError
from usv_predictor.frames import ned_to_body, wrap_angle
from usv_predictor.records import NS_PER_S
from usv_predictor.replay.convert.common import (
    KVLCC2_LPP_FULL_M,
    MIN_ROWS,
    Format,
    Manoeuvre,
    ScaleInfo,
    _check_range,
    _check_track_follows_heading,
    _first_side,
    _parse_table,
    _read_text,
    _sig_half_unit,
    _velocity_frame,
    _yaw_rate_column,
)

MARIN_DT_S = 0.13535  # (s), full-scale sample interval (SOURCE.txt)


MARIN_COLUMNS = ("time", "x0", "y0", "phi", "psi", "u", "v", "p", "r", "delta", "rev")
MARIN_HEADER_LINES = 3
_MARIN_NAME = re.compile(r"MARIN_FREE_KVLCC2_(zz|tc)_(-?\d+)_m$", re.IGNORECASE)
_MARIN_TITLE = re.compile(r"^\s*(?P<kind>.+?)\s+manoeuvring\s+for\s+\S+\s*:\s*(?P<args>.*?)\s*$", re.IGNORECASE)
_MARIN_ZIGZAG_ARGS = re.compile(r"(-?\d+)\s*/\s*(-?\d+)")
_MARIN_TURN_ARGS = re.compile(r"^(-?\d+(?:\.\d+)?)\s*(?:\(deg\))?$", re.IGNORECASE)
# title words -> (what the file holds, file-name tag); the manoeuvre types of the SIMMAN 2008 MARIN format
MARIN_TYPES = {"zig-zag": ("zigzag", "zz"), "turning / pull-out": ("turning_pullout", "tc"),
               "turning": ("turning", "tc")}
MARIN_HOLD_TOLERANCE_DEG = 0.2  # (deg) the rudder is "held" within this of its median hold (3 digits: 0.1 deg steps)
MARIN_MIDSHIPS_FRACTION = 0.25  # after a pull-out the median |rudder| must be below this fraction of the turn's
MARIN_EXECUTE_DEG = 0.5  # (deg) the turn's execute: the first row the rudder is this far from its approach angle


def _marin_type(path: Path, title_line: str) -> tuple[str, str, str]:
    """(type, file-name tag, the title's arguments) of a MARIN file from its 2nd line; DatasetError naming the
    known types."""
    title = _MARIN_TITLE.match(title_line)
    kind = re.sub(r"\s*/\s*", " / ", title.group("kind").strip().lower()) if title else None
    if title is None or kind not in MARIN_TYPES:
        known = ", ".join(f"'{k.capitalize()} manoeuvring for KVLCC2 : ...'" for k in MARIN_TYPES)
        raise DatasetError(f"{path}:2: expected a manoeuvre title ({known}), found {title_line.strip()!r}")
    return (*MARIN_TYPES[kind], title.group("args"))


def read_marin(path: Path) -> list[Manoeuvre]:
    """The manoeuvres of one MARIN KVLCC2 file (.dat, tab-separated, full scale, 3 significant digits): a zig-zag,
    or a turning circle followed by its pull-out (two manoeuvres), by the title line."""
    path = Path(path)
    lines = _read_text(path, "cp1252").splitlines()
    if len(lines) < MARIN_HEADER_LINES or "MARIN" not in lines[0]:
        raise DatasetError(f"{path}:1: expected the MARIN header ('MARIN(Maritime Research Institute ...', 3 lines)")
    kind, tag, args = _marin_type(path, lines[1])
    if kind == "zigzag":
        title = _MARIN_ZIGZAG_ARGS.search(args)
        if title is None:
            raise DatasetError(f"{path}:2: expected 'Zig-zag manoeuvring for KVLCC2 : A / -A', found "
                               f"{lines[1].strip()!r}")
    else:
        title = _MARIN_TURN_ARGS.match(args)
        if title is None:
            raise DatasetError(f"{path}:2: expected the turn's rudder angle like ': 35 (deg)', found "
                               f"{lines[1].strip()!r}")
    first_rudder = float(title.group(1))  # file convention: positive to port
    named = _MARIN_NAME.match(path.stem)
    if named and named.group(1).lower() != tag:
        raise DatasetError(f"{path}:2: title says {lines[1].split(' manoeuvring')[0].strip()!r} but the file name says "
                           f"{named.group(1)!r} (zz: zig-zag, tc: turning / pull-out)")
    if named and float(named.group(2)) != first_rudder:
        raise DatasetError(f"{path}:2: title says first rudder {first_rudder:g} but the file name says "
                           f"{named.group(2)}")
    a = _parse_table(path, lines[MARIN_HEADER_LINES:], MARIN_HEADER_LINES + 1, MARIN_COLUMNS,
                     lambda line: line.split("\t"), allow_trailing_blank=True)
    first = MARIN_HEADER_LINES + 1
    # Time: 3 significant digits repeat the column; rebuild, and prove the column agrees within its rounding.
    t_s = np.arange(len(a)) * MARIN_DT_S
    mismatch = np.abs(a[:, 0] - t_s) > _sig_half_unit(a[:, 0]) + 0.002 * t_s + 1e-9
    if mismatch.any():
        k = int(np.flatnonzero(mismatch)[0])
        raise DatasetError(f"{path}:{first + k}: column 'time': {a[k, 0]:g} s disagrees with the rebuilt time "
                           f"base row * {MARIN_DT_S:g} s = {t_s[k]:.4f} s beyond the 3-digit rounding")
    # a turn slows the ship to ~35 % of its approach speed: the median is checked on the approach for a turn
    approach = slice(None) if kind == "zigzag" else slice(0, max(MIN_ROWS, int(round(20.0 / MARIN_DT_S))))
    _check_range(path, "u", np.hypot(a[approach, 5], a[approach, 6]), 4.0, 12.0, "full-scale speed in m/s (~7.97)")
    _check_range(path, "rev", a[:, 10], 50.0, 150.0, "propeller speed in rpm (~91.7)")
    _check_range(path, "delta", np.abs(a[:, 9]), 0.0, 40.0, "rudder angle in deg")
    psi_unwrapped = np.radians(np.unwrap(a[:, 4], period=360.0))
    half = 75  # +-10 s: the 10 m position steps need a long baseline
    _yaw_rate_column(path, t_s, a[:, 4], {"r": a[:, 8]}, 15)
    frame = _velocity_frame(path, t_s, a[:, 1], a[:, 2], psi_unwrapped, a[:, 5], a[:, 6], half, tolerance_mps=0.5)
    if frame != "earth":
        raise DatasetError(f"{path}: columns 'u', 'v' look body-fixed; SOURCE.txt says earth-fixed dx0/dt, dy0/dt")
    # Positions: integrate the earth-fixed velocities (0.01 m/s digits) instead of the 10 m position steps.
    step = 0.5 * np.diff(t_s)
    x = a[0, 1] + np.r_[0.0, np.cumsum(step * (a[1:, 5] + a[:-1, 5]))]
    y = a[0, 2] + np.r_[0.0, np.cumsum(step * (a[1:, 6] + a[:-1, 6]))]
    run_m = np.r_[0.0, np.cumsum(np.hypot(np.diff(x), np.diff(y)))]
    deviation = np.hypot(x - a[:, 1], y - a[:, 2])
    too_far = deviation > 20.0 + 0.01 * run_m
    if too_far.any():
        k = int(np.flatnonzero(too_far)[0])
        raise DatasetError(f"{path}:{first + k}: columns 'x0', 'y0' are {deviation[k]:.0f} m from the integral of "
                           f"'u', 'v'; expected within 20 m + 1 % of the distance run (m and m/s)")
    course_deg = _check_track_follows_heading(path, t_s, x, y, psi_unwrapped, 15, 30.0)
    u, v = ned_to_body(a[:, 5], a[:, 6], psi_unwrapped)
    delta = -np.radians(a[:, 9])  # file delta positive to PORT
    amplitude = abs(first_rudder)
    first_side = _first_side(delta, math.radians(0.5 * amplitude))
    expected_side = "port" if first_rudder > 0 else "starboard"
    if first_side != expected_side:
        raise DatasetError(f"{path}: title says first rudder {first_rudder:g} (to {expected_side}, file delta "
                           f"positive to port) but the rudder column goes {first_side} first")
    whole = Manoeuvre(
        name=f"marin_zz_{int(amplitude):02d}_{int(amplitude):02d}_{expected_side[0]}", source="marin", path=path,
        t_s=t_s, x_n=x, y_e=y, psi=wrap_angle(psi_unwrapped), u=u, v=v, r=np.radians(a[:, 8]), delta=delta,
        rpm=a[:, 10].copy(), scale=ScaleInfo("full", 1.0, KVLCC2_LPP_FULL_M, KVLCC2_LPP_FULL_M),
        rudder_amplitude_deg=amplitude, check_angle_deg=amplitude, first_side=first_side,
        notes={
            "columns": "time[s] x0[m] y0[m] phi[deg] psi[deg] u[m/s] v[m/s] p[deg/s] r[deg/s] delta[deg] rev[rpm]",
            "time_base": f"rebuilt as row * {MARIN_DT_S} s (3-digit time column agrees within its rounding)",
            "positions": "integrated (trapezoid) from the earth-fixed u, v starting at the first x0, y0; max "
                         f"deviation from the 3-digit x0, y0 {float(deviation.max()):.1f} m",
            "velocity_frame": "u, v columns are earth-fixed (dx0/dt, dy0/dt), rotated into the body by psi",
            "rudder_sign": "file delta positive to port; written delta = -file delta (positive to starboard)",
            "rpm": "propeller rpm as given (full scale)",
            "model_scale": "full scale as published; Froude-scale by lambda = 45.7 for the L7 model",
            "course_minus_heading_median_deg": f"{course_deg:.2f}",
        },
    )
    if kind == "zigzag":
        return [whole]
    return _marin_turn(whole, amplitude, expected_side, pullout_expected=kind == "turning_pullout")


def _slice(m: Manoeuvre, start: int, stop: int, **changes: object) -> Manoeuvre:
    """Rows [start, stop) of a manoeuvre (its own time base kept: stamps continue the file's clock)."""
    arrays = {name: getattr(m, name)[start:stop].copy() for name in ("t_s", "x_n", "y_e", "psi", "u", "v", "r")}
    arrays["delta"] = None if m.delta is None else m.delta[start:stop].copy()
    arrays["rpm"] = None if m.rpm is None else m.rpm[start:stop].copy()
    return replace(m, **arrays, **changes)


def _marin_turn(m: Manoeuvre, amplitude: float, side: str, *, pullout_expected: bool) -> list[Manoeuvre]:
    """A turning (/ pull-out) record -> [turning circle] or [turning circle, pull-out], split at the last row the
    rudder holds the turn's angle before it returns (the pull-out's execute). DatasetError when a pull-out is
    announced but the rudder never returns, or does not return to midships."""
    sign = 1.0 if side == "starboard" else -1.0
    toward = sign * np.degrees(m.delta)  # (N,) deg, positive toward the turn's side
    held = np.flatnonzero(toward >= 0.5 * amplitude)
    execute = int(np.flatnonzero(np.abs(toward - toward[0]) > MARIN_EXECUTE_DEG)[0])
    hold_deg = float(np.median(toward[held]))
    back = np.flatnonzero(toward[held[0]:] < 0.5 * amplitude)
    turn_note = (f"rudder {hold_deg:.1f} deg to {side} from t = {m.t_s[execute]:.1f} s (execute: the rudder leaves the "
                 f"approach by {MARIN_EXECUTE_DEG:g} deg)")
    if len(back) == 0:
        if pullout_expected:
            raise DatasetError(f"{m.path}: title says 'Turning / Pull-out' but the rudder never returns from its "
                               f"{hold_deg:.1f} deg hold (truncated file?)")
        return [_slice(m, 0, len(m.t_s), name=f"marin_tc_{int(amplitude):02d}_{side[0]}", kind="turning_circle",
                       check_angle_deg=math.nan, notes={**m.notes, "turn": turn_note},
                       extra={"turning_circle": json.dumps({"rudder_deg": hold_deg, "side": side,
                                                            "execute_s": float(m.t_s[execute])})})]
    returning = held[0] + int(back[0])
    holding = np.flatnonzero(toward[:returning] >= hold_deg - MARIN_HOLD_TOLERANCE_DEG)
    split = int(holding[-1])  # the last row of the hold: the pull-out's execute
    if len(m.t_s) - split < MIN_ROWS or split < MIN_ROWS:
        raise DatasetError(f"{m.path}: the pull-out starts at row {split + MARIN_HEADER_LINES + 1} of {len(m.t_s)}: "
                           f"expected at least {MIN_ROWS} rows of turn and of pull-out")
    after = np.abs(toward[returning:])
    if np.median(after) > MARIN_MIDSHIPS_FRACTION * amplitude:
        raise DatasetError(f"{m.path}:{returning + MARIN_HEADER_LINES + 1}: after the pull-out execute the rudder "
                           f"stays at a median {np.median(after):.1f} deg; expected it back to midships (below "
                           f"{MARIN_MIDSHIPS_FRACTION * amplitude:.1f} deg)")
    name = f"marin_tc_{int(amplitude):02d}_{side[0]}"
    psi = np.unwrap(m.psi)
    heading_deg = float(np.degrees(psi[split] - psi[0]))
    split_note = (f"one file, two manoeuvres: the turning circle is rows 0-{split} (t <= {m.t_s[split]:.1f} s, "
                  f"{abs(heading_deg):.0f} deg of heading change), the pull-out rows {split}- (from the last row of "
                  "the rudder hold); both bags keep the file's clock")
    turn = _slice(m, 0, split + 1, name=name, kind="turning_circle", check_angle_deg=math.nan,
                  notes={**m.notes, "turn": turn_note, "split": split_note},
                  extra={"turning_circle": json.dumps({"rudder_deg": hold_deg, "side": side,
                                                       "execute_s": float(m.t_s[execute])})})
    pullout = _slice(m, split, len(m.t_s), name=f"{name}_pullout", kind="pullout", check_angle_deg=math.nan,
                     notes={**m.notes, "split": split_note,
                            "pullout": f"rudder from {hold_deg:.1f} deg to midships from t = {m.t_s[split]:.1f} s"},
                     extra={"pullout": json.dumps({"rudder_deg": hold_deg, "side": side,
                                                   "execute_s": float(m.t_s[split])})})
    return [turn, pullout]


FORMAT = Format(
    "marin", read_marin, lambda name: name.upper().startswith("MARIN_") and name.lower().endswith(".dat"),
    "MARIN_*.dat",
    "no explicit data licence; research use. Cite SIMMAN 2008 (Stern et al. 2011). Do not commit the raw "
    "files into a repository.",
    epoch_ns=1_199_145_600 * NS_PER_S,  # 2008-01-01 00:00 UTC (SIMMAN 2008): the files carry no date
    datum_deg=(51.9700, 5.6650),  # MARIN, Wageningen (nominal, NOT measured): lat/lon = datum + the tank track
)
