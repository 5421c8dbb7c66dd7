"""Public measured manoeuvres -> plain numbers in the marine convention -> rosbag2 with the default topics.

Readers return one `Manoeuvre` per file: SI units, NED earth frame, body FRD, heading psi clockwise
from north (rad, wrapped), eta = [x_n, y_e, psi], nu = [u, v, r], rudder delta positive to starboard
(r > 0), propeller speed in rpm. Everything here is pure except `write_manoeuvre_bag` (one bagio.write_bag)
and `convert` (what `replay convert` does: every file read first, then one bag each).

Sources (see docs/data.md for the evidence behind each convention; every check below raises
DatasetError naming file, line and column):
  hsva    KVLCC2 free-running zig-zags, HSVA for SIMMAN 2008, MODEL scale (1:45.714, L_pp 7 m, 0.05 s).
          The data contradict SOURCE.txt's column header in two places, both detected from the data:
          the 7th column (labelled p) is the yaw rate - it equals d(psi)/dt - and the 8th (labelled r)
          is not; u, v are earth-fixed dx0/dt, dy0/dt. The reader picks the column that IS d(psi)/dt and
          the velocity frame the positions prove, and refuses a file where neither fits.
  marin   KVLCC2 free-running tests, MARIN for SIMMAN 2008, FULL scale (L_pp 320 m): every manoeuvre type of
          the format, named by the title line ("Zig-zag manoeuvring for KVLCC2 : 10 / -10", "Turning / Pull-out
          manoeuvring for KVLCC2 : 35 (deg)", "Turning manoeuvring ..."). A turning / pull-out file is split at
          the instant the rudder leaves its hold into two manoeuvres: the turning circle (approach + steady
          rudder) and the pull-out (rudder back to midships). 3 significant digits: the time base is rebuilt as
          row * 0.13535 s (the time column must agree within its rounding); positions (10 m steps at 4 km) are
          rebuilt by integrating the earth-fixed u, v from the first position.
  fuzhou  3.6 m rudder-steered USV, 30 deg zig-zag at sea, 0.5 s interpolated. The `speed` column is in
          KNOTS, not m/s as SOURCE.txt says: the GNSS track moves 0.51 m per second per unit of speed.
          The reader detects the unit from the track (knots or m/s, else error). u, v: over-ground
          velocity of the GNSS track (centred difference over 2 s) rotated into the body; r: centred
          difference of the unwrapped heading over 1 s. No propeller data: no engine_rpm topic.
  dalian  a small twin-thruster USV (differential thrust, PWM commands), closed-loop path following at sea,
          .xlsx (read with openpyxl, imported only here). The x, y columns are NOT metres (11.2 % inflated) and t is
          NOT time (a nominal 0.1 s per row): time from DateTime, position from Longitude/Latitude; rows without a
          new GNSS fix (about every second row) carry no position or heading measurement; u, v, r are derived by
          the EKF/RTS smoother (data/smoother.py) from the fixes and the heading (velocity over ground); PWM_L is
          the port thruster (checked on every file: more PWM_L turns to starboard), c = (PWM - 1500) / 500.
"""
from __future__ import annotations

import csv
import hashlib
import json
import math
import re
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from usv_predictor.errors import DatasetError
from usv_predictor.frames import LocalTangentPlane, ned_to_body, wrap_angle
from usv_predictor.records import NS_PER_S, Signal

CONVERSION_VERSION = "2"  # 2: MARIN turning / pull-out files; custom_data manoeuvre_type
GRAVITY = 9.81  # (m/s^2), the value the simulator writes as accel_z = -g
KNOT = 1852.0 / 3600.0  # (m/s per knot)
MIN_ROWS = 20  # a manoeuvre shorter than this is a truncated file

# Nominal epochs (UTC) - the files carry no date; only the time base within a file is measured.
EPOCH_NS = {
    "hsva": 1_136_073_600 * NS_PER_S,  # 2006-01-01 00:00 UTC (year of the HSVA report)
    "marin": 1_199_145_600 * NS_PER_S,  # 2008-01-01 00:00 UTC (SIMMAN 2008)
    "fuzhou": 1_640_995_200 * NS_PER_S,  # 2022-01-01 00:00 UTC (year of the publication)
}  # dalian: the file's DateTime (Manoeuvre.epoch_ns)
# Arbitrary GNSS datums of the tank data (nominal, NOT measured): lat/lon = datum + the tank track.
DATUM_DEG = {
    "hsva": (53.5680, 10.0110),  # HSVA, Hamburg (nominal)
    "marin": (51.9700, 5.6650),  # MARIN, Wageningen (nominal)
}
LICENCE = {
    "hsva": "no explicit data licence; research use. Cite SIMMAN 2008 (Stern et al. 2011) and the HSVA report "
            "(A. Cura Hochbaum, 2006). Do not commit the raw files into a repository.",
    "marin": "no explicit data licence; research use. Cite SIMMAN 2008 (Stern et al. 2011). Do not commit the raw "
             "files into a repository.",
    "fuzhou": "none stated; research use. Cite Alexandersson, Zhang, Mao, Ringsberg (2022), Ships and Offshore "
              "Structures, doi:10.1080/17445302.2022.2067409. Do not commit the raw file into a repository.",
    "dalian": "MIT (github.com/2345vor/USV-ASW-NMPC, 'MI Project Contributors'; the same files as 2345vor/MI "
              "datas/ at commit 54d75c029cc43fe2f4443e9449e8ae1cb0a026c9). Do not commit the raw files or bags made "
              "from them into this repository.",
}
FORMATS = ("hsva", "marin", "fuzhou", "dalian")
MANOEUVRE_KINDS = ("zigzag", "turning_circle", "pullout", "path_following")
UNSUPPORTED_FORMATS: dict[str, str] = {}

HSVA_LAMBDA = 45.714  # model scale 1:45.714 (SOURCE.txt)
HSVA_DT_S = 0.05  # (s)
MARIN_DT_S = 0.13535  # (s), full-scale sample interval (SOURCE.txt)
KVLCC2_LPP_FULL_M = 320.0  # (m)
KVLCC2_LPP_MODEL_M = 7.0  # (m)


@dataclass(frozen=True)
class ScaleInfo:
    """Scale of the numbers in a Manoeuvre (they are never rescaled by the reader)."""

    scale: str  # "model" or "full"
    scale_factor: float  # lambda = full-scale length / this length (1 at full scale) (-)
    L_pp_m: float  # length between perpendiculars at this scale (m)
    full_scale_L_pp_m: float  # (m)


@dataclass(frozen=True, eq=False)
class Manoeuvre:
    """One measured manoeuvre, marine convention, SI. Arrays are (N,) float64 on one time base.

    rpm is the PROPELLER speed (rpm), None when not measured. lat_deg/lon_deg are the measured fixes
    when the source has them, else None (then the bag's fixes are x_n, y_e about a nominal datum).
    A twin-thruster record has delta None and `thrusters` = (port, starboard) normalised commands in [-1, 1];
    `fix` marks the rows that carry a GNSS fix (None: every row); x_n, y_e, lat, lon are NaN on the others and
    only the fixes are written. epoch_ns: the stamp of t_s = 0 (None: EPOCH_NS[source]).
    """

    name: str  # bag name, e.g. hsva_z_10_05
    source: str  # one of FORMATS
    path: Path
    t_s: np.ndarray  # (N,) s from the file's first row, strictly increasing
    x_n: np.ndarray  # (N,) m
    y_e: np.ndarray  # (N,) m
    psi: np.ndarray  # (N,) rad, wrapped to (-pi, pi]
    u: np.ndarray  # (N,) m/s, body forward
    v: np.ndarray  # (N,) m/s, body starboard
    r: np.ndarray  # (N,) rad/s, positive turning to starboard
    delta: np.ndarray | None  # (N,) rad, positive turns the vessel to starboard; None without a rudder
    rpm: np.ndarray | None  # (N,) propeller rpm, or None
    scale: ScaleInfo
    rudder_amplitude_deg: float  # nominal rudder angle of the zig-zag or turn (from the file name/header) (deg)
    check_angle_deg: float  # nominal heading check angle of a zig-zag (deg); NaN for a turn or pull-out
    first_side: str  # "starboard" or "port": side of the first rudder execute
    lat_deg: np.ndarray | None = None
    lon_deg: np.ndarray | None = None
    notes: Mapping[str, str] = field(default_factory=dict)  # conventions and conversions, for custom_data
    thrusters: tuple[np.ndarray, np.ndarray] | None = None  # (N,) port and starboard commands (-), twin thrusters
    fix: np.ndarray | None = None  # (N,) bool: rows with a new GNSS fix and heading (None: every row)
    epoch_ns: int | None = None  # stamp of t_s = 0 (ns since the Unix epoch); None: EPOCH_NS[source]
    extra: Mapping[str, str] = field(default_factory=dict)  # further custom_data keys of the source
    kind: str = "zigzag"  # one of MANOEUVRE_KINDS: what the record is (custom_data manoeuvre_type)

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0])

    @property
    def rate_hz(self) -> float:
        return float((len(self.t_s) - 1) / self.duration_s)


# ----------------------------------------------------------------------------- numeric helpers


def centred_derivative(t_s: np.ndarray, x: np.ndarray, half_width: int) -> np.ndarray:
    """dx/dt by centred differences over +-half_width samples (one-sided, shorter, at the ends).

    A difference over 2k samples is a smoothing differentiator: it removes the rounding/interpolation
    noise that a 1-sample difference would amplify, at the cost of a 2k-sample low-pass.
    """
    n = len(x)
    idx = np.arange(n)
    hi = np.minimum(idx + half_width, n - 1)
    lo = np.maximum(idx - half_width, 0)
    return (x[hi] - x[lo]) / (t_s[hi] - t_s[lo])


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def _sig_half_unit(x: np.ndarray, digits: int = 3) -> np.ndarray:
    """Half a unit of the last significant digit of each value (the rounding error of a 3-digit table)."""
    ax = np.abs(x)
    exponent = np.floor(np.log10(np.where(ax > 0.0, ax, 1.0)))
    return 0.5 * 10.0 ** (exponent - (digits - 1))


def _first_side(delta: np.ndarray, threshold: float) -> str:
    """Side of the first rudder execute: sign of the first |delta - delta[0]| > threshold."""
    moved = np.flatnonzero(np.abs(delta - delta[0]) > threshold)
    if len(moved) == 0:
        return "none"
    return "starboard" if delta[moved[0]] - delta[0] > 0 else "port"


# ----------------------------------------------------------------------------- parsing helpers


def _read_text(path: Path, encoding: str) -> str:
    try:
        return Path(path).read_text(encoding=encoding)
    except OSError as err:
        raise DatasetError(f"{path}: cannot read ({err.strerror or err})") from err
    except UnicodeDecodeError as err:
        raise DatasetError(f"{path}: not {encoding} text ({err.reason} at byte {err.start})") from err


def _parse_table(path: Path, lines: Sequence[str], first_line: int, columns: Sequence[str],
                 split: Callable[[str], list[str]], allow_trailing_blank: bool) -> np.ndarray:
    """Rows of numbers -> (N, len(columns)); errors name file, 1-based line and column."""
    rows: list[list[float]] = []
    blank_from: int | None = None
    for offset, line in enumerate(lines):
        number = first_line + offset
        cells = split(line)
        if not any(c.strip() for c in cells):
            if blank_from is None:
                blank_from = number
            continue
        if blank_from is not None:
            raise DatasetError(f"{path}:{blank_from}: empty row inside the data (data continue on line {number})")
        if len(cells) != len(columns):
            raise DatasetError(f"{path}:{number}: expected {len(columns)} columns ({' '.join(columns)}), "
                               f"found {len(cells)}")
        row = []
        for name, cell in zip(columns, cells):
            try:
                value = float(cell)
            except ValueError:
                raise DatasetError(f"{path}:{number}: column {name!r}: {cell.strip()!r} is not a number") from None
            if not math.isfinite(value):
                raise DatasetError(f"{path}:{number}: column {name!r}: {cell.strip()!r} is not finite")
            row.append(value)
        rows.append(row)
    if blank_from is not None and not allow_trailing_blank:
        raise DatasetError(f"{path}:{blank_from}: unexpected empty row")
    if len(rows) < MIN_ROWS:
        raise DatasetError(f"{path}: only {len(rows)} data rows, expected at least {MIN_ROWS} (truncated file?)")
    return np.asarray(rows, dtype=np.float64)


def _check_time(path: Path, t_s: np.ndarray, first_line: int, expected_dt: float | None, column: str) -> None:
    """Strictly increasing time; a uniform step `expected_dt` (1 %) when given. Duplicates are refused."""
    steps = np.diff(t_s)
    bad = np.flatnonzero(steps <= 0.0)
    if len(bad):
        k = int(bad[0]) + 1
        what = "repeats" if steps[bad[0]] == 0.0 else "goes back"
        raise DatasetError(f"{path}:{first_line + k}: column {column!r}: time {t_s[k]:g} s {what} "
                           f"(previous row {t_s[k - 1]:g} s); expected strictly increasing time")
    if expected_dt is not None:
        off = np.flatnonzero(np.abs(steps - expected_dt) > 0.01 * expected_dt)
        if len(off):
            k = int(off[0]) + 1
            raise DatasetError(f"{path}:{first_line + k}: column {column!r}: step {steps[off[0]]:g} s, "
                               f"expected a uniform {expected_dt:g} s")


def _check_range(path: Path, column: str, values: np.ndarray, low: float, high: float, expected: str) -> None:
    """The median of a column must be in [low, high] - catches wrong units and wrong columns."""
    median = float(np.median(values))
    if not low <= median <= high:
        raise DatasetError(f"{path}: column {column!r}: median {median:g} is outside [{low:g}, {high:g}]; "
                           f"expected {expected} (see SOURCE.txt)")


def _yaw_rate_column(path: Path, t_s: np.ndarray, psi_deg: np.ndarray, candidates: Mapping[str, np.ndarray],
                     half_width: int) -> str:
    """The candidate column (deg/s) that is d(psi)/dt; error if none is within 30 % rms."""
    dpsi = centred_derivative(t_s, np.unwrap(psi_deg, period=360.0), half_width)
    scale = max(_rms(dpsi), 1e-6)
    errors = {name: _rms(centred_derivative(t_s, np.cumsum(np.r_[0.0, 0.5 * (c[1:] + c[:-1]) * np.diff(t_s)]),
                                            half_width) - dpsi) / scale for name, c in candidates.items()}
    best = min(errors, key=errors.__getitem__)
    if errors[best] > 0.3:
        described = ", ".join(f"{n}: {e:.0%}" for n, e in errors.items())
        raise DatasetError(f"{path}: no column is the yaw rate d(psi)/dt in deg/s (relative rms error {described}); "
                           f"expected one within 30 %")
    return best


def _velocity_frame(path: Path, t_s: np.ndarray, x: np.ndarray, y: np.ndarray, psi: np.ndarray,
                    c1: np.ndarray, c2: np.ndarray, half_width: int, tolerance_mps: float) -> str:
    """'earth' if (c1, c2) = (dx/dt, dy/dt), 'body' if they are (u, v) of FRD; error if neither fits."""
    vx, vy = centred_derivative(t_s, x, half_width), centred_derivative(t_s, y, half_width)
    ub, vb = ned_to_body(vx, vy, psi)
    misfit = {"earth": max(_rms(vx - c1), _rms(vy - c2)), "body": max(_rms(ub - c1), _rms(vb - c2))}
    best = min(misfit, key=misfit.__getitem__)
    if misfit[best] > tolerance_mps:
        raise DatasetError(f"{path}: the velocity columns are neither the time derivative of the positions "
                           f"(rms misfit {misfit['earth']:.3g} m/s) nor their body-axis components "
                           f"({misfit['body']:.3g} m/s); expected one within {tolerance_mps:g} m/s "
                           f"(positions in m, velocities in m/s, heading positive to starboard)")
    return best


def _check_track_follows_heading(path: Path, t_s: np.ndarray, x: np.ndarray, y: np.ndarray, psi: np.ndarray,
                                 half_width: int, max_deg: float) -> float:
    """Course over ground vs heading: a mirrored axis or a port-positive heading fails this."""
    vx, vy = centred_derivative(t_s, x, half_width), centred_derivative(t_s, y, half_width)
    moving = np.hypot(vx, vy) > 0.2 * np.median(np.hypot(vx, vy))
    course = np.unwrap(np.arctan2(vy, vx)[moving])
    difference = np.degrees(np.abs(wrap_angle(course - psi[moving])))
    median = float(np.median(difference))
    expected = "(x north, y east, psi positive to starboard, y positive to starboard)"
    if median > max_deg:
        raise DatasetError(f"{path}: the track runs {median:.0f} deg off the heading in median; "
                           f"expected < {max_deg:g} deg {expected}")
    # A mirrored axis turns the course the other way than the heading: small offsets hide it, this does not.
    if np.std(psi[moving]) > math.radians(2.0) and np.corrcoef(course, psi[moving])[0, 1] < 0.5:
        raise DatasetError(f"{path}: the course over ground turns against the heading (correlation "
                           f"{np.corrcoef(course, psi[moving])[0, 1]:.2f}); expected it to follow {expected}")
    return median


def _file_digest(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


# ----------------------------------------------------------------------------- HSVA

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


# ----------------------------------------------------------------------------- MARIN

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


# ----------------------------------------------------------------------------- Fuzhou USV

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


# ----------------------------------------------------------------------------- Dalian twin-thruster USV

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


# ----------------------------------------------------------------------------- discovery

READERS: dict[str, Callable[[Path], Sequence[Manoeuvre]]] = {
    "hsva": lambda p: [read_hsva(p)], "marin": read_marin, "fuzhou": lambda p: [read_fuzhou(p)],
    "dalian": lambda p: [read_dalian(p)]}  # format -> the manoeuvres of one file (a MARIN turn file holds two)


def detect_format(path: Path) -> str:
    """hsva | marin | fuzhou | dalian from the file name (and suffix); DatasetError when unknown."""
    name = Path(path).name
    if name.upper().startswith("HSVA_") and name.lower().endswith(".dat"):
        return "hsva"
    if name.upper().startswith("MARIN_") and name.lower().endswith(".dat"):
        return "marin"
    if name.lower().endswith(".csv") and "zigzag" in name.lower():
        return "fuzhou"
    if name.lower().endswith(".xlsx"):
        return "dalian"
    raise DatasetError(f"{path}: unknown data format (expected HSVA_*.dat, MARIN_*.dat, a zigzag*.csv of the "
                       f"Fuzhou USV, a .xlsx of the Dalian USV; give --format)")


def find_sources(inputs: Sequence[Path], fmt: str = "auto") -> list[tuple[Path, str]]:
    """(file, format) for every manoeuvre file among `inputs` (files or directories, sorted).

    Directories are searched (not recursively) for *.dat, *.csv and *.xlsx; other files (SOURCE.txt,
    ship_data.yml, open_water_characteristics.csv) are skipped.
    """
    found: list[tuple[Path, str]] = []
    for item in inputs:
        item = Path(item)
        if item.is_dir():
            candidates = sorted(p for p in item.iterdir() if p.suffix.lower() in (".dat", ".csv", ".xlsx")
                                and p.name != "open_water_characteristics.csv")
            if not candidates:
                raise DatasetError(f"{item}: no .dat, .csv or .xlsx manoeuvre files in this directory")
            for p in candidates:
                found.append((p, detect_format(p) if fmt == "auto" else fmt))
        elif item.is_file():
            found.append((item, detect_format(item) if fmt == "auto" else fmt))
        else:
            raise DatasetError(f"{item}: no such file or directory")
    for p, f in found:
        if f in UNSUPPORTED_FORMATS:
            raise DatasetError(f"{p}: {UNSUPPORTED_FORMATS[f]}")
        if f not in READERS:
            raise DatasetError(f"{p}: unknown format {f!r}; formats: {', '.join(FORMATS)}")
    return found


def read_manoeuvres(path: Path, fmt: str) -> list[Manoeuvre]:
    """Every manoeuvre of one file (one, or a MARIN turning circle and its pull-out)."""
    return list(READERS[fmt](Path(path)))


# ----------------------------------------------------------------------------- conversion


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
