"""The dataset stage's speed: bag -> Signals per message vs in bulk, and a whole `replay dataset`, side by side.

Run: .venv/bin/python benchmarks/bench_dataset.py [--repeats 3] [--bags bags]

(a) rosbags: AnyReader + deserialize_cdr + adapter.decode, one message at a time (the obvious way);
(b) bagio.read_bag: AnyReader + msg_adapters.cdr.decode_many + one vectorised adapter.decode per topic;
both over every shipped bag (calm twins included) and the default topics of config/predictor.yaml,
ground truth included. (b) is split into its phases (open the bag, iterate the raw messages, decode)
to show where the time goes. Then `replay dataset bags/training bags/sea_trial` end to end: one process,
then bags read in parallel (the default --jobs), warm in this process and as a fresh process (interpreter
start and imports included). Target: >= 250k msg/s bag -> Signals. The machine's other load shows in the
figures: compare the rows of one run, not runs of different days.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rosbags.highlevel import AnyReader

from msg_adapters.cdr import decode_many
from usv_predictor.replay.bagio import jazzy_typestore, read_bag
from usv_predictor.replay.cli import main as replay_main
from usv_predictor.replay.recordings import default_jobs, find_bags, topic_specs

from timing import best_seconds  # benchmarks/timing.py (the script folder is on sys.path)

ROOT = Path(__file__).resolve().parents[1]
TARGET_MSG_S = 250_000


def per_message(bags: list[Path], specs: list) -> int:
    """(a): one rosbags object and one adapter call per message; returns the message count."""
    adapters = {s.topic: s.adapter() for s in specs}
    count = 0
    for bag in bags:
        with AnyReader([bag], default_typestore=jazzy_typestore()) as reader:
            wanted = [c for c in reader.connections if c.topic in adapters]
            rows: dict[str, list] = {t: [] for t in adapters}
            for connection, _, raw in reader.messages(connections=wanted):
                msg = reader.deserialize(raw, connection.msgtype)
                rows[connection.topic].append(adapters[connection.topic].decode(msg))
                count += 1
    return count


def bulk(bags: list[Path], specs: list) -> int:
    """(b): bagio.read_bag; returns the message count."""
    return sum(len(signal) for bag in bags for signal in read_bag(bag, specs).values())


def phases(bags: list[Path], specs: list) -> dict[str, float]:
    """(b) taken apart: seconds to open the bags, to iterate the raw messages, and to decode them in bulk."""
    spent = {"open (AnyReader: metadata + zstd + sqlite)": 0.0, "iterate raw messages": 0.0,
             "decode_many + adapters": 0.0}
    keys = list(spent)
    by_topic = {s.topic: s for s in specs}
    for bag in bags:
        t0 = time.perf_counter()
        with AnyReader([bag], default_typestore=jazzy_typestore()) as reader:
            t1 = time.perf_counter()
            raws: dict[str, list] = {t: [] for t in by_topic}
            wanted = [c for c in reader.connections if c.topic in by_topic]
            for connection, _, raw in reader.messages(connections=wanted):
                raws[connection.topic].append(raw)
            t2 = time.perf_counter()
            for topic, spec in by_topic.items():
                spec.adapter().decode(decode_many(spec.ros_type, raws[topic], reader.typestore))
            t3 = time.perf_counter()
        spent[keys[0]] += t1 - t0
        spent[keys[1]] += t2 - t1
        spent[keys[2]] += t3 - t2
    return spent


def whole_dataset(args: list[str]) -> float:
    with tempfile.TemporaryDirectory() as tmp, contextlib.redirect_stdout(io.StringIO()), \
            contextlib.redirect_stderr(io.StringIO()):
        start = time.perf_counter()
        code = replay_main(["dataset", *args, "--output", str(Path(tmp) / "ds.npz")])
        seconds = time.perf_counter() - start
    if code != 0:
        raise SystemExit(f"replay dataset failed with exit code {code}")
    return seconds


def fresh_process(args: list[str]) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        subprocess.run([sys.executable, "-m", "usv_predictor.replay", "dataset", *args, "--output",
                        str(Path(tmp) / "ds.npz")],
                       check=True, capture_output=True, cwd=ROOT)
        return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bags", type=Path, default=ROOT / "bags", help="directory searched for bags (default bags/)")
    parser.add_argument("--repeats", type=int, default=3, help="runs of the fast paths, best kept (default 3)")
    args = parser.parse_args()
    bags = sorted(p.parent for p in args.bags.rglob("metadata.yaml"))
    specs = topic_specs()
    size = sum(f.stat().st_size for b in bags for f in b.iterdir())
    bulk(bags[:1], specs)  # warm-up: lazy imports and typestores are not what we measure
    count = bulk(bags, specs)
    print(f"{len(bags)} bags under {args.bags} ({size / 1e6:.1f} MB), {count:,} messages on {len(specs)} topics")
    slow = best_seconds(lambda: per_message(bags, specs), 1)
    fast = best_seconds(lambda: bulk(bags, specs), args.repeats)
    print(f"\n{'bag -> Signals':42s} {'seconds':>8s} {'msg/s':>10s}")
    print(f"{'(a) rosbags deserialize_cdr + adapters':42s} {slow:8.2f} {count / slow:10,.0f}")
    print(f"{'(b) bagio.read_bag (cdr, bulk)':42s} {fast:8.2f} {count / fast:10,.0f}   "
          f"{slow / fast:.1f}x faster; target {TARGET_MSG_S:,} msg/s: "
          f"{'met' if count / fast >= TARGET_MSG_S else 'MISSED'}")
    runs = [phases(bags, specs) for _ in range(args.repeats)]
    spent = {phase: min(run[phase] for run in runs) for phase in runs[0]}
    total = sum(spent.values())
    print(f"\n(b) by phase (best of {args.repeats}, {total:.2f} s in all)")
    for phase, seconds in spent.items():
        print(f"  {phase:44s} {seconds:6.2f} s {100 * seconds / total:5.1f} %  ({count / seconds:12,.0f} msg/s alone)")
    dataset_args = [str(args.bags / "training"), str(args.bags / "sea_trial")]
    messages = sum(len(s) for b in find_bags(dataset_args) for s in read_bag(b.path, specs).values())
    print(f"\nreplay dataset {' '.join(dataset_args)} --output ... ({messages:,} messages, {default_jobs(99)} CPUs)")
    for label, extra in (("--jobs 1, in this process (warm)", ["--jobs", "1"]),
                         ("default --jobs, in this process (warm)", [])):
        seconds = best_seconds(lambda: whole_dataset(dataset_args + extra), args.repeats)
        print(f"  {label:44s} {seconds:6.2f} s ({messages / seconds:10,.0f} msg/s end to end)")
    cold = fresh_process(dataset_args)
    print(f"  {'default --jobs, fresh process (start+imports)':44s} {cold:6.2f} s ({messages / cold:10,.0f} "
          f"msg/s end to end)")

if __name__ == "__main__":
    main()
