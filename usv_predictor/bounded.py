"""Bounded reading of the YAML and JSON files the tools are given: the one way a user-supplied document is read.

Every file read as YAML or JSON (a bag's metadata.yaml, a vessel file, config/predictor.yaml, an evaluation or
identification result, a model's embedded metadata.json and vessel.json) goes through `load_yaml` / `load_json`
(`parse_yaml` / `parse_json` for text that is already in memory, e.g. a model's extra files). They refuse, with
the caller's error class and one line naming the file:

- what is not a regular file, checked with stat before anything opens it (a FIFO would block the open, a
  character device such as /dev/zero never ends, a link loop is ELOOP); the open itself is non-blocking and
  checked again with fstat, so a file swapped for a FIFO after the stat cannot block either;
- more than MAX_BYTES bytes (stat size, then at most MAX_BYTES + 1 bytes are read);
- nesting deeper than MAX_DEPTH (YAML: counted while the document is composed, before the recursive composer can
  hit Python's recursion limit; JSON: a RecursionError of the decoder, then an iterative walk);
- a YAML document that expands to more than MAX_NODES nodes through its aliases (the "billion laughs": ten
  aliases of ten aliases of ... are few bytes and 10^9 nodes for whoever walks them);
- an alias inside the node it names (a cyclic document, which every walk of it would follow for ever);
- YAML tags other than the standard ones (`!!python/object`, ...): yaml.SafeLoader's constructor refuses them.

YAML is parsed by libyaml's event parser when present (the C scanner: a file of comments is read at C speed) and
composed here in Python, where the depth and the expansion are counted.
"""
from __future__ import annotations

import errno
import json
import os
import stat
from typing import Any

import yaml
from yaml.composer import Composer, ComposerError
from yaml.constructor import SafeConstructor
from yaml.resolver import Resolver

MAX_BYTES = 16 << 20  # a document larger than this is not a configuration or a metadata file (bytes)
MAX_DEPTH = 64  # nesting levels of mappings and sequences; the project's files use fewer than 10
MAX_NODES = 1_000_000  # nodes of a YAML document with its aliases expanded

try:  # libyaml's event parser
    from yaml._yaml import CParser as _Parser
except ImportError:  # pure Python: reader, scanner and parser
    class _Parser(yaml.reader.Reader, yaml.scanner.Scanner, yaml.parser.Parser):  # type: ignore[no-redef]
        def __init__(self, stream: Any) -> None:
            yaml.reader.Reader.__init__(self, stream)
            yaml.scanner.Scanner.__init__(self)
            yaml.parser.Parser.__init__(self)


def _kind(mode: int) -> str:
    kinds = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
             (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))
    return next((name for test, name in kinds if test(mode)), "not a regular file")


def regular_file(path: str | os.PathLike[str], what: str, error: type[Exception],
                 max_bytes: int = MAX_BYTES) -> os.stat_result:
    """stat of `path` when it is a regular file of at most `max_bytes` (links followed); `error` naming `what` and
    the path otherwise (missing, a link loop, a FIFO, a device, a directory, too large). Nothing is opened."""
    try:
        info = os.stat(path)
    except OSError as err:
        if err.errno == errno.ELOOP:
            raise error(f"cannot read {what} {path}: a loop of symbolic links") from err
        if err.errno == errno.ENOENT:
            raise error(f"cannot read {what} {path}: no such file") from err
        raise error(f"cannot read {what} {path}: {err.strerror or err}") from err
    if not stat.S_ISREG(info.st_mode):
        raise error(f"cannot read {what} {path}: it is {_kind(info.st_mode)}, expected a regular file")
    if info.st_size > max_bytes:
        raise error(f"cannot read {what} {path}: {info.st_size} bytes, more than the {max_bytes} such a file may have")
    return info


def read_bytes(path: str | os.PathLike[str], what: str, error: type[Exception], max_bytes: int = MAX_BYTES) -> bytes:
    """The bytes of a regular file of at most `max_bytes` (regular_file), read without ever blocking."""
    regular_file(path, what, error, max_bytes)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | getattr(os, "O_CLOEXEC", 0))
    except OSError as err:
        raise error(f"cannot read {what} {path}: {err.strerror or err}") from err
    try:
        info = os.fstat(fd)  # what was opened, which may not be what was stat'ed a moment ago
        if not stat.S_ISREG(info.st_mode):
            raise error(f"cannot read {what} {path}: it is {_kind(info.st_mode)}, expected a regular file")
        chunks, size = [], 0
        while size <= max_bytes:
            chunk = os.read(fd, min(1 << 20, max_bytes + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
    except OSError as err:
        raise error(f"cannot read {what} {path}: {err.strerror or err}") from err
    finally:
        os.close(fd)
    if size > max_bytes:
        raise error(f"cannot read {what} {path}: more than the {max_bytes} bytes such a file may have")
    return b"".join(chunks)


def read_text(path: str | os.PathLike[str], what: str, error: type[Exception], max_bytes: int = MAX_BYTES) -> str:
    """read_bytes decoded as UTF-8 (`error` naming the byte offset otherwise)."""
    data = read_bytes(path, what, error, max_bytes)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise error(f"cannot read {what} {path}: not UTF-8 text (byte {err.start}: {err.reason})") from err


# ----------------------------------------------------------------------------- YAML


class _BoundedComposer(Composer):
    """yaml's composer counting the depth and the expanded size of the document as it composes it."""

    def __init__(self) -> None:
        super().__init__()
        self._depth = 0
        self._nodes = 0  # composed so far, each alias counted as the nodes it stands for
        self._weights: dict[str, int] = {}  # anchor -> nodes under it, aliases expanded
        self._open: set[str] = set()  # anchors whose node is being composed

    def compose_node(self, parent: Any, index: Any) -> Any:
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent):
            if event.anchor in self._open:
                raise ComposerError(None, None, f"alias *{event.anchor} refers to a node that holds it (a cycle)",
                                    event.start_mark)
            self._nodes += self._weights.get(event.anchor, 1)
            self._check_size(event)
            return super().compose_node(parent, index)
        self._depth += 1
        if self._depth > MAX_DEPTH:
            raise ComposerError(None, None, f"nested deeper than {MAX_DEPTH} levels", event.start_mark)
        start = self._nodes
        self._nodes += 1
        self._check_size(event)
        anchor = getattr(event, "anchor", None)
        if anchor is not None:
            self._open.add(anchor)
        try:
            node = super().compose_node(parent, index)
        finally:
            self._depth -= 1
            self._open.discard(anchor)
        if anchor is not None:
            self._weights[anchor] = self._nodes - start
        return node

    def _check_size(self, event: Any) -> None:
        if self._nodes > MAX_NODES:
            raise ComposerError(None, None, f"expands to more than {MAX_NODES} nodes through its aliases "
                                            "(an alias bomb?)", event.start_mark)


class BoundedSafeLoader(_BoundedComposer, _Parser, SafeConstructor, Resolver):  # type: ignore[misc, valid-type]
    """yaml.SafeLoader (libyaml's parser when present) with the composer above: standard tags only, bounded."""

    def __init__(self, stream: Any) -> None:
        _Parser.__init__(self, stream)
        _BoundedComposer.__init__(self)
        SafeConstructor.__init__(self)
        Resolver.__init__(self)


def _yaml_problem(err: yaml.YAMLError) -> str:
    mark = getattr(err, "problem_mark", None)
    problem = getattr(err, "problem", None) or str(err).strip().splitlines()[0]
    if mark is None:
        return str(problem)
    return f"{problem} (line {mark.line + 1}, column {mark.column + 1})"


def parse_yaml(text: str | bytes, source: str, error: type[Exception]) -> Any:
    """The YAML document of `text`, bounded as the module docstring says; `error` "SOURCE: not valid YAML: why"."""
    if len(text) > MAX_BYTES:
        raise error(f"{source}: more than the {MAX_BYTES} bytes such a document may have")
    try:
        loader = BoundedSafeLoader(text)
        try:
            return loader.get_single_data()
        finally:
            loader.dispose()
    except yaml.YAMLError as err:
        raise error(f"{source}: not valid YAML: {_yaml_problem(err)}") from err
    except RecursionError as err:  # cannot happen below MAX_DEPTH; kept so that it can never be a traceback
        raise error(f"{source}: not valid YAML: nested too deeply") from err


def load_yaml(path: str | os.PathLike[str], what: str, error: type[Exception]) -> Any:
    """The YAML document of the file `path` (a `what`, e.g. "vessel file"), bounded (module docstring)."""
    return parse_yaml(read_text(path, what, error), f"cannot read {what} {path}", error)


# ----------------------------------------------------------------------------- JSON


def _depth_within(value: Any, limit: int) -> bool:
    stack = [(value, 1)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, (dict, list)):
            if depth > limit:
                return False
            stack.extend((child, depth + 1) for child in (item.values() if isinstance(item, dict) else item))
    return True


def parse_json(text: str | bytes, source: str, error: type[Exception], **loads: Any) -> Any:
    """The JSON document of `text`, at most MAX_BYTES and MAX_DEPTH deep; `error` "SOURCE: not valid JSON: why".
    `loads` go to json.loads (e.g. parse_constant to refuse NaN)."""
    if len(text) > MAX_BYTES:
        raise error(f"{source}: more than the {MAX_BYTES} bytes such a document may have")
    try:
        value = json.loads(text, **loads)
    except RecursionError as err:
        raise error(f"{source}: not valid JSON: nested deeper than {MAX_DEPTH} levels") from err
    except json.JSONDecodeError as err:
        raise error(f"{source}: not valid JSON: {err.msg} (line {err.lineno}, column {err.colno})") from err
    except UnicodeDecodeError as err:
        raise error(f"{source}: not valid JSON: not UTF-8 text (byte {err.start}: {err.reason})") from err
    except ValueError as err:  # what a hook of `loads` refuses (parse_constant: NaN)
        raise error(f"{source}: not valid JSON: {err}") from err
    if not _depth_within(value, MAX_DEPTH):
        raise error(f"{source}: not valid JSON: nested deeper than {MAX_DEPTH} levels")
    return value


def load_json(path: str | os.PathLike[str], what: str, error: type[Exception], **loads: Any) -> Any:
    """The JSON document of the file `path` (a `what`, e.g. "evaluation file"), bounded (module docstring)."""
    return parse_json(read_text(path, what, error), f"cannot read {what} {path}", error, **loads)
