"""`replay`: the command-line front of the replay tool (`python -m usv_predictor.replay <command>`).

Each command is a module usv_predictor/replay/cmd_<name>.py exposing NAME, HELP,
add_arguments(parser) and run(args) -> dict (the machine-readable result). Modules are imported
only when needed: `replay <command>` imports that command alone, `replay --help` imports every
command module (they keep heavy imports inside run()) and lists those that import. Every command
gets `--json PATH` (result written atomically). Errors (UsvPredictorError, bad arguments) print
one line `replay <command>: error: <message>` on stderr and exit with code 2.
"""
from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path
from types import ModuleType
from typing import Any, NoReturn

from usv_predictor.atomic import write_json_atomic
from usv_predictor.errors import UsvPredictorError

PROG = "replay"
COMMANDS: tuple[str, ...] = (
    "usv_predictor.replay.cmd_info",
    "usv_predictor.replay.cmd_simulate",
    "usv_predictor.replay.cmd_convert",
    "usv_predictor.replay.cmd_dataset",
    "usv_predictor.replay.cmd_train",
    "usv_predictor.replay.cmd_evaluate",
    "usv_predictor.replay.cmd_report",
    "usv_predictor.replay.cmd_identify",
    "usv_predictor.replay.cmd_diagnose",
)
EXIT_ERROR = 2


class _UsageError(Exception):
    """An argparse error, raised instead of printing usage and exiting."""

    def __init__(self, prog: str, message: str) -> None:
        super().__init__(message)
        self.prog = prog


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        raise _UsageError(self.prog, message)


def _command_name(module_name: str) -> str:
    """'usv_predictor.replay.cmd_info' -> 'info' (the convention that lets imports be lazy)."""
    return module_name.rsplit(".", 1)[-1].removeprefix("cmd_").replace("_", "-")


def _load(module_name: str) -> ModuleType | None:
    try:
        return importlib.import_module(module_name)
    except ImportError as err:
        print(f"{PROG}: note: command module {module_name} unavailable ({err})", file=sys.stderr)
        return None


def _add_command(subparsers: Any, module: ModuleType) -> None:
    parser = subparsers.add_parser(module.NAME, help=module.HELP, description=module.HELP)
    module.add_arguments(parser)
    parser.add_argument("--json", metavar="PATH", type=Path, help="write the machine-readable result to PATH")
    parser.set_defaults(_command=module)


def build_parser(argv: list[str]) -> argparse.ArgumentParser:
    """The parser, with only the named command's module imported when argv names one."""
    parser = _Parser(prog=PROG, description="Replay rosbag2 recordings through the USV motion predictor.")
    subparsers = parser.add_subparsers(title="commands", metavar="<command>", parser_class=_Parser)
    wanted = [m for m in COMMANDS if _command_name(m) in argv[:1]] or list(COMMANDS)
    for module_name in wanted:
        module = _load(module_name)
        if module is not None:
            _add_command(subparsers, module)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one replay command; returns the process exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    prog = PROG
    try:
        try:
            args = build_parser(argv).parse_args(argv)
        except SystemExit as done:  # --help printed; return instead of exiting the caller
            return int(done.code or 0)
        command = getattr(args, "_command", None)
        if command is None:
            raise _UsageError(PROG, "a command is required (see --help)")
        prog = f"{PROG} {command.NAME}"
        result = command.run(args)
        if args.json is not None:
            write_json_atomic(args.json, result)
    except _UsageError as err:
        print(f"{err.prog}: error: {err}", file=sys.stderr)
        return EXIT_ERROR
    except UsvPredictorError as err:
        print(f"{prog}: error: {err}", file=sys.stderr)
        return EXIT_ERROR
    return 0
