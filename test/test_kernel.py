"""The compiled kernel (physics/kernel.py) equals its torch twin (models/greybox.GreyBoxRollout, models/hybrid.
ResidualGreyBox) to 1e-9 in float64: on every preset, hull model and actuator layout, with every extension term, with
each residual, eager and from a TorchScript file; and it is what loading and the predictors run."""
from __future__ import annotations

import io
import math

import numpy as np
import pytest
import torch

from test_greybox import VESSELS
from usv_predictor.analysis.diagnosis import set_terms
from usv_predictor.models.greybox import GreyBoxPredictor, GreyBoxRollout, greybox_metadata, greybox_predictor
from usv_predictor.models.hybrid import (GeneralisingResidual, PolynomialResidual, ResidualGreyBox, SumResidual,
                                         ZeroResidual)
from usv_predictor.models.kernel_rollout import KERNEL_FORM, KernelRollout, KernelUnavailable, check_equal
from usv_predictor.physics import effects
from usv_predictor.physics.vessel import load_vessel

RTOL = 1e-9  # relative to each output column's scale (float64: the twins differ by rounding only)
DT = 0.5  # (s)
PRESETS = {name: load_vessel(name) for name in ("jari_usv", "kvlcc2_model", "otter", "wamv")}
ALL = {**VESSELS, **{f"preset {n}": v for n, v in PRESETS.items()}}


def inputs(vessel, batch: int = 5, steps: int = 40, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Starts (B, 4) round the compass, controls (B, H, C) that sweep the layout's range, references (B, 4)."""
    rng = np.random.default_rng(seed)
    speed = 0.3 * math.sqrt(vessel.geometry.L_pp)  # (m/s) a few knots for a small boat, more for a long one
    state = np.stack([speed * rng.uniform(0.5, 1.5, batch), rng.normal(0, 0.05 * speed, batch),
                      rng.normal(0, 0.3 * speed / vessel.geometry.L_pp, batch), rng.uniform(-3, 3, batch)], axis=1)
    t = np.arange(steps)[None, :] * DT
    phase = rng.uniform(0, 2 * math.pi, (batch, 1))
    layout = vessel.layout
    if layout == "twin_thrusters":
        controls = np.stack([0.6 + 0.35 * np.sin(0.3 * t + phase), 0.5 - 0.4 * np.sin(0.2 * t + phase)], axis=2)
    else:
        columns = [math.radians(25.0) * np.sin(0.25 * t + phase)]
        if layout == "rudder_propeller":
            columns.append(rng.uniform(400, 800, (batch, 1)) + 50.0 * np.sin(0.1 * t))
        elif layout == "rudder_throttle":
            columns.append(0.5 + 0.4 * np.sin(0.15 * t + phase))
        controls = np.stack(columns, axis=2)
    reference = state.copy()
    reference[:, 0] *= 1.1
    reference[:, 1:3] = 0.0
    return state, controls, reference


TERMS = {  # every extension term, at a strength that changes the prediction
    "current_ne": (0.3, -0.2), "wind_ne": (-6.0, 4.0), "wave_ne": (0.04, 0.03), "wave_resistance": (0.6,),
    "rudder_offset": (0.03,), "yaw_rate_bias": (0.01,), "heading_offset": (0.05,), "actuator_delay": (0.7,),
    "resistance_change": (0.15,), "propeller_side_force": (0.02,), "thrust_imbalance": (0.08,),
}


def relative_error(got: np.ndarray, expected: np.ndarray) -> float:
    scale = 1.0 + np.abs(expected).max(axis=(0, 1, 2))  # (6,)
    return float((np.abs(got - expected).max(axis=(0, 1, 2)) / scale).max())


def torch_rollout(module, state, controls, reference=None) -> np.ndarray:
    with torch.no_grad():
        return module(torch.from_numpy(state), torch.from_numpy(controls),
                      None if reference is None else torch.from_numpy(reference)).numpy()


def test_the_terms_and_the_kernels_places_are_the_effect_records():
    assert set(TERMS) == set(effects.grey_box_terms())


@pytest.mark.parametrize("name", sorted(ALL))
@pytest.mark.parametrize("terms", ["calm", "every term", "each term"])
def test_kernel_equals_the_torch_twin(name, terms):
    vessel = ALL[name]
    module = GreyBoxRollout(vessel, dt=DT, substeps=2)
    kernel = KernelRollout(module, live=True)
    state, controls, reference = inputs(vessel)
    cases = {"calm": [{}], "every term": [TERMS], "each term": [{k: v} for k, v in TERMS.items()]}[terms]
    for case in cases:
        set_terms(module, case)
        for ref in (None, reference):
            expected = torch_rollout(module, state, controls, ref)
            got = kernel.rollout(state, controls, ref)
            assert got.shape == expected.shape == (1, 5, 40, 6)
            assert relative_error(got, expected) < RTOL, (name, case, ref is None)


def test_a_term_changes_the_kernels_prediction():
    """Not a kernel that ignores its terms: each term moves the prediction (so the equality above can fail)."""
    vessel = VESSELS["jari_usv (mmg, rudder_propeller)"]
    module = GreyBoxRollout(vessel, dt=DT)
    kernel = KernelRollout(module, live=True)
    state, controls, _ = inputs(vessel)
    calm = kernel.rollout(state, controls)
    set_terms(module, {"wave_ne": TERMS["wave_ne"]})
    waves = kernel.rollout(state, controls)
    for name, value in TERMS.items():
        if name == "thrust_imbalance":  # a twin-thruster term: the rudder boat has no thrusters
            continue
        if name == "wave_resistance":  # the head-sea resistance of waves: against the waves alone
            set_terms(module, {"wave_ne": TERMS["wave_ne"], name: value})
            assert relative_error(kernel.rollout(state, controls), waves) > 1e-4, name
            continue
        set_terms(module, {name: value})
        assert relative_error(kernel.rollout(state, controls), calm) > 1e-4, name
    set_terms(module, {})
    assert relative_error(kernel.rollout(state, controls), calm) == 0.0


def test_a_file_without_a_later_term_runs_in_the_kernel_without_it():
    """A grey box saved before a term existed holds the other terms in order: the kernel reads the absent one as
    zero (the model that file holds has none of it) instead of refusing the file to the slow torch rollout."""
    vessel = VESSELS["jari_usv (mmg, rudder_propeller)"]
    module = GreyBoxRollout(vessel, dt=DT)
    set_terms(module, TERMS)
    older = GreyBoxRollout(vessel, dt=DT)
    set_terms(older, {**TERMS, "wave_resistance": (0.0,)})
    del older.wave_resistance
    older.term_names = tuple(n for n in older.term_names if n != "wave_resistance")
    state, controls, reference = inputs(vessel)
    with torch.no_grad():
        module.wave_resistance.zero_()
    same = KernelRollout(module).rollout(state, controls, reference)
    assert np.array_equal(KernelRollout(older).rollout(state, controls, reference), same)
    with torch.no_grad():
        module.wave_resistance[:] = TERMS["wave_resistance"][0]
    assert relative_error(KernelRollout(module).rollout(state, controls, reference), same) > 1e-4
    older.term_names = ("wind_ne", "current_ne")  # out of order: not a file of this model
    with pytest.raises(KernelUnavailable, match="extension terms"):
        KernelRollout(older)


@pytest.mark.parametrize("substeps", [1, 3])
def test_kernel_equals_the_twin_at_other_substeps_and_from_a_file(substeps):
    vessel = PRESETS["otter"]
    module = GreyBoxRollout(vessel, dt=0.2, substeps=substeps)
    set_terms(module, TERMS)
    buffer = io.BytesIO()
    torch.jit.save(torch.jit.script(module), buffer)
    buffer.seek(0)
    loaded = torch.jit.load(buffer)
    kernel = KernelRollout(loaded)
    state, controls, _ = inputs(vessel)
    assert relative_error(kernel.rollout(state, controls), torch_rollout(module, state, controls)) < RTOL


def test_terms_set_per_row_and_steered_rows():
    """The fit check's batches: each row its own terms ((size, B) tensors), and rows whose sway and yaw are held."""
    vessel = PRESETS["jari_usv"]
    module = GreyBoxRollout(vessel, dt=DT)
    state, controls, _ = inputs(vessel, batch=4)
    rows = np.array([[0.0, 0.2, 0.0, -0.3], [0.0, 0.1, 0.4, 0.0]])  # (2, B) current north, east per row
    module.current_ne = torch.nn.Parameter(torch.from_numpy(rows), requires_grad=False)
    kernel = KernelRollout(module, live=True)
    free = np.array([1.0, 0.0, 1.0, 0.0])
    got = kernel.rollout(state, controls, free=free)
    for b in range(4):
        one = GreyBoxRollout(vessel, dt=DT)
        set_terms(one, {"current_ne": rows[:, b]})
        expected = torch_rollout(one, state[b:b + 1], controls[b:b + 1])
        if free[b]:
            assert relative_error(got[:, b:b + 1], expected) < RTOL
        else:  # held: the sway and yaw rate stay at the start's (water-relative) values
            assert np.allclose(got[0, b, :, 2], state[b, 2])
            assert relative_error(got[:, b:b + 1], expected) > 1e-3


def _randomised(residual: GeneralisingResidual, scale: float, level_b: tuple[float, float]) -> GeneralisingResidual:
    """Random weights; the features' normalisation about the inputs' (level_b: the second level's mean and std)."""
    generator = torch.Generator().manual_seed(3)
    with torch.no_grad():
        for p in [*residual.weights, *residual.biases, residual.head_weight, residual.head_bias]:
            p.copy_(torch.randn(p.shape, generator=generator, dtype=torch.float64) * scale)
        residual.in_mean.copy_(torch.tensor([0.0, 0.0, 1.0, 0.0, level_b[0], 0.0, 0.0]))
        residual.in_std.copy_(torch.tensor([0.1, 0.2, 0.3, 0.2, level_b[1], 0.7, 0.7]))
        residual.z_low.copy_(torch.full((7,), -2.0))
        residual.z_high.copy_(torch.full((7,), 1.5))
        residual.bound.copy_(torch.tensor([0.02, 0.05, 0.03]))
    return residual


def residual_of(kind: str, vessel):
    L = vessel.geometry.L_pp
    if kind == "polynomial":
        return PolynomialResidual(vessel, {"X_du": 0.01, "Y_0": 0.002, "Y_dur": -0.01, "N_0": -0.001, "N_duv": 0.02},
                                  u0=3.0), 1
    level_b = (0.5, 0.3) if vessel.layout == "twin_thrusters" else (600.0, 150.0)  # thruster commands, rpm
    learned = _randomised(GeneralisingResidual(L, 3.0, members=3, hidden=6, layers=2), 0.7, level_b)
    if kind == "learned":
        return learned, 3
    poly, _ = residual_of("polynomial", vessel)
    return SumResidual(poly, learned), 3


@pytest.mark.parametrize("name", ["jari_usv (mmg, rudder_propeller)", "otter (small_craft, twin_thrusters)",
                                  "jari_usv (mmg, rudder_only)"])
@pytest.mark.parametrize("kind", ["zero", "polynomial", "learned", "sum"])
def test_kernel_equals_the_hybrid(name, kind):
    vessel = ALL[name]
    residual, members = (ZeroResidual(), 1) if kind == "zero" else residual_of(kind, vessel)
    module = ResidualGreyBox(vessel, DT, residual, members=members)
    set_terms(module, {"current_ne": (0.2, 0.1), "wave_ne": (0.03, -0.02)})
    state, controls, reference = inputs(vessel)
    expected = torch_rollout(module, state, controls, reference)
    kernel = KernelRollout(torch.jit.script(module))
    got = kernel.rollout(state, controls, reference)
    assert got.shape == expected.shape == (members, 5, 40, 6)
    assert relative_error(got, expected) < RTOL
    if kind != "zero":  # the residual acts: the plain grey box predicts otherwise
        plain = GreyBoxRollout(vessel, DT)
        set_terms(plain, {"current_ne": (0.2, 0.1), "wave_ne": (0.03, -0.02)})
        assert relative_error(got[:1], torch_rollout(plain, state, controls, reference)) > 1e-6


def test_the_kernels_tanh_is_tanh_to_rounding():
    """The learned residual's activation (physics/kernel._tanh: a series and six squarings, no libm call) against
    numpy's tanh: absolutely within 2 ulp of 1 over the range a network meets, relatively within 7e-16 near 0 (where
    1 - exp(-2|x|) would cancel), odd, saturated at +-1 beyond 20, NaN kept."""
    from usv_predictor.physics import kernel as kn

    xs = np.concatenate([np.linspace(-25.0, 25.0, 20001), np.geomspace(1e-300, 1.0, 2001),
                         -np.geomspace(1e-12, 19.0, 2001)])
    got = np.array([kn._tanh(float(x)) for x in xs])
    expected = np.tanh(xs)
    assert np.abs(got - expected).max() <= 4.5e-16
    small = (np.abs(xs) < 0.5) & (xs != 0.0)
    assert (np.abs(got - expected)[small] / np.abs(expected[small])).max() <= 7e-16
    assert [kn._tanh(x) for x in (0.0, 20.0, -21.0, 1e6, math.inf, -math.inf)] == [0.0, 1.0, -1.0, 1.0, 1.0, -1.0]
    assert math.isnan(kn._tanh(math.nan))


def test_an_unknown_module_is_refused_with_a_reason():
    class Other(torch.nn.Module):
        def forward(self, state, controls):
            return torch.zeros(1, state.shape[0], controls.shape[1], 6)

    with pytest.raises(KernelUnavailable, match="cannot read this Other"):
        KernelRollout(Other())


def test_check_equal_catches_a_kernel_that_differs():
    vessel = PRESETS["jari_usv"]
    module = GreyBoxRollout(vessel, DT)
    kernel = KernelRollout(module)
    meta = greybox_metadata(vessel, module)
    assert check_equal(kernel, module, meta) < RTOL
    other = GreyBoxRollout(vessel, DT)
    set_terms(other, {"current_ne": (0.5, 0.0)})
    with pytest.raises(KernelUnavailable, match="differs from the module"):
        check_equal(kernel, other, meta)


def test_the_physics_predictor_runs_the_kernel():
    vessel = PRESETS["otter"]
    predictor = greybox_predictor(vessel, DT)
    assert isinstance(predictor, GreyBoxPredictor) and predictor.inference_note == KERNEL_FORM
    state, controls, _ = inputs(vessel)
    got = predictor.predict(state, controls)
    assert relative_error(got, torch_rollout(predictor.rollout, state, controls)) < RTOL


def test_a_batch_split_over_threads_is_the_same_batch():
    """KernelRollout(threads=2) rolls out halves of a large batch on two threads (the kernel runs without the GIL):
    the same numbers bit for bit, per-row terms and steered rows cut with their rows."""
    vessel = PRESETS["otter"]
    module = GreyBoxRollout(vessel, dt=DT)
    state, controls, reference = inputs(vessel, batch=80)
    rows = np.random.default_rng(1).normal(0.0, 0.3, (2, 80))  # (2, B) a current per row
    module.current_ne = torch.nn.Parameter(torch.from_numpy(rows), requires_grad=False)
    free = (np.arange(80) % 3 != 0).astype(float)
    one = KernelRollout(module, live=True).rollout(state, controls, reference, free=free)
    split = KernelRollout(module, live=True, threads=2)
    np.testing.assert_array_equal(split.rollout(state, controls, reference, free=free), one)
    assert np.abs(one[0, :, -1, 3:5] - one[0, :1, -1, 3:5]).max() > 1.0  # the rows differ: a mix-up would show


@pytest.mark.parametrize("name", sorted(ALL))
def test_the_float_models_constants_are_the_torch_modules(name):
    """The kernel's two packers, from a Vessel (dynamics.kernel_constants: the float model) and from the torch
    module's attributes (KernelRollout: an artifact), give the same ki and p: one set of constants."""
    from usv_predictor.physics.dynamics import kernel_constants

    vessel = ALL[name]
    kernel = KernelRollout(GreyBoxRollout(vessel, dt=0.2, substeps=3))
    ki, p = kernel_constants(vessel, dt=0.2, substeps=3)
    np.testing.assert_array_equal(ki, kernel.ki)
    np.testing.assert_allclose(p, kernel.p, rtol=1e-15, atol=0.0)


def test_read_only_and_strided_inputs_reuse_the_one_compiled_rollout():
    """A read-only contiguous view (np.broadcast_to of a plan's (H, C) controls) or a strided one is passed as the
    kernel's one signature: numba types a read-only array apart, and compiling a second specialisation in mid-run
    holds the GIL for seconds (the node's cycles stall)."""
    from usv_predictor.physics import kernel as kn

    vessel = PRESETS["jari_usv"]
    kernel = KernelRollout(GreyBoxRollout(vessel, dt=DT))
    state, controls, reference = inputs(vessel, batch=1)
    expected = kernel.rollout(state, controls, reference)
    read_only = np.broadcast_to(controls[0], controls.shape)  # (1, H, C), contiguous, not writable
    assert read_only.flags.c_contiguous and not read_only.flags.writeable
    strided = np.repeat(reference, 2, axis=0)[::2]
    np.testing.assert_array_equal(kernel.rollout(state, read_only, strided), expected)
    assert kernel.engine is not kn.rollout  # this model's rows side by side: that engine's one signature
    assert len(kernel.engine.signatures) == 1, kernel.engine.signatures
    kernel.warm_up()  # and the one-row-at-a-time rollout's
    assert len(kn.rollout.signatures) == 1, kn.rollout.signatures


def test_a_live_kernel_follows_a_learned_residual_changed_in_place():
    """A training step changes the network's weights in place: a live kernel predicts what the module now does (the
    changed network, not the packed one); a kernel that is not live keeps what it read."""
    vessel = ALL["jari_usv (mmg, rudder_propeller)"]
    residual, members = residual_of("learned", vessel)
    module = ResidualGreyBox(vessel, DT, residual, members=members)
    state, controls, reference = inputs(vessel)
    live, once = KernelRollout(module, live=True), KernelRollout(module)
    before = live.rollout(state, controls, reference)
    with torch.no_grad():
        residual.head_bias.add_(0.01)  # as an optimiser's step does
        residual.in_std.mul_(1.5)
    expected = torch_rollout(module, state, controls, reference)
    assert relative_error(before, expected) > 1e-6  # the change acts
    assert relative_error(live.rollout(state, controls, reference), expected) < RTOL
    assert relative_error(once.rollout(state, controls, reference), before) < RTOL


# ---- several rows side by side (kernel.rollout_lanes_for) -----------------------------------------------------------

ROW_TERMS = ("wind_ne",)  # the terms whose loads run one row at a time
LANE_VESSELS = ("jari_usv (mmg, rudder_propeller)", "jari_usv (mmg, rudder_only)", "preset kvlcc2_model")


def one_row_at_a_time(kernel, state, controls, reference, free):
    """kernel.rollout's rows by physics/kernel.rollout, the one-row-at-a-time rollout every model has."""
    from usv_predictor.physics import kernel as kn

    out = np.empty((kernel.members, state.shape[0], controls.shape[1], 6))
    use = reference is not None
    kn.rollout(state, controls, reference if use else state, use, kernel.ki, kernel.p, kernel.terms, free, out)
    return out


@pytest.mark.parametrize("name", LANE_VESSELS)
@pytest.mark.parametrize("batch", [1, 9, 70])  # one row; a vector's 8 and a remainder; LANES (64) and a second group
def test_rows_side_by_side_are_the_rollout_one_row_at_a_time(name, batch):
    """The MMG hull's rudder layouts roll their rows out LANES at a time, the derivative one loop over the rows
    (eight wide): the same model as one row at a time with every term but the wind's (that runs one row at a time),
    the waves' drift and head-sea resistance among them, held rows and rudder_only's reference, to rounding."""
    from usv_predictor.physics import kernel as kn

    vessel = ALL[name]
    module = GreyBoxRollout(vessel, dt=DT, substeps=2)
    kernel = KernelRollout(module, live=True)
    state, controls, reference = inputs(vessel, batch=batch, seed=batch)
    free = (np.arange(batch) % 4 != 1).astype(float)
    lane_terms = {k: v for k, v in TERMS.items() if k not in ROW_TERMS}
    calm = {}
    # the terms that do not act alone on this boat: C_AW (in waves only), the thrusters' imbalance, and the waves
    # where its drift tables are zero (the KVLCC2 preset's)
    drift = int(kernel.ki[kn.K_O_DRIFT]) + np.arange(9 * int(kernel.ki[kn.K_DRIFT_ROWS]))
    inert = {"wave_resistance", "thrust_imbalance"} | (set() if kernel.p[drift].any() else {"wave_ne"})
    for case in ({}, lane_terms, *({k: v} for k, v in lane_terms.items())):
        set_terms(module, case)
        for ref in (None, reference):
            got = kernel.rollout(state, controls, ref, free=free)
            assert kernel.engine is not kn.rollout, case  # this model and these terms run side by side
            if not case:
                calm[ref is None] = got
            elif len(case) > 1 or not inert & set(case):
                assert relative_error(got, calm[ref is None]) > 1e-7, case  # the term acts in the lanes
            assert relative_error(got, one_row_at_a_time(kernel, state, controls, ref, free)) < 1e-12, case
            assert relative_error(kernel.rollout(state, controls, ref), torch_rollout(module, state, controls, ref)) \
                < RTOL, case


def test_the_rows_side_by_side_differ_where_their_inputs_do():
    """Not lanes that copy one row into the others: every row of a batch of 70 is its own prediction (equal to it
    rolled out alone), and a held row keeps its yaw rate."""
    vessel = ALL["jari_usv (mmg, rudder_propeller)"]
    kernel = KernelRollout(GreyBoxRollout(vessel, dt=DT), live=True)
    state, controls, reference = inputs(vessel, batch=70, seed=3)
    free = (np.arange(70) % 5 != 0).astype(float)
    got = kernel.rollout(state, controls, free=free)
    for b in (0, 7, 8, 63, 64, 69):  # the first, a vector's edges, the first group's last, the second group
        alone = kernel.rollout(state[b:b + 1], controls[b:b + 1], free=free[b:b + 1])
        assert relative_error(got[:, b:b + 1], alone) < 1e-12, b
    assert np.allclose(got[0, ::5, :, 2], state[::5, 2:3])  # held rows: r stays the start's
    assert np.abs(got[0, :, -1, 3:5] - got[0, :1, -1, 3:5]).max() > 1.0


@pytest.mark.parametrize("why", ["wind", "a term per row", "small craft", "rudder_throttle", "residual"])
def test_rows_run_one_at_a_time_where_the_lanes_cannot(why):
    """A wind (its loads are not in the lanes' derivative), terms set per row, a hull or layout
    with a loop in its derivative (strips, thrust tables), a learned or polynomial residual: one row at a time,
    equal to the torch twin (the equality above, for each)."""
    from usv_predictor.physics import kernel as kn

    name = {"small craft": "otter hull (small_craft, rudder_propeller)",
            "rudder_throttle": "jari_usv (mmg, rudder_throttle)"}.get(why, "jari_usv (mmg, rudder_propeller)")
    vessel = ALL[name]
    if why == "residual":
        residual, members = residual_of("polynomial", vessel)
        module = ResidualGreyBox(vessel, DT, residual, members=members)
    else:
        module = GreyBoxRollout(vessel, dt=DT)
    state, controls, _ = inputs(vessel, batch=3)
    if why == "wind":
        set_terms(module, {"wind_ne": TERMS["wind_ne"]})
    elif why == "a term per row":
        rows = np.array([[0.3, 0.0, -0.2], [0.0, 0.1, 0.2]])  # (2, B) a current per row
        module.current_ne = torch.nn.Parameter(torch.from_numpy(rows), requires_grad=False)
    kernel = KernelRollout(module, live=True)
    got = kernel.rollout(state, controls)
    assert kernel.engine is kn.rollout, why
    assert relative_error(got, torch_rollout(module, state, controls)) < RTOL, why
    lanes = GreyBoxRollout(ALL["jari_usv (mmg, rudder_propeller)"], dt=DT)
    assert KernelRollout(lanes).engine is not kn.rollout  # the same call without that runs side by side


def test_the_elementary_functions_are_libms_to_a_few_ulp():
    """The derivative's cos, sin, atan2, exp (polynomials without a call or a branch, so that a loop of them runs
    eight wide) and sqrt (the instruction), compiled with the rollout's flags, against numpy's libm."""
    from numba import njit

    from usv_predictor.physics import kernel as kn

    @njit(**kn.VECTOR)
    def evaluate(x, y):  # (N,), (N,) -> (N, 5): cos x, sin x, atan2(y, x), exp(-|x|), sqrt |y|
        out = np.empty((x.size, 5))
        for i in range(x.size):
            out[i, 0], out[i, 1] = kn._cos_sin(x[i])
            out[i, 2] = kn._atan2(y[i], x[i])
            out[i, 3] = kn._exp_neg(-abs(x[i]))
            out[i, 4] = kn._sqrt(abs(y[i]))
        return out

    rng = np.random.default_rng(7)
    x = np.concatenate([rng.uniform(-30.0, 30.0, 20000), rng.uniform(-1e-3, 1e-3, 2000), [0.0, -0.0, math.pi, 1e-300],
                        np.arange(-8, 9) * (math.pi / 4)])
    y = np.concatenate([rng.uniform(-30.0, 30.0, 20000), rng.uniform(-1e-3, 1e-3, 2000), [0.0, 1.0, -0.0, 0.0],
                        np.linspace(-2.0, 2.0, 17)])
    got = evaluate(x, y)
    # the flags' reassociation folds pi/2's three parts into one double: ~4e-17 |x| (|x| <= 30 here)
    assert np.abs(got[:, 0] - np.cos(x)).max() < 1.5e-15 and np.abs(got[:, 1] - np.sin(x)).max() < 1.5e-15
    small = np.abs(x) < 3.2
    assert np.abs(got[small, 0] - np.cos(x[small])).max() < 3e-16
    assert np.abs(got[:, 2] - np.arctan2(y, x)).max() < 5e-16
    exp = np.exp(-np.abs(x))  # ln 2's two parts folded the same way: ~2.3e-17 m relatively (m <= 44 here)
    assert (np.abs(got[:, 3] - exp) / exp).max() < 1.5e-15
    np.testing.assert_array_equal(got[:, 4], np.sqrt(np.abs(y)))  # the instruction: correctly rounded
    assert kn._exp_neg(-1e3) == pytest.approx(math.exp(kn.EXP_FLOOR), rel=1e-13)  # floored: 4e-18 for ~0
    assert all(math.isnan(v) for v in (*kn._cos_sin(math.nan), *kn._cos_sin(math.inf), kn._sqrt(-1.0)))
