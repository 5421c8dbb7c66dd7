"""Atomic output files: written beside the target under a temporary name, renamed onto it when complete.

A reader never sees a half-written output, a failure leaves the previous file (or nothing) in place, and the
result is readable like any other output (mkstemp makes files private; we publish them as 0644).
"""
from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Iterator

from usv_predictor.errors import UsvPredictorError

OUTPUT_MODE = 0o644


@contextmanager
def atomic_path(path: str | os.PathLike[str], error: type[Exception] = UsvPredictorError,
                what: str = "output") -> Iterator[Path]:
    """Yield a temporary path beside `path`; rename it onto `path` on success, remove it on failure.

    OSError (directory not creatable, disk full, ...) becomes `error` naming the path.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent)
        os.close(fd)
    except OSError as err:
        raise error(f"cannot write {what} {path}: {err}") from err
    try:
        yield Path(tmp)
        os.chmod(tmp, OUTPUT_MODE)
        os.replace(tmp, path)
    except OSError as err:
        Path(tmp).unlink(missing_ok=True)
        raise error(f"cannot write {what} {path}: {err}") from err
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


@contextmanager
def atomic_open(path: str | os.PathLike[str], mode: str = "w", error: type[Exception] = UsvPredictorError,
                what: str = "output") -> Iterator[IO]:
    """atomic_path as an open file object ("w" text in UTF-8, or "wb")."""
    with atomic_path(path, error, what) as tmp:
        with open(tmp, mode, **({} if "b" in mode else {"encoding": "utf-8"})) as out:
            yield out
