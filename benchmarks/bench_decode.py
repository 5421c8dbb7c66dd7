"""Messages per second: rosbags' per-message deserialize_cdr vs the bulk decoder, side by side.

Run: .venv/bin/python benchmarks/bench_decode.py [--count 200000] [--small]

Part 1 decodes in-memory CDR for every supported type. Part 2 writes a rosbag2 recording of Imu
messages with rosbags' Writer in a temporary directory and measures end to end, reader included.
Both decoders run in the same process on the same bytes, and the outputs are checked to agree.
--small: only the node's case instead, batches of 1-32 messages: decode_many's small-batch walk
(msg_adapters.cdr.SMALL_BATCH) against the vectorised walk (SMALL_BATCH 0), alternating, median us per call.
--node-codec: the node's codec work, old and new alternating, p50 / p99 ms, warm and cold (a 32 MB sweep before
each call): one cycle's inputs from a shipped bag (decode_values with LEAN_BATCH 0 / 256), the 64-candidate plan
(decode_joint_trajectory_walk / decode_joint_trajectory), the answer to it and a Path (the encoders as they were
before 2026-11-26, kept here, / msg_adapters.outputs; the answer also each way in its own run of calls, each after
malloc_trim(0): whether the old encoder's fresh 800 kB buffers are new memory to fault in depends on what the
allocator did before, and after a trim they are);
each pair's outputs are checked equal first.
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
                                                                              "   (above SMALL_BATCH: "
                                                                              "both vectorised)"))


NODE_BAG = Path(__file__).resolve().parents[1] / "bags" / "sea_trial" / "turning_circle_stbd_20deg_700rpm"
NODE_BATCH = {"imu": 20, "velocity": 2, "heading": 2, "rudder_angle": 1, "engine_rpm": 1, "gnss": 1}  # one cycle


def node_cycle_batches(typestore: Typestore) -> list[tuple[object, list[bytes]]]:
    """(adapter, raws) of one node cycle at 10 Hz with 200 Hz IMU: NODE_BATCH messages of each input of
    config/predictor.yaml, taken from a shipped bag (recorded bytes, as the node receives them)."""
    import msg_adapters
    from usv_predictor.config import load_predictor_config

    entries = {entry.topic: entry for entry in load_predictor_config().inputs if entry.role in NODE_BATCH}
    found: dict[str, list[bytes]] = {}
    with AnyReader([NODE_BAG], default_typestore=typestore) as reader:
        connections = [c for c in reader.connections if c.topic in entries]
        for connection, _, raw in reader.messages(connections=connections):
            kept = found.setdefault(connection.topic, [])
            if len(kept) < 100:
                kept.append(bytes(raw))
    batches = []
    for topic, entry in entries.items():
        adapter = msg_adapters.get_adapter(entry.role, entry.ros_type, **entry.options)
        batches.append((adapter, found[topic][50:50 + NODE_BATCH[entry.role]]))
    return batches


def old_fill(layout: object, **values: object) -> bytes:
    """CdrLayout.fill as it was before 2026-11-26: a fresh copy of the template per message, then tobytes()."""
    buffer = layout.template.copy()
    for name, (dtype, count, occurrences, runs) in layout.slots.items():
        if not occurrences or not count:
            continue
        rows = np.broadcast_to(np.asarray(values[name], dtype=dtype), (occurrences, count))
        for run in runs:
            view = np.ndarray((run.count, count), dtype=dtype, buffer=buffer, offset=run.offset,
                              strides=(run.stride, dtype.itemsize))
            view[...] = rows[run.first:run.first + run.count]
    return buffer.tobytes()


def old_candidate_predictions_cdr(stamp_ns: int, t_ns: np.ndarray, eta: np.ndarray, nu: np.ndarray, frame_id: str,
                                  names: list[str]) -> bytes:
    """outputs.candidate_predictions_cdr with old_fill: as it was before 2026-11-26."""
    from msg_adapters import outputs
    from msg_adapters.cdr_writer import time_parts

    poses, twists = outputs._check_batch(t_ns, eta, nu, names)
    layout = outputs._trajectory_layout(len(t_ns), frame_id, tuple(names))
    steps, bodies = len(t_ns), len(names)
    return old_fill(layout, stamp=time_parts(stamp_ns), time_from_start=time_parts(t_ns - int(stamp_ns)),
                    transforms=poses.transpose(1, 0, 2).reshape(steps, 7 * bodies),
                    twists=twists.transpose(1, 0, 2).reshape(steps, 6 * bodies))


def bench_node_codec(typestore: Typestore, repeats: int) -> None:
    """The node's per-message codec work, old and new side by side, alternating calls: warm (back to back) and
    cold (a 32 MB sweep before each call, as the node's caches are after 100 ms of other processes)."""
    import ctypes
    import ctypes.util
    import os
    import sys
    import time

    from msg_adapters import cdr, outputs
    from msg_adapters.cdr import decode_joint_trajectory, decode_joint_trajectory_walk, decode_values

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_node import candidates_message  # the benchmark's 64-candidate plan

    import msg_adapters
    from rclpy.serialization import serialize_message

    sweep = np.ones(4_000_000)  # 32 MB

    libc = ctypes.CDLL(ctypes.util.find_library("c"))

    def side_by_side(label: str, old, new, cold: bool, alternate: bool = True) -> None:
        """alternate False: all old calls, then all new ones, each after malloc_trim(0) (the allocator has given
        its free memory back to the system: a fresh buffer is new pages to fault in)."""
        times: dict[str, list[float]] = {"old": [], "new": []}
        rounds = [(("old", old), ("new", new))] * repeats if alternate else [(("old", old),)] * repeats + [
            (("new", new),)] * repeats
        for pair in rounds:
            for name, work in pair:
                if cold:
                    sweep[::8] += 1.0
                if not alternate:
                    libc.malloc_trim(0)
                start = time.perf_counter()
                work()
                times[name].append(time.perf_counter() - start)
        (o50, o99), (n50, n99) = (np.percentile(np.array(t) * 1e3, [50, 99]) for t in times.values())
        print(f"  {label:52s} {'cold' if cold else 'warm'}  {o50:7.3f} {o99:7.3f}   {n50:7.3f} {n99:7.3f}")

    batches = node_cycle_batches(typestore)

    def cycle(limit: int):
        def run() -> None:
            cdr.LEAN_BATCH = limit
            for adapter, raws in batches:
                decode_values(adapter, raws)
        return run

    for adapter, raws in batches:  # the same values both ways
        cdr.LEAN_BATCH = 0
        before = decode_values(adapter, raws)
        cdr.LEAN_BATCH = 256
        after = decode_values(adapter, raws)
        assert before.values.tobytes() == after.values.tobytes() and before.errors == after.errors == []
    plan = serialize_message(candidates_message(msg_adapters.rclpy_factory(), 64, 120))
    assert decode_joint_trajectory(plan).positions.tobytes() == decode_joint_trajectory_walk(plan).positions.tobytes()
    rng = np.random.default_rng(0)
    stamp = 1_700_000_000 * 1_000_000_000
    t_ns = stamp + np.arange(1, 121, dtype=np.int64) * 500_000_000
    eta, nu = rng.normal(0, 100, (64, 120, 3)), rng.normal(0, 2, (64, 120, 3))
    names = [f"c{i}" for i in range(64)]
    answer = (stamp, t_ns, eta, nu, "odom", names)
    assert old_candidate_predictions_cdr(*answer) == outputs.candidate_predictions_cdr(*answer)
    path = (stamp, t_ns, eta[0], "odom")
    from msg_adapters.cdr_writer import time_parts

    def old_path() -> bytes:
        return old_fill(outputs._path_layout(120, "odom"), stamp=time_parts(stamp), pose_stamp=time_parts(t_ns),
                        pose=outputs.enu_poses(eta[0]))

    assert old_path() == outputs.path_cdr(*path)
    print(f"the node's codec, old and new alternating, {repeats} calls each, ms; load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}; outputs checked equal first")
    print(f"  {'':52s}       {'old p50':>7s} {'p99':>7s}   {'new p50':>7s} {'p99':>7s}")
    for cold in (False, True):
        side_by_side("inputs of one cycle (20 IMU, 2+2+1+1+1 others)", cycle(0), cycle(256), cold)
        side_by_side("64-candidate plan, 128 joints x 120 points (130 kB)", lambda: decode_joint_trajectory_walk(plan),
                     lambda: decode_joint_trajectory(plan), cold)
        side_by_side("answer to 64 candidates x 120 steps (800 kB)", lambda: old_candidate_predictions_cdr(*answer),
                     lambda: outputs.candidate_predictions_cdr(*answer), cold)
        side_by_side("answer, each way in its own run, after malloc_trim",
                     lambda: old_candidate_predictions_cdr(*answer),
                     lambda: outputs.candidate_predictions_cdr(*answer), cold, alternate=False)
        side_by_side("Path of 120 poses", old_path, lambda: outputs.path_cdr(*path), cold)
    cdr.LEAN_BATCH = 256


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=200_000, help="messages per measurement")
    parser.add_argument("--repeats", type=int, default=3, help="runs of decode_many, best kept")
    parser.add_argument("--small", action="store_true", help="the node's small batches only (1-32 messages)")
    parser.add_argument("--node-codec", action="store_true",
                        help="the node's codec per cycle, plan and answer, old and new side by side (warm and cold)")
    args = parser.parse_args()
    typestore = get_typestore(Stores.ROS2_JAZZY)
    if args.node_codec:
        bench_node_codec(typestore, max(args.repeats, 400))
        return
    if args.small:
        bench_small(typestore, max(args.repeats, 2000))
        return
    bench_in_memory(typestore, args.count, args.repeats)
    bench_end_to_end(typestore, args.count, args.repeats)


if __name__ == "__main__":
    main()
