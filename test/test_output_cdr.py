"""The node's outputs written as CDR with numpy are the bytes rclpy serialises for the same messages.

Oracle: `rclpy.serialization.serialize_message` of the message objects (msg_adapters.outputs.encode_*, the
node's former path). rclpy's buffer leaves alignment padding uninitialised (it differs from call to call) and
can be longer than the content (its size estimate aligns empty float64 sequences; DDS sends the content only),
so the comparison is on the content: every byte that carries a value must be equal, the padding positions are
found by an independent walk over rclpy's own type introspection (rosidl SLOT_TYPES), ours must be zero there
and exactly as long as the content. rosbags' serialiser (zero padding) must agree byte for byte, and rclpy must
read our bytes back into the same message. Sizes: empty, typical (120 steps, 5 statuses), maximal (600 s at
dt 0.01 s = 60000 steps; 64 candidates); frame ids of every length 0..8 (alignment), multi-byte UTF-8.
"""
from __future__ import annotations

import math
import struct
from typing import Any

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import Stores, get_typestore
from rosidl_parser import definition

import msg_adapters
from msg_adapters import outputs
from msg_adapters.cdr_writer import CdrWriter
from usv_predictor.errors import AdapterError

RCLPY = msg_adapters.rclpy_factory()
TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
ROSBAGS = msg_adapters.rosbags_factory(TYPESTORE)
NS = 1_000_000_000
MAX_STEPS = 60_000  # horizon_s 600 s / dt 0.01 s: the largest the configuration allows
FRAMES = ["", "o", "od", "odo", "odom", "map_1", "odom_ab", "base_lnk", "ødom", "карта/世界"]
PRIMITIVE_SIZES = {"double": 8, "float": 4, "int64": 8, "uint64": 8, "int32": 4, "uint32": 4, "int16": 2,
                   "uint16": 2, "int8": 1, "uint8": 1, "octet": 1, "boolean": 1, "char": 1}  # bytes


# --- an independent account of which bytes carry values ----------------------------------------


class ContentMap:
    """Walks a message the way XCDR1 lays it out: True for value bytes, False for alignment padding."""

    def __init__(self) -> None:
        self.mask: list[bool] = []

    def _primitive(self, size: int) -> None:
        self.mask += [False] * (-len(self.mask) % size) + [True] * size

    def message(self, msg: Any) -> None:
        for name, slot_type in zip(type(msg).get_fields_and_field_types(), type(msg).SLOT_TYPES, strict=True):
            self.field(slot_type, getattr(msg, name))

    def field(self, slot_type: Any, value: Any) -> None:
        if isinstance(slot_type, definition.BasicType):
            self._primitive(PRIMITIVE_SIZES[slot_type.typename])
        elif isinstance(slot_type, definition.AbstractString):
            self._primitive(4)
            self.mask += [True] * (len(value.encode("utf-8")) + 1)
        elif isinstance(slot_type, definition.NamespacedType):
            self.message(value)
        elif isinstance(slot_type, definition.AbstractSequence):
            self._primitive(4)
            self._elements(slot_type.value_type, value)
        elif isinstance(slot_type, definition.Array):
            self._elements(slot_type.value_type, value)
        else:
            pytest.fail(f"the walker knows no {slot_type}")

    def _elements(self, value_type: Any, values: Any) -> None:
        if isinstance(value_type, definition.BasicType):  # fast path for long float arrays
            size = PRIMITIVE_SIZES[value_type.typename]
            if len(values):
                self._primitive(size)
                self.mask += [True] * (size * (len(values) - 1))
            return
        for value in values:
            self.field(value_type, value)


def content_mask(msg: Any) -> np.ndarray:
    walk = ContentMap()
    walk.message(msg)
    return np.array([True] * 4 + walk.mask)  # the encapsulation header is content


def assert_same_bytes(ours: bytes, rclpy_msg: Any, rosbags_msg: Any | None, ros_type: str) -> None:
    assert isinstance(ours, bytes)
    reference = np.frombuffer(serialize_message(rclpy_msg), dtype=np.uint8)
    mine = np.frombuffer(ours, dtype=np.uint8)
    mask = content_mask(rclpy_msg)
    assert len(mine) == len(mask), f"{ros_type}: {len(mine)} bytes, the content is {len(mask)}"
    assert len(reference) >= len(mine)
    differ = np.flatnonzero((mine != reference[: len(mine)]) & mask)
    assert differ.size == 0, f"{ros_type}: value bytes differ from rclpy's at {differ[:10].tolist()}"
    assert not mine[~mask].any(), f"{ros_type}: padding is not zero"
    assert deserialize_message(ours, type(rclpy_msg)) == rclpy_msg
    if rosbags_msg is not None:
        assert bytes(TYPESTORE.serialize_cdr(rosbags_msg, ros_type)) == ours


# --- cases -------------------------------------------------------------------------------------


def prediction(steps: int, seed: int, special: bool = False) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """(stamp_ns, t_ns (H,), eta (H, 3), nu (H, 3)): a future track; `special` adds -0.0, huge and tiny values."""
    rng = np.random.default_rng(seed)
    stamp = 1_700_000_000 * NS + int(rng.integers(0, NS))
    t_ns = stamp - NS // 4 + (1 + np.arange(steps, dtype=np.int64)) * (NS // 2)
    eta = np.column_stack([rng.normal(0, 300, steps), rng.normal(0, 300, steps), rng.uniform(-10, 10, steps)])
    nu = rng.normal(0, 2, (steps, 3))
    if special and steps >= 4:
        eta[:4] = [[-0.0, 0.0, -0.0], [1e300, -1e-300, math.pi], [5e-324, -5e-324, -math.pi], [0.0, 0.0, 2 * math.pi]]
        nu[:4] = [[-0.0, -0.0, -0.0], [1e300, -1e300, 1e-310], [0.0, 0.0, 0.0], [-1.0, 1.0, -1.0]]
    return stamp, t_ns, eta, nu


@pytest.mark.parametrize("steps", [0, 1, 2, 3, 120])
@pytest.mark.parametrize("frame", FRAMES)
def test_path_bytes_equal_rclpy(steps: int, frame: str) -> None:
    stamp, t_ns, eta, _ = prediction(steps, len(frame), special=True)
    outputs.path_cdr(stamp + 1, t_ns + 7, eta * 2 + 1, frame)  # the layout's buffer holds other values first
    ours = outputs.path_cdr(stamp, t_ns, eta, frame)
    assert_same_bytes(ours, outputs.encode_path(stamp, t_ns, eta, frame, RCLPY),
                      outputs.encode_path(stamp, t_ns, eta, frame, ROSBAGS), outputs.PATH_TYPE)


@pytest.mark.parametrize("steps", [0, 1, 3, 120])
@pytest.mark.parametrize(("frame", "child"), [("", ""), ("odom", "base_link"), ("o", "ba"), ("map_1", "bøat"),
                                              ("odo", "b")])
def test_predicted_velocities_bytes_equal_rclpy(steps: int, frame: str, child: str) -> None:
    stamp, t_ns, eta, nu = prediction(steps, steps + len(child), special=True)
    outputs.predicted_velocities_cdr(stamp + 1, t_ns + 7, eta * 2 + 1, nu - 3, frame, child)  # other values first
    ours = outputs.predicted_velocities_cdr(stamp, t_ns, eta, nu, frame, child)
    assert_same_bytes(ours, outputs.encode_predicted_velocities(stamp, t_ns, eta, nu, frame, child, RCLPY),
                      outputs.encode_predicted_velocities(stamp, t_ns, eta, nu, frame, child, ROSBAGS),
                      outputs.TRAJECTORY_TYPE)


@pytest.mark.parametrize(("bodies", "steps"), [(0, 0), (0, 3), (1, 0), (1, 120), (3, 5), (64, 120)])
def test_candidate_predictions_bytes_equal_rclpy(bodies: int, steps: int) -> None:
    stamp, t_ns, _, _ = prediction(steps, 7)
    rng = np.random.default_rng(bodies)
    eta, nu = rng.normal(0, 100, (bodies, steps, 3)), rng.normal(0, 2, (bodies, steps, 3))
    names = [f"c{i}" + "x" * (i % 5) for i in range(bodies)]  # odd and even name lengths
    # the layout's buffer is reused (CdrLayout.fill): other values first, every value byte must be rewritten
    earlier = outputs.candidate_predictions_cdr(stamp + 1, t_ns + 7, eta * 2 + 1, nu - 3, "odom", names)
    ours = outputs.candidate_predictions_cdr(stamp, t_ns, eta, nu, "odom", names)
    assert earlier != ours or steps * bodies == 0
    assert_same_bytes(ours, outputs.encode_candidate_predictions(stamp, t_ns, eta, nu, "odom", names, RCLPY),
                      outputs.encode_candidate_predictions(stamp, t_ns, eta, nu, "odom", names, ROSBAGS),
                      outputs.TRAJECTORY_TYPE)


@pytest.mark.parametrize("steps", [0, 1, 2, 120])
def test_covariance_bytes_equal_rclpy(steps: int) -> None:
    members = np.random.default_rng(steps).normal(0, 5, (5, steps, 3))
    covariance = np.einsum("ehi,ehj->hij", members, members) / 5
    ours = outputs.covariance_cdr(covariance)
    rosbags_msg = outputs.encode_covariance(covariance, ROSBAGS)
    rosbags_msg.data = np.asarray(rosbags_msg.data, dtype=np.float64)  # rosbags wants an array for float64[]
    assert_same_bytes(ours, outputs.encode_covariance(covariance, RCLPY), rosbags_msg, outputs.COVARIANCE_TYPE)


CURRENTS = [  # (current_ne m/s, P_nn, P_ne, P_ee (m/s)^2): typical, signed zero and correlation, extremes
    ((0.3, -0.2), (0.0004, -0.0001, 0.0009)),
    ((-0.0, 0.0), (0.25, 0.0, 0.25)),
    ((1e300, -5e-324), (5e-324, -1e-300, 1e300)),
]


@pytest.mark.parametrize(("current", "cov"), CURRENTS)
@pytest.mark.parametrize("frame", FRAMES)
def test_estimated_current_bytes_equal_rclpy(current: tuple[float, float], cov: tuple[float, float, float],
                                             frame: str) -> None:
    stamp = 1_700_000_000 * NS + 987_654_321 + len(frame)
    ours = outputs.current_cdr(stamp, current, cov, frame)
    assert_same_bytes(ours, outputs.encode_current(stamp, current, cov, frame, RCLPY),
                      outputs.encode_current(stamp, current, cov, frame, ROSBAGS), outputs.CURRENT_TYPE)


def test_the_estimated_current_is_enu_with_the_unknown_components_marked() -> None:
    """x east, y north; the 2 x 2 block swapped NED -> ENU; z and the rates UNKNOWN_VARIANCE, uncorrelated."""
    msg = deserialize_message(outputs.current_cdr(5 * NS, (0.3, -0.2), (0.0004, -0.0001, 0.0009), "odom"),
                              RCLPY(outputs.CURRENT_TYPE))
    assert (msg.twist.twist.linear.x, msg.twist.twist.linear.y, msg.twist.twist.linear.z) == (-0.2, 0.3, 0.0)
    assert msg.header.frame_id == "odom"
    assert msg.header.stamp.sec == 5
    covariance = np.asarray(msg.twist.covariance).reshape(6, 6)
    np.testing.assert_array_equal(covariance[:2, :2], [[0.0009, -0.0001], [-0.0001, 0.0004]])
    np.testing.assert_array_equal(np.diag(covariance)[2:], [outputs.UNKNOWN_VARIANCE] * 4)
    assert np.count_nonzero(covariance) == 4 + 4
    stamp, current, block = outputs.decode_current(msg)
    assert stamp == 5 * NS
    np.testing.assert_array_equal(current, [0.3, -0.2])
    np.testing.assert_array_equal(block, [[0.0004, -0.0001], [-0.0001, 0.0009]])


def statuses(count: int, values: int, seed: int) -> list[outputs.Status]:
    rng = np.random.default_rng(seed)

    def text(longest: int) -> str:
        return "".join(rng.choice(list("abcxyz_ :./-019éø")) for _ in range(int(rng.integers(0, longest + 1))))

    return [outputs.Status(int(rng.integers(0, 4)), f"predictor: {text(12)}", text(80), text(9),
                           tuple((text(20), text(30)) for _ in range(int(rng.integers(0, values + 1)))))
            for _ in range(count)]


@pytest.mark.parametrize(("count", "values", "seed"), [(0, 0, 0), (1, 0, 1), (1, 1, 2), (5, 15, 3), (9, 40, 4),
                                                         (40, 60, 5)])
def test_diagnostics_bytes_equal_rclpy(count: int, values: int, seed: int) -> None:
    found = statuses(count, values, seed)
    stamp = 1_700_000_000 * NS + 123_456_789 + seed
    assert_same_bytes(outputs.diagnostics_cdr(stamp, found), outputs.encode_diagnostics(stamp, found, RCLPY), None,
                      outputs.DIAGNOSTICS_TYPE)


@pytest.mark.parametrize("what", ["path", "velocities", "covariance"])
def test_maximal_sizes_bytes_equal_rclpy(what: str) -> None:
    """600 s at dt 0.01 s: 60000 poses (~4.6 MB of Path)."""
    stamp, t_ns, eta, nu = prediction(MAX_STEPS, 99, special=True)
    if what == "path":
        ours, msg = outputs.path_cdr(stamp, t_ns, eta,
                                     "odom_ab"), outputs.encode_path(stamp, t_ns, eta, "odom_ab", RCLPY)
    elif what == "velocities":
        ours = outputs.predicted_velocities_cdr(stamp, t_ns, eta, nu, "odom", "base")
        msg = outputs.encode_predicted_velocities(stamp, t_ns, eta, nu, "odom", "base", RCLPY)
    else:
        covariance = np.einsum("hi,hj->hij", eta, eta)
        ours, msg = outputs.covariance_cdr(covariance), outputs.encode_covariance(covariance, RCLPY)
    assert_same_bytes(ours, msg, None, what)


def test_stamps_are_split_into_sec_and_nanosec_like_builtin_interfaces() -> None:
    """Negative relative times (a time_from_start before the stamp) floor: sec -1, nanosec 999999999."""
    t_ns = np.array([-1, 0, NS - 1, (2**31 - 1) * NS], dtype=np.int64)
    ours = outputs.predicted_velocities_cdr(0, t_ns, np.zeros((4, 3)), np.zeros((4, 3)), "", "")
    msg = deserialize_message(ours, RCLPY(outputs.TRAJECTORY_TYPE))
    parts = [(p.time_from_start.sec, p.time_from_start.nanosec) for p in msg.points]
    assert parts == [(-1, NS - 1), (0, 0), (0, NS - 1), (2**31 - 1, 0)]


def test_the_writer_aligns_relative_to_the_end_of_the_header() -> None:
    """Handcrafted: a string of 2 (+ NUL) then a float64 lands on 16 after the header, not 12 or 20."""
    writer = CdrWriter()
    writer.string("ab")
    writer.slot("x", "<f8")
    writer.uint32(7)
    data = writer.layout().fill(x=[[-2.5]])
    assert data == b"\x00\x01\x00\x00" + struct.pack("<I", 3) + b"ab\x00" + bytes(1) + struct.pack("<d", -2.5) \
        + struct.pack("<I", 7)


def test_shape_errors_name_the_array() -> None:
    with pytest.raises(AdapterError, match=r"eta must have shape \(3, 3\)"):
        outputs.path_cdr(0, np.arange(3), np.zeros((2, 3)), "odom")
    with pytest.raises(AdapterError, match=r"covariance must have shape \(H, 3, 3\)"):
        outputs.covariance_cdr(np.zeros((4, 9)))
