"""Model families (models/families.py): every model the package writes names a known family."""
from __future__ import annotations

import pytest

from usv_predictor.config import package_share_path
from usv_predictor.errors import ModelError
from usv_predictor.models.artifact import load_artifact
from usv_predictor.models.families import MODEL_FAMILIES, family_name, family_of
from usv_predictor.models.loading import physics_predictor
from usv_predictor.physics.vessel import load_vessel


@pytest.mark.parametrize("model_type, family", [
    ("dnn", "dnn"), ("greybox", "greybox"), ("greybox+current+wave_drift", "greybox"), ("hybrid", "hybrid"),
    ("physics (calm-water MMG grey box of the preset)", "physics"), ("nomoto", "nomoto"),
])  # fmt: skip
def test_a_model_type_names_its_family(model_type, family):
    assert family_of({"model_type": model_type}).name == family


def test_the_shipped_model_and_the_physics_baseline_are_known_families():
    assert family_of(load_artifact(package_share_path("models", "default.pt")).metadata).name == "dnn"
    baseline = family_of(physics_predictor(load_vessel("jari_usv"), 0.5).metadata)
    assert baseline.name == "physics"
    assert baseline.physics


def test_only_the_grey_box_families_carry_the_physics():
    assert {name for name, f in MODEL_FAMILIES.items() if f.physics} == {"greybox", "physics"}
    assert family_name("greybox+rudder_offset") == "greybox"


def test_a_foreign_model_type_is_named_with_the_known_families():
    with pytest.raises(ModelError, match=r"m\.pt: model_type 'keras' is not a model family of usv_predictor; "
                                         r"known: dnn, greybox, hybrid, nomoto, physics"):
        family_of({"model_type": "keras"}, where="m.pt")
    with pytest.raises(ModelError, match="model_type None"):
        family_of({})
