"""Reading and writing rosbag2 recordings: the only code in usv_predictor that touches bags.

Messages are converted through msg_adapters (one TopicSpec = topic + role + ROS type + adapter
options), so bags hold standard ROS messages (REP-103/105) and Signals hold SI values in marine
frames (see msg_adapters.ROLE_FIELDS). Uses the rosbags library with the ROS 2 Jazzy typestore:
no ROS installation is needed.

Writing encodes each Signal column-wise (msg_adapters.columnar_factory) and serialises all rows of
a topic at once with numpy into little-endian CDR (`serialize_columns`, proven byte-equal to
rosbags' serialize_cdr in the tests); topics it cannot lay out (per-row varying strings or
sequence lengths) fall back to one serialize_cdr per row. Messages are written in global stamp
order, log time = header stamp. Compression is zstd, chosen by measurement on a 4-minute,
44k-message manoeuvre (13.9 MB raw): whole-file mode for sqlite3 (2.3 MB; per-message mode only
reaches 6.2 MB because single messages are too short for zstd to find redundancy, and is 3x
slower); chunk ("storage") mode for mcap (2.7 MB vs 2.2 MB whole-file, but it is mcap's native
compression that every mcap tool reads directly).
Bags are written into a temporary directory beside the target and renamed at the end.

Reading decodes each topic in bulk (msg_adapters.cdr.decode_many -> structure of arrays -> one vectorised
adapter.decode); types without a fixed layout (JointState, MultiArrays) go one rosbags message at a time. A topic
may carry several roles (both thrusters in one Float64MultiArray, JointState or Wrench): its messages are decoded
once and each role's adapter reads its part (read_signals); writing encodes the roles into one message per stamp
(msg_adapters.encode_shared).
"""
from __future__ import annotations

import os
import shutil
import sqlite3
import struct
import sys
import tempfile
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path, PurePath
from types import MappingProxyType
from typing import Any

import numpy as np
import yaml
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import Nodetype
from rosbags.rosbag2 import CompressionFormat, CompressionMode, ReaderError, StoragePlugin, Writer, WriterError
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_typestore

from msg_adapters import check_shared, columnar_factory, encode_shared, get_adapter, rosbags_factory
from msg_adapters.cdr import decode_many, has_fast_layout
from usv_predictor.atomic import NO_SPACE_ERRNOS, write_failure
from usv_predictor.bounded import load_yaml, regular_file
from usv_predictor.config import PredictorConfig, input_topics
from usv_predictor.errors import AdapterError, BagError, one_line
from usv_predictor.records import Signal

if sys.version_info >= (3, 14):
    from compression.zstd import ZstdError
else:  # the backport rosbags itself uses before Python 3.14
    from backports.zstd import ZstdError

BAG_VERSION = 9  # rosbag2 metadata version (Jazzy writes 9)
STORAGES = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}
# zstd compression per storage (see the module docstring for the measurements behind the choice)
COMPRESSION_MODES = {"sqlite3": CompressionMode.FILE, "mcap": CompressionMode.STORAGE}

CDR_LE_HEADER = b"\x00\x01\x00\x00"  # encapsulation: CDR, little endian
PRIMITIVE_DTYPES = {
    "bool": "u1", "byte": "i1", "char": "u1", "octet": "u1", "int8": "i1", "uint8": "u1",
    "int16": "<i2", "uint16": "<u2", "int32": "<i4", "uint32": "<u4", "int64": "<i8", "uint64": "<u8",
    "float32": "<f4", "float64": "<f8",
}  # fmt: skip

# Exceptions meaning "this bag cannot be read": storage, metadata, truncated compressed file
_READ_ERRORS = (AnyReaderError, ReaderError, OSError, EOFError, sqlite3.DatabaseError, ZstdError, yaml.YAMLError,
                UnicodeDecodeError)  # a metadata.yaml that is not UTF-8
# ... and "this message cannot be deserialised"
_DESERIALIZE_ERRORS = (SerdeError, struct.error, ValueError, IndexError)


@dataclass(frozen=True)
class TopicSpec:
    """One topic of a bag: its name, what it means (role) and how it is published."""

    topic: str
    role: str
    ros_type: str
    options: Mapping[str, object] = field(default_factory=lambda: MappingProxyType({}))
    frame_id: str = ""

    def adapter(self) -> Any:
        """The msg_adapters adapter; AdapterError is reported as BagError naming the topic."""
        try:
            return get_adapter(self.role, self.ros_type, **dict(self.options))
        except AdapterError as err:
            raise BagError(f"topic {self.topic!r}: {err}") from err


def config_topic_specs(cfg: PredictorConfig, include_ground_truth: bool = False) -> dict[str, TopicSpec]:
    """role -> TopicSpec of the config's input topics, as the tools write them (frame: the entry's, else the base
    frame)."""
    return {t.role: TopicSpec(t.topic, t.role, t.ros_type, t.options, t.frame_id or cfg.base_frame_id)
            for t in input_topics(cfg, include_ground_truth=include_ground_truth)}


def jazzy_typestore() -> Any:
    return get_typestore(Stores.ROS2_JAZZY)


# ------------------------------------------------------------------ bulk CDR serialisation


class _NotColumnar(Exception):
    """The columnar message cannot be laid out with one fixed layout for all rows."""


@dataclass
class _Layout:
    """Byte layout shared by all rows: constant bytes plus typed leaves at fixed offsets."""

    rows: int
    template: bytearray = field(default_factory=bytearray)  # CDR body, without the 4-byte header
    leaves: list[tuple[int, np.dtype, np.ndarray]] = field(default_factory=list)

    def align(self, size: int) -> None:
        self.template.extend(b"\x00" * (-len(self.template) % size))

    def constant(self, data: bytes) -> None:
        self.template.extend(data)

    def leaf(self, dtype: np.dtype, value: Any, count: int | None) -> None:
        """Add `count` (None: a scalar) primitives; value is constant or has one row per message."""
        array = np.asarray(value)
        per_message = () if count is None else (count,)
        width = count or 1
        if array.shape == (self.rows, *per_message):
            rows = array.reshape(self.rows, width)
        elif array.shape == per_message:
            rows = array.reshape(1, width)  # same in every message, broadcast on assignment
        else:
            raise _NotColumnar(f"leaf of shape {array.shape} for {self.rows} rows of {per_message}")
        self.align(dtype.itemsize)
        self.leaves.append((len(self.template), dtype, rows))
        self.template.extend(b"\x00" * (dtype.itemsize * width))

    def string(self, text: Any) -> None:
        if not isinstance(text, str):
            raise _NotColumnar("string field varies per message")
        data = text.encode() + b"\x00"
        self.align(4)
        self.constant(np.uint32(len(data)).tobytes())
        self.constant(data)


def _lay_out(typestore: Any, type_name: str, msg: Any, layout: _Layout) -> None:
    _, fields = typestore.fielddefs[type_name]
    for name, desc in fields:
        _lay_out_field(typestore, desc, getattr(msg, name), layout)


def _lay_out_field(typestore: Any, desc: tuple, value: Any, layout: _Layout) -> None:
    nodetype, detail = desc
    if nodetype == Nodetype.NAME:
        _lay_out(typestore, detail, value, layout)
    elif nodetype == Nodetype.BASE:
        if detail[0] == "string":
            layout.string(value)
        else:
            layout.leaf(np.dtype(PRIMITIVE_DTYPES[detail[0]]), value, None)
    elif nodetype in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        element, bound = detail
        is_primitive = element[0] == Nodetype.BASE and element[1][0] != "string"
        count = np.shape(value)[-1] if is_primitive else len(value)
        if nodetype == Nodetype.SEQUENCE:
            layout.align(4)
            layout.constant(np.uint32(count).tobytes())
        elif count != bound:
            raise _NotColumnar(f"array of {count} elements where {bound} are declared")
        if is_primitive:
            if count:
                layout.leaf(np.dtype(PRIMITIVE_DTYPES[element[1][0]]), value, count)
        else:
            for item in value:
                _lay_out_field(typestore, element, item, layout)
    else:
        raise _NotColumnar(f"unsupported node type {nodetype}")


def serialize_columns(typestore: Any, type_name: str, msg: Any, rows: int) -> list[memoryview]:
    """CDR bytes of `rows` messages given as one columnar message (leaves constant or (rows, ...)).

    Raises _NotColumnar when rows do not share one layout (then serialise row by row).
    """
    layout = _Layout(rows)
    try:
        _lay_out(typestore, type_name, msg, layout)
    except AttributeError as err:
        raise _NotColumnar(str(err)) from err
    size = len(CDR_LE_HEADER) + len(layout.template)
    buffer = np.empty((rows, size), dtype=np.uint8)
    buffer[:] = np.frombuffer(CDR_LE_HEADER + bytes(layout.template), dtype=np.uint8)
    for offset, dtype, value in layout.leaves:
        view = np.ndarray(
            (rows, value.shape[1]), dtype=dtype, buffer=buffer, offset=len(CDR_LE_HEADER) + offset,
            strides=(size, dtype.itemsize),
        )  # fmt: skip
        view[...] = value
    data = memoryview(buffer).cast("B")
    return [data[i * size : (i + 1) * size] for i in range(rows)]


def _row_values(signal: Signal, row: int) -> list[float]:
    return [float(x) for x in signal.values[row]]


def encode_stream(spec: TopicSpec, signal: Signal, typestore: Any) -> list[memoryview | bytes]:
    """CDR bytes of every row of `signal` as `spec.ros_type` messages, via the topic's adapter."""
    return encode_group([(spec, signal)], typestore)


def encode_group(streams: Sequence[tuple[TopicSpec, Signal]], typestore: Any) -> list[memoryview | bytes]:
    """CDR bytes of the messages of one topic: one stream, or several roles sharing the topic (both thrusters in
    one Float64MultiArray, JointState or Wrench: msg_adapters.encode_shared), whose rows must share their stamps."""
    spec = streams[0][0]
    adapters = [s.adapter() for s, _ in streams]
    for (each, signal), adapter in zip(streams, adapters):
        if tuple(signal.fields) != tuple(adapter.fields):
            raise BagError(f"topic {each.topic!r} ({each.role}): signal fields {signal.fields} do not match the "
                           f"role's {adapter.fields}")
    try:
        check_shared(spec.topic, adapters)
    except AdapterError as err:
        raise BagError(str(err)) from err
    t_ns = np.asarray(streams[0][1].t_ns, dtype=np.int64)
    for each, signal in streams[1:]:
        if not np.array_equal(np.asarray(signal.t_ns, dtype=np.int64), t_ns):
            raise BagError(f"topic {spec.topic!r}: roles {streams[0][0].role} and {each.role} share the topic but "
                           "not their sample times (one message carries both)")
    rows = len(t_ns)
    if rows == 0:
        return []
    columns = [list(signal.values.T) for _, signal in streams]
    try:
        message = encode_shared(adapters, t_ns, columns, columnar_factory(), spec.frame_id, spec.topic)
        return serialize_columns(typestore, spec.ros_type, message, rows)
    except _NotColumnar:
        make = rosbags_factory(typestore)
        return [
            typestore.serialize_cdr(
                encode_shared(adapters, int(t_ns[i]), [_row_values(signal, i) for _, signal in streams], make,
                              spec.frame_id, spec.topic),
                spec.ros_type)
            for i in range(rows)
        ]


# ------------------------------------------------------------------ writing


def _group_streams(streams: Sequence[tuple[TopicSpec, Signal]]) -> list[list[tuple[TopicSpec, Signal]]]:
    """The streams per topic, in first-appearance order; a topic may carry several roles (encode_group checks them),
    never one role twice."""
    groups: dict[str, list[tuple[TopicSpec, Signal]]] = {}
    for spec, signal in streams:
        group = groups.setdefault(spec.topic, [])
        if any(other.role == spec.role for other, _ in group):
            raise BagError(f"topic {spec.topic!r} appears twice in the streams to write")
        group.append((spec, signal))
    return list(groups.values())


def _install(built: Path, target: Path) -> None:
    """Move the finished bag directory to `target`, replacing an old one only after success."""
    if target.exists():
        old = built.parent / f"{target.name}.old"
        target.rename(old)
        built.rename(target)
        if old.is_dir():
            shutil.rmtree(old)
        else:
            old.unlink()
    else:
        built.rename(target)


def prepare_outputs(directory: Path, bags: Sequence[Path], overwrite: bool) -> None:
    """Before any work: check the output directory can be made (or is) a writable directory and refuse existing
    bags without overwrite. Nothing is created here: write_bag makes the directory with its first bag, so a run
    that fails before writing one leaves no empty directory behind."""
    directory = Path(directory)
    existing_parent = directory
    while not existing_parent.exists() and existing_parent != existing_parent.parent:
        existing_parent = existing_parent.parent  # the nearest ancestor that exists: the directory is made below it
    if not existing_parent.is_dir():
        raise BagError(f"--output {directory}: cannot create the output directory ({existing_parent} is not a "
                       "directory)")
    if not os.access(existing_parent, os.W_OK | os.X_OK):
        what = "directory is" if existing_parent == directory else f"cannot create it: {existing_parent} is"
        raise BagError(f"--output {directory}: {what} not writable")
    existing = [str(p) for p in bags if Path(p).exists()]
    if existing and not overwrite:
        raise BagError(f"{existing[0]} exists already; use --overwrite to replace it")


URI_SPECIAL = frozenset("#?%")  # what a sqlite `file:` URI reads as a fragment, a query or an escape


@contextmanager
def _plain_sqlite_path(path: Path) -> Iterator[Path]:
    """`path`, or, when its absolute form holds a character a sqlite URI gives a meaning to (URI_SPECIAL), the same
    directory entry reached through a link in a fresh temporary directory whose path holds none of them.

    rosbags opens sqlite storage as `file:<path>` URIs (the writer) and `file:<path>?immutable=1` (the reader), so a
    `#` in `--output out#1` cut the path there: the database went to a file `out` beside the intended folder and
    the bag had none. Through the link, sqlite sees a plain path that leads to the intended place."""
    absolute = Path(os.path.abspath(path))
    if not URI_SPECIAL & set(str(absolute)):
        yield path
        return
    if URI_SPECIAL & set(absolute.name):  # its storage files are named after it: no link avoids that
        raise BagError(f"{path}: a bag's name may not hold {' or '.join(sorted(URI_SPECIAL))} (sqlite would read "
                       "its storage file's path as a URI); rename it")
    links = Path(tempfile.mkdtemp(prefix="usv_predictor_sqlite."))
    try:
        if URI_SPECIAL & set(str(links)):
            raise BagError(f"{path}: its path holds one of {''.join(sorted(URI_SPECIAL))}, which sqlite reads as a "
                           f"URI, and so does the temporary directory {links}")
        os.symlink(absolute.parent, links / "parent")
        yield links / "parent" / absolute.name
    finally:
        shutil.rmtree(links, ignore_errors=True)


def write_bag(
    path: Path,
    streams: Sequence[tuple[TopicSpec, Signal]],
    *,
    storage: str = "sqlite3",
    compress: bool = True,
    metadata: Mapping[str, str] | None = None,
    overwrite: bool = False,
) -> Path:
    """Write `streams` (topic spec, Signal) into a new rosbag2 bag at `path`; returns `path`.

    `metadata` is stored in the bag's custom_data. Atomic: nothing is left at `path` (nor beside
    it) when anything fails; an existing bag is replaced only with overwrite=True.
    """
    path = Path(path)
    if storage not in STORAGES:
        raise BagError(f"{path}: unknown storage {storage!r}; use one of {sorted(STORAGES)}")
    if path.exists() and not overwrite:
        raise BagError(f"{path} exists already; use --overwrite to replace it")
    groups = _group_streams(streams)
    typestore = jazzy_typestore()
    encoded = [encode_group(group, typestore) for group in groups]
    firsts = [group[0] for group in groups]  # the stamps and type of each topic
    stamps = np.concatenate([np.asarray(s.t_ns, dtype=np.int64) for _, s in firsts] or [np.zeros(0, np.int64)])
    topic_index = np.concatenate([np.full(len(s), i) for i, (_, s) in enumerate(firsts)] or [np.zeros(0, int)])
    row_index = np.concatenate([np.arange(len(s)) for _, s in firsts] or [np.zeros(0, int)])
    order = np.argsort(stamps, kind="stable")

    path.parent.mkdir(parents=True, exist_ok=True)
    workdir = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent))
    try:
        built = workdir / path.name
        with _plain_sqlite_path(built) as plain:
            writer = Writer(plain, version=BAG_VERSION, storage_plugin=STORAGES[storage])
            if compress:
                writer.set_compression(COMPRESSION_MODES[storage], CompressionFormat.ZSTD)
            for key, value in (metadata or {}).items():
                writer.set_custom_data(str(key), str(value))
            with writer:
                connections = [writer.add_connection(spec.topic, spec.ros_type, typestore=typestore)
                               for spec, _ in firsts]
                for stamp, topic, row in zip(stamps[order].tolist(), topic_index[order].tolist(),
                                             row_index[order].tolist()):
                    writer.write(connections[topic], stamp, encoded[topic][row])
        _install(built, path)
    except (WriterError, OSError, sqlite3.Error) as err:
        cause = err.__cause__ if isinstance(err, WriterError) and err.__cause__ is not None else err
        raise BagError(f"cannot write bag {path}: {write_failure(cause)}") from err
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    return path


# ------------------------------------------------------------------ reading


STORAGE_FILE_BYTES = 1 << 50  # a storage file is bounded by the disk, not by us (bytes)


def _check_bag_files(path: Path) -> None:
    """Before any reader opens them: the bag's metadata.yaml read within bounds (bounded.load_yaml) and every
    storage file it lists, or a single-file bag, a regular file (a FIFO would block sqlite's open for ever, a
    device never ends); BagError naming the file otherwise."""
    if not path.is_dir():
        regular_file(path, "bag file", BagError, STORAGE_FILE_BYTES)
        return
    metadata = path / "metadata.yaml"
    if not os.path.lexists(metadata):
        return  # the reader names what is missing
    try:
        info = load_yaml(metadata, "rosbag2 metadata", BagError)["rosbag2_bagfile_information"]
        names = [PurePath(str(name)).name for name in info.get("relative_file_paths") or []]
    except BagError as err:
        raise BagError(f"{path}: {err}") from err
    except (KeyError, TypeError, AttributeError) as err:
        raise BagError(f"{path}: cannot read rosbag2 metadata {metadata}: not a rosbag2 metadata file "
                       f"({type(err).__name__}: {one_line(err)})") from err
    for name in names:
        if os.path.lexists(path / name):  # a missing one: the reader names it
            try:
                regular_file(path / name, "storage file", BagError, STORAGE_FILE_BYTES)
            except BagError as err:
                raise BagError(f"{path}: {err}") from err


@contextmanager
def _open_reader(path: Path) -> Iterator[AnyReader]:
    """AnyReader over one bag; unreadable bags become BagError naming the path."""
    if not path.exists():
        raise BagError(f"{path}: no such bag")
    _check_bag_files(path)
    try:
        with _plain_sqlite_path(path) as plain, AnyReader([plain], default_typestore=jazzy_typestore()) as reader:
            yield reader
    except OSError as err:
        if err.errno in NO_SPACE_ERRNOS:  # a compressed bag is decompressed into a temporary file first
            raise BagError(f"{path}: cannot read bag: {write_failure(err)} for its decompressed copy") from err
        raise BagError(f"{path}: cannot read bag ({type(err).__name__}: {one_line(err)})") from err
    except _READ_ERRORS as err:
        raise BagError(f"{path}: cannot read bag ({type(err).__name__}: {one_line(err)})") from err
    except RecursionError as err:  # what rosbags raises on a message definition that contains itself
        raise BagError(f"{path}: cannot read bag: a message definition it carries refers to itself (a type that "
                       "contains itself has no end)") from err


def absolute_topic(name: str) -> str:
    """A topic name resolved in the root namespace, as ROS 2 resolves a relative name of a node in "/" (REP-144):
    `imu/data` -> `/imu/data`; an absolute name stays. The config's names are relative (remappable), while
    `ros2 bag record` writes the resolved, fully qualified ones."""
    return name if name.startswith("/") else "/" + name


def resolve_topic(configured: str, present: Iterable[str]) -> str | None:
    """The bag's name for a configured topic: the same name, else the one that resolves to the same absolute name
    (`imu/data` matches a recorded `/imu/data` and the reverse); None when the bag has neither."""
    names = list(present)
    if configured in names:
        return configured
    wanted = absolute_topic(configured)
    return next((name for name in names if absolute_topic(name) == wanted), None)


def _select_connections(path: Path, reader: AnyReader, spec: TopicSpec) -> list[Any]:
    name = resolve_topic(spec.topic, {c.topic for c in reader.connections})
    connections = [c for c in reader.connections if c.topic == name]
    if not connections:
        present = sorted({c.topic for c in reader.connections})
        raise BagError(f"{path}: no topic {spec.topic!r}; topics present: {present}")
    found = sorted({c.msgtype for c in connections})
    if found != [spec.ros_type]:
        raise BagError(f"{path}: topic {spec.topic!r} has type {', '.join(found)}, expected {spec.ros_type}")
    return connections


def _deserialize_all(path: Path, spec: TopicSpec, reader: AnyReader, raws: list) -> list[Any]:
    """One rosbags object per message: for types the bulk decoder cannot lay out (JointState, MultiArrays)."""
    messages = []
    for raw in raws:
        try:
            messages.append(reader.deserialize(raw, spec.ros_type))
        except _DESERIALIZE_ERRORS as err:
            raise BagError(f"{path}: topic {spec.topic!r}: cannot deserialise a {spec.ros_type}: {err}") from err
    return messages


def _decode_one_by_one(
    path: Path, spec: TopicSpec, adapter: Any, messages: list, log_times: list[int]
) -> tuple[np.ndarray, np.ndarray]:
    """Decode deserialised messages one at a time."""
    stamps: list[int] = []
    rows: list[tuple[float, ...]] = []
    for msg, log_time in zip(messages, log_times):
        try:
            stamp, values = adapter.decode(msg)
        except AdapterError as err:
            raise BagError(f"{path}: topic {spec.topic!r} ({spec.role}): {err}") from err
        stamps.append(log_time if stamp is None else stamp)
        rows.append(values)
    return np.asarray(stamps, dtype=np.int64), np.asarray(rows,
                                                          dtype=np.float64).reshape(len(rows), len(adapter.fields))


def _decode_in_bulk(
    path: Path, spec: TopicSpec, adapter: Any, columns_in: Any, raws: list, log_times: list[int]
) -> tuple[np.ndarray, np.ndarray]:
    """All messages at once: one vectorised adapter.decode of the msg_adapters.cdr structure of arrays."""
    try:
        stamp, columns = adapter.decode(columns_in)
    except (AdapterError, BagError) as err:
        raise BagError(f"{path}: topic {spec.topic!r} ({spec.role}): {err}") from err
    t_ns = np.asarray(log_times, dtype=np.int64) if stamp is None else np.asarray(stamp, dtype=np.int64)
    return t_ns, np.column_stack(columns).reshape(len(raws), len(adapter.fields))


def _decode_topic(
    path: Path, specs: Sequence[TopicSpec], adapters: Sequence[Any], reader: AnyReader, raws: list,
    log_times: list[int]
) -> list[Signal]:
    """Signals of one topic (one per role it carries) from its raw CDR messages, rows sorted by stamp; the messages
    are decoded (bulk or one by one) once, whatever the number of roles."""
    typestore = reader.typestore  # built by AnyReader from the bag's own message definitions
    ros_type = specs[0].ros_type
    bulk = bool(raws) and ros_type in typestore.fielddefs and has_fast_layout(ros_type, typestore)
    if bulk:
        try:
            columns_in = decode_many(ros_type, raws, typestore)
        except BagError as err:
            raise BagError(f"{path}: topic {specs[0].topic!r}: {err}") from err
    else:
        messages = _deserialize_all(path, specs[0], reader, raws)
    signals = []
    for spec, adapter in zip(specs, adapters):
        if bulk:
            t_ns, values = _decode_in_bulk(path, spec, adapter, columns_in, raws, log_times)
        else:
            t_ns, values = _decode_one_by_one(path, spec, adapter, messages, log_times)
        order = np.argsort(t_ns, kind="stable")
        signals.append(Signal(t_ns[order], values[order], adapter.fields))
    return signals


def read_signals(path: Path, topics: Sequence[TopicSpec]) -> list[Signal]:
    """The Signal of each TopicSpec (same order), decoded through their adapters; several specs may name one topic
    (both thrusters in one Float64MultiArray, JointState or Wrench: msg_adapters.check_shared says which can).

    Stamps are the header stamps (log time for header-less types), rows sorted by stamp.
    The bag is only read, never modified.
    """
    path = Path(path)
    adapters = [spec.adapter() for spec in topics]
    by_topic: dict[str, list[int]] = {}
    for k, spec in enumerate(topics):
        by_topic.setdefault(spec.topic, []).append(k)
    for topic, members in by_topic.items():
        if len(members) > 1:
            try:
                check_shared(topic, [adapters[k] for k in members])
            except AdapterError as err:
                raise BagError(f"{path}: {err}") from err
    with _open_reader(path) as reader:
        topic_of = {}
        for topic, members in by_topic.items():
            for connection in _select_connections(path, reader, topics[members[0]]):
                topic_of[connection.id] = topic
        raws: dict[str, list] = {topic: [] for topic in by_topic}
        log_times: dict[str, list[int]] = {topic: [] for topic in by_topic}
        selected = [c for c in reader.connections if c.id in topic_of]
        for connection, log_time, raw in reader.messages(connections=selected):
            raws[topic_of[connection.id]].append(raw)
            log_times[topic_of[connection.id]].append(log_time)
        out: list[Signal | None] = [None] * len(topics)
        for topic, members in by_topic.items():
            decoded = _decode_topic(path, [topics[k] for k in members], [adapters[k] for k in members], reader,
                                    raws[topic], log_times[topic])
            for k, signal in zip(members, decoded):
                out[k] = signal
    return [signal for signal in out if signal is not None]


def read_bag(path: Path, topics: Sequence[TopicSpec]) -> dict[str, Signal]:
    """topic -> Signal of the requested topics (read_signals keyed by topic; a topic carrying several roles needs
    read_signals). The bag is only read, never modified."""
    repeated = sorted({s.topic for s in topics if sum(1 for o in topics if o.topic == s.topic) > 1})
    if repeated:
        raise BagError(f"{path}: topic(s) {repeated} carry several roles: read them with read_signals")
    return {spec.topic: signal for spec, signal in zip(topics, read_signals(path, topics))}


def read_custom_data(path: Path) -> dict[str, str]:
    """The bag's custom_data (metadata.yaml), e.g. how it was made; {} when it has none."""
    metadata_path = Path(path) / "metadata.yaml"
    try:
        info = load_yaml(metadata_path, "rosbag2 metadata", BagError)["rosbag2_bagfile_information"]
        custom = info.get("custom_data") or {}
        if not isinstance(custom, dict):
            raise TypeError(f"custom_data is a {type(custom).__name__}, expected a mapping")
    except BagError as err:
        raise BagError(f"{path}: {err}") from err
    except (KeyError, TypeError, AttributeError) as err:
        raise BagError(f"{path}: cannot read rosbag2 metadata {metadata_path}: {one_line(err)}") from err
    return {str(k): str(v) for k, v in custom.items()}


def _size_on_disk(path: Path) -> int:
    if path.is_file():
        return path.stat().st_size
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def bag_info(path: Path) -> dict:
    """Summary of a bag: topics (type, count, rate Hz, first/last ns), duration, custom_data, size."""
    path = Path(path)
    with _open_reader(path) as reader:
        first: dict[str, int] = {}
        last: dict[str, int] = {}
        counts: dict[str, int] = {}
        types: dict[str, str] = {}
        for connection, log_time, _ in reader.messages():
            topic = connection.topic
            first.setdefault(topic, log_time)
            last[topic] = log_time
            counts[topic] = counts.get(topic, 0) + 1
        for connection in reader.connections:
            types[connection.topic] = connection.msgtype
            counts.setdefault(connection.topic, 0)
        topics = []
        for topic in sorted(types):
            span_s = (last.get(topic, 0) - first.get(topic, 0)) * 1e-9
            topics.append(
                {
                    "topic": topic,
                    "type": types[topic],
                    "count": counts[topic],
                    "rate_hz": (counts[topic] - 1) / span_s if counts[topic] > 1 and span_s > 0 else None,
                    "first_ns": first.get(topic),
                    "last_ns": last.get(topic),
                }
            )
        start = min(first.values(), default=None)
        end = max(last.values(), default=None)
    return {
        "path": str(path),
        "topics": topics,
        "message_count": sum(counts.values()),
        "start_ns": start,
        "end_ns": end,
        "duration_s": (end - start) * 1e-9 if start is not None else 0.0,
        "custom_data": read_custom_data(path) if path.is_dir() else {},
        "size_bytes": _size_on_disk(path),
    }
