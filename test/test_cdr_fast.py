"""The bulk CDR decoder equals rosbags' deserialiser on every field, and rejects what it rejects."""
from __future__ import annotations

import math
import random
import struct
from types import SimpleNamespace

import numpy as np
import pytest
from rosbags.interfaces import Nodetype
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_typestore

from msg_adapters.cdr import decode_many, has_fast_layout, supported_types
from usv_predictor.errors import BagError

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)

# Expected output dtype of each ROS primitive (written out here, not taken from the module).
PRIMITIVE_DTYPES = {
    "bool": np.dtype(bool), "byte": np.dtype(np.int8), "char": np.dtype(np.uint8),
    "int8": np.dtype(np.int8), "uint8": np.dtype(np.uint8), "int16": np.dtype(np.int16),
    "uint16": np.dtype(np.uint16), "int32": np.dtype(np.int32), "uint32": np.dtype(np.uint32),
    "int64": np.dtype(np.int64), "uint64": np.dtype(np.uint64),
    "float32": np.dtype(np.float32), "float64": np.dtype(np.float64),
}
FRAME_ALPHABET = "abcxyz_/019ABZéø波"  # multi-byte UTF-8 too: byte length != character count
SPECIAL_FLOATS = (
    math.nan, -math.nan, math.inf, -math.inf, 0.0, -0.0, 1e308, -1e308, 5e-324, -123.456,
    struct.unpack("<d", struct.pack("<Q", 0x7FF8_0000_0000_0123))[0],  # NaN with a payload
)


# --- random messages built from the typestore definitions -------------------------------------


def random_frame_id(rng: random.Random) -> str:
    return "".join(rng.choice(FRAME_ALPHABET) for _ in range(rng.randint(0, 20)))


def random_scalar(base: str, rng: random.Random) -> object:
    if base == "string":
        return random_frame_id(rng)
    if base == "bool":
        return rng.random() < 0.5
    if base == "float64":
        if rng.random() < 0.3:
            return rng.choice(SPECIAL_FLOATS)
        if rng.random() < 0.3:  # any bit pattern: signalling NaNs, subnormals, ...
            return struct.unpack("<d", struct.pack("<Q", rng.getrandbits(64)))[0]
        return rng.uniform(-1, 1) * 10.0 ** rng.uniform(-300, 300)
    if base == "float32":
        if rng.random() < 0.3:
            return rng.choice((math.nan, math.inf, -math.inf, -0.0, 3.4e38, 1e-45))
        return float(np.float32(rng.uniform(-1, 1) * 10.0 ** rng.uniform(-30, 30)))
    info = np.iinfo(PRIMITIVE_DTYPES[base])
    return rng.randint(int(info.min), int(info.max))


def random_array(base: str, count: int, rng: random.Random) -> np.ndarray:
    dtype = PRIMITIVE_DTYPES[base]
    if dtype == np.dtype(bool):
        return np.array([rng.random() < 0.5 for _ in range(count)])
    bits = np.array([rng.getrandbits(8 * dtype.itemsize) for _ in range(count)], dtype=object)
    return bits.astype(f"u{dtype.itemsize}").view(dtype)  # every bit pattern, NaN payloads too


def random_message(ros_type: str, rng: random.Random) -> object:
    msgdef = TYPESTORE.get_msgdef(ros_type)
    values = {}
    for name, (node, detail) in msgdef.fields:
        if node == Nodetype.NAME:
            values[name] = random_message(detail, rng)
        elif node == Nodetype.BASE:
            values[name] = random_scalar(detail[0], rng)
        elif node == Nodetype.ARRAY:
            values[name] = random_array(detail[0][1][0], detail[1], rng)
        else:
            pytest.fail(f"{ros_type}.{name}: the test builder knows no {node}")
    return msgdef.cls(**values)


def serialize(message: object, *, little_endian: bool = True) -> bytes:
    return bytes(TYPESTORE.serialize_cdr(message, message.__msgtype__, little_endian=little_endian))


# --- field-by-field comparison with rosbags ----------------------------------------------------


def bits(array: np.ndarray) -> np.ndarray:
    """Integer view of a numeric array so that NaNs (and their payloads) compare exactly."""
    if array.dtype.kind == "f":
        return array.view(f"u{array.dtype.itemsize}")
    return array


def rosbags_view(column: np.ndarray) -> np.ndarray:
    """Bits of a decoded scalar column as rosbags reports them.

    rosbags returns a float32 scalar as a Python float; that conversion quiets a signalling NaN
    (sets the quiet bit, payload kept) while the fast decoder keeps the wire bits. Every other
    value, quiet NaNs included, must match bit for bit.
    """
    if column.dtype != np.float32:
        return bits(column)
    quiet = np.uint32(0x0040_0000)
    return np.where(np.isnan(column), bits(column) | quiet, bits(column))


def assert_matches(
    decoded: SimpleNamespace, messages: list[object], ros_type: str, path: str = ""
) -> None:
    """Every field of `decoded` equals the same field of rosbags' messages, nothing extra."""
    msgdef = TYPESTORE.get_msgdef(ros_type)
    assert sorted(vars(decoded)) == sorted(name for name, _ in msgdef.fields), path
    for name, (node, detail) in msgdef.fields:
        column = getattr(decoded, name)
        values = [getattr(message, name) for message in messages]
        where = f"{ros_type} {path}{name}"
        if node == Nodetype.NAME:
            assert_matches(column, values, detail, f"{path}{name}.")
        elif detail[0] == "string":
            assert column.dtype == object, where
            assert column.tolist() == values, where
        elif node == Nodetype.BASE:
            expected = np.array(values, dtype=PRIMITIVE_DTYPES[detail[0]])
            assert column.dtype == expected.dtype, where
            assert column.shape == (len(messages),), where
            np.testing.assert_array_equal(rosbags_view(column), bits(expected), err_msg=where)
        else:
            expected = np.stack(values) if values else np.empty((0, detail[1]))
            assert column.dtype == PRIMITIVE_DTYPES[detail[0][1][0]], where
            assert column.shape == (len(messages), detail[1]), where
            expected_bits = bits(expected.astype(column.dtype))
            np.testing.assert_array_equal(bits(column), expected_bits, err_msg=where)


def rosbags_decode(raws: list[bytes], ros_type: str) -> list[object]:
    return [TYPESTORE.deserialize_cdr(raw, ros_type) for raw in raws]


# --- tests -------------------------------------------------------------------------------------


@pytest.mark.parametrize("ros_type", supported_types())
def test_matches_rosbags_on_every_field_with_mixed_layouts(ros_type: str) -> None:
    rng = random.Random(ros_type)
    raws = [serialize(random_message(ros_type, rng)) for _ in range(400)]
    assert len({len(raw) for raw in raws}) > 1 or "std_msgs" in ros_type  # layouts really mixed

    decoded = decode_many(ros_type, raws, TYPESTORE)

    assert has_fast_layout(ros_type, TYPESTORE)
    assert_matches(decoded, rosbags_decode(raws, ros_type), ros_type)


@pytest.mark.parametrize("ros_type", supported_types())
def test_one_layout_batch_equals_rosbags(ros_type: str) -> None:
    """The common case: one frame id per topic, decoded as a single zero-copy group."""
    rng = random.Random(f"{ros_type} constant")
    messages = [random_message(ros_type, rng) for _ in range(50)]
    for message in messages:
        for field in ("header", "child_frame_id"):
            if hasattr(message, field):
                if field == "header":
                    message.header.frame_id = "base_link"
                else:
                    message.child_frame_id = "odom"
    raws = [serialize(message) for message in messages]

    assert_matches(decode_many(ros_type, raws), rosbags_decode(raws, ros_type), ros_type)


def test_order_is_preserved_across_layout_groups() -> None:
    rng = random.Random(7)
    ros_type = "nav_msgs/msg/Odometry"
    raws = [serialize(random_message(ros_type, rng)) for _ in range(60)]
    permutation = list(range(len(raws)))
    rng.shuffle(permutation)

    straight = decode_many(ros_type, raws)
    shuffled = decode_many(ros_type, [raws[i] for i in permutation])

    assert shuffled.child_frame_id.tolist() == [straight.child_frame_id[i] for i in permutation]
    np.testing.assert_array_equal(
        bits(shuffled.twist.covariance), bits(straight.twist.covariance[permutation])
    )
    np.testing.assert_array_equal(
        shuffled.header.stamp.nanosec, straight.header.stamp.nanosec[permutation]
    )


def test_big_endian_messages_mixed_with_little_endian_ones() -> None:
    rng = random.Random(11)
    ros_type = "sensor_msgs/msg/Imu"
    raws = [
        serialize(random_message(ros_type, rng), little_endian=rng.random() < 0.5)
        for _ in range(80)
    ]
    assert {raw[1] for raw in raws} == {0, 1}

    assert_matches(decode_many(ros_type, raws), rosbags_decode(raws, ros_type), ros_type)


def test_handcrafted_bytes_follow_the_cdr_layout() -> None:
    """Offsets checked against the wire format itself, not only against rosbags' serialiser."""
    header = b"\x00\x01\x00\x00"
    float64 = decode_many("std_msgs/msg/Float64", [header + struct.pack("<d", -2.5)])
    assert float64.data.tolist() == [-2.5]

    # stamp (8) + length (4) + 'ab\0' (3) = 15 -> the quaternion starts aligned at 16
    stamped = header + struct.pack("<iI", -3, 7) + struct.pack("<I", 3) + b"ab\x00" + b"\x00"
    stamped += struct.pack("<4d", 0.1, 0.2, 0.3, 0.9)
    quaternion = decode_many("geometry_msgs/msg/QuaternionStamped", [stamped, stamped])
    assert quaternion.header.stamp.sec.tolist() == [-3, -3]
    assert quaternion.header.stamp.nanosec.tolist() == [7, 7]
    assert quaternion.header.frame_id.tolist() == ["ab", "ab"]
    assert quaternion.quaternion.w.tolist() == [0.9, 0.9]
    assert quaternion.quaternion.x.tolist() == [0.1, 0.1]


def test_empty_batch_gives_empty_columns_of_the_right_shape() -> None:
    decoded = decode_many("sensor_msgs/msg/Imu", [])

    assert decoded.orientation_covariance.shape == (0, 9)
    assert decoded.angular_velocity.z.shape == (0,)
    assert decoded.angular_velocity.z.dtype == np.float64
    assert decoded.header.stamp.sec.dtype == np.int32
    assert decoded.header.frame_id.dtype == object


def test_type_without_fixed_layout_falls_back_to_rosbags_with_the_same_structure() -> None:
    ros_type = "sensor_msgs/msg/JointState"
    joint_state = TYPESTORE.types[ros_type]
    header = TYPESTORE.types["std_msgs/msg/Header"]
    stamp = TYPESTORE.types["builtin_interfaces/msg/Time"]
    messages = [
        joint_state(
            header=header(stamp=stamp(sec=i, nanosec=2 * i), frame_id="j" * i),
            name=["rudder", "engine"][: i % 3],
            position=np.arange(i % 3, dtype=np.float64) * i,
            velocity=np.array([], dtype=np.float64),
            effort=np.array([], dtype=np.float64),
        )
        for i in range(5)
    ]
    raws = [serialize(message) for message in messages]

    decoded = decode_many(ros_type, raws)

    assert not has_fast_layout(ros_type)
    assert decoded.header.stamp.sec.tolist() == [0, 1, 2, 3, 4]
    assert decoded.header.stamp.sec.dtype == np.int32
    assert decoded.header.frame_id.tolist() == ["", "j", "jj", "jjj", "jjjj"]
    assert decoded.name.tolist() == [message.name for message in messages]
    for column, message in zip(decoded.position, messages, strict=True):
        np.testing.assert_array_equal(column, message.position)


def test_every_truncation_raises_bag_error_naming_type_and_index() -> None:
    rng = random.Random(3)
    for ros_type in supported_types():
        good = [serialize(random_message(ros_type, rng)) for _ in range(4)]
        victim = good[2]
        for cut in range(len(victim)):
            batch = [*good[:2], victim[:cut], *good[3:]]
            with pytest.raises(BagError, match=rf"{ros_type} message 2\b"):
                decode_many(ros_type, batch)


@pytest.mark.parametrize("ros_type", supported_types())
def test_corrupted_messages_are_accepted_or_rejected_exactly_like_rosbags(ros_type: str) -> None:
    """Random byte overwrites and trailing bytes: same values, or BagError where rosbags fails."""
    rng = random.Random(f"{ros_type} corrupt")
    rejected = 0
    for trial in range(150):
        batch = [serialize(random_message(ros_type, rng)) for _ in range(3)]
        victim = bytearray(batch[1])
        if trial % 3 == 0:
            victim += bytes(rng.randrange(256) for _ in range(rng.randint(1, 6)))
        else:  # aim at the first 24 bytes half of the time: header, stamp, string length
            position = rng.randrange(min(24, len(victim)) if trial % 2 else len(victim))
            victim[position] = rng.randrange(256)
        batch[1] = bytes(victim)
        try:
            expected = rosbags_decode(batch, ros_type)
        except SerdeError:
            rejected += 1
            with pytest.raises(BagError, match=rf"{ros_type} message 1\b"):
                decode_many(ros_type, batch)
        else:
            assert_matches(decode_many(ros_type, batch), expected, ros_type)
    assert rejected > 0  # the property was exercised on both sides


def test_invalid_utf8_string_is_rejected() -> None:
    message = TYPESTORE.types["geometry_msgs/msg/QuaternionStamped"](
        header=TYPESTORE.types["std_msgs/msg/Header"](
            stamp=TYPESTORE.types["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id="ab"
        ),
        quaternion=TYPESTORE.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
    )
    raw = bytearray(serialize(message))
    raw[16] = 0xFF  # first character of 'ab': 4 header + 8 stamp + 4 length bytes before it

    with pytest.raises(BagError, match="not valid UTF-8"):
        decode_many("geometry_msgs/msg/QuaternionStamped", [serialize(message), bytes(raw)])


def test_unknown_type_is_a_bag_error() -> None:
    with pytest.raises(BagError, match="no_pkg/msg/Nothing"):
        decode_many("no_pkg/msg/Nothing", [b"\x00\x01\x00\x00"])


# --- the small-batch path (the node's 1-2 messages per input and cycle) ------------------------


def _decode_or_error(ros_type: str, batch: list[bytes]) -> SimpleNamespace | str:
    try:
        return decode_many(ros_type, batch)
    except BagError as err:
        return f"BagError: {err}"


@pytest.mark.parametrize("ros_type", supported_types())
def test_small_batches_decode_and_refuse_as_the_vectorised_path(ros_type: str, monkeypatch) -> None:
    """Batches of 1-3 messages (cdr.SMALL_BATCH: walked in Python) against the same batches through the vectorised
    walk (SMALL_BATCH 0): the same values, or the same BagError message, for intact, truncated, overwritten and
    padded messages; and rosbags agrees on the intact ones. Mixed frame ids make two layout groups in one batch."""
    from msg_adapters import cdr

    rng = random.Random(f"{ros_type} small")
    outcomes = {"values": 0, "refused": 0}
    for trial in range(120):
        batch = [serialize(random_message(ros_type, rng)) for _ in range(1 + trial % 3)]
        victim = bytearray(batch[-1])
        if trial % 4 == 1:
            victim = victim[: rng.randrange(len(victim))]
        elif trial % 4 == 2:
            victim[rng.randrange(min(24, len(victim)))] = rng.randrange(256)
        elif trial % 4 == 3:
            victim += bytes(rng.randint(1, 6))
        batch[-1] = bytes(victim)
        small = _decode_or_error(ros_type, batch)
        monkeypatch.setattr(cdr, "SMALL_BATCH", 0)
        vectorised = _decode_or_error(ros_type, batch)
        monkeypatch.setattr(cdr, "SMALL_BATCH", 16)
        if isinstance(vectorised, str):
            outcomes["refused"] += 1
            assert small == vectorised
        else:
            outcomes["values"] += 1
            assert not isinstance(small, str), small
            assert_matches(small, rosbags_decode(batch, ros_type), ros_type)
    assert min(outcomes.values()) > 10, outcomes  # both sides of the property exercised


def test_a_big_endian_message_in_a_small_batch_takes_the_general_path() -> None:
    """A big-endian header is not the small path's to read: the batch goes the general way (rosbags for that
    message), with the same result as a batch too large for the small path."""
    message = random_message("std_msgs/msg/Float64", random.Random(2))
    little = serialize(message)
    big = b"\x00\x00\x00\x00" + struct.pack(">d", message.data)
    decoded = decode_many("std_msgs/msg/Float64", [little, big])
    np.testing.assert_array_equal(decoded.data, [message.data, message.data])


# --- decode_values' lean path (alike messages, fields converted on access: the node's inputs) ---------------------


def _lean_cases() -> list[tuple[str, str]]:
    from msg_adapters.standard import ADAPTER_CLASSES

    return sorted((role, ros_type) for role, ros_type in ADAPTER_CLASSES if has_fast_layout(ros_type))


def _decoded_values(adapter: object, batch: list[bytes]) -> tuple:
    from msg_adapters.cdr import decode_values

    out = decode_values(adapter, batch)
    return (out.index.tolist(), None if out.stamps is None else out.stamps.tolist(), bits(out.values).tolist(),
            out.errors, out.columns)


def _leaf_bits(columns: SimpleNamespace, ros_type: str) -> list:
    from msg_adapters.cdr import _flatten

    found = []
    for leaf in _flatten(ros_type, TYPESTORE):
        value = columns
        for name in leaf.path:
            value = getattr(value, name)
        found.append((leaf.path, value.dtype.str, value.tolist() if value.dtype == object else bits(value).tolist()))
    return found


@pytest.mark.parametrize(("role", "ros_type"), _lean_cases())
def test_alike_messages_decode_lazily_to_decode_many_s_values(role: str, ros_type: str, monkeypatch) -> None:
    """decode_values reads a batch of alike messages (one length, one frame id) as one structured array and converts
    a field when the adapter reads it (cdr.LEAN_BATCH); against the same batches with it off (decode_many): the
    same index, stamps, values (bit for bit) and errors, and every leaf of the columns equal, on intact batches of
    1-40 messages and with a message truncated, overwritten, padded, of another frame id, or a frame id that is
    not UTF-8 in every message."""
    from msg_adapters import cdr
    from msg_adapters import get_adapter

    try:
        adapter = get_adapter(role, ros_type)
    except Exception as err:  # an adapter that needs options (units, full_scale) is covered through its default
        pytest.skip(f"{role} {ros_type} needs options: {err}")
    rng = random.Random(f"{role} {ros_type} lean")
    lean_used = 0
    original = cdr._lean_columns

    def counted(*args: object) -> object:
        nonlocal lean_used
        found = original(*args)
        lean_used += found is not None
        return found

    monkeypatch.setattr(cdr, "_lean_columns", counted)
    for trial in range(60):
        frame = random_frame_id(rng) or "f"
        messages = [random_message(ros_type, rng) for _ in range(rng.choice([1, 2, 5, 20, 40]))]
        for message in messages:
            if hasattr(message, "header"):
                message.header.frame_id = frame
        batch = [serialize(message) for message in messages]
        victim, spoil = rng.randrange(len(batch)), trial % 6
        raw = bytearray(batch[victim])
        if spoil == 1:
            batch[victim] = bytes(raw[: rng.randrange(len(raw))])
        elif spoil == 2:
            raw[rng.randrange(min(24, len(raw)))] = rng.randrange(256)
            batch[victim] = bytes(raw)
        elif spoil == 3:
            batch[victim] = bytes(raw + bytes(rng.randint(1, 6)))
        elif spoil == 4 and hasattr(messages[victim], "header"):
            messages[victim].header.frame_id = frame + "x"
            batch[victim] = serialize(messages[victim])
        elif spoil == 5 and hasattr(messages[0], "header"):
            batch = [raw[:16] + b"\xff" + raw[17:] for raw in batch]  # the frame id's first byte (after the stamp)
        lean = _decoded_values(adapter, batch)
        monkeypatch.setattr(cdr, "LEAN_BATCH", 0)
        general = _decoded_values(adapter, batch)
        monkeypatch.setattr(cdr, "LEAN_BATCH", 256)
        assert lean[:4] == general[:4], (trial, spoil)
        if lean[4] is not None and general[4] is not None:
            assert _leaf_bits(lean[4], ros_type) == _leaf_bits(general[4], ros_type)
    assert 10 < lean_used, lean_used  # the lean path was taken (intact batches), and not always
