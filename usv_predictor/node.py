"""The `predictor` rclpy node: parameters, subscriptions via msg_adapters, a timer, /diagnostics.

The only module of the package that imports rclpy. Inputs arrive as ROS messages (REP-103/105:
ENU, FLU, yaw counter-clockwise from east) and are turned into plain numbers in SI units and
marine frames (NED, FRD, heading clockwise from north) by msg_adapters; the node keeps the latest
sample of each input. No model is loaded yet (issue 6): every rate_hz the node publishes
/diagnostics with the freshness of each input and a "no model loaded" status.

Parameters are declared from config/predictor.yaml (or `--config FILE`) with descriptors that
carry the loader's ranges, so rclpy rejects out-of-range overrides; usv_predictor.config then
validates the effective set once more.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, Sequence

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rclpy.utilities import remove_ros_args

import msg_adapters
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
from usv_predictor.errors import AdapterError, ConfigError, UsvPredictorError

DIAGNOSTICS_TOPIC = "/diagnostics"
NO_MODEL_MESSAGE = "no model loaded (prediction not implemented yet)"
ERROR_LOG_PERIOD_S = 5.0  # throttle of repeated decode warnings (s)

# DiagnosticStatus levels are `byte` fields (bytes of length 1 in rclpy); compare them as ints.
OK, WARN, ERROR = (level[0] for level in (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR))

_DESCRIPTIONS = {
    "model_path": "TorchScript model file; empty = the package's shipped default model",
    "vessel": "vessel preset name (config/vessels/<vessel>.yaml)",
    "rate_hz": "prediction and diagnostics rate (Hz)",
    "horizon_s": "prediction horizon (s); a whole number of dt steps",
    "dt": "prediction time step (s)",
    "ensemble_size": "number of ensemble members of the prediction",
    "frame_id": "earth-fixed ENU frame of predicted_path",
    "base_frame_id": "body FLU frame of the vessel",
}


def _is_float_parameter(name: str) -> bool:
    return name in FLOAT_RANGES or name.endswith(".max_age_s")


def _declared_value(name: str, value: Any) -> Any:
    """`rate_hz: 10` in a YAML file is an int; declare it as the double it stands for."""
    if _is_float_parameter(name) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def _descriptor(name: str, value: Any) -> ParameterDescriptor:
    """Descriptor of one declared parameter: ranges from usv_predictor.config, all but staleness read-only."""
    leaf = name.rsplit(".", 1)[-1]
    descriptor = ParameterDescriptor(
        name=name,
        description=_DESCRIPTIONS.get(name, f"{name.replace('.', ' ')} (see config/predictor.yaml)"),
        read_only=leaf != "max_age_s",  # topics, types and the model are fixed once subscribed
    )
    float_range: Range | None = FLOAT_RANGES.get(name) or (MAX_AGE_RANGE if _is_float_parameter(name) else None)
    if float_range is not None and isinstance(value, float):
        descriptor.floating_point_range = [
            FloatingPointRange(from_value=float(float_range.low), to_value=float(float_range.high), step=0.0)
        ]
        descriptor.additional_constraints = float_range.describe(leaf)
    elif name == "ensemble_size" and isinstance(value, int):
        descriptor.integer_range = [IntegerRange(from_value=int(ENSEMBLE_RANGE.low),
                                                 to_value=int(ENSEMBLE_RANGE.high), step=1)]
        descriptor.additional_constraints = ENSEMBLE_RANGE.describe(leaf)
    return descriptor


@dataclass
class InputState:
    """What the node knows of one input: the latest decoded sample and its bookkeeping."""

    config: InputConfig
    adapter: msg_adapters.Adapter
    values: tuple[float, ...] = ()
    received_ns: int | None = None  # node clock when the latest good sample arrived
    stamp_ns: int | None = None  # header stamp of that sample (None for header-less types)
    messages: int = 0
    decode_errors: int = 0
    last_error: str = ""
    error_ns: int | None = None  # node clock of the latest decode failure


def input_level(state: InputState, now_ns: int, max_age_s: float) -> tuple[int, str]:
    """Diagnostic level and message of one input: ERROR never/undecodable, WARN stale, else OK."""
    if state.error_ns is not None and (state.received_ns is None or state.error_ns > state.received_ns):
        return ERROR, f"cannot decode messages: {state.last_error}"
    if state.received_ns is None:
        return ERROR, "no message received"
    age_s = max(0.0, (now_ns - state.received_ns) * 1e-9)
    if age_s > max_age_s:
        return WARN, f"stale: last message {age_s:.2f} s ago (limit {max_age_s:g} s)"
    return OK, "fresh"


def _key_values(pairs: dict[str, Any]) -> list[KeyValue]:
    return [KeyValue(key=key, value=str(value)) for key, value in pairs.items()]


class PredictorNode(Node):
    """Subscribes to the configured inputs and reports their freshness on /diagnostics."""

    def __init__(self, config_path: str | Path | None = None, **node_options: Any) -> None:
        super().__init__(NODE_NAME, **node_options)
        defaults_path = Path(config_path) if config_path is not None else default_config_path()
        self.config = self._declare_parameters(defaults_path)
        make = msg_adapters.rclpy_factory()
        self._inputs: dict[str, InputState] = {}
        for entry in self.config.inputs:
            adapter = msg_adapters.get_adapter(entry.role, entry.ros_type, **entry.options)
            self._inputs[entry.role] = InputState(entry, adapter)
            self.create_subscription(
                make(entry.ros_type), entry.topic, partial(self._on_message, entry.role), qos_profile_sensor_data
            )
        self._diagnostics = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, 10)
        self.create_timer(1.0 / self.config.rate_hz, self._on_timer)
        self.get_logger().info(
            f"usv_predictor {__version__}: {len(self._inputs)} inputs ({', '.join(self._inputs)}), "
            f"{self.config.rate_hz:g} Hz, parameters from {defaults_path}; {NO_MODEL_MESSAGE}"
        )

    def _declare_parameters(self, defaults_path: Path) -> PredictorConfig:
        """Declare every parameter of the defaults file; validate the effective values (with overrides)."""
        defaults = flatten_ros_parameters(read_ros_parameters(defaults_path))
        try:
            for name, raw in defaults.items():
                value = _declared_value(name, raw)
                self.declare_parameter(name, value, _descriptor(name, value))
        except ParameterException as err:
            raise ConfigError(
                f"node {self.get_name()}: parameter rejected ({err}); defaults from {defaults_path}"
            ) from err
        effective = {name: self.get_parameter(name).value for name in defaults}
        source = f"{defaults_path} (with the node's parameter overrides)"
        return parse_predictor_config(unflatten_ros_parameters(effective), source=source)

    def _on_message(self, role: str, msg: Any) -> None:
        state = self._inputs[role]
        now_ns = self.get_clock().now().nanoseconds
        try:
            stamp_ns, values = state.adapter.decode(msg)
            state.values = tuple(float(v) for v in values)
        except (AdapterError, ValueError, ArithmeticError) as err:
            state.decode_errors += 1
            state.last_error, state.error_ns = str(err), now_ns
            self.get_logger().warning(
                f"input {role} on {state.config.topic}: {err}", throttle_duration_sec=ERROR_LOG_PERIOD_S
            )
            return
        state.stamp_ns = None if stamp_ns is None else int(stamp_ns)
        state.received_ns = now_ns
        state.messages += 1

    def _on_timer(self) -> None:
        now = self.get_clock().now()
        report = DiagnosticArray()
        report.header.stamp = now.to_msg()
        report.status = [self._input_status(state, now.nanoseconds) for state in self._inputs.values()]
        report.status.append(self._model_status())
        self._diagnostics.publish(report)

    def _input_status(self, state: InputState, now_ns: int) -> DiagnosticStatus:
        role = state.config.role
        max_age_s = float(self.get_parameter(f"inputs.{role}.max_age_s").value)
        level, message = input_level(state, now_ns, max_age_s)
        values: dict[str, Any] = {
            "topic": self.resolve_topic_name(state.config.topic),
            "type": state.config.ros_type,
            "messages": state.messages,
            "decode_errors": state.decode_errors,
            "max_age_s": f"{max_age_s:g}",
        }
        if state.received_ns is not None:
            values["age_s"] = f"{max(0.0, (now_ns - state.received_ns) * 1e-9):.3f}"
            if state.stamp_ns is not None:
                values["latency_s"] = f"{(state.received_ns - state.stamp_ns) * 1e-9:.3f}"
            values.update({name: f"{v:.6g}" for name, v in zip(state.adapter.fields, state.values, strict=True)})
        if state.last_error:
            values["last_error"] = state.last_error
        return DiagnosticStatus(
            level=bytes([level]),
            name=f"{self.get_name()}: input {role}",
            message=message,
            hardware_id=self.config.base_frame_id,
            values=_key_values(values),
        )

    def _model_status(self) -> DiagnosticStatus:
        cfg = self.config
        return DiagnosticStatus(
            level=DiagnosticStatus.WARN,
            name=f"{self.get_name()}: model",
            message=NO_MODEL_MESSAGE,
            hardware_id=cfg.base_frame_id,
            values=_key_values(
                {
                    "model_path": cfg.model_path or "(shipped default)",
                    "vessel": cfg.vessel,
                    "horizon_s": f"{cfg.horizon_s:g}",
                    "dt": f"{cfg.dt:g}",
                    "ensemble_size": cfg.ensemble_size,
                    "version": __version__,
                }
            ),
        )


def parse_arguments(argv: Sequence[str]) -> argparse.Namespace:
    """Command-line options of `predictor` (ROS arguments after --ros-args are left to rclpy)."""
    parser = argparse.ArgumentParser(
        prog="predictor",
        description="Online 3-DOF motion prediction node for unmanned surface vehicles (usv_predictor). "
        "Subscribes to the inputs of config/predictor.yaml and publishes /diagnostics; "
        "prediction outputs come with the model (not loaded yet).",
        epilog="ROS arguments follow --ros-args, e.g.: predictor --ros-args --params-file my.yaml -r imu/data:=/imu",
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


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of `ros2 run usv_predictor predictor`; args is a full argv (program name first)."""
    argv = list(sys.argv if args is None else args)
    options = parse_arguments(argv)  # --help exits here, before ROS starts
    rclpy.init(args=argv)
    node: PredictorNode | None = None
    try:
        node = PredictorNode(config_path=options.config)
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except UsvPredictorError as err:
        print(f"predictor: error: {err}", file=sys.stderr)
        return 1
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
