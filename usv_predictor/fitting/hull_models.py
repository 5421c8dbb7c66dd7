"""The hull models identification knows, one record each (HULL_FITS, keyed by a vessel's `hull_model`,
physics/hulls.py): how a vessel of that hull is identified, its hull forces at given coefficients, and the trial that
would determine each of its coefficients.

    mmg          fitting/identification.identify (with the interaction search of fitting/interaction.py),
                 identification.hull_forces, identification.WOULD_DETERMINE
    small_craft  fitting/small_craft_identification.identify_small_craft, its hull_forces and WOULD_DETERMINE

This module sits above the three it names, so they never import one another in a circle: identify, hull_forces,
would_determine and trials_text here are the entry points that pick a vessel's hull model.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from types import MappingProxyType
from typing import Any

import numpy as np

from usv_predictor.data.recording import Recording
from usv_predictor.errors import ConfigError
from usv_predictor.fitting import identification, small_craft_identification
from usv_predictor.fitting.identification import IdentificationResult
from usv_predictor.fitting.interaction import identify_interaction
from usv_predictor.physics.vessel import Vessel


@dataclass(frozen=True)
class HullModelFit:
    identify: Callable[..., IdentificationResult]  # (vessel, recordings, **options) -> the identified vessel and fit
    hull_forces: Callable[..., np.ndarray]  # (vessel, values, nu (T, 3), u0 m/s, names) -> (T, 3) [X, Y, N] N, N, N m
    would_determine: Mapping[str, str]  # coefficient -> the trial that would determine it


def _identify_mmg(vessel: Vessel, recordings: Sequence[Recording], **options: Any) -> IdentificationResult:
    """identification.identify, searching the interaction factors with fitting/interaction.identify_interaction."""
    return identification.identify(vessel, recordings, search_interaction=identify_interaction, **options)


def _identify_small_craft(vessel: Vessel, recordings: Sequence[Recording], *, interaction: str = "fix",
                          **options: Any) -> IdentificationResult:
    """small_craft_identification.identify_small_craft; `interaction` (rudder_propeller's factors) has no meaning
    for a twin-thruster hull and is ignored; the result's prior is the vessel file as given."""
    return replace(small_craft_identification.identify_small_craft(vessel, recordings, **options), prior=vessel)


def _small_craft_forces(vessel: Vessel, values: Mapping[str, float], nu: np.ndarray, u0: float,
                        names: Sequence[str] | None = None) -> np.ndarray:
    """small_craft_identification.hull_forces (no reference speed u0: its terms are dimensional)."""
    return small_craft_identification.hull_forces(vessel, values, nu, names)


HULL_FITS: Mapping[str, HullModelFit] = MappingProxyType({
    "mmg": HullModelFit(_identify_mmg, identification.hull_forces, identification.WOULD_DETERMINE),
    "small_craft": HullModelFit(_identify_small_craft, _small_craft_forces,
                                small_craft_identification.WOULD_DETERMINE),
})


def hull_fit(hull_model: str) -> HullModelFit:
    """The record of `hull_model`; ConfigError naming the known ones when identification has none for it."""
    try:
        return HULL_FITS[hull_model]
    except KeyError:
        raise ConfigError(f"hull model {hull_model!r} cannot be identified; identification knows "
                          f"{', '.join(HULL_FITS)}") from None


def identify(vessel: Vessel, recordings: Sequence[Recording], *, output_error: bool = False,
             **options: Any) -> IdentificationResult:
    """Identify `vessel`'s hull from `recordings` by its hull model's record (options: those of
    identification.identify, structure, prior, smoother, rel_ci_limit, data, interaction, progress); output_error:
    then the output-error (multiple-shooting) fit of the whole calm-water model and the stability check over the
    envelope (fitting/output_error.refine), kept when it predicts held-out manoeuvres better."""
    result = hull_fit(vessel.hull_model_name).identify(vessel, recordings, **options)
    if not output_error:
        return result
    from usv_predictor.fitting.output_error import refine

    return refine(result, recordings, progress=options.get("progress"))


def hull_forces(vessel: Vessel, values: Mapping[str, float], nu: np.ndarray, u0: float,
                names: Sequence[str] | None = None) -> np.ndarray:
    """(T, 3) hull [X, Y, N] (N, N, N m) of coefficient `values` at velocities nu (T, 3), by the vessel's hull model
    (u0: the MMG terms' reference speed, m/s)."""
    return hull_fit(vessel.hull_model_name).hull_forces(vessel, values, nu, u0, names)


def would_determine(name: str, hull_model: str = "mmg") -> str:
    """The trial that would determine coefficient `name` of `hull_model` (identification.would_determine)."""
    return identification.would_determine(name, hull_fit(hull_model).would_determine)


def trials_text(names: Sequence[str], hull_model: str = "mmg") -> str:
    """The coefficients grouped by the trial that would determine them (identification.trials_text)."""
    return identification.trials_text(names, hull_fit(hull_model).would_determine)
