"""Model families: one record per kind of motion model the package makes, runs and reads.

Every family writes the same artifact (models/artifact.py: one TorchScript rollout + metadata) and the
artifact's `model_type` names its family; a diagnosis extension is written as "<family>+<causes>"
(e.g. "greybox+current"). The record says where the family's rollout lives, which command makes it and
whether it carries the physics (its identified MMG hull can be the calm-water model of `replay diagnose`).
Loading a model checks its family (a file of another program is refused by name); adding a family = one
file in models/ + one record here (+ its fitting in fitting/).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from usv_predictor.errors import ModelError


@dataclass(frozen=True)
class ModelFamily:
    name: str  # the artifact's model_type (before any "+<causes>")
    module: str  # where its rollout module is defined
    made_by: str  # the command that makes it
    physics: bool  # it is the MMG grey box: its hull can be the calm-water model of a diagnosis
    description: str


MODEL_FAMILIES: Mapping[str, ModelFamily] = MappingProxyType({
    "dnn": ModelFamily("dnn", "usv_predictor.models.dnn", "replay train", False,
                       "seed 000's feed-forward network, closed-loop rollout of an ensemble"),
    "greybox": ModelFamily("greybox", "usv_predictor.models.greybox", "replay identify / replay diagnose --export",
                           True, "the MMG grey box (identified hull; with a diagnosis, its extension terms)"),
    "hybrid": ModelFamily("hybrid", "usv_predictor.models.hybrid", "replay identify --hybrid", False,
                          "the identified grey box plus a learned residual on the accelerations"),
    "nomoto": ModelFamily("nomoto", "usv_predictor.models.nomoto", "replay identify --family nomoto / auto", False,
                          "the low-order model: Nomoto yaw (first or second order), a speed equation and a drift "
                          "proportional to r"),
    "physics": ModelFamily("physics", "usv_predictor.models.greybox", "replay evaluate --model physics", True,
                           "the calm-water grey box of a vessel preset (no file: the physics baseline)"),
})  # fmt: skip


def family_name(model_type: str) -> str:
    """'greybox+current' -> 'greybox'; 'physics (calm-water ...)' -> 'physics'."""
    return model_type.split("+", 1)[0].split(" ", 1)[0]


def family_of(metadata: Mapping[str, Any], where: str = "model") -> ModelFamily:
    """The family of an artifact's metadata; ModelError naming the file and the known families otherwise."""
    model_type = metadata.get("model_type")
    family = MODEL_FAMILIES.get(family_name(model_type)) if isinstance(model_type, str) else None
    if family is None:
        raise ModelError(f"{where}: model_type {model_type!r} is not a model family of usv_predictor; "
                         f"known: {', '.join(MODEL_FAMILIES)}")
    return family
