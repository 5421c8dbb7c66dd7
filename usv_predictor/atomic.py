"""Atomic output files: written beside the target under a temporary name, renamed onto it when complete.

A reader never sees a half-written output, a failure leaves the previous file (or nothing) in place, and the
result is readable like any other output (mkstemp makes files private; we publish them as 0644).
"""
from __future__ import annotations

import json
import math
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any, Iterator

import numpy as np

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


def jsonable(value: Any) -> Any:
    """JSON-friendly copy: numpy scalars/arrays, paths, NaN/inf (-> null) handled."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, np.generic):
        return jsonable(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Path):
        return str(value)
    return value


def write_json_atomic(path: Path, result: dict, what: str = "--json") -> None:
    """Write `result` as JSON (jsonable, sorted keys) to `path` via a temporary file and os.replace."""
    text = json.dumps(jsonable(result), indent=2, sort_keys=True) + "\n"
    with atomic_open(path, "w", UsvPredictorError, what) as out:
        out.write(text)


def write_text_atomic(path: Path, text: str, what: str = "output") -> None:
    """Write a UTF-8 text file via a temporary file and os.replace."""
    with atomic_open(path, "w", UsvPredictorError, what) as out:
        out.write(text)
