"""The online estimate of the sea in the node (pure: no rclpy; node.py calls it each cycle).

The estimator is fitting/online.py's EKF, built for the model as `replay evaluate --adaptive` builds it
(analysis/adaptive.estimator_for: the artifact's vessel, hull and terms), with the OnlineConfig of the
parameters `online.*` (config/predictor.yaml). Per prediction cycle, between the state assembly and the rollout:

    feed      one sample per model step dt, on the grid t_0 + k dt of the first sample fed since the last reset
              (t_0 = that sample's t_c): a cycle whose t_c lies within half a cycle period (at most dt/2) of the
              next grid time feeds its LiveState (u, v, r, psi, controls at t_c, time (t_c - t_0) s, and a
              rudder_only boat's reference: the approach its rollout holds the engine speed of, ApproachTracker,
              so the filter's process model holds the same engine speed); the others feed nothing. The box averages
              of consecutive 10 Hz cycles overlap: feeding every cycle would treat correlated measurements as
              independent (docs/online.md). When t_c falls on the grid (rate_hz * dt a whole number, cycles on
              whole periods: the lock-step DDS test) the samples and their times are those of the Recording
              `replay evaluate` builds, so the estimates are its estimates (for rudder_only only once both hold the
              same approach: replay the manoeuvre's, the node the latest straight running it has seen).
    apply     grey box, extended grey box, hybrid: the model's current_ne, yaw_rate_bias, resistance_change are set
              to the estimate after each sample fed (analysis/adaptive.set_terms / live_terms: a copy_, microseconds)
              and stay until the next one, so the cycle's rollout (and a candidate-plans rollout) predicts with
              the live sea; a learned model (DNN): computed and reported, not applied (adaptive.NOT_APPLIED).
    reset     the node's clock jumped back (buffers cleared), the model was swapped, an `online.*` parameter
              changed: back to the prior, the grid restarts. A stale input or a refused input skips the cycle
              (nothing fed); the filter's own gap rule restarts its velocity states after more than max_gap_s and
              keeps the slow terms (fitting/online.py), and it resets by itself after reset_gap_s.
"""
from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

from usv_predictor.analysis import adaptive
from usv_predictor.fitting.online import B_R, K_R, TERMS, OnlineConfig, OnlineEstimate, OnlineEstimator
from usv_predictor.node.live import LiveState
from usv_predictor.records import NS_PER_S

COST_WINDOW = 200  # filter steps kept for the cost percentiles


@dataclass(frozen=True)
class Fed:
    """One sample fed to the filter: the estimate after it and the state time it belongs to."""

    t_c_ns: int  # the sample's time (the LiveState's t_c, the node's clock)
    estimate: OnlineEstimate


class LiveSea:
    """The estimator of one model: feeds it on the dt grid, applies its estimate, reports it."""

    def __init__(self, model: Any, vessel: Any, config: OnlineConfig, enabled: bool, dt: float, rate_hz: float
                 ) -> None:
        self.model = model  # the ModelArtifact whose module's terms are set
        self.config = config
        self.enabled = bool(enabled)
        self.original = adaptive.model_terms(model)  # None: a learned model, not applied
        self.applied = self.enabled and self.original is not None
        self.dt_ns = round(dt * NS_PER_S)
        # a cycle within this of the next grid time feeds (ns): half a cycle period, at most half a step
        self.tolerance_ns = round(0.5 * min(1.0 / rate_hz, dt) * NS_PER_S)
        self.estimator: OnlineEstimator | None = (adaptive.estimator_for(model, vessel, config) if self.enabled
                                                  else None)
        self.fed = 0  # samples fed since start-up
        self.latest: Fed | None = None
        self.last_reset = ""
        self.cost_s: deque[float] = deque(maxlen=COST_WINDOW)  # filter step + applying the terms (s)
        self._t0_ns: int | None = None  # grid origin: the first sample fed since the last reset
        self._next_ns: int | None = None  # the next grid time

    @property
    def why(self) -> str:
        """Why the estimate is (not) applied."""
        if not self.enabled:
            return "online.enabled is false: the model predicts with its own terms"
        if self.original is None:
            return adaptive.NOT_APPLIED
        return "current_ne, yaw_rate_bias, resistance_change of the grey box set to the estimate before each rollout"

    def due(self, t_c_ns: int) -> bool:
        """Does the sample at t_c_ns fall on the grid (within tolerance_ns of the next grid time)?"""
        return self._next_ns is None or t_c_ns >= self._next_ns - self.tolerance_ns

    def observe(self, state: LiveState) -> Fed | None:
        """Feed the cycle's state if it is due, apply the new estimate; the sample fed (None: not due, disabled)."""
        if self.estimator is None or not self.due(state.t_c_ns):
            return None
        started = time.perf_counter()
        if self._t0_ns is None:
            self._t0_ns = state.t_c_ns
        steps = (state.t_c_ns - self._t0_ns + self.tolerance_ns) // self.dt_ns + 1  # the grid time after this one
        self._next_ns = self._t0_ns + steps * self.dt_ns
        u, v, r, psi = (float(x) for x in state.state)
        estimate = self.estimator.step((state.t_c_ns - self._t0_ns) / NS_PER_S, u, v, r, psi, state.controls,
                                       state.reference)
        if self.applied:
            adaptive.set_terms(self.model, adaptive.live_terms(estimate, self.original))
        self.cost_s.append(time.perf_counter() - started)
        self.fed += 1
        self.latest = Fed(state.t_c_ns, estimate)
        return self.latest

    def started(self) -> bool:
        """Has the filter a state (something worth publishing)?"""
        return self.estimator is not None and self.estimator.x is not None

    def reset(self, why: str) -> None:
        """Back to the prior (the model's own terms), the grid restarts at the next sample."""
        if self.estimator is not None:
            self.estimator.reset()
        self.restore()
        self._t0_ns = self._next_ns = None
        self.latest = None
        self.last_reset = why

    def restore(self) -> None:
        """Put the model's own terms back (before the model is dropped or the estimator switched off)."""
        if self.applied:
            adaptive.set_terms(self.model, {k: v for k, v in self.original.items() if k in TERMS})

    def report(self, now_ns: int) -> tuple[bool, str, dict[str, str]]:
        """(warn, message, values) for /diagnostics."""
        values: dict[str, str] = {"enabled": str(self.enabled).lower(), "applied": "yes" if self.applied else "no",
                                  "why": self.why, "samples_fed": str(self.fed)}
        if self.last_reset:
            values["last_reset"] = self.last_reset
        if self.estimator is None:
            return False, "off", values
        c = self.config
        values.update(prior_current_std_mps=f"{c.prior_current_std_m_s:g}", current_noise=f"{c.current_noise:g}")
        if self.cost_s:
            ms = sorted(x * 1e3 for x in self.cost_s)
            values.update(filter_ms_p50=f"{ms[len(ms) // 2]:.3f}", filter_ms_max=f"{ms[-1]:.3f}")
        if self.latest is None or not self.started():
            return False, "no estimate yet: waiting for a complete state", values
        e = self.latest.estimate
        values.update({
            "status": e.status, "age_s": f"{(now_ns - self.latest.t_c_ns) / NS_PER_S:.3f}",
            "converged": str(e.converged).lower(),
            "current_speed_mps": f"{e.current_speed_m_s:.4f}", "current_toward_deg": f"{e.current_to_deg:.1f}",
            "current_std_max_mps": f"{e.current_std_max_m_s:.4f}",
            "current_n_mps": f"{e.current_ne[0]:.4f}", "current_e_mps": f"{e.current_ne[1]:.4f}",
            "gyro_bias_deg_s": f"{math.degrees(e.state[B_R]):.4f}",
            "gyro_bias_std_deg_s": f"{math.degrees(e.std[B_R]):.4f}",
            "resistance_change_pct": f"{100.0 * e.state[K_R]:.2f}",
            "resistance_change_std_pct": f"{100.0 * e.std[K_R]:.2f}",
            "nis_mean": f"{e.nis_mean:.3f}" if math.isfinite(e.nis_mean) else "none",
            "nis_expected": "3",
            "updates": str(e.updates), "rejections": str(e.rejections), "changes": str(e.changes),
            "resets": str(e.resets),
        })
        speed = (f"current {e.current_speed_m_s:.2f} m/s toward {e.current_to_deg:.0f} deg "
                 f"(std {e.current_std_max_m_s:.3f} m/s)")
        if e.status.startswith(("rejected", "reset: the filter diverged")):
            return True, f"{e.status}; {speed}", values
        if not e.converged:
            return False, (f"not converged: {speed}; along the track the current and a resistance change cannot be "
                           "told apart until the boat turns"), values
        return False, f"converged: {speed}", values
