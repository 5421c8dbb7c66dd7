"""Messages per second: rosbags' per-message deserialize_cdr vs the bulk decoder, side by side.

Run: .venv/bin/python benchmarks/bench_decode.py [--count 200000] [--small]

Part 1 decodes in-memory CDR for every supported type. Part 2 writes a rosbag2 recording of Imu
messages with rosbags' Writer in a temporary directory and measures end to end, reader included.
Both decoders run in the same process on the same bytes, and the outputs are checked to agree.
--small: only the node's case instead, batches of 1-32 messages: decode_many's small-batch walk
(msg_adapters.cdr.SMALL_BATCH) against the vectorised walk (SMALL_BATCH 0), alternating, median us per call.
"""
from __future__ import annotations

import argparse
import random
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.interfaces import Nodetype
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from msg_adapters.cdr import decode_many, supported_types

from timing import best_seconds  # benchmarks/timing.py (the script folder is on sys.path)

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

IMU = "sensor_msgs/msg/Imu"


def sample_message(
    ros_type: str, typestore: Typestore, rng: random.Random, frame_id: str | None
) -> object:
    """A message with random numbers; strings are `frame_id`, or random of length 0..20 if None."""
    msgdef = typestore.get_msgdef(ros_type)
    values = {}
    for name, (node, detail) in msgdef.fields:
        if node == Nodetype.NAME:
            values[name] = sample_message(detail, typestore, rng, frame_id)
        elif node == Nodetype.ARRAY:
            numbers = [rng.gauss(0, 1) for _ in range(detail[1])]
            values[name] = np.array(numbers, dtype=detail[0][1][0])
        elif detail[0] == "string":
            values[name] = frame_id if frame_id is not None else "f" * rng.randint(0, 20)
        elif detail[0].startswith("float"):
            values[name] = rng.gauss(0, 100)
        else:
            values[name] = rng.randint(0, 100)
    return msgdef.cls(**values)


def sample_raws(
    ros_type: str, typestore: Typestore, count: int, frame_id: str | None
) -> list[bytes]:
    """`count` serialised messages: 1000 distinct ones repeated (serialising is not measured)."""
    rng = random.Random(ros_type)
    distinct = [
        bytes(typestore.serialize_cdr(sample_message(ros_type, typestore, rng, frame_id), ros_type))
        for _ in range(min(count, 1000))
    ]
    return [distinct[i % len(distinct)] for i in range(count)]


def rosbags_decode(raws: list[bytes], ros_type: str, typestore: Typestore) -> list[object]:
    return [typestore.deserialize_cdr(raw, ros_type) for raw in raws]


def agree(raws: list[bytes], ros_type: str, typestore: Typestore) -> bool:
    """Spot check on the first message's stamp: the tests compare every field."""
    fast = decode_many(ros_type, raws[:1000], typestore)
    slow = rosbags_decode(raws[:1000], ros_type, typestore)
    if not hasattr(fast, "header"):
        expected = np.array([message.data for message in slow], dtype=fast.data.dtype)
        return bool(np.array_equal(fast.data, expected))
    return fast.header.stamp.nanosec.tolist() == [m.header.stamp.nanosec for m in slow]


def bench_in_memory(typestore: Typestore, count: int, repeats: int) -> None:
    print(f"in-memory CDR, {count} messages per type (best of {repeats} for decode_many)")
    print(f'{"type":48s} {"rosbags msg/s":>14s} {"decode_many msg/s":>18s} {"speed-up":>9s}  agree')
    cases = [(ros_type, "base_link") for ros_type in supported_types()]
    cases.append((IMU, None))  # every message a different frame_id length: many layout groups
    for ros_type, frame_id in cases:
        raws = sample_raws(ros_type, typestore, count, frame_id)
        slow = best_seconds(lambda: rosbags_decode(raws, ros_type, typestore), 1)
        fast = best_seconds(lambda: decode_many(ros_type, raws, typestore), repeats)
        label = ros_type if frame_id is not None else f"{ros_type} (mixed frame_id lengths)"
        print(
            f"{label:48s} {count / slow:14,.0f} {count / fast:18,.0f} {slow / fast:8.1f}x  "
            f"{agree(raws, ros_type, typestore)}"
        )


def write_bag(path: Path, raws: list[bytes], storage: StoragePlugin, typestore: Typestore) -> None:
    with Writer(path, version=9, storage_plugin=storage) as writer:
        connection = writer.add_connection("/imu/data", IMU, typestore=typestore)
        for number, raw in enumerate(raws):
            writer.write(connection, 1_700_000_000_000_000_000 + number * 10_000_000, raw)


def read_raws(path: Path, typestore: Typestore) -> list[bytes]:
    with AnyReader([path], default_typestore=typestore) as reader:
        return [raw for _, _, raw in reader.messages()]


def bench_end_to_end(typestore: Typestore, count: int, repeats: int) -> None:
    print(f"\nend to end: rosbag2 file with {count} {IMU}, AnyReader included (best of {repeats})")
    print(
        f'{"storage":8s} {"read only msg/s":>16s} {"read+rosbags msg/s":>19s} '
        f'{"read+decode_many msg/s":>23s}'
    )
    raws = sample_raws(IMU, typestore, count, "imu_link")
    for storage in (StoragePlugin.SQLITE3, StoragePlugin.MCAP):
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "bag"
            write_bag(path, raws, storage, typestore)
            read = best_seconds(lambda: read_raws(path, typestore), repeats)  # also warms the cache
            slow = best_seconds(
                lambda: rosbags_decode(read_raws(path, typestore), IMU, typestore), 1
            )
            fast = best_seconds(
                lambda: decode_many(IMU, read_raws(path, typestore), typestore), repeats
            )
        print(
            f"{storage.name.lower():8s} {count / read:16,.0f} {count / slow:19,.0f} "
            f"{count / fast:23,.0f}"
        )


def bench_small(typestore: Typestore, repeats: int) -> None:
    import os
    import time

    from msg_adapters import cdr

    print(f"small batches (the node's per-cycle input), median of {repeats} alternating calls, us per call; "
          f"load average {os.getloadavg()[0]:.2f}")
    print(f'{"type":36s} {"n":>3s} {"small walk":>11s} {"vectorised":>11s}')
    for ros_type in ("sensor_msgs/msg/Imu", "geometry_msgs/msg/TwistStamped", "std_msgs/msg/Float64",
                     "sensor_msgs/msg/NavSatFix"):
        raws = sample_raws(ros_type, typestore, 32, "base_link")
        for n in (1, 2, 4, 8, 16, 32):
            batch = raws[:n]
            times: dict[int, list[float]] = {cdr.SMALL_BATCH: [], 0: []}
            for _ in range(repeats):
                for limit in times:
                    cdr.SMALL_BATCH, start = limit, time.perf_counter()
                    decode_many(ros_type, batch, typestore)
                    times[limit].append(time.perf_counter() - start)
            small, vectorised = (1e6 * float(np.median(t)) for t in times.values())
            cdr.SMALL_BATCH = max(times)
            print(f"{ros_type:36s} {n:3d} {small:11.1f} {vectorised:11.1f}" + ("" if n <= max(times) else
                                                                              "   (above SMALL_BATCH: both vectorised)"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=200_000, help="messages per measurement")
    parser.add_argument("--repeats", type=int, default=3, help="runs of decode_many, best kept")
    parser.add_argument("--small", action="store_true", help="the node's small batches only (1-32 messages)")
    args = parser.parse_args()
    typestore = get_typestore(Stores.ROS2_JAZZY)
    if args.small:
        bench_small(typestore, max(args.repeats, 2000))
        return
    bench_in_memory(typestore, args.count, args.repeats)
    bench_end_to_end(typestore, args.count, args.repeats)


if __name__ == "__main__":
    main()
