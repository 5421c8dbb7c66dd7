"""Planned control sequences: one plan the node predicts under, or a batch of candidate plans to compare.

A planner (MPC, sampling, collision avoidance) asks "where will I be if I command this?". Both inputs are
trajectory_msgs/JointTrajectory (decoded by msg_adapters.cdr.decode_joint_trajectory), one joint per control
of the vessel's actuator layout (physics/actuators.py), positions in the control's unit (rad, rpm):

    header.stamp     the plan's time zero t0, and its tag: every prediction made under the plan carries it
    joint_names      plan: the layout's control names in any order, e.g. ["delta", "rpm"]
                     candidates: "<candidate>/<control>" for every candidate and every control, e.g.
                     ["a/delta", "a/rpm", "b/delta", "b/rpm"]: N = 1 .. MAX_CANDIDATES candidates
    points[j]        positions (one per joint), time_from_start (>= 0, strictly increasing), shared by all
                     candidates; velocities, accelerations and effort are ignored

The control at time t (the model's step k is t_c + k dt, the state time plus k steps) is the linear
interpolation between the points around t; before t0 + time_from_start[0] it is the measured command (the
one the node would hold), after the last point the last point's value is held.

A plan is refused (InputRejected, counted by kind and reported on /diagnostics) when its stamp is 0 (no time
zero, no tag), older than max_age_s or more than max_future_s ahead of the clock, its joint names are not the
layout's controls (per candidate), it has no points, its times are negative or not increasing, or a position
is not finite or outside the control's plausible range (a unit mistake, as for the measured inputs).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from msg_adapters.cdr import JOINT_TRAJECTORY_TYPE, JointTrajectoryData
from usv_predictor.errors import InputRejected
from usv_predictor.physics.actuators import ActuatorLayout
from usv_predictor.records import NS_PER_S

PLAN_TYPE = JOINT_TRAJECTORY_TYPE  # of both plan topics
MAX_CANDIDATES = 64  # candidate plans per batch: one TorchScript call of batch size N
CANDIDATE_SEPARATOR = "/"  # joint name = "<candidate>/<control>"


@dataclass(frozen=True)
class PlanLimits:
    max_age_s: float  # a plan stamped longer ago than this is refused, and no longer followed (s)
    max_future_s: float  # a plan stamped further ahead of the clock is refused (s)


@dataclass(frozen=True)
class Plan:
    """N control sequences on one time grid, in the layout's control columns and units."""

    stamp_ns: int  # header.stamp: t0 and the tag of the predictions made under it
    names: tuple[str, ...]  # (N,) candidate names; ("",) for a single plan
    t_ns: np.ndarray  # (P,) int64 absolute times of the points: stamp + time_from_start
    controls: np.ndarray  # (N, P, C) float64

    def age_s(self, now_ns: int) -> float:
        return (now_ns - self.stamp_ns) / NS_PER_S

    def schedule(self, grid_ns: np.ndarray, held: np.ndarray) -> np.ndarray:
        """(N, H, C) controls at the times grid_ns (H,): interpolated, `held` (C,) before the plan starts."""
        grid_ns = np.asarray(grid_ns, dtype=np.int64)
        t = self.t_ns
        before = np.searchsorted(t, grid_ns, side="right") - 1  # (H,) the point at or before each time
        j0 = np.clip(before, 0, len(t) - 1)
        j1 = np.minimum(j0 + 1, len(t) - 1)
        span = (t[j1] - t[j0]).astype(np.float64)
        weight = np.divide((grid_ns - t[j0]).astype(np.float64), span, out=np.zeros(len(grid_ns)), where=span > 0)
        weight = np.clip(weight, 0.0, 1.0)[None, :, None]  # (1, H, 1)
        values = self.controls[:, j0] * (1.0 - weight) + self.controls[:, j1] * weight  # (N, H, C)
        values[:, before < 0] = np.asarray(held, dtype=np.float64)
        return values


def parse_plan(data: JointTrajectoryData, layout: ActuatorLayout, now_ns: int, limits: PlanLimits,
               candidates: bool = False) -> Plan:
    """A decoded JointTrajectory -> Plan (one plan, or candidates), or InputRejected saying why not."""
    if data.stamp_ns == 0:
        raise InputRejected("stamp", "header.stamp is 0: a plan needs its time zero (and the tag of its predictions)")
    ahead = (data.stamp_ns - now_ns) / NS_PER_S
    if ahead > limits.max_future_s:
        raise InputRejected("future", f"stamp {ahead:.3f} s ahead of the clock (limit {limits.max_future_s:g} s)")
    if -ahead > limits.max_age_s:
        raise InputRejected("stale", f"stamp {-ahead:.3f} s old (limit plan_max_age_s {limits.max_age_s:g} s)")
    names, columns = (_candidate_columns if candidates else _plan_columns)(data.joint_names, layout)
    if len(data.time_from_start_ns) == 0:
        raise InputRejected("empty", "no points")
    times = data.time_from_start_ns
    if times[0] < 0 or np.any(np.diff(times) <= 0):
        raise InputRejected("time", "time_from_start must be >= 0 and strictly increasing over the points")
    controls = data.positions[:, columns].reshape(len(times), len(names), len(layout.controls))  # (P, N, C)
    controls = controls.transpose(1, 0, 2)  # (N, P, C)
    _check_controls(controls, names, layout)
    return Plan(int(data.stamp_ns), names, int(data.stamp_ns) + times, np.ascontiguousarray(controls))


def _plan_columns(joints: Sequence[str], layout: ActuatorLayout) -> tuple[tuple[str, ...], np.ndarray]:
    controls = layout.control_names
    if sorted(joints) != sorted(controls):
        raise InputRejected("joints", f"joint_names {list(joints)}: expected the controls of the actuator layout "
                                      f"{layout.name}, {list(controls)} (any order, each once)")
    return ("",), np.array([list(joints).index(name) for name in controls])


def _candidate_columns(joints: Sequence[str], layout: ActuatorLayout) -> tuple[tuple[str, ...], np.ndarray]:
    controls = layout.control_names
    expected = f"'<candidate>{CANDIDATE_SEPARATOR}<control>' for each candidate and each of {list(controls)}"
    column: dict[tuple[str, str], int] = {}
    names: dict[str, None] = {}  # candidates in order of first appearance
    for index, joint in enumerate(joints):
        candidate, separator, control = joint.rpartition(CANDIDATE_SEPARATOR)
        if not separator or not candidate or control not in controls or (candidate, control) in column:
            raise InputRejected("joints", f"joint name {joint!r}: expected {expected}")
        column[(candidate, control)] = index
        names.setdefault(candidate)
    if not names:
        raise InputRejected("joints", f"no joint names: expected {expected}")
    if len(names) > MAX_CANDIDATES:
        raise InputRejected("too_many", f"{len(names)} candidates, at most {MAX_CANDIDATES}")
    missing = [f"{n}{CANDIDATE_SEPARATOR}{c}" for n in names for c in controls if (n, c) not in column]
    if missing:
        raise InputRejected("joints", f"joints {missing[:4]} missing: expected {expected}")
    return tuple(names), np.array([column[(n, c)] for n in names for c in controls])


def _check_controls(controls: np.ndarray, names: Sequence[str], layout: ActuatorLayout) -> None:
    """Finite and plausible (Control.plausible): a plan in degrees for a rad control is refused."""
    def joint(i: int, control: str) -> str:
        return f"{names[i]}{CANDIDATE_SEPARATOR}{control}" if names[i] else control

    for c, control in enumerate(layout.controls):
        column = controls[..., c]  # (N, P)
        bad = ~np.isfinite(column)
        if bad.any():
            i, j = np.argwhere(bad)[0]
            raise InputRejected("non_finite", f"{joint(i, control.name)} is {column[i, j]} at point {j}")
        low, high = control.plausible
        outside = (column < low) | (column > high)
        if outside.any():
            i, j = np.argwhere(outside)[0]
            raise InputRejected("range", f"{joint(i, control.name)} = {column[i, j]:g} {control.unit} at point {j} "
                                         f"outside the plausible [{low:g}, {high:g}]: wrong units?")


def describe_stamp(stamp_ns: int) -> str:
    """A plan's stamp as sec.nanosec, how planners print builtin_interfaces/Time."""
    sec, nanosec = divmod(int(stamp_ns), NS_PER_S)
    return f"{sec}.{nanosec:09d}"

