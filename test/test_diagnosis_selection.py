"""The selection of causes (usv_predictor.analysis.diagnosis.select_causes), driven by tables of held-out scores.

Each table holds the held-out loss (noise units) and track error (m) of the calm-water model with a set of causes, as
diagnose fits them; a set the table does not hold is a KeyError, so a test also proves which sets the selection asks
for (every one of them is fitted once, in diagnose)."""
from __future__ import annotations

import math

import pytest

from usv_predictor.analysis.diagnosis import (EVIDENCE_CANDIDATE, EVIDENCE_CAUSE, MIN_GAIN, HeldOut, contribution,
                                              log_evidence, select_causes)

# boat 20 of the unknown-boat benchmark (seed 2026; docs/results/unknown_boats.md): a 5.4 m/s wind. The first round
# ranked wave_drift
# first (held-out loss 2.94 of the calm-water model's 4.80) on a poor fit of the wind alone (3.20); wave_drift+wind
# left 1.12, and the wind alone, fitted from that pair's wind, leaves about as little (the table's 1.15).
N_EFF = 20.6  # effective segments of that diagnosis: 5.1 = n_eff / 2 * ln(4.80 / 2.94)
BOAT_20 = {
    (): HeldOut(4.80, 1.03),
    ("wave_drift",): HeldOut(2.94, 0.86),
    ("wind",): HeldOut(1.15, 0.58),
    ("current",): HeldOut(4.93, 1.37),
    ("rudder_offset",): HeldOut(3.70, 0.91),
    ("wave_drift", "wind"): HeldOut(1.12, 0.57),
    ("current", "wave_drift"): HeldOut(3.52, 1.23),
    ("rudder_offset", "wave_drift"): HeldOut(2.12, 0.74),
    ("current", "wind"): HeldOut(1.14, 0.60),
    ("rudder_offset", "wind"): HeldOut(1.13, 0.58),
}


def table(scores: dict[tuple[str, ...], HeldOut], asked: list[frozenset[str]] | None = None):
    by_set = {frozenset(k): v for k, v in scores.items()}

    def score(causes: tuple[str, ...]) -> HeldOut:
        if asked is not None:
            asked.append(frozenset(causes))
        return by_set[frozenset(causes)]

    return score


CANDIDATES = ("wave_drift", "current", "wind", "rudder_offset")


def test_a_first_cause_that_a_later_one_makes_redundant_is_dropped():
    """Boat 20: forward, the wind earns its place given wave_drift (evidence 9.9); backward, wave_drift does not given
    the wind (0.3 < EVIDENCE_CAUSE): it is dropped, the wind alone is named, and no other cause joins it."""
    asked: list[frozenset[str]] = []
    selection = select_causes("wave_drift", CANDIDATES, table(BOAT_20, asked), N_EFF, max_causes=2)
    assert selection.causes == ("wind",)
    assert [d.cause for d in selection.dropped] == ["wave_drift"]
    drop = selection.dropped[0]
    assert drop.given == ("wind",)
    assert drop.evidence == pytest.approx(log_evidence(N_EFF, 1.12, 1.15))
    assert drop.evidence < EVIDENCE_CAUSE
    assert not drop.earns_place
    assert selection.drop_reasons()[0].startswith("wave_drift dropped: given wind it adds evidence 0.3 (removes 3 % ")
    (wind,) = selection.contributions  # the wind over the calm-water model
    assert wind.given == ()
    assert wind.earns_place
    assert wind.evidence == pytest.approx(log_evidence(N_EFF, 1.15, 4.80))
    # after the drop the wind may take another partner, but none earns its place (and wave_drift is not tried again)
    assert frozenset({"current", "wind"}) in asked
    assert frozenset({"rudder_offset", "wind"}) in asked


def test_without_the_backward_step_the_first_cause_would_stay():
    """What the backward step changes: the forward step alone keeps wave_drift (the answer of the benchmark run before
    the backward step)."""
    forward = contribution("wind", ("wave_drift",), table(BOAT_20), N_EFF)
    assert forward.earns_place
    assert forward.evidence == pytest.approx(log_evidence(N_EFF, 1.12, 2.94))
    selection = select_causes("wave_drift", CANDIDATES, table(BOAT_20), N_EFF, max_causes=1)
    assert selection.causes == ("wave_drift",)
    assert selection.dropped == ()


def test_two_causes_that_each_earn_their_place_are_both_named_the_stronger_first():
    """A current and a rudder offset, each needed given the other: both kept; the one that explains most alone comes
    first even when the first round ranked the other first."""
    scores = {(): HeldOut(10.0, 20.0), ("current",): HeldOut(6.0, 8.0), ("rudder_offset",): HeldOut(5.0, 15.0),
              ("wind",): HeldOut(9.0, 19.0), ("current", "rudder_offset"): HeldOut(1.0, 2.0),
              ("current", "wind"): HeldOut(5.9, 7.9)}
    selection = select_causes("current", ("current", "rudder_offset", "wind"), table(scores), 20.0)
    assert selection.causes == ("rudder_offset", "current")
    assert selection.dropped == ()
    kept = {c.cause: c for c in selection.contributions}
    assert kept["rudder_offset"].given == ("current",)
    assert kept["current"].given == ("rudder_offset",)
    assert kept["current"].evidence == pytest.approx(10.0 * math.log(5.0))
    assert all(c.earns_place for c in selection.contributions)


def test_drops_go_weakest_first_and_the_rest_is_checked_again():
    """Three causes allowed: current, then wind, then rudder_offset are added; given the other two, current adds
    nothing (dropped); given rudder_offset alone, wind no longer earns its place either (dropped next); the rudder
    offset alone stays, and no dropped cause is tried again."""
    scores = {(): HeldOut(10.0), ("current",): HeldOut(5.0), ("wind",): HeldOut(6.0), ("rudder_offset",): HeldOut(1.7),
              ("current", "wind"): HeldOut(2.0), ("current", "rudder_offset"): HeldOut(2.5),
              ("current", "rudder_offset", "wind"): HeldOut(1.0), ("rudder_offset", "wind"): HeldOut(1.05),
              ("current", "yaw_rate_bias"): HeldOut(4.9),
              ("rudder_offset", "yaw_rate_bias"): HeldOut(1.65), ("current", "wind", "yaw_rate_bias"): HeldOut(1.9)}
    asked: list[frozenset[str]] = []
    selection = select_causes("current", ("current", "wind", "rudder_offset", "yaw_rate_bias"), table(scores, asked),
                              20.0, max_causes=3)
    assert selection.causes == ("rudder_offset",)
    assert [(d.cause, d.given) for d in selection.dropped] == [("current", ("wind", "rudder_offset")),
                                                                ("wind", ("rudder_offset",))]
    assert selection.dropped[1].evidence == pytest.approx(10.0 * math.log(1.7 / 1.05))
    assert selection.dropped[1].evidence < EVIDENCE_CAUSE
    # the wind went before the next forward step (which would have tried it with the rudder offset and the yaw-rate
    # bias), and the yaw-rate bias was tried with the rudder offset alone
    assert frozenset({"rudder_offset", "yaw_rate_bias"}) in asked
    assert frozenset({"rudder_offset", "wind", "yaw_rate_bias"}) not in asked


def test_a_cause_whose_share_is_too_small_or_that_worsens_the_track_does_not_earn_its_place():
    """The rule has three parts: the evidence, the share of the loss (MIN_GAIN) and a lower track error."""
    n_eff = 4000.0  # so many segments that a 2 % lower loss is strong evidence
    scores = {(): HeldOut(10.0, 5.0), ("current",): HeldOut(10.0 * (1 - MIN_GAIN / 2), 4.0),
              ("wind",): HeldOut(5.0, 6.0), ("rudder_offset",): HeldOut(5.0, float("nan"))}
    small = contribution("current", (), table(scores), n_eff)
    assert small.evidence >= EVIDENCE_CAUSE
    assert small.gain < MIN_GAIN
    assert not small.earns_place
    worse_track = contribution("wind", (), table(scores), n_eff)
    assert worse_track.evidence >= EVIDENCE_CAUSE
    assert worse_track.track_gain < 0
    assert not worse_track.earns_place
    no_gnss = contribution("rudder_offset", (), table(scores), n_eff)  # no track to judge by: loss and evidence decide
    assert math.isnan(no_gnss.track_gain)
    assert no_gnss.earns_place


def test_a_diverged_fit_is_never_added():
    scores = {(): HeldOut(10.0), ("current",): HeldOut(2.0), ("wind",): HeldOut(9.0),
              ("current", "wind"): HeldOut(math.inf)}
    selection = select_causes("current", ("current", "wind"), table(scores), 20.0)
    assert selection.causes == ("current",)
    assert selection.dropped == ()
    assert not contribution("wind", ("current",), table(scores), 20.0).earns_place


# the shipped Otter sea trial (bags/otter/sea_trial: current 0.2 m/s, wind 4.5 m/s and 0.25 m waves at once),
# diagnosed against the preset (`replay diagnose bags/otter/sea_trial --vessel otter`): 80 held-out
# segments of 10 s every 2.5 s; wave_drift named (the wind confounded with it, so not a further candidate)
OTTER_N_EFF = 20.0  # 80 * 2.5 / 10
OTTER_SEA_TRIAL = {
    (): HeldOut(136.882, 2.49), ("wave_drift",): HeldOut(31.767, 2.21), ("current",): HeldOut(56.197, 2.64),
    ("yaw_rate_bias",): HeldOut(137.139, 2.49), ("resistance",): HeldOut(126.209, 2.50),
    ("current", "wave_drift"): HeldOut(19.375, 0.76), ("wave_drift", "yaw_rate_bias"): HeldOut(31.777, 2.21),
    ("resistance", "wave_drift"): HeldOut(32.119, 2.21),
}


def test_a_further_cause_short_of_evidence_alone_is_reported_not_named():
    """The Otter sea trial's current: given wave_drift it removes 39 % of the held-out loss and 66 % of the track
    error, evidence 4.94 (< 5): not added, but reported as the further candidate, with why; with half the segments
    (evidence 2.5 < EVIDENCE_CANDIDATE) it is not reported, and with one cause allowed it is never tried."""
    candidates = ("wave_drift", "current", "yaw_rate_bias", "resistance")
    selection = select_causes("wave_drift", candidates, table(OTTER_SEA_TRIAL), OTTER_N_EFF)
    assert selection.causes == ("wave_drift",)
    assert selection.dropped == ()
    further = selection.further_candidate
    assert further is selection.not_added
    assert further.cause == "current"
    assert further.given == ("wave_drift",)
    assert further.evidence == pytest.approx(log_evidence(OTTER_N_EFF, 19.375, 31.767))
    assert EVIDENCE_CANDIDATE <= further.evidence < EVIDENCE_CAUSE
    assert not further.earns_place
    assert further.gain == pytest.approx(1 - 19.375 / 31.767)
    assert further.track_gain == pytest.approx(1 - 0.76 / 2.21)
    assert selection.further_candidate_reason() == (
        "current not named as a further cause: given wave_drift it adds evidence 4.9 (removes 39 % of the held-out "
        "loss, 66 % of the track error); a cause needs evidence >= 5, >= 5 % and a lower track error")
    few = select_causes("wave_drift", candidates, table(OTTER_SEA_TRIAL), OTTER_N_EFF / 2)
    assert few.not_added.cause == "current"
    assert few.not_added.evidence < EVIDENCE_CANDIDATE
    assert few.further_candidate is None
    assert few.further_candidate_reason() == ""
    one = select_causes("wave_drift", candidates, table(OTTER_SEA_TRIAL), OTTER_N_EFF, max_causes=1)
    assert one.not_added is None
    assert one.further_candidate is None
    # short of the share or of the track, evidence alone is not what is missing: no further candidate either
    worse_track = {**OTTER_SEA_TRIAL, ("current", "wave_drift"): HeldOut(19.375, 2.30)}
    assert select_causes("wave_drift", candidates, table(worse_track), OTTER_N_EFF).further_candidate is None


def test_a_further_cause_that_is_named_is_no_candidate():
    """With the evidence (n_eff 25: 6.2 >= 5) the current is added; two causes allowed, the forward step ends there
    and no further candidate is reported beside the named further cause."""
    candidates = ("wave_drift", "current")
    selection = select_causes("wave_drift", candidates, table(OTTER_SEA_TRIAL), 25.0)
    assert selection.causes == ("wave_drift", "current")
    assert selection.further_candidate is None


# boat 42 of the rudder_only suite (seed 2026): a -2.83 deg compass offset. Its extension predicts u, v, r and psi as
# the calm-water model does (test_effects.py) and removes 57 % of the position channels' held-out loss, 3.4 % of the
# pooled one; per channel [u, v, r, x_n, y_e, psi] in noise units
CALM_CHANNELS = (4.35, 4.35, 4.35, 0.55, 0.55, 4.35)
OFFSET_CHANNELS = (4.35, 4.35, 4.35, 0.237, 0.237, 4.35)
BOAT_42 = {
    (): HeldOut(sum(CALM_CHANNELS) / 6, 1.24, CALM_CHANNELS),
    ("heading_offset",): HeldOut(sum(OFFSET_CHANNELS) / 6, 0.73, OFFSET_CHANNELS),
    ("current",): HeldOut(3.05, 1.20, (4.3, 4.3, 4.3, 0.55, 0.55, 4.3)),
    ("current", "heading_offset"): HeldOut(2.95, 0.72, (4.3, 4.3, 4.3, 0.237, 0.237, 4.3)),
}


def test_a_compass_offset_is_measured_on_the_positions_it_alone_moves():
    """Over the calm-water model the offset's evidence is that of the two position channels (Effect.channels: the
    others' likelihood is the same with and without it), 8.8 where the pooled loss gives 0.36; given another cause,
    whose terms the heading turns (a current's body components), the pooled loss again."""
    n_eff = 21.0
    alone = contribution("heading_offset", (), table(BOAT_42), n_eff)
    assert alone.evidence == pytest.approx(log_evidence(n_eff, 0.237, 0.55))
    assert alone.evidence == pytest.approx(8.84, abs=0.01)
    assert alone.gain == pytest.approx(1.0 - 0.237 / 0.55)
    assert alone.earns_place
    pooled = log_evidence(n_eff, BOAT_42[("heading_offset",)].loss, BOAT_42[()].loss)
    assert pooled == pytest.approx(0.36, abs=0.01) and pooled < EVIDENCE_CANDIDATE
    given = contribution("heading_offset", ("current",), table(BOAT_42), n_eff)
    assert given.evidence == pytest.approx(log_evidence(n_eff, 2.95, 3.05))
    assert not given.earns_place
    # a cause measured on every channel keeps the pooled loss, channel losses or not
    current = contribution("current", (), table(BOAT_42), n_eff)
    assert current.evidence == pytest.approx(log_evidence(n_eff, 3.05, BOAT_42[()].loss))
    selection = select_causes("heading_offset", ("current",), table(BOAT_42), n_eff)
    assert selection.causes == ("heading_offset",)
    assert selection.not_added is not None and selection.not_added.cause == "current"
