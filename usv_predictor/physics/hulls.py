"""Hull models: which equations describe the bare hull of a vessel, and which vessel sections hold their
coefficients. One record per model (HULL_MODELS, in the style of physics/actuators.ACTUATOR_LAYOUTS); a vessel
YAML names its model under `hull_model` (default mmg). The equations are in physics/dynamics.py (floats) and
models/greybox.py (torch), each with one registry line per model; `coefficients` names the section whose fields
are the identifiable hull coefficients (GreyBoxRollout.hull, in the section's field order).

    mmg          Yasukawa & Yoshimura 2015 (the MMG standard method): non-dimensional hull polynomial in
                 v' = v/U and r' = r L/U, non-dimensional added mass. For ships and fast monohulls under way;
                 singular at U = 0 (regularised below dynamics.SPEED_FLOOR), so it cannot turn on the spot.
    small_craft  Fossen 2021 ch. 6 and his Otter model (MSS otter.m, PythonVehicleSimulator otter.py):
                 dimensional added mass and linear + quadratic damping derivatives, strip-theory cross-flow
                 drag, the rigid-body and added-mass Coriolis matrices (with the Munk moment). Regular at zero
                 speed: a twin-thruster boat turns on the spot.
"""
from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping

from usv_predictor.errors import ConfigError


@dataclass(frozen=True)
class HullModel:
    name: str
    description: str
    sections: tuple[str, ...]  # vessel sections it needs besides geometry, windage and wave_drift
    coefficients: str  # the section whose fields are the hull coefficients an identification fits
    equations: str  # where the equations come from
    structure: str  # its name in a grey-box artifact's metadata (architecture.structure)
    label: str  # its short name in messages and model types ("the calm-water MMG grey box")


MMG = HullModel(
    name="mmg",
    description="non-dimensional MMG hull polynomial and added mass (ships, fast monohulls under way)",
    sections=("added_mass", "hull"),
    coefficients="hull",
    equations="Yasukawa & Yoshimura 2015 eq. 4-8 (MMG standard method) in Fossen's matrix form (Fossen 2021 eq. 6.5)",
    structure="MMG (Yasukawa & Yoshimura 2015)",
    label="MMG",
)

SMALL_CRAFT = HullModel(
    name="small_craft",
    description="dimensional added mass, linear + quadratic damping and cross-flow drag (small craft, USVs; "
                "regular at zero speed)",
    sections=("small_craft",),
    coefficients="small_craft",
    equations="Fossen 2021 eq. 6.5 (ch. 6): 3-DOF C_RB independent of the linear velocity, C_A(nu_r) of a diagonal "
              "added-mass matrix (Munk moment), linear + quadratic damping, strip-theory cross-flow drag with "
              "Hoerner's C_d; as coded in Fossen's otter.py (PythonVehicleSimulator) and otter.m (MSS)",
    structure="small craft (Fossen 2021 ch. 6)",
    label="small-craft",
)

HULL_MODELS: Mapping[str, HullModel] = MappingProxyType({
    MMG.name: MMG,
    SMALL_CRAFT.name: SMALL_CRAFT,
})  # fmt: skip
DEFAULT_HULL_MODEL = MMG


def hull_model(name: str) -> HullModel:
    """The hull model record of `name` (ConfigError listing the known models otherwise)."""
    try:
        return HULL_MODELS[name]
    except (KeyError, TypeError):
        raise ConfigError(f"unknown hull model {name!r}; known: {', '.join(HULL_MODELS)}") from None
