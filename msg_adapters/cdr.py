"""Bulk decoding of ROS 2 CDR messages into numpy structure-of-arrays, many messages at once.

The replay tool (bagio) and the `predictor` node decode through the same `decode_many` (the node
through `decode_values`, which adds the adapter and isolates undecodable messages; its plan inputs
through `decode_joint_trajectory`). Encoding is msg_adapters.cdr_writer. Never imports rclpy.

rosbags' deserialiser builds one Python object per message (~50k Imu/s); rebuilding training sets
reads millions. Messages made only of numbers, fixed-size numeric arrays and strings have a byte
layout that depends on nothing but their string lengths, so this module

1. reads every string length with a few vectorised gathers over the concatenated messages,
2. groups the messages by (total length, string lengths) -- usually one group per topic,
3. decodes each group with a single `np.frombuffer` through a structured dtype whose offsets are
   derived from the typestore's message definition (no hand-written offsets).

Wire format (OMG XCDR1 as written by ROS 2): a 4-byte encapsulation header (`00 01` = little
endian, `00 00` = big endian, then 2 option bytes); primitives aligned to their size relative to
the first byte after the header; a string is a uint32 length that counts its NUL terminator,
then the bytes. The result must equal `Typestore.deserialize_cdr` field for field: big-endian
messages and types with sequences etc. go through rosbags per message, and messages rosbags
would reject are rejected with a `BagError`.
"""
from __future__ import annotations

import functools
import operator
import struct
from collections.abc import Callable, Sequence
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from rosbags.interfaces import Nodetype
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.base import normalize_fieldname

from usv_predictor.errors import AdapterError, BagError
from usv_predictor.records import NS_PER_S

if TYPE_CHECKING:
    from collections.abc import Iterator, Sequence

    from rosbags.typesys.store import Typestore

# The default and common input types of the predictor (DESIGN.md); tested against rosbags.
_DEFAULT_TYPES = (
    "sensor_msgs/msg/Imu",
    "geometry_msgs/msg/TwistStamped",
    "geometry_msgs/msg/TwistWithCovarianceStamped",
    "std_msgs/msg/Float64",
    "std_msgs/msg/Float32",
    "sensor_msgs/msg/NavSatFix",
    "nav_msgs/msg/Odometry",
    "geometry_msgs/msg/QuaternionStamped",
)

# Wire dtype of each ROS primitive; 'byte' is signed and 'char' unsigned, as in rosbags.
_WIRE_DTYPES = {
    "bool": np.dtype("u1"),
    "byte": np.dtype("i1"),
    "char": np.dtype("u1"),
    "int8": np.dtype("i1"),
    "uint8": np.dtype("u1"),
    "int16": np.dtype("<i2"),
    "uint16": np.dtype("<u2"),
    "int32": np.dtype("<i4"),
    "uint32": np.dtype("<u4"),
    "int64": np.dtype("<i8"),
    "uint64": np.dtype("<u8"),
    "float32": np.dtype("<f4"),
    "float64": np.dtype("<f8"),
}
_STRING = "string"
_OBJECT = "object"  # anything without a fixed layout: only rosbags decodes it
_LITTLE_ENDIAN_HEADER = (0, 1)
_HEADER_SIZE = 4
_MAX_TRAILING_PADDING = 3  # rosbags accepts up to 3 unread bytes at the end
# batches of at most this many messages walk their strings and group their layouts in plain Python (_decode_small):
# the same checks, messages and layouts as the vectorised walk, without its fixed cost of ~40 numpy calls, which
# dominates for the node's 1-2 messages per input and cycle (benchmarks/bench_decode.py --small)
SMALL_BATCH = 16
# decode_values of at most this many messages that are alike (one length, one set of strings: one publisher's
# stream) reads them as one structured array and converts a field only when the adapter asks for it
# (_lean_columns): the node's inputs every cycle. 0 turns it off (test_cdr_fast.py, benchmarks/bench_decode.py).
LEAN_BATCH = 256


class _Leaf(NamedTuple):
    """One leaf field of a flattened message definition."""

    path: tuple[str, ...]  # attribute names from the message root, e.g. ('header', 'stamp', 'sec')
    kind: str  # a key of _WIRE_DTYPES, _STRING or _OBJECT
    count: int  # elements of a fixed-size numeric array, 0 for a scalar


class _Layout(NamedTuple):
    """Byte layout of one group of messages that share their string lengths."""

    dtype: np.dtype  # structured, itemsize = the group's message length
    size: int  # bytes the fields need, header included
    fields: dict[int, str | None]  # leaf index -> structured field; None for an empty string


def supported_types() -> tuple[str, ...]:
    """Message types that `decode_many` decodes vectorised and that are tested against rosbags.

    Any other type whose fields are numbers, fixed-size numeric arrays and strings takes the
    vectorised path too (see `has_fast_layout`); the rest falls back to rosbags.
    """
    return _DEFAULT_TYPES


def has_fast_layout(ros_type: str, typestore: Typestore | None = None) -> bool:
    """Whether `ros_type` is decoded vectorised (True) or message by message by rosbags."""
    return _all_fixed(_flatten(ros_type, typestore or _default_typestore()))


def decode_many(
    ros_type: str,
    raws: Sequence[bytes | memoryview],
    typestore: Typestore | None = None,
) -> SimpleNamespace:
    """Decode N CDR messages of `ros_type` into a namespace of numpy arrays, in input order.

    The namespace mirrors the message (`out.header.stamp.sec`, `out.angular_velocity.z`); numeric
    leaves are arrays of shape (N,) or (N, k) for fixed arrays of k, strings and fields without a
    fixed layout (sequences, arrays of messages) are object arrays of shape (N,) holding what
    rosbags returns. Raises BagError for an unknown type or a message rosbags would reject.
    """
    typestore = typestore or _default_typestore()
    leaves = _flatten(ros_type, typestore)
    count = len(raws)
    if count == 0:
        return _to_namespace(leaves, [_empty(leaf) for leaf in leaves])

    if count <= SMALL_BATCH and _all_fixed(leaves):
        small = _decode_small(ros_type, leaves, raws)
        if small is not None:
            return small
    lengths = np.fromiter(map(len, raws), dtype=np.int64, count=count)
    if (lengths < _HEADER_SIZE).any():
        index = int(np.argmax(lengths < _HEADER_SIZE))
        what = f"{lengths[index]} bytes, expected at least the 4-byte CDR header"
        raise BagError(_where(ros_type, index, what))
    buffer = np.frombuffer(b"".join(raws), dtype=np.uint8)
    starts = np.zeros(count, dtype=np.int64)
    np.cumsum(lengths[:-1], out=starts[1:])

    # Big-endian (and malformed) headers go to rosbags, which decodes or rejects them.
    little = (buffer[starts] == _LITTLE_ENDIAN_HEADER[0]) & (
        buffer[starts + 1] == _LITTLE_ENDIAN_HEADER[1]
    )
    fast_mask = little if _all_fixed(leaves) else np.zeros(count, dtype=bool)

    parts: list[tuple[np.ndarray, list[np.ndarray]]] = []
    if fast_mask.any():
        fast = np.flatnonzero(fast_mask)
        parts.extend(_decode_vectorised(ros_type, leaves, raws, buffer, starts, lengths, fast))
    if not fast_mask.all():
        slow = np.flatnonzero(~fast_mask)
        parts.append((slow, _decode_with_rosbags(ros_type, leaves, raws, slow, typestore)))
    return _to_namespace(leaves, _assemble(leaves, count, parts))


@functools.cache
def _default_typestore() -> Typestore:
    """One shared ROS 2 Jazzy typestore: each new one would regenerate rosbags' decoders."""
    return get_typestore(Stores.ROS2_JAZZY)


@functools.lru_cache(maxsize=256)
def _all_fixed(leaves: tuple[_Leaf, ...]) -> bool:
    """Whether flattened leaves have a layout fixed by their string lengths alone."""
    return all(leaf.kind != _OBJECT for leaf in leaves)


# --- message definitions -> leaves and layouts -------------------------------------------------


@functools.lru_cache(maxsize=256)
def _flatten(ros_type: str, typestore: Typestore, prefix: tuple[str, ...] = ()) -> tuple[_Leaf, ...]:
    """Leaves of `ros_type` in wire order; nested messages are expanded, not leaves.

    Reads the plain field definitions: `get_msgdef` would generate rosbags' codecs we never call.
    Cached per (type, typestore): the node decodes a few messages per call, where walking the
    definition again would cost more than the decoding.
    """
    try:
        fields = typestore.fielddefs[ros_type][1]
    except KeyError as err:
        msg = f"unknown message type {ros_type!r}: not in the typestore, register its definition"
        raise BagError(msg) from err
    leaves: list[_Leaf] = []
    for name, (node, detail) in fields:
        path = (*prefix, normalize_fieldname(name))  # rosbags' attribute names
        if node == Nodetype.NAME:
            leaves.extend(_flatten(detail, typestore, path))
        elif node == Nodetype.BASE and (detail[0] in _WIRE_DTYPES or detail[0] == _STRING):
            leaves.append(_Leaf(path, detail[0], 0))
        elif node == Nodetype.ARRAY and _is_numeric(detail[0]):
            leaves.append(_Leaf(path, detail[0][1][0], detail[1]))  # e.g. float64[9] covariance
        else:
            leaves.append(_Leaf(path, _OBJECT, 0))
    return tuple(leaves)


def _is_numeric(desc: tuple[object, object]) -> bool:
    """Whether a field description is a numeric (or bool) primitive."""
    return desc[0] == Nodetype.BASE and desc[1][0] in _WIRE_DTYPES


def _align(position: int | np.ndarray, alignment: int) -> int | np.ndarray:
    """Round a CDR position (relative to the end of the header) up to `alignment` bytes."""
    return (position + alignment - 1) & -alignment


def _past_fixed(position: int | np.ndarray, leaf: _Leaf) -> int | np.ndarray:
    """The CDR position after a fixed-size leaf (a scalar or fixed array) that starts at or after `position`."""
    wire = _WIRE_DTYPES[leaf.kind]
    return _align(position, wire.itemsize) + wire.itemsize * max(leaf.count, 1)


@functools.lru_cache(maxsize=1024)
def _layout(leaves: tuple[_Leaf, ...], string_lengths: tuple[int, ...], itemsize: int) -> _Layout:
    """Offsets of every leaf when the strings have `string_lengths` (each counting its NUL)."""
    names: list[str] = []
    formats: list[object] = []
    offsets: list[int] = []
    fields: dict[int, str | None] = {}
    lengths = iter(string_lengths)
    position = 0
    for index, leaf in enumerate(leaves):
        if leaf.kind == _STRING:
            position = _align(position, 4) + 4  # skip the uint32 length
            length = next(lengths)
            fields[index] = None
            if length > 1:  # the characters, without the NUL terminator
                fields[index] = f"f{index}"
                names.append(f"f{index}")
                formats.append((np.dtype("u1"), (length - 1,)))
                offsets.append(position)
            position += length
        else:
            wire = _WIRE_DTYPES[leaf.kind]
            position = _align(position, wire.itemsize)
            fields[index] = f"f{index}"
            names.append(f"f{index}")
            formats.append((wire, (leaf.count,)) if leaf.count else wire)
            offsets.append(position)
            position += wire.itemsize * max(leaf.count, 1)
    dtype = np.dtype({
        "names": names,
        "formats": formats,
        "offsets": [_HEADER_SIZE + offset for offset in offsets],
        "itemsize": max(itemsize, _HEADER_SIZE + position),  # a short group fails _check_size
    })
    return _Layout(dtype, _HEADER_SIZE + position, fields)


# --- vectorised path ---------------------------------------------------------------------------


def _decode_vectorised(
    ros_type: str,
    leaves: Sequence[_Leaf],
    raws: Sequence[bytes | memoryview],
    buffer: np.ndarray,
    starts: np.ndarray,
    lengths: np.ndarray,
    index: np.ndarray,
) -> Iterator[tuple[np.ndarray, list[np.ndarray]]]:
    """Decode the little-endian messages at `index`, one frombuffer per layout group."""
    string_lengths = _string_lengths(ros_type, leaves, buffer, starts[index], lengths[index], index)
    keys = np.column_stack([lengths[index], *string_lengths])  # (n, 1 + strings)
    if (keys == keys[0]).all():
        groups = [(keys[0], np.arange(len(index)))]
    else:
        unique, inverse = np.unique(keys, axis=0, return_inverse=True)
        order = np.argsort(inverse.reshape(-1), kind="stable")
        splits = np.cumsum(np.bincount(inverse.reshape(-1), minlength=len(unique)))[:-1]
        groups = list(zip(unique, np.split(order, splits)))
    for key, members in groups:
        group_index = index[members]
        layout = _layout(tuple(leaves), tuple(int(length) for length in key[1:]), int(key[0]))
        _check_size(ros_type, int(key[0]), layout.size, int(group_index[0]))
        records = _records(raws, buffer, starts, group_index, layout.dtype)
        yield group_index, _read_records(ros_type, leaves, layout, records, group_index)


def _string_lengths(
    ros_type: str,
    leaves: Sequence[_Leaf],
    buffer: np.ndarray,
    starts: np.ndarray,
    lengths: np.ndarray,
    index: np.ndarray,
) -> list[np.ndarray]:
    """Length (NUL included) of every string of every message, checked like rosbags does.

    Each string moves everything after it, so the walk carries one position per message once
    the first string has been passed.
    """
    payload = lengths - _HEADER_SIZE
    body = starts + _HEADER_SIZE
    position: int | np.ndarray = 0
    found: list[np.ndarray] = []
    for leaf in leaves[: _last_string(tuple(leaves)) + 1]:
        if leaf.kind != _STRING:
            position = _past_fixed(position, leaf)
            continue
        name = ".".join(leaf.path)
        position = _align(position, 4)
        what = f"truncated before the length of {name!r}"
        _require(ros_type, index, payload >= position + 4, what)
        at = body + position
        length = (
            buffer[at].astype(np.int64)
            | buffer[at + 1].astype(np.int64) << 8
            | buffer[at + 2].astype(np.int64) << 16
            | buffer[at + 3].astype(np.int64) << 24
        )
        what = f"string {name!r} has length 0, expected >= 1 (its NUL included)"
        _require(ros_type, index, length >= 1, what)
        end = position + 4 + length
        _require(ros_type, index, payload >= end, f"truncated inside string {name!r}")
        terminated = buffer[body + end - 1] == 0
        _require(ros_type, index, terminated, f"string {name!r} lacks its NUL terminator")
        found.append(length)
        position = end
    return found


def _decode_small(ros_type: str, leaves: tuple[_Leaf, ...],
                  raws: Sequence[bytes | memoryview]) -> SimpleNamespace | None:
    """decode_many of a few messages of a fixed-layout type: each message's strings walked in Python with the checks
    and messages of _string_lengths, its layout group found in a dict; then the same _layout, _check_size and
    _read_records as the vectorised path. None when a message is not little-endian CDR (decode_many's general path
    then decodes or rejects the batch as always)."""
    groups: dict[tuple[int, ...], list[int]] = {}
    for index, raw in enumerate(raws):
        if len(raw) < _HEADER_SIZE:
            raise BagError(_where(ros_type, index, f"{len(raw)} bytes, expected at least the 4-byte CDR header"))
        if (raw[0], raw[1]) != _LITTLE_ENDIAN_HEADER:
            return None
        key = (len(raw), *_message_string_lengths(ros_type, leaves, raw, index))
        groups.setdefault(key, []).append(index)
    parts: list[tuple[np.ndarray, list[np.ndarray]]] = []
    for key, members in groups.items():
        layout = _layout(leaves, key[1:], key[0])
        _check_size(ros_type, key[0], layout.size, members[0])
        joined = raws[members[0]] if len(members) == 1 else b"".join([raws[i] for i in members])
        records = np.frombuffer(joined, dtype=layout.dtype, count=len(members))
        group_index = np.array(members, dtype=np.int64)
        parts.append((group_index, _read_records(ros_type, leaves, layout, records, group_index)))
    return _to_namespace(leaves, _assemble(leaves, len(raws), parts))


def _message_string_lengths(ros_type: str, leaves: Sequence[_Leaf], raw: bytes | memoryview, index: int) -> list[int]:
    """_string_lengths for one message (its position `index` in the batch), in Python integers."""
    return [length for length, _, _ in _message_strings(ros_type, leaves, raw, index)]


def _message_strings(ros_type: str, leaves: Sequence[_Leaf], raw: bytes | memoryview, index: int
                     ) -> list[tuple[int, int, int]]:
    """(length counting the NUL, offset of its uint32 length field, end offset) of each string of one message, the
    offsets from the message's first byte; BagError as _string_lengths."""
    payload = len(raw) - _HEADER_SIZE
    position = 0
    found: list[tuple[int, int, int]] = []
    for leaf in leaves[: _last_string(tuple(leaves)) + 1]:
        if leaf.kind != _STRING:
            position = _past_fixed(position, leaf)
            continue
        name = ".".join(leaf.path)
        position = _align(position, 4)
        if payload < position + 4:
            raise BagError(_where(ros_type, index, f"truncated before the length of {name!r}"))
        at = _HEADER_SIZE + position
        length = int.from_bytes(raw[at: at + 4], "little")
        if length < 1:
            raise BagError(_where(ros_type, index, f"string {name!r} has length 0, expected >= 1 (its NUL included)"))
        end = position + 4 + length
        if payload < end:
            raise BagError(_where(ros_type, index, f"truncated inside string {name!r}"))
        if raw[_HEADER_SIZE + end - 1] != 0:
            raise BagError(_where(ros_type, index, f"string {name!r} lacks its NUL terminator"))
        found.append((length, at, _HEADER_SIZE + end))
        position = end
    return found


@functools.lru_cache(maxsize=256)
def _last_string(leaves: tuple[_Leaf, ...]) -> int:
    """Index of the last string leaf (-1: none)."""
    return max((i for i, leaf in enumerate(leaves) if leaf.kind == _STRING), default=-1)


def _require(ros_type: str, index: np.ndarray, valid: np.ndarray, what: str) -> None:
    """Raise BagError for the first message where `valid` is False."""
    if not valid.all():
        raise BagError(_where(ros_type, int(index[int(np.argmin(valid))]), what))


def _check_size(ros_type: str, length: int, needed: int, index: int) -> None:
    """Reject messages shorter than their layout, or longer than rosbags tolerates."""
    if length < needed:
        raise BagError(_where(ros_type, index, f"truncated: {length} bytes, expected {needed}"))
    if length > needed + _MAX_TRAILING_PADDING:
        msg = f"{length} bytes, expected {needed} (+ at most {_MAX_TRAILING_PADDING} padding)"
        raise BagError(_where(ros_type, index, msg))


def _records(
    raws: Sequence[bytes | memoryview],
    buffer: np.ndarray,
    starts: np.ndarray,
    group_index: np.ndarray,
    dtype: np.dtype,
) -> np.ndarray:
    """The group's messages as one structured array; zero-copy when they are adjacent."""
    first, count = int(group_index[0]), len(group_index)
    if int(group_index[-1]) - first + 1 == count:
        return np.frombuffer(buffer, dtype=dtype, count=count, offset=int(starts[first]))
    joined = b"".join([raws[i] for i in group_index.tolist()])
    return np.frombuffer(joined, dtype=dtype, count=count)


def _read_records(
    ros_type: str,
    leaves: Sequence[_Leaf],
    layout: _Layout,
    records: np.ndarray,
    group_index: np.ndarray,
) -> list[np.ndarray]:
    """One owned, native-endian array per leaf from a structured view over the group."""
    return [_read_leaf(ros_type, leaf, layout.fields[index], records, group_index) for index, leaf in enumerate(leaves)]


def _read_leaf(ros_type: str, leaf: _Leaf, field: str | None, records: np.ndarray, group_index: np.ndarray
               ) -> np.ndarray:
    """One leaf's owned, native-endian array from the records' `field`."""
    if leaf.kind == _STRING:
        return _decode_strings(ros_type, leaf, records[field] if field else None, group_index)
    if leaf.kind == "bool":
        return records[field] != 0  # rosbags: any non-zero byte is True
    return records[field].astype(_native(leaf.kind))  # owned, contiguous


def _decode_strings(
    ros_type: str,
    leaf: _Leaf,
    chars: np.ndarray | None,
    group_index: np.ndarray,
) -> np.ndarray:
    """UTF-8 decode a (n, length) byte block; a topic has few distinct frame ids, so dedupe."""
    count = len(group_index)
    if chars is None:
        return np.full(count, "", dtype=object)
    if (chars == chars[0]).all():
        rows, inverse = chars[:1], np.zeros(count, dtype=np.intp)
    else:
        rows, inverse = np.unique(chars, axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
    texts = []
    for row_number, row in enumerate(rows):
        try:
            texts.append(row.tobytes().decode())
        except UnicodeDecodeError as err:
            first = int(group_index[int(np.argmax(inverse == row_number))])
            name = ".".join(leaf.path)
            what = f"string {name!r} is not valid UTF-8"
            raise BagError(_where(ros_type, first, what)) from err
    return _object_array(texts)[inverse]


# --- rosbags path and assembly -----------------------------------------------------------------


def _decode_with_rosbags(
    ros_type: str,
    leaves: Sequence[_Leaf],
    raws: Sequence[bytes | memoryview],
    index: np.ndarray,
    typestore: Typestore,
) -> list[np.ndarray]:
    """Deserialise message by message (big endian, or no fixed layout) into the same leaves."""
    messages = []
    for i in index.tolist():
        try:
            messages.append(typestore.deserialize_cdr(raws[i], ros_type))
        except SerdeError as err:
            raise BagError(_where(ros_type, i, str(err))) from err
    columns = []
    for leaf in leaves:
        values = list(map(operator.attrgetter(".".join(leaf.path)), messages))
        if leaf.kind in (_STRING, _OBJECT):
            columns.append(_object_array(values))
        elif leaf.count:
            columns.append(np.stack(values).astype(_native(leaf.kind)))
        else:
            columns.append(np.array(values, dtype=_native(leaf.kind)))
    return columns


def _assemble(
    leaves: Sequence[_Leaf],
    count: int,
    parts: Sequence[tuple[np.ndarray, list[np.ndarray]]],
) -> list[np.ndarray]:
    """Scatter the parts' columns back into input order (no copy for a single in-order part)."""
    if len(parts) == 1:
        return parts[0][1]
    columns = []
    for number, leaf in enumerate(leaves):
        column = _empty(leaf, count)
        for index, part_columns in parts:
            column[index] = part_columns[number]
        columns.append(column)
    return columns


def _native(kind: str) -> np.dtype:
    """Output dtype of a primitive: native byte order, bool as np.bool_."""
    return np.dtype(bool) if kind == "bool" else _WIRE_DTYPES[kind].newbyteorder("=")


def _empty(leaf: _Leaf, count: int = 0) -> np.ndarray:
    """An uninitialised column for `count` messages."""
    if leaf.kind in (_STRING, _OBJECT):
        return np.empty(count, dtype=object)
    return np.empty((count, leaf.count) if leaf.count else (count,), dtype=_native(leaf.kind))


def _object_array(values: Sequence[object]) -> np.ndarray:
    """A 1-D object array even when the values are themselves sequences."""
    array = np.empty(len(values), dtype=object)
    for i, value in enumerate(values):
        array[i] = value
    return array


def _to_namespace(leaves: Sequence[_Leaf], columns: Sequence[np.ndarray]) -> SimpleNamespace:
    """Nest the columns by field path: ('header', 'stamp', 'sec') -> out.header.stamp.sec."""
    root = SimpleNamespace()
    for leaf, column in zip(leaves, columns, strict=True):
        node = root
        for name in leaf.path[:-1]:
            if not hasattr(node, name):
                setattr(node, name, SimpleNamespace())
            node = getattr(node, name)
        setattr(node, leaf.path[-1], column)
    return root


def _where(ros_type: str, index: int, what: str) -> str:
    """Error message naming the type and the message's position in the batch."""
    return f"cannot decode {ros_type} message {index} of the batch: {what}"


# --- decoding with an adapter, one bad message at a time --------------------------------------


class DecodedBatch(NamedTuple):
    """What `decode_values` made of N messages: the decodable ones in order, and why the others were not."""

    index: np.ndarray  # (M,) positions in the batch of the decoded messages, increasing
    stamps: np.ndarray | None  # (M,) int64 header stamps (ns); None for a header-less type
    values: np.ndarray  # (M, k) float64, the adapter's fields (SI, marine frames)
    columns: SimpleNamespace | None  # the decoded fields of those M messages (None: decoded one by one)
    errors: list[tuple[int, str]]  # (position, reason) of every message that could not be decoded


def decode_values(
    adapter: Any,
    raws: Sequence[bytes | memoryview],
    typestore: Typestore | None = None,
    deserialize: Callable[[bytes | memoryview], Any] | None = None,
) -> DecodedBatch:
    """N CDR messages of `adapter.ros_type` -> the adapter's values, decoded in bulk (`decode_many`).

    A batch with an undecodable message is decoded again one message at a time so that only that
    message is lost (its reason in `errors`). Types without a fixed layout (sensor_msgs/JointState)
    are decoded one by one with `deserialize(raw) -> message` (default: rosbags).
    """
    typestore = typestore or _default_typestore()
    ros_type = adapter.ros_type
    width = len(adapter.fields)
    if not raws:
        return DecodedBatch(np.zeros(0, dtype=np.int64), None, np.zeros((0, width)), None, [])
    if not has_fast_layout(ros_type, typestore):
        return _decode_one_by_one(adapter, raws, deserialize
                                  or functools.partial(_rosbags_message, typestore, ros_type))
    try:
        return _decode_values_in_bulk(adapter, raws, typestore, np.arange(len(raws)))
    except (AdapterError, BagError, ValueError, ArithmeticError):
        pass
    good: list[int] = []
    errors: list[tuple[int, str]] = []
    for i, raw in enumerate(raws):
        try:
            _decode_values_in_bulk(adapter, [raw], typestore, np.array([i]))
        except (AdapterError, BagError, ValueError, ArithmeticError) as err:
            errors.append((i, str(err).replace("message 0 of the batch: ", "message: ")))
        else:
            good.append(i)
    if not good:
        return DecodedBatch(np.zeros(0, dtype=np.int64), None, np.zeros((0, width)), None, errors)
    batch = _decode_values_in_bulk(adapter, [raws[i] for i in good], typestore, np.array(good))
    return batch._replace(errors=errors)


class _LazyColumns(SimpleNamespace):
    """decode_many's namespace over alike messages whose leaves are converted on first access (then kept as plain
    attributes): an adapter reads 3-8 of an Imu's 14 leaves. A field the type lacks is an AttributeError, as
    in decode_many's namespace."""

    def __init__(self, source: tuple[str, tuple[_Leaf, ...], _Layout, np.ndarray, np.ndarray],
                 children: dict[str, Any]) -> None:
        self.__dict__.update(_source=source, _children=children)  # (SimpleNamespace's own __init__: no fields)

    def __getattr__(self, name: str) -> Any:
        child = self.__dict__["_children"].get(name) if not name.startswith("_") else None
        if child is None:
            raise AttributeError(f"{name!r} is not a field here")
        source = self.__dict__["_source"]
        if isinstance(child, dict):
            value: Any = _LazyColumns(source, child)
        else:
            ros_type, leaves, layout, records, group_index = source
            value = _read_leaf(ros_type, leaves[child], layout.fields[child], records, group_index)
        self.__dict__[name] = value
        return value


@functools.lru_cache(maxsize=256)
def _leaf_tree(leaves: tuple[_Leaf, ...]) -> dict[str, Any]:
    """The leaves nested by field path: name -> the leaf's index, or the dict of an inner message's fields."""
    tree: dict[str, Any] = {}
    for index, leaf in enumerate(leaves):
        node = tree
        for name in leaf.path[:-1]:
            node = node.setdefault(name, {})
        node[leaf.path[-1]] = index
    return tree


def _lean_columns(ros_type: str, raws: Sequence[bytes | memoryview], typestore: Typestore) -> SimpleNamespace | None:
    """decode_many(ros_type, raws) for alike messages, its leaves converted on access (_LazyColumns): every message
    little-endian CDR of one length, every string's length and bytes those of the first message, which decodes
    (its strings walked with _decode_small's checks, within _check_size's limits, valid UTF-8). None otherwise:
    decode_many then decodes the batch, or gives its error."""
    leaves = _flatten(ros_type, typestore)
    if not raws or not _all_fixed(leaves):
        return None
    first = raws[0]
    size = len(first)
    if size < _HEADER_SIZE or (first[0], first[1]) != _LITTLE_ENDIAN_HEADER:
        return None
    try:
        strings = _message_strings(ros_type, leaves, first, 0)
    except BagError:
        return None
    layout = _layout(leaves, tuple(length for length, _, _ in strings), size)
    if not layout.size <= size <= layout.size + _MAX_TRAILING_PADDING:
        return None
    try:
        for _, at, end in strings:
            bytes(first[at + 4:end - 1]).decode("utf-8")
    except UnicodeDecodeError:
        return None
    spans = [(at, end, first[at:end]) for _, at, end in strings]
    for raw in raws[1:]:
        if len(raw) != size or (raw[0], raw[1]) != _LITTLE_ENDIAN_HEADER:
            return None
        for at, end, text in spans:
            if raw[at:end] != text:
                return None
    joined = first if len(raws) == 1 else b"".join(raws)
    records = np.frombuffer(joined, dtype=layout.dtype, count=len(raws))
    return _LazyColumns((ros_type, leaves, layout, records, np.arange(len(raws))), _leaf_tree(leaves))


def _rosbags_message(typestore: Typestore, ros_type: str, raw: bytes | memoryview) -> Any:
    try:
        return typestore.deserialize_cdr(raw, ros_type)
    except SerdeError as err:
        raise BagError(f"cannot decode {ros_type} message: {err}") from err


def _decode_values_in_bulk(adapter: Any, raws: Sequence[bytes | memoryview], typestore: Typestore,
                           index: np.ndarray) -> DecodedBatch:
    columns = _lean_columns(adapter.ros_type, raws, typestore) if len(raws) <= LEAN_BATCH else None
    if columns is None:
        columns = decode_many(adapter.ros_type, raws, typestore)
    stamp, values = adapter.decode(columns)
    table = np.column_stack([np.asarray(v, dtype=np.float64) for v in values]).reshape(len(raws), len(adapter.fields))
    stamps = None if stamp is None else np.asarray(stamp, dtype=np.int64).reshape(len(raws))
    return DecodedBatch(index, stamps, table, columns, [])


def _decode_one_by_one(adapter: Any, raws: Sequence[bytes | memoryview],
                       deserialize: Callable[[bytes | memoryview], Any]) -> DecodedBatch:
    index: list[int] = []
    stamps: list[int | None] = []
    rows: list[tuple[float, ...]] = []
    errors: list[tuple[int, str]] = []
    for i, raw in enumerate(raws):
        try:
            stamp, values = adapter.decode(deserialize(raw))
            row = tuple(float(v) for v in values)
        except (AdapterError, BagError, ValueError, ArithmeticError, TypeError, IndexError) as err:
            errors.append((i, str(err)))
            continue
        index.append(i)
        stamps.append(stamp)
        rows.append(row)
    header_less = not stamps or stamps[0] is None
    return DecodedBatch(np.array(index, dtype=np.int64), None if header_less else np.array(stamps, dtype=np.int64),
                        np.array(rows, dtype=np.float64).reshape(len(rows), len(adapter.fields)), None, errors)


# --- decoding trajectory_msgs/JointTrajectory (the node's plan inputs) -------------------------

JOINT_TRAJECTORY_TYPE = "trajectory_msgs/msg/JointTrajectory"


class JointTrajectoryData(NamedTuple):
    """A decoded trajectory_msgs/JointTrajectory whose points all carry one position per joint."""

    stamp_ns: int  # header.stamp
    frame_id: str
    joint_names: tuple[str, ...]  # (J,)
    time_from_start_ns: np.ndarray  # (P,) int64
    positions: np.ndarray  # (P, J) float64


_UINT32_LE = struct.Struct("<I")


class _Reader:
    """Sequential little-endian CDR reader over one message (after its header); AdapterError on overrun."""

    def __init__(self, raw: bytes | memoryview, what: str) -> None:
        self.data = memoryview(raw)[_HEADER_SIZE:]
        self.position = 0
        self.what = what

    def _take(self, size: int, alignment: int, field: str) -> int:
        start = (self.position + alignment - 1) & -alignment
        if start + size > len(self.data):
            raise AdapterError(f"{self.what}: truncated in {field} ({len(self.data) + _HEADER_SIZE} bytes)")
        self.position = start + size
        return start

    def uint32(self, field: str) -> int:
        start = self._take(4, 4, field)
        return int.from_bytes(self.data[start:start + 4], "little")

    def int32(self, field: str) -> int:
        start = self._take(4, 4, field)
        return int.from_bytes(self.data[start:start + 4], "little", signed=True)

    def time_ns(self, field: str) -> int:
        sec = self.int32(field)
        return sec * NS_PER_S + self.uint32(field)

    def string(self, field: str) -> str:
        length = self.uint32(field)
        if length < 1:
            raise AdapterError(f"{self.what}: {field} has length 0, expected >= 1 (its NUL included)")
        start = self._take(length, 1, field)
        data = bytes(self.data[start:start + length])
        if data[-1] != 0:
            raise AdapterError(f"{self.what}: {field} lacks its NUL terminator")
        try:
            return data[:-1].decode("utf-8")
        except UnicodeDecodeError as err:
            raise AdapterError(f"{self.what}: {field} is not valid UTF-8") from err

    def strings(self, field: str, count: int) -> tuple[str, ...]:
        """`count` strings named field[0], field[1], ...: string() in one loop with local variables (a 128-joint plan
        has 128 names), the same checks and messages."""
        data, size, position, out = self.data, len(self.data), self.position, []
        for j in range(count):
            position = (position + 3) & -4
            if position + 4 > size:
                raise AdapterError(f"{self.what}: truncated in {field}[{j}] ({size + _HEADER_SIZE} bytes)")
            (length,) = _UINT32_LE.unpack_from(data, position)
            position += 4
            if length < 1:
                raise AdapterError(f"{self.what}: {field}[{j}] has length 0, expected >= 1 (its NUL included)")
            if position + length > size:
                raise AdapterError(f"{self.what}: truncated in {field}[{j}] ({size + _HEADER_SIZE} bytes)")
            text = bytes(data[position:position + length])
            position += length
            if text[-1] != 0:
                raise AdapterError(f"{self.what}: {field}[{j}] lacks its NUL terminator")
            try:
                out.append(text[:-1].decode("utf-8"))
            except UnicodeDecodeError as err:
                raise AdapterError(f"{self.what}: {field}[{j}] is not valid UTF-8") from err
            self.position = position
        return tuple(out)

    def float64s(self, field: str, limit: int) -> np.ndarray | int:
        """A sequence<float64>: its values (offset into data returned as a view-free copy)."""
        count = self.uint32(field)
        if count > limit:
            raise AdapterError(f"{self.what}: {field} has {count} elements, more than the {limit} allowed")
        if count == 0:
            return np.zeros(0)
        start = self._take(8 * count, 8, field)
        return np.frombuffer(self.data, dtype="<f8", count=count, offset=start)


def decode_joint_trajectory(raw: bytes | memoryview, max_joints: int = 1024,
                            max_points: int = 100_000) -> JointTrajectoryData:
    """One CDR trajectory_msgs/JointTrajectory -> stamp, joints and (P, J) positions (AdapterError says what is wrong).

    Every point must carry exactly one position per joint; velocities, accelerations and effort are
    read past (any length) and not returned. Bytes after the last point are ignored.

    Points 0 and 1 are walked field by field; when point 1's size is a multiple of 8 bytes (the alignment of
    float64), every later point with point 1's sequence lengths has its layout at point 1's offsets plus a whole
    stride, so their lengths are checked and their positions and time_from_start read with numpy views at those
    offsets (`_later_points`); a plan that is not so regular, or is truncated, is walked point by point
    (`_walk_points`), which gives its error. test_plans.py proves both equal to rclpy's deserialisation and to each
    other, on malformed bytes too.
    """
    reader, stamp_ns, frame_id, names, count = _trajectory_head(raw, max_joints, max_points)
    joints = len(names)
    times = np.empty(count, dtype=np.int64)
    positions = np.empty((count, joints), dtype=np.float64)
    first = min(count, 2)
    lengths = _walk_points(reader, joints, max_joints, times, positions, 0, first)
    if count > 2 and _later_points(reader, lengths, times, positions):
        return JointTrajectoryData(stamp_ns, frame_id, names, times, positions)
    _walk_points(reader, joints, max_joints, times, positions, first, count)
    return JointTrajectoryData(stamp_ns, frame_id, names, times, positions)


def decode_joint_trajectory_walk(raw: bytes | memoryview, max_joints: int = 1024, max_points: int = 100_000
                                 ) -> JointTrajectoryData:
    """decode_joint_trajectory walking every name and point field by field (the former decoder): the reference
    its names loop and numpy reading of the later points are tested and benchmarked against."""
    reader, stamp_ns, frame_id, names, count = _trajectory_head(raw, max_joints, max_points, walk=True)
    times = np.empty(count, dtype=np.int64)
    positions = np.empty((count, len(names)), dtype=np.float64)
    _walk_points(reader, len(names), max_joints, times, positions, 0, count)
    return JointTrajectoryData(stamp_ns, frame_id, names, times, positions)


def _trajectory_head(raw: bytes | memoryview, max_joints: int, max_points: int, walk: bool = False
                     ) -> tuple[_Reader, int, str, tuple[str, ...], int]:
    """The reader after the points' count, with the header, the joint names (walk: one string() call each, as
    the former decoder did) and the count of points."""
    what = JOINT_TRAJECTORY_TYPE
    if len(raw) < _HEADER_SIZE or bytes(raw[:2]) != bytes(_LITTLE_ENDIAN_HEADER):
        raise AdapterError(f"{what}: not a little-endian CDR message")
    reader = _Reader(raw, what)
    stamp_ns = reader.time_ns("header.stamp")
    frame_id = reader.string("header.frame_id")
    joints = reader.uint32("joint_names")
    if joints > max_joints:
        raise AdapterError(f"{what}: {joints} joint names, more than the {max_joints} allowed")
    if walk:
        names = tuple(reader.string(f"joint_names[{j}]") for j in range(joints))
    else:
        names = reader.strings("joint_names", joints)
    count = reader.uint32("points")
    if count > max_points:
        raise AdapterError(f"{what}: {count} points, more than the {max_points} allowed")
    return reader, stamp_ns, frame_id, names, count


_POINT_SEQUENCES = ("positions", "velocities", "accelerations", "effort")  # JointTrajectoryPoint's float64 sequences


def _walk_points(reader: _Reader, joints: int, max_joints: int, times: np.ndarray, positions: np.ndarray,
                 start: int, end: int) -> tuple[int, ...]:
    """Points start..end-1 field by field into times (P,) and positions (P, J); the sequence lengths of the last."""
    lengths: tuple[int, ...] = ()
    for k in range(start, end):
        values = reader.float64s(f"points[{k}].positions", max_joints)
        if len(values) != joints:
            raise AdapterError(f"{reader.what}: points[{k}] has {len(values)} positions for {joints} joint names")
        positions[k] = values
        lengths = (joints, *(len(reader.float64s(f"points[{k}].{name}", max_joints)) for name in _POINT_SEQUENCES[1:]))
        times[k] = reader.time_ns(f"points[{k}].time_from_start")
    return lengths


def _point_offsets(start: int, lengths: Sequence[int]) -> tuple[list[int], int, int, int]:
    """A JointTrajectoryPoint at body offset `start` with these sequence lengths (positions, velocities,
    accelerations, effort): (offsets of the four lengths, of the positions' first value, of time_from_start, end)."""
    position, counts, values = start, [], start
    for index, length in enumerate(lengths):
        position = _align(position, 4)
        counts.append(position)
        position += 4
        if length:
            position = _align(position, 8)
            if index == 0:
                values = position
            position += 8 * length
    time_at = _align(position, 4)
    return counts, values, time_at, time_at + 8


def _later_points(reader: _Reader, lengths: tuple[int, ...], times: np.ndarray, positions: np.ndarray) -> bool:
    """Points 2.. read with numpy at point 1's offsets plus k strides (decode_joint_trajectory's docstring); False
    (nothing read, the reader where it was) when point 1's size is not a multiple of 8, a later point's sequence
    lengths differ from point 1's or the message is too short for them all: the caller walks them."""
    count = len(times)
    start = reader.position
    counts_at, values_at, time_at, end = _point_offsets(start, lengths)
    stride = end - start
    # point 1 (index 1) ended at `start`; the same layout holds from there when the stride keeps the 8-byte phase
    if stride % 8 or start + (count - 2) * stride > len(reader.data):
        return False
    later = count - 2  # points 2 .. count-1
    data = reader.data
    for offset, length in zip(counts_at, lengths):
        found = np.ndarray((later,), dtype="<u4", buffer=data, offset=offset, strides=(stride,))
        if (found != length).any():
            return False
    joints = lengths[0]
    if joints:
        positions[2:] = np.ndarray((later, joints), dtype="<f8", buffer=data, offset=values_at, strides=(stride, 8))
    sec = np.ndarray((later,), dtype="<i4", buffer=data, offset=time_at, strides=(stride,))
    nanosec = np.ndarray((later,), dtype="<u4", buffer=data, offset=time_at + 4, strides=(stride,))
    times[2:] = sec.astype(np.int64) * NS_PER_S + nanosec
    reader.position = start + later * stride
    return True
