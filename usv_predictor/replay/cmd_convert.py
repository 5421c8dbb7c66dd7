"""`replay convert`: public measured manoeuvres (HSVA/MARIN KVLCC2, Fuzhou USV) -> one rosbag2 per manoeuvre.

Bags carry the default input topics of config/predictor.yaml (no ground truth: measured data have
none) and custom_data with source, licence note, scale, conventions and conversion version. The readers
and the conversion live in usv_predictor.replay.convert; docs/data.md says what each source supports.
"""
from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

NAME = "convert"
HELP = "convert public measured manoeuvres (HSVA/MARIN KVLCC2 zig-zags, Fuzhou USV zig-zag) to rosbag2 bags"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("sources", nargs="+", type=Path, metavar="SOURCE_DIR_OR_FILE",
                        help="data directories (e.g. ../shared/data/raw/kvlcc2_hsva_simman2008) or manoeuvre files")
    parser.add_argument("--output", type=Path, required=True, help="directory for the bags (one per manoeuvre)")
    parser.add_argument("--format", choices=("auto", "hsva", "marin", "fuzhou"), default="auto",
                        help="input format (default auto: from the file names)")
    parser.add_argument("--storage", choices=("sqlite3", "mcap"), default="sqlite3", help="rosbag2 storage (default sqlite3)")
    parser.add_argument("--overwrite", action="store_true", help="replace existing bags")


def run(args: argparse.Namespace) -> dict:
    from usv_predictor.config import input_topics, load_predictor_config
    from usv_predictor.errors import DatasetError
    from usv_predictor.replay import convert
    from usv_predictor.replay.bagio import TopicSpec, prepare_outputs

    sources = convert.find_sources(args.sources, args.format)
    manoeuvres = [convert.read_manoeuvre(path, fmt) for path, fmt in sources]  # read all first: fail before writing
    names: dict[str, Path] = {}
    for m in manoeuvres:
        if m.name in names:
            raise DatasetError(f"{m.path} and {names[m.name]} both convert to bag {m.name!r}; convert them separately")
        names[m.name] = m.path
    prepare_outputs(args.output, [args.output / m.name for m in manoeuvres], args.overwrite)
    cfg = load_predictor_config()
    specs = {t.role: TopicSpec(t.topic, t.role, t.ros_type, t.options, t.frame_id or cfg.base_frame_id)
             for t in input_topics(cfg, include_ground_truth=False)}
    command = shlex.join(["replay", *sys.argv[1:]]) if sys.argv else "replay convert"
    results = []
    for k, m in enumerate(manoeuvres):
        started = time.perf_counter()
        path = args.output / m.name
        messages = convert.write_manoeuvre_bag(path, m, specs, storage=args.storage, overwrite=args.overwrite,
                                               command=command)
        summary = convert.summarise(m) | {"bag": str(path), "messages": messages}
        results.append(summary)
        print(f"[{k + 1}/{len(manoeuvres)}] {path}  {m.duration_s:.0f} s at {m.rate_hz:.2f} Hz, {messages} messages "
              f"({time.perf_counter() - started:.2f} s)", file=sys.stderr)
    return {"bags": results, "conversion_version": convert.CONVERSION_VERSION, "output": str(args.output)}
