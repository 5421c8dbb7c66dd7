#!/usr/bin/env python3
"""Play a shipped bag to the `predictor` node over DDS with /clock, and report what the node published.

    python tools/play_bag.py bags/sea_trial/turning_circle_stbd_20deg_700rpm --seconds 8 --rate 2 --run-node

Publishes the bag's input topics as their serialized CDR bytes (no decode/encode: the node sees exactly
the recorded messages) and /clock (rosgraph_msgs/Clock) at every message time, paced at `rate` x real time.
With --run-node it starts `python -m usv_predictor.node -p use_sim_time:=true` beside it; either way it
listens to predicted_path and prints the count, the rate in sim time, and the first and last pose.
A small tool for the demo and the tests (test_node_dds.py imports BagPlayer and PathListener).
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, NamedTuple

import rclpy
from rclpy.node import Node
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore
from rosgraph_msgs.msg import Clock

import msg_adapters
from msg_adapters.outputs import decode_path
from usv_predictor.config import input_topics, load_predictor_config


class RawMessage(NamedTuple):
    log_time_ns: int
    topic: str
    ros_type: str
    data: bytes  # CDR, as recorded


def read_messages(bag: Path, start_s: float = 0.0, seconds: float | None = None,
                  config_path: Path | None = None) -> list[RawMessage]:
    """The input topics configured in `config_path` (default: config/predictor.yaml) of `bag` in log-time order,
    from start_s for `seconds` (s since its start)."""
    wanted = {spec.topic for spec in input_topics(load_predictor_config(config_path))}
    out: list[RawMessage] = []
    with AnyReader([Path(bag)], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        first = reader.start_time + int(start_s * 1e9)
        last = None if seconds is None else first + int(seconds * 1e9)
        connections = [c for c in reader.connections if c.topic in wanted]
        for connection, log_time, raw in reader.messages(connections=connections, start=first, stop=last):
            out.append(RawMessage(int(log_time), connection.topic, connection.msgtype, bytes(raw)))
    out.sort(key=lambda m: m.log_time_ns)
    return out


class BagPlayer:
    """Publishes raw messages and /clock from `node`; publish_until(t) sends every message with log time <= t."""

    def __init__(self, node: Node, messages: list[RawMessage]) -> None:
        make = msg_adapters.rclpy_factory()
        self.node = node
        self.messages = messages
        self.cursor = 0
        types = {m.topic: m.ros_type for m in messages}
        self.publishers = {topic: node.create_publisher(make(ros_type), topic, 100) for topic, ros_type in types.items()}
        self.clock = node.create_publisher(Clock, "/clock", 10)
        self.published = 0

    @property
    def done(self) -> bool:
        return self.cursor >= len(self.messages)

    @property
    def next_time_ns(self) -> int:
        return self.messages[self.cursor].log_time_ns

    def publish_clock(self, t_ns: int) -> None:
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(int(t_ns), 1_000_000_000)
        self.clock.publish(msg)

    def publish_until(self, t_ns: int, topics: set[str] | None = None) -> int:
        """Publish the messages up to t_ns (those of `topics` only, when given); returns how many."""
        sent = 0
        while not self.done and self.messages[self.cursor].log_time_ns <= t_ns:
            message = self.messages[self.cursor]
            if topics is None or message.topic in topics:
                self.publishers[message.topic].publish(message.data)  # serialized CDR: published as is
                sent += 1
            self.cursor += 1
        self.published += sent
        return sent


class PathListener:
    """Keeps every predicted_path received: (header stamp ns, pose stamps (H,), eta (H, 3) NED, frame)."""

    def __init__(self, node: Node, topic: str = "predicted_path") -> None:
        make = msg_adapters.rclpy_factory()
        self.paths: list[tuple[int, Any, Any, str]] = []
        self.arrival_ns: list[int] = []
        node.create_subscription(make("nav_msgs/msg/Path"), topic, self._on_path, 10)

    def _on_path(self, msg: Any) -> None:
        self.arrival_ns.append(time.perf_counter_ns())
        t_ns, eta = decode_path(msg)
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self.paths.append((stamp, t_ns, eta, msg.header.frame_id))

    def summary(self) -> str:
        if not self.paths:
            return "no predicted_path received"
        stamps = [p[0] for p in self.paths]
        span = (stamps[-1] - stamps[0]) / 1e9
        rate = (len(stamps) - 1) / span if span > 0 else float("nan")
        first, last = self.paths[0], self.paths[-1]
        pose = lambda p, k: f"north {p[2][k, 0]:.1f} m, east {p[2][k, 1]:.1f} m at +{(p[1][k] - p[0]) / 1e9:.2f} s"
        return (f"{len(self.paths)} paths of {len(last[1])} poses in frame {last[3]!r}, {rate:.2f} Hz in sim time\n"
                f"  first path: first pose {pose(first, 0)}, last pose {pose(first, -1)}\n"
                f"  last path:  first pose {pose(last, 0)}, last pose {pose(last, -1)}")


def play(player: BagPlayer, executor: Any, rate: float, clock_step_ns: int = 10_000_000) -> None:
    """Free-running playback at `rate` x real time: /clock every clock_step_ns of sim time, messages in order."""
    t_start = player.next_time_ns
    wall_start = time.monotonic()
    sim = t_start
    while not player.done:
        player.publish_clock(sim)
        player.publish_until(sim)
        sim += clock_step_ns
        wait = wall_start + (sim - t_start) / 1e9 / rate - time.monotonic()
        executor.spin_once(timeout_sec=max(0.0, wait))
        while wait > 0 and time.monotonic() < wall_start + (sim - t_start) / 1e9 / rate:
            executor.spin_once(timeout_sec=0.001)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[1])
    parser.add_argument("bag", type=Path)
    parser.add_argument("--start", type=float, default=0.0, help="start this far into the bag (s)")
    parser.add_argument("--seconds", type=float, default=8.0, help="sim seconds to play (default 8)")
    parser.add_argument("--rate", type=float, default=1.0, help="playback speed (x real time)")
    parser.add_argument("--run-node", action="store_true", help="start the predictor node with use_sim_time")
    args = parser.parse_args(argv)
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")}
    os.environ.update(env)
    messages = read_messages(args.bag, args.start, args.seconds)
    node_process = None
    if args.run_node:
        node_process = subprocess.Popen([sys.executable, "-m", "usv_predictor.node", "--ros-args",
                                         "-p", "use_sim_time:=true", "--log-level", "warn"], env=env)
    rclpy.init()
    node = rclpy.create_node("bag_player")
    try:
        player, listener = BagPlayer(node, messages), PathListener(node)
        executor = rclpy.executors.SingleThreadedExecutor()
        executor.add_node(node)
        deadline = time.monotonic() + 10.0  # the node's start-up (torch import, model load) and discovery
        while time.monotonic() < deadline and (node.count_subscribers("imu/data") == 0
                                               or node.count_publishers("predicted_path") == 0):
            executor.spin_once(timeout_sec=0.05)
        print(f"playing {len(messages)} messages ({args.seconds:g} s of {args.bag.name}) at {args.rate:g}x",
              file=sys.stderr)
        play(player, executor, args.rate)
        end = time.monotonic() + 0.5
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
        print(listener.summary())
        return 0 if listener.paths else 1
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        if node_process is not None:
            node_process.terminate()
            node_process.wait(timeout=10)


if __name__ == "__main__":
    sys.exit(main())
