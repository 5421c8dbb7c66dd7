"""Typed loader of config/predictor.yaml, shared by the `predictor` node and the `replay` tool.

The file is a ROS 2 parameter file (`predictor: ros__parameters: {...}`), so the node can be given
the same file with `--ros-args --params-file`. Units are SI (s, Hz); topics are relative names;
types are ROS interface names such as `sensor_msgs/msg/Imu`. Every key of an input entry other
than topic, type, frame_id and max_age_s is an option of its msg_adapters adapter (e.g. heading
`units: deg`, `convention: compass`; rudder `sign: 1`, positive = turn to starboard).

Package data (this file, config/vessels/<name>.yaml, bags/, models/) is searched, file by file, in:
1. the source tree this module sits in, when it is one (package.xml beside it: editable install,
   tests), so code and data always come from the same checkout even in a sourced workspace;
2. the ament index, when AMENT_PREFIX_PATH knows usv_predictor (a sourced colcon install; this
   is what `ros2 run` uses, and the source tree is never beside installed code);
3. <sys.prefix>/share/usv_predictor (a plain pip install of the package into a virtualenv).
"""
from __future__ import annotations

import math
import os
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Iterator, Mapping, NamedTuple

from usv_predictor.bounded import load_yaml
from usv_predictor.errors import ConfigError

PACKAGE_NAME = "usv_predictor"
NODE_NAME = "predictor"
PARAMS_KEY = "ros__parameters"


class Range(NamedTuple):
    """Closed interval of an allowed numeric parameter value, with its unit for messages."""

    low: float
    high: float
    unit: str

    def describe(self, name: str) -> str:
        return f"{self.low:g} <= {name} <= {self.high:g} ({self.unit})"

    def check(self, name: str, value: float, source: str) -> float:
        """`value` if finite and within [low, high], else ConfigError naming source, name, value (and unit)."""
        if not (self.low <= value <= self.high) or not math.isfinite(value):
            unit = f" {self.unit}" if self.unit else ""
            raise ConfigError(f"{source}: {name}={value}{unit} is outside the allowed range [{self.low}, {self.high}]")
        return value


# The node declares its ROS parameters with these same ranges, so rclpy and the loader agree.
FLOAT_RANGES: Mapping[str, Range] = MappingProxyType(
    {
        "rate_hz": Range(0.1, 100.0, "Hz"),
        "horizon_s": Range(1.0, 600.0, "s"),
        "dt": Range(0.01, 10.0, "s"),
    }
)
MAX_AGE_RANGE = Range(0.01, 60.0, "s")
ENSEMBLE_RANGE = Range(1, 64, "members")

# Keys of an input entry that belong to the predictor, not to the adapter.
INPUT_KEYS = frozenset({"topic", "type", "frame_id", "max_age_s"})
GROUND_TRUTH_KEYS = frozenset({"topic", "type", "frame_id", "role"})
OUTPUT_ROLES = ("predicted_path", "predicted_velocities")
# Outputs a parameter file may leave out (older files): role -> (default topic, type)
OPTIONAL_OUTPUTS: Mapping[str, tuple[str, str]] = MappingProxyType(
    {"estimated_current": ("estimated_current", "geometry_msgs/msg/TwistWithCovarianceStamped")}
)
# The online estimator of the sea (fitting/online.py OnlineConfig: the fields a parameter file may set, with the
# node's parameter ranges). `online.enabled` switches it off; the node and `replay evaluate --adaptive` read the
# same values. A file without an `online` section gets OnlineConfig's defaults, enabled.
ONLINE_RANGES: Mapping[str, Range] = MappingProxyType(
    {
        "prior_current_std_m_s": Range(0.001, 5.0, "m/s"),
        "prior_yaw_rate_bias_std_rad_s": Range(1e-5, 0.2, "rad/s"),
        "prior_resistance_std": Range(0.001, 2.0, "-"),
        "current_noise": Range(1e-6, 1.0, "(m/s)/sqrt(s)"),
        "bias_noise": Range(0.0, 0.01, "(rad/s)/sqrt(s)"),
        "resistance_noise": Range(0.0, 0.1, "1/sqrt(s)"),
        "velocity_std_m_s": Range(1e-4, 2.0, "m/s"),
        "yaw_rate_std_rad_s": Range(1e-5, 0.5, "rad/s"),
    }
)
ONLINE_KEYS = frozenset({"enabled"} | set(ONLINE_RANGES))
TOP_LEVEL_KEYS = frozenset(
    {"model_path", "vessel", "ensemble_size", "frame_id", "base_frame_id", "inputs", "outputs", "ground_truth",
     "online"}
    | set(FLOAT_RANGES)
)
# Standard parameters every rclpy node has; a parameter file may set them.
ROS_STANDARD_KEYS = frozenset({"use_sim_time", "qos_overrides", "start_type_description_service"})

_ROS_TYPE = re.compile(r"^[A-Za-z][A-Za-z0-9_]*/msg/[A-Z][A-Za-z0-9]*$")
_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
_TOPIC = re.compile(r"^[~/]?[A-Za-z_{][A-Za-z0-9_/{}~]*$")
_FRAME = re.compile(r"^[A-Za-z0-9_/.\-]+$")


@dataclass(frozen=True)
class InputConfig:
    """One subscribed (or recorded) quantity: its role decides the adapter and the plain numbers."""

    role: str
    topic: str
    ros_type: str
    frame_id: str
    max_age_s: float  # older than this the input is stale (s)
    options: Mapping[str, Any]  # keyword options of msg_adapters.get_adapter (read-only)


class OutputConfig(NamedTuple):
    topic: str
    ros_type: str


class InputTopic(NamedTuple):
    """Same fields, same order as usv_predictor.replay.bagio.TopicSpec, so either can feed the other."""

    topic: str
    role: str
    ros_type: str
    options: Mapping[str, Any]
    frame_id: str


@dataclass(frozen=True)
class PredictorConfig:
    """The validated contents of a predictor parameter file (or of the node's parameters)."""

    source: str  # file (or parameter set) it came from, for messages
    model_path: str  # "" = the shipped default model
    vessel: str  # preset name in config/vessels/
    rate_hz: float  # prediction rate (Hz); the node publishes /diagnostics at its diagnostics_rate_hz
    horizon_s: float  # prediction horizon (s)
    dt: float  # prediction step (s)
    ensemble_size: int
    frame_id: str  # earth-fixed ENU frame of the predicted path
    base_frame_id: str  # body FLU frame
    inputs: tuple[InputConfig, ...]
    outputs: Mapping[str, OutputConfig]
    ground_truth: InputConfig  # reference only, never an input for fitting
    online_enabled: bool = True  # run the online estimator of the sea (docs/online.md)
    # OnlineConfig fields the file sets (ONLINE_RANGES); the others keep OnlineConfig's defaults
    online: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))

    @property
    def horizon_steps(self) -> int:
        return round(self.horizon_s / self.dt)

    def input(self, role: str) -> InputConfig:
        for entry in self.inputs:
            if entry.role == role:
                return entry
        raise ConfigError(f"{self.source}: no input with role {role!r}; configured: {[i.role for i in self.inputs]}")


# --------------------------------------------------------------------------- locating package data


def _ament_share_dir() -> Path | None:
    """share/usv_predictor of the ament index, only when AMENT_PREFIX_PATH is set and knows us."""
    if not os.environ.get("AMENT_PREFIX_PATH"):
        return None
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    except ImportError:
        return None
    try:
        return Path(get_package_share_directory(PACKAGE_NAME))
    except PackageNotFoundError:
        return None


def share_roots() -> tuple[Path, ...]:
    """Candidate share directories of the package, in the order they are searched."""
    roots: list[Path] = []
    source_tree = Path(__file__).resolve().parents[1]
    if (source_tree / "package.xml").is_file():
        roots.append(source_tree)
    ament = _ament_share_dir()
    if ament is not None:
        roots.append(ament)
    roots.append(Path(sys.prefix) / "share" / PACKAGE_NAME)
    return tuple(roots)


def package_share_path(*parts: str) -> Path:
    """The first existing share/usv_predictor/<parts> (e.g. 'config', 'vessels', 'jari_usv.yaml')."""
    roots = share_roots()
    for root in roots:
        candidate = root.joinpath(*parts)
        if candidate.exists():
            return candidate
    wanted = "/".join(parts) or "."
    raise ConfigError(
        f"cannot find {wanted!r} of package {PACKAGE_NAME}; looked in: {', '.join(str(r) for r in roots)}"
    )


def default_config_path() -> Path:
    return package_share_path("config", "predictor.yaml")


def vessel_preset_path(name: str) -> Path:
    """config/vessels/<name>.yaml, found like the other package data."""
    if not _NAME.match(name):
        raise ConfigError(f"vessel name {name!r} is not a preset name (letters, digits, underscores)")
    return package_share_path("config", "vessels", f"{name}.yaml")


# --------------------------------------------------------------------------- reading and flattening


def read_ros_parameters(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The nested `predictor: ros__parameters:` mapping of a parameter file."""
    path = Path(path)
    document = load_yaml(path, "predictor config", ConfigError)
    if not isinstance(document, dict) or not isinstance(document.get(NODE_NAME), dict):
        raise ConfigError(f"{path}: expected a top-level '{NODE_NAME}:' mapping (ROS 2 parameter file)")
    params = document[NODE_NAME].get(PARAMS_KEY)
    if not isinstance(params, dict):
        raise ConfigError(f"{path}: expected '{NODE_NAME}: {PARAMS_KEY}:' to be a mapping")
    return params


def flatten_ros_parameters(params: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested parameters -> {dotted.name: value}, the names rclpy declares (lists stay values)."""
    flat: dict[str, Any] = {}
    for key, value in params.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flatten_ros_parameters(value, prefix=f"{name}."))
        else:
            flat[name] = value
    return flat


def unflatten_ros_parameters(flat: Mapping[str, Any]) -> dict[str, Any]:
    """{dotted.name: value} -> nested mapping; inverse of flatten_ros_parameters."""
    nested: dict[str, Any] = {}
    for name, value in flat.items():
        *parents, leaf = name.split(".")
        node = nested
        for part in parents:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ConfigError(f"parameter {name!r} nests under {part!r}, which is already a value")
        node[leaf] = value
    return nested


# --------------------------------------------------------------------------- validation


class _Section:
    """A mapping being validated, with the dotted key path used in error messages."""

    def __init__(self, source: str, data: Any, path: str) -> None:
        if not isinstance(data, Mapping):
            raise ConfigError(f"{source}: {path} must be a mapping, got {type(data).__name__}")
        self.source, self.data, self.path = source, data, path

    def where(self, key: str) -> str:
        return f"{self.source}: {self.path}.{key}"

    def raw(self, key: str) -> Any:
        if key not in self.data:
            raise ConfigError(f"{self.where(key)} is missing")
        return self.data[key]

    def section(self, key: str) -> _Section:
        return _Section(self.source, self.raw(key), f"{self.path}.{key}")

    def keys(self) -> Iterator[str]:
        return iter(self.data)

    def text(self, key: str, pattern: re.Pattern[str] | None = None, allow_empty: bool = False) -> str:
        value = self.raw(key)
        if not isinstance(value, str):
            raise ConfigError(f"{self.where(key)} = {value!r} must be a string")
        if value == "" and allow_empty:
            return value
        if pattern is not None and not pattern.match(value):
            raise ConfigError(f"{self.where(key)} = {value!r} is not valid (expected to match {pattern.pattern})")
        return value

    def number(self, key: str, allowed: Range, integer: bool = False) -> float:
        value = self.raw(key)
        kinds = (int,) if integer else (int, float)
        if isinstance(value, bool) or not isinstance(value, kinds) or not math.isfinite(value):
            kind = "an integer" if integer else "a number"
            raise ConfigError(f"{self.where(key)} = {value!r} must be {kind}; allowed {allowed.describe(key)}")
        if not allowed.low <= value <= allowed.high:
            raise ConfigError(f"{self.where(key)} = {value!r} is out of range; allowed {allowed.describe(key)}")
        return value


def _check_keys(section: _Section, allowed: frozenset[str]) -> None:
    unknown = sorted(set(section.keys()) - allowed - ROS_STANDARD_KEYS)
    if unknown:
        raise ConfigError(f"{section.source}: unknown key(s) {unknown} in {section.path}; allowed: {sorted(allowed)}")


def _parse_input(entry: _Section, role: str, default_frame: str, reserved: frozenset[str]) -> InputConfig:
    frame_id = entry.text("frame_id", _FRAME) if "frame_id" in entry.data else default_frame
    max_age = float(entry.number("max_age_s", MAX_AGE_RANGE)) if "max_age_s" in reserved else math.inf
    options = {key: value for key, value in entry.data.items() if key not in reserved}
    for key, value in options.items():
        if isinstance(value, Mapping):
            raise ConfigError(f"{entry.where(key)}: adapter options must be plain values, got a mapping")
    return InputConfig(
        role=role,
        topic=entry.text("topic", _TOPIC),
        ros_type=entry.text("type", _ROS_TYPE),
        frame_id=frame_id,
        max_age_s=max_age,
        options=MappingProxyType(options),
    )


def parse_predictor_config(params: Mapping[str, Any], source: str) -> PredictorConfig:
    """Validate a nested `ros__parameters` mapping; ConfigError names source, key and allowed values."""
    top = _Section(source, params, f"{NODE_NAME}.{PARAMS_KEY}")
    _check_keys(top, TOP_LEVEL_KEYS)
    rate_hz, horizon_s, dt = (float(top.number(key, FLOAT_RANGES[key])) for key in ("rate_hz", "horizon_s", "dt"))
    steps = horizon_s / dt
    if steps < 1.0 or abs(steps - round(steps)) > 1e-6 * steps:
        raise ConfigError(
            f"{top.where('horizon_s')} = {horizon_s:g} s is not a whole number of steps of dt = {dt:g} s"
        )
    base_frame_id = top.text("base_frame_id", _FRAME)
    frame_id = top.text("frame_id", _FRAME)

    inputs_section = top.section("inputs")
    inputs = []
    for role in inputs_section.keys():
        if not _NAME.match(str(role)):
            raise ConfigError(f"{inputs_section.where(str(role))}: input role must be an identifier")
        inputs.append(_parse_input(inputs_section.section(role), role, base_frame_id, INPUT_KEYS))
    if not inputs:
        raise ConfigError(f"{inputs_section.source}: {inputs_section.path} has no inputs")

    outputs_section = top.section("outputs")
    _check_keys(outputs_section, frozenset(OUTPUT_ROLES) | set(OPTIONAL_OUTPUTS))
    outputs = {}
    for role in OUTPUT_ROLES + tuple(OPTIONAL_OUTPUTS):
        if role in OPTIONAL_OUTPUTS and role not in outputs_section.data:
            outputs[role] = OutputConfig(*OPTIONAL_OUTPUTS[role])
            continue
        entry = outputs_section.section(role)
        _check_keys(entry, frozenset({"topic", "type"}))
        outputs[role] = OutputConfig(entry.text("topic", _TOPIC), entry.text("type", _ROS_TYPE))

    online_enabled, online = True, {}
    if "online" in top.data:
        online_section = top.section("online")
        _check_keys(online_section, ONLINE_KEYS)
        if "enabled" in online_section.data:
            online_enabled = online_section.raw("enabled")
            if not isinstance(online_enabled, bool):
                raise ConfigError(f"{online_section.where('enabled')} = {online_enabled!r} must be true or false")
        online = {key: float(online_section.number(key, allowed)) for key, allowed in ONLINE_RANGES.items()
                  if key in online_section.data}

    truth_section = top.section("ground_truth")
    truth = _parse_input(truth_section, truth_section.text("role", _NAME), frame_id, GROUND_TRUTH_KEYS)

    return PredictorConfig(
        source=source,
        model_path=top.text("model_path", allow_empty=True),
        vessel=top.text("vessel", _NAME),
        rate_hz=rate_hz,
        horizon_s=horizon_s,
        dt=dt,
        ensemble_size=int(top.number("ensemble_size", ENSEMBLE_RANGE, integer=True)),
        frame_id=frame_id,
        base_frame_id=base_frame_id,
        inputs=tuple(inputs),
        outputs=MappingProxyType(outputs),
        ground_truth=truth,
        online_enabled=online_enabled,
        online=MappingProxyType(online),
    )


def load_predictor_config(path: str | os.PathLike[str] | None = None) -> PredictorConfig:
    """Load and validate a predictor parameter file; None = the package's config/predictor.yaml."""
    resolved = Path(path) if path is not None else default_config_path()
    return parse_predictor_config(read_ros_parameters(resolved), source=str(resolved))


def input_topics(cfg: PredictorConfig, include_ground_truth: bool = False) -> tuple[InputTopic, ...]:
    """The configured inputs as TopicSpec-like records (topic, role, ros_type, options, frame_id)."""
    entries = cfg.inputs + ((cfg.ground_truth,) if include_ground_truth else ())
    return tuple(InputTopic(e.topic, e.role, e.ros_type, e.options, e.frame_id) for e in entries)
