"""Outputs: written atomically, never onto an input, and JSON that holds only what JSON can.

Atomic files: written beside the target under a temporary name, renamed onto it when complete. A reader never
sees a half-written output, a failure (disk full, file-size limit, Ctrl-C) removes the temporary file and leaves
the previous file (or nothing) in place, and the result is readable like any other output (mkstemp makes files
private; we publish them as 0644). A full disk or the file-size limit reads "cannot write X: no space left (...)".

Strict JSON: `jsonable` turns numpy scalars and arrays, paths and tuples into JSON values and refuses NaN and
infinity with an OutputError naming the field (`identification.collinearity[1].vif.Y_0 is nan`): JSON has no
such numbers, so a value that is undefined must be written as None on purpose where it is made
(`finite_or_none`), never replaced silently on the way out.

Inputs: `check_outputs` refuses, before any work, an output that is an input, lies inside one (a bag is a
directory) or inside any bag, would replace an input, repeats another output, or cannot be created.
"""
from __future__ import annotations

import errno
import json
import math
import os
import sqlite3
import stat
import tempfile
from collections.abc import Collection, Iterable, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any, Iterator

import numpy as np

from usv_predictor.errors import OutputError, UsvPredictorError

OUTPUT_MODE = 0o644
# errno values that mean "the bytes do not fit": disk full, the file-size limit (ulimit -f), a quota
NO_SPACE_ERRNOS = frozenset({errno.ENOSPC, errno.EFBIG, errno.EDQUOT})
PROBE_PREFIX = ".usv_predictor_probe."
BAG_METADATA = "metadata.yaml"  # what makes a directory a rosbag2 bag


# ----------------------------------------------------------------------------- atomic files

def write_failure(err: BaseException) -> str:
    """Why a write failed, in words: 'no space left (...)' for a full disk or the file-size limit."""
    if isinstance(err, OSError) and err.errno in NO_SPACE_ERRNOS:
        return f"no space left ({err.strerror})"
    if isinstance(err, sqlite3.Error) and "full" in str(err):  # sqlite words a full disk as "database or disk is full"
        return f"no space left ({err})"
    if isinstance(err, sqlite3.Error) and str(getattr(err, "sqlite_errorname", "")).startswith("SQLITE_IOERR"):
        return f"{err} (a full disk or the file-size limit?)"  # how sqlite reports EFBIG
    if isinstance(err, OSError) and err.strerror:
        return err.strerror
    return str(err) or type(err).__name__


def special_file(path: str | os.PathLike[str]) -> str | None:
    """What `path` is when it exists and is neither a regular file nor a directory (the link itself is looked at,
    not what it points to): "a symbolic link to /dev/stdout", "a character device", ...; None otherwise. An output
    never replaces such a file: renaming a new file onto /dev/null (a copy of it, a link to the terminal) would
    turn a device into a regular file, and a link into a file that no longer points anywhere."""
    try:
        info = os.lstat(path)
    except OSError:
        return None
    if stat.S_ISREG(info.st_mode) or stat.S_ISDIR(info.st_mode):
        return None
    if stat.S_ISLNK(info.st_mode):
        return f"a symbolic link to {os.readlink(path)}"
    kinds = ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
             (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))
    return next((name for test, name in kinds if test(info.st_mode)), "not a regular file")


@contextmanager
def atomic_path(path: str | os.PathLike[str], error: type[Exception] = UsvPredictorError,
                what: str = "output") -> Iterator[Path]:
    """Yield a temporary path beside `path`; rename it onto `path` on success, remove it on any failure.

    OSError (directory not creatable, disk full, ...) becomes `error` naming the path: "cannot write X: why"; a
    `path` that is a special file (special_file: a device, a FIFO, a link) is refused and left as it is.
    """
    path = Path(path)
    special = special_file(path)
    if special is not None:
        raise error(f"cannot write {what} {path}: it is {special}, and an output replaces only a regular file")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent)
        os.close(fd)
    except OSError as err:
        raise error(f"cannot write {what} {path}: {write_failure(err)}") from err
    try:
        yield Path(tmp)
        os.chmod(tmp, OUTPUT_MODE)
        os.replace(tmp, path)
    except OSError as err:
        Path(tmp).unlink(missing_ok=True)
        raise error(f"cannot write {what} {path}: {write_failure(err)}") from err
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


def write_bytes_atomic(path: str | os.PathLike[str], data: bytes, error: type[Exception] = UsvPredictorError,
                       what: str = "output") -> None:
    """Write `data` via a temporary file and os.replace (for writers that cannot fail cleanly themselves:
    serialise into memory first, then write the bytes here)."""
    with atomic_open(path, "wb", error, what) as out:
        out.write(data)


def write_text_atomic(path: Path, text: str, what: str = "output") -> None:
    """Write a UTF-8 text file via a temporary file and os.replace."""
    with atomic_open(path, "w", UsvPredictorError, what) as out:
        out.write(text)


# ----------------------------------------------------------------------------- strict JSON

def finite_or_none(value: Any) -> float | None:
    """A number as a float, or None when it is missing or not finite: how an undefined value is written to JSON."""
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _plain(value: Any, where: str, what: str) -> Any:
    if isinstance(value, dict):
        return {str(k): _plain(v, f"{where}.{k}" if where else str(k), what) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v, f"{where}[{i}]", what) for i, v in enumerate(value)]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist(), where, what)
    if isinstance(value, np.generic):
        return _plain(value.item(), where, what)
    if isinstance(value, float) and not math.isfinite(value):
        raise OutputError(f"{what}: field {where or '(top level)'} is {value}, and JSON has no NaN or infinity "
                          f"(a value without a definition must be written as null where it is made)")
    if isinstance(value, Path):
        return str(value)
    return value


def jsonable(value: Any, what: str = "JSON") -> Any:
    """JSON-ready copy: numpy scalars/arrays and tuples -> lists and numbers, paths -> str, keys -> str.

    NaN or infinity anywhere is an OutputError naming `what` and the field (e.g. `evidence[2].heldout_loss`).
    """
    return _plain(value, "", what)


def json_text(value: Any, what: str = "JSON") -> str:
    """`value` as strict JSON text (sorted keys, indented, one trailing newline); OutputError naming a NaN/inf field."""
    return json.dumps(jsonable(value, what), indent=2, sort_keys=True, allow_nan=False) + "\n"


def write_json_atomic(path: Path, result: dict, what: str = "--json") -> None:
    """Write `result` as strict JSON (json_text) to `path` via a temporary file and os.replace."""
    text = json_text(result, f"{what} {path}")
    with atomic_open(path, "w", OutputError, what) as out:
        out.write(text)


# ----------------------------------------------------------------------------- outputs apart from inputs

def _resolved(path: str | os.PathLike[str]) -> Path:
    return Path(path).expanduser().resolve(strict=False)


def _within(child: Path, parent: Path) -> bool:
    return child == parent or parent in child.parents


def _probe_writable(option: str, given: Path, target: Path, directory: bool) -> None:
    """The output can be created: its nearest existing ancestor is a directory in which a file can be made
    (tried, not guessed: os.access says yes to root on a read-only file system)."""
    if target.exists():
        if directory and not target.is_dir():
            raise OutputError(f"{option} {given} exists and is not a directory")
        if not directory and target.is_dir():
            raise OutputError(f"{option} {given} is a directory; give a file name")
    base = target if directory and target.is_dir() else target.parent
    while not base.exists() and base != base.parent:
        base = base.parent
    if not base.is_dir():
        raise OutputError(f"cannot write {option} {given}: {base} is not a directory")
    try:
        fd, probe = tempfile.mkstemp(prefix=PROBE_PREFIX, dir=base)
        os.close(fd)
        os.unlink(probe)
    except OSError as err:
        raise OutputError(f"cannot write {option} {given}: {base} is not writable ({write_failure(err)})") from err


def check_outputs(outputs: Mapping[str, str | os.PathLike[str] | None],
                  inputs: Iterable[str | os.PathLike[str] | None], directories: Collection[str] = ()) -> None:
    """Before any work, refuse (OutputError naming the option, the path and the input) an output that

    - is an input, or lies inside an input directory (a bag is a directory): inputs are only read;
    - is a file output where a directory holding an input is (it would replace that directory);
    - is, or lies inside, a rosbag2 bag (a directory holding metadata.yaml), an input or not;
    - is the same path as another output;
    - is a special file (a device, a FIFO, a link, but a link to a directory for a directory output);
    - cannot be created (its nearest existing ancestor is not a directory, or no file can be made there).

    outputs: option -> path (None: not asked for); inputs: paths (those that do not exist are skipped: reading
    them fails on its own); directories: the options whose output is a directory (an input may lie inside it).
    """
    existing = [(Path(i), _resolved(i)) for i in inputs if i is not None and Path(i).exists()]
    seen: dict[Path, str] = {}
    for option, path in outputs.items():
        if path is None:
            continue
        given, target = Path(path), _resolved(path)
        for source_given, source in existing:
            if target == source:
                raise OutputError(f"{option} {given} is the input {source_given}: an input is never replaced")
            if source.is_dir() and _within(target, source):
                raise OutputError(f"{option} {given} is inside the input {source_given}: inputs are only read")
            if option not in directories and _within(source, target):
                raise OutputError(f"{option} {given} would replace the directory holding the input {source_given}")
        special = special_file(given)
        if special is not None and not (option in directories and given.is_dir()):  # a link to a directory is fine
            raise OutputError(f"{option} {given} is {special}: an output replaces only a regular file (give a new "
                              "file name)")
        bag = next((d for d in (target, *target.parents) if (d / BAG_METADATA).is_file()), None)
        if bag is not None:
            raise OutputError(f"{option} {given} is {'the' if bag == target else 'inside the'} rosbag2 bag {bag}: "
                              "a recording is not an output folder")
        if target in seen:
            raise OutputError(f"{option} {given} is also {seen[target]}: give each output its own path")
        seen[target] = option
        _probe_writable(option, given, target, option in directories)


# ----------------------------------------------------------------------------- one writer per output

LOCK_DIR_NAME = "usv_predictor_output_locks"  # in the system's temporary directory: never inside an output


@contextmanager
def output_locks(outputs: Mapping[str, str | os.PathLike[str] | None]) -> Iterator[None]:
    """Hold an exclusive lock on every output (option -> path, None: not asked for) while the command runs; an
    output another process holds is an OutputError naming it, before any work: two `evaluate` into one folder at once
    mixed their files. The locks are flock()s on files named by the sha256 of each resolved path, in the system's
    temporary directory (never beside the output: nothing is left there); the kernel drops them when the process
    ends, however it ends."""
    import fcntl
    import hashlib

    held: list[int] = []
    try:
        directory = Path(tempfile.gettempdir()) / LOCK_DIR_NAME
        directory.mkdir(mode=0o1777, exist_ok=True)
        for option, path in outputs.items():
            if path is None:
                continue
            key = hashlib.sha256(str(_resolved(path)).encode()).hexdigest()[:32]
            try:
                fd = os.open(directory / f"{key}.lock", os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o666)
            except OSError:
                continue  # no lock to be had (a read-only /tmp): the outputs are still atomic, only not exclusive
            held.append(fd)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError as err:
                raise OutputError(f"{option} {path} is being written by another run of this tool right now: wait for "
                                  "it to end, or give another path") from err
        yield
    finally:
        for fd in held:
            os.close(fd)  # closing drops the flock
