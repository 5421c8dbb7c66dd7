#!/usr/bin/env python3
"""Play a shipped bag to the `predictor` node over DDS with /clock, and report what the node published.

    python tools/play_bag.py bags/sea_trial/turning_circle_stbd_20deg_700rpm --seconds 8 --rate 2 --run-node
    python tools/play_bag.py bags/otter/sea_trial/calm/turning_circle_port_d0.4_p0.6 --run-node \
        --config my_predictor.yaml -p fit_check.period_s:=2.0

Publishes the bag's input topics (those of --config, default config/predictor.yaml) as their serialized CDR
bytes (no decode/encode: the node sees exactly the recorded messages) and /clock (rosgraph_msgs/Clock) at every
message time, paced at `rate` x real time. With --run-node it starts `python -m usv_predictor.node [--config FILE]
--ros-args -p use_sim_time:=true [-p NAME:=VALUE ...]` beside it; either way it listens to predicted_path and
/diagnostics and prints the paths' count, rate in sim time, first and last pose, and the node's latest
`model`, `prediction` and `fit check` statuses. A small tool for the demo and the tests (test_node_dds.py imports
BagPlayer and PathListener).
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
from diagnostic_msgs.msg import DiagnosticArray
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
        self.publishers = {topic: node.create_publisher(make(ros_type), topic, 100) for topic,
                           ros_type in types.items()}
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
        def pose(p, k):
            return f"north {p[2][k, 0]:.1f} m, east {p[2][k, 1]:.1f} m at +{(p[1][k] - p[0]) / 1e9:.2f} s"
        return (f"{len(self.paths)} paths of {len(last[1])} poses in frame {last[3]!r}, {rate:.2f} Hz in sim time\n"
                f"  first path: first pose {pose(first, 0)}, last pose {pose(first, -1)}\n"
                f"  last path:  first pose {pose(last, 0)}, last pose {pose(last, -1)}")


class DiagnosticsListener:
    """Keeps the latest status of each name on /diagnostics (`predictor: fit check` -> level, message)."""

    LEVELS = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}

    def __init__(self, node: Node) -> None:
        self.latest: dict[str, tuple[str, str]] = {}
        self.values: dict[str, dict[str, str]] = {}
        node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            self.latest[status.name] = (self.LEVELS.get(status.level[0], str(status.level[0])), status.message)
            self.values[status.name] = {kv.key: kv.value for kv in status.values}

    def summary(self, names: tuple[str, ...] = ("model", "prediction", "fit check")) -> str:
        lines = []
        for name in names:
            found = [(key, value) for key, value in self.latest.items() if key.endswith(f": {name}")]
            for key, (level, message) in found:
                lines.append(f"{key}: {level} {message}")
                if name == "fit check":  # how many checks ran, on what, at what cost
                    shown = ("checks", "windows", "speed_ratio", "yaw_rate_ratio", "compute_ms_p50", "not_run")
                    lines.append("  " + ", ".join(f"{k} {v}" for k, v in self.values[key].items() if k in shown))
        return "\n".join(lines) or "no /diagnostics received"


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
    parser.add_argument("--config", type=Path, default=None,
                        help="parameter file of the node (predictor --config FILE) and of the topics played "
                             "(default: config/predictor.yaml)")
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                        help="a parameter of the node (-p NAME:=VALUE after --ros-args), repeatable")
    parser.add_argument("--settle", type=float, default=0.5,
                        help="wall seconds to keep listening after the last message (default 0.5)")
    args = parser.parse_args(argv)
    if args.config is not None and not args.config.is_file():
        parser.error(f"--config {args.config}: no such file")
    for param in args.param:
        if ":=" not in param:
            parser.error(f"--param {param!r}: expected NAME:=VALUE")
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")}
    os.environ.update(env)
    messages = read_messages(args.bag, args.start, args.seconds, args.config)
    node_process = None
    if args.run_node:
        config = [] if args.config is None else ["--config", str(args.config)]
        params = [item for param in args.param for item in ("-p", param)]
        node_process = subprocess.Popen([sys.executable, "-m", "usv_predictor.node", *config, "--ros-args",
                                         "-p", "use_sim_time:=true", *params, "--log-level", "warn"], env=env)
    rclpy.init()
    node = rclpy.create_node("bag_player")
    try:
        player, listener = BagPlayer(node, messages), PathListener(node)
        diagnostics = DiagnosticsListener(node)
        executor = rclpy.executors.SingleThreadedExecutor()
        executor.add_node(node)
        deadline = time.monotonic() + 30.0  # the node's start-up (torch import, model load) and discovery
        first_topic = messages[0].topic if messages else "imu/data"
        while time.monotonic() < deadline and (node.count_subscribers(first_topic) == 0
                                               or node.count_publishers("predicted_path") == 0
                                               or (args.run_node and node.count_subscribers("/clock") == 0)):
            executor.spin_once(timeout_sec=0.05)
            if node_process is not None and node_process.poll() is not None:
                print(f"the predictor node exited with code {node_process.returncode} before playback",
                      file=sys.stderr)
                return 2
        if messages:  # the node's clock first: a message arriving before any /clock is stamped at time 0
            end = time.monotonic() + 0.2
            while time.monotonic() < end:
                player.publish_clock(messages[0].log_time_ns)
                executor.spin_once(timeout_sec=0.01)
        print(f"playing {len(messages)} messages ({args.seconds:g} s of {args.bag.name}) at {args.rate:g}x",
              file=sys.stderr)
        play(player, executor, args.rate)
        end = time.monotonic() + args.settle
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
        print(listener.summary())
        print(diagnostics.summary())
        return 0 if listener.paths else 1
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        if node_process is not None:
            node_process.terminate()
            node_process.wait(timeout=10)


if __name__ == "__main__":
    sys.exit(main())
