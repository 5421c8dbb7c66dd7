"""identify writes strict JSON whatever the data: a singular design's variance inflation factors are null with a
note (never NaN or inf), undefined numbers are null; and `--prior none` says which prior to use and why."""
from __future__ import annotations

import json

import numpy as np
import pytest

from usv_predictor.atomic import json_text
from usv_predictor.fitting import identification as idf


def _design(columns: list[np.ndarray]) -> idf.Design:
    n = len(columns[0])
    return idf.Design("N", tuple(f"N_{k}" for k in range(len(columns))), np.column_stack(columns), np.zeros(n),
                      np.zeros(n, dtype=int), np.ones(n))


@pytest.mark.parametrize("scale", [1.0, 1.0 + 1e-15])  # exactly collinear, and collinear to the last bit
def test_a_singular_design_has_null_vifs_with_a_note(scale: float) -> None:
    rng = np.random.default_rng(0)
    a, c = rng.normal(size=200), rng.normal(size=200)
    col = idf.collinearity(_design([a, scale * 2.0 * a, c, np.ones(200)]))
    data = json.loads(json_text(col.to_json()))  # strict: raises on NaN / inf
    assert data["vif"]["N_0"] is None
    assert data["vif"]["N_1"] is None
    assert data["singular"] is True
    assert "singular" in data["vif_note"]
    assert data["constant_regressors"] == ["N_3"]
    assert data["vif"]["N_2"] is None or data["vif"]["N_2"] >= 1.0


def test_a_regular_design_has_finite_vifs_and_no_note() -> None:
    rng = np.random.default_rng(1)
    col = idf.collinearity(_design([rng.normal(size=200), rng.normal(size=200)]))
    data = col.to_json()
    assert all(1.0 <= v < 1.2 for v in data["vif"].values())
    assert "vif_note" not in data
    assert not data["singular"]


def test_undefined_coefficient_numbers_are_null() -> None:
    c = idf.Coefficient("N_r", float("nan"), (float("-inf"), float("nan")), -0.05, "identified", float("nan"))
    data = json.loads(json_text(c.to_json()))
    assert data["estimate"] is None
    assert data["ci95"] == [None, None]
    assert data["rel_ci"] is None
    cv = idf.CrossValidation("abkowitz", {"X": 0.1, "N": float("nan")}, float("nan"))
    assert json.loads(json_text(cv.to_json())) == {"structure": "abkowitz", "per_equation_nmse": {"X": 0.1, "N": None},
                                                   "score": None}


def test_prior_none_refusal_names_the_prior_to_use_and_why() -> None:
    rng = np.random.default_rng(2)
    col = idf.collinearity(_design([rng.normal(size=50), rng.normal(size=50)]))
    fit = idf.EquationFit("N", (), lambda: col, 0.1, 50.0)
    message = idf._message(["N_vvr", "N_rrr"], [fit], ["zigzag_a", "zigzag_b"])
    assert "Use --prior fix" in message
    assert "N_vvr, N_rrr" in message
    assert "--prior ridge" in message and "EVERY coefficient" in message  # why not ridge
    assert "turning circles both ways" in message
    assert "\n" not in message


def test_coefficient_flags_say_which_values_are_the_priors() -> None:
    fixed = idf.Coefficient("N_rrr", -0.013, (-0.013, -0.013), -0.013, "fixed to prior", 0.0)
    free = idf.Coefficient("N_r", -0.03, (-0.031, -0.029), -0.05, "identified", 0.03)
    ridged = idf.Coefficient("N_vvr", -0.2, (-0.5, 0.1), -0.29, "ridge towards prior", 1.4)
    assert idf.coefficient_flags(free, ("N_rrr",), "fix") == {"determined_by_data": True, "note": None}
    flags = idf.coefficient_flags(fixed, ("N_rrr",), "fix")
    assert flags == {"determined_by_data": False,
                     "note": "not determined by these manoeuvres; prior used (held at the vessel file's value)"}
    assert idf.coefficient_flags(ridged, ("N_vvr",), "ridge")["determined_by_data"] is False
    assert idf.coefficient_flags(ridged, (), "ridge")["determined_by_data"] is True  # identifiable, only pulled
    json.loads(json_text(free.to_json() | idf.coefficient_flags(free, (), "fix")))  # strict JSON
