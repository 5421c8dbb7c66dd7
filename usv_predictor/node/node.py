"""The `predictor` rclpy node: live 3-DOF motion prediction from a TorchScript model artifact.

The only module of the package that imports rclpy; the work is done by usv_predictor.node.live (pure).
Inputs arrive as ROS messages (REP-103/105: ENU, FLU, yaw counter-clockwise from east) and are turned
into plain numbers in SI units and marine frames (NED, FRD, heading clockwise from north) by
msg_adapters, checked and buffered (live.InputSet). Every 1 / rate_hz a timer builds the state the way
the replay tool builds a Recording, rolls the model out over horizon_s with the current actuator
commands held, and publishes (docs/node.md has the details):

    predicted_path               nav_msgs/Path, ENU, frame_id (default odom), pose k stamped t_c + k dt
    predicted_velocities         trajectory_msgs/MultiDOFJointTrajectory (msg_adapters.outputs)
    predicted_path_covariance    std_msgs/Float64MultiArray, ensemble covariance of (x, y, yaw) ENU per step
    /diagnostics                 inputs (age, rate, rejections), model (id, metadata), prediction (latency)

A cycle that cannot be trusted (no input yet, stale input, non-finite model output) publishes nothing
but /diagnostics, with the reason, and a throttled warning. Parameters are declared from
config/predictor.yaml (or `--config FILE`) with descriptors carrying the loader's ranges, so rclpy
rejects out-of-range overrides; the node-only parameters (NODE_PARAMETERS) are declared here.
model_path may change at run time: the new model is validated first, the old one kept on failure.
"""
from __future__ import annotations

import argparse
import math
import signal
import sys
from collections import deque
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

import msg_adapters
from msg_adapters.outputs import encode_path, encode_predicted_velocities
from usv_predictor import __version__
from usv_predictor.config import (
    ENSEMBLE_RANGE,
    FLOAT_RANGES,
    MAX_AGE_RANGE,
    NODE_NAME,
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
from usv_predictor.errors import AdapterError, ConfigError, ModelError, UsvPredictorError
from usv_predictor.models import loading
from usv_predictor.models.families import MODEL_FAMILIES, family_name
from usv_predictor.node import live
from usv_predictor.physics.actuators import DEFAULT_LAYOUT, ActuatorLayout, unused_roles
from usv_predictor.physics.vessel import load_vessel
from usv_predictor.records import NS_PER_S

DIAGNOSTICS_TOPIC = "/diagnostics"
COVARIANCE_TOPIC = "predicted_path_covariance"
ERROR_LOG_PERIOD_S = 5.0  # throttle of repeated warnings (s)
RECENT_REJECT_S = 5.0  # an input with a rejected sample this recently is WARN (s)
LATENCY_WINDOW = 200  # cycles kept for the latency percentiles

# DiagnosticStatus levels are `byte` fields (bytes of length 1 in rclpy); compare them as ints.
OK, WARN, ERROR = (level[0] for level in (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR))
RCLError = _rclpy.RCLError  # what rcl raises (e.g. a publish on a context that is shut down)
RCLInvalidROSArgsError = _rclpy.RCLInvalidROSArgsError  # unparsable --ros-args (a broken --params-file)

_DESCRIPTIONS = {
    "model_path": "TorchScript model file; empty = the package's shipped default model (may change at run time)",
    "vessel": "vessel preset name (config/vessels/<vessel>.yaml); the model must be made for it",
    "rate_hz": "prediction and diagnostics rate (Hz)",
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


NODE_PARAMETERS: dict[str, NodeParameter] = {
    "state_delay_s": NodeParameter(0.0, "the state averages [now - delay - dt, now - delay] (s): room for late "
                                        "messages; predictions start at now - delay - dt/2", 0.0, 5.0),
    "max_future_s": NodeParameter(0.5, "input stamps further than this ahead of the clock are refused (s)", 0.0, 60.0),
    "buffer_capacity": NodeParameter(2048, "samples kept per input (ring buffer: bounded memory)", 16, 100000),
    "datum_lat_deg": NodeParameter(math.nan, "latitude of the local tangent plane of predicted_path (deg); "
                                             "NaN = the first GNSS fix"),
    "datum_lon_deg": NodeParameter(math.nan, "longitude of that plane (deg); NaN = the first GNSS fix"),
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


def _is_float_parameter(name: str) -> bool:
    return name in FLOAT_RANGES or name.endswith(".max_age_s")


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
        read_only=leaf != "max_age_s" and name != "model_path",  # topics and types are fixed once subscribed
    )
    allowed: Range | None = FLOAT_RANGES.get(name) or (MAX_AGE_RANGE if _is_float_parameter(name) else None)
    if name == "ensemble_size":
        allowed = ENSEMBLE_RANGE
    return _ranged(descriptor, leaf, value, allowed)


def _node_descriptor(name: str, spec: NodeParameter) -> ParameterDescriptor:
    descriptor = ParameterDescriptor(name=name, description=spec.description, read_only=True)
    unit = "s" if name.endswith("_s") else "samples"
    allowed = None if spec.low is None else Range(spec.low, spec.high, unit)
    return _ranged(descriptor, name, spec.default, allowed)


def _family_description(metadata: dict[str, Any]) -> str:
    """What kind of model it is (models/families.py), for /diagnostics."""
    family = MODEL_FAMILIES.get(family_name(str(metadata.get("model_type", ""))))
    return family.description if family is not None else "not a model family of usv_predictor"


def _key_values(pairs: dict[str, Any]) -> list[KeyValue]:
    return [KeyValue(key=key, value=str(value)) for key, value in pairs.items()]


def load_model(model_path: str, config: PredictorConfig, layout: ActuatorLayout = DEFAULT_LAYOUT) -> live.Rollout:
    """The model of `model_path` ("" = the shipped one), checked against the configuration: its step, vessel and
    control columns (the vessel's actuator layout); ModelError naming the file and the mismatch."""
    expect = {"dt": config.dt, "vessel": config.vessel, "control_layout": list(layout.control_names)}
    artifact = loading.load_model(model_path, expect=expect, option="model_path", physics=False)
    return live.Rollout(artifact, config.horizon_steps, config.ensemble_size)


@dataclass
class DecodeFailures:
    count: int = 0
    last: str = ""
    at_ns: int | None = None


class PredictorNode(Node):
    """Subscribes to the configured inputs, predicts at rate_hz, reports on /diagnostics."""

    def __init__(self, config_path: str | Path | None = None, **node_options: Any) -> None:
        super().__init__(NODE_NAME, **node_options)
        defaults_path = Path(config_path) if config_path is not None else default_config_path()
        self.config = self._declare_parameters(defaults_path)
        self.layout = load_vessel(self.config.vessel).actuator_layout  # ConfigError: fatal at start-up
        self.rollout = load_model(self.config.model_path, self.config, self.layout)  # ModelError: fatal at start-up
        # the inputs this vessel uses: the config may list control roles of other actuator layouts (it does)
        used = [entry for entry in self.config.inputs if entry.role not in unused_roles(self.layout)]
        self.inputs = live.InputSet(
            {entry.role: msg_adapters.ROLE_FIELDS[entry.role] for entry in used},
            {entry.role: float(self.get_parameter(f"inputs.{entry.role}.max_age_s").value) for entry in used},
            self._live_settings(), self.layout,
        )
        make = msg_adapters.rclpy_factory()
        self._entries: dict[str, InputConfig] = {entry.role: entry for entry in used}
        self._adapters = {
            entry.role: msg_adapters.get_adapter(entry.role, entry.ros_type, **entry.options)
            for entry in used
        }
        self._failures = {role: DecodeFailures() for role in self._entries}
        for entry in used:
            self.create_subscription(
                make(entry.ros_type), entry.topic, partial(self._on_message, entry.role), qos_profile_sensor_data
            )
        outputs = self.config.outputs
        self._path_pub = self.create_publisher(make(outputs["predicted_path"].ros_type), outputs["predicted_path"].topic, 10)
        self._velocities_pub = self.create_publisher(
            make(outputs["predicted_velocities"].ros_type), outputs["predicted_velocities"].topic, 10
        )
        self._covariance_pub = self.create_publisher(Float64MultiArray, COVARIANCE_TOPIC, 10)
        self._diagnostics = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, 10)
        self._make = make
        self._latencies: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self.published = 0
        self.skipped = 0
        self.last_skip = ""
        self.last_prediction: live.Prediction | None = None
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.create_timer(1.0 / self.config.rate_hz, self._on_timer)
        self.get_logger().info(
            f"usv_predictor {__version__}: model {self.rollout.artifact.path} ({self.rollout.artifact.model_id}, "
            f"{self.rollout.members} member(s)), {len(self._entries)} inputs ({', '.join(self._entries)}), "
            f"{self.config.rate_hz:g} Hz, horizon {self.config.horizon_s:g} s, parameters from {defaults_path}"
        )

    # --------------------------------------------------------------- parameters
    def _declare_parameters(self, defaults_path: Path) -> PredictorConfig:
        """Declare every parameter of the defaults file and the node's own; validate the effective values."""
        defaults = flatten_ros_parameters(read_ros_parameters(defaults_path))
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

    def _on_set_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        """Swap the model (validated first; the old one stays on failure) and apply new staleness limits."""
        swap: live.Rollout | None = None
        for parameter in parameters:
            if parameter.name == "model_path":
                try:
                    swap = load_model(str(parameter.value), self.config, self.layout)
                except (ModelError, ConfigError) as err:
                    self.get_logger().error(f"model_path not changed, keeping {self.rollout.artifact.path}: {err}")
                    return SetParametersResult(successful=False, reason=str(err))
        if swap is not None:
            self.rollout = swap
            self.get_logger().info(f"model swapped to {swap.artifact.path} ({swap.artifact.model_id})")
        for parameter in parameters:
            role = parameter.name.removeprefix("inputs.").removesuffix(".max_age_s")
            if parameter.name.endswith(".max_age_s") and role in self.inputs.tracks:
                self.inputs.tracks[role].max_age_s = float(parameter.value)
        return SetParametersResult(successful=True)

    # --------------------------------------------------------------- callbacks
    def _on_message(self, role: str, msg: Any) -> None:
        now_ns = self.get_clock().now().nanoseconds
        try:
            if role == "heading" and hasattr(msg, "data"):
                live.check_raw_heading(float(msg.data), str(self._entries[role].options.get("units", "deg")))
            stamp_ns, values = self._adapters[role].decode(msg)
            values = tuple(float(v) for v in values)
        except live.InputRejected as err:
            self.inputs.tracks[role].reject(err.kind, str(err), now_ns)
            self._warn_input(role, str(err))
            return
        except (AdapterError, ValueError, ArithmeticError) as err:
            failures = self._failures[role]
            failures.count, failures.last, failures.at_ns = failures.count + 1, str(err), now_ns
            self._warn_input(role, str(err))
            return
        try:
            self.inputs.add(role, now_ns if stamp_ns is None else int(stamp_ns), values, now_ns)
        except live.InputRejected as err:
            self._warn_input(role, str(err))

    def _warn_input(self, role: str, message: str) -> None:
        self.get_logger().warning(f"input {role} on {self._entries[role].topic}: {message}",
                                  throttle_duration_sec=ERROR_LOG_PERIOD_S)

    def _on_timer(self) -> None:
        if not self.context.ok():  # shutting down (SIGINT/SIGTERM): publishing would fail
            return
        now = self.get_clock().now()
        if self.inputs.observe_clock(now.nanoseconds):
            self.get_logger().warning("the clock jumped back: input buffers cleared")
        try:
            prediction = live.predict(self.inputs, self.rollout, now.nanoseconds)
            self._publish(prediction)
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
        self._publish_diagnostics(now.nanoseconds)

    # --------------------------------------------------------------- outputs
    def _publish(self, prediction: live.Prediction) -> None:
        frame = self.config.frame_id
        self._path_pub.publish(encode_path(prediction.stamp_ns, prediction.t_ns, prediction.eta, frame, self._make))
        self._velocities_pub.publish(encode_predicted_velocities(
            prediction.stamp_ns, prediction.t_ns, prediction.eta, prediction.nu, frame, self.config.base_frame_id,
            self._make))
        if len(prediction.eta_members) > 1:
            self._covariance_pub.publish(covariance_message(live.enu_covariance(prediction.eta_members)))

    def _publish_diagnostics(self, now_ns: int) -> None:
        report = DiagnosticArray()
        report.header.stamp = self.get_clock().now().to_msg()
        report.status = [self._input_status(role, now_ns) for role in self._entries]
        report.status += [self._model_status(), self._prediction_status()]
        self._diagnostics.publish(report)

    def _status(self, level: int, what: str, message: str, values: dict[str, Any]) -> DiagnosticStatus:
        return DiagnosticStatus(level=bytes([level]), name=f"{self.get_name()}: {what}", message=message,
                                hardware_id=self.config.base_frame_id, values=_key_values(values))

    def _input_status(self, role: str, now_ns: int) -> DiagnosticStatus:
        track, entry, failures = self.inputs.tracks[role], self._entries[role], self._failures[role]
        age = track.age_s(now_ns)
        values: dict[str, Any] = {
            "topic": self.resolve_topic_name(entry.topic),
            "type": entry.ros_type,
            "messages": track.received + failures.count,
            "decode_errors": failures.count,
            "rejected": sum(track.rejected.values()),
            **{f"rejected_{kind}": count for kind, count in sorted(track.rejected.items())},
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
            return self._status(WARN, f"input {role}", f"stale: last message {age:.2f} s ago "
                                                       f"(limit {track.max_age_s:g} s)", values)
        if recent_reject:
            return self._status(WARN, f"input {role}", f"messages refused: {track.last_reject}", values)
        return self._status(OK, f"input {role}", "fresh", values)

    def _model_status(self) -> DiagnosticStatus:
        artifact = self.rollout.artifact
        meta = artifact.metadata
        values = {
            "model_path": str(artifact.path), "model_id": artifact.model_id, "model_type": meta.get("model_type"),
            "family": _family_description(meta),
            "feature_set": meta.get("feature_set"), "vessel": meta.get("vessel"), "dt": f"{artifact.dt:g}",
            "ensemble_size": f"{self.rollout.members}/{artifact.ensemble_size}",
            "training_data_sha256": meta.get("training_data_sha256"), "created_utc": meta.get("created_utc"),
            "horizon_s": f"{self.config.horizon_s:g}", "version": __version__,
        }
        return self._status(OK, "model", f"loaded {artifact.model_id}", values)

    def _prediction_status(self) -> DiagnosticStatus:
        latencies = np.array(self._latencies) * 1e3
        values: dict[str, Any] = {"published": self.published, "skipped": self.skipped,
                                  "rate_hz": f"{self.config.rate_hz:g}"}
        if len(latencies):
            values.update(compute_ms_p50=f"{np.percentile(latencies, 50):.3f}",
                          compute_ms_p99=f"{np.percentile(latencies, 99):.3f}",
                          compute_ms_max=f"{latencies.max():.3f}")
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


def covariance_message(covariance: np.ndarray) -> Float64MultiArray:
    """(H, 3, 3) covariances of [x east, y north, yaw] -> Float64MultiArray (steps x 9, row-major)."""
    steps = covariance.shape[0]
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label="step", size=steps, stride=steps * 9),
                      MultiArrayDimension(label="cov_x_y_yaw_enu", size=9, stride=9)]
    msg.layout.data_offset = 0
    msg.data = covariance.reshape(-1).astype(float).tolist()
    return msg


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


EXIT_OK = 0  # stopped by SIGINT or SIGTERM (Ctrl-C, systemd, docker stop, launch): a normal end
EXIT_ERROR = 2  # a start-up error (parameter, parameter file, ROS arguments, model, vessel): one line on stderr,
                # the same code as the replay tool's bad input
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
SPIN_PERIOD_S = 0.1  # longest wait between two looks at the stop flag (s)


class _StopRequest:
    """SIGINT / SIGTERM set a flag the spin loop reads between callbacks: a callback is never interrupted half-way
    (no publish on a context that is shutting down), and the context is shut down only after the loop ends."""

    def __init__(self) -> None:
        self.requested: int | None = None

    def __call__(self, signum: int, frame: Any) -> None:
        self.requested = signum

    def install(self) -> dict[int, Any]:
        return {sig: signal.signal(sig, self) for sig in STOP_SIGNALS}


def _spin(node: PredictorNode, stop: _StopRequest) -> None:
    """Run the node's callbacks until a stop signal (or an external shutdown of its context)."""
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    try:
        while stop.requested is None and node.context.ok():
            executor.spin_once(timeout_sec=SPIN_PERIOD_S)
    except ExternalShutdownException:
        pass
    except RCLError:  # a publish that raced a shutdown made elsewhere (the context is gone): a normal end
        if node.context.ok():
            raise
    finally:
        executor.shutdown(timeout_sec=SPIN_PERIOD_S)


def _first_line(err: BaseException) -> str:
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of `ros2 run usv_predictor predictor`; args is a full argv (program name first).

    Exit codes: 0 after SIGINT or SIGTERM (also while publishing: the signal only sets a flag the spin loop reads
    between callbacks), 2 for a start-up error (one line `predictor: error: ...` on stderr: a parameter, the
    parameter file, the ROS arguments, the model, the vessel or an input adapter).
    """
    argv = list(sys.argv if args is None else args)
    stop = _StopRequest()
    previous = stop.install()  # before the slow start-up (torch, the model): an early stop is clean too
    node: PredictorNode | None = None
    try:
        options = parse_arguments(argv)  # --help exits here, before ROS starts
        import torch

        torch.set_num_threads(1)  # one rollout of a tiny network: threads cost more than they give
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)  # our handlers stop the loop
        if stop.requested is None:
            node = PredictorNode(config_path=options.config)
        if stop.requested is None:
            _spin(node, stop)
    except RCLInvalidROSArgsError as err:  # a broken --params-file, a malformed -p or -r
        print(f"predictor: error: invalid ROS arguments: {_first_line(err)}", file=sys.stderr)
        return EXIT_ERROR
    except UsvPredictorError as err:
        print(f"predictor: error: {err}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:  # a SIGINT before our handler was installed
        pass
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
