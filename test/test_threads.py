"""How a process of the package uses the cores: numpy's BLAS runs on one thread (usv_predictor/__init__.py).

Counted from outside, in a child process: OpenBLAS starts its pool of threads when numpy is first imported, so the
threads a child gains across `import numpy` are the BLAS pool's.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
# OpenBLAS reads these, first to last, for its thread count; the parent's (conftest sets some for xdist workers)
# must not decide the child's.
BLAS_VARIABLES = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")


def threads_gained(imports: str, **variables: str) -> int:
    """Threads a fresh interpreter has after `imports` minus before them (Linux: /proc/self/task)."""
    env = {k: v for k, v in os.environ.items() if k not in BLAS_VARIABLES} | variables
    code = ("import os; before = len(os.listdir('/proc/self/task')); " + imports +
            "; print(len(os.listdir('/proc/self/task')) - before)")
    done = subprocess.run([sys.executable, "-c", code], env=env, cwd=REPO_ROOT, capture_output=True, text=True,
                          timeout=120, check=True)
    return int(done.stdout.strip())


@pytest.fixture(scope="module")
def numpy_alone() -> int:
    if not Path("/proc/self/task").is_dir():
        pytest.skip("threads are counted in /proc/self/task (Linux)")
    gained = threads_gained("import numpy")
    if gained < 1:
        pytest.skip(f"numpy's BLAS starts no thread of its own on this machine ({os.cpu_count()} cpus): nothing to "
                    "limit")
    return gained


def test_the_package_gives_numpy_one_blas_thread(numpy_alone: int) -> None:
    assert threads_gained("import usv_predictor, numpy") == 0, \
        f"numpy alone starts {numpy_alone} BLAS threads; after usv_predictor it must start none"


def test_a_blas_thread_count_the_user_set_is_kept(numpy_alone: int) -> None:
    assert threads_gained("import usv_predictor, numpy", OPENBLAS_NUM_THREADS="2") == 1
