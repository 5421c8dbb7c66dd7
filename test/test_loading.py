"""The one model loader (usv_predictor.models.loading) the node and the replay tool share: the spec forms,
the shipped default, and every refusal naming the file (or option) and what differs."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import usv_predictor.config as config
from usv_predictor.errors import ModelError
from usv_predictor.models import loading
from usv_predictor.models.greybox import GreyBoxPredictor

SHIPPED = Path(__file__).resolve().parents[1] / "models" / "default.pt"


def test_physics_with_a_vessel_is_the_calm_water_grey_box_of_that_preset():
    model = loading.load_model("physics:kvlcc2_model", dt=0.25)
    assert isinstance(model, GreyBoxPredictor)
    assert model.metadata["model_id"] == "physics-kvlcc2_model"
    assert model.metadata["dt"] == pytest.approx(0.25)
    out = model.predict(np.array([[1.0, 0.0, 0.0, 0.0]]), np.tile([0.0, 80.0], (1, 4, 1)))
    assert out.shape == (1, 1, 4, 6)


def test_bare_physics_takes_the_configs_vessel_and_step_unless_told():
    cfg = config.load_predictor_config()
    model = loading.load_model("physics")
    assert model.metadata["model_id"] == f"physics-{cfg.vessel}"
    assert model.metadata["dt"] == pytest.approx(cfg.dt)
    assert loading.load_model("physics", vessel="kvlcc2_model").metadata["model_id"] == "physics-kvlcc2_model"


def test_an_empty_spec_is_the_shipped_model():
    assert loading.default_model_path().resolve() == SHIPPED.resolve()
    for spec in (None, ""):
        model = loading.load_model(spec)
        assert model.path.resolve() == SHIPPED.resolve()
        assert model.metadata["format"] == "usv_predictor.model/1"


def test_a_missing_file_is_named_with_the_callers_option(tmp_path):
    with pytest.raises(ModelError, match=r"^--model .*nope\.pt: no such model file$"):
        loading.load_model(str(tmp_path / "nope.pt"))
    with pytest.raises(ModelError, match=r"^model_path .*nope\.pt: no such model file$"):
        loading.load_model(str(tmp_path / "nope.pt"), option="model_path", physics=False)


def test_without_physics_the_word_is_a_file_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ModelError, match="physics: no such model file"):
        loading.load_model("physics", option="model_path", physics=False)


def test_a_missing_shipped_model_says_where_it_looked_and_what_to_pass(tmp_path, monkeypatch):
    monkeypatch.setattr(config, "share_roots", lambda: (tmp_path,))
    with pytest.raises(ModelError, match="no shipped model: models/default.pt does not exist") as err:
        loading.load_model(None)
    assert str(tmp_path / "models" / "default.pt") in str(err.value)
    assert "--model physics" in str(err.value)
    with pytest.raises(ModelError, match="or set model_path to a model file$"):
        loading.load_model("", option="model_path", physics=False)


def test_a_step_or_metadata_that_differs_is_refused_naming_both():
    shipped_dt = loading.model_dt(loading.load_model(str(SHIPPED)))
    other = shipped_dt / 2
    with pytest.raises(ModelError, match=rf"has dt={shipped_dt:g} s but --dt for .*default\.pt has dt={other:g} s"):
        loading.load_model(str(SHIPPED), dt=other)
    with pytest.raises(ModelError, match=r"does not match the configuration: vessel"):
        loading.load_model(str(SHIPPED), expect={"vessel": "kvlcc2_model"})
    assert loading.load_model(str(SHIPPED), dt=shipped_dt).metadata["dt"] == pytest.approx(shipped_dt)


def test_the_physics_step_must_be_positive():
    with pytest.raises(ModelError, match=r"physics predictor step dt=0 s must be > 0"):
        loading.load_model("physics", dt=0)
