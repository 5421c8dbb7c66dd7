"""Diagnosis: what the calm-water model gets wrong on measured data, the physical cause, and the gain.

Method (simulation error, multiple shooting): every recording is cut into segments (default 20 s every
5 s); from each segment's measured start state the grey box (usv_predictor.models.greybox) is rolled out with the
measured controls and compared with what was measured, channel by channel, in units of the channel's noise:
    residual = (predicted - measured) / sigma,  channels u, v, r, x_n, y_e, psi (positions from the start).
Each hypothesis of the DESIGN.md vocabulary is one small term of the grey box (its physics.effects record); its
parameters are fitted by Levenberg-Marquardt on the residuals of the FIT manoeuvres and the hypotheses are
compared on HELD-OUT manoeuvres (two folds by manoeuvre, each fitted on the other) by the Gaussian
log-likelihood ratio of their held-out losses L (mean squared weighted residual):
    evidence(a over b) = n_eff / 2 * ln(L_b / L_a),  n_eff = segments * stride / horizon
(overlapping segments are not independent, so only one in horizon/stride counts). Held out, no parameter
penalty is needed. A hypothesis whose extension alone moves only some channels (physics.effects.Effect.channels: a
compass offset, the two positions) is measured over the calm-water model on those (L the mean of their channel
losses): the other channels are predicted exactly as without it, so with a variance per channel their likelihood
ratio is 1, where the pooled loss dilutes it (evidence_channels). A cause is named only when its evidence over the
calm-water model is at least
EVIDENCE_CAUSE (5: "strong" on the Kass & Raftery scale, 2 ln B > 10) and it removes at least MIN_GAIN of
its held-out loss; a runner-up that is itself a cause and that the winner beats by less than
EVIDENCE_CONFOUND is reported as confounded with it.

Further causes (select_causes): after the primary, the cause whose set with the chosen ones leaves the lowest
held-out loss is added while it passes the same three tests (evidence, MIN_GAIN, track) over the model with the
chosen causes (forward); after each addition every chosen cause, the primary included, must still pass them over the
model with all the others (backward): the weakest that does not is dropped and the rest checked again, and the named
cause that explains most alone becomes the primary (a 5.4 m/s wind was named as 0.05 m wave drift, the wind "further").
Every set of causes is fitted once per fold; a set nested in a larger fitted one is refitted from the larger fit's
values of its terms where those fit its fold better than its own fit (Levenberg-Marquardt from the records' starts can
end in a poorer minimum: that wind alone left 3.2 noise units, with the wave drift 1.1).

A cause is also named only when its extension lowers the held-out TRACK error (the mean distance between the
predicted and the GNSS position at the end of the held-out segments, MIN_TRACK_GAIN): a term that lowers the
loss by bending the velocities while the predicted track gets worse is no physical cause (run_diagnosis applies
the same rule to the measured 30 s open-loop gain and withdraws a cause whose extension raises it). A gyro bias
(Effect.track_neutral) moves only the start's yaw rate, which the hull forgets within seconds: its extension is
named when it raises either error by at most TRACK_NEUTRAL.

Otherwise the answer is `none` — unless the calm-water model itself does not fit: then it is `model_mismatch`
(identify the boat first), when nothing is named but the calm-water model leaves a held-out loss above NONE_LOSS
noise units (not "within the noise"), when the fit check failed (analysis/fit_check.py, the caller passes its reasons),
when its rollout diverges on the data (diverged_segments), when the best model (the calm-water one with the named
causes; with a candidate that was not named, with that candidate) leaves a held-out loss above MISMATCH_LOSS noise
units and more than MISMATCH_SHARE of the calm-water model's, or above FIT_CEILING_LOSS whatever share its causes
removed, or when a named cause's parameter, fitted on all manoeuvres, lies outside its effect's physical range
(physics.effects.Effect.outside_range). The best environmental cause is reported beside model_mismatch.

`inconclusive`: a cause had the evidence of the loss but its extension does not lower the held-out track error
(above; or, in run_diagnosis, the 30 s open-loop position error), while the calm-water model with that candidate
does fit by the loss test; or, where the answer would be `none`, the best hypothesis has evidence between
EVIDENCE_CANDIDATE and EVIDENCE_CAUSE, removes MIN_GAIN of the loss and lowers the track error (something is
there, not enough to name it). Neither `none` (something is there) nor `model_mismatch` (the model fits; "identify the
boat first" would be the wrong remedy): the candidate, its parameters and why it is not named are reported
(Diagnosis.candidate, candidate_parameters, inconclusive_reasons). When no physical cause is named (model_mismatch,
inconclusive), diagnosis_run tries the learned residual of last resort and answers `unexplained` when it lowers the
held-out loss and track error as a cause must (analysis/diagnosis_unexplained.py). The calm-water model's held-out loss
and track error before any hypothesis are reported beside the answer (Diagnosis.calm_water_fit).
"""
from __future__ import annotations

import dataclasses
import math
import os
import time
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np
import torch

from usv_predictor.data.recording import Recording
from usv_predictor.data.segments import SIGMA, Segments, make_segments, weighted_residuals  # noqa: F401 (API)
from usv_predictor.data.wave_motion import WaveFilter, wave_filter
from usv_predictor.errors import ConfigError, DiagnosisError
from usv_predictor.frames import compass_deg
from usv_predictor.models.greybox import GreyBoxRollout
from usv_predictor.models.kernel_rollout import KernelRollout
from usv_predictor.physics import effects as fx
from usv_predictor.physics.effects import Term
from usv_predictor.physics.vessel import Vessel

EVIDENCE_CAUSE = 5.0  # held-out log-likelihood ratio over the calm-water model needed to name a cause
MIN_GAIN = 0.05  # ... and the share of the calm-water model's held-out loss it must remove
EVIDENCE_CANDIDATE = 3.0  # ... and a `none` is only confident while no hypothesis reaches this evidence (2 ln B > 6:
#                            "strong" on the Kass & Raftery scale; EVIDENCE_CAUSE is their "very strong"): one between
#                            the two that removes MIN_GAIN of the loss and lowers the track error is `inconclusive`
#                            (an unknown boat's identified model showed a 5.5 m/s wind with evidence 3.8 and both
#                            folds' fits within 1 m/s and 12 deg of it). Not lower: clean days reach 1-2.2 (clean
#                            unknown boats 1.0 with 4 % of the loss, 2.2 with 3.6 %; the KVLCC2 tank's zig-zags 1.0
#                            with 33 %, the preset's speed error read as a current), where weak effects lie too (a
#                            6.4 m/s wind on a 16 m boat: 1.5 with 13 %); docs/results/unknown_boats.md
NONE_TRACK_GAIN = 0.25  # ... nor while a hypothesis with positive evidence removes this share of the held-out
#                         track error, however little of the loss: positions are two channels of six in the loss, so
#                         a term seen only in the track (a compass offset rotates the course, not the body
#                         velocities) can halve the track error at little evidence and under MIN_GAIN of the loss (an
#                         unknown rudder_only boat's 2.8 deg offset: evidence 0.36, 3.4 % of the loss, 41 % of the
#                         track error; the suite's clean boats' best hypotheses remove at most 5.1 % of it)
EVIDENCE_CONFOUND = 2.0  # a winner beating a runner-up cause by less than this is confounded with it
MIN_TRACK_GAIN = 0.0  # share of the calm-water model's held-out track error (m, at the segment end) a cause must
#                       remove: a cause whose extension does not lower it is never named
TRACK_NEUTRAL = 0.02  # share of that track error (and of the 30 s open-loop error) a set of track-neutral causes
#                       (physics/effects.py Effect.track_neutral: a gyro bias) may add: their extension moves only
#                       the start's yaw rate, which the hull's yaw dynamics forget within seconds
NESTED_REFIT = 1e-3  # a set of causes is refitted from a larger set's fit (select_causes, diagnose) when that fit,
#                      without the other causes' terms, leaves at least this share less of the fold's loss than the
#                      set's own fit (smaller differences are the fit's convergence tolerance, not a poorer minimum)
PROBE_DIRECTIONS = 8  # (-) compass directions (every 45 deg) a direction-valued term is probed at before the fit's
#                       descent (Term.probe, _probes) ...
PROBE_SHARES = (1.0, 0.5)  # ... at these shares of its probe magnitude (-): a wind's load goes with the square of its
#                            speed, so a probe of more than twice the truth's load loses to the start near zero and
#                            the descent ends in another basin (an unknown boat's 5.4 m/s wind probed at 8 m/s alone,
#                            2.2 times its load: 1.4 m/s from 307 deg on one fold, for 5.4 from 107)
MISMATCH_LOSS = 25.0  # held-out loss (mean squared error in noise units) the best model may leave ...
MISMATCH_SHARE = 0.5  # ... unless its causes removed more than half of the calm-water model's: above both, no
#                       environmental cause explains the data and the answer is model_mismatch (waves of 1.1 m
#                       leave 27 of 95 after wave_drift: explained; a clean day leaves 0.1)
FIT_CEILING_LOSS = 100.0  # held-out loss (noise units) no model that fits leaves, whatever share of the calm-water
#                           model's its causes removed (the MISMATCH_SHARE exception ends here): the loss is the mean
#                           squared residual in noise scales (data.segments.SIGMA), so 100 is an RMS error of
#                           sqrt(100) = 10 noise scales in every channel over the segment (0.5 m/s in u and v,
#                           2.9 deg/s in r, 10 m in position, 5.7 deg in heading), an order of magnitude above the
#                           noise: a cause fitted to such a model absorbs the model's error (an unknown boat's 1.4 m
#                           wave drift was named as a 28 m/s wind that left 1190 of 2432). The right causes of the 50
#                           unknown boats (docs/results/unknown_boats.md) left at most 43 (a current, 94 before), waves
#                           of 1.1 m 27
NONE_LOSS = 5.0  # held-out loss (noise units) above which the calm-water model is not "within the noise": `none`
#                 is then model_mismatch (clean presets leave 0.1, the right cause <= 0.5; an identified unknown
#                 boat that fits 0.3; one that left 17 hid a 0.77 deg/s gyro bias behind a confident `none`)
GAIN_METRIC = "mean_position_error_after_30s_m"  # the held-out error a named cause's extension must lower
MODEL_MISMATCH = "model_mismatch"  # the answer when the calm-water model itself is wrong (identify it first)
REMEDY = "identify this boat first (docs/your_boat.md)"
INCONCLUSIVE = "inconclusive"  # a candidate explains the held-out loss but its extension does not predict tracks better
UNEXPLAINED = "unexplained"  # no physical cause, but the learned residual of last resort lowers the held-out error
#                             (analysis/diagnosis_unexplained.py, run by diagnosis_run in place of the two above)
INCONCLUSIVE_REMEDY = ("record more of the day (longer runs, turns both ways, more headings) or test the candidate "
                       "against its rivals with --hypotheses")


# Every hypothesis and the grey-box terms (physics.effects.Term) it fits: `none` (none) and each effect record.
HYPOTHESES: Mapping[str, tuple[Term, ...]] = fx.RegistryView(
    lambda: {name: () if name == fx.NONE else fx.EFFECTS[name].terms for name in fx.hypothesis_names()})


def _predicted(model: GreyBoxRollout | KernelRollout, seg: Segments) -> np.ndarray | torch.Tensor:
    """(B, H, 6) rollout of the segments (the kernel's in numpy, on the segments' own memory)."""
    if isinstance(model, KernelRollout):
        return model.rollout(seg.state.numpy(), seg.controls.numpy(),
                             None if seg.reference is None else seg.reference.numpy())[0]
    with torch.no_grad():
        return model(seg.state, seg.controls, seg.reference)[0]


def residuals(model: GreyBoxRollout | KernelRollout, seg: Segments) -> torch.Tensor:
    """Weighted residuals (B, H, 6) of the rollout against the measurements, wave-filtered when the segments are
    (data.segments.weighted_residuals)."""
    return torch.as_tensor(weighted_residuals(_predicted(model, seg), seg))


def loss(model: GreyBoxRollout, seg: Segments) -> float:
    """Mean squared weighted residual (1.0 = errors at the noise scale)."""
    r = residuals(model, seg)
    return float((r * r).sum() / torch.count_nonzero(seg.weight))


def segment_losses(model: GreyBoxRollout, seg: Segments) -> np.ndarray:
    """(B,) mean squared weighted residual of each segment."""
    return segment_scores(model, seg)[0]


def segment_scores(model: GreyBoxRollout, seg: Segments) -> tuple[np.ndarray, np.ndarray]:
    """(B,) mean squared weighted residual (wave-filtered when the segments are) and (B,) track error (m) of each
    segment: the distance between the predicted and the GNSS position at the segment's end (NaN without a fix there;
    never filtered), from one rollout."""
    return segment_channel_scores(model, seg)[:2]


def segment_channel_scores(model: GreyBoxRollout, seg: Segments) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """segment_scores and (B, 6) each channel's mean squared weighted residual per segment (NaN where a channel has
    no sample), from one rollout."""
    predicted = _predicted(model, seg)
    r = np.asarray(weighted_residuals(predicted, seg))  # (B, H, 6)
    counts = np.count_nonzero(seg.weight.numpy(), axis=1)  # (B, 6)
    squared = (r * r).sum(axis=1)  # (B, 6)
    losses = squared.sum(axis=1) / np.maximum(counts.sum(axis=1), 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        by_channel = np.where(counts > 0, squared / np.maximum(counts, 1), np.nan)
    end = np.asarray(weighted_residuals(predicted, seg, filtered=False))[:, -1, 3:5]  # (B, 2) at the end
    weight = seg.weight[:, -1, 3:5].numpy()  # (B, 2) 1/sigma, 0 without a fix
    with np.errstate(divide="ignore", invalid="ignore"):
        track = np.where((weight > 0).all(axis=1), np.hypot(*(end / np.where(weight > 0, weight, 1.0)).T), np.nan)
    return losses, track, by_channel


def channel_loss(means: Sequence[float], channels: Sequence[int]) -> float:
    """The held-out loss on `channels` (Effect.channels): the mean over them of the (6,) channel means of
    _channel_means; NaN when the channels were not scored (no means)."""
    return float(np.mean([means[c] for c in channels])) if len(means) else math.nan


def _channel_means(by_channel: np.ndarray) -> tuple[float, ...]:
    """(6,) each channel's mean over the segments of (B, 6) per-segment channel losses (NaN: no sample)."""
    with np.errstate(invalid="ignore"):
        if not len(by_channel) or np.isnan(by_channel).all():
            return ()
        return tuple(float(x) for x in np.nanmean(by_channel, axis=0))


def _channels_text(cause: str) -> str:
    """' in x_n, y_e' for a cause measured on some channels (evidence_channels), '' for one measured on all."""
    channels = evidence_channels(cause)
    return f" in {', '.join(fx.CHANNELS[c] for c in channels)}" if channels else ""


def evidence_channels(cause: str) -> tuple[int, ...]:
    """The channels a cause's evidence over the calm-water model is measured on: its effect's (Effect.channels, the
    channels its extension alone moves), () for all (the pooled loss)."""
    return fx.EFFECTS[cause].channels if cause in fx.EFFECTS else ()


def diagnosis_segments(recordings: Sequence[Recording], horizon_s: float, stride_s: float,
                       wave_filter_mode: str = "auto") -> tuple[Segments, WaveFilter]:
    """The segments a diagnosis fits and scores (make_segments) with the wave filter its detector decides
    (data/wave_motion.py; `replay diagnose --wave-filter`), and that decision."""
    decided = wave_filter(recordings, SIGMA, wave_filter_mode)
    return make_segments(recordings, horizon_s, stride_s, filter_s=decided.sigma_s), decided


def diverged_segments(model: GreyBoxRollout | KernelRollout, seg: Segments) -> int:
    """How many segments the calm-water model (no hypothesis terms) cannot roll out (non-finite residuals) although
    their measured start and controls are finite: a model that diverges on the data (0: it rolls out everywhere)."""
    set_terms(model, {})
    finite_inputs = torch.isfinite(seg.state).all(dim=1) & torch.isfinite(seg.controls).all(dim=(1, 2))  # (B,)
    finite_out = torch.isfinite(residuals(model, seg)).all(dim=(1, 2))  # (B,)
    return int((finite_inputs & ~finite_out).sum())


def _mean_track(track: np.ndarray) -> float:
    """Mean of the finite segment track errors (m); NaN when no segment ends with a fix."""
    finite = track[np.isfinite(track)]
    return float(finite.mean()) if len(finite) else float("nan")


def _loss_text(loss: float) -> str:
    """A held-out loss for the progress lines, 9 characters wide: a non-finite one (a fit whose rollout left the
    finite numbers on a held-out segment; its JSON `heldout_loss` is null) says so instead of printing nan."""
    return f"{loss:9.3f}" if math.isfinite(loss) else f"{'diverged':>9s}"


def set_terms(model: GreyBoxRollout, values: dict[str, Sequence[float]]) -> None:
    """Zero every extension term, then set the given ones (SI)."""
    with torch.no_grad():
        for name in fx.grey_box_terms():
            getattr(model, name).zero_()
        for name, value in values.items():
            getattr(model, name)[:] = torch.as_tensor(value, dtype=torch.float64)


@dataclass(frozen=True)
class Fit:
    hypothesis: str
    terms: dict[str, tuple[float, ...]]  # SI values per grey-box term
    loss: float  # on the data it was fitted on
    std: dict[str, tuple[float, ...]]  # standard errors (SI), conservative (see fit_hypothesis)
    iterations: int
    seconds: float


def evidence_text(value: float) -> str:
    """An evidence as the messages print it: one decimal, never rounded up to the EVIDENCE_CAUSE a cause needs (the
    Otter sea trial's further current at 4.996 reads 4.99, not 5.0, beside "a cause needs evidence >= 5")."""
    text = f"{value:.1f}"
    if value < EVIDENCE_CAUSE <= float(text):
        text = f"{math.floor(value * 100.0) / 100.0:.2f}"
    return text


def _cost(r: np.ndarray) -> float:
    """The squared norm r . r of weighted residuals (N,); inf, without numpy's overflow warning, when a trial's rollout
    nearly diverges (residuals beyond ~1e19 in float32): such a trial is never better than the current one."""
    with np.errstate(over="ignore", invalid="ignore"):
        return float(r @ r)


def fit_hypothesis(model: GreyBoxRollout, seg: Segments, hypothesis: str | Sequence[str], *, max_iter: int = 12,
                   start: Mapping[str, Sequence[float]] | None = None,
                   hold: frozenset[str] | None = None) -> Fit:
    """Levenberg-Marquardt on the weighted residuals, finite-difference Jacobian in scaled parameters, from the
    lowest loss of the start and the probes of its directions (_probes: a wind or wave direction toward every 45 deg).

    `hypothesis` is one name of HYPOTHESES or several, fitted together (a cause and the ones added to it).
    `start`: initial values (SI) of some of its terms in place of their records' Term.start (cause selection starts a
    set of causes from a larger set's fit, select_causes); a term given a start is not probed.
    `hold`: terms held at their start in this descent. None: a staged term (Term.staged) not given a start is also
    descended with held first, then freed from that fit; the lower loss of that and the descent with it free is kept.

    Standard errors come from (J^T J)^-1 s^2, inflated by the steps per segment because the residuals of
    one segment are strongly correlated (a conservative effective sample size: one per segment).
    """
    started = time.perf_counter()
    names = (hypothesis,) if isinstance(hypothesis, str) else tuple(hypothesis)
    terms = tuple(term for name in names for term in HYPOTHESES[name])
    start = start or {}
    staged = frozenset(t.name for t in terms if t.staged and t.name not in start)
    if hold is None and staged:
        free = fit_hypothesis(model, seg, names, max_iter=max_iter, start=start, hold=frozenset())
        first = fit_hypothesis(model, seg, names, max_iter=max_iter, start=start, hold=staged)
        fits = [free]
        if math.isfinite(first.loss):  # every term given a start: no probes from the held fit's optimum
            fits.append(fit_hypothesis(model, seg, names, max_iter=max_iter, start=first.terms, hold=frozenset()))
        best = min(fits, key=lambda f: f.loss)
        set_terms(model, best.terms)
        return dataclasses.replace(best, iterations=sum(f.iterations for f in (*fits, first)),
                                   seconds=time.perf_counter() - started)
    hold = hold or frozenset()
    hypothesis = "+".join(names)
    sizes = [len(t.start) for t in terms]
    scale = np.concatenate([[t.scale] * n for t, n in zip(terms, sizes)]) if terms else np.zeros(0)
    theta = (np.concatenate([np.clip(start.get(t.name, t.start), t.low, t.high) for t in terms]) / scale if terms
             else np.zeros(0))
    # the bounds (SI); a held term's are its start
    low = np.concatenate([[t.low] * n for t, n in zip(terms, sizes)]) if terms else np.zeros(0)
    high = np.concatenate([[t.high] * n for t, n in zip(terms, sizes)]) if terms else np.zeros(0)
    k = 0
    for t, n in zip(terms, sizes):
        if t.name in hold:
            low[k:k + n] = high[k:k + n] = theta[k:k + n] * scale[k:k + n]
        k += n

    def unpack(p: np.ndarray) -> dict[str, tuple[float, ...]]:
        values, k = {}, 0
        for t, n in zip(terms, sizes):
            values[t.name] = tuple(float(x) for x in np.clip(p[k:k + n] * scale[k:k + n], low[k:k + n], high[k:k + n]))
            k += n
        return values

    def res(p: np.ndarray) -> np.ndarray:
        set_terms(model, unpack(p))
        return residuals(model, seg).flatten().numpy()

    count = max(int(torch.count_nonzero(seg.weight)), 1)
    r = res(theta)
    if not np.all(np.isfinite(r)):
        set_terms(model, {})
        if terms and bool(torch.isfinite(residuals(model, seg)).all()):
            # the calm-water model rolls out, this hypothesis's start does not: a diverged fit (infinite loss), which
            # ranks last and is never named (diagnose); not an error of the data
            values = unpack(theta)
            set_terms(model, values)
            return Fit(hypothesis, values, math.inf, {name: (math.inf,) * len(v) for name, v in values.items()}, 0,
                       time.perf_counter() - started)
        raise DiagnosisError(f"hypothesis {hypothesis}: the calm-water model's residuals are not finite on these "
                             "segments (NaN/inf in the recordings, or a rollout that diverges at this step: try a "
                             "smaller --dt)")
    cost = _cost(r)
    for probe in _probes(terms, sizes, theta, start):  # other basins of a direction: descend from the lowest
        r_probe = res(probe)
        cost_probe = _cost(r_probe)
        if np.all(np.isfinite(r_probe)) and cost_probe < cost:
            theta, r, cost = probe, r_probe, cost_probe
    lam, it = 1e-2, 0
    jac = np.zeros((len(r), len(theta)))
    for it in range(1, max_iter + 1 if len(theta) else 1):  # noqa: B007 -- the count is returned
        eps = 1e-3
        for j in range(len(theta)):
            step = theta.copy()
            step[j] += eps
            jac[:, j] = (res(step) - r) / eps
        jac[~np.isfinite(jac)] = 0.0  # a perturbation whose rollout diverged gives no direction
        jtj, jtr = jac.T @ jac, jac.T @ r
        improved = False
        for _ in range(8):
            delta = np.linalg.solve(jtj + lam * np.diag(np.diag(jtj) + 1e-9), -jtr)
            if not np.all(np.isfinite(delta)):  # a non-finite Jacobian: no step (a NaN parameter would reach the
                break                            # rollout's indexing, e.g. the actuator delay)
            trial = np.clip(theta + delta, low / scale, high / scale)
            if not np.all(np.isfinite(trial)):  # never roll out non-finite parameters (a NaN delay indexes nothing)
                lam *= 10.0
                continue
            r_trial = res(trial)
            c_trial = _cost(r_trial)
            if c_trial < cost:
                theta, r, improved = trial, r_trial, True
                converged = (cost - c_trial) < 1e-6 * cost
                cost, lam = c_trial, lam * 0.3
                break
            lam *= 10.0
        if not improved or converged:
            break
    values = unpack(theta)
    std: dict[str, tuple[float, ...]] = {}
    if len(theta):
        steps = seg.target.shape[1]
        s2 = cost / max(count - len(theta), 1)
        try:
            cov = np.linalg.inv(jac.T @ jac) * s2 * steps
        except np.linalg.LinAlgError:
            cov = np.full((len(theta), len(theta)), np.inf)
        sd = np.sqrt(np.abs(np.diag(cov))) * scale
        k = 0
        for t, n in zip(terms, sizes):
            std[t.name] = tuple(float(x) for x in sd[k:k + n])
            k += n
    set_terms(model, values)
    return Fit(hypothesis, values, cost / count, std, it, time.perf_counter() - started)


def _probes(terms: Sequence[Term], sizes: Sequence[int], theta: np.ndarray,
            given: Mapping[str, Sequence[float]]) -> list[np.ndarray]:
    """fit_hypothesis's other starting points (scaled like theta): each 2-D term with a probe magnitude (Term.probe)
    and no given start set to each PROBE_SHARES share of that magnitude toward each of PROBE_DIRECTIONS compass
    directions, the other terms as in theta. One rollout each; the descent starts from the lowest loss of them and
    theta."""
    found, k = [], 0
    for term, n in zip(terms, sizes):
        if term.probe > 0.0 and term.name not in given:
            for share in PROBE_SHARES:
                for j in range(PROBE_DIRECTIONS):
                    angle = 2.0 * math.pi * j / PROBE_DIRECTIONS  # (rad) from north, clockwise (north, east)
                    probe = theta.copy()
                    probe[k:k + n] = share * term.probe * np.array([math.cos(angle), math.sin(angle)]) / term.scale
                    found.append(probe)
        k += n
    return found


def compiled_rollout(vessel: Vessel, dt: float, substeps: int = 1) -> KernelRollout:
    """The grey box on the compiled kernel (models/kernel_rollout.py): called as the module is, its terms the
    module's, set in place by set_terms and re-read at every call; the segments split over the machine's cores."""
    return KernelRollout(GreyBoxRollout(vessel, dt=dt, substeps=substeps), live=True, threads=os.cpu_count() or 1)


# ---- from grey-box terms to the DESIGN.md vocabulary -------------------------------------------------

def physical_parameters(hypothesis: str, terms: Mapping[str, Sequence[float]]) -> dict[str, float]:
    """Grey-box terms (SI) -> the diagnosis vocabulary (speeds, compass directions, degrees, seconds), as the
    hypothesis' record reads them; {} for `none`."""
    effect = fx.EFFECTS.get(hypothesis)
    return {} if effect is None else effect.readout.read(terms)


# ---- the diagnosis -----------------------------------------------------------------------------------

@dataclass(frozen=True)
class Evidence:
    hypothesis: str
    heldout_loss: float  # mean over the held-out segments of both folds, each fold fitted on the other
    gain_vs_none: float  # relative reduction of the calm-water model's held-out loss
    evidence_vs_none: float  # held-out log-likelihood ratio over the calm-water model (module docstring)
    evidence_of_best: float  # how clearly the winner beats this hypothesis (0 for the winner)
    fold_parameters: tuple[dict[str, float], ...]  # the physical parameters fitted on each fold
    heldout_track_error_m: float = float("nan")  # mean held-out position error at the segment end (m)
    track_gain_vs_none: float = float("nan")  # relative reduction of the calm-water model's held-out track error
    measured_on: str = ""  # " in x_n, y_e": the channels gain and evidence are measured on (evidence_channels); "": all


@dataclass(frozen=True)
class AddedCause:
    """A further cause found after the primary one, with its evidence over the model without it."""

    cause: str
    parameters: dict[str, float]
    uncertainty: dict[str, float]
    heldout_loss: float
    evidence: float  # held-out log-likelihood ratio over the model with the causes before it
    gain: float  # share of that model's held-out loss it removes
    track_gain: float = float("nan")  # share of that model's held-out track error it removes


@dataclass(frozen=True)
class CalmWaterFit:
    """How well the calm-water model fits the held-out data before any hypothesis."""

    heldout_loss: float  # mean squared weighted residual (1 = errors at the noise scale)
    heldout_track_error_m: float  # mean position error at the end of the held-out segments (m)
    horizon_s: float  # the segments' length (s)


@dataclass(frozen=True, kw_only=True)
class Diagnosis:
    """The answer of a diagnosis, built by keyword (about twenty fields)."""

    cause: str
    parameters: dict[str, float]
    uncertainty: dict[str, float]
    confounded_with: tuple[str, ...]
    evidence: tuple[Evidence, ...]  # every hypothesis, best first
    fit: Fit  # the winner refitted on all manoeuvres (for `none`: the calm-water model)
    folds: tuple[tuple[str, ...], tuple[str, ...]]  # manoeuvre names of the two folds
    message: str
    seconds: float = 0.0
    notes: tuple[str, ...] = field(default_factory=tuple)
    additional_causes: tuple[AddedCause, ...] = ()
    calm_water_fit: CalmWaterFit | None = None
    mismatch_reasons: tuple[str, ...] = ()  # why the answer is model_mismatch (empty otherwise)
    best_environmental_cause: str = ""  # with model_mismatch: the cause that would have been named ("" none)
    candidate: str = ""  # inconclusive: the hypothesis that explains the loss but was not named
    candidate_parameters: dict[str, float] = field(default_factory=dict)  # ... its parameters, fitted on all data
    inconclusive_reasons: tuple[str, ...] = ()  # ... why it is not named
    dropped_causes: tuple[str, ...] = ()  # causes dropped by the backward step of select_causes, and why
    further_candidate: AddedCause | None = None  # a further cause not named for want of evidence alone
    #                      (Selection.further_candidate; its parameters fitted with the named causes on all manoeuvres)
    further_candidate_reason: str = ""  # ... why it is not named ("" without one)

    @property
    def hypotheses(self) -> tuple[str, ...]:
        """Every named cause, primary first (what the extended model contains)."""
        if self.cause in ("none", MODEL_MISMATCH, INCONCLUSIVE, UNEXPLAINED):
            return ()
        return (self.cause, *(a.cause for a in self.additional_causes))


def check_data(recordings: Sequence[Recording]) -> list[str]:
    """Refuse what cannot be diagnosed; return notes on what limits the answer."""
    if len(recordings) < 2:
        raise DiagnosisError(
            f"{len(recordings)} manoeuvre(s): a diagnosis needs at least two (it fits on one and checks on the "
            "other); add a turning circle each way and a zig-zag")
    notes = []
    # the turn side through the layout's steering signal: a rudder angle, or the thrust difference port - starboard
    turns = [float(np.sign(np.nanmean(rec.actuator_layout.steering_signal(rec.controls)))) for rec in recordings]
    if not (any(t > 0 for t in turns) and any(t < 0 for t in turns)):
        notes.append("all manoeuvres turn the same way: a steering offset (rudder offset, thruster imbalance) and "
                     "current/wind can be confounded; turn both ways to separate them")
    headings = np.concatenate([np.mod(rec.psi, 2 * math.pi) for rec in recordings])
    coverage = len(np.unique(np.floor(headings / (math.pi / 4)))) / 8.0
    if coverage < 0.75:
        notes.append(f"headings cover {coverage * 100:.0f} % of the compass: heading-dependent causes (current, "
                     "wind, waves, heading offset) are poorly separated; add a full turning circle")
    return notes


def effective_segments(segments: int, stride_s: float, horizon_s: float) -> float:
    """n_eff of the module docstring: overlapping segments (stride < horizon) count as segments * stride / horizon,
    at least 2."""
    return max(segments * stride_s / horizon_s, 2.0)


def log_evidence(n_eff: float, loss: float, over_loss: float) -> float:
    """Held-out log-likelihood ratio (module docstring) of a model leaving mean `loss` over one leaving `over_loss`
    (noise units): n_eff / 2 * ln(over_loss / loss)."""
    return 0.5 * n_eff * math.log(max(over_loss, 1e-12) / max(loss, 1e-12))


# ---- the selection of causes (forward, then backward elimination) -----------------------------------

def track_neutral(causes: Sequence[str]) -> bool:
    """Whether every one of the causes is track-neutral (Effect.track_neutral; `none` and unknown names are not)."""
    return bool(causes) and all(c in fx.EFFECTS and fx.EFFECTS[c].track_neutral for c in causes)


def track_rule_failed(causes: Sequence[str]) -> str:
    """What an extension with these causes did when it fails lowers_track (for the messages)."""
    return f"raises by more than {TRACK_NEUTRAL:.0%}" if track_neutral(causes) else "does not lower"


def lowers_track(track_gain: float, causes: Sequence[str] = ()) -> bool:
    """The track rule of naming the causes (MIN_TRACK_GAIN): their extension lowers the held-out track error, or,
    for track-neutral causes (track_neutral), raises it by at most TRACK_NEUTRAL; without GNSS at the segment ends
    (NaN) there is no track to judge by."""
    floor = -TRACK_NEUTRAL if track_neutral(causes) else MIN_TRACK_GAIN
    return not math.isfinite(track_gain) or track_gain > floor


@dataclass(frozen=True)
class HeldOut:
    """Held-out scores of the calm-water model with a set of causes (each fold fitted on the other)."""

    loss: float  # mean held-out loss (noise units); inf for a diverged fit
    track_m: float = float("nan")  # mean held-out track error at the segment end (m); NaN without GNSS fixes
    channel_loss: tuple[float, ...] = ()  # (6,) each channel's mean held-out loss (channel_loss); () not scored

    def on(self, channels: Sequence[int]) -> float:
        """The loss on these channels (all: `loss`); `loss` when the channels were not scored."""
        return channel_loss(self.channel_loss, channels) if channels and self.channel_loss else self.loss


@dataclass(frozen=True)
class Contribution:
    """What one cause adds to the model with the `given` causes (the rule of naming it: `earns_place`)."""

    cause: str
    given: tuple[str, ...]  # the other causes (empty: over the calm-water model)
    heldout_loss: float  # of the model with `given` and the cause (noise units)
    evidence: float  # held-out log-likelihood ratio over the model with `given` only
    gain: float  # share of that model's held-out loss the cause removes
    track_gain: float  # share of that model's held-out track error it removes (NaN without GNSS)

    @property
    def earns_place(self) -> bool:
        """The one rule a cause is named by, first, added or kept: evidence >= EVIDENCE_CAUSE, gain >= MIN_GAIN and
        a lower held-out track error, over the model without it."""
        return (self.evidence >= EVIDENCE_CAUSE and self.gain >= MIN_GAIN
                and lowers_track(self.track_gain, (self.cause,)))

    def describe(self) -> str:
        """'given wind it adds evidence 0.8 (removes 3 % of the held-out loss, 1 % of the track error)'."""
        given = f"given {'+'.join(self.given)}" if self.given else "over the calm-water model"
        track = f", {self.track_gain * 100:.0f} % of the track error" if math.isfinite(self.track_gain) else ""
        return (f"{given} it adds evidence {evidence_text(self.evidence)} (removes {self.gain * 100:.0f} % of the "
                f"held-out loss{track})")


@dataclass(frozen=True)
class Selection:
    """The causes named and the ones dropped (select_causes)."""

    causes: tuple[str, ...]  # the named causes, the one that explains most alone first
    contributions: tuple[Contribution, ...]  # per named cause (same order): what it adds given all the others
    dropped: tuple[Contribution, ...]  # causes dropped, in order, each with what it added given the others then
    not_added: Contribution | None = None  # the best further cause the forward step tried last and did not add,
    #                                        given the named causes (None: none tried, max_causes reached)

    def drop_reasons(self) -> tuple[str, ...]:
        """'wave_drift dropped: given wind it adds evidence 0.8 (...; a cause needs >= 5 and >= 5 %)' per drop."""
        return tuple(f"{c.cause} dropped: {c.describe()}; {NEEDS}" for c in self.dropped)

    @property
    def further_candidate(self) -> Contribution | None:
        """The further cause not added for want of evidence alone (not_added with EVIDENCE_CANDIDATE <= evidence <
        EVIDENCE_CAUSE, removing MIN_GAIN and lowering the track error): something more is there, not enough to name
        it; the answer reports it as the primary's `inconclusive` reports a candidate. None otherwise."""
        c = self.not_added  # given the named causes: the forward step ends where it is tried
        if c is None:
            return None
        near = (EVIDENCE_CANDIDATE <= c.evidence < EVIDENCE_CAUSE and c.gain >= MIN_GAIN
                and lowers_track(c.track_gain, (c.cause,)))
        return c if near else None

    def further_candidate_reason(self) -> str:
        """'current not named as a further cause: given wave_drift it adds evidence 4.9 (...); a cause needs ...'."""
        c = self.further_candidate
        return "" if c is None else f"{c.cause} not named as a further cause: {c.describe()}; {NEEDS}"


NEEDS = (f"a cause needs evidence >= {EVIDENCE_CAUSE:g}, >= {MIN_GAIN * 100:.0f} % and a lower track error")  # the rule


def contribution(cause: str, given: Sequence[str], score: Callable[[tuple[str, ...]], HeldOut],
                 n_eff: float) -> Contribution:
    """What `cause` adds to the model with `given`: score(given + (cause,)) over score(given) (module docstring);
    over the calm-water model (no `given`) on the channels its extension alone moves (evidence_channels)."""
    given = tuple(given)
    with_, without = score((*given, cause)), score(given)
    channels = () if given else evidence_channels(cause)
    if not math.isfinite(with_.loss):  # a diverged fit adds nothing
        evidence, gain = -math.inf, -math.inf
    elif not math.isfinite(without.loss):
        evidence, gain = math.inf, 1.0
    else:
        loss_with, loss_without = with_.on(channels), without.on(channels)
        evidence = log_evidence(n_eff, loss_with, loss_without)
        gain = 1.0 - loss_with / loss_without if loss_without > 0 else 0.0
    track_gain = (1.0 - with_.track_m / without.track_m
                  if math.isfinite(with_.track_m) and math.isfinite(without.track_m) and without.track_m > 0
                  else float("nan"))
    return Contribution(cause, given, float(with_.loss), float(evidence), float(gain), float(track_gain))


def select_causes(primary: str, candidates: Sequence[str], score: Callable[[tuple[str, ...]], HeldOut],
                  n_eff: float, max_causes: int = 2) -> Selection:
    """Stepwise selection of the causes, from the primary (the cause named first): forward, then backward.

    Forward: of the candidates not chosen (nor dropped before), the one whose set with the chosen causes leaves the
    lowest held-out loss is added if it earns its place given them (Contribution.earns_place), up to max_causes.
    Backward, after each addition: every chosen cause, the primary included, must still earn its place given all
    the others; while some do not, the one with the least evidence is dropped (and never added again) and the rest
    re-checked. A first cause that a later one makes redundant is so dropped (an unknown boat's 5.4 m/s wind was
    named as 0.05 m wave drift, with the wind "further"). The named cause that explains most alone (lowest
    score((cause,)).loss) comes first. Nothing remains when no cause earns its place (possible only by the track
    rule). score(causes) is the held-out score of the calm-water model with the set of causes (a table of fitted
    sets in diagnose; the order of `causes` only orders the fit); a pure function of it.
    """
    chosen, dropped, not_added = [primary], [], None
    while len(chosen) < max_causes:
        trials = {name: score((*chosen, name)) for name in candidates if name not in chosen
                  and name not in {d.cause for d in dropped}}
        trials = {name: t for name, t in trials.items() if math.isfinite(t.loss)}  # a diverged fit is no cause
        if not trials:
            break
        name = min(trials, key=lambda n: trials[n].loss)
        tried = contribution(name, chosen, score, n_eff)
        if not tried.earns_place:
            not_added = tried
            break
        chosen.append(name)
        while chosen:
            weak = [c for c in (contribution(cause, [o for o in chosen if o != cause], score, n_eff)
                                for cause in chosen)
                    if not c.earns_place]
            if not weak:
                break
            weakest = min(weak, key=lambda c: (c.evidence, c.gain))
            chosen.remove(weakest.cause)
            dropped.append(weakest)
    if chosen:  # the one that explains most alone first, the others in the order they were added
        first = min(chosen, key=lambda c: score((c,)).loss)
        chosen = [first, *(c for c in chosen if c != first)]
    contributions = tuple(contribution(c, [o for o in chosen if o != c], score, n_eff) for c in chosen)
    return Selection(tuple(chosen), contributions, tuple(dropped), not_added)


def diagnose(recordings: Sequence[Recording], vessel: Vessel, *, hypotheses: Sequence[str] | None = None,
             horizon_s: float = 20.0, stride_s: float = 5.0, max_causes: int = 2,
             progress: Callable[[str], None] = lambda _: None, segments: Segments | None = None,
             rollout: KernelRollout | None = None, fit_mismatch: str = "") -> Diagnosis:
    """Name the cause of what the calm-water grey box gets wrong on these recordings.

    After the primary cause, up to max_causes - 1 further ones are added one at a time (forward selection)
    while each passes the same held-out evidence test against the model with the causes before it; after each
    addition a cause that no longer passes it given the others is dropped (backward elimination, select_causes).
    segments / rollout: make_segments(recordings, horizon_s, stride_s) and compiled_rollout(vessel, dt)
    when the caller has them already (built here otherwise); the rollout's terms are left at the final fit.
    """
    started = time.perf_counter()
    applicable = fx.hypothesis_names(vessel.layout)  # a rudder offset needs a rudder, an imbalance two thrusters
    names = list(hypotheses or applicable)
    foreign = [name for name in names if name in HYPOTHESES and name not in applicable]
    if foreign:
        raise ConfigError(f"hypotheses {foreign} do not apply to vessel {vessel.name} (actuator layout "
                          f"{vessel.layout}); "
                          f"its hypotheses are {', '.join(applicable)}")
    notes = check_data(recordings)
    unknown = [name for name in dict.fromkeys(names) if name not in HYPOTHESES]
    if unknown:
        raise DiagnosisError(f"unknown hypothesis {', '.join(map(repr, unknown))}; choose from {', '.join(HYPOTHESES)}")
    names = list(dict.fromkeys(names))
    if "none" not in names:
        names.insert(0, "none")
    dt = recordings[0].dt
    seg = segments if segments is not None else diagnosis_segments(recordings, horizon_s, stride_s)[0]
    folds = _folds(recordings)
    model = rollout if rollout is not None else compiled_rollout(vessel, dt)
    diverged = diverged_segments(model, seg)
    if diverged:
        # the calm-water model itself cannot be rolled out over the data: it does not fit them (not an error of the
        # data, and no environmental answer, nor `none`, can be trusted)
        reason = (f"the calm-water model's rollout diverges (NaN/inf) on {diverged} of {len(seg)} segments of "
                  f"{horizon_s:g} s at dt {dt:g} s from measured, finite starts and controls")
        names_of = lambda fold: tuple(recordings[i].name for i in fold)  # noqa: E731
        return Diagnosis(cause=MODEL_MISMATCH, parameters={}, uncertainty={}, confounded_with=(), evidence=(),
                         fit=Fit("none", {}, math.inf, {}, 0, 0.0), folds=(names_of(folds[0]), names_of(folds[1])),
                         message=f"{MODEL_MISMATCH}: {reason}: {REMEDY}", seconds=time.perf_counter() - started,
                         notes=tuple(notes), additional_causes=(),
                         calm_water_fit=CalmWaterFit(math.inf, math.inf, horizon_s), mismatch_reasons=(reason,),
                         best_environmental_cause="")
    per_segment: dict[str, np.ndarray] = {}
    per_track: dict[str, np.ndarray] = {}
    per_channel: dict[str, tuple[float, ...]] = {}  # (6,) each channel's mean held-out loss (_channel_means)
    fold_params: dict[str, tuple[dict[str, float], ...]] = {}
    fold_segments = tuple(seg.select(np.isin(seg.recording, fold)) for fold in folds)
    # every set of causes fitted (the first round's single hypotheses, `none` as the empty set, the selection's
    # sets): its fit order and, per fold k (fitted on fold k, held out on the other), the held-out segment losses,
    # track errors, physical parameters, the fit and the losses per channel
    FoldResult = tuple[np.ndarray, np.ndarray, dict[str, float], Fit, np.ndarray]  # one fold
    fitted: dict[frozenset[str], tuple[tuple[str, ...], list[FoldResult]]] = {}
    nested_checked: set[tuple[frozenset[str], frozenset[str]]] = set()

    def fold_fit(causes: tuple[str, ...], k: int,
                 start: Mapping[str, Sequence[float]] | None = None) -> FoldResult:
        """The set of causes fitted on fold k, scored on the other: held-out losses, track errors, parameters, fit."""
        hypothesis = causes[0] if len(causes) == 1 else (causes or "none")
        fit = fit_hypothesis(model, fold_segments[k], hypothesis, start=start)
        loss_, track_, by_channel = segment_channel_scores(model, fold_segments[1 - k])
        parameters = physical_parameters(hypothesis, fit.terms) if isinstance(hypothesis, str) else {}
        return loss_, track_, parameters, fit, by_channel

    def fit_set(causes: tuple[str, ...]) -> None:
        if frozenset(causes) not in fitted:
            fitted[frozenset(causes)] = (causes, [fold_fit(causes, 0), fold_fit(causes, 1)])

    def refit_nested(key: frozenset[str]) -> None:
        """A set of causes nested in a larger fitted set fits its fold at least as well as the larger set's fit
        without the other causes' terms: where that restriction beats the set's own fit (Levenberg-Marquardt from
        the records' starts ends in a poorer minimum), refit the set from it and keep the better fit of the fold."""
        own_terms = {term.name for name in key for term in HYPOTHESES[name]}
        for larger in [k for k in fitted if key < k and (key, k) not in nested_checked]:
            nested_checked.add((key, larger))
            causes, folds_ = fitted[key]
            for k in (0, 1):
                restriction = {t: v for t, v in fitted[larger][1][k][3].terms.items() if t in own_terms}
                set_terms(model, restriction)
                if not loss(model, fold_segments[k]) < folds_[k][3].loss * (1.0 - NESTED_REFIT):
                    continue
                refit = fold_fit(causes, k, restriction)
                if refit[3].loss < folds_[k][3].loss:
                    progress(f"{'+'.join(causes):30s} fold {k + 1} refitted from {'+'.join(fitted[larger][0])}'s fit: "
                             f"loss on its fold {folds_[k][3].loss:.3f} -> {refit[3].loss:.3f}")
                    folds_[k] = refit

    def score(causes: tuple[str, ...]) -> HeldOut:
        """The held-out score of the calm-water model with these causes (fitted once per set; select_causes)."""
        key = frozenset(causes)
        new = key not in fitted
        fit_set(tuple(causes))
        if key:
            refit_nested(key)
        losses, tracks, by_channel = held_out(key)
        if new and len(key) > 1:
            progress(f"{'+'.join(causes):30s} held-out loss {_loss_text(losses.mean())}, track error "
                     f"{_mean_track(tracks):7.2f} m")
        return HeldOut(float(losses.mean()), _mean_track(tracks), _channel_means(by_channel))

    def held_out(key: frozenset[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        folds_ = fitted[key][1]
        return tuple(np.concatenate([folds_[0][i], folds_[1][i]]) for i in (0, 1, 4))  # type: ignore[return-value]

    def first_round(name: str) -> None:
        key = frozenset() if name == "none" else frozenset({name})
        per_segment[name], per_track[name], by_channel = held_out(key)
        per_channel[name] = _channel_means(by_channel)
        fold_params[name] = tuple(f[2] for f in fitted[key][1])

    for name in names:
        fit_set(() if name == "none" else (name,))
        first_round(name)
        progress(f"{name:15s} held-out loss {_loss_text(per_segment[name].mean())}, track error after {horizon_s:g} s "
                 f"{_mean_track(per_track[name]):7.2f} m")
    # a hypothesis whose value both folds fit under what the diagnosis tells from the calm-water model's own error
    # (Effect.unresolved: a delay under a quarter step) is no candidate, and a note says why
    for name in [n for n in names if n != "none"]:
        reasons = [fx.EFFECTS[name].unresolved(found, dt) for found in fold_params[name]]
        if all(reasons):
            names.remove(name)
            notes.append(f"{name} is not a candidate: " + "; ".join(f"fold {k + 1}: {'; '.join(r)}"
                                                                     for k, r in enumerate(reasons)))
            progress(notes[-1])
    n_eff = effective_segments(len(per_segment["none"]), stride_s, horizon_s)

    def evidence_for(a: str, over: str) -> float:
        return log_evidence(n_eff, per_segment[a].mean(), per_segment[over].mean())

    def over_none(n: str) -> tuple[float, float]:
        """(evidence, share of the loss removed) of hypothesis n over the calm-water model, on the channels its
        extension alone moves (evidence_channels; all: the pooled loss)."""
        channels = evidence_channels(n)
        if not channels:
            return evidence_for(n, "none"), float(1.0 - per_segment[n].mean() / base.mean())
        with_, without = channel_loss(per_channel[n], channels), channel_loss(per_channel["none"], channels)
        if not (math.isfinite(with_) and math.isfinite(without) and without > 0.0):  # a diverged fit: no evidence
            return -math.inf, -math.inf
        return log_evidence(n_eff, with_, without), float(1.0 - with_ / without)

    def track_gain(track: np.ndarray, over: np.ndarray) -> float:
        before = _mean_track(over)
        return 1.0 - _mean_track(track) / before if before > 0 else float("nan")

    base = per_segment["none"]
    calm = CalmWaterFit(float(base.mean()), _mean_track(per_track["none"]), float(horizon_s))

    def evidence_table() -> tuple[Evidence, ...]:
        # a hypothesis whose fit diverged (non-finite held-out loss) ranks last, never first (NaN does not sort)
        ranked = sorted(names, key=lambda n: (not math.isfinite(per_segment[n].mean()), per_segment[n].mean()))
        best = ranked[0]
        scores = {n: over_none(n) for n in ranked}  # (evidence, share removed) over the calm-water model
        return tuple(Evidence(n, float(per_segment[n].mean()), scores[n][1], scores[n][0],
                              0.0 if n == best else evidence_for(best, n), fold_params[n], _mean_track(per_track[n]),
                              track_gain(per_track[n], per_track["none"]), _channels_text(n))
                     for n in ranked)

    def named(e: Evidence, confounded: tuple[str, ...]) -> str:
        track = (f"{e.track_gain_vs_none * 100:.0f} % of its held-out track error after {horizon_s:g} s"
                 if not math.isfinite(e.track_gain_vs_none) or e.track_gain_vs_none > 0 else
                 f"leaves its held-out track error after {horizon_s:g} s within {TRACK_NEUTRAL:.0%} "
                 f"({e.track_gain_vs_none * -100:+.1f} %: a sensor bias, it moves only the start's yaw rate)")
        text = (f"{e.hypothesis} removes {e.gain_vs_none * 100:.0f} % of the calm-water model's held-out "
                f"error{e.measured_on} (evidence {evidence_text(e.evidence_vs_none)}) and {track}")
        if confounded:
            text += f"; {', '.join(confounded)} explain(s) it almost as well: the data cannot tell them apart"
        return text

    def confounded_with(cause: str, named_causes: Sequence[str], table: Sequence[Evidence]) -> tuple[str, ...]:
        """The hypotheses (none and the named causes aside) that are causes themselves and that `cause` beats by
        less than EVIDENCE_CONFOUND: the data cannot tell them apart from it (in the table's order)."""
        return tuple(e.hypothesis for e in table if e.hypothesis not in ("none", *named_causes)
                     and e.evidence_vs_none >= EVIDENCE_CAUSE and evidence_for(cause, e.hypothesis) < EVIDENCE_CONFOUND)

    evidence = evidence_table()

    def is_strong(e: Evidence) -> bool:
        return e.hypothesis != "none" and e.evidence_vs_none >= EVIDENCE_CAUSE and e.gain_vs_none >= MIN_GAIN

    # the hypothesis of the lowest held-out loss; where it is not strong, one measured on the channels it alone moves
    # that is (evidence_channels: a compass offset that halves the position error while a term that bends every
    # channel a little leaves a lower pooled loss at little evidence)
    top = evidence[0]
    if not is_strong(top):
        top = next((e for e in evidence if evidence_channels(e.hypothesis) and is_strong(e)), top)
    cause, confounded, message = "none", (), "the calm-water model explains the held-out data within the noise"
    rejected = ""  # a candidate not named: the evidence of the loss but its extension does not lower the held-out
    #                track error, or evidence between EVIDENCE_CANDIDATE and EVIDENCE_CAUSE (the answer: inconclusive)
    strong = is_strong(top)
    # too much for a confident `none`: the best hypothesis by its evidence (EVIDENCE_CANDIDATE), else the first (the
    # lowest held-out loss) seen in the track (NONE_TRACK_GAIN); a model that fits by the NONE_LOSS test, so the
    # candidate is no cover for a model that does not
    by_evidence = (top.hypothesis != "none" and top.evidence_vs_none >= EVIDENCE_CANDIDATE
                   and top.gain_vs_none >= MIN_GAIN and lowers_track(top.track_gain_vs_none, (top.hypothesis,)))
    candidate = top if by_evidence else next(
        (e for e in evidence if e.hypothesis != "none" and e.evidence_vs_none > 0.0
         and math.isfinite(e.track_gain_vs_none) and e.track_gain_vs_none >= NONE_TRACK_GAIN), None)
    if strong and lowers_track(top.track_gain_vs_none, (top.hypothesis,)):
        cause = top.hypothesis
        confounded = confounded_with(cause, (cause,), evidence)
        message = named(top, confounded)
    elif strong:
        rejected = (f"{top.hypothesis} removes {top.gain_vs_none * 100:.0f} % of the held-out "
                    f"error{top.measured_on} (evidence {evidence_text(top.evidence_vs_none)}) but its extension "
                    f"{track_rule_failed((top.hypothesis,))} the held-out track error after "
                    f"{horizon_s:g} s ({calm.heldout_track_error_m:.3g} -> "
                    f"{top.heldout_track_error_m:.3g} m): not named")
        message = rejected
    elif candidate is not None and base.mean() <= NONE_LOSS:  # not enough to name, too much for a `none`
        top = candidate  # the candidate of the answer below
        track = (f" and {top.track_gain_vs_none * 100:.0f} % of the held-out track error after {horizon_s:g} s"
                 if math.isfinite(top.track_gain_vs_none) else "")
        allows = (f"< {EVIDENCE_CANDIDATE:g}" if by_evidence
                  else f"no hypothesis removing >= {NONE_TRACK_GAIN:.0%} of the track error")
        rejected = (f"{top.hypothesis} removes {top.gain_vs_none * 100:.0f} % of the held-out "
                    f"error{top.measured_on}{track} with evidence {evidence_text(top.evidence_vs_none)}: more than "
                    f"a `none` allows ({allows}), less than names a cause (>= {EVIDENCE_CAUSE:g})")
        message = rejected
    elif top.hypothesis != "none":
        message = (f"best hypothesis {top.hypothesis} removes {top.gain_vs_none * 100:.1f} % of the held-out "
                   f"error{top.measured_on} with evidence {evidence_text(top.evidence_vs_none)} (a cause needs >= "
                   f"{EVIDENCE_CAUSE:g} and >= {MIN_GAIN * 100:.0f} %): no cause named")
    # further causes, forward, each followed by the backward check that every chosen cause still earns its place
    # given the others (select_causes); the sets are fitted once, a set nested in a larger one refitted from it
    drops: tuple[str, ...] = ()
    added_raw: list[tuple[str, float, float, float, float]] = []
    chosen: list[str] = []
    further: Contribution | None = None
    further_reason = ""
    if cause != "none":
        selection = select_causes(cause, [n for n in names if n != "none" and n not in confounded], score, n_eff,
                                  max_causes)
        drops = selection.drop_reasons()
        for reason in drops:
            progress(reason)
        for name in names:  # the single hypotheses refitted from a larger set's fit (refit_nested)
            first_round(name)
        evidence = evidence_table()
        chosen = list(selection.causes)
        if not chosen:  # no cause earns its place given the others (by the track rule): not named
            rejected = f"{'; '.join(drops)}: no cause earns its place"
            cause, confounded, message = "none", (), rejected
        elif chosen[0] != cause or drops:
            cause = chosen[0]
            primary = next(e for e in evidence if e.hypothesis == cause)
            confounded = confounded_with(cause, chosen, evidence)
            message = named(primary, confounded)
        added_raw = [(c.cause, c.heldout_loss, c.evidence, c.gain, c.track_gain) for c in selection.contributions[1:]]
        further, further_reason = selection.further_candidate, selection.further_candidate_reason()
    current_loss = held_out(frozenset(chosen))[0] if chosen else base
    # model_mismatch: the calm-water model itself is wrong, so no environmental answer (nor `none`) can be trusted
    mismatch: list[str] = []
    if fit_mismatch:
        mismatch.append(f"the fit check failed ({fit_mismatch})")
    # the loss test of model_mismatch, on the best model: with the named causes, or with the candidate not named
    best_loss = per_segment[top.hypothesis] if rejected else current_loss
    best_model = top.hypothesis if rejected else "+".join(chosen) or "the calm-water model"
    loss_mismatch = best_loss.mean() > MISMATCH_LOSS and (best_loss.mean() > MISMATCH_SHARE * base.mean()
                                                          or best_loss.mean() > FIT_CEILING_LOSS)
    if rejected and (fit_mismatch or loss_mismatch):
        mismatch.append(rejected)
    if cause == "none" and not rejected and not loss_mismatch and base.mean() > NONE_LOSS:
        mismatch.append(f"no hypothesis explains the calm-water model's held-out loss of {base.mean():.3g} noise units "
                        f"(`none` needs <= {NONE_LOSS:g}: the model explains the data within the noise)")
    if loss_mismatch:
        mismatch.append(f"{best_model} leaves a held-out loss of {best_loss.mean():.3g} noise units "
                        f"(a model that fits leaves <= {MISMATCH_LOSS:g}, or <= {FIT_CEILING_LOSS:g} when its causes "
                        f"remove more than {MISMATCH_SHARE:.0%} of the calm-water model's)")
    best_environmental = cause if cause != "none" else ""
    if rejected and not mismatch:
        candidate_fit = fit_hypothesis(model, seg, top.hypothesis)
        return _inconclusive(
            Diagnosis(cause=INCONCLUSIVE, parameters={}, uncertainty={}, confounded_with=(), evidence=tuple(evidence),
                      fit=candidate_fit,
                      folds=(tuple(recordings[i].name for i in folds[0]), tuple(recordings[i].name for i in folds[1])),
                      message="", seconds=time.perf_counter() - started, notes=tuple(notes), additional_causes=(),
                      calm_water_fit=calm),
            top.hypothesis, physical_parameters(top.hypothesis, candidate_fit.terms),
            f"{rejected}; with it the calm-water model leaves a held-out loss of {best_loss.mean():.3g} noise units "
            f"(it fits by the loss test)", model, seg)
    # a further cause not named for want of evidence (reported, not in the extended model): its parameters fitted with
    # the named causes on all manoeuvres, before their own final fit (whose terms the rollout is left with)
    further_fit = fit_hypothesis(model, seg, [*chosen, further.cause]) if further is not None and not mismatch else None
    # the named causes refitted on all manoeuvres; a parameter outside its effect's physical range (the record's:
    # a wind beyond what `replay simulate` admits) is the model's error absorbed by the cause, not a cause
    final = fit_hypothesis(model, seg, chosen) if chosen and not mismatch else None
    if final is not None:
        mismatch.extend(reason for name in chosen
                        for reason in fx.EFFECTS[name].outside_range(physical_parameters(name, final.terms)))
    if mismatch:
        final = None
        message = (f"{MODEL_MISMATCH}: the calm-water model does not fit these bags (held-out loss "
                   f"{calm.heldout_loss:.3g} "
                   f"noise units, track error {calm.heldout_track_error_m:.3g} m after {horizon_s:g} s before any "
                   f"hypothesis): {'; '.join(mismatch)}"
                   + (f"; the best environmental cause would be {best_environmental}" if best_environmental else "")
                   + f": {REMEDY}")
        cause, confounded, chosen, added_raw, further_fit = MODEL_MISMATCH, (), [], [], None
    progress(f"calm-water model before any hypothesis: held-out loss {calm.heldout_loss:.3g} noise units, track "
             f"error {calm.heldout_track_error_m:.3g} m after {horizon_s:g} s")
    final = final if final is not None else fit_hypothesis(model, seg, "none")
    parameters = physical_parameters(cause, final.terms)
    uncertainty = _physical_uncertainty(cause, final)
    added = tuple(AddedCause(n, physical_parameters(n, final.terms), _physical_uncertainty(n, final), loss_, ev, g, tg)
                  for n, loss_, ev, g, tg in added_raw)
    if added:
        message += "; further: " + ", ".join(f"{a.cause} (removes {a.gain * 100:.0f} % more, evidence {a.evidence:.1f})"
                                            for a in added)
    if drops and cause != MODEL_MISMATCH:
        message += "; " + "; ".join(drops)
    candidate = None
    if further is not None and further_fit is not None:
        candidate = AddedCause(further.cause, physical_parameters(further.cause, further_fit.terms),
                               _physical_uncertainty(further.cause, further_fit), further.heldout_loss,
                               further.evidence, further.gain, further.track_gain)
        message += "; " + further_reason
    return Diagnosis(cause=cause, parameters=parameters, uncertainty=uncertainty, confounded_with=confounded,
                     evidence=tuple(evidence), fit=final,
                     folds=(tuple(recordings[i].name for i in folds[0]), tuple(recordings[i].name for i in folds[1])),
                     message=message, seconds=time.perf_counter() - started, notes=tuple(notes),
                     additional_causes=added, calm_water_fit=calm, mismatch_reasons=tuple(mismatch),
                     best_environmental_cause=best_environmental, dropped_causes=drops, further_candidate=candidate,
                     further_candidate_reason=further_reason if candidate is not None else "")


def withdraw_causes(diagnosis: Diagnosis, reason: str, model: GreyBoxRollout | KernelRollout,
                    seg: Segments) -> Diagnosis:
    """The diagnosis with its named causes withdrawn for `reason` (their extension made the held-out prediction
    worse, measure_gain): `inconclusive` with the withdrawn causes as the candidate. A named cause passed the
    model_mismatch tests (fit check, loss), so the calm-water model fits: identifying the boat again is not the
    remedy. The calm-water model is refitted (no terms) on all segments."""
    candidate = "+".join(diagnosis.hypotheses)
    parameters = dict(diagnosis.parameters)
    for added in diagnosis.additional_causes:
        parameters.update(added.parameters)
    return _inconclusive(dataclasses.replace(diagnosis, uncertainty={}, confounded_with=(), additional_causes=(),
                                             further_candidate=None, further_candidate_reason=""),
                         candidate, parameters, reason, model, seg)


def _inconclusive(diagnosis: Diagnosis, candidate: str, parameters: dict[str, float], reason: str,
                  model: GreyBoxRollout | KernelRollout, seg: Segments) -> Diagnosis:
    """`diagnosis` as the answer `inconclusive`: what was found (candidate, its parameters) and why it is not named."""
    calm = diagnosis.calm_water_fit
    before = (f" (calm-water model: held-out loss {calm.heldout_loss:.3g} noise units, track error "
              f"{calm.heldout_track_error_m:.3g} m after {calm.horizon_s:g} s)") if calm is not None else ""
    found = ", ".join(f"{k} {v:.3g}" for k, v in parameters.items())
    message = (f"{INCONCLUSIVE}: {candidate} ({found}) explains the held-out loss but is not named: {reason}{before}; "
               f"{INCONCLUSIVE_REMEDY}")
    return dataclasses.replace(diagnosis, cause=INCONCLUSIVE, parameters={}, uncertainty={}, message=message,
                               fit=fit_hypothesis(model, seg, "none"), candidate=candidate,
                               candidate_parameters=parameters, inconclusive_reasons=(reason,))


def _folds(recordings: Sequence[Recording]) -> tuple[list[int], list[int]]:
    """Two folds by manoeuvre, alternating in order of the mean turn command so both folds turn both ways."""
    order = sorted(range(len(recordings)),
                   key=lambda i: float(np.nanmean(
                       recordings[i].actuator_layout.steering_signal(recordings[i].controls))))
    return order[0::2], order[1::2]


def _physical_uncertainty(cause: str, fit: Fit) -> dict[str, float]:
    """Standard errors, keyed like physical_parameters (first-order propagation for vectors); {} for `none`."""
    effect = fx.EFFECTS.get(cause)
    return {} if effect is None else effect.readout.uncertainty(fit.terms, fit.std)


# ---- what the calm-water model gets wrong, in a naval architect's terms -------------------------------

def discrepancy(model: GreyBoxRollout | KernelRollout, seg: Segments,
                recordings: Sequence[Recording]) -> dict[str, object]:
    """Structure of the calm-water model's segment errors: track drift, asymmetry, dependence on heading.

    - track drift: the end-of-segment position error divided by the horizon, averaged as a vector
      (a current shows as a steady drift toward a fixed direction);
    - port/starboard asymmetry: mean yaw-rate error (measured - predicted) in port and starboard turns
      (a rudder offset turns one way better than the other);
    - heading dependence: the first harmonic in the heading of the along/cross-track error rates
      (heading-dependent loads such as wind and waves, or a misaligned compass).
    """
    set_terms(model, {})
    with torch.no_grad():
        predicted = model(seg.state, seg.controls, seg.reference)[0].numpy()  # (B, H, 6)
    target = seg.target.numpy()
    valid = seg.weight.numpy()[:, -1, 3] > 0
    horizon = target.shape[1] * recordings[0].dt
    err = (target[:, -1, 3:5] - predicted[:, -1, 3:5]) / horizon  # (B, 2) m/s, measured minus predicted
    rate = err[valid]
    drift = rate.mean(axis=0) if len(rate) else np.zeros(2)
    yaw_err = (target[:, :, 2] - predicted[:, :, 2]).mean(axis=1)
    side = np.sign(recordings[0].actuator_layout.steering_signal(seg.controls.numpy()).mean(axis=1))  # (B,)
    psi0 = seg.state[:, 3].numpy()[valid]
    along = rate[:, 0] * np.cos(psi0) + rate[:, 1] * np.sin(psi0)
    cross = -rate[:, 0] * np.sin(psi0) + rate[:, 1] * np.cos(psi0)
    design = np.column_stack([np.ones_like(psi0), np.cos(psi0), np.sin(psi0)])

    def harmonic(values: np.ndarray) -> dict[str, float]:
        if len(values) < 4:
            return {"mean_mps": float("nan"), "amplitude_mps": float("nan"), "phase_deg": float("nan")}
        (mean, a, b), *_ = np.linalg.lstsq(design, values, rcond=None)
        return {"mean_mps": float(mean), "amplitude_mps": float(math.hypot(a, b)),
                "phase_deg": compass_deg(a, b)}

    return {
        "track_drift_speed_mps": float(math.hypot(*drift)),
        "track_drift_direction_to_deg": compass_deg(drift[0], drift[1]),
        "yaw_rate_error_starboard_turns_deg_s": (float(np.degrees(yaw_err[side > 0].mean())) if (side > 0).any()
                                                 else None),
        "yaw_rate_error_port_turns_deg_s": float(np.degrees(yaw_err[side < 0].mean())) if (side < 0).any() else None,
        "along_track_error_rate_vs_heading": harmonic(along),
        "cross_track_error_rate_vs_heading": harmonic(cross),
        "segments": int(len(seg)),
        "segment_horizon_s": horizon,
    }


# ---- the extended model and its gain on held-out manoeuvres --------------------------------------------

def extended_rollout(vessel: Vessel, dt: float, terms: dict[str, Sequence[float]], substeps: int = 2) -> GreyBoxRollout:
    rollout = GreyBoxRollout(vessel, dt=dt, substeps=substeps)
    set_terms(rollout, terms)
    return rollout


def measure_gain(recordings: Sequence[Recording], vessel: Vessel, diagnosis: Diagnosis, *,
                 horizons_s: Sequence[float] = (10.0, 30.0, 60.0), stride_s: float = 5.0,
                 horizon_s: float = 20.0, segment_stride_s: float = 5.0, segments: Segments | None = None,
                 rollout: KernelRollout | None = None) -> dict[str, object]:
    """Every evaluation metric of the calm-water and the extended model on manoeuvres held out from the fit.

    Each fold's manoeuvres are predicted by the extension fitted on the other fold only. segments / rollout:
    make_segments(recordings, horizon_s, segment_stride_s) and compiled_rollout(vessel, dt) when the caller has
    them already (built here otherwise).
    """
    from usv_predictor.analysis import evaluation
    from usv_predictor.models.greybox import GreyBoxPredictor, greybox_metadata

    dt = recordings[0].dt
    base_rollout = GreyBoxRollout(vessel, dt=dt, substeps=2)
    baseline = GreyBoxPredictor(base_rollout, {**greybox_metadata(vessel, base_rollout), "model_id": "calm-water"})
    names = [r.name for r in recordings]
    before, after = [], []
    seg = segments if segments is not None else make_segments(recordings, horizon_s, segment_stride_s)
    fitter = rollout if rollout is not None else compiled_rollout(vessel, dt)
    for fit_fold, test_fold in ((0, 1), (1, 0)):
        fit_names, test_names = diagnosis.folds[fit_fold], diagnosis.folds[test_fold]
        fit_idx = [names.index(n) for n in fit_names]
        held_out = [recordings[names.index(n)] for n in test_names]
        fit = fit_hypothesis(fitter, seg.select(np.isin(seg.recording, fit_idx)), diagnosis.hypotheses)
        extended = extended_rollout(vessel, dt, fit.terms)
        predictor = GreyBoxPredictor(extended, {**greybox_metadata(vessel, extended), "model_id": "extended"})
        before += evaluation.evaluate(baseline, held_out, horizons_s=horizons_s, stride_s=stride_s).recordings
        after += evaluation.evaluate(predictor, held_out, horizons_s=horizons_s, stride_s=stride_s).recordings
    base_summary = evaluation.summarise(before, horizons_s)
    ext_summary = evaluation.summarise(after, horizons_s)
    gain = {}
    for key, b in base_summary.items():
        a = ext_summary.get(key)
        if key in evaluation.COUNT_KEYS or a is None or b is None or not b:
            continue
        gain[key] = (b - a) / abs(b)  # relative improvement: + is better (every summary metric is an error)
    return {"baseline": base_summary, "extended": ext_summary, "relative_improvement": gain,
            "per_recording": {"baseline": [e.to_json() for e in before], "extended": [e.to_json() for e in after]}}


def export_extended(path, vessel: Vessel, diagnosis: Diagnosis, dt: float, *, data_digest: str = "",
                    description: Vessel | None = None):
    """The extended grey box (calm-water model + the named cause, refitted on all manoeuvres) as an artifact, with
    `description` (the vessel file the calm-water model came from; None: `vessel` itself) embedded."""
    from usv_predictor.models.artifact import export_module
    from usv_predictor.models.greybox import greybox_metadata

    rollout = extended_rollout(vessel, dt, diagnosis.fit.terms)
    meta = greybox_metadata(vessel, rollout, model_type=f"greybox+{diagnosis.cause}", training_data_sha256=data_digest,
                            training={"method": "diagnosis (usv_predictor.analysis.diagnosis)",
                                      "cause": diagnosis.cause,
                                      "parameters": diagnosis.parameters,
                                      "additional_causes": [a.cause for a in diagnosis.additional_causes]})
    return export_module(path, rollout, meta, vessel=description or vessel)
