"""Frames, angles and the one place where marine (NED/FRD) meets ROS (ENU/FLU) conventions.

Inside usv_predictor (Fossen 2021, ch. 2):
    earth frame NED: x_n north, y_e east, z down; heading psi clockwise from north (rad);
    body frame FRD: x forward, y starboard, z down; nu = [u, v, r] (m/s, m/s, rad/s),
    eta = [x_n, y_e, psi] (m, m, rad).
ROS messages (REP-103/105): earth ENU (x east, y north, z up), body FLU (x forward, y left,
z up), yaw counter-clockwise from east. Only msg_adapters call the *_enu / *_flu helpers.
"""
from __future__ import annotations

import math
from typing import TypeVar

import numpy as np

ArrayOrFloat = TypeVar("ArrayOrFloat", float, np.ndarray)

# WGS-84 ellipsoid
WGS84_A = 6378137.0  # semi-major axis (m)
WGS84_F = 1.0 / 298.257223563  # flattening (-)
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)  # first eccentricity squared (-)


def wrap_angle(angle: ArrayOrFloat) -> ArrayOrFloat:
    """Wrap an angle (rad) to [-pi, pi). The one wrapping helper of the package."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def angle_difference_deg(a: float, b: float) -> float:
    """a - b wrapped to [-180, 180) deg: the one difference of two compass directions (or headings) in degrees."""
    return (a - b + 180.0) % 360.0 - 180.0


def compass_deg(north: float, east: float) -> float:
    """Compass direction (deg clockwise from north, [0, 360) up to rounding) a (north, east) vector points to."""
    return math.degrees(math.atan2(east, north)) % 360.0


def heading_to_enu_yaw(psi: ArrayOrFloat) -> ArrayOrFloat:
    """NED heading (clockwise from north) -> ENU yaw (counter-clockwise from east), rad."""
    return wrap_angle(math.pi / 2.0 - psi)


def enu_yaw_to_heading(yaw: ArrayOrFloat) -> ArrayOrFloat:
    """ENU yaw (counter-clockwise from east) -> NED heading (clockwise from north), rad."""
    return wrap_angle(math.pi / 2.0 - yaw)


def ned_to_enu(x_n: ArrayOrFloat, y_e: ArrayOrFloat) -> tuple[ArrayOrFloat, ArrayOrFloat]:
    """Horizontal position NED (north, east) -> ENU (east, north)."""
    return y_e, x_n


def enu_to_ned(x_east: ArrayOrFloat, y_north: ArrayOrFloat) -> tuple[ArrayOrFloat, ArrayOrFloat]:
    """Horizontal position ENU (east, north) -> NED (north, east)."""
    return y_north, x_east


def frd_to_flu(x: ArrayOrFloat, y: ArrayOrFloat, z: ArrayOrFloat):
    """Body vector FRD (marine) -> FLU (ROS). Involutive: also FLU -> FRD."""
    return x, -y, -z


flu_to_frd = frd_to_flu


def yaw_to_quaternion(yaw: ArrayOrFloat):
    """ENU yaw (rad) -> quaternion (x, y, z, w) of a level body, as geometry_msgs/Quaternion."""
    half = np.asarray(yaw) * 0.5
    return 0.0 * half, 0.0 * half, np.sin(half), np.cos(half)


def quaternion_to_yaw(x: ArrayOrFloat, y: ArrayOrFloat, z: ArrayOrFloat, w: ArrayOrFloat):
    """Quaternion (x, y, z, w) -> ENU yaw (rad), the z-y-x Euler yaw angle."""
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def body_to_ned(u: ArrayOrFloat, v: ArrayOrFloat, psi: ArrayOrFloat):
    """Body velocity (u fwd, v stbd) -> NED velocity (north, east) at heading psi (Fossen eq. 2.40)."""
    c, s = np.cos(psi), np.sin(psi)
    return u * c - v * s, u * s + v * c


def ned_to_body(v_north: ArrayOrFloat, v_east: ArrayOrFloat, psi: ArrayOrFloat):
    """NED velocity (north, east) -> body velocity (u fwd, v stbd) at heading psi."""
    c, s = np.cos(psi), np.sin(psi)
    return v_north * c + v_east * s, -v_north * s + v_east * c


def direction_to_unit_ned(direction: ArrayOrFloat):
    """Compass direction (rad, clockwise from north) -> unit vector (north, east)."""
    return np.cos(direction), np.sin(direction)


class LocalTangentPlane:
    """Flat-earth NED plane tangent to WGS-84 at a datum (Fossen 2021 sec. 2.4.3).

    Accurate to centimetres over the few kilometres of a manoeuvring trial.
    """

    def __init__(self, lat0_deg: float, lon0_deg: float) -> None:
        if not (-90.0 < lat0_deg < 90.0 and -180.0 <= lon0_deg <= 180.0):
            raise ValueError(f"datum ({lat0_deg}, {lon0_deg}) deg is not a valid latitude/longitude")
        self.lat0_deg = float(lat0_deg)
        self.lon0_deg = float(lon0_deg)
        lat0 = math.radians(lat0_deg)
        sin2 = math.sin(lat0) ** 2
        # Radii of curvature in the meridian and the prime vertical (m)
        self._r_north = WGS84_A * (1.0 - WGS84_E2) / (1.0 - WGS84_E2 * sin2) ** 1.5
        self._r_east = WGS84_A / math.sqrt(1.0 - WGS84_E2 * sin2) * math.cos(lat0)

    def to_ned(self, lat_deg: ArrayOrFloat, lon_deg: ArrayOrFloat):
        """Latitude/longitude (deg) -> (x_n, y_e) in metres from the datum."""
        x_n = np.radians(np.asarray(lat_deg) - self.lat0_deg) * self._r_north
        y_e = np.radians(np.asarray(lon_deg) - self.lon0_deg) * self._r_east
        return x_n, y_e

    def to_geodetic(self, x_n: ArrayOrFloat, y_e: ArrayOrFloat):
        """(x_n, y_e) in metres from the datum -> latitude/longitude (deg)."""
        lat = self.lat0_deg + np.degrees(np.asarray(x_n) / self._r_north)
        lon = self.lon0_deg + np.degrees(np.asarray(y_e) / self._r_east)
        return lat, lon
