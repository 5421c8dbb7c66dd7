"""Figures of an evaluation in the layout of seed 000 (Fig. 10-15), written atomically as PNG.

    track_figure            measured vs predicted track, rotated so x is along the measured drift (Fig. 11)
    rotated_position_figure along- and across-drift position vs time (Fig. 12)
    states_figure           u, v, r vs time (Fig. 10)
    open_loop_figure        open-loop position error vs prediction horizon
    turning_summary_figure  radius, drift direction and drift distance per test, measured vs predicted (Fig. 13-15)
    force_decomposition_figure  hull / rudder / propeller forces of an identification vs the measured total
                                (seed 001 Fig. 13)

Rotation: with the drift direction alpha (compass, toward) the map (east, north) is turned so the drift points
along +x: along = x_n cos(alpha) + y_e sin(alpha), across = x_n sin(alpha) - y_e cos(alpha) (to port of the
drift), a proper rotation, so the figure still reads like a map. Without a drift (no turning circle) tracks are
drawn east right, north up.

Matplotlib is used through Figure + the Agg canvas (no pyplot state, no display). Every file is saved to a
temporary name in the target directory and renamed, so a reader never sees half a PNG.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from usv_predictor.analysis.evaluation import X_N, Y_E, Prediction, R, U, V
from usv_predictor.atomic import atomic_open
from usv_predictor.errors import PlotError

if TYPE_CHECKING:
    from usv_predictor.fitting.identification import IdentificationResult

MEASURED = {"color": "black", "linewidth": 1.0, "label": "measured"}
PREDICTED = {"color": "tab:blue", "linewidth": 1.4, "label": "predicted"}
BAND = {"color": "tab:blue", "alpha": 0.2, "linewidth": 0.0}
DPI = 110


def new_figure(width_in: float, height_in: float) -> Figure:
    fig = Figure(figsize=(width_in, height_in), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Figure, path: Path) -> Path:
    """Write fig as PNG to path via a temporary file in the same directory and os.replace."""
    path = Path(path)
    with atomic_open(path, "wb", PlotError, "figure") as out:
        fig.savefig(out, format="png")
    return path


def rotate_to_drift(x_n: np.ndarray, y_e: np.ndarray, direction_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """(along drift, across drift to port) in m for a compass drift direction (deg, toward)."""
    a = math.radians(direction_deg)
    return x_n * math.cos(a) + y_e * math.sin(a), x_n * math.sin(a) - y_e * math.cos(a)


@dataclass(frozen=True)
class PlaneAxes:
    """How a track is drawn: the two coordinates and their axis labels."""

    direction_deg: float | None
    origin_n_m: float = 0.0  # positions are drawn from the start of the run, like seed 000 Fig. 11
    origin_e_m: float = 0.0

    def coordinates(self, series: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x_n, y_e = series[:, X_N] - self.origin_n_m, series[:, Y_E] - self.origin_e_m
        if self.direction_deg is None:
            return y_e, x_n
        return rotate_to_drift(x_n, y_e, self.direction_deg)

    @property
    def labels(self) -> tuple[str, str]:
        if self.direction_deg is None:
            return "east from the start (m)", "north from the start (m)"
        return (f"along drift, toward {self.direction_deg:.1f} deg (m)", "across drift, to port (m)")


def _axes_for(direction_deg: float | None, prediction: Prediction) -> PlaneAxes:
    start = prediction.measured[0]
    return PlaneAxes(direction_deg if direction_deg is not None and math.isfinite(direction_deg) else None,
                     float(start[X_N]), float(start[Y_E]))


def track_figure(prediction: Prediction, title: str, drift_direction_deg: float | None = None) -> Figure:
    """Seed 000 Fig. 11: the measured and predicted tracks, x along the measured drift."""
    plane = _axes_for(drift_direction_deg, prediction)
    fig = new_figure(6.4, 6.0)
    ax = fig.add_subplot()
    for series, style in ((prediction.measured, MEASURED), (prediction.predicted, PREDICTED)):
        x, y = plane.coordinates(series)
        ax.plot(x, y, **style)
    x0, y0 = plane.coordinates(prediction.measured[:1])
    ax.plot(x0, y0, "o", color="tab:green", markersize=6, label="start")
    x1, y1 = plane.coordinates(prediction.predicted[-1:])
    ax.plot(x1, y1, "s", color=PREDICTED["color"], markersize=5, label="predicted end")
    known = np.flatnonzero(np.isfinite(prediction.measured[:, X_N]))
    if len(known):
        xm, ym = plane.coordinates(prediction.measured[known[-1:]])
        ax.plot(xm, ym, "s", color="black", markersize=5, label="measured end")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(plane.labels[0])
    ax.set_ylabel(plane.labels[1])
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize="small")
    ax.set_title(f"{title}\ntrack, {prediction.reference} reference"
                 + ("" if plane.direction_deg is None else ", rotated to the measured drift"), fontsize="medium")
    return fig


def rotated_position_figure(prediction: Prediction, title: str, drift_direction_deg: float | None = None) -> Figure:
    """Seed 000 Fig. 12: along- and across-drift (or north and east) position against time."""
    plane = _axes_for(drift_direction_deg, prediction)
    fig = new_figure(7.5, 5.2)
    axes = fig.subplots(2, 1, sharex=True)
    measured = plane.coordinates(prediction.measured)
    predicted = plane.coordinates(prediction.predicted)
    labels = plane.labels if plane.direction_deg is not None else ("north from the start (m)",
                                                                   "east from the start (m)")
    if plane.direction_deg is None:  # east/north plane: show north first like x_n, y_e
        measured, predicted = measured[::-1], predicted[::-1]
    for k, ax in enumerate(axes):
        ax.plot(prediction.t_s, measured[k], **MEASURED)
        ax.plot(prediction.t_s, predicted[k], **PREDICTED)
        ax.set_ylabel(labels[k])
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc="best", fontsize="small")
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(f"{title}\nposition vs time, {prediction.reference} reference", fontsize="medium")
    return fig


def states_figure(prediction: Prediction, title: str) -> Figure:
    """Seed 000 Fig. 10: surge u, sway v (m/s) and yaw rate r (deg/s) against time, with the ensemble spread."""
    fig = new_figure(7.5, 7.0)
    axes = fig.subplots(3, 1, sharex=True)
    rows = ((U, 1.0, "u (m/s)"), (V, 1.0, "v (m/s)"), (R, math.degrees(1.0), "r (deg/s)"))
    t = prediction.t_s
    for ax, (col, scale, label) in zip(axes, rows):
        ax.plot(t, scale * prediction.measured[:, col], **MEASURED)
        ax.plot(t, scale * prediction.predicted[:, col], **PREDICTED)
        spread = scale * prediction.predicted_std[:, col]
        if np.any(spread > 0.0):
            mean = scale * prediction.predicted[:, col]
            ax.fill_between(t, mean - 2 * spread, mean + 2 * spread, label="ensemble +-2 std", **BAND)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc="best", fontsize="small")
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(f"{title}\nmotion states vs time, closed loop", fontsize="medium")
    return fig


@dataclass(frozen=True)
class OpenLoopCurve:
    label: str
    step_s: float
    mean_error_by_step_m: Sequence[float]
    horizons: Sequence[tuple[float, float]]  # (horizon s, mean error m) marked on the curve


def open_loop_figure(curves: Sequence[OpenLoopCurve], title: str) -> Figure:
    """Mean open-loop position error against the prediction horizon, one curve per recording."""
    fig = new_figure(7.5, 4.8)
    ax = fig.add_subplot()
    colours = [f"C{k % 10}" for k in range(len(curves))]
    for curve, colour in zip(curves, colours):
        errors = np.asarray(curve.mean_error_by_step_m, dtype=float)
        horizon = curve.step_s * np.arange(1, len(errors) + 1)
        ax.plot(horizon, errors, color=colour, linewidth=1.2, label=curve.label)
        marks = [(h, e) for h, e in curve.horizons if e is not None and math.isfinite(e)]
        if marks:
            ax.plot(*zip(*marks), "o", color=colour, markersize=4)
    ax.set_xlabel("prediction horizon (s)")
    ax.set_ylabel("mean position error (m)")
    ax.set_xlim(left=0.0)
    ax.set_ylim(bottom=0.0)
    ax.grid(True, alpha=0.3)
    if curves:
        ax.legend(loc="upper left", fontsize="x-small")
    ax.set_title(f"{title}\nopen-loop position error vs horizon (mean over start points)", fontsize="medium")
    return fig


@dataclass(frozen=True)
class TurningRow:
    """One test of the turning summary: measured and predicted values (None where undefined)."""

    label: str
    radius_m: tuple[float | None, float | None]
    drift_direction_deg: tuple[float | None, float | None]
    drift_distance_m: tuple[float | None, float | None]


def turning_summary_figure(rows: Sequence[TurningRow], title: str) -> Figure:
    """Seed 000 Fig. 13-15: turning radius (eq. 29), drift direction and drift distance per test."""
    fig = new_figure(8.0, 8.0)
    axes = fig.subplots(3, 1, sharex=True)
    x = np.arange(len(rows))
    width = 0.38
    panels = (("radius_m", "turning radius eq. 29 (m)"), ("drift_direction_deg", "drift direction (deg, toward)"),
              ("drift_distance_m", "drift distance eq. 27 (m)"))
    for ax, (field_name, label) in zip(axes, panels):
        pairs = [getattr(r, field_name) for r in rows]
        for k, (name, style) in enumerate((("measured", MEASURED), ("predicted", PREDICTED))):
            values = [np.nan if p[k] is None else p[k] for p in pairs]
            ax.bar(x + (k - 0.5) * width, values, width, color="0.35" if k == 0 else style["color"], label=name)
        ax.set_ylabel(label)
        ax.grid(True, axis="y", alpha=0.3)
    axes[0].legend(loc="best", fontsize="small")
    axes[-1].set_xticks(x, [r.label for r in rows], fontsize="small")
    fig.suptitle(f"{title}\nturning tests, measured vs predicted", fontsize="medium")
    return fig



def force_decomposition_figure(result: IdentificationResult, k: int) -> Figure:
    """Seed 001 Fig. 13: hull / rudder / propeller decomposition and measured vs identified total over time,
    for manoeuvre k of an identification (X, Y in N, N in N m; the grey band: the part left out of the fit)."""
    from usv_predictor.fitting.hull_models import hull_forces

    d = result.data[k]
    values = result.fit.values()
    hull = hull_forces(result.vessel, values, d.nu, result.fit.u0)
    hull_v = hull_forces(result.vessel, values, d.nu, result.fit.u0,
                         names=[n for n in values if "v" in n.split("_", 1)[-1] and "r" not in n.split("_", 1)[-1]])
    hull_r = hull_forces(result.vessel, values, d.nu, result.fit.u0,
                         names=[n for n in values if "r" in n.split("_", 1)[-1] and "v" not in n.split("_", 1)[-1]])
    model_total = hull + d.rudder + d.propeller
    fig = Figure(figsize=(9, 8), dpi=DPI)
    FigureCanvasAgg(fig)
    axes = fig.subplots(3, 1, sharex=True)
    labels = ("X (N)", "Y (N)", "N (N m)")
    for i, ax in enumerate(axes):
        ax.plot(d.t_s, d.total[:, i], color="k", lw=1.5, label="measured (inverse dynamics)")
        ax.plot(d.t_s, model_total[:, i], color="tab:red", lw=1.0, ls="--", label="identified total")
        ax.plot(d.t_s, hull[:, i], color="tab:blue", lw=0.9, label="hull")
        if i > 0:
            ax.plot(d.t_s, hull_v[:, i], color="tab:cyan", lw=0.7, label="hull(v)")
            ax.plot(d.t_s, hull_r[:, i], color="tab:purple", lw=0.7, label="hull(r)")
        ax.plot(d.t_s, d.rudder[:, i], color="tab:green", lw=0.9, label="rudder (prior)")
        if i == 0:
            ax.plot(d.t_s, d.propeller[:, i], color="tab:orange", lw=0.9, label="propeller (prior)")
        ax.set_ylabel(labels[i])
        ax.grid(alpha=0.3)
        ax.axvspan(d.t_s[0], d.t_s[np.argmax(d.keep)] if d.keep.any() else d.t_s[0], color="0.9")
    axes[0].legend(fontsize=7, ncol=3)
    axes[1].legend(fontsize=7, ncol=3)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(f"{d.name}: force decomposition ({result.structure}, prior {result.fit.prior_policy})")
    fig.tight_layout()
    return fig
