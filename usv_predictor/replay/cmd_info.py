"""`replay info BAG...`: what a bag holds (topics, types, counts, rates, duration, custom_data)."""
from __future__ import annotations

import argparse
import datetime
import sys
from pathlib import Path

NAME = "info"
HELP = "summarise rosbag2 bags: topics, types, message counts, rates, duration, custom_data"
INPUTS = ("bags",)
OUTPUTS: dict[str, str] = {}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bags", nargs="+", type=Path, metavar="BAG", help="rosbag2 directory")


def _format(info: dict) -> str:
    start = info["start_ns"]
    started = (
        datetime.datetime.fromtimestamp(start * 1e-9, tz=datetime.timezone.utc).isoformat(timespec="milliseconds")
        if start is not None
        else "-"
    )
    lines = [
        f"bag:       {info['path']}",
        f"size:      {info['size_bytes'] / 1024:.1f} KiB",
        f"start:     {started}",
        f"duration:  {info['duration_s']:.3f} s",
        f"messages:  {info['message_count']}",
        "topics:",
    ]
    width = max((len(t["topic"]) for t in info["topics"]), default=0)
    for topic in info["topics"]:
        rate = f"{topic['rate_hz']:8.2f} Hz" if topic["rate_hz"] is not None else "       - Hz"
        lines.append(f"  {topic['topic']:<{width}}  {topic['count']:>7}  {rate}  {topic['type']}")
    if info["custom_data"]:
        lines.append("custom_data:")
        lines.extend(f"  {key}: {value}" for key, value in sorted(info["custom_data"].items()))
    return "\n".join(lines)


def run(args: argparse.Namespace) -> dict:
    from usv_predictor.replay.bagio import bag_info  # heavy (rosbags); keep `--help` fast

    infos = []
    for bag in args.bags:
        print(f"reading {bag} ...", file=sys.stderr)
        infos.append(bag_info(bag))
        print(_format(infos[-1]))
    return {"bags": infos}
