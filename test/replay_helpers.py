"""Shared helpers of the tests that feed the replay tool bad input (test_hardening.py, test_fuzz.py).

`replay` runs a command in-process through usv_predictor.replay.cli.main and returns (exit code, stderr); the
other helpers say what a run must leave behind: the inputs byte-identical (`digest`), no temporary file of an
atomic writer (`leftovers`), and on failure one line `replay <command>: error: ...` (`assert_one_line`).
`bag_streams` / `write_variant` turn a bag into the Signals of its configured topics and back, to make
mutated copies; `write_layout_variant` writes the jari_usv preset as a vessel file of another actuator layout.
"""
from __future__ import annotations

import hashlib
import os
import subprocess
import time
from collections.abc import Iterable, Mapping
from pathlib import Path

import pytest
import yaml

from usv_predictor.atomic import PROBE_PREFIX
from usv_predictor.physics.vessel import vessel_dir
from usv_predictor.records import Signal
from usv_predictor.replay import cli
from usv_predictor.replay.bagio import TopicSpec, read_bag, write_bag
from usv_predictor.replay.recordings import bag_metadata, topic_specs

EXIT_CODES = (0, cli.EXIT_ERROR)  # what bad input may end with: a clean run, or one line and exit 2


def pinned_tool(name: str) -> str:
    """The path of a tool requirements.txt pins (colcon, ruff): beside this interpreter (the virtualenv's bin/), else
    on PATH; the test fails saying how to install it when there is none."""
    import shutil
    import sys

    beside_python = Path(sys.executable).parent / name
    found = str(beside_python) if beside_python.is_file() else shutil.which(name)
    if found is None:
        pytest.fail(f"{name} is not installed (it is pinned in requirements.txt; run ./run.sh test)")
    return found


def replay(capsys: pytest.CaptureFixture[str], *argv: object) -> tuple[int, str]:
    """Run `replay ARGV...` in this process: (exit code, what it printed on stderr)."""
    capsys.readouterr()
    code = cli.main([str(a) for a in argv])
    return code, capsys.readouterr().err


def digest(paths: Iterable[Path]) -> dict[str, str]:
    """sha256 of every file under `paths` (files or directories), by path: an input must not change at all."""
    out: dict[str, str] = {}
    for root in paths:
        root = Path(root)
        files = [root] if root.is_file() else sorted(p for p in root.rglob("*") if p.is_file())
        for f in files:
            out[str(f)] = hashlib.sha256(f.read_bytes()).hexdigest()
    return out


def leftovers(root: Path) -> list[Path]:
    """Temporary files of the atomic writers (`.<name>.<random>.partial`, bag work directories, write probes)."""
    found = []
    for dirpath, dirnames, filenames in os.walk(root):
        for name in [*dirnames, *filenames]:
            if name.endswith(".partial") or name.startswith(PROBE_PREFIX):
                found.append(Path(dirpath) / name)
    return found


def assert_one_line(code: int, err: str, command: str, allowed: Iterable[int] = EXIT_CODES) -> None:
    """Exit 0 or 2 (or `allowed`), never a traceback; an error is one line naming the command."""
    assert code in tuple(allowed), f"replay {command} exited {code}:\n{err[-3000:]}"
    assert "Traceback" not in err, err[-3000:]
    if code == cli.EXIT_ERROR:
        last = err.strip().splitlines()[-1]
        assert last.startswith(f"replay {command}: error: ") or last.startswith("replay: error: "), last


def bag_streams(path: Path) -> tuple[list[tuple[TopicSpec, Signal]], dict[str, str]]:
    """The configured topics of a bag (ground truth included) as (spec, Signal), and its custom_data."""
    present, custom = bag_metadata(path) or ({}, {})
    specs = [s for s in topic_specs() if s.topic in present]
    signals = read_bag(path, specs)
    return [(s, signals[s.topic]) for s in specs], custom


def write_variant(path: Path, streams: list[tuple[TopicSpec, Signal]], custom: Mapping[str, str]) -> Path:
    """Write a (mutated) copy of a bag: uncompressed sqlite3, the same custom_data."""
    return write_bag(path, streams, metadata=custom, compress=False)


def write_layout_variant(directory: Path, layout: str, **sections: object) -> Path:
    """jari_usv with `layout` (and the sections it needs, e.g. throttle=...) as a vessel file named jari_<layout>
    (every replay command takes a YAML path for --vessel)."""
    raw = yaml.safe_load((vessel_dir() / "jari_usv.yaml").read_text())
    path = Path(directory) / f"jari_{layout}.yaml"
    path.write_text(yaml.safe_dump({**raw, "name": f"jari_{layout}", "actuator_layout": layout, **sections}))
    return path


def write_model_with_metadata(path: Path, source: Path, drop: Iterable[str] = (), **changes: object) -> Path:
    """A copy of the model file `source` whose metadata.json has `changes` (and lacks the keys `drop`), written with
    torch.jit.save directly: what a hand-edited or hostile file holds, which export_module would refuse to write.
    Dropping `vessel_sha256` leaves the embedded vessel.json out too (a model of before, naming its vessel only)."""
    import json

    import torch

    from usv_predictor.models.artifact import quiet_jit

    extra = {"metadata.json": "", "vessel.json": ""}
    with quiet_jit():
        module = torch.jit.load(str(source), map_location="cpu", _extra_files=extra)
    metadata = {k: v for k, v in json.loads(extra["metadata.json"]).items() if k not in set(drop)}
    metadata.update(changes)
    files = {"metadata.json": json.dumps(metadata)}
    if "vessel_sha256" in metadata:
        files["vessel.json"] = extra["vessel.json"]
    with quiet_jit():
        torch.jit.save(module, str(path), _extra_files=files)
    return path


def never_returning_model(path: Path, like: Path) -> Path:
    """A TorchScript model with the metadata and vessel of `like` whose forward prints `model: running` (on stdout:
    the moment a test waits for) and then never returns (a scripted loop: TorchScript releases the GIL, and no
    signal reaches it). Only ever loaded in a process of its own: the thread left inside it burns a core."""
    import torch

    from usv_predictor.models.artifact import export_like, load_artifact

    class NeverReturns(torch.nn.Module):
        def forward(self, state: torch.Tensor, controls: torch.Tensor) -> torch.Tensor:
            print("model: running")
            x = state.sum()
            while bool(x > -1.0):
                x = x + 1.0
            return torch.zeros(1, state.shape[0], controls.shape[1], 6)

    export_like(path, NeverReturns(), load_artifact(like))
    return path


def slow_model(path: Path, like: Path, loops_per_step: int = 3000) -> Path:
    """A TorchScript model with the metadata and vessel of `like` that answers zeros (every member) after
    `loops_per_step` scripted iterations per step: about 0.8 s for 120 steps here, 7 ms for two."""
    import torch

    from usv_predictor.models.artifact import export_like, load_artifact

    members = int(load_artifact(like).metadata["ensemble_size"])

    class Slow(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.loops_per_step = loops_per_step
            self.members = members

        def forward(self, state: torch.Tensor, controls: torch.Tensor) -> torch.Tensor:
            x = state.sum()
            for _ in range(controls.shape[1] * self.loops_per_step):
                x = x * 1.0
            return torch.zeros(self.members, state.shape[0], controls.shape[1], 6) + x * 0.0

    export_like(path, Slow(), load_artifact(like))
    return path


def stop_and_time(process: subprocess.Popen, sig: int, timeout_s: float = 30.0) -> tuple[str, float]:
    """Send `sig` to a running process and wait for its end: (its stderr, the seconds from the signal to its end);
    killed if it outlives the wait (the caller's assertions then name the exit code it got)."""
    try:
        sent = time.monotonic()
        process.send_signal(sig)
        _, err = process.communicate(timeout=timeout_s)
        return err, time.monotonic() - sent
    finally:
        if process.poll() is None:
            process.kill()
