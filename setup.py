"""ament_python packaging of usv_predictor (layout of ros2/demo_nodes_py, jazzy).

Installs the Python packages, the ament index marker, package.xml, the config and vessel presets,
the small demo/test bags and any shipped models under share/usv_predictor, and the console
scripts `predictor` and `replay` (into lib/usv_predictor for `ros2 run`, see setup.cfg).
"""
from __future__ import annotations

import re
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE_NAME = "usv_predictor"
HERE = Path(__file__).resolve().parent


def read_version() -> str:
    """The single version number lives in usv_predictor/__init__.py (package.xml must agree)."""
    text = (HERE / PACKAGE_NAME / "__init__.py").read_text(encoding="utf-8")
    match = re.search(r'^__version__ = "([^"]+)"', text, re.MULTILINE)
    if match is None:
        raise RuntimeError(f"{PACKAGE_NAME}/__init__.py has no __version__ line")
    return match.group(1)


def tree_data_files(folder: str) -> list[tuple[str, list[str]]]:
    """data_files entries for every file under `folder`, keeping its sub-folders (rosbag2 dirs).

    Paths are relative to setup.py, as setuptools requires; a missing folder installs nothing.
    """
    root = HERE / folder
    if not root.is_dir():
        return []
    by_dir: dict[str, list[str]] = {}
    for path in sorted(root.rglob("*")):
        if path.is_file() and "__pycache__" not in path.parts:
            relative = path.relative_to(HERE)
            by_dir.setdefault(str(relative.parent), []).append(str(relative))
    return [(f"share/{PACKAGE_NAME}/{directory}", files) for directory, files in by_dir.items()]


def flat_data_files(folder: str, pattern: str) -> list[tuple[str, list[str]]]:
    """data_files entry for the files of one folder matching `pattern` (none if there are none)."""
    files = sorted(str(p.relative_to(HERE)) for p in (HERE / folder).glob(pattern) if p.is_file())
    return [(f"share/{PACKAGE_NAME}/{folder}", files)] if files else []


setup(
    name=PACKAGE_NAME,
    version=read_version(),
    packages=find_packages(include=[PACKAGE_NAME, f"{PACKAGE_NAME}.*", "msg_adapters", "msg_adapters.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE_NAME}"]),
        (f"share/{PACKAGE_NAME}", ["package.xml"]),
        *flat_data_files("config", "*.yaml"),
        *flat_data_files("config/vessels", "*.yaml"),
        *tree_data_files("bags"),
        *tree_data_files("models"),
    ],
    install_requires=["setuptools"],
    maintainer="usv_predictor maintainers",
    maintainer_email="maintainers@example.com",
    description="Online 3-DOF motion prediction for unmanned surface vehicles (node + bag replay tool).",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "predictor = usv_predictor.node:main",
            "replay = usv_predictor.replay.cli:main",
        ],
    },
)
