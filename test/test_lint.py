"""The linter is part of the suite: `ruff check` (pinned in requirements.txt, configured in ruff.toml) on the package,
the message adapters, the tests, the benchmarks, the tools and setup.py, as navigation2's packages run flake8."""
from __future__ import annotations

import re
import subprocess
from pathlib import Path

from replay_helpers import pinned_tool

REPO_ROOT = Path(__file__).resolve().parents[1]
CHECKED = ("usv_predictor", "msg_adapters", "test", "benchmarks", "tools", "setup.py")


def ruff_executable() -> str:
    return pinned_tool("ruff")


def test_ruff_is_the_pinned_version() -> None:
    pinned = re.search(r"^ruff==(\S+)", (REPO_ROOT / "requirements.txt").read_text(encoding="utf-8"), re.MULTILINE)
    assert pinned, "requirements.txt does not pin ruff"
    done = subprocess.run([ruff_executable(), "--version"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split()[-1] == pinned.group(1), f"{done.stdout.strip()}, requirements.txt pins {pinned.group(1)}"


def test_ruff_check_passes() -> None:
    done = subprocess.run([ruff_executable(), "check", "--no-cache", "--config", str(REPO_ROOT / "ruff.toml"),
                           *CHECKED], cwd=REPO_ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, f"ruff check found problems:\n{done.stdout}{done.stderr}"
