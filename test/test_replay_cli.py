"""The `replay` command line: help for the tool and every command, `info` on a tiny bag, --json,
and one-line errors with exit code 2."""
from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from msg_adapters import ROLE_FIELDS
from usv_predictor.records import Signal
from usv_predictor.replay import cli
from usv_predictor.replay.bagio import TopicSpec, bag_info, write_bag

REPO_ROOT = Path(__file__).resolve().parents[1]


def _importable_commands() -> list[str]:
    names = []
    for module_name in cli.COMMANDS:
        try:
            names.append(importlib.import_module(module_name).NAME)
        except ImportError:
            continue  # a command another issue has not delivered yet
    return names


@pytest.fixture()
def tiny_bag(tmp_path: Path) -> Path:
    t_ns = 1_700_000_000_000_000_000 + np.arange(20, dtype=np.int64) * 100_000_000  # 10 Hz, 1.9 s
    streams = [
        (TopicSpec("heading", "heading", "std_msgs/msg/Float64"),
         Signal(t_ns, np.zeros((20, 1)), ROLE_FIELDS["heading"])),
        (
            TopicSpec("velocity", "velocity", "geometry_msgs/msg/TwistStamped"),
            Signal(t_ns[::2], np.ones((10, 3)), ROLE_FIELDS["velocity"]),
        ),
    ]
    return write_bag(tmp_path / "tiny", streams, metadata={"generator": "test_replay_cli"})


def test_tool_help_lists_the_commands(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: replay")
    for name in _importable_commands():
        assert name in out


@pytest.mark.parametrize("name", _importable_commands())
def test_every_command_has_help_and_json(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main([name, "--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: replay {name}")
    assert "--json PATH" in out


def test_command_modules_follow_the_naming_convention() -> None:
    for module_name in cli.COMMANDS:
        try:
            module = importlib.import_module(module_name)
        except ImportError:
            continue
        assert module.NAME == cli._command_name(module_name)
        assert module.HELP
        assert callable(module.add_arguments)
        assert callable(module.run)


def test_a_missing_command_module_does_not_break_help(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(cli, "COMMANDS", ("usv_predictor.replay.cmd_not_written_yet", *cli.COMMANDS))
    assert cli.main(["--help"]) == 0
    captured = capsys.readouterr()
    assert "info" in captured.out
    assert "cmd_not_written_yet unavailable" in captured.err


def test_info_prints_a_summary_and_writes_json(tiny_bag: Path, tmp_path: Path, capsys) -> None:
    json_path = tmp_path / "out" / "info.json"
    assert cli.main(["info", str(tiny_bag), "--json", str(json_path)]) == 0
    captured = capsys.readouterr()
    assert "velocity" in captured.out
    assert "geometry_msgs/msg/TwistStamped" in captured.out
    assert "10.00 Hz" in captured.out
    assert "5.00 Hz" in captured.out
    assert "generator: test_replay_cli" in captured.out
    assert f"reading {tiny_bag}" in captured.err  # progress goes to stderr
    result = json.loads(json_path.read_text())
    expected = bag_info(tiny_bag)
    assert result["bags"][0]["message_count"] == expected["message_count"] == 30
    assert result["bags"][0]["custom_data"] == {"generator": "test_replay_cli"}
    assert [t["topic"] for t in result["bags"][0]["topics"]] == ["heading", "velocity"]
    assert list(json_path.parent.iterdir()) == [json_path]  # no temporary file left behind


@pytest.mark.parametrize(
    ("argv", "prefix", "fragment"),
    [
        (["info"], "replay info: error:", "required: BAG"),
        (["info", "/nonexistent/bag"], "replay info: error:", "/nonexistent/bag: no such bag"),
        (["info", "x", "--bogus"], "replay: error:", "unrecognized arguments: --bogus"),
        (["no-such-command"], "replay: error:", "invalid choice"),
        ([], "replay: error:", "a command is required"),
    ],
)
def test_errors_are_one_line_with_exit_code_2(argv, prefix, fragment, capsys) -> None:
    assert cli.main(argv) == 2
    err_lines = [line for line in capsys.readouterr().err.splitlines() if not line.startswith("reading ")]
    assert len(err_lines) == 1
    assert err_lines[0].startswith(prefix)
    assert fragment in err_lines[0]


def test_corrupt_bag_error_and_no_json(tmp_path: Path, capsys) -> None:
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "metadata.yaml").write_text("rosbag2_bagfile_information: [")
    json_path = tmp_path / "result.json"
    assert cli.main(["info", str(tmp_path / "broken"), "--json", str(json_path)]) == 2
    assert "replay info: error:" in capsys.readouterr().err
    assert not json_path.exists()


def test_python_dash_m_entry_point(tiny_bag: Path) -> None:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO_ROOT), os.environ.get("PYTHONPATH", "")])}
    run = [sys.executable, "-m", "usv_predictor.replay"]
    done = subprocess.run([*run, "info", str(tiny_bag)], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "std_msgs/msg/Float64" in done.stdout
    failed = subprocess.run([*run, "info"], capture_output=True, text=True, env=env, timeout=120)
    assert failed.returncode == 2
    assert failed.stderr.strip().startswith("replay info: error:")


def test_help_does_not_import_heavy_modules() -> None:
    code = (
        "import sys\n"
        "from usv_predictor.replay import cli\n"
        "assert cli.main(['--help']) == 0\n"
        "heavy = sorted(m for m in ('rosbags', 'torch', 'rclpy') if m in sys.modules)\n"
        "print('heavy:', heavy)\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO_ROOT), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().endswith("heavy: []")
