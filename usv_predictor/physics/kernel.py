"""The compiled grey-box kernel: one machine-code rollout of the 3-DOF manoeuvring model for every hull model, actuator
layout, sea and sensor term and learned residual, batched over start states.

It integrates exactly the model of models/greybox.py (GreyBoxRollout, its twin in torch for autograd and the
TorchScript file format; test_kernel.py proves them equal to 1e-9 in float64 on every preset, layout, hull model,
term and residual), whose equations are those of physics/dynamics.py:

    M nu_r_dot + C(nu_r) nu_r + D(nu_r) nu_r = tau_act + tau_wind + tau_wave (+ M g_residual)    (Fossen 2021 eq. 6.5)
    eta_dot = R(psi) (nu_r + nu_c)                                                               (Fossen 2021 eq. 2.40)

with the MMG hull (Yasukawa & Yoshimura 2015 eq. 4-8) or Fossen's small-craft hull (2021 ch. 6, cross-flow drag by
strips), the MMG rudder and propeller (eq. 10-16, 37-43) or twin thrusters with thrust maps and exact first-order
motor lags, the wind of seed 000 eq. 12-18 and the wave drift of eq. 19 with its head-sea resistance, RK4 with
`substeps` per step and a first-order hold of the reported controls (models/greybox.py's module docstring has the
interface and every term).

Why compiled: the torch twin is ~150 tensor operations on (B,) tensors per RK4 stage, each a few microseconds of
dispatch for a few nanoseconds of arithmetic. Here a stage is ~300 scalar flops (a few hundred more with the
small-craft hull's cross-flow strips), so one 120-step prediction of one state costs ~10^5 flops: tens of
microseconds (benchmarks/bench_kernel.py measures it against the TorchScript file and the arithmetic floor).

Everything is numba `@njit(cache=True)`: compiled once per signature, on first use, into numba's cache (beside
this file in __pycache__ when that is writable, else in the user's cache folder; NUMBA_CACHE_DIR overrides), so a
second process loads machine code in well under a second. docs/kernel.md says where and what a read-only install
does.

The packed inputs (models/kernel_rollout.py builds them from a GreyBoxRollout or its TorchScript file): two flat
arrays, so that a derivative passes two array handles, not twenty (each array argument of a call between compiled
functions costs a reference count and a struct copy: that was half of a derivative's time):
    ki  (NK,) int64    the kinds, sizes and offsets into p (K_* below): hull model, layout, substeps, residual,
                       small-craft coefficient indices, where each table starts in p
    p   (NP,) float64  the constants in SI units at fixed places (P_* below: the sea, the mass matrix, the hull
                       model's and layout's), then the extension terms (T_*, effects.grey_box_terms' order, SI), the
                       hull coefficients (GreyBoxRollout.hull, its hull model's field order), the wave-drift Fourier
                       tables [[a0/2, 0, 0], [n, a_n, b_n], ...] of X, Y, N, the small-craft strips (m), two thrust
                       maps ([forward_N, reverse_N, exponent, dead_band, has table], table commands, thrusts N), the
                       lags ([T (s), exp(-h/2T), exp(-h/T)] per lagged column), the Abkowitz terms and a learned
                       residual's stacked member weights (K_O_* say where)
and per call: terms (R, NT) the extension terms per row (R = 1 or B), free (B,) 1 on a free row, 0 where sway and
yaw are held (the fit check's steered rows).
"""
from __future__ import annotations

import math
import os
import tempfile
from typing import Any

import numba
import numpy as np
from llvmlite import ir as llvm_ir
from numba import njit
from numba.core import cgutils, types
from numba.extending import intrinsic, overload
from numba.np.unsafe.ndarray import to_fixed_tuple


def _probe() -> int:
    return 0


def _cache_folder() -> bool:
    """Whether numba can cache this module's machine code, finding it a place if it must: beside this file or in the
    user's cache folder (numba's own choice; NUMBA_CACHE_DIR overrides both), else a folder of this user's in the
    temporary directory. False (compiled in every process, no cache) when none is writable: a read-only install
    under a user without a home (docs/kernel.md)."""
    try:
        njit(cache=True)(_probe)
        return True
    except RuntimeError:  # numba: "cannot cache function ...: no locator available for file ..."
        pass
    folder = os.path.join(tempfile.gettempdir(), f"usv_predictor-numba-{os.getuid()}")
    try:
        os.makedirs(folder, mode=0o700, exist_ok=True)
        numba.config.CACHE_DIR = folder
        njit(cache=True)(_probe)
        return True
    except (OSError, RuntimeError):
        return False


CACHED = _cache_folder()  # whether the compiled kernel is kept on disk between processes
_compiled = njit(cache=CACHED)
# the derivative and the small force models it calls every stage, inlined into their callers in numba's IR: a call
# between compiled functions passes each array as a struct and counts its references (atomic operations), which cost
# as much as the arithmetic; the rollout calls the derivative from one place, so it holds one copy of it
_inlined = njit(cache=CACHED, inline="always")

# The learned residual's loops vectorise (eight lanes with AVX-512) only when: a division does not test its divisor
# and raise (error_model numpy); sums may be reassociated and multiply-adds fused (fastmath reassoc, contract; not
# nnan / ninf: NaN and inf keep their meaning); the rows and vectors are sliced views, whose indices are known
# non-negative (no wraparound select). The network is inlined into the rollout (a call between compiled functions
# passes each array as a struct and counts its references), so the rollout is compiled with the same flags: VECTOR.
VECTOR = {"fastmath": {"reassoc", "contract", "nsz"}, "error_model": "numpy"}

# ---- kinds ------------------------------------------------------------------------------------------------------
MMG, SMALL_CRAFT = 0, 1  # hull models (physics/hulls.py)
RUDDER_PROPELLER, RUDDER_THROTTLE, RUDDER_ONLY, TWIN_THRUSTERS = 0, 1, 2, 3  # actuator layouts (physics/actuators.py)
RESIDUAL_POLYNOMIAL, RESIDUAL_MLP = 1, 2  # bits of K_RESIDUAL (models/hybrid.py): Abkowitz terms, learned members

K_NAMES = (
    "hull_kind", "layout", "substeps", "residual",
    "i_xud", "i_yvd", "i_nrd", "i_xu", "i_xuu", "i_yv", "i_yr", "i_nv", "i_nr", "i_nrr", "i_cd",  # small-craft hull
    "o_hull", "o_drift", "drift_rows", "o_strips", "n_strips",  # where the hull, drift tables and strips start
    "o_maps", "map_width", "map_n0", "map_n1", "o_lag", "o_coef",  # thrust maps (2 x (5 + 2 width)), lags, Abkowitz
    "o_w0", "o_b0", "o_wh", "o_bh", "o_wo", "o_bo", "o_norm", "members", "hidden", "hidden_layers",  # learned
)
(K_HULL, K_LAYOUT, K_SUBSTEPS, K_RESIDUAL, K_XUD, K_YVD, K_NRD, K_XU, K_XUU, K_YV, K_YR, K_NV, K_NR, K_NRR, K_CD,
 K_O_HULL, K_O_DRIFT, K_DRIFT_ROWS, K_O_STRIPS, K_N_STRIPS, K_O_MAPS, K_MAP_WIDTH, K_MAP_N0, K_MAP_N1, K_O_LAG,
 K_O_COEF, K_O_W0, K_O_B0, K_O_WH, K_O_BH, K_O_WO, K_O_BO, K_O_NORM, K_MEMBERS, K_HIDDEN,
 K_HIDDEN_LAYERS) = range(len(K_NAMES))
N_KINDS = len(K_NAMES)

# ---- constants (SI): the names of the records of physics/dynamics.py (constants_of), as the torch twin holds them --
P_NAMES = (
    "dt",  # step (s)
    "L_sea",  # wave-drift moment arm L_pp (m)
    "wind_x", "wind_y", "wind_n",  # 0.5 rho_air A c (kg/m, kg/m, kg)
    "q_wave",  # 0.5 rho g L (N/m^2)
    # the hull model: mass matrix about midship and the force scale
    "L", "m", "x_G", "m11", "m22", "m23", "m32", "m33", "det_vr",  # (m, kg, m, kg ... kg^2 m^2)
    "q_force",  # MMG: 0.5 rho L d (kg/m)
    "speed_floor",  # MMG: SPEED_FLOOR (m/s)
    "m33_rigid", "half_rho_d", "strip_dx",  # small craft: I_z + m x_G^2 (kg m^2), 0.5 rho d (kg/m^2), strip width (m)
    # the rudder layouts: MMG propeller and rudder
    "rho", "L_act", "x_P", "w_P0", "gear_ratio", "D_P", "k0", "k1", "k2", "t_P", "epsilon", "eta", "kappa", "l_R_m",
    "gamma_R_minus", "gamma_R_plus", "A_R", "f_alpha", "t_R", "a_H", "x_R_m", "x_H_m",
    "static_thrust", "rpm_per_rev_s",  # rudder_throttle: rho D^4 K_T(0) (kg m), 60 gear_ratio (rpm s)
    "half_spacing",  # twin_thrusters: b/2 (m)
    "engine_speed_rpm",  # rudder_only: the engine speed held (rpm), 0 = from the reference's straight running
    # a polynomial residual (models/hybrid.PolynomialResidual): its speed and the vessel's constants
    "poly_u0", "poly_L", "poly_q_force", "poly_m11", "poly_m22", "poly_m23", "poly_m32", "poly_m33",
    # a learned residual (models/hybrid.GeneralisingResidual)
    "mlp_L", "mlp_u_ref", "mlp_speed_floor", "mlp_support_width",
)
(P_DT, P_L_SEA, P_WIND_X, P_WIND_Y, P_WIND_N, P_Q_WAVE, P_L, P_M, P_X_G, P_M11, P_M22, P_M23, P_M32, P_M33, P_DET_VR,
 P_Q_FORCE, P_SPEED_FLOOR, P_M33_RIGID, P_HALF_RHO_D, P_STRIP_DX, P_RHO, P_L_ACT, P_X_P, P_W_P0, P_GEAR_RATIO, P_D_P,
 P_K0, P_K1, P_K2, P_T_P, P_EPSILON, P_ETA, P_KAPPA, P_L_R_M, P_GAMMA_R_MINUS, P_GAMMA_R_PLUS, P_A_R, P_F_ALPHA, P_T_R,
 P_A_H, P_X_R_M, P_X_H_M, P_STATIC_THRUST, P_RPM_PER_REV_S, P_HALF_SPACING, P_ENGINE_SPEED_RPM, P_POLY_U0, P_POLY_L,
 P_POLY_Q_FORCE, P_POLY_M11, P_POLY_M22, P_POLY_M23, P_POLY_M32, P_POLY_M33, P_MLP_L, P_MLP_U_REF, P_MLP_SPEED_FLOOR,
 P_MLP_SUPPORT_WIDTH) = range(len(P_NAMES))

# ---- extension terms, effects.grey_box_terms' order (models/kernel_rollout.py checks it), right after the constants
T_NAMES = ("current_ne", "current_ne", "wind_ne", "wind_ne", "wave_ne", "wave_ne", "wave_resistance", "rudder_offset",
           "yaw_rate_bias", "heading_offset", "actuator_delay", "resistance_change", "propeller_side_force",
           "thrust_imbalance")
T_BASE = len(P_NAMES)
(T_CURRENT_N, T_CURRENT_E, T_WIND_N, T_WIND_E, T_WAVE_N, T_WAVE_E, T_WAVE_RESISTANCE, T_RUDDER_OFFSET, T_YAW_RATE_BIAS,
 T_HEADING_OFFSET, T_ACTUATOR_DELAY, T_RESISTANCE_CHANGE, T_SIDE_FORCE,
 T_THRUST_IMBALANCE) = range(T_BASE, T_BASE + len(T_NAMES))
N_TERMS = len(T_NAMES)
N_POLY = 7  # the Abkowitz terms X_du, Y_0, Y_duv, Y_dur, N_0, N_duv, N_dur (models/hybrid.EXTRA_NAMES)
N_FEATURES = 7  # models/hybrid.GENERALISING_FEATURES


# ---- packing ------------------------------------------------------------------------------------------------------

SMALL_CRAFT_INDICES = ("X_udot", "Y_vdot", "N_rdot", "X_u", "X_uu", "Y_v", "Y_r", "N_v", "N_r", "N_rr", "cross_flow_cd")
RUDDER_CONSTANTS = ("x_P", "w_P0", "gear_ratio", "D_P", "k0", "k1", "k2", "t_P", "epsilon", "eta", "kappa", "l_R_m",
                    "gamma_R_minus", "gamma_R_plus", "A_R", "f_alpha", "t_R", "a_H", "x_R_m", "x_H_m")
MASS_CONSTANTS = ("L", "m", "x_G", "m11", "m22", "m23", "m32", "m33", "det_vr")


def fourier_tables(tables: list[list[list[float]]]) -> np.ndarray:
    """(K, N, 3) of K Fourier tables [[a0/2, 0, 0], [n, a_n, b_n], ...], zero rows padding the shorter ones."""
    rows = max(len(t) for t in tables)
    out = np.zeros((len(tables), rows, 3))
    for k, table in enumerate(tables):
        out[k, :len(table)] = np.asarray(table, dtype=np.float64).reshape(-1, 3)
    return out


def thrust_maps(specs: list[tuple[list[float], list[float], list[float]]]) -> tuple[np.ndarray, int, list[int]]:
    """(2 x [spec (5), table commands (T), table thrusts (T)] flat, T, the tables' lengths) of up to two thrust maps
    (models/greybox._thrust_constants)."""
    width = max([len(x) for _, x, _ in specs] + [2])
    flat = np.zeros((2, 5 + 2 * width))
    lengths = [0, 0]
    for k, (spec, x, y) in enumerate(specs):
        flat[k, :5] = spec
        flat[k, 5:5 + len(x)], flat[k, 5 + width:5 + width + len(y)], lengths[k] = x, y, len(x)
    return flat.reshape(-1), width, lengths


class Packer:
    """The flat constants p after the fixed places (P_NAMES, the terms): each table appended, its offset and sizes
    recorded in ki (K_*). Two callers fill it: physics/dynamics.kernel_constants (a Vessel: the float model) and
    models/kernel_rollout.py (a GreyBoxRollout or its TorchScript file's module)."""

    def __init__(self) -> None:
        self.ki = np.zeros(len(K_NAMES), dtype=np.int64)
        self.fixed = np.zeros(T_BASE + N_TERMS)
        self.parts: list[np.ndarray] = []
        self.size = len(self.fixed)

    def set(self, name: str, value: Any) -> None:
        self.fixed[P_NAMES.index(name)] = float(value)

    def append(self, offset_key: int, values: Any) -> None:
        values = np.asarray(values, dtype=np.float64).reshape(-1)
        self.ki[offset_key] = self.size
        self.parts.append(values)
        self.size += len(values)

    def constants(self) -> np.ndarray:
        return np.ascontiguousarray(np.concatenate([self.fixed, *self.parts]))


def thrust_map_spec(m) -> tuple[list[float], list[float], list[float]]:
    """([forward_N, reverse_N, exponent, dead_band, has table], table commands, table thrusts) of a vessel.ThrustMap
    (a power-law map: the placeholder table [-1, 1] -> [0, 0]), as models/greybox.py holds it."""
    if m.table_command:
        return ([m.forward_N, m.reverse_N, m.exponent, m.dead_band, 1.0], [float(x) for x in m.table_command],
                [float(y) for y in m.table_thrust_N])
    return [m.forward_N, m.reverse_N, m.exponent, m.dead_band, 0.0], [-1.0, 1.0], [0.0, 0.0]


def lag_factors(time_constants, tau: float) -> list[float]:
    """exp(-tau / T) per time constant T (s), 0 for an instantaneous motor (T = 0)."""
    return [math.exp(-tau / t) if t > 0.0 else 0.0 for t in time_constants]


# ---- elementary functions without a call or a branch ---------------------------------------------------------------
# libm's sin, cos, atan2 and exp are calls, and a loop that calls cannot run its lanes side by side (the PyPI llvmlite
# has no vector maths library): rollout_lanes' derivative uses these instead (_cos_sin_of & co. choose), so that its
# lanes run eight wide with AVX-512; one row at a time libm's calls are cheaper. Each is within a few ulp of libm
# (test_kernel.py measures them compiled as the rollout is, with its fastmath flags).
_TWO_OVER_PI = 0.63661977236758134308  # 2 / pi
_PIO2_1, _PIO2_2, _PIO2_3 = 1.57079632673412561417e+00, 6.07710050630396597660e-11, 2.02226624871116645580e-21
# pi / 2 in three parts (fdlibm's rem_pio2), and fdlibm's __kernel_sin, __kernel_cos minimax coefficients on |r| <= pi/4
_S1, _S2, _S3, _S4, _S5, _S6 = (-1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04,
                                2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10)
_K1, _K2, _K3, _K4, _K5, _K6 = (4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05,
                                -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11)
# fdlibm's atan minimax coefficients on |t| <= 7/16, and pi/4, pi/2, pi as a double and the rest
_A0, _A1, _A2, _A3, _A4, _A5, _A6, _A7, _A8, _A9, _A10 = (
    3.33333333333329318027e-01, -1.99999999998764832476e-01, 1.42857142725034663711e-01, -1.11111104054623557880e-01,
    9.09088713343650656196e-02, -7.69187620504482999495e-02, 6.66107313738753120669e-02, -5.83357013379057348645e-02,
    4.97687799461593236017e-02, -3.65315727442169155270e-02, 1.62858201153657823623e-02)
_TAN_PI_8 = 0.41421356237309504880
_PI_4, _PI_4_LO = 7.85398163397448278999e-01, 3.06161699786838301793e-17
_PI_2, _PI_2_LO = 1.57079632679489655800e+00, 6.12323399573676603587e-17
_PI, _PI_LO = 3.14159265358979311600e+00, 1.22464679914735317720e-16
EXP_FLOOR = -40.0  # _exp_neg's lowest argument: exp(-40) = 4.2e-18
_INV_LN2 = 1.44269504088896338700  # 1 / ln 2
_LN2_HI, _LN2_LO = 6.93147180369123816490e-01, 1.90821492927058770002e-10  # ln 2 in two parts (fdlibm)
# 1/2!, ..., 1/13!: the Taylor series of expm1 to r^13 (_exp_neg's, and _tanh's below)
_EXPM1_TAYLOR = tuple(1.0 / math.factorial(k) for k in range(2, 14))
_C2, _C3, _C4, _C5, _C6, _C7, _C8, _C9, _C10, _C11, _C12, _C13 = _EXPM1_TAYLOR


@intrinsic
def _sqrt_intrinsic(typingctx, x):
    """LLVM's sqrt instruction (NaN below 0, as libm's): numba calls libm's sqrt, which LLVM turns into the
    instruction only where it proves the argument non-negative, and a call keeps a loop one lane wide."""
    def codegen(context, builder, signature, args):
        double = llvm_ir.DoubleType()
        function = cgutils.get_or_insert_function(builder.module, llvm_ir.FunctionType(double, [double]),
                                                  "llvm.sqrt.f64")
        return builder.call(function, args)
    return types.float64(types.float64), codegen


@intrinsic
def _data(typingctx, array):
    """A pointer to an array's first element (it indexes as the array does, p[i]), which carries no reference count:
    an array handed to an inlined function is counted in and out, and those calls keep a loop one lane wide."""
    def codegen(context, builder, signature, args):
        return context.make_array(signature.args[0])(context, builder, args[0]).data
    return types.CPointer(array.dtype)(array), codegen


@njit(cache=CACHED, inline="always", **VECTOR)
def _sqrt(x):
    """sqrt x (the instruction; NaN below 0)."""
    return _sqrt_intrinsic(x)


@njit(cache=CACHED, inline="always", **VECTOR)
def _cos_sin(x):
    """(cos x, sin x): x - k pi/2 in three parts (Cody & Waite), the minimax polynomials on |r| <= pi/4, the
    quadrant by selects. NaN and inf give NaN. Within 1 ulp compiled alone; in the rollout, whose flags let the
    compiler fold the three parts into one double, within ~4e-17 |x| (1.2e-15 at |x| = 30)."""
    k = math.floor(x * _TWO_OVER_PI + 0.5)
    r = ((x - k * _PIO2_1) - k * _PIO2_2) - k * _PIO2_3
    z = r * r
    s = r + r * z * (_S1 + z * (_S2 + z * (_S3 + z * (_S4 + z * (_S5 + z * _S6)))))
    hz = 0.5 * z
    w = 1.0 - hz
    c = w + (((1.0 - w) - hz) + z * z * (_K1 + z * (_K2 + z * (_K3 + z * (_K4 + z * (_K5 + z * _K6))))))
    q = k - 4.0 * math.floor(0.25 * k)  # the quadrant 0, 1, 2, 3
    odd = q == 1.0 or q == 3.0
    sin_x = c if odd else s
    cos_x = s if odd else c
    sin_x = -sin_x if q >= 2.0 else sin_x
    cos_x = -cos_x if (q == 1.0 or q == 2.0) else cos_x
    finite = abs(x) < math.inf  # inf - inf may fold away: NaN said outright
    return (cos_x if finite else math.nan), (sin_x if finite else math.nan)


@njit(cache=CACHED, inline="always", **VECTOR)
def _atan2(y, x):
    """atan2(y, x) (rad): t = min / max of |x|, |y| in [0, 1], reduced to |t| <= tan(pi/8) by (t - 1) / (t + 1)
    (+ pi/4), the minimax polynomial, then the octant and the quadrant by selects; atan2(0, 0) = 0."""
    ax, ay = abs(x), abs(y)
    big = max(ax, ay)
    t = min(ax, ay) / max(big, 1e-300)
    reduced = t > _TAN_PI_8
    t_reduced = (t - 1.0) / (t + 1.0)  # both values of each choice computed first: selects, not branches
    t = t_reduced if reduced else t
    z = t * t
    w = z * z
    odd = z * (_A0 + w * (_A2 + w * (_A4 + w * (_A6 + w * (_A8 + w * _A10)))))
    even = w * (_A1 + w * (_A3 + w * (_A5 + w * (_A7 + w * _A9))))
    a = t - t * (odd + even)
    a = _PI_4 + (a + _PI_4_LO) if reduced else a
    a = (_PI_2 - a) + _PI_2_LO if ay > ax else a
    a = (_PI - a) + _PI_LO if x < 0.0 else a
    return -a if y < 0.0 else a


@njit(cache=CACHED, inline="always", **VECTOR)
def _exp_neg(x):
    """exp x for x <= 0 (below EXP_FLOOR as at it): x = -m ln 2 + r with |r| <= ln 2 / 2, exp r from the Taylor
    series to r^13 (the rest below 4e-18), times 2^-m from m's six bits (exact: powers of two). Within 2 ulp alone;
    in the rollout, whose flags fold ln 2's two parts into one double, within ~2.3e-17 m relatively (1.3e-15 at the
    floor)."""
    x = max(x, EXP_FLOOR)
    m = math.floor(0.5 - x * _INV_LN2)  # 0 ... 58
    r = (x + m * _LN2_HI) + m * _LN2_LO
    e = 1.0 + r * (1.0 + r * (_C2 + r * (_C3 + r * (_C4 + r * (_C5 + r * (_C6 + r * (_C7 + r * (_C8 + r * (
        _C9 + r * (_C10 + r * (_C11 + r * (_C12 + r * _C13))))))))))))
    half = math.floor(0.5 * m)
    e = e * (0.5 if m - 2.0 * half > 0.0 else 1.0)
    m, half = half, math.floor(0.5 * half)
    e = e * (0.25 if m - 2.0 * half > 0.0 else 1.0)
    m, half = half, math.floor(0.5 * half)
    e = e * (0.0625 if m - 2.0 * half > 0.0 else 1.0)
    m, half = half, math.floor(0.5 * half)
    e = e * (2.0 ** -8 if m - 2.0 * half > 0.0 else 1.0)
    m, half = half, math.floor(0.5 * half)
    e = e * (2.0 ** -16 if m - 2.0 * half > 0.0 else 1.0)
    return e * (2.0 ** -32 if half > 0.0 else 1.0)



def _cos_sin_of(p, x):
    """(cos x, sin x): _cos_sin's where p is a pointer (_data: rollout_lanes', whose lanes run side by side), libm's
    where p is an array (one row at a time a call is cheaper). Chosen by p's type as the caller is compiled, so that
    the caller holds only the one it uses (the other would cost its compile time, not its run time)."""
    return math.cos(x), math.sin(x)


def _atan2_of(p, y, x):
    """atan2(y, x): _atan2's where p is a pointer, libm's where it is an array (_cos_sin_of)."""
    return math.atan2(y, x)


def _exp_of(p, x):
    """exp x (x <= 0): _exp_neg's where p is a pointer, libm's where it is an array (_cos_sin_of)."""
    return math.exp(x)


@overload(_cos_sin_of, inline="always", jit_options=VECTOR)
def _cos_sin_by_type(p, x):
    if isinstance(p, types.CPointer):
        return lambda p, x: _cos_sin(x)
    return lambda p, x: (math.cos(x), math.sin(x))


@overload(_atan2_of, inline="always", jit_options=VECTOR)
def _atan2_by_type(p, y, x):
    if isinstance(p, types.CPointer):
        return lambda p, y, x: _atan2(y, x)
    return lambda p, y, x: math.atan2(y, x)


@overload(_exp_of, inline="always", jit_options=VECTOR)
def _exp_by_type(p, x):
    if isinstance(p, types.CPointer):
        return lambda p, x: _exp_neg(x)
    return lambda p, x: math.exp(x)


# ---- the sea --------------------------------------------------------------------------------------------------------

@_compiled
def _fourier(ki, p, k, chi):
    """Table k's a0/2 + sum a_n cos(n chi) + b_n sin(n chi) (-) at chi (rad) (seed 000 eq. 19)."""
    o = ki[K_O_DRIFT] + 3 * k * ki[K_DRIFT_ROWS]
    value = p[o]
    for i in range(1, ki[K_DRIFT_ROWS]):
        row = o + 3 * i
        if p[row + 1] != 0.0:
            value += p[row + 1] * math.cos(p[row] * chi)
        if p[row + 2] != 0.0:
            value += p[row + 2] * math.sin(p[row] * chi)
    return value


@_compiled
def _air_load(p, u_rw, v_rw):
    """(X, Y, N) of the apparent wind (u_rw, v_rw) in the body frame (seed 000 eq. 12-14)."""
    v2 = u_rw * u_rw + v_rw * v_rw
    gamma = -math.atan2(v_rw, u_rw)
    return (-p[P_WIND_X] * v2 * math.cos(gamma), p[P_WIND_Y] * v2 * math.sin(gamma),
            p[P_WIND_N] * v2 * math.sin(2.0 * gamma))


@_inlined
def _drift_load(p, sea, fx, fy, fn, cos_chi):
    """(X, Y, N) of the mean wave drift from its tables' values (fx, fy, fn) at chi, cos_chi = cos chi: q_wave
    zeta_a^2 times them (N: times L as well), less the head-sea added resistance q_wave zeta_a^2 C_AW max(cos chi,
    0)^2 (GreyBoxRollout._sea_loads_with). _sea_loads and _lanes_wave_drift both finish their sums here."""
    head = max(cos_chi, 0.0)
    return sea[4] * fx - sea[7] * head * head, sea[4] * fy, sea[4] * p[P_L_SEA] * fn


@_compiled
def _sea_loads(ki, p, sea, c, s, psi, u_r, v_r):
    """(X, Y, N) of the wind over the still-air drag and the mean wave drift at heading psi (c, s its cosine and sine);
    sea = _sea_of's (current n, e, wind n, e (m/s), q_wave zeta_a^2 (N), wave direction from (rad), waves on (1/0),
    q_wave zeta_a^2 C_AW (N): the head-sea added resistance beyond the drift series): GreyBoxRollout._sea_loads_with.
    Without wind the increment is exactly zero and is not computed; without waves the drift is left out (the torch
    twin adds a 1e-15 m wave's, the price of a finite gradient at zero there)."""
    x = y = n = 0.0
    if sea[2] != 0.0 or sea[3] != 0.0:
        u_g = u_r + sea[0] * c + sea[1] * s
        v_g = v_r - sea[0] * s + sea[1] * c
        wx, wy, wn = _air_load(p, u_g - (sea[2] * c + sea[3] * s), v_g - (-sea[2] * s + sea[3] * c))
        sx, sy, sn = _air_load(p, u_g, v_g)
        x, y, n = wx - sx, wy - sy, wn - sn
    if sea[6] != 0.0:
        chi = sea[5] - psi
        dx, dy, dn = _drift_load(p, sea, _fourier(ki, p, 0, chi), _fourier(ki, p, 1, chi), _fourier(ki, p, 2, chi),
                                 math.cos(chi))
        x, y, n = x + dx, y + dy, n + dn
    return x, y, n


@_compiled
def _sea_of(p):
    """The sea terms' values over a rollout (GreyBoxRollout._sea_terms): current, wind, q_wave zeta_a^2, wave from,
    whether there are waves, and q_wave zeta_a^2 C_AW."""
    amp = math.sqrt(p[T_WAVE_N] ** 2 + p[T_WAVE_E] ** 2 + 1e-30)  # as the torch twin (a finite gradient there)
    waves = 1.0 if p[T_WAVE_N] != 0.0 or p[T_WAVE_E] != 0.0 else 0.0
    return (p[T_CURRENT_N], p[T_CURRENT_E], p[T_WIND_N], p[T_WIND_E], p[P_Q_WAVE] * amp,
            math.atan2(p[T_WAVE_E], p[T_WAVE_N]), waves, p[P_Q_WAVE] * amp * p[T_WAVE_RESISTANCE])


# ---- hull models ----------------------------------------------------------------------------------------------------

@_inlined
def _hull_forces(hull, ki, p, u_r, v_r, r):
    """(X_H, Y_H, N_H) at midship (N, N, N m) of the hull model `hull`, with the relative resistance change of the
    terms."""
    h = ki[K_O_HULL]
    change = p[T_RESISTANCE_CHANGE]
    if hull == MMG:  # Yasukawa & Yoshimura 2015 eq. 8, regularised below the speed floor
        L = p[P_L]
        U = max(_sqrt(u_r * u_r + v_r * v_r), p[P_SPEED_FLOOR])
        vp = v_r / U
        rp = r * L / U
        q = p[P_Q_FORCE] * U * U
        vv, rr = vp * vp, rp * rp  # products, not pow(): a power call costs as much as the polynomial
        x_h = q * (-p[h] * (1.0 + change) * u_r * abs(u_r) / (U * U) + p[h + 1] * vv + p[h + 2] * vp * rp
                   + p[h + 3] * rr + p[h + 4] * (vv * vv))
        y_h = q * (p[h + 5] * vp + p[h + 6] * rp + p[h + 7] * (vv * vp) + p[h + 8] * vv * rp + p[h + 9] * vp * rr
                   + p[h + 10] * (rr * rp))
        n_h = q * L * (p[h + 11] * vp + p[h + 12] * rp + p[h + 13] * (vv * vp) + p[h + 14] * vv * rp
                       + p[h + 15] * vp * rr + p[h + 16] * (rr * rp))
        return x_h, y_h, n_h
    # small craft: linear + quadratic damping, strip-theory cross-flow drag (Fossen's crossFlowDrag)
    y_cf = 0.0
    n_cf = 0.0
    o = ki[K_O_STRIPS]
    for k in range(ki[K_N_STRIPS]):
        x = p[o + k]
        w = v_r + x * r
        f = abs(w) * w
        y_cf += f
        n_cf += x * f
    cross = -p[P_HALF_RHO_D] * p[h + ki[K_CD]] * p[P_STRIP_DX]
    x_h = (1.0 + change) * ((p[h + ki[K_XU]] + p[h + ki[K_XUU]] * abs(u_r)) * u_r)
    y_h = p[h + ki[K_YV]] * v_r + p[h + ki[K_YR]] * r + cross * y_cf
    n_h = p[h + ki[K_NV]] * v_r + p[h + ki[K_NR]] * r + p[h + ki[K_NRR]] * abs(r) * r + cross * n_cf
    return x_h, y_h, n_h


@_inlined
def _solve(hull, ki, p, x, y, n, u_r, v_r, r):
    """nu_r_dot = M^-1 (tau - C(nu_r) nu_r): MMG eq. 4 (the Munk moment in N_v), or the small-craft hull's with its
    fitted added mass and the Munk moment (Y_vdot - X_udot) u_r v_r."""
    m, x_g = p[P_M], p[P_X_G]
    m23, m32 = p[P_M23], p[P_M32]
    if hull == MMG:
        m11, m22, m33, det = p[P_M11], p[P_M22], p[P_M33], p[P_DET_VR]
        munk = 0.0
    else:
        h = ki[K_O_HULL]
        x_udot, y_vdot = p[h + ki[K_XUD]], p[h + ki[K_YVD]]
        m11 = m - x_udot
        m22 = m - y_vdot
        m33 = p[P_M33_RIGID] - p[h + ki[K_NRD]]
        det = m22 * m33 - m23 * m32
        munk = (y_vdot - x_udot) * u_r * v_r
    rhs_x = x + m22 * v_r * r + x_g * m * r * r
    rhs_y = y - m11 * u_r * r
    rhs_n = n - x_g * m * u_r * r + munk
    return rhs_x / m11, (m33 * rhs_y - m23 * rhs_n) / det, (m22 * rhs_n - m32 * rhs_y) / det


@_compiled
def _resistance(ki, p):
    """(r1 (N s/m), r2 (N s^2/m^2)) of the straight-running resistance r1 u + r2 u^2."""
    h = ki[K_O_HULL]
    change = p[T_RESISTANCE_CHANGE]
    if ki[K_HULL] == MMG:
        return 0.0, p[P_Q_FORCE] * p[h] * (1.0 + change)
    return -p[h + ki[K_XU]] * (1.0 + change), -p[h + ki[K_XUU]] * (1.0 + change)


# ---- actuator force models ------------------------------------------------------------------------------------------

@_inlined
def _thrust(ki, p, k, level):
    """Thrust map k's vessel.ThrustMap.thrust (N): dead band, then the power law or the piecewise-linear table."""
    width = ki[K_MAP_WIDTH]
    o = ki[K_O_MAPS] + k * (5 + 2 * width)  # [spec (5), table commands (width), table thrusts (width)]
    c = min(max(level, -1.0), 1.0)
    a = max(abs(c) - p[o + 3], 0.0) / (1.0 - p[o + 3])
    e = a if c > 0.0 else -a
    if p[o + 4] > 0.0:
        tx, ty = o + 5, o + 5 + width
        y = p[ty]
        for i in range(ki[K_MAP_N0 + k] - 1):
            step = p[tx + i + 1] - p[tx + i]
            y += (p[ty + i + 1] - p[ty + i]) / step * min(max(e - p[tx + i], 0.0), step)
        return y
    if e >= 0.0:
        return p[o] * max(e, 0.0) ** p[o + 2]
    return -p[o + 1] * max(-e, 0.0) ** p[o + 2]


@_inlined
def _rudder_propeller(p, u_r, v_r, r, rpm, cos_d, sin_d):
    """(X_R, Y_R, N_R, X_P, Y_P, N_P): the MMG rudder with slipstream (eq. 13-16, 37-43) and propeller (eq. 10-12);
    cos_d, sin_d the rudder angle's (the rollout computes them once per level, not once per stage)."""
    L = p[P_L_ACT]
    speed = _sqrt(u_r * u_r + v_r * v_r) + 1e-9
    beta_p = _atan2_of(p, -v_r, max(u_r, 1e-9)) - p[P_X_P] * r * L / speed
    u_p = u_r * (1.0 - p[P_W_P0] * _exp_of(p, -4.0 * beta_p * beta_p))
    n_raw = rpm / 60.0 / p[P_GEAR_RATIO]
    n_p = max(n_raw, 1e-6)
    d_p = p[P_D_P]
    j = u_p / (n_p * d_p)
    k_t = p[P_K0] + p[P_K1] * j + p[P_K2] * j * j
    running = 1.0 if n_raw > 1e-6 else 0.0
    d2 = d_p * d_p
    x_p = running * (1.0 - p[P_T_P]) * p[P_RHO] * n_p * n_p * (d2 * d2) * k_t
    slip = _sqrt(u_p * u_p + running * 8.0 * max(k_t, 0.0) * n_p * n_p * d2 / math.pi)
    eta = p[P_ETA]
    jet = u_p + p[P_KAPPA] * (slip - u_p)
    u_rud = p[P_EPSILON] * _sqrt(eta * jet * jet + (1.0 - eta) * u_p * u_p)
    beta_r = -(v_r + p[P_L_R_M] * r)  # U beta_R (m/s): the inflow angle as U sin(beta) = -v (docs/kernel.md)
    gamma_minus, gamma_plus = p[P_GAMMA_R_MINUS], p[P_GAMMA_R_PLUS]
    gamma_r = gamma_minus if beta_r < 0.0 else gamma_plus
    v_rud = gamma_r * beta_r
    # sin(alpha), alpha = delta - atan2(v_rud, u_c) (eq. 14), by the angle difference: sin delta cos theta -
    # cos delta sin theta with cos theta = u_c / h, sin theta = v_rud / h: one sqrt instead of an atan2 and a sine
    u_c = max(u_rud, 1e-9)
    inflow = _sqrt(u_c * u_c + v_rud * v_rud)
    sin_alpha = (sin_d * u_c - cos_d * v_rud) / inflow
    f_n = 0.5 * p[P_RHO] * p[P_A_R] * (u_rud * u_rud + v_rud * v_rud) * p[P_F_ALPHA] * sin_alpha
    y_p = p[T_SIDE_FORCE] * x_p / (1.0 - p[P_T_P])
    return (-(1.0 - p[P_T_R]) * f_n * sin_d, -(1.0 + p[P_A_H]) * f_n * cos_d,
            -(p[P_X_R_M] + p[P_A_H] * p[P_X_H_M]) * f_n * cos_d, x_p, y_p, y_p * p[P_X_P] * L)


@_inlined
def _actuator_forces(layout, ki, p, u_r, v_r, r, a, b):
    """(X, Y, N) of steering then of propulsion at the levels (a, b) of the layout."""
    if layout == TWIN_THRUSTERS:
        return _actuator_forces_at(layout, ki, p, u_r, v_r, r, a, b, 0.0, 0.0)
    return _actuator_forces_at(layout, ki, p, u_r, v_r, r, a, b, math.cos(a), math.sin(a))


@_inlined
def _actuator_forces_at(layout, ki, p, u_r, v_r, r, a, b, cos_a, sin_a):
    """_actuator_forces with the rudder angle's cosine and sine given (a rudder layout's; unused with thrusters)."""
    if layout == TWIN_THRUSTERS:
        imbalance = p[T_THRUST_IMBALANCE]
        t_p = (1.0 + imbalance) * _thrust(ki, p, 0, a)
        t_s = (1.0 - imbalance) * _thrust(ki, p, 1, b)
        return 0.0, 0.0, p[P_HALF_SPACING] * (t_p - t_s), t_p + t_s, 0.0, 0.0
    rpm = b
    if layout == RUDDER_THROTTLE:  # the engine speed whose static thrust is the map's at the level
        thrust = max(_thrust(ki, p, 0, b), 0.0)
        rpm = _sqrt(thrust / p[P_STATIC_THRUST]) * p[P_RPM_PER_REV_S]
    return _rudder_propeller(p, u_r, v_r, r, rpm, cos_a, sin_a)


@_inlined
def _lagged(ki, p, k, y0, u0, u1, u2, h):
    """Exact first-order lag k over a substep for a linear command u0 -> u2: the levels at h/2 and h (CommandLag)."""
    o = ki[K_O_LAG] + 3 * k  # [T (s), exp(-h/2T), exp(-h/T)]
    drift = p[o] * (u2 - u0) / h
    start = y0 - u0 + drift
    return u1 - drift + start * p[o + 1], u2 - drift + start * p[o + 2]


# ---- residuals (models/hybrid.py) -----------------------------------------------------------------------------------

@_compiled
def _polynomial_residual(ki, p, u, v, r):
    """The Abkowitz terms beyond the MMG hull as accelerations (PolynomialResidual)."""
    o = ki[K_O_COEF]
    U = max(math.sqrt(u * u + v * v), 1e-3)
    L = p[P_POLY_L]
    vp, rp, du = v / U, r * L / U, (u - p[P_POLY_U0]) / U
    q = p[P_POLY_Q_FORCE] * U * U
    x = q * p[o] * du
    y = q * (p[o + 1] + p[o + 2] * du * vp + p[o + 3] * du * rp)
    n = q * L * (p[o + 4] + p[o + 5] * du * vp + p[o + 6] * du * rp)
    m22, m23, m32, m33 = p[P_POLY_M22], p[P_POLY_M23], p[P_POLY_M32], p[P_POLY_M33]
    det = m22 * m33 - m23 * m32
    return x / p[P_POLY_M11], (m33 * y - m23 * n) / det, (m22 * n - m32 * y) / det



# tanh from exp(-2|x|) = exp(-2|x| / 64)^64: the Taylor series of expm1 to r^13 on |r| <= 0.625, then six squarings
# carried as m = t - 1 ((1 + m)^2 - 1 = m (2 + m)), so that 1 - t = -m and 1 + t = 2 + m never cancel
TANH_SATURATION = 20.0  # |x| beyond which tanh x is +-1 in float64 (1 - tanh 20 = 8.5e-18)


@njit(cache=CACHED, inline="always", **VECTOR)
def _tanh(x):
    """tanh x = -m / (2 + m), m = exp(-2 |x|) - 1 (above), the sign restored; NaN stays NaN. Within 4.5e-16 of tanh x
    absolutely and 7e-16 relatively (test_kernel.py), without a call or a branch: a loop of them runs eight lanes
    wide (AVX-512) where a loop of libm's exp runs one."""
    a = abs(x)
    a = TANH_SATURATION if a > TANH_SATURATION else a
    r = a * (-2.0 / 64.0)
    m = r * (1.0 + r * (_C2 + r * (_C3 + r * (_C4 + r * (_C5 + r * (_C6 + r * (_C7 + r * (_C8 + r * (
        _C9 + r * (_C10 + r * (_C11 + r * (_C12 + r * _C13))))))))))))
    for _ in range(6):
        m = m * (2.0 + m)
    y = -m / (2.0 + m)
    return y if x >= 0.0 else -y


@njit(cache=CACHED, inline="always", **VECTOR)
def _tanh_layer(p, weights, bias, x, out):
    """out = tanh(W x + b) (one dense layer): W (len(out), len(x)) output-major at p[weights:], b at p[bias:]."""
    n_in = x.size
    for j in range(out.size):
        row = p[weights + j * n_in:weights + (j + 1) * n_in]
        acc = 0.0
        for i in range(n_in):
            acc += row[i] * x[i]
        out[j] = acc + p[bias + j]
    for j in range(out.size):
        out[j] = _tanh(out[j])


@njit(cache=CACHED, inline="always", **VECTOR)
def _mlp_residual(ki, p, e, work, psi, u, v, r, a, b):
    """Member e's bounded residual accelerations (GeneralisingResidual): features -> z -> tanh layers -> bound tanh,
    times the support envelope, scaled by U^2 / L (surge, sway) and U^2 / L^2 (yaw). Weights in p, member-major; the
    first layer's input-major (seven vector updates of the hidden vector), the others output-major (each output's
    weights contiguous: one dot product per output): w0 (E, F, W), b0 (E, W), wh (E, layers, W_out, W_in),
    bh (E, layers, W), wo (E, 3, W), bo (E, 3); norm (5, F): in_mean, in_std, z_low, z_high, the bound (first 3).
    work (3, max(W, F)) scratch: z, then the layers in turn."""
    hidden, layers = ki[K_HIDDEN], ki[K_HIDDEN_LAYERS]
    L = p[P_MLP_L]
    speed = max(math.sqrt(u * u + v * v), p[P_MLP_SPEED_FLOOR])
    feats = (v / speed, r * L / speed, speed / p[P_MLP_U_REF], a, b, math.sin(psi), math.cos(psi))
    width = p[P_MLP_SUPPORT_WIDTH]
    norm = ki[K_O_NORM]
    z = work[0, :N_FEATURES]
    beyond2 = 0.0
    for i in range(N_FEATURES):
        zi = (feats[i] - p[norm + i]) / p[norm + N_FEATURES + i]
        over = max(zi - p[norm + 3 * N_FEATURES + i], 0.0) + max(p[norm + 2 * N_FEATURES + i] - zi, 0.0)
        beyond2 += (over / width) ** 2
        z[i] = zi
    h = work[1, :hidden]
    g = work[2, :hidden]
    # seven vector updates of h: seven-long dot products would not vectorise
    w0 = ki[K_O_W0] + e * N_FEATURES * hidden
    b0 = ki[K_O_B0] + e * hidden
    bias = p[b0:b0 + hidden]
    for j in range(hidden):
        h[j] = bias[j]
    for i in range(N_FEATURES):
        zi = z[i]
        row = p[w0 + i * hidden:w0 + (i + 1) * hidden]
        for j in range(hidden):
            h[j] += zi * row[j]
    for j in range(hidden):
        h[j] = _tanh(h[j])
    for layer in range(layers):
        _tanh_layer(p, ki[K_O_WH] + (e * layers + layer) * hidden * hidden, ki[K_O_BH] + (e * layers + layer) * hidden,
                    h, g)
        h, g = g, h
    wo = ki[K_O_WO] + e * 3 * hidden
    bo = ki[K_O_BO] + e * 3
    w_u = p[wo:wo + hidden]
    w_v = p[wo + hidden:wo + 2 * hidden]
    w_r = p[wo + 2 * hidden:wo + 3 * hidden]
    out_u, out_v, out_r = p[bo], p[bo + 1], p[bo + 2]
    for i in range(hidden):
        out_u += w_u[i] * h[i]
        out_v += w_v[i] * h[i]
        out_r += w_r[i] * h[i]
    envelope = math.exp(-0.5 * beyond2)
    q = feats[2] * p[P_MLP_U_REF]
    q = q * q / L
    bound = norm + 4 * N_FEATURES
    return (p[bound] * _tanh(out_u) * envelope * q, p[bound + 1] * _tanh(out_v) * envelope * q,
            p[bound + 2] * _tanh(out_r) * envelope * q / L)


# ---- the float model's entry points (physics/dynamics.ManoeuvringModel) -----------------------------------------

@_compiled
def loads(ki, p, sea, psi, u_r, v_r, r, a, b):
    """(hull X, Y, N, steering X, Y, N, propulsion X, Y, N, wind X, Y, N, waves X, Y, N) at midship (N, N m) for the
    water-relative velocities, the actuator levels (a, b) and sea = sea_tuple's."""
    c, s = math.cos(psi), math.sin(psi)
    hx, hy, hn = _hull_forces(ki[K_HULL], ki, p, u_r, v_r, r)
    ax, ay, an, px, py, pn = _actuator_forces(ki[K_LAYOUT], ki, p, u_r, v_r, r, a, b)
    calm = (sea[0], sea[1], sea[2], sea[3], 0.0, 0.0, 0.0, 0.0)
    wx, wy, wn = _sea_loads(ki, p, calm, c, s, psi, u_r, v_r)
    waves = (sea[0], sea[1], 0.0, 0.0, sea[4], sea[5], sea[6], sea[7])
    vx, vy, vn = _sea_loads(ki, p, waves, c, s, psi, u_r, v_r)
    return hx, hy, hn, ax, ay, an, px, py, pn, wx, wy, wn, vx, vy, vn


@_compiled
def actuator_loads_many(ki, p, nu, levels, out):
    """out (T, 6): the steering then propulsion (X, Y, N) of each sample's water-relative nu (T, 3) at its actuator
    levels (T, 2): one call for a recording (identification's known forces)."""
    for k in range(nu.shape[0]):
        out[k, 0], out[k, 1], out[k, 2], out[k, 3], out[k, 4], out[k, 5] = _actuator_forces(
            ki[K_LAYOUT], ki, p, nu[k, 0], nu[k, 1], nu[k, 2], levels[k, 0], levels[k, 1])
    return out


@_compiled
def accelerations(ki, p, sea, psi, u_r, v_r, r, a, b, accel_n, accel_e):
    """(u_r_dot, v_r_dot, r_dot) = M^-1 (tau - C(nu_r) nu_r - M_RB R^T dV_c/dt): a turning current accelerates the
    water and the rigid body feels it (Fossen 2021 sec. 10.3); accel_n, accel_e the current's d/dt (m/s^2)."""
    c, s = math.cos(psi), math.sin(psi)
    hx, hy, hn = _hull_forces(ki[K_HULL], ki, p, u_r, v_r, r)
    ax, ay, an, px, py, pn = _actuator_forces(ki[K_LAYOUT], ki, p, u_r, v_r, r, a, b)
    lx, ly, ln = _sea_loads(ki, p, sea, c, s, psi, u_r, v_r)
    x, y, n = hx + ax + px + lx, hy + ay + py + ly, hn + an + pn + ln
    if accel_n != 0.0 or accel_e != 0.0:
        m = p[P_M]
        a_u = accel_n * c + accel_e * s
        a_v = -accel_n * s + accel_e * c
        x -= m * a_u
        y -= m * a_v
        n -= m * p[P_X_G] * a_v
    return _solve(ki[K_HULL], ki, p, x, y, n, u_r, v_r, r)


def sea_tuple(q_wave: float, current_n: float, current_e: float, wind_speed: float, wind_from: float,
              wave_amplitude: float, wave_from: float, wave_resistance: float) -> tuple[float, ...]:
    """The kernel's sea (_sea_of) from the float model's: the wind's velocity TOWARD (north, east) from its speed and
    the direction it blows FROM, the wave drift's q_wave zeta_a^2 (N) and direction, and its head-sea added
    resistance q_wave zeta_a^2 C_AW (N)."""
    drift = q_wave * wave_amplitude * wave_amplitude
    return (current_n, current_e, -wind_speed * math.cos(wind_from), -wind_speed * math.sin(wind_from),
            drift, wave_from, 1.0 if wave_amplitude > 0.0 else 0.0, drift * wave_resistance)


# ---- the rollout ----------------------------------------------------------------------------------------------------

@_inlined
def _motion(kind, ki, p, sea, psi, u_r, v_r, r, a, b, cos_a, sin_a, lx, ly, ln):
    """(x_n_dot, y_e_dot, u_r_dot, v_r_dot, r_dot) of the grey box without a learned residual at the actuator levels
    (a, b); cos_a, sin_a a rudder layout's cos a, sin a; (lx, ly, ln) sea loads the caller computed (rollout_lanes'
    wave drift: 0 elsewhere). kind (hull, layout, residual, loaded): the hull model, the
    layout, K_RESIDUAL's bits (_derivative's) and whether sea's wind or waves load the hull (rollout passes ki's and
    1; rollout_lanes constants, which fold its branches away, with ki as a tuple and p as a pointer, which carry no
    reference count, and p's type picks the elementary functions without a call, _cos_sin_of: its lanes then run
    side by side)."""
    hull, layout, _, loaded = kind
    c, s = _cos_sin_of(p, psi)
    hx, hy, hn = _hull_forces(hull, ki, p, u_r, v_r, r)
    ax, ay, an, px, py, pn = _actuator_forces_at(layout, ki, p, u_r, v_r, r, a, b, cos_a, sin_a)
    if loaded and (sea[2] != 0.0 or sea[3] != 0.0 or sea[6] != 0.0):  # calm water: _sea_loads' zeros, no call
        sx, sy, sn = _sea_loads(ki, p, sea, c, s, psi, u_r, v_r)
        lx, ly, ln = lx + sx, ly + sy, ln + sn
    du, dv, dr = _solve(hull, ki, p, hx + ax + px + lx, hy + ay + py + ly, hn + an + pn + ln, u_r, v_r, r)
    u = u_r + sea[0] * c + sea[1] * s
    v = v_r - sea[0] * s + sea[1] * c
    return u * c - v * s, u * s + v * c, du, dv, dr


@_inlined
def _derivative(kind, ki, p, sea, free, e, work, psi, u_r, v_r, r, a, b, cos_a, sin_a):
    """d/dt of [x_n, y_e, psi, u_r, v_r, r] at the actuator levels (a, b) (GreyBoxRollout._derivative): _motion
    with member e's learned residual (kind: _motion's), sway and yaw times free (0: held)."""
    residual = kind[2]
    x_dot, y_dot, du, dv, dr = _motion(kind, ki, p, sea, psi, u_r, v_r, r, a, b, cos_a, sin_a, 0.0, 0.0, 0.0)
    if residual != 0:
        eu = ev = er = 0.0
        if residual & RESIDUAL_POLYNOMIAL:
            eu, ev, er = _polynomial_residual(ki, p, u_r, v_r, r)
        if residual & RESIDUAL_MLP:
            mu, mv, mr = _mlp_residual(ki, p, e, work, psi, u_r, v_r, r, a, b)
            eu, ev, er = eu + mu, ev + mv, er + mr
        du, dv, dr = du + eu, dv + ev, dr + er
    return x_dot, y_dot, r, du, dv * free, dr * free


# ---- the rollout's parts, shared by rollout and rollout_lanes ----------------------------------------------------
# a row's start (_held_controls, _start) is called once per row: compiled once and called, not inlined into every
# rollout (inlined, it cost each of them ~5 s of compile time); the per-substep parts are inlined

@_compiled
def _held_controls(p, controls, b, held):
    """held (H, C) = row b's controls as the hull feels them: shifted later by actuator_delay (linear interpolation,
    the first value held before)."""
    steps, width = held.shape
    shift = p[T_ACTUATOR_DELAY] / p[P_DT]
    for k in range(steps):
        if shift != 0.0:
            index = min(max(k - shift, 0.0), float(steps - 1))
            low = math.floor(index)
            frac = index - low
            lo = int(low)
            hi = min(lo + 1, steps - 1)
            for i in range(width):
                held[k, i] = controls[b, lo, i] * (1.0 - frac) + controls[b, hi, i] * frac
        else:
            for i in range(width):
                held[k, i] = controls[b, k, i]


@_compiled
def _start(layout, ki, p, sea, state, reference, use_reference, held, b):
    """Row b's start: (psi, u_r, v_r, r) water-relative with the sensors' terms removed, from the measured state, and
    the layout's carry (a, b): the lagged motors at the first reported commands; rudder_only's held engine speed
    (the engine speed whose thrust holds the reference's straight running, or the one given)."""
    psi = state[b, 3] - p[T_HEADING_OFFSET]
    c, s = math.cos(psi), math.sin(psi)
    u_r = state[b, 0] - (sea[0] * c + sea[1] * s)
    v_r = state[b, 1] - (-sea[0] * s + sea[1] * c)
    r = state[b, 2] - p[T_YAW_RATE_BIAS]
    carry_a = 0.0
    carry_b = 0.0
    if layout == RUDDER_THROTTLE:
        carry_b = held[0, 1]
    elif layout == TWIN_THRUSTERS:
        carry_a = held[0, 0]
        carry_b = held[0, 1]
    elif layout == RUDDER_ONLY:
        psi_held = reference[b, 3] - p[T_HEADING_OFFSET] if use_reference else psi
        c_held, s_held = math.cos(psi_held), math.sin(psi_held)
        speed_held = reference[b, 0] - (sea[0] * c_held + sea[1] * s_held) if use_reference else u_r
        r1, r2 = _resistance(ki, p)
        sea_x = _sea_loads(ki, p, sea, c_held, s_held, psi_held, speed_held, 0.0)[0]
        speed = max(speed_held, 0.0)
        u_p = speed * (1.0 - p[P_W_P0])
        scale = (1.0 - p[P_T_P]) * p[P_RHO]
        d_p = p[P_D_P]
        qa = scale * p[P_K0] * d_p ** 4
        qb = scale * p[P_K1] * d_p ** 3 * u_p
        qc = scale * p[P_K2] * d_p ** 2 * u_p * u_p - (r1 * speed + r2 * speed * speed - sea_x)
        n = (-qb + math.sqrt(max(qb * qb - 4.0 * qa * qc, 0.0))) / (2.0 * qa)
        carry_b = max(n, 0.0) * 60.0 * p[P_GEAR_RATIO]
        if p[P_ENGINE_SPEED_RPM] > 0.0:
            carry_b = p[P_ENGINE_SPEED_RPM]
    return psi, u_r, v_r, r, carry_a, carry_b


@_inlined
def _levels(layout, ki, p, held, k, j, carry_a, carry_b):
    """The actuator levels at substep j of step k's start, middle and end (a0, a1, a2, b0, b1, b2) from the reported
    controls' first-order hold (the layout's stage: lagged motors, rudder offset, rudder_only's held engine speed),
    and the carry after it."""
    steps, width = held.shape
    substeps = ki[K_SUBSTEPS]
    nxt = min(k + 1, steps - 1)
    f0 = j / substeps
    f1 = (j + 0.5) / substeps
    f2 = (j + 1.0) / substeps
    c0a = held[k, 0] + f0 * (held[nxt, 0] - held[k, 0])
    c1a = held[k, 0] + f1 * (held[nxt, 0] - held[k, 0])
    c2a = held[k, 0] + f2 * (held[nxt, 0] - held[k, 0])
    c0b = c1b = c2b = 0.0
    if width > 1:
        c0b = held[k, 1] + f0 * (held[nxt, 1] - held[k, 1])
        c1b = held[k, 1] + f1 * (held[nxt, 1] - held[k, 1])
        c2b = held[k, 1] + f2 * (held[nxt, 1] - held[k, 1])
    h_sub = p[P_DT] / substeps
    if layout == TWIN_THRUSTERS:
        a0, b0 = carry_a, carry_b
        a1, a2 = _lagged(ki, p, 0, carry_a, c0a, c1a, c2a, h_sub)
        b1, b2 = _lagged(ki, p, 1, carry_b, c0b, c1b, c2b, h_sub)
        return a0, a1, a2, b0, b1, b2, a2, b2
    offset = p[T_RUDDER_OFFSET]
    a0, a1, a2 = c0a + offset, c1a + offset, c2a + offset
    if layout == RUDDER_THROTTLE:
        b1, b2 = _lagged(ki, p, 0, carry_b, c0b, c1b, c2b, h_sub)
        return a0, a1, a2, carry_b, b1, b2, carry_a, b2
    if layout == RUDDER_ONLY:
        return a0, a1, a2, carry_b, carry_b, carry_b, carry_a, carry_b
    return a0, a1, a2, c0b, c1b, c2b, carry_a, carry_b


@_inlined
def _measured(p, sea, out, e, b, k, psi, u_r, v_r, r, x_n, y_e):
    """out[e, b, k] = [u, v, r, x_n, y_e, psi] as measured: over ground, with the sensors' terms."""
    c, s = math.cos(psi), math.sin(psi)
    out[e, b, k, 0] = u_r + sea[0] * c + sea[1] * s
    out[e, b, k, 1] = v_r - sea[0] * s + sea[1] * c
    out[e, b, k, 2] = r + p[T_YAW_RATE_BIAS]
    out[e, b, k, 3] = x_n
    out[e, b, k, 4] = y_e
    out[e, b, k, 5] = psi + p[T_HEADING_OFFSET]


# ---- the rollout ----------------------------------------------------------------------------------------------------

# without the GIL: two threads roll out two halves of a batch at once; VECTOR: the learned residual's flags (above)
@njit(cache=CACHED, nogil=True, **VECTOR)
def rollout(state, controls, reference, use_reference, ki, constants, terms, free, out):
    """The grey box's closed-loop rollout into out (E, B, H, 6) [u, v, r, x_n, y_e, psi] as measured, from state
    (B, 4) [u, v, r, psi] as measured and controls (B, H, C) as reported (models/greybox.py's interface); reference
    (B, 4) the straight running of rudder_only's engine speed where use_reference; terms (R, NT) each row's extension
    terms (R = 1: the same for all), free (B,) 0 on a row whose sway and yaw are held. E members of a learned residual
    (1 without one) share the batch: member e's prediction of row b is out[e, b]. One row at a time; rollout_lanes
    runs the same model several rows side by side where it can."""
    rows, steps, width = controls.shape
    members = out.shape[0]
    p = constants.copy()  # the terms of each row go into their place in it
    substeps = ki[K_SUBSTEPS]
    layout = ki[K_LAYOUT]
    kind = (ki[K_HULL], layout, ki[K_RESIDUAL], 1)
    h_sub = p[P_DT] / substeps
    work = np.empty((3, max(ki[K_HIDDEN], N_FEATURES)))  # _mlp_residual's scratch
    held = np.empty((steps, width))  # the controls as the hull feels them (actuator delay)
    rudder = layout != TWIN_THRUSTERS
    for e in range(members):
        for b in range(rows):
            p[T_BASE:T_BASE + N_TERMS] = terms[min(b, terms.shape[0] - 1)]
            sea = _sea_of(p)
            row_free = free[b]
            _held_controls(p, controls, b, held)
            psi, u_r, v_r, r, carry_a, carry_b = _start(layout, ki, p, sea, state, reference, use_reference, held, b)
            x_n = 0.0
            y_e = 0.0
            last_level = math.nan  # equal to no level: the first is computed
            cos_a = sin_a = 0.0
            for k in range(steps):
                for j in range(substeps):
                    a0, a1, a2, b0, b1, b2, carry_a, carry_b = _levels(layout, ki, p, held, k, j, carry_a, carry_b)
                    # the four RK4 stages from one call site (the derivative is inlined once); the weighted sum
                    # k1 + 2 k2 + 2 k3 + k4 accumulated in that order
                    hh = 0.5 * h_sub
                    d = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
                    s0 = s1 = s2 = s3 = s4 = s5 = 0.0
                    for stage in range(4):
                        # the rudder angle's cosine and sine once per level: the stages' levels are a0, a1, a1, a2,
                        # and a0 is often the last substep's a2
                        if rudder and stage != 2:
                            level = a0 if stage == 0 else (a1 if stage == 1 else a2)
                            if level != last_level:
                                cos_a, sin_a = math.cos(level), math.sin(level)
                                last_level = level
                        if stage == 0:
                            d = _derivative(kind, ki, p, sea, row_free, e, work, psi, u_r, v_r, r, a0, b0, cos_a,
                                            sin_a)
                            s0, s1, s2, s3, s4, s5 = d
                            continue
                        weight, lev_a, lev_b = (hh, a1, b1) if stage < 3 else (h_sub, a2, b2)
                        d = _derivative(kind, ki, p, sea, row_free, e, work, psi + weight * d[2], u_r + weight * d[3],
                                        v_r + weight * d[4], r + weight * d[5], lev_a, lev_b, cos_a, sin_a)
                        twice = 2.0 if stage < 3 else 1.0
                        s0 += twice * d[0]
                        s1 += twice * d[1]
                        s2 += twice * d[2]
                        s3 += twice * d[3]
                        s4 += twice * d[4]
                        s5 += twice * d[5]
                    w = h_sub / 6.0
                    x_n += w * s0
                    y_e += w * s1
                    psi += w * s2
                    u_r += w * s3
                    v_r += w * s4
                    r += w * s5
                _measured(p, sea, out, e, b, k, psi, u_r, v_r, r, x_n, y_e)
    return out


# ---- several rows side by side --------------------------------------------------------------------------------------

LANES = 64  # rows rolled out side by side: their derivative is one loop over them, eight wide (AVX-512)
LANE_KINDS = ((MMG, RUDDER_PROPELLER), (MMG, RUDDER_ONLY))  # (hull, layout) whose derivative has no loop or call
N_LANE_ROWS = 29
# the rows of _rollout_lanes' one (N_LANE_ROWS, LANES) array: one array, and rows a constant LANES apart, so that the
# compiler knows that no two of them overlap (separate arrays would each need a run-time overlap check)
(L_PSI, L_U, L_V, L_R, L_X, L_Y,  # the state
 L_DPSI, L_DU, L_DV, L_DR,  # the last stage's derivative (the next stage starts from it)
 L_SX, L_SY, L_SPSI, L_SU, L_SV, L_SR,  # the RK4 sums k1 + 2 k2 + 2 k3 + k4
 L_A0, L_A1, L_A2, L_B0, L_B1, L_B2,  # the substep's levels at its start, middle and end
 L_FREE, L_CARRY_A, L_CARRY_B,
 L_CHI, L_WX, L_WY, L_WN) = range(N_LANE_ROWS)  # the stage's wave direction off the bow and its drift (X, Y, N)


@_inlined
def _lanes_wave_drift(ki, p, sea, x, n, weight):
    """The mean wave drift (X, Y, N) of _sea_loads (_fourier's tables, then _drift_load) into rows L_WX, L_WY, L_WN
    of lanes 0..n-1 at their stage's heading psi + weight psi_dot: each table row's harmonic one loop over the lanes
    (a coefficient of zero adds an exact zero, where _fourier skips it)."""
    rows = ki[K_DRIFT_ROWS]
    for i in range(n):
        x[L_CHI, i] = sea[5] - (x[L_PSI, i] + weight * x[L_DPSI, i])
        x[L_WX, i] = p[ki[K_O_DRIFT]]
        x[L_WY, i] = p[ki[K_O_DRIFT] + 3 * rows]
        x[L_WN, i] = p[ki[K_O_DRIFT] + 6 * rows]
    for k in range(3):
        for j in range(1, rows):
            row = ki[K_O_DRIFT] + 3 * k * rows + 3 * j
            order, cos_part, sin_part = p[row], p[row + 1], p[row + 2]
            for i in range(n):  # eight wide
                c, s = _cos_sin(order * x[L_CHI, i])
                x[L_WX + k, i] = (x[L_WX + k, i] + cos_part * c) + sin_part * s
    for i in range(n):
        x[L_WX, i], x[L_WY, i], x[L_WN, i] = _drift_load(p, sea, x[L_WX, i], x[L_WY, i], x[L_WN, i],
                                                         _cos_sin(x[L_CHI, i])[0])


@_inlined
def _rollout_lanes(hull, layout, state, controls, reference, use_reference, ki, constants, terms, free, out):
    """rollout's model, LANES rows at a time, with the stage's derivative one loop over the rows (`hull`, `layout`
    constants of the caller: the derivative's branches fold away). The terms the same for every row (R = 1), without
    wind or a residual (rollout_lanes_for says which calls qualify); waves' drift is summed before each stage's
    derivative, the Fourier tables' rows outside the loop over the lanes (_lanes_wave_drift)."""
    rows, steps, width = controls.shape
    p = constants.copy()
    p[T_BASE:T_BASE + N_TERMS] = terms[0]
    sea = _sea_of(p)
    substeps = ki[K_SUBSTEPS]
    h_sub = p[P_DT] / substeps
    kind = (hull, layout, 0, 0)
    # no reference counts in the lanes' loop: the kinds as a tuple (values the loop keeps in registers), the
    # constants through a pointer
    kp, pp = to_fixed_tuple(ki, N_KINDS), _data(p)
    held = np.empty((min(rows, LANES), steps, width))
    x = np.zeros((N_LANE_ROWS, LANES))  # the drift's rows stay zero without waves
    waves = sea[6] != 0.0
    for g in range(0, rows, LANES):
        n = min(LANES, rows - g)
        for i in range(n):
            _held_controls(p, controls, g + i, held[i])
            (x[L_PSI, i], x[L_U, i], x[L_V, i], x[L_R, i], x[L_CARRY_A, i], x[L_CARRY_B, i]) = _start(
                layout, ki, p, sea, state, reference, use_reference, held[i], g + i)
            x[L_X, i] = 0.0
            x[L_Y, i] = 0.0
            x[L_FREE, i] = free[g + i]
        for k in range(steps):
            for j in range(substeps):
                for i in range(n):
                    (x[L_A0, i], x[L_A1, i], x[L_A2, i], x[L_B0, i], x[L_B1, i], x[L_B2, i], x[L_CARRY_A, i],
                     x[L_CARRY_B, i]) = _levels(layout, ki, p, held[i], k, j, x[L_CARRY_A, i], x[L_CARRY_B, i])
                for i in range(n):
                    x[L_DPSI, i] = x[L_DU, i] = x[L_DV, i] = x[L_DR, i] = 0.0
                    x[L_SX, i] = x[L_SY, i] = x[L_SPSI, i] = x[L_SU, i] = x[L_SV, i] = x[L_SR, i] = 0.0
                for stage in range(4):
                    weight = 0.0 if stage == 0 else (0.5 * h_sub if stage < 3 else h_sub)
                    twice = 2.0 if stage == 1 or stage == 2 else 1.0
                    level = 0 if stage == 0 else (1 if stage < 3 else 2)
                    if waves:
                        _lanes_wave_drift(kp, pp, sea, x, n, weight)
                    for i in range(n):  # the lanes: no call, no branch (selects), eight wide
                        lev_a = x[L_A0 + level, i]
                        lev_b = x[L_B0 + level, i]
                        cos_a, sin_a = _cos_sin(lev_a)
                        r_i = x[L_R, i] + weight * x[L_DR, i]
                        x_dot, y_dot, du, dv, dr = _motion(kind, kp, pp, sea, x[L_PSI, i] + weight * x[L_DPSI, i],
                                                           x[L_U, i] + weight * x[L_DU, i],
                                                           x[L_V, i] + weight * x[L_DV, i], r_i, lev_a, lev_b, cos_a,
                                                           sin_a, x[L_WX, i], x[L_WY, i], x[L_WN, i])
                        free_i = x[L_FREE, i]
                        d = (x_dot, y_dot, r_i, du, dv * free_i, dr * free_i)
                        x[L_DPSI, i], x[L_DU, i], x[L_DV, i], x[L_DR, i] = d[2], d[3], d[4], d[5]
                        x[L_SX, i] += twice * d[0]
                        x[L_SY, i] += twice * d[1]
                        x[L_SPSI, i] += twice * d[2]
                        x[L_SU, i] += twice * d[3]
                        x[L_SV, i] += twice * d[4]
                        x[L_SR, i] += twice * d[5]
                w = h_sub / 6.0
                for i in range(n):
                    x[L_X, i] += w * x[L_SX, i]
                    x[L_Y, i] += w * x[L_SY, i]
                    x[L_PSI, i] += w * x[L_SPSI, i]
                    x[L_U, i] += w * x[L_SU, i]
                    x[L_V, i] += w * x[L_SV, i]
                    x[L_R, i] += w * x[L_SR, i]
            for i in range(n):
                _measured(p, sea, out, 0, g + i, k, x[L_PSI, i], x[L_U, i], x[L_V, i], x[L_R, i], x[L_X, i],
                          x[L_Y, i])
    return out


@njit(cache=CACHED, nogil=True, **VECTOR)
def _lanes_mmg_rudder_propeller(state, controls, reference, use_reference, ki, constants, terms, free, out):
    return _rollout_lanes(MMG, RUDDER_PROPELLER, state, controls, reference, use_reference, ki, constants, terms,
                          free, out)


@njit(cache=CACHED, nogil=True, **VECTOR)
def _lanes_mmg_rudder_only(state, controls, reference, use_reference, ki, constants, terms, free, out):
    return _rollout_lanes(MMG, RUDDER_ONLY, state, controls, reference, use_reference, ki, constants, terms, free,
                          out)


_LANE_ROLLOUTS = {(MMG, RUDDER_PROPELLER): _lanes_mmg_rudder_propeller, (MMG, RUDDER_ONLY): _lanes_mmg_rudder_only}
assert tuple(_LANE_ROLLOUTS) == LANE_KINDS


def rollout_lanes_for(ki: np.ndarray, terms: np.ndarray, members: int):
    """The compiled rollout_lanes of this model (the signature of rollout), or None when it must run one row at a
    time: a hull and layout without a lanes version, a residual, several members, terms per row or wind."""
    if members != 1 or int(ki[K_RESIDUAL]) != 0 or terms.shape[0] != 1:
        return None
    t = terms[0]
    if t[T_WIND_N - T_BASE] != 0.0 or t[T_WIND_E - T_BASE] != 0.0:
        return None
    return _LANE_ROLLOUTS.get((int(ki[K_HULL]), int(ki[K_LAYOUT])))
