#!/usr/bin/env python3
"""Run the walkthrough docs/your_boat.md as written: the demo's last step and test_your_boat.py.

    python tools/your_boat.py out/demo/your_boat

The commands are the doc's ```bash blocks, in order: one source, so the doc cannot drift from what runs. They run in
the working directory given, as in a fresh clone's root: `bags` there links to the repository's bags/ (the doc's
paths are relative to the root; nothing is written into the clone) and `replay` is this interpreter's
virtualenv's (its bin/ first on PATH). Step 4's ```yaml block is merged into a copy of config/predictor.yaml and
written under the name the doc's `predictor --config FILE` gives (my_predictor.yaml), with the model_path placeholder
(/path/to/NAME.pt) replaced by the NAME.pt made in step 2. `ros2 run usv_predictor predictor ARGS` runs until it is
stopped: here the node starts with ARGS from tools/play_bag.py --run-node, which plays PLAY_SECONDS of an otter bag
to it over DDS (use_sim_time + /clock) and prints what it published (paths, the model, the fit check).
Each command is printed before it runs with its wall time after; the first that fails ends the run with its code.
"""
from __future__ import annotations

import argparse
import os
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, NamedTuple

import yaml

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "your_boat.md"
PLAY_BAG = REPO / "tools" / "play_bag.py"
PLAY_BAG_PATH = "bags/otter/sea_trial/calm/turning_circle_stbd_d0.4_p0.6"  # a held turn after a straight approach
PLAY_SECONDS = 40.0  # (s of the bag) the approach and 30 s of the turn: a steady window for the fit check
PLAY_RATE = 1.5  # (x real time) the bag's player and the node keep up on a loaded 2-core machine
NODE = ("ros2", "run", "usv_predictor", "predictor")
PLACEHOLDER = re.compile(r"^/path/to/(?P<name>[^/]+\.pt)$")


class DocError(Exception):
    """The doc has no command this runner can run as written (one line, exit 2)."""


class Step(NamedTuple):
    argv: tuple[str, ...]  # as the doc writes it
    line: str  # the doc's text, continuation lines joined


def doc_blocks(text: str, language: str) -> list[str]:
    """The contents of the ```language fenced blocks of a Markdown text, in order."""
    return [m.group(1) for m in re.finditer(rf"^```{language}\n(.*?)^```", text, re.S | re.M)]


def doc_steps(doc: Path = DOC) -> list[Step]:
    """Every command of the doc's ```bash blocks (backslash continuations joined, comments skipped)."""
    steps = []
    for block in doc_blocks(doc.read_text(), "bash"):
        for line in re.sub(r"\\\n\s*", " ", block).splitlines():
            line = line.strip()
            if line and not line.startswith("#"):
                steps.append(Step(tuple(shlex.split(line)), line))
    return steps


def node_config(doc: Path = DOC) -> dict[str, Any]:
    """The doc's ```yaml block of the node's parameters (the one with `predictor:`)."""
    for block in doc_blocks(doc.read_text(), "yaml"):
        parsed = yaml.safe_load(block)
        if isinstance(parsed, dict) and "predictor" in parsed:
            return parsed
    raise DocError(f"{doc}: no ```yaml block with `predictor:` (step 4's node parameters)")


def merged(base: dict[str, Any], changes: dict[str, Any]) -> dict[str, Any]:
    """base with changes merged in, mapping by mapping."""
    out = dict(base)
    for key, value in changes.items():
        out[key] = merged(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out


def write_node_config(workdir: Path, name: str, doc: Path = DOC) -> Path:
    """config/predictor.yaml with the doc's block merged in, model_path's placeholder made the workdir's file."""
    config = merged(yaml.safe_load((REPO / "config" / "predictor.yaml").read_text()), node_config(doc))
    parameters = config["predictor"]["ros__parameters"]
    placeholder = PLACEHOLDER.match(str(parameters.get("model_path", "")))
    if placeholder:
        parameters["model_path"] = str((workdir / placeholder.group("name")).resolve())
    path = workdir / name
    temporary = path.with_name(path.name + ".tmp")
    temporary.write_text(yaml.safe_dump(config, sort_keys=False))
    os.replace(temporary, path)  # atomic
    return path


def command_of(step: Step, workdir: Path, doc: Path = DOC) -> list[str]:
    """What runs for a step of the doc: replay from this virtualenv, the node from play_bag.py (module docstring)."""
    argv = list(step.argv)
    if argv[0] == "replay":
        return [str(Path(sys.executable).with_name("replay")), *argv[1:]]
    if tuple(argv[:4]) == NODE:
        args = argv[4:]
        if args[:1] != ["--config"] or len(args) != 2:
            raise DocError(f"{doc}: `{step.line}`: expected `{' '.join(NODE)} --config FILE`")
        config = write_node_config(workdir, args[1], doc)
        print(f"wrote {config} (config/predictor.yaml with step 4's block)", flush=True)
        return [sys.executable, str(PLAY_BAG), PLAY_BAG_PATH, "--run-node", "--config", config.name,
                "--seconds", f"{PLAY_SECONDS:g}", "--rate", f"{PLAY_RATE:g}", "--settle", "1.0"]
    raise DocError(f"{doc}: `{step.line}`: a command this runner does not know (replay ..., {' '.join(NODE)} ...)")


def run(workdir: Path, doc: Path = DOC) -> int:
    """Run every step in `workdir` (created; `bags` linked); the exit code of the first that fails, else 0."""
    workdir.mkdir(parents=True, exist_ok=True)
    bags = workdir / "bags"
    if not bags.exists():
        bags.symlink_to(REPO / "bags", target_is_directory=True)
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}",
           "ROS_AUTOMATIC_DISCOVERY_RANGE": os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")}
    for step in doc_steps(doc):
        command = command_of(step, workdir, doc)
        print(f"$ {step.line}", flush=True)
        started = time.monotonic()
        code = subprocess.run(command, cwd=workdir, env=env).returncode
        print(f"  ({time.monotonic() - started:.1f} s, exit {code})", flush=True)
        if code != 0:
            print(f"your_boat: `{step.line}` failed with exit code {code}", file=sys.stderr)
            return code
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("workdir", type=Path, help="where the commands run and write (created)")
    parser.add_argument("--doc", type=Path, default=DOC, help="the walkthrough (default docs/your_boat.md)")
    args = parser.parse_args(argv)
    if not args.doc.is_file():
        parser.error(f"--doc {args.doc}: no such file")
    try:
        return run(args.workdir, args.doc)
    except DocError as err:
        print(f"your_boat: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
