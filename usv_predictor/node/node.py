"""The `predictor` rclpy node: live 3-DOF motion prediction from a TorchScript model artifact.

The only module of the package that imports rclpy; the work is done by usv_predictor.node.live (pure).
Messages travel as serialized CDR both ways (docs/node.md, "Design"): the input subscriptions are raw, the
callbacks only keep the bytes and their arrival clock, and each timer decodes all pending messages of an
input in one call (msg_adapters.cdr.decode_values: bulk CDR decoder + the input's adapter, the same decoder
the replay tool reads bags with), turning REP-103/105 messages (ENU, FLU) into SI numbers in marine frames
(NED, FRD, heading clockwise from north), checked and buffered by live.InputSet. Every 1 / rate_hz a timer
builds the state the way the replay tool builds a Recording, rolls the model out over horizon_s with the
current actuator commands held (or under the plan on `plan`), and publishes CDR written with numpy
(msg_adapters.outputs, byte-equal to rclpy's serialisation):

    predicted_path               nav_msgs/Path, ENU, frame_id (default odom), pose k stamped t_c + k dt
    predicted_velocities         trajectory_msgs/MultiDOFJointTrajectory (msg_adapters.outputs)
    predicted_path_covariance    std_msgs/Float64MultiArray, ensemble covariance of (x, y, yaw) ENU per step
    candidate_predictions        trajectory_msgs/MultiDOFJointTrajectory, one joint per candidate plan, published
                                 as soon as a batch arrives on `candidate_plans` (plans.py)
    estimated_current            geometry_msgs/TwistWithCovarianceStamped, the online estimate of the current
                                 (sea.py, fitting/online.py) in frame_id (ENU), once per dt, stamped with its time
    /diagnostics                 at diagnostics_rate_hz: inputs (age, rate, rejections), model, prediction
                                 (latency), plan and candidate plans (refusals), the sea estimate

A cycle that cannot be trusted (no input yet, stale input, non-finite model output) publishes nothing
(/diagnostics says why) and logs a throttled warning. Parameters are declared from
config/predictor.yaml (or `--config FILE`) with descriptors carrying the loader's ranges, so rclpy
rejects out-of-range overrides; the node-only parameters (NODE_PARAMETERS) are declared here.
model_path may change at run time: the new model is validated first, the old one kept on failure.
"""
from __future__ import annotations

import argparse
import contextlib
from concurrent.futures import Future, ThreadPoolExecutor
import math
import os
import signal
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticStatus
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.context import Context
from rclpy.exceptions import ParameterException
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from rclpy.serialization import deserialize_message
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

import msg_adapters
from msg_adapters.cdr import decode_joint_trajectory, decode_values
from msg_adapters.outputs import (
    COVARIANCE_TYPE,
    CURRENT_TYPE,
    DIAGNOSTICS_TYPE,
    PATH_TYPE,
    TRAJECTORY_TYPE,
    Status,
    candidate_predictions_cdr,
    covariance_cdr,
    current_cdr,
    diagnostics_cdr,
    path_cdr,
    predicted_velocities_cdr,
)
from usv_predictor import __version__
from usv_predictor.analysis.fit_check import MIN_HOLD_S as FIT_MIN_HOLD_S
from usv_predictor.analysis.fit_check import STEADY_S as FIT_STEADY_S
from usv_predictor.config import (
    ENSEMBLE_RANGE,
    FLOAT_RANGES,
    MAX_AGE_RANGE,
    NODE_NAME,
    ONLINE_RANGES,
    InputConfig,
    PredictorConfig,
    Range,
    default_config_path,
    flatten_ros_parameters,
    parse_predictor_config,
    read_ros_parameters,
    unflatten_ros_parameters,
)
from usv_predictor.data.recording import PLAUSIBLE
from usv_predictor.errors import AdapterError, ConfigError, ModelError, RecordingError, UsvPredictorError, one_line
from usv_predictor.fitting.online import OnlineConfig
from usv_predictor.models import loading
from usv_predictor.models.artifact import metadata_differences
from usv_predictor.models.families import MODEL_FAMILIES, family_name
from usv_predictor.node import EXIT_CODES, EXIT_INTERRUPTED, EXIT_OK, STOP_SIGNALS, live, plans, sea
from usv_predictor.node.fit import MAX_GAP_S as FIT_MAX_GAP_S
from usv_predictor.node.fit import PERIOD_RANGE_S, CycleGap, FitCheckSettings, LiveFitCheck
from usv_predictor.physics.actuators import ActuatorLayout, check_layout_inputs, unused_roles
from usv_predictor.physics.vessel import Vessel, vessel_preset_exists
from usv_predictor.records import NS_PER_S

DIAGNOSTICS_TOPIC = "/diagnostics"
USE_SIM_TIME = "use_sim_time"  # rclpy's parameter: fixed once the node runs (_on_set_parameters)
COVARIANCE_TOPIC = "predicted_path_covariance"
PLAN_TOPIC = "plan"  # trajectory_msgs/JointTrajectory: controls to predict under (plans.py)
CANDIDATE_PLANS_TOPIC = "candidate_plans"  # trajectory_msgs/JointTrajectory: N candidates "<name>/<control>"
CANDIDATE_PREDICTIONS_TOPIC = "candidate_predictions"  # trajectory_msgs/MultiDOFJointTrajectory, joint = candidate
ERROR_LOG_PERIOD_S = 5.0  # throttle of repeated warnings (s)
RECENT_REJECT_S = 5.0  # an input with a rejected sample this recently is WARN (s)
LATENCY_WINDOW = 200  # cycles kept for the latency percentiles
FIT_LOG_PERIOD_S = 60.0  # throttle of the fit check's mismatch log line (s): the verdict stays on /diagnostics
FIT_TIMER_S = 0.5  # (s) how often the fit check's timer looks whether a check is due (fit_check.period_s >= this)
FIT_NICE = 10  # (-) the fit check's worker thread runs this much nicer than the node: on busy cores the cycle first

# DiagnosticStatus levels are `byte` fields (bytes of length 1 in rclpy); compare them as ints.
OK, WARN, ERROR = (level[0] for level in (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR))
RCLError = _rclpy.RCLError  # what rcl raises (e.g. a publish on a context that is shut down)
RCLInvalidROSArgsError = _rclpy.RCLInvalidROSArgsError  # unparsable --ros-args (a broken --params-file)

FIT_PREFIX = "fit_check."

_DESCRIPTIONS = {
    "model_path": "TorchScript model file; empty = the package's shipped default model (may change at run time)",
    "vessel": "vessel preset name (config/vessels/<vessel>.yaml); the model must be made for it",
    "rate_hz": "prediction rate (Hz)",
    "horizon_s": "prediction horizon (s); a whole number of dt steps",
    "dt": "prediction time step (s); must equal the model's",
    "ensemble_size": "ensemble members used (the model must have at least this many)",
    "frame_id": "earth-fixed ENU frame of predicted_path",
    "base_frame_id": "body FLU frame of the vessel",
}


@dataclass(frozen=True)
class NodeParameter:
    """A parameter of the node only (not of config/predictor.yaml): default, range, meaning."""

    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    read_only: bool = True  # False: may change at run time (validated in _on_set_parameters)


NODE_PARAMETERS: dict[str, NodeParameter] = {
    "state_delay_s": NodeParameter(0.0, "the state averages [now - delay - dt, now - delay] (s): room for late "
                                        "messages; predictions start at now - delay - dt/2", 0.0, 5.0),
    "max_future_s": NodeParameter(0.5, "input stamps further than this ahead of the clock are refused (s)", 0.0, 60.0),
    "buffer_capacity": NodeParameter(2048, "samples kept per input (ring buffer: bounded memory)", 16, 100000),
    "datum_lat_deg": NodeParameter(math.nan, "latitude of the local tangent plane of predicted_path (deg); "
                                             "NaN = the first GNSS fix"),
    "datum_lon_deg": NodeParameter(math.nan, "longitude of that plane (deg); NaN = the first GNSS fix"),
    "diagnostics_rate_hz": NodeParameter(1.0, "rate of /diagnostics (Hz)", 0.01, 100.0),
    "plan_max_age_s": NodeParameter(1.0, "a plan (or candidate plans) stamped longer ago than this is refused, and a "
                                         "followed plan is dropped for the held commands (s)", 0.01, 60.0),
    "candidates_threads": NodeParameter(1, "threads the candidate plans' batched rollout runs on: 2 splits a batch "
                                           "of a numpy DNN or of the compiled grey-box kernel in halves, the first "
                                           "on a helper thread (a second core when the machine has one free; "
                                           "docs/node.md)", 1, 2),
    "candidates_members": NodeParameter(0, "ensemble members whose mean answers the candidate plans: 0 = the "
                                           "node's own (ensemble_size); fewer cost less in proportion and give a "
                                           "different mean, from fewer members (docs/node.md)", 0, 64),
    f"{FIT_PREFIX}enabled": NodeParameter(FitCheckSettings.enabled, "run the fit check on the inputs (fit.py): the "
                                          "model's steady speed and yaw rate at held commands against the measured "
                                          "ones, on /diagnostics as 'fit check'", read_only=False),
    f"{FIT_PREFIX}period_s": NodeParameter(FitCheckSettings.period_s, "time between two fit checks (s)",
                                           *PERIOD_RANGE_S, read_only=False),
    f"{FIT_PREFIX}refuse": NodeParameter(FitCheckSettings.refuse, "publish no prediction while the fit check finds "
                                         "that the model does not fit the inputs (false: published, /diagnostics "
                                         "ERROR)", read_only=False),
}


DATUM_RANGES = {name: Range(*PLAUSIBLE[field], "deg") for name, field in
                (("datum_lat_deg", "lat"), ("datum_lon_deg", "lon"))}  # the plausible GNSS fixes


def datum_of(lat: Any, lon: Any) -> tuple[float, float] | None:
    """The datum parameters as (lat, lon) deg, or None when both are NaN (the first fix); ConfigError naming the
    parameter when one is out of range, infinite, or set without the other."""
    values = {"datum_lat_deg": float(lat), "datum_lon_deg": float(lon)}
    unset = [name for name, v in values.items() if math.isnan(v)]
    for name, v in values.items():
        if name not in unset:
            DATUM_RANGES[name].check(name, v, f"node {NODE_NAME}: parameter")
    if len(unset) == 2:
        return None
    if unset:
        given = next(name for name in values if name not in unset)
        raise ConfigError(f"node {NODE_NAME}: parameter {given} is set but {unset[0]} is not: give both, or neither "
                          "(the datum is then the first GNSS fix)")
    return values["datum_lat_deg"], values["datum_lon_deg"]


ONLINE_PREFIX = "online."


def _online_leaf(name: str) -> str | None:
    """The OnlineConfig field of an `online.*` parameter (None for another parameter, or online.enabled)."""
    leaf = name.removeprefix(ONLINE_PREFIX)
    return leaf if name.startswith(ONLINE_PREFIX) and leaf in ONLINE_RANGES else None


def online_defaults() -> dict[str, Any]:
    """online.enabled and every ONLINE_RANGES field with OnlineConfig's default: declared when the file lacks them."""
    default = OnlineConfig()
    return {f"{ONLINE_PREFIX}enabled": True,
            **{f"{ONLINE_PREFIX}{leaf}": float(getattr(default, leaf)) for leaf in ONLINE_RANGES}}


def _is_float_parameter(name: str) -> bool:
    return name in FLOAT_RANGES or name.endswith(".max_age_s") or _online_leaf(name) is not None


def _declared_value(name: str, value: Any) -> Any:
    """`rate_hz: 10` in a YAML file is an int; declare it as the double it stands for."""
    if _is_float_parameter(name) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def _ranged(descriptor: ParameterDescriptor, leaf: str, value: Any, allowed: Range | None) -> ParameterDescriptor:
    if allowed is None:
        return descriptor
    if isinstance(value, float):
        descriptor.floating_point_range = [
            FloatingPointRange(from_value=float(allowed.low), to_value=float(allowed.high), step=0.0)
        ]
    elif isinstance(value, int) and not isinstance(value, bool):
        descriptor.integer_range = [IntegerRange(from_value=int(allowed.low), to_value=int(allowed.high), step=1)]
    descriptor.additional_constraints = allowed.describe(leaf)
    return descriptor


def _descriptor(name: str, value: Any) -> ParameterDescriptor:
    """Descriptor of one file parameter: ranges from usv_predictor.config; only staleness and model_path writable."""
    leaf = name.rsplit(".", 1)[-1]
    descriptor = ParameterDescriptor(
        name=name,
        description=_DESCRIPTIONS.get(name, f"{name.replace('.', ' ')} (see config/predictor.yaml)"),
        # topics and types are fixed once subscribed; the online estimator restarts with new values
        read_only=leaf != "max_age_s" and name != "model_path" and not name.startswith(ONLINE_PREFIX),
    )
    allowed: Range | None = FLOAT_RANGES.get(name) or ONLINE_RANGES.get(leaf if _online_leaf(name) else "") or (
        MAX_AGE_RANGE if _is_float_parameter(name) else None)
    if name == "ensemble_size":
        allowed = ENSEMBLE_RANGE
    return _ranged(descriptor, leaf, value, allowed)


def _node_descriptor(name: str, spec: NodeParameter) -> ParameterDescriptor:
    descriptor = ParameterDescriptor(name=name, description=spec.description, read_only=spec.read_only)
    unit = ("s" if name.endswith("_s") else "Hz" if name.endswith("_hz") else "threads" if name.endswith("_threads")
            else "samples")
    allowed = None if spec.low is None else Range(spec.low, spec.high, unit)
    return _ranged(descriptor, name, spec.default, allowed)


def _family_description(metadata: dict[str, Any]) -> str:
    """What kind of model it is (models/families.py), for /diagnostics."""
    family = MODEL_FAMILIES.get(family_name(str(metadata.get("model_type", ""))))
    return family.description if family is not None else "not a model family of usv_predictor"


def cycle_deadline(config: PredictorConfig) -> loading.RolloutDeadline:
    """The budget of a model's rollout in the node: one cycle, 1 / rate_hz (s), over horizon_steps steps."""
    return loading.RolloutDeadline(1.0 / config.rate_hz, config.horizon_steps,
                                   f"the node's cycle (1 / rate_hz {config.rate_hz:g} Hz)")


def load_model(model_path: str, config: PredictorConfig, vessel: Vessel | None = None,
               abandon: Callable[[], bool] | None = None) -> tuple[live.Rollout, Vessel]:
    """The model of `model_path` ("" = the shipped one) and its vessel, checked against the configuration: its step,
    vessel and control columns (the vessel's actuator layout), its speed (a rollout over the horizon within the
    cycle, cycle_deadline; a model whose code never returns is given up on: models/loading.call_guarded); ModelError
    naming the file and the mismatch or the measured time (loading.Abandoned once abandon() is true: stopping).

    The vessel is the configured one (`vessel`: a preset, or, when no preset of that name is installed, the
    description the model embeds under that name); a model that embeds a description differing from it is refused
    naming the fields (models/loading.model_vessel). vessel: the node's vessel when a model is swapped (the new
    model must be made for it)."""
    artifact = loading.load_model(model_path, expect={"dt": config.dt}, option="model_path", physics=False,
                                  deadline=cycle_deadline(config), abandon=abandon)
    source = f"model {artifact.path}"
    chosen = loading.resolve_vessel(vessel or config.vessel, model=artifact, option="vessel", source=source)
    diffs = metadata_differences(artifact.metadata, {"vessel": config.vessel,
                                                     "control_layout": list(chosen.actuator_layout.control_names)})
    if diffs:
        raise ModelError(f"{source} does not match the configuration: {'; '.join(diffs)}")
    return live.Rollout(artifact, config.horizon_steps, config.ensemble_size), chosen


@dataclass(frozen=True)
class WorkerPools:
    """The node's worker threads, owned by the node: made by start() when the node starts, ended by shutdown() in
    destroy_node.

    fit: the fit check's rollouts (one thread, FIT_NICE nicer than the node: on busy cores the cycle first);
    candidates: the candidate plans' batched rollout, encoding and publishing, in arrival order, off the executor's
    thread; candidates_helper: with candidates_threads 2, the thread that rolls out the first half of each batch
    (live.Rollout.batch), else None."""

    fit: ThreadPoolExecutor
    candidates: ThreadPoolExecutor
    candidates_helper: ThreadPoolExecutor | None

    @classmethod
    def start(cls, candidates_threads: int) -> WorkerPools:
        return cls(fit=ThreadPoolExecutor(max_workers=1, thread_name_prefix="fit_check", initializer=_lower_priority,
                                          initargs=(FIT_NICE,)),
                   candidates=ThreadPoolExecutor(max_workers=1, thread_name_prefix="candidates"),
                   candidates_helper=(ThreadPoolExecutor(max_workers=1, thread_name_prefix="candidates_helper")
                                      if candidates_threads > 1 else None))

    def shutdown(self) -> None:
        """Every pool ends after its running task (a candidate batch or a fit check: at most a few seconds); queued
        tasks are cancelled."""
        for pool in (self.candidates, self.candidates_helper, self.fit):
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=True)


@dataclass
class DecodeFailures:
    count: int = 0
    last: str = ""
    at_ns: int | None = None


@dataclass
class PlanInput:
    """What came of the messages of one plan topic (the plan, or the candidate plans)."""

    topic: str
    received: int = 0
    refused: dict[str, int] = field(default_factory=dict)
    last_refused: str = ""
    last_refused_ns: int | None = None
    answered: int = 0  # candidates: batches predicted and published
    skipped: str = ""  # candidates: why the latest batch got no prediction (no state yet, ...)
    compute_s: deque[float] = field(default_factory=lambda: deque(maxlen=LATENCY_WINDOW))  # the batched rollout
    answer_s: deque[float] = field(default_factory=lambda: deque(maxlen=LATENCY_WINDOW))  # arrival -> published
    batch: int = 0  # candidates in the latest batch

    def refuse(self, kind: str, message: str, now_ns: int) -> None:
        self.refused[kind] = self.refused.get(kind, 0) + 1
        self.last_refused, self.last_refused_ns = message, now_ns


class PredictorNode(Node):
    """Subscribes to the configured inputs and the plan topics, predicts at rate_hz, reports on /diagnostics."""

    def __init__(self, config_path: str | Path | None = None, stopping: Callable[[], bool] | None = None,
                 **node_options: Any) -> None:
        """stopping: true once the process is asked to stop (main's stop flag): a model load waiting on the model's
        code gives up then (models/loading.call_guarded), at start-up and at a model swap."""
        super().__init__(NODE_NAME, **node_options)
        self._stopping = stopping
        self._workers: WorkerPools | None = None
        defaults_path = Path(config_path) if config_path is not None else default_config_path()
        self.config = self._declare_parameters(defaults_path)
        # the vessel, resolved once (models/loading.resolve_vessel): the configured preset, else (none installed of
        # that name) the description the model embeds under that name
        configured = loading.resolve_vessel(self.config.vessel) if vessel_preset_exists(self.config.vessel) else None
        if configured is not None:  # the configuration's own errors before the model's
            self._layout_inputs(configured.actuator_layout)
        # the model and its vessel (ModelError, ConfigError: fatal at start-up); the vessel's actuator layout says
        # which inputs are read
        self.rollout, self.vessel = load_model(self.config.model_path, self.config, configured, abandon=stopping)
        self.layout = self.vessel.actuator_layout
        # the compiled grey-box kernel (the fit check's causes, a grey box's rollout) compiled or loaded now, never in
        # a cycle or in the fit check's worker (compiling holds the GIL)
        self.kernel_warm_up_s = loading.warm_up(self.vessel, self.config.dt)
        self._check_stopping("after the kernel's warm-up")
        # every control role of the layout configured (ConfigError naming the roles and the layout: fatal); the
        # control roles of other layouts (the shipped config lists every layout's) are ignored: logged once here,
        # reported on /diagnostics ("ignored inputs")
        ignored_notes = self._layout_inputs(self.layout)
        self.ignored = {entry.role: entry.topic for entry in self.config.inputs
                        if entry.role in unused_roles(self.layout)}
        used = [entry for entry in self.config.inputs if entry.role not in self.ignored]
        self.inputs = live.InputSet(
            {entry.role: msg_adapters.ROLE_FIELDS[entry.role] for entry in used},
            {entry.role: float(self.get_parameter(f"inputs.{entry.role}.max_age_s").value) for entry in used},
            self._live_settings(), self.layout,
        )
        _check_output_types(self.config)
        make = msg_adapters.rclpy_factory()
        self._clock = self.get_clock()
        self._entries: dict[str, InputConfig] = {entry.role: entry for entry in used}
        self._adapters = {
            entry.role: msg_adapters.get_adapter(entry.role, entry.ros_type, **entry.options)
            for entry in used
        }
        self._deserializers = {entry.role: _deserializer(make(entry.ros_type), entry.ros_type) for entry in used}
        self._failures = {role: DecodeFailures() for role in self._entries}
        # CDR bytes and their arrival clock, decoded in bulk at the next timer (bounded: the oldest go first)
        capacity = self.inputs.settings.capacity
        self._pending: dict[str, deque[tuple[bytes, int]]] = {role: deque(maxlen=capacity) for role in self._entries}
        self.arrived = {role: 0 for role in self._entries}  # messages received per input (decoded or pending)
        self.dropped = {role: 0 for role in self._entries}  # pushed out of a full pending queue undecoded
        # one subscription per topic; roles sharing one (both thrusters in one Float64MultiArray, JointState or
        # Wrench) each decode their own part of its messages (msg_adapters.check_shared: which can share)
        by_topic: dict[str, list[str]] = {}
        for entry in used:
            by_topic.setdefault(self.resolve_topic_name(entry.topic), []).append(entry.role)
        self._check_topics(by_topic)
        for topic, roles in by_topic.items():
            try:
                msg_adapters.check_shared(topic, [self._adapters[role] for role in roles])
            except AdapterError as err:
                raise ConfigError(f"{self.config.source}: {err}") from err
            self.create_subscription(make(self._entries[roles[0]].ros_type), self._entries[roles[0]].topic,
                                     partial(self._on_message, tuple(roles)), qos_profile_sensor_data, raw=True)
        outputs = self.config.outputs
        self._path_pub = self.create_publisher(make(PATH_TYPE), outputs["predicted_path"].topic, 10)
        self._velocities_pub = self.create_publisher(make(TRAJECTORY_TYPE), outputs["predicted_velocities"].topic, 10)
        self._covariance_pub = self.create_publisher(make(COVARIANCE_TYPE), COVARIANCE_TOPIC, 10)
        self._diagnostics = self.create_publisher(make(DIAGNOSTICS_TYPE), DIAGNOSTICS_TOPIC, 10)
        self._candidates_pub = self.create_publisher(make(TRAJECTORY_TYPE), CANDIDATE_PREDICTIONS_TOPIC, 10)
        self._current_pub = self.create_publisher(make(CURRENT_TYPE), outputs["estimated_current"].topic, 10)
        self.candidate_rollout = self._candidates_of(self.rollout)  # the candidates' model (candidates_members)
        self.sea = self._make_sea(self.rollout, {})
        self.fit = self._make_fit(self.rollout)
        self._check_stopping("after the fit check's model")
        self._workers = WorkerPools.start(int(self.get_parameter("candidates_threads").value))
        self._cycle_gap = CycleGap(1.0 / self.config.rate_hz)  # the fit check's GIL-heavy parts run between cycles
        self._fit_running: Future | None = None
        # candidate plans: state and controls on the executor's thread, the batched rollout (13-20 ms for 64), the
        # answer's encoding and publishing on the candidates' worker, so that the 10 Hz cycle is not held up (numpy
        # releases the GIL inside its products and activations); where the sea estimate writes the model's terms
        # (sea.py: grey box, hybrid) they and a candidate rollout take turns on _terms_lock (_terms_guard)
        self._terms_lock = threading.Lock()
        self.plan = PlanInput(PLAN_TOPIC)
        self.candidates = PlanInput(CANDIDATE_PLANS_TOPIC)
        self.following: plans.Plan | None = None  # the plan the predictions are made under
        self._plan_ended = ""  # why the node stopped following the latest plan (stale), for /diagnostics
        self._plan_ended_ns: int | None = None
        self.create_subscription(make(plans.PLAN_TYPE), PLAN_TOPIC, self._on_plan, 10, raw=True)
        self.create_subscription(make(plans.PLAN_TYPE), CANDIDATE_PLANS_TOPIC, self._on_candidates, 10, raw=True)
        self._latencies: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self._cycle_times: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self.published = 0
        self.skipped = 0
        self.model_refused: tuple[str, str] | None = None  # (model_path, why) of the last refused swap
        self.last_skip = ""
        self.last_prediction: live.Prediction | None = None
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.create_timer(1.0 / self.config.rate_hz, self._on_timer)
        self.create_timer(1.0 / float(self.get_parameter("diagnostics_rate_hz").value), self._on_diagnostics_timer)
        self.create_timer(FIT_TIMER_S, self._on_fit_timer)  # runs a check when fit_check.period_s has passed
        for note in ignored_notes:
            self.get_logger().info(note)
        self.get_logger().info(
            f"usv_predictor {__version__}: model {self.rollout.artifact.path} ({self.rollout.artifact.model_id}, "
            f"{self.rollout.members} member(s)), {len(self._entries)} inputs ({', '.join(self._entries)}), "
            f"{self.config.rate_hz:g} Hz, horizon {self.config.horizon_s:g} s, parameters from {defaults_path}; "
            f"grey-box kernel ready in {self.kernel_warm_up_s:.1f} s"
        )

    def _check_topics(self, inputs: dict[str, list[str]]) -> None:
        """Every topic the node publishes or subscribes to, as remapped, is its own: an input or an output remapped
        onto another (`-r imu/data:=/diagnostics`, `-r predicted_path:=/diagnostics`) is a ConfigError naming both,
        before DDS refuses the second endpoint with an RCLError (or, of one type, the node hears itself)."""
        seen = {topic: f"input {', '.join(roles)}" for topic, roles in inputs.items()}
        outputs = self.config.outputs
        endpoints = [("output predicted_path", outputs["predicted_path"].topic),
                     ("output predicted_velocities", outputs["predicted_velocities"].topic),
                     ("output estimated_current", outputs["estimated_current"].topic),
                     ("output predicted_path_covariance", COVARIANCE_TOPIC), ("output /diagnostics", DIAGNOSTICS_TOPIC),
                     ("output candidate_predictions", CANDIDATE_PREDICTIONS_TOPIC), ("input plan", PLAN_TOPIC),
                     ("input candidate_plans", CANDIDATE_PLANS_TOPIC)]
        for what, name in endpoints:
            resolved = self.resolve_topic_name(name)
            if resolved in seen:
                raise ConfigError(f"node {self.get_name()}: {what} resolves to {resolved}, the topic of its "
                                  f"{seen[resolved]} too: remap one of them to a topic of its own")
            seen[resolved] = what

    def _check_stopping(self, step: str) -> None:
        """loading.Abandoned once the process is asked to stop: start-up goes no further (main ends with the stop's
        code), so that a stop during it is done within 2 s."""
        if self._stopping is not None and self._stopping():
            raise loading.Abandoned(f"node {self.get_name()}: stopping during start-up ({step})")

    @property
    def workers(self) -> WorkerPools:
        """The node's worker pools (made at start-up, once the model and the inputs are set up)."""
        if self._workers is None:
            raise RuntimeError(f"node {self.get_name()}: its worker pools are not started")
        return self._workers

    def destroy_node(self) -> None:
        """The workers end first (a candidate batch or a fit check running finishes: at most a few seconds)."""
        if self._workers is not None:
            self._workers.shutdown()
        super().destroy_node()

    # --------------------------------------------------------------- parameters
    def _declare_parameters(self, defaults_path: Path) -> PredictorConfig:
        """Declare every parameter of the defaults file and the node's own; validate the effective values."""
        defaults = flatten_ros_parameters(read_ros_parameters(defaults_path))
        defaults = {**online_defaults(), **defaults}  # a file without an `online` section: OnlineConfig's defaults
        try:
            for name, raw in defaults.items():
                value = _declared_value(name, raw)
                self.declare_parameter(name, value, _descriptor(name, value))
            for name, spec in NODE_PARAMETERS.items():
                self.declare_parameter(name, spec.default, _node_descriptor(name, spec))
        except ParameterException as err:
            raise ConfigError(
                f"node {self.get_name()}: parameter rejected ({err}); defaults from {defaults_path}"
            ) from err
        effective = {name: self.get_parameter(name).value for name in defaults}
        source = f"{defaults_path} (with the node's parameter overrides)"
        return parse_predictor_config(unflatten_ros_parameters(effective), source=source)

    def _live_settings(self) -> live.LiveSettings:
        value = {name: self.get_parameter(name).value for name in NODE_PARAMETERS}
        datum = datum_of(value["datum_lat_deg"], value["datum_lon_deg"])
        return live.LiveSettings(dt=self.config.dt, horizon_steps=self.config.horizon_steps,
                                 state_delay_s=float(value["state_delay_s"]), max_future_s=float(value["max_future_s"]),
                                 capacity=int(value["buffer_capacity"]), datum=datum)

    def _plan_limits(self) -> plans.PlanLimits:
        return plans.PlanLimits(max_age_s=float(self.get_parameter("plan_max_age_s").value),
                                max_future_s=self.inputs.settings.max_future_s)

    def _layout_inputs(self, layout: ActuatorLayout) -> list[str]:
        """check_layout_inputs of the configured inputs for `layout` (ConfigError naming the missing roles)."""
        return check_layout_inputs(layout, {entry.role: entry.topic for entry in self.config.inputs},
                                   f"{self.config.source}, vessel {self.config.vessel}")

    def _on_set_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        """Swap the model (validated first; the old one stays on failure) and apply new staleness limits.

        use_sim_time is fixed once the node runs: switched on by a peer, the clock would be whoever publishes /clock
        (this callback runs before rclpy's TimeSource's, which is why refusing here keeps the clock)."""
        if any(p.name == USE_SIM_TIME for p in parameters):
            return SetParametersResult(successful=False, reason=f"{USE_SIM_TIME} is fixed at start-up (-p "
                                       f"{USE_SIM_TIME}:=true): switched by a peer, /clock would own the node's clock")
        swap: live.Rollout | None = None
        online = {p.name: p.value for p in parameters if p.name.startswith(ONLINE_PREFIX)}
        fit_changes = {p.name: p.value for p in parameters if p.name.startswith(FIT_PREFIX)}
        try:
            self._online_config(online)
            fit_settings = self._fit_settings(fit_changes)
        except ConfigError as err:
            return SetParametersResult(successful=False, reason=str(err))
        for parameter in parameters:
            if parameter.name == "model_path":
                try:
                    swap, _ = load_model(str(parameter.value), self.config, self.vessel, self._stopping)
                    candidates = self._candidates_of(swap)
                except Exception as err:  # noqa: BLE001 - the callback boundary: any file, however made, is refused
                    # (a ModelError or ConfigError names the culprit; anything else is what the model's own code or
                    # metadata raised past the checks) and the old model keeps predicting
                    why = one_line(err) if isinstance(err, (ModelError, ConfigError)) else \
                        f"model {parameter.value} cannot be used: {type(err).__name__}: {one_line(err)}"
                    self.model_refused = (str(parameter.value), why)
                    self.get_logger().error(f"model_path not changed, keeping {self.rollout.artifact.path}: {why}")
                    return SetParametersResult(successful=False, reason=why)
        if swap is not None:
            self.model_refused = None
            self.rollout = swap
            self.candidate_rollout = candidates
            self.get_logger().info(f"model swapped to {swap.artifact.path} ({swap.artifact.model_id})")
        if swap is not None or online:
            with self._terms_lock:
                self.sea.restore()
            self.sea = self._make_sea(self.rollout, online)
            self.sea.last_reset = "the model was swapped" if swap is not None else "online parameters changed"
        if swap is not None:
            self.fit = self._make_fit(swap, fit_settings)
            self.fit.last_reset = "the model was swapped"
        self.fit.settings = fit_settings
        for parameter in parameters:
            role = parameter.name.removeprefix("inputs.").removesuffix(".max_age_s")
            if parameter.name.endswith(".max_age_s") and role in self.inputs.tracks:
                self.inputs.tracks[role].max_age_s = float(parameter.value)
        return SetParametersResult(successful=True)

    # --------------------------------------------------------------- inputs: bytes in, decoded in bulk
    def _on_message(self, roles: tuple[str, ...], raw: bytes) -> None:
        """Keep the CDR bytes and the arrival clock for each role of the topic; decoding waits for the next timer
        (one bulk call per input, each role's adapter reading its part of a shared topic's messages)."""
        arrival_ns = self._clock.now().nanoseconds
        for role in roles:
            pending = self._pending[role]
            if len(pending) == pending.maxlen:
                self.dropped[role] += 1
            pending.append((raw, arrival_ns))
            self.arrived[role] += 1

    def _catch_up(self, now_ns: int) -> None:
        """Clear the buffers if the clock jumped back, then decode and buffer every pending message.

        Under use_sim_time the clock reads 0 until the first /clock message: nothing is decoded then, and messages
        that arrived then take the first reading after it as their arrival clock (else a header stamp would be
        refused as 1.6e9 s ahead of the clock, and a header-less message stamped 0)."""
        if now_ns == 0:
            return
        if self.inputs.observe_clock(now_ns):
            self.get_logger().warning("the clock jumped back: input buffers cleared, sea estimate reset")
            with self._terms_lock:
                self.sea.reset("the clock jumped back")
            self.fit.reset("the clock jumped back")
            for pending in self._pending.values():  # what arrived before the jump belongs to the old time line
                kept = [(raw, at_ns) for raw, at_ns in pending if at_ns <= now_ns]
                pending.clear()
                pending.extend(kept)
        for role, pending in self._pending.items():
            if pending:
                messages = [(raw, at_ns or now_ns) for raw, at_ns in pending]  # at_ns 0: before the clock started
                pending.clear()
                self._take(role, messages)

    def _take(self, role: str, messages: list[tuple[bytes, int]]) -> None:
        """Decode one input's messages in one call (msg_adapters.cdr) and add them in arrival order (a batch of
        live.BULK_ADD_MIN or more with no decode error and no raw heading beyond a turn: InputSet.add_many)."""
        entry = self._entries[role]
        batch = decode_values(self._adapters[role], [raw for raw, _ in messages], deserialize=self._deserializers[role])
        errors = dict(batch.errors)
        raw_heading = getattr(batch.columns, "data", None) if role == "heading" else None
        units = str(entry.options.get("units", "deg"))
        if (len(messages) >= live.BULK_ADD_MIN and not errors
                and (raw_heading is None or live.raw_headings_within_a_turn(raw_heading, units))):
            arrivals = np.fromiter((arrival_ns for _, arrival_ns in messages), dtype=np.int64, count=len(messages))
            stamps = arrivals if batch.stamps is None else batch.stamps
            for err in self.inputs.add_many(role, stamps, batch.values, arrivals, at_arrival=batch.stamps is None):
                self._warn_input(role, str(err))
            return
        row = 0
        for i, (_, arrival_ns) in enumerate(messages):
            if i in errors:
                failures = self._failures[role]
                failures.count, failures.last, failures.at_ns = failures.count + 1, errors[i], arrival_ns
                self._warn_input(role, errors[i])
                continue
            stamp_ns = arrival_ns if batch.stamps is None else int(batch.stamps[row])
            values = tuple(batch.values[row].tolist())
            try:
                if raw_heading is not None:
                    live.check_raw_heading(float(raw_heading[row]), units)
            except live.InputRejected as err:
                self.inputs.tracks[role].received += 1
                self.inputs.tracks[role].reject(err.kind, str(err), arrival_ns)
                self._warn_input(role, str(err))
                row += 1
                continue
            row += 1
            try:
                self.inputs.add(role, stamp_ns, values, arrival_ns, at_arrival=batch.stamps is None)
            except live.InputRejected as err:
                self._warn_input(role, str(err))

    def _warn_input(self, role: str, message: str) -> None:
        self.get_logger().warning(f"input {role} on {self._entries[role].topic}: {message}",
                                  throttle_duration_sec=ERROR_LOG_PERIOD_S)

    # --------------------------------------------------------------- plans
    def _on_plan(self, raw: bytes) -> None:
        """A plan to predict under from the next cycle on (it replaces the previous one; refused: held commands)."""
        now_ns = self._clock.now().nanoseconds
        self.plan.received += 1
        try:
            self.following = plans.parse_plan(decode_joint_trajectory(raw), self.layout, now_ns, self._plan_limits())
        except (live.InputRejected, AdapterError) as err:
            kind = getattr(err, "kind", "malformed")
            self.plan.refuse(kind, str(err), now_ns)
            self.following = None
            self.get_logger().warning(f"plan on {self.resolve_topic_name(PLAN_TOPIC)} refused, predicting with the "
                                      f"current commands held: {err}", throttle_duration_sec=ERROR_LOG_PERIOD_S)

    def _current_plan(self, now_ns: int) -> plans.Plan | None:
        """The plan to follow this cycle, or None (held commands) once it is older than plan_max_age_s."""
        plan = self.following
        if plan is not None and plan.age_s(now_ns) > self._plan_limits().max_age_s:
            self._plan_ended = (f"the plan stamped {plans.describe_stamp(plan.stamp_ns)} is stale "
                                f"({plan.age_s(now_ns):.2f} s old, plan_max_age_s {self._plan_limits().max_age_s:g} s)")
            self._plan_ended_ns = now_ns
            self.following = None
            return None
        return plan

    def _on_candidates(self, raw: bytes) -> None:
        """Candidate plans: decoded, checked and their state and controls prepared here; the batched rollout and the
        answer, tagged with the plans' stamp, on the candidates' worker (_answer_candidates)."""
        started = time.perf_counter()
        now_ns = self._clock.now().nanoseconds
        self.candidates.received += 1
        self._catch_up(now_ns)
        try:
            data = decode_joint_trajectory(raw)
            batch = plans.parse_plan(data, self.layout, now_ns, self._plan_limits(), candidates=True)
        except (live.InputRejected, AdapterError) as err:
            self.candidates.refuse(getattr(err, "kind", "malformed"), str(err), now_ns)
            self.get_logger().warning(f"candidate plans on {self.resolve_topic_name(CANDIDATE_PLANS_TOPIC)} refused: "
                                      f"{err}", throttle_duration_sec=ERROR_LOG_PERIOD_S)
            return
        try:
            if self.fit.refusing:
                raise live.CycleSkipped(self.fit.refusing)
            prepared = live.prepare_batch(self.inputs, now_ns, batch.schedule)
        except (live.CycleSkipped, ModelError, AdapterError, RuntimeError) as err:
            self._no_candidates_answer(err)
            return
        self.workers.candidates.submit(self._answer_candidates, self.candidate_rollout, batch, prepared, now_ns,
                                       started)

    def _candidates_of(self, rollout: live.Rollout) -> live.Rollout:
        """The model the candidate plans are rolled out with: `rollout` itself, or its first candidates_members
        members (live.Rollout: a fused DNN is fused again with those only); ConfigError when it asks for more members
        than the node uses."""
        wanted = int(self.get_parameter("candidates_members").value)
        if wanted == 0 or wanted == rollout.members:
            return rollout
        if wanted > rollout.members:
            raise ConfigError(f"node {NODE_NAME}: parameter candidates_members = {wanted}: expected at most the "
                              f"{rollout.members} member(s) the node uses (ensemble_size), or 0 for all of them")
        return live.Rollout(rollout.artifact, rollout.horizon_steps, wanted)

    def _answer_candidates(self, rollout: live.Rollout, batch: plans.Plan, prepared: live.PreparedBatch, now_ns: int,
                           started: float) -> None:
        """The candidates' worker: one batched rollout, the answer encoded and published. An unexpected exception is
        logged here (a worker's exception would otherwise stay in its Future, unseen)."""
        try:
            try:
                with self._terms_guard():
                    result = live.predict_prepared(rollout, prepared, now_ns, self.workers.candidates_helper)
            except (live.CycleSkipped, ModelError, AdapterError, RuntimeError) as err:  # CycleSkipped: NaN output
                self._no_candidates_answer(err)
                return
            if not self.context.ok():  # shutting down: publishing would fail
                return
            self._candidates_pub.publish(candidate_predictions_cdr(batch.stamp_ns, result.t_ns, result.eta, result.nu,
                                                                   self.config.frame_id, batch.names))
            self.candidates.answered += 1
            self.candidates.skipped = ""
            self.candidates.batch = len(batch.names)
            self.candidates.compute_s.append(result.compute_s)
            self.candidates.answer_s.append(time.perf_counter() - started)
        except Exception as err:  # noqa: BLE001 - the worker's boundary: say it, the node carries on
            self.candidates.skipped = f"{type(err).__name__}: {err}"
            self.get_logger().error(f"candidate plans: the answer failed: {type(err).__name__}: {err}")

    def _terms_guard(self) -> Any:
        """_terms_lock when the sea estimate writes terms into the model (sea.applied: grey box, hybrid), else
        nothing to guard: a DNN's estimate is computed beside it, and its cycle never waits for candidates."""
        return self._terms_lock if self.sea.applied else contextlib.nullcontext()

    def _no_candidates_answer(self, err: Exception) -> None:
        self.candidates.skipped = str(err)
        self.get_logger().warning(f"no prediction for the candidate plans: {err}",
                                  throttle_duration_sec=ERROR_LOG_PERIOD_S)

    # --------------------------------------------------------------- the cycle
    def _on_timer(self) -> None:
        if not self.context.ok():  # shutting down (SIGINT/SIGTERM): publishing would fail
            return
        started = time.perf_counter()
        now_ns = self._clock.now().nanoseconds
        self._catch_up(now_ns)
        plan = self._current_plan(now_ns)
        # the sea estimate feeds on the cycle's state; a model it sets terms of (grey box, hybrid) needs it before the
        # rollout, a model it is not applied to (a DNN) gets it after the outputs are published (the same state: the
        # filter step, ~0.5 ms every dt, is then not in the prediction's latency)
        deferred: list[live.LiveState] = []
        try:
            if self.fit.refusing:  # fit_check.refuse: a model that does not fit the inputs predicts nothing
                raise live.CycleSkipped(self.fit.refusing)
            prediction = live.predict(self.inputs, self.rollout, now_ns, None if plan is None else plan.schedule,
                                      observe=self._observe_sea if self.sea.applied else deferred.append)
            self._publish(prediction, prediction.stamp_ns if plan is None else plan.stamp_ns)
        except (live.CycleSkipped, ModelError, AdapterError, RuntimeError) as err:
            # RuntimeError: what a TorchScript module raises; the cycle is lost, the node carries on
            self.skipped += 1
            self.last_skip = str(err)
            self.get_logger().warning(f"no prediction: {err}", throttle_duration_sec=ERROR_LOG_PERIOD_S)
        else:
            self.published += 1
            self.last_skip = ""
            self.last_prediction = prediction
            self._latencies.append(prediction.compute_s)
            self._cycle_times.append(time.perf_counter() - started)
        finally:
            for state in deferred:
                self._observe_sea(state)
            self._cycle_gap.ended()

    def _publish(self, prediction: live.Prediction, stamp_ns: int) -> None:
        """The three outputs as CDR bytes; header.stamp = the cycle's clock, or the stamp of the plan followed."""
        frame = self.config.frame_id
        self._path_pub.publish(path_cdr(stamp_ns, prediction.t_ns, prediction.eta, frame))
        self._velocities_pub.publish(predicted_velocities_cdr(stamp_ns, prediction.t_ns, prediction.eta, prediction.nu,
                                                              frame, self.config.base_frame_id))
        if len(prediction.eta_members) > 1:
            self._covariance_pub.publish(covariance_cdr(live.enu_covariance(prediction.eta_members)))

    # --------------------------------------------------------------- the sea estimate (sea.py)
    def _online_config(self, changes: dict[str, Any]) -> tuple[bool, OnlineConfig]:
        """(enabled, OnlineConfig) of the `online.*` parameters with `changes` (name -> new value) applied;
        ConfigError naming the parameter when OnlineConfig refuses the combination."""
        value = {name: self.get_parameter(name).value for name in online_defaults()}
        value.update(changes)
        fields = {leaf: float(value[name]) for name in value if (leaf := _online_leaf(name)) is not None}
        try:
            return bool(value[f"{ONLINE_PREFIX}enabled"]), OnlineConfig(**fields)
        except ConfigError as err:
            raise ConfigError(f"node {NODE_NAME}: parameters online.*: {err}") from err

    def _make_sea(self, rollout: live.Rollout, changes: dict[str, Any]) -> sea.LiveSea:
        enabled, config = self._online_config(changes)
        return sea.LiveSea(rollout.artifact, self.vessel, config, enabled, self.config.dt, self.config.rate_hz)

    def _observe_sea(self, state: live.LiveState) -> None:
        """The cycle's state (before its rollout when the estimate is applied to the model, else after its outputs):
        feed the estimator when the state is on its dt grid, publish the estimate."""
        with self._terms_guard():
            fed = self.sea.observe(state)
        if fed is not None and self.sea.started():
            estimate = fed.estimate
            self._current_pub.publish(current_cdr(fed.t_c_ns, estimate.current_ne, estimate.current_cov,
                                                  self.config.frame_id))

    def _sea_status(self, now_ns: int) -> Status:
        warn, message, values = self.sea.report(now_ns)
        return self._status(WARN if warn else OK, "sea estimate", message, values)

    # --------------------------------------------------------------- the fit check (fit.py), own timer
    def _fit_settings(self, changes: dict[str, Any] | None = None) -> FitCheckSettings:
        """FitCheckSettings of the `fit_check.*` parameters with `changes` applied (ConfigError naming the one
        refused)."""
        value = {name: self.get_parameter(name).value for name in NODE_PARAMETERS if name.startswith(FIT_PREFIX)}
        value.update(changes or {})
        return FitCheckSettings(enabled=bool(value[f"{FIT_PREFIX}enabled"]),
                                period_s=float(value[f"{FIT_PREFIX}period_s"]),
                                refuse=bool(value[f"{FIT_PREFIX}refuse"]))

    def _make_fit(self, rollout: live.Rollout, settings: FitCheckSettings | None = None) -> LiveFitCheck:
        """The fit check of `rollout`'s model on its own copy of the model file (fit.py: its rollouts run in the
        worker thread, and the sea estimate set in the node's grey box never reaches the copy)."""
        artifact = rollout.artifact
        meta = artifact.metadata
        label = (f"the preset {meta.get('vessel')}" if str(meta.get("model_type", "")).startswith("physics")
                 else f"model {artifact.model_id} ({meta.get('model_type', '?')}, vessel {meta.get('vessel')})")
        copy = loading.load_model(str(artifact.path), physics=False, abandon=self._stopping)
        return LiveFitCheck(copy, self.vessel, self.layout, label, settings or self._fit_settings())

    def _on_fit_timer(self) -> None:
        """A fit check on the buffered inputs when one is due (fit.py); the verdict is read by the cycle (refuse)
        and /diagnostics."""
        if not self.context.ok():
            return
        now_ns = self._clock.now().nanoseconds
        if not self.fit.due(now_ns) or (self._fit_running is not None and not self._fit_running.done()):
            return
        self._catch_up(now_ns)
        refused = "; ".join(f"input {role} refused: {why}" for role, why in self.inputs.refusals.values())
        if refused:
            self.fit.skip(refused, now_ns)
            return
        try:
            recording = self.inputs.buffered_recording(FIT_MAX_GAP_S)  # a snapshot of the buffers, in this thread
        except RecordingError as err:  # less than a step: full buffers say why
            self.fit.skip(self._buffers_too_short(0.0) or str(err), now_ns)
            return
        short = self._buffers_too_short(recording.duration_s)
        if short:
            self.fit.skip(short, now_ns)
            return
        reference = None
        if self.inputs.approach is not None:  # rudder_only: the approach the predictions hold, seen in the buffers too
            self.inputs.approach.observe_recording(recording)
            reference = self.inputs.approach.reference
        self._fit_running = self.workers.fit.submit(self._run_fit, self.fit, recording, now_ns, reference)

    def _buffers_too_short(self, span_s: float) -> str:
        """Why no steady window can ever be seen ("" when one can): the span the check reads is shorter than a window
        needs because an input's ring buffer is full and itself spans less (a fast IMU fills buffer_capacity samples
        in seconds), not because of a recent gap."""
        need_s = max(FIT_MIN_HOLD_S, FIT_STEADY_S)
        if span_s >= need_s:
            return ""
        full = []
        for role in self.inputs.required:
            buffer = self.inputs.tracks[role].buffer
            if len(buffer) == buffer.capacity and (buffer.latest_ns - buffer.oldest_ns) / NS_PER_S < need_s:
                full.append(role)
        if not full:
            return ""
        return (f"the input buffers hold {span_s:.1f} s ({', '.join(full)}: "
                f"{self.inputs.tracks[full[0]].buffer.capacity} "
                f"samples, full), less than the {need_s:g} s a steady window needs: raise buffer_capacity to at least "
                f"{need_s:g} s of the fastest input")

    def _run_fit(self, fit: LiveFitCheck, recording: Any, now_ns: int, reference: Any = None) -> None:
        """The check's rollouts, in the worker thread; the verdict is read by the cycle and /diagnostics."""
        try:
            check = fit.run(recording, now_ns, reference, self._cycle_gap)
        except Exception as err:  # noqa: BLE001 -- a worker's exception would vanish in its Future: reported instead
            fit.skip(f"the check failed: {type(err).__name__}: {_first_line(err)}", now_ns)
            self.get_logger().warning(f"fit check not run: {err}", throttle_duration_sec=ERROR_LOG_PERIOD_S)
            return
        if check is not None and check.mismatch:
            self.get_logger().error(f"fit check: {fit.report(now_ns)[1]}", throttle_duration_sec=FIT_LOG_PERIOD_S)

    def _fit_status(self, now_ns: int) -> Status:
        level, message, values = self.fit.report(now_ns)
        return self._status({"ok": OK, "warn": WARN, "error": ERROR}[level], "fit check", message, values)

    # --------------------------------------------------------------- /diagnostics (own rate)
    def _on_diagnostics_timer(self) -> None:
        if not self.context.ok():
            return
        now_ns = self._clock.now().nanoseconds
        self._catch_up(now_ns)
        self._publish_diagnostics(now_ns)

    def _publish_diagnostics(self, now_ns: int) -> None:
        self._current_plan(now_ns)  # a plan that went stale is dropped before any status reads it: one story per report
        statuses = [self._input_status(role, now_ns) for role in self._entries]
        statuses += [self._model_status(), self._prediction_status(), self._plan_status(now_ns),
                     self._candidates_status(now_ns), self._sea_status(now_ns), self._fit_status(now_ns)]
        if self.ignored:
            statuses.append(self._ignored_status())
        self._diagnostics.publish(diagnostics_cdr(now_ns, statuses))

    def _status(self, level: int, what: str, message: str, values: dict[str, Any]) -> Status:
        return Status(level, f"{self.get_name()}: {what}", message, self.config.base_frame_id,
                      tuple((key, str(value)) for key, value in values.items()))

    def _input_status(self, role: str, now_ns: int) -> Status:
        track, entry, failures = self.inputs.tracks[role], self._entries[role], self._failures[role]
        age = track.age_s(now_ns)
        values: dict[str, Any] = {
            "topic": self.resolve_topic_name(entry.topic),
            "type": entry.ros_type,
            "messages": track.received + failures.count,
            "decode_errors": failures.count,
            "rejected": sum(track.rejected.values()),
            **{f"rejected_{kind}": count for kind, count in sorted(track.rejected.items())},
            "dropped_undecoded": self.dropped[role],
            # header-less: a newer message at the same clock reading (live.InputSet.add)
            "superseded": track.superseded,
            "rate_hz": f"{track.buffer.rate_hz(now_ns):.1f}",
            "buffer": f"{len(track.buffer)}/{track.buffer.capacity}",
            "max_age_s": f"{track.max_age_s:g}",
        }
        if age is not None:
            values["age_s"] = f"{age:.3f}"
            t, latest = track.buffer.samples()
            values.update({name: f"{v:.6g}" for name, v in zip(track.buffer.fields, latest[-1])})
        if failures.last:
            values["last_decode_error"] = failures.last
        if track.last_reject:
            values["last_rejected"] = track.last_reject
        recent_reject = track.last_reject_ns is not None and now_ns - track.last_reject_ns < RECENT_REJECT_S * NS_PER_S
        if failures.at_ns is not None and (track.last_accept_ns is None or failures.at_ns > track.last_accept_ns):
            return self._status(ERROR, f"input {role}", f"cannot decode messages: {failures.last}", values)
        if track.refused:  # it disagrees with a redundant input (live.InputSet.check_consistency)
            return self._status(ERROR, f"input {role}", f"refused: {track.refused}", values)
        if age is None:
            if track.last_reject:
                return self._status(ERROR, f"input {role}", f"every message refused: {track.last_reject}", values)
            return self._status(ERROR, f"input {role}", "no message received", values)
        if age > track.max_age_s:
            stale = f"stale: last message {age:.2f} s ago (limit {track.max_age_s:g} s)"
            # refusals are why an input goes stale while its messages still arrive (stamps behind, ahead, ...)
            refused = f"; messages refused: {track.last_reject}" if recent_reject else ""
            return self._status(WARN, f"input {role}", stale + refused, values)
        if recent_reject:
            return self._status(WARN, f"input {role}", f"messages refused: {track.last_reject}", values)
        return self._status(OK, f"input {role}", "fresh", values)

    def _ignored_status(self) -> Status:
        """The configured control inputs of other actuator layouts: not subscribed (check_layout_inputs)."""
        values = {"actuator_layout": self.layout.name, "vessel": self.config.vessel,
                  **{role: self.resolve_topic_name(topic) for role, topic in sorted(self.ignored.items())}}
        return self._status(OK, "ignored inputs", f"not subscribed: {', '.join(sorted(self.ignored))} (controls of "
                            f"other actuator layouts than {self.layout.name})", values)

    def _model_status(self) -> Status:
        artifact = self.rollout.artifact
        meta = artifact.metadata
        values = {
            "model_path": str(artifact.path), "model_id": artifact.model_id, "model_type": meta.get("model_type"),
            "family": _family_description(meta),
            "feature_set": meta.get("feature_set"), "vessel": meta.get("vessel"), "dt": f"{artifact.dt:g}",
            "ensemble_size": f"{self.rollout.members}/{artifact.ensemble_size}",
            "rollout": artifact.inference_note,  # fused (a DNN), the compiled kernel (a grey box) or the file's own
            "kernel_ready_s": f"{self.kernel_warm_up_s:.2f}",  # the kernel compiled or loaded at start-up
            "training_data_sha256": meta.get("training_data_sha256"), "created_utc": meta.get("created_utc"),
            "horizon_s": f"{self.config.horizon_s:g}", "version": __version__,
        }
        if self.model_refused is not None:  # still predicting with the model above
            path, why = self.model_refused
            values.update(refused_model_path=path, refused_because=why)
            return self._status(WARN, "model", f"loaded {artifact.model_id}; model_path {path} refused: {why}", values)
        return self._status(OK, "model", f"loaded {artifact.model_id}", values)

    def _prediction_status(self) -> Status:
        values: dict[str, Any] = {"published": self.published, "skipped": self.skipped,
                                  "rate_hz": f"{self.config.rate_hz:g}"}
        values.update(_percentiles("compute_ms", self._latencies))  # the rollout
        values.update(_percentiles("cycle_ms", self._cycle_times))  # decode, state, rollout, encode, publish
        values["controls"] = ("held" if self.following is None
                              else f"plan stamped {plans.describe_stamp(self.following.stamp_ns)}")
        for check, why in sorted(self.inputs.unjudged.items()):  # a check that cannot judge refuses nothing
            values[f"check {check}"] = f"cannot judge: {why}"
        last = self.last_prediction
        if last is not None:
            values["anchored"] = "gnss" if last.anchored else "relative to (0, 0): no GNSS"
            spread = np.sqrt(np.trace(live.enu_covariance(last.eta_members)[-1, :2, :2]))
            values["spread_at_horizon_m"] = f"{spread:.3f}"
        if self.last_skip:
            values["reason"] = self.last_skip
            return self._status(WARN, "prediction", f"skipped: {self.last_skip}", values)
        if last is None:
            return self._status(WARN, "prediction", "no prediction yet", values)
        return self._status(OK, "prediction", "published", values)

    def _plan_values(self, plan_input: PlanInput) -> dict[str, Any]:
        return {"topic": self.resolve_topic_name(plan_input.topic), "type": plans.PLAN_TYPE,
                "received": plan_input.received, "refused": sum(plan_input.refused.values()),
                **{f"refused_{kind}": count for kind, count in sorted(plan_input.refused.items())},
                "plan_max_age_s": f"{self._plan_limits().max_age_s:g}",
                **({"last_refused": plan_input.last_refused} if plan_input.last_refused else {})}

    def _plan_status(self, now_ns: int) -> Status:
        values = self._plan_values(self.plan)
        plan = self._current_plan(now_ns)
        if plan is not None:
            values.update(stamp=plans.describe_stamp(plan.stamp_ns), age_s=f"{plan.age_s(now_ns):.3f}",
                          points=len(plan.t_ns), ends_in_s=f"{(int(plan.t_ns[-1]) - now_ns) / NS_PER_S:.3f}")
            return self._status(OK, "plan", f"predicting under the plan stamped {plans.describe_stamp(plan.stamp_ns)}",
                                values)
        refused_ns, ended_ns = self.plan.last_refused_ns, self._plan_ended_ns
        latest = max((t for t in (refused_ns, ended_ns) if t is not None), default=None)
        if latest is not None and now_ns - latest < RECENT_REJECT_S * NS_PER_S:
            reason = f"refused: {self.plan.last_refused}" if latest == refused_ns else self._plan_ended
            return self._status(WARN, "plan", f"{reason}; predicting with the current commands held", values)
        return self._status(OK, "plan", "no plan: predicting with the current commands held", values)

    def _candidates_status(self, now_ns: int) -> Status:
        found = self.candidates
        values = self._plan_values(found)
        values.update(answered=found.answered, last_batch=found.batch, max_candidates=plans.MAX_CANDIDATES,
                      threads=1 if self.workers.candidates_helper is None else 2,
                      members=f"{self.candidate_rollout.members}/{self.rollout.members}")
        values.update(_percentiles("compute_ms", found.compute_s))
        values.update(_percentiles("answer_ms", found.answer_s))  # arrival -> published
        if found.last_refused_ns is not None and now_ns - found.last_refused_ns < RECENT_REJECT_S * NS_PER_S:
            return self._status(WARN, "candidate plans", f"refused: {found.last_refused}", values)
        if found.skipped:
            values["reason"] = found.skipped
            return self._status(WARN, "candidate plans", f"no prediction: {found.skipped}", values)
        if found.answered == 0:
            return self._status(OK, "candidate plans", "none received", values)
        return self._status(OK, "candidate plans", f"answered {found.answered} batch(es)", values)


def _percentiles(name: str, seconds: deque[float]) -> dict[str, str]:
    """{name_p50, name_p99, name_max} in ms of the latest values (none when empty)."""
    if not seconds:
        return {}
    ms = np.array(list(seconds)) * 1e3  # list(): one C-level copy, whole, while the candidates' worker may append
    return {f"{name}_p50": f"{np.percentile(ms, 50):.3f}", f"{name}_p99": f"{np.percentile(ms, 99):.3f}",
            f"{name}_max": f"{ms.max():.3f}"}


def _deserializer(message_type: Any, ros_type: str) -> Callable[[bytes], Any]:
    """rclpy's deserialize_message for the types msg_adapters.cdr decodes one by one (JointState,
    Float64MultiArray); a message it cannot read (rclpy raises RMWError, a RuntimeError) is an AdapterError, so
    decode_values counts it for its input and keeps the others."""
    def deserialize(raw: bytes) -> Any:
        try:
            return deserialize_message(raw, message_type)
        except RuntimeError as err:
            raise AdapterError(f"cannot decode {ros_type} message: {_first_line(err)}") from err

    return deserialize


def _check_output_types(config: PredictorConfig) -> None:
    """The outputs are written as CDR of fixed types: another configured type is a ConfigError naming it."""
    expected = {"predicted_path": PATH_TYPE, "predicted_velocities": TRAJECTORY_TYPE, "estimated_current": CURRENT_TYPE}
    for role, ros_type in expected.items():
        if config.outputs[role].ros_type != ros_type:
            raise ConfigError(f"{config.source}: outputs.{role}.type is {config.outputs[role].ros_type!r}; "
                              f"the node publishes {ros_type}")


def make_executor(context: Context | None = None) -> Executor:
    """The executor `main` spins the node with: rclpy's EventsExecutor (measured faster, docs/node.md); the
    SingleThreadedExecutor on an rclpy without it (Jazzy before 7.1.4)."""
    try:
        from rclpy.experimental import EventsExecutor
    except ImportError:
        return SingleThreadedExecutor(context=context)
    # EventsExecutor() calls faulthandler.enable(), which needs sys.stderr to have a file descriptor; where it
    # was replaced by an object without one (pytest's capture, an embedding program) the crash report goes to the
    # process's own stderr
    if not _has_fileno(sys.stderr) and _has_fileno(sys.__stderr__):
        with contextlib.redirect_stderr(sys.__stderr__):
            return EventsExecutor(context=context)
    return EventsExecutor(context=context)


def _has_fileno(stream: Any) -> bool:
    try:
        stream.fileno()
    except (AttributeError, OSError, ValueError):  # io.UnsupportedOperation is both an OSError and a ValueError
        return False
    return True


def parse_arguments(argv: Sequence[str]) -> argparse.Namespace:
    """Command-line options of `predictor` (ROS arguments after --ros-args are left to rclpy)."""
    parser = argparse.ArgumentParser(
        prog="predictor",
        description="Online 3-DOF motion prediction node for unmanned surface vehicles (usv_predictor). "
        "Subscribes to the inputs of config/predictor.yaml, rolls the TorchScript model out at rate_hz and "
        "publishes predicted_path, predicted_velocities, predicted_path_covariance and /diagnostics.",
        epilog="ROS arguments follow --ros-args, e.g.: predictor --ros-args --params-file my.yaml "
        "-p use_sim_time:=true -r imu/data:=/imu",
    )
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        help="parameter file whose values become the declared defaults "
        "(default: the package's config/predictor.yaml)",
    )
    parser.add_argument("--version", action="version", version=f"usv_predictor {__version__}")
    return parser.parse_args(remove_ros_args(list(argv))[1:])


EXIT_ERROR = 2  # a start-up error (parameter, parameter file, ROS arguments, model, vessel): one line on stderr,
                # the same code as the replay tool's bad input
SPIN_PERIOD_S = 0.1  # longest wait between two looks at the stop flag (s)


class _StopRequest:
    """SIGINT / SIGTERM / SIGHUP set a flag the spin loop reads between callbacks: a callback is never interrupted
    half-way (no publish on a context that is shutting down), and the context is shut down only after the loop ends."""

    def __init__(self) -> None:
        self.requested: int | None = None

    def __call__(self, signum: int, frame: Any) -> None:
        self.requested = signum

    def install(self) -> dict[int, Any]:
        return {sig: signal.signal(sig, self) for sig in STOP_SIGNALS}


def spin(node: Node, executor: Executor, stop: _StopRequest | None = None) -> None:
    """Run the node's callbacks until a stop signal (stop.requested) or an external shutdown of its context.

    A loop of spin_once, not executor.spin(): in rclpy 7.1.5 EventsExecutor.spin() never runs timers and does
    not return on shutdown (measured: 80 % of a core, zero timer calls), while its spin_once does both. The loop
    looks at the stop flag at least every SPIN_PERIOD_S, between callbacks (never half-way through one).
    """
    executor.add_node(node)
    try:
        while (stop is None or stop.requested is None) and node.context.ok():
            executor.spin_once(timeout_sec=SPIN_PERIOD_S)
    except ExternalShutdownException:
        pass
    except RCLError:  # a publish that raced a shutdown made elsewhere (the context is gone): a normal end
        if node.context.ok():
            raise
    finally:
        executor.shutdown(timeout_sec=SPIN_PERIOD_S)


def _lower_priority(steps: int) -> None:
    """Make the calling thread `steps` nicer (Linux: a thread is a task of its own; nice is capped at 19). A
    platform without per-thread priorities leaves it alone."""
    try:
        own = os.getpriority(os.PRIO_PROCESS, 0)  # the calling thread's on Linux
        os.setpriority(os.PRIO_PROCESS, 0, min(19, own + steps))
    except (AttributeError, OSError):
        pass


def _first_line(err: BaseException) -> str:
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of `ros2 run usv_predictor predictor`; args is a full argv (program name first), None: sys.argv
    (the program itself).

    Exit codes (EXIT_CODES): 130 after SIGINT, 143 after SIGTERM, 0 after SIGHUP, at any moment (also while
    publishing: the signal only sets a flag the spin loop reads between callbacks; during a model load the wait on
    the model's code gives up); 2 for a start-up error (one line `predictor: error: ...` on stderr: a parameter, the
    parameter file, the ROS arguments, the model, the vessel or an input adapter). A start-up error after a stop
    signal is the stop's code, without the line. The program (args None) ends through loading.exit_program: the
    atexit handlers run, the interpreter's teardown is skipped (torch's alone takes 1.5 s on a loaded machine; with
    a guard thread still inside a model's code that never returned it aborts).
    """
    code = _run(list(sys.argv if args is None else args))
    if args is None:  # the program: ended without the interpreter's teardown of torch (1.5 s) or a stuck guard thread
        loading.exit_program(code)
    return code


def _run(argv: list[str]) -> int:
    """main without its os._exit: the node's start-up, spin and stop; the exit code."""
    stop = _StopRequest()
    previous = stop.install()  # before the slow start-up (ROS, the model): an early stop is clean too
    node: PredictorNode | None = None
    try:
        options = parse_arguments(argv)  # --help exits here, before ROS starts
        import torch

        torch.set_num_threads(1)  # one rollout of a tiny network: threads cost more than they give
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)  # our handlers stop the loop
        if stop.requested is None:
            node = PredictorNode(config_path=options.config, stopping=lambda: stop.requested is not None)
        if stop.requested is None:
            spin(node, make_executor(node.context), stop)
    except (RCLInvalidROSArgsError, ParameterException, RCLError, UsvPredictorError) as err:
        if stop.requested is not None:  # what a stop cut short (a model load given up on): the stop's code
            return EXIT_CODES[stop.requested]
        print(f"predictor: error: {_start_up_error(err)}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:  # a SIGINT before our handler was installed
        return EXIT_INTERRUPTED
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return EXIT_OK if stop.requested is None else EXIT_CODES[stop.requested]


def _start_up_error(err: Exception) -> str:
    """The one line of a start-up error (after `predictor: error: `)."""
    if isinstance(err, RCLInvalidROSArgsError):  # a broken --params-file, a malformed -p or -r
        return f"invalid ROS arguments: {_first_line(err)}"
    if isinstance(err, ParameterException):  # a ROS parameter of the wrong type (-p use_sim_time:=maybe)
        return f"invalid parameter: {_first_line(err)}"
    if isinstance(err, RCLError):  # an endpoint DDS refuses at start-up (a spin ends on its own RCLError: spin())
        return f"ROS refused the node: {_first_line(err)}"
    return one_line(err)


if __name__ == "__main__":
    sys.exit(main())
