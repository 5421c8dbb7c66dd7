"""Topic names as `ros2 bag record` writes them (fully qualified, `/imu/data`) match the config's relative names
(`imu/data`), as ROS resolves names in the root namespace; and every replay command that reads bags takes --config."""
from __future__ import annotations

import dataclasses
import importlib
from pathlib import Path

import numpy as np
import pytest
import yaml
from replay_helpers import bag_streams, write_variant

from usv_predictor.replay import cli
from usv_predictor.replay.bagio import absolute_topic, resolve_topic
from usv_predictor.replay.recordings import bag_metadata, load_recordings


def test_names_resolve_in_the_root_namespace() -> None:
    assert absolute_topic("imu/data") == "/imu/data"
    assert absolute_topic("/imu/data") == "/imu/data"
    assert resolve_topic("imu/data", ["/imu/data", "/velocity"]) == "/imu/data"
    assert resolve_topic("/imu/data", ["imu/data"]) == "imu/data"
    assert resolve_topic("imu/data", ["imu/data", "/imu/data"]) == "imu/data"  # the exact name first
    assert resolve_topic("imu/data", ["/ns/imu/data", "/imu/data_raw"]) is None  # another namespace is another topic


@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> tuple[Path, Path]:
    """A simulated zig-zag (relative topic names, as `replay simulate` writes) and its copy with every topic fully
    qualified, as `ros2 bag record` writes them."""
    root = tmp_path_factory.mktemp("topics")
    assert cli.main(["simulate", "--manoeuvre", "zigzag", "--duration", "40", "--output", str(root / "rel")]) == 0
    [relative] = [p.parent for p in (root / "rel").rglob("metadata.yaml")]
    streams, custom = bag_streams(relative)
    qualified = [(dataclasses.replace(spec, topic="/" + spec.topic), signal) for spec, signal in streams]
    absolute = write_variant(root / "abs" / relative.name, qualified, custom)
    return relative, absolute


def test_a_bag_with_fully_qualified_topics_reads_like_the_relative_one(bags) -> None:
    relative, absolute = bags
    present, _ = bag_metadata(absolute)
    assert "/imu/data" in present and "imu/data" not in present  # the bag really is qualified
    warnings: list[str] = []
    [a] = load_recordings([absolute], 0.5, warn=warnings.append)
    [r] = load_recordings([relative], 0.5)
    assert warnings == []  # nothing missing: not even the optional GNSS and ground truth
    assert np.array_equal(a.nu, r.nu)
    assert np.array_equal(a.controls, r.controls)
    assert a.truth is not None
    assert np.array_equal(a.position, r.position, equal_nan=True)


def test_replay_dataset_reads_qualified_topics(bags, tmp_path: Path, capsys) -> None:
    _, absolute = bags
    code = cli.main(["dataset", str(absolute), "--val", "0", "--output", str(tmp_path / "ds.npz")])
    assert code == 0, capsys.readouterr().err


CONFIG_FREE = {"info"}  # lists every topic of a bag whatever the config says: it reads no configured topic


def _bag_commands() -> list[str]:
    """The commands that read configured topics from bags: those whose INPUTS name bags (or bag-or-evaluation
    inputs), but `info`."""
    names = []
    for module_name in cli.COMMANDS:
        module = importlib.import_module(module_name)
        if {"bags", "inputs"} & set(getattr(module, "INPUTS", ())) and module.NAME not in CONFIG_FREE:
            names.append(module.NAME)
    return names


def test_the_bag_commands_are_found() -> None:
    assert {"dataset", "evaluate", "report", "identify", "diagnose"} <= set(_bag_commands())


@pytest.mark.parametrize("name", _bag_commands())
def test_every_command_that_reads_bags_takes_config(name: str, capsys) -> None:
    assert cli.main([name, "--help"]) == 0
    assert "--config" in capsys.readouterr().out
    module = importlib.import_module(f"usv_predictor.replay.cmd_{name}")
    assert "config" in module.INPUTS  # a config file is an input: never overwritten by an output


def test_identify_reads_the_topics_of_its_config(bags, tmp_path: Path, capsys) -> None:
    """The config renames the engine-speed topic: identify looks for that name (and says so) instead of the default."""
    _, absolute = bags
    config = yaml.safe_load(Path("config/predictor.yaml").read_text())
    config["predictor"]["ros__parameters"]["inputs"]["engine_rpm"]["topic"] = "propulsion/rpm"
    path = tmp_path / "renamed.yaml"
    path.write_text(yaml.safe_dump(config))
    code = cli.main(["identify", str(absolute), "--vessel", "jari_usv", "--prior", "fix", "--config", str(path),
                     "--output", str(tmp_path / "m.pt")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2, err[-1]
    assert "'propulsion/rpm'" in err[-1], err[-1]
    assert "/engine_rpm" in err[-1], err[-1]
