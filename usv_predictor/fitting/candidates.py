"""Is the chosen identification the best the data allow? Every structure x prior the data can take, scored by the
same leave-one-manoeuvre-out cross-validation as the chosen one (usv_predictor.fitting.identification, step 7).

`replay identify` fits the structure(s) and prior it is told. This module refits the hull forces it already has
(ForceData: no second smoother pass, only linear regressions) under every other structure and prior policy and warns
when the chosen one scores far worse than another: a user who picked `--prior ridge` where `--prior fix`
cross-validates ten times better must hear it before trusting the model.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from usv_predictor.errors import UsvPredictorError
from usv_predictor.fitting import small_craft_identification as small_craft
from usv_predictor.fitting.identification import (
    PRIORS,
    STRUCTURES_OF,
    ForceData,
    IdentificationResult,
    cross_validate,
    fit_hull,
)
from usv_predictor.physics.vessel import Vessel

FAR_WORSE = 3.0  # (-) the chosen CV score (normalised force MSE) above this times the best candidate's: a warning


@dataclass(frozen=True)
class Candidate:
    structure: str
    prior: str
    score: float | None  # mean normalised MSE of the held-out hull forces; None: refused (not identifiable)
    chosen: bool

    def to_json(self) -> dict:
        return {"structure": self.structure, "prior": self.prior, "cv_score": self.score, "chosen": self.chosen}


def candidate_scores(vessel: Vessel, data: Sequence[ForceData], result: IdentificationResult) -> list[Candidate]:
    """Every structure x prior on the same hull forces (the chosen one from `result`, the others refitted)."""
    chosen = (result.structure, result.fit.prior_policy)
    computed = {cv.structure: cv.score for cv in result.cross_validation}
    hull_model = vessel.hull_model_name

    def refit_score(structure: str, prior: str) -> float:  # the hull model's own regression and cross-validation
        if hull_model == "small_craft":
            return small_craft.scale_anchored_fit(vessel, data, structure, prior)[1].score  # as identify fits it
        return cross_validate(vessel, data, fit_hull(vessel, data, structure, prior, u0=result.fit.u0)).score

    out = []
    for structure in STRUCTURES_OF[hull_model]:
        for prior in PRIORS:
            if (structure, prior) == chosen or (prior == chosen[1] and structure in computed):
                score: float | None = computed[structure]
            else:
                try:
                    score = refit_score(structure, prior)
                except (UsvPredictorError, np.linalg.LinAlgError):  # prior none refuses what the data cannot
                    score = None                                   # determine; a singular design has no score
                if score is not None and not math.isfinite(score):
                    score = None
            out.append(Candidate(structure, prior, score, (structure, prior) == chosen))
    return out


def cv_warning(candidates: Sequence[Candidate]) -> str | None:
    """The warning when the chosen candidate's CV score is more than FAR_WORSE times the best one's (None else)."""
    chosen = next((c for c in candidates if c.chosen), None)
    scored = [c for c in candidates if c.score is not None and not c.chosen]
    if chosen is None or chosen.score is None or not scored:
        return None
    best = min(scored, key=lambda c: c.score)
    if not chosen.score > FAR_WORSE * best.score:
        return None
    return (f"--structure {chosen.structure} --prior {chosen.prior} cross-validates {chosen.score / best.score:.1f} "
            f"times worse than --structure {best.structure} --prior {best.prior} (held-out force error "
            f"{chosen.score:.3g} vs {best.score:.3g}, normalised MSE): identify with --structure {best.structure} "
            f"--prior {best.prior} unless you know better")
