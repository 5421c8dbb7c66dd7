"""Serialized ROS 2 CDR written with numpy: fixed layouts laid out once, filled per message.

A message whose sequence lengths and strings are known (a Path of H poses in frame "odom") has a
fixed byte layout: `CdrWriter` lays it out once (constants: lengths, strings, zero padding) and
records where each numeric field goes (`slot`); `CdrLayout.fill` then writes a message as one
template copy plus one strided write per run of equally spaced occurrences of a slot.

Wire format (OMG XCDR1, little endian, as ROS 2 writes it; msg_adapters.cdr reads it): a 4-byte
encapsulation header `00 01 00 00`; a primitive is aligned to its size relative to the first byte
after the header; a string is a uint32 length counting its NUL, the UTF-8 bytes and the NUL; a
sequence is a uint32 count then its elements (no alignment when empty). Padding bytes are zero
(rclpy's `serialize_message` leaves them uninitialised, and may append unused bytes after the
content when a message holds empty float64 sequences; DDS sends the content only).
"""
from __future__ import annotations

import threading
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from usv_predictor.errors import AdapterError
from usv_predictor.records import NS_PER_S

CDR_LE_HEADER = bytes((0, 1, 0, 0))  # encapsulation: CDR, little endian, no options
_UINT32 = np.dtype("<u4")


class _Run(NamedTuple):
    """Occurrences of a slot at equal spacing: a strided view writes them all at once."""

    offset: int  # byte offset of the first occurrence in the message (header included)
    stride: int  # bytes between occurrences
    count: int  # occurrences
    first: int  # index of the first occurrence among the slot's


class CdrLayout:
    """A laid-out message: constant bytes (header included) and where each numeric slot goes.

    `fill` writes into a buffer kept with the layout (laid out from the template once; every fill writes every
    occurrence of every slot, so the constant bytes are never touched again) and returns it as `bytes`: one copy
    per message. A fresh template copy per message could cost four times the copy itself: an 800 kB answer to 64
    candidate plans, when the allocator has returned the last one's memory to the system, is 200 pages to fault
    in twice (the copy, then `tobytes`): 1.6 ms against 0.4 (benchmarks/bench_decode.py --node-codec, docs/node.md).
    A lock per layout keeps two threads filling one layout apart."""

    def __init__(self, template: np.ndarray, slots: dict[str, tuple[np.dtype, int, int, tuple[_Run, ...]]]) -> None:
        self.template = template  # (size,) uint8: the message with every slot zero (read-only)
        self.template.flags.writeable = False
        self.slots = slots  # name -> (dtype, count, occurrences, runs)
        self._buffer = template.copy()  # (size,) uint8, filled in place
        self._lock = threading.Lock()

    @property
    def size(self) -> int:
        return len(self.template)

    def fill(self, **values: Any) -> bytes:
        """The message bytes. values[name]: (occurrences, count) of the slot, or broadcastable to it.

        Every slot needs its values; values for a slot the layout never reserved (none of a repeated
        field, e.g. the poses of an empty Path) must be empty.
        """
        missing = sorted(set(self.slots) - set(values))
        unused = sorted(name for name in set(values) - set(self.slots) if np.size(values[name]))
        if missing or unused:
            raise AdapterError(f"CDR layout: no values for slots {missing}, values for absent slots {unused}")
        rows = {name: np.broadcast_to(np.asarray(values[name], dtype=dtype), (occurrences, count))
                for name, (dtype, count, occurrences, _) in self.slots.items() if occurrences and count}
        with self._lock:
            for name, block in rows.items():
                dtype, count, _, runs = self.slots[name]
                for run in runs:
                    view = np.ndarray((run.count, count), dtype=dtype, buffer=self._buffer, offset=run.offset,
                                      strides=(run.stride, dtype.itemsize))
                    view[...] = block[run.first:run.first + run.count]
            return self._buffer.tobytes()


class CdrWriter:
    """Lays out one little-endian CDR message: constants are written, numeric slots reserved (module docstring)."""

    def __init__(self) -> None:
        self._body = bytearray()  # after the 4-byte encapsulation header: alignment is relative to it
        self._slots: dict[str, tuple[np.dtype, int, list[int]]] = {}

    @property
    def position(self) -> int:
        return len(self._body)

    def align(self, size: int) -> None:
        self._body.extend(bytes(-len(self._body) % size))

    def primitive(self, dtype: str | np.dtype, value: Any) -> None:
        """A constant primitive (e.g. a sequence length, a status level)."""
        wire = np.dtype(dtype)
        self.align(wire.itemsize)
        self._body.extend(np.asarray(value, dtype=wire).tobytes())

    def uint32(self, value: int) -> None:
        self.primitive(_UINT32, value)

    def string(self, text: str) -> None:
        """A string: uint32 length counting the NUL, the UTF-8 bytes, the NUL."""
        data = text.encode("utf-8") + b"\x00"
        self.uint32(len(data))
        self._body.extend(data)

    def strings(self, texts: Sequence[str]) -> None:
        """A sequence<string>."""
        self.uint32(len(texts))
        for text in texts:
            self.string(text)

    def slot(self, name: str, dtype: str | np.dtype, count: int = 1) -> None:
        """Reserve `count` primitives of `dtype` (a fixed array, or one occurrence of a repeated field)."""
        wire = np.dtype(dtype)
        self.align(wire.itemsize)
        kept = self._slots.setdefault(name, (wire, count, []))
        if kept[0] != wire or kept[1] != count:
            raise AdapterError(f"CDR slot {name!r} reserved as {kept[1]} x {kept[0]}, now as {count} x {wire}")
        kept[2].append(self.position)
        self._body.extend(bytes(wire.itemsize * count))

    def sequence(self, name: str, dtype: str | np.dtype, count: int) -> None:
        """A sequence of `count` primitives filled from slot `name` (no alignment of the elements when empty)."""
        self.uint32(count)
        if count:
            self.slot(name, dtype, count)
        else:
            self._slots.setdefault(name, (np.dtype(dtype), 0, []))  # nothing to fill

    def layout(self) -> CdrLayout:
        template = np.frombuffer(CDR_LE_HEADER + bytes(self._body), dtype=np.uint8).copy()
        return CdrLayout(template, {name: (dtype, count, len(offsets), _runs(offsets))
                                    for name, (dtype, count, offsets) in self._slots.items()})


def _runs(offsets: Sequence[int]) -> tuple[_Run, ...]:
    """Split body offsets into equally spaced runs (a Path's poses: the first, then all others)."""
    runs: list[_Run] = []
    i, n = 0, len(offsets)
    while i < n:
        last, stride = i, 0  # the run is offsets[i..last]
        if i + 1 < n:
            last, stride = i + 1, offsets[i + 1] - offsets[i]
            while last + 1 < n and offsets[last + 1] - offsets[last] == stride:
                last += 1
        runs.append(_Run(offsets[i] + len(CDR_LE_HEADER), stride, last - i + 1, i))
        i = last + 1
    return tuple(runs)


def time_parts(t_ns: Any) -> np.ndarray:
    """builtin_interfaces Time/Duration (sec int32, nanosec uint32) from int ns: (..., 2) int64, floor division."""
    sec, nanosec = np.divmod(np.asarray(t_ns, dtype=np.int64), NS_PER_S)
    return np.stack([sec, nanosec], axis=-1)
