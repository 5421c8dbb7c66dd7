"""What every reader of replay/convert shares: the Manoeuvre record a reader returns (module docstring of
replay/convert: the conventions), the Format record of a public data format, and the numeric and parsing helpers
whose checks raise DatasetError naming file, line and column.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from usv_predictor.errors import DatasetError
from usv_predictor.frames import ned_to_body, wrap_angle
from usv_predictor.physics.manoeuvres import CONVERTED_KINDS

CONVERSION_VERSION = "2"  # 2: MARIN turning / pull-out files; custom_data manoeuvre_type
GRAVITY = 9.81  # (m/s^2), the value the simulator writes as accel_z = -g
KNOT = 1852.0 / 3600.0  # (m/s per knot)
MIN_ROWS = 20  # a manoeuvre shorter than this is a truncated file

MANOEUVRE_KINDS = CONVERTED_KINDS  # the manoeuvre_type of a converted record (physics/manoeuvres.MANOEUVRE_KINDS)
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
    only the fixes are written. epoch_ns: the stamp of t_s = 0 (None: its format's epoch_ns).
    """

    name: str  # bag name, e.g. hsva_z_10_05
    source: str  # the name of its format (convert/formats.FORMATS)
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
    epoch_ns: int | None = None  # stamp of t_s = 0 (ns since the Unix epoch); None: its format's epoch_ns
    extra: Mapping[str, str] = field(default_factory=dict)  # further custom_data keys of the source
    kind: str = "zigzag"  # one of MANOEUVRE_KINDS: what the record is (custom_data manoeuvre_type)

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0])

    @property
    def rate_hz(self) -> float:
        return float((len(self.t_s) - 1) / self.duration_s)


@dataclass(frozen=True)
class Format:
    """One public data format `replay convert` reads: one record each (convert/formats.FORMATS)."""

    name: str  # --format NAME, and the source of its manoeuvres (Manoeuvre.source)
    read: Callable[[Path], Sequence[Manoeuvre]]  # one file -> its manoeuvres (a MARIN turn file holds two)
    matches: Callable[[str], bool]  # the file name is one of this format's (format auto: detect_format)
    files: str  # how its files are named, for detect_format's refusal (e.g. "HSVA_*.dat")
    licence: str  # the data's licence and citation, written into every bag's custom_data
    epoch_ns: int | None = None  # nominal stamp of t_s = 0 (ns since the Unix epoch); None: the file's own
    datum_deg: tuple[float, float] | None = None  # nominal GNSS datum (lat, lon deg) of a track without fixes


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
