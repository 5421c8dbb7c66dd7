"""Shared pytest fixtures.

`raw_data_dir`: the public raw data sets in ../shared/data/raw (relative to the repository root).
Tests that use it are skipped with a clear reason when the folder is absent (a plain clone), but
when the CI environment variable is set (CI=true in .ci/run) the absence is a test FAILURE, so a
CI run can never pass by silently skipping the tests on real data.
"""
from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]

if os.environ.get("PYTEST_XDIST_WORKER"):
    # Two workers share two cores (./run.sh test -n 2): one math thread each (torch, numpy's BLAS, and the
    # commands the tests start), or OpenMP's spinning threads of one worker steal the other's core.
    for _name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(_name, "1")
RAW_DATA_DIR = REPO_ROOT.parent / "shared" / "data" / "raw"


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "slow: a case that runs processes (signals, file-size limits) or long commands; still run by "
                   "default, deselect with -m 'not slow'")


def running_in_ci() -> bool:
    """True when CI is set to anything but an explicit no (CI=true, CI=1, ...)."""
    return os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO_ROOT


@pytest.fixture(scope="session")
def raw_data_dir() -> Path:
    """Path of ../shared/data/raw; skip when absent, but fail under CI."""
    if RAW_DATA_DIR.is_dir() and any(RAW_DATA_DIR.iterdir()):
        return RAW_DATA_DIR
    reason = f"raw data folder {RAW_DATA_DIR} is absent or empty (expected ../shared/data/raw beside the repo)"
    if running_in_ci():
        pytest.fail(f"{reason}; CI is set, so tests on real data must not be skipped", pytrace=False)
    pytest.skip(reason)


@pytest.fixture()
def ros_context(monkeypatch: pytest.MonkeyPatch) -> Iterator[Any]:
    """A private rclpy context (rclpy.context.Context) on this process's domain, discovery on this host only
    (the node tests; rclpy is imported here, not when a test without ROS collects this file)."""
    import rclpy
    from rclpy.context import Context

    from ros_helpers import domain_id

    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    context = Context()
    rclpy.init(context=context, domain_id=domain_id(0))
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)
