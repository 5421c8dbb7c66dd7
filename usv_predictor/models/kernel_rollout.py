"""A grey box or hybrid run on the compiled kernel (physics/kernel.py): what every rollout that is not differentiated
calls — the node's predictions and candidate plans, `replay evaluate`, diagnosis fits and gains, the fit check.

KernelRollout(module) reads a GreyBoxRollout (models/greybox.py), a ResidualGreyBox (models/hybrid.py, with a
polynomial, learned or summed residual) or their TorchScript files' modules: the constants from the module's
attributes (as FusedDnnRollout rebuilds a DNN from its buffers), the hull coefficients, engine speed and extension
terms from its parameters. It is called like the module:

    kernel(state (B, 4), controls (B, H, C), reference (B, 4) | None) -> (E, B, H, 6) torch tensor
    kernel.rollout(the same as numpy arrays) -> (E, B, H, 6) numpy array

`live=True` re-reads at every call the parameters that changed (torch counts in-place changes: a few microseconds
when none did): for diagnosis and identification, which set the module's terms in place (diagnosis.set_terms), the
fit check, which replaces them, and the node, whose sea estimate writes them (node/sea.py); a learned residual's
weights or normalisation changed in place (a training step) re-pack the network. `live=False` reads them once.
Attributes it does not have are the module's (model.current_ne is the module's tensor), so the callers' code does
not change. A module it cannot read (another family, an artifact of a version whose attributes differ) is a
KernelUnavailable naming what is missing; models/loading.py then keeps the file's module.
"""
from __future__ import annotations

import functools
import math
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable, Mapping

import numpy as np
import torch

from usv_predictor.errors import KernelUnavailable
from usv_predictor.physics import effects
from usv_predictor.physics import kernel as kn

HULL_KINDS = {"MmgHullModule": kn.MMG, "SmallCraftHullModule": kn.SMALL_CRAFT}  # the torch twin's class -> kind
LAYOUT_KINDS = {"RudderPropellerModule": kn.RUDDER_PROPELLER, "RudderThrottleModule": kn.RUDDER_THROTTLE,
                "RudderOnlyModule": kn.RUDDER_ONLY, "TwinThrusterModule": kn.TWIN_THRUSTERS}
# the small-craft hull module's indices of kernel.SMALL_CRAFT_INDICES' coefficients (greybox.SmallCraftHullModule)
MODULE_INDICES = ("i_xud", "i_yvd", "i_nrd", "i_xu", "i_xuu", "i_yv", "i_yr", "i_nv", "i_nr", "i_nrr", "i_cd")
LEARNED_BUFFERS = ("in_mean", "in_std", "z_low", "z_high", "bound")  # GeneralisingResidual's normalisation buffers
PROBE_STEPS = 24  # steps of check_equal's probe: every constant acts within them (a wrong one moves the first step)
KERNEL_FORM = "compiled kernel (physics/kernel.py, numba)"  # the inference_note of a model running it


def _name(module: Any) -> str:
    """The class name of an eager module or of a TorchScript module's original class."""
    return str(getattr(module, "original_name", type(module).__name__))


def _array(tensor: torch.Tensor | None) -> np.ndarray | None:
    return None if tensor is None else tensor.detach().to(torch.float64).cpu().numpy()


def _plain(array: np.ndarray) -> np.ndarray:
    """The array as the kernel's one compiled signature takes it: float64, C-contiguous and writable (numba types a
    read-only array, e.g. a contiguous np.broadcast_to view of a plan's controls, apart: it would compile a second
    specialisation, seconds holding the GIL, in the middle of a run)."""
    if (type(array) is np.ndarray and array.dtype == np.float64 and array.flags.c_contiguous
            and array.flags.writeable):
        return array  # the common case, without np.require's ~1 us
    return np.require(array, dtype=np.float64, requirements=("C", "W"))


def _floats(value: Any) -> np.ndarray:
    if isinstance(value, torch.Tensor):
        return value.detach().to(torch.float64).cpu().numpy().reshape(-1)
    return np.asarray(value, dtype=np.float64).reshape(-1)


def _fetcher(owner: Any, name: str) -> Callable[[], Any]:
    """A call returning owner.name: a TorchScript module's C++ getattr, an eager module's parameter (its buffer or
    attribute through getattr when it holds none of that name), else getattr."""
    script = getattr(owner, "_c", None)
    if isinstance(owner, torch.jit.ScriptModule) and script is not None:
        return functools.partial(script.getattr, name)
    parameters = getattr(owner, "_parameters", None)
    if isinstance(owner, torch.nn.Module) and isinstance(parameters, dict):
        def fetch() -> Any:
            value = parameters.get(name)
            return getattr(owner, name) if value is None else value
        return fetch
    return functools.partial(getattr, owner, name)


class KernelRollout:
    """The compiled rollout of a grey-box module (module docstring)."""

    accepts_reference = True  # forward's third argument: rudder_only's reference state (models/greybox.py)

    def __init__(self, module: Any, *, live: bool = False, threads: int = 1) -> None:
        self.module = module
        self.live = bool(live)
        self.threads = max(1, int(threads))  # a batch of at least SPLIT_ROWS rows a thread is split over this many
        self._read: tuple = ()  # what _refresh read last: (data_ptr, version) per parameter, and the tensors
        self._learned_read: tuple = ()  # ... and the versions of the learned residual's tensors
        self._held: list = []
        self._ones = np.ones(1)
        try:
            self._pack(module)
            self._fetch = self._fetchers()
            self._refresh()
        except (AttributeError, KeyError, TypeError, ValueError, IndexError, RuntimeError) as err:
            raise KernelUnavailable(f"the kernel cannot read this {_name(module)} ({type(err).__name__}: "
                                    f"{err})") from err

    # ---- packing ---------------------------------------------------------------------------------------------
    def _pack(self, m: Any) -> None:
        hull_kind = HULL_KINDS.get(_name(m.hull_forces))
        layout = LAYOUT_KINDS.get(_name(m.actuator_forces))
        if hull_kind is None or layout is None:
            raise KeyError(f"hull {_name(m.hull_forces)} / actuators {_name(m.actuator_forces)}")
        term_names = tuple(m.term_names)
        expected = tuple(dict.fromkeys(kn.T_NAMES))
        # a file written before a term existed holds the others in order: the model it holds has none of that term
        self._absent = {name: torch.zeros(term.size, dtype=torch.float64)
                        for name, term in effects.grey_box_terms().items() if name not in term_names}
        if term_names != tuple(n for n in expected if n not in self._absent) \
                or tuple(effects.grey_box_terms()) != expected:
            raise ValueError(f"extension terms {term_names}, the kernel's are {expected}")
        pk = kn.Packer()
        ki = pk.ki
        ki[kn.K_HULL], ki[kn.K_LAYOUT], ki[kn.K_SUBSTEPS] = hull_kind, layout, int(m.substeps)
        if ki[kn.K_SUBSTEPS] < 1:
            raise ValueError(f"substeps {m.substeps}")
        pk.set("dt", m.dt)
        pk.set("L_sea", m.L)
        for name in ("wind_x", "wind_y", "wind_n", "q_wave"):
            pk.set(name, getattr(m, name))
        hf, af = m.hull_forces, m.actuator_forces
        for name in kn.MASS_CONSTANTS:
            pk.set(name, getattr(hf, name))
        self.n_hull = int(m.hull.numel())
        pk.append(kn.K_O_HULL, np.zeros(self.n_hull))  # the hull coefficients: _refresh writes them
        drift = kn.fourier_tables([m.drift_x, m.drift_y, m.drift_n])
        ki[kn.K_DRIFT_ROWS] = drift.shape[1]
        pk.append(kn.K_O_DRIFT, drift)
        strips = np.zeros(0)
        if hull_kind == kn.MMG:
            pk.set("q_force", hf.q_force)
            pk.set("speed_floor", hf.speed_floor)
        else:
            for name in ("m33_rigid", "half_rho_d", "strip_dx"):
                pk.set(name, getattr(hf, name))
            strips = _floats(hf.strips)
            for k, name in enumerate(MODULE_INDICES):
                ki[kn.K_XUD + k] = int(getattr(hf, name))
        ki[kn.K_N_STRIPS] = len(strips)
        pk.append(kn.K_O_STRIPS, strips)
        lags = np.zeros((2, 3))  # [T (s), exp(-h/2T), exp(-h/T)] per lagged column
        maps: list[tuple[list[float], list[float], list[float]]] = []
        if layout == kn.TWIN_THRUSTERS:
            pk.set("half_spacing", af.half_spacing)
            maps = [(af.port, af.port_x, af.port_y), (af.starboard, af.starboard_x, af.starboard_y)]
            lags[:, :] = np.stack([_floats(af.lag.t), _floats(af.lag.e_half), _floats(af.lag.e_full)], axis=1)
        else:
            for name in ("rho", *kn.RUDDER_CONSTANTS):
                pk.set(name, getattr(af, name))
            pk.set("L_act", af.L)
            if layout == kn.RUDDER_THROTTLE:
                pk.set("static_thrust", af.static_thrust)
                pk.set("rpm_per_rev_s", af.rpm_per_rev_s)
                maps = [(af.map, af.table_x, af.table_y)]
                lags[0] = [_floats(af.lag.t)[0], _floats(af.lag.e_half)[0], _floats(af.lag.e_full)[0]]
        flat, ki[kn.K_MAP_WIDTH], (ki[kn.K_MAP_N0], ki[kn.K_MAP_N1]) = kn.thrust_maps(maps)
        pk.append(kn.K_O_MAPS, flat)
        pk.append(kn.K_O_LAG, lags)
        pk.append(kn.K_O_COEF, np.zeros(kn.N_POLY))  # the Abkowitz terms: _refresh writes them
        self.members = 1
        self._poly_module = None
        self._learned: list = []  # the learned residual's weights and normalisation (tensors), [] without one
        residual = getattr(m, "residual", None)
        if residual is not None:
            self.members = int(m.members)
            ki[kn.K_RESIDUAL] = self._pack_residual(residual, pk)
            if self.members != 1 and not ki[kn.K_RESIDUAL] & kn.RESIDUAL_MLP:
                raise ValueError(f"{self.members} members without a learned residual")
        ki[kn.K_MEMBERS] = self.members
        self.n_controls = int(m.n_controls)
        self.ki, self.p = ki, pk.constants()

    def _pack_residual(self, residual: Any, pk: kn.Packer) -> int:
        """The residual's kind bits (kernel.RESIDUAL_*), its constants and weights packed."""
        name = _name(residual)
        if name == "ZeroResidual":
            return 0
        if name == "SumResidual":
            return self._pack_residual(residual.first, pk) | self._pack_residual(residual.second, pk)
        if name == "PolynomialResidual":
            self._poly_module = residual
            for field in ("u0", "L", "q_force", "m11", "m22", "m23", "m32", "m33"):
                pk.set(f"poly_{field}", getattr(residual, field))
            return kn.RESIDUAL_POLYNOMIAL
        if name == "GeneralisingResidual":
            params = dict(residual.named_parameters())  # a scripted ParameterList cannot be iterated: by name
            self._learned = [*params.values(), *(getattr(residual, f) for f in LEARNED_BUFFERS)]  # what _refresh
            #     stamps: a weight changed in place (a training step) re-packs the network
            layers = sum(1 for key in params if key.startswith("weights."))
            weights = [_array(params[f"weights.{k}"]) for k in range(layers)]  # (E, in, out) each
            biases = [_array(params[f"biases.{k}"]) for k in range(layers)]  # (E, 1, out) each
            members, width, hidden = weights[0].shape
            if width != kn.N_FEATURES or members != self.members or int(residual.members) != self.members:
                raise ValueError(f"learned residual of {width} features and {members} members")
            ki = pk.ki
            ki[kn.K_HIDDEN], ki[kn.K_HIDDEN_LAYERS] = hidden, len(weights) - 1
            hidden_w = np.stack(weights[1:], axis=1) if len(weights) > 1 else np.zeros((members, 0, hidden, hidden))
            hidden_b = (np.stack([b[:, 0] for b in biases[1:]], axis=1) if len(biases) > 1
                        else np.zeros((members, 0, hidden)))
            norm = np.zeros((5, kn.N_FEATURES))
            for k, field in enumerate(LEARNED_BUFFERS[:4]):
                norm[k] = _floats(getattr(residual, field))
            norm[4, :3] = _floats(residual.bound)
            # the kernel reads the hidden and head layers output-major (swapped in, out), the first input-major
            for key, values in ((kn.K_O_W0, weights[0]), (kn.K_O_B0, biases[0][:, 0]),
                                (kn.K_O_WH, hidden_w.swapaxes(-1, -2)), (kn.K_O_BH, hidden_b),
                                (kn.K_O_WO, _array(residual.head_weight).swapaxes(-1, -2)),
                                (kn.K_O_BO, _array(residual.head_bias)[:, 0]), (kn.K_O_NORM, norm)):
                pk.append(key, values)
            for field in ("L", "u_ref", "speed_floor", "support_width"):
                pk.set(f"mlp_{field}", getattr(residual, field))
            return kn.RESIDUAL_MLP
        raise KeyError(f"residual {name}")

    def _fetchers(self) -> list:
        """One cheap read per parameter the kernel re-reads (hull coefficients, held engine speed, extension terms,
        Abkowitz terms): a TorchScript module's own C++ getattr, an eager module's parameter dictionary (the module's
        __getattr__ costs ~1 us a name in Python); whatever replaces a parameter writes the place these read."""
        owners = [(self.module, name) for name in ("hull", "engine_speed_rpm", *dict.fromkeys(kn.T_NAMES))]
        if self._poly_module is not None:
            owners.append((self._poly_module, "coef"))
        return [functools.partial(self._absent.__getitem__, name) if name in self._absent else _fetcher(owner, name)
                for owner, name in owners]

    def _tensors(self) -> list:
        return [fetch() for fetch in self._fetch]

    def _refresh(self) -> None:
        """Read the module's parameters into p and the terms: hull coefficients, held engine speed, extension terms,
        Abkowitz terms; the learned residual's network re-packed when one of its tensors changed in place. Skipped
        when none changed since the last read: one stamp of the tensors' identities (kept here, so a replaced
        parameter's id cannot be a freed one's) and versions (torch counts every in-place change)."""
        tensors = self._tensors()
        key = (*map(id, tensors), *(t._version for t in tensors))
        learned = tuple(t._version for t in self._learned)  # the network's tensors, held since the packing
        if key == self._read and learned == self._learned_read:
            return
        if self._read and learned != self._learned_read:  # the network changed in place
            self._pack(self.module)
        self._learned_read = learned
        hull = _floats(tensors[0])
        if len(hull) != self.n_hull:
            raise ValueError(f"{len(hull)} hull coefficients, packed for {self.n_hull}")
        o = self.ki[kn.K_O_HULL]
        self.p[o:o + self.n_hull] = hull
        self.p[kn.P_ENGINE_SPEED_RPM] = float(_floats(tensors[1])[0])
        if self._poly_module is not None:
            o = self.ki[kn.K_O_COEF]
            self.p[o:o + kn.N_POLY] = _floats(tensors[-1])
        values = []  # (rows, size) per term: a term set per row is (size, B) in the module (fit_check's batches)
        for tensor in tensors[2:2 + len(dict.fromkeys(kn.T_NAMES))]:
            value = tensor.detach().to(torch.float64).cpu().numpy()
            values.append(value[None, :] if value.ndim == 1 else value.T)
        rows = max(v.shape[0] for v in values)
        self.terms = np.ascontiguousarray(np.concatenate([np.broadcast_to(v, (rows, v.shape[1])) for v in values],
                                                         axis=1))  # (R, NT)
        # several rows side by side where the model and its terms allow it (physics/kernel.rollout_lanes_for)
        self.engine = kn.rollout_lanes_for(self.ki, self.terms, self.members) or kn.rollout
        self._read, self._held = key, tensors

    # ---- running ---------------------------------------------------------------------------------------------
    def rollout(self, state: np.ndarray, controls: np.ndarray, reference: np.ndarray | None = None,
                free: np.ndarray | None = None) -> np.ndarray:
        """(E, B, H, 6) from (B, 4), (B, H, C) and (B, 4) | None float64 arrays; free (B,): the fit check's steered
        rows (0: sway and yaw held), all free by default."""
        if self.live:
            self._refresh()
        state, controls = _plain(state), _plain(controls)
        if controls.ndim != 3 or controls.shape[2] != self.n_controls or state.shape != (controls.shape[0], 4):
            raise ValueError(f"state must be (B, 4) and controls (B, H, {self.n_controls}), the vessel's actuator "
                             f"layout; got {state.shape} and {controls.shape}")
        rows, steps = controls.shape[:2]
        if self.terms.shape[0] not in (1, rows):
            raise ValueError(f"the terms are set for {self.terms.shape[0]} rows, the batch has {rows}")
        use_reference = reference is not None
        reference = state if reference is None else _plain(reference)
        free = self._all_free(rows) if free is None else _plain(free)
        parts = min(self.threads, rows // SPLIT_ROWS)
        if parts > 1 and steps:  # the kernel runs without the GIL: each thread its share of the rows
            bounds = np.linspace(0, rows, parts + 1).astype(int)
            shares = [slice(lo, hi) for lo, hi in zip(bounds[:-1], bounds[1:])]
            done = list(_pool(parts).map(lambda rows_: self._run(state[rows_], controls[rows_], reference[rows_],
                                                                 use_reference, free[rows_], rows_), shares))
            return np.concatenate(done, axis=1)
        return self._run(state, controls, reference, use_reference, free, slice(0, rows))

    def warm_up(self, side_by_side: bool = True) -> None:
        """Compile (or load from numba's cache) the engines this model may run, on a one-row two-step batch: one
        row at a time (kernel.rollout: terms per row, wind, waves) and, with side_by_side, its rows side by side
        where it allows that (self.engine). Compiling holds the GIL: the node does it before its first cycle."""
        state = np.array([[1.0, 0.0, 0.0, 0.0]])
        controls = np.zeros((1, 2, self.n_controls))
        out = np.empty((self.members, 1, 2, 6))
        for engine in dict.fromkeys((kn.rollout, self.engine) if side_by_side else (kn.rollout,)):
            engine(state, controls, state, False, self.ki, self.p, self.terms[:1], self._all_free(1), out)

    def _all_free(self, rows: int) -> np.ndarray:
        """(rows,) ones: a view of one array kept for the largest batch yet (the kernel only reads it)."""
        if self._ones.shape[0] < rows:
            self._ones = np.ones(rows)
        return self._ones[:rows]

    def _run(self, state: np.ndarray, controls: np.ndarray, reference: np.ndarray, use_reference: bool,
             free: np.ndarray, rows: slice) -> np.ndarray:
        """(E, b, H, 6) of the rows `rows` of the batch (their inputs given, C-contiguous float64: a share of rows
        of such an array is one too; the terms cut to them when per row)."""
        terms = self.terms if self.terms.shape[0] == 1 else _plain(self.terms[rows])
        out = np.empty((self.members, state.shape[0], controls.shape[1], 6))
        if state.shape[0] and controls.shape[1]:
            self.engine(state, controls, reference, use_reference, self.ki, self.p, terms, free, out)
        return out

    def __call__(self, state: torch.Tensor, controls: torch.Tensor, reference: torch.Tensor | None = None,
                 free: torch.Tensor | None = None) -> torch.Tensor:
        return torch.from_numpy(self.rollout(_array(state), _array(controls), _array(reference), _array(free)))

    def __getattr__(self, name: str) -> Any:  # the module's attributes (terms, hull, metadata helpers)
        if name == "module":
            raise AttributeError(name)
        return getattr(self.module, name)


SPLIT_ROWS = 32  # (-) rows a thread must have before a batch is split (below, a thread's start costs more)
_POOLS: dict[int, ThreadPoolExecutor] = {}


def _pool(threads: int) -> ThreadPoolExecutor:
    """A process-wide pool of `threads` threads for split batches (made once per size)."""
    if threads not in _POOLS:
        _POOLS[threads] = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="usv-kernel")
    return _POOLS[threads]


def check_equal(kernel: KernelRollout, module: Any, metadata: Mapping[str, Any], rtol: float = 1e-6) -> float:
    """The largest difference between the kernel's and the module's predictions on a probe (three starts, PROBE_STEPS
    steps with the controls swept through the layout's range), relative to each output column's scale;
    KernelUnavailable beyond rtol."""
    horizon = min(int(metadata.get("horizon_steps") or PROBE_STEPS), PROBE_STEPS)  # the file's rollout is the slow one
    width = kernel.n_controls
    state = np.array([[1.5, 0.0, 0.0, 0.3], [2.0, 0.1, 0.05, -2.0], [0.5, -0.05, -0.02, 3.0]])
    sweep = np.linspace(-1.0, 1.0, horizon)
    controls = np.zeros((3, horizon, width))
    layout = int(kernel.ki[kn.K_LAYOUT])
    if layout == kn.TWIN_THRUSTERS:
        controls[:, :, 0], controls[:, :, 1] = 0.6 + 0.3 * sweep, 0.6 - 0.3 * sweep
    else:
        controls[:, :, 0] = math.radians(20.0) * sweep
        if width > 1:
            controls[:, :, 1] = 0.7 if layout == kn.RUDDER_THROTTLE else 600.0
    from usv_predictor.models.artifact import MODEL_RUN_ERRORS, failure_reason

    try:
        with torch.no_grad():
            expected = module(torch.from_numpy(state), torch.from_numpy(controls)).double().numpy()
        got = kernel.rollout(state, controls)
    except MODEL_RUN_ERRORS as err:  # the module's own code (or the kernel's shape check) on the probe
        raise KernelUnavailable(f"the probe cannot be rolled out: {failure_reason(err)}") from err
    if got.shape != expected.shape:
        raise KernelUnavailable(f"the kernel answers {got.shape}, the module {expected.shape}")
    scale = 1.0 + np.nanmax(np.abs(expected), axis=(0, 1, 2))
    with np.errstate(invalid="ignore"):
        error = float(np.nanmax(np.abs(got - expected).max(axis=(0, 1, 2)) / scale))
    if not (error <= rtol) or (np.isfinite(expected) != np.isfinite(got)).any():
        raise KernelUnavailable(f"the kernel differs from the module by {error:.3g} of the output's scale "
                                f"(limit {rtol:g})")
    return error
