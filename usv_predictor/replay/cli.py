"""`replay`: the command-line front of the replay tool (`python -m usv_predictor.replay <command>`).

Each command is a module usv_predictor/replay/cmd_<name>.py exposing NAME, HELP,
add_arguments(parser) and run(args) -> dict (the machine-readable result), and the paths it reads and writes:
INPUTS (the argument names holding input paths) and OUTPUTS (argument name -> "file" or "dir"). Modules are
imported only when needed: `replay <command>` imports that command alone, `replay --help` imports every
command module (they keep heavy imports inside run()) and lists those that import. Every command
gets `--json PATH` (result written atomically, strict JSON).

Before any work, every output (and --json) is checked against every input (usv_predictor.atomic.check_outputs:
never an input, never inside one, never replacing one) and for being writable. Errors (UsvPredictorError, bad
arguments, an OS error reading or writing a file) print one line `replay <command>: error: <message>` on
stderr and exit with code 2 (EXIT_ERROR); Ctrl-C (SIGINT) prints `replay <command>: interrupted` and exits with
130 (EXIT_INTERRUPTED), SIGTERM `replay <command>: terminated` and 143 (EXIT_TERMINATED), SIGHUP `replay
<command>: hung up` and 129 (EXIT_HUNG_UP), leaving no partial output (every writer is atomic and removes its
temporary file as the exception unwinds). A SystemError caused by one of these signals (raised inside the Python code
a compiled function's wrapper runs: _signal_behind) ends the command as that signal does.

A model's code runs at load in a guard thread while the main thread waits with a timeout
(usv_predictor.models.loading.call_guarded), so these signals are honoured also while a model never returns; such a
run ends with its code through loading.exit_program (os._exit after the atexit handlers: a normal interpreter exit
would abort with the thread inside torch), when main is the program (called without argv); so does a run ended by
Ctrl-C, whose code 130 the interpreter's own exit could turn into a death by SIGINT (main).
"""
from __future__ import annotations

import argparse
import importlib
import signal
import sys
import threading
from pathlib import Path
from types import ModuleType
from typing import Any, NoReturn

from usv_predictor.atomic import check_outputs, output_locks, write_json_atomic
from usv_predictor.errors import UsvPredictorError, one_line

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
    "usv_predictor.replay.cmd_vessel",
)
EXIT_ERROR = 2
EXIT_INTERRUPTED = 130  # 128 + SIGINT, what a shell reports for Ctrl-C
EXIT_TERMINATED = 143  # 128 + SIGTERM
EXIT_HUNG_UP = 129  # 128 + SIGHUP


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


class _Terminated(BaseException):
    """SIGTERM (or SIGHUP) arrived: unwinds like KeyboardInterrupt, so every atomic writer removes its temporary
    file."""

    def __init__(self, signum: int = signal.SIGTERM) -> None:
        super().__init__(signum)
        self.signum = signum


def _on_sigterm(signum: int, frame: Any) -> None:
    raise _Terminated(signum)


def _path_values(args: argparse.Namespace, name: str) -> list[Path]:
    """The paths an argument holds (a path, a list of them, or a model spec that names an existing file)."""
    value = getattr(args, name, None)
    values = value if isinstance(value, (list, tuple)) else [value]
    return [Path(v) for v in values if v is not None and (isinstance(v, Path) or Path(str(v)).exists())]


def check_paths(command: ModuleType, args: argparse.Namespace) -> dict[str, Any]:
    """Outputs (the command's OUTPUTS and --json) apart from its INPUTS and writable (OutputError otherwise); returns
    them (option -> path or None)."""
    inputs = [path for name in getattr(command, "INPUTS", ()) for path in _path_values(args, name)]
    kinds: dict[str, str] = dict(getattr(command, "OUTPUTS", {}))
    outputs = {f"--{name.replace('_', '-')}": getattr(args, name, None) for name in kinds}
    outputs["--json"] = args.json
    directories = {f"--{name.replace('_', '-')}" for name, kind in kinds.items() if kind == "dir"}
    check_outputs(outputs, inputs, directories)
    return outputs


def _error_line(err: BaseException) -> str:
    """An OSError as one line naming the file."""
    if isinstance(err, OSError) and err.filename is not None:
        return f"{err.filename}: {err.strerror or err}"
    return str(err) or type(err).__name__


def _signal_behind(err: SystemError) -> BaseException | None:
    """The KeyboardInterrupt (or _Terminated) a SystemError carries, else None. A signal handler that raises runs at
    the interpreter's next check; when that falls in Python code a compiled (numba) function's wrapper calls after its
    machine code (numba's `_numba_unpickle` when it boxes an array), the wrapper returns its result with the
    exception set and Python reports a SystemError caused by it: the stop the user asked for, not a bug."""
    seen: BaseException | None = err
    visited: set[int] = set()
    while seen is not None and id(seen) not in visited:  # a chain set by hand may loop
        if isinstance(seen, (KeyboardInterrupt, _Terminated)):
            return seen
        visited.add(id(seen))
        seen = seen.__cause__ or seen.__context__
    return None


def main(argv: list[str] | None = None) -> int:
    """Run one replay command; returns the process exit code. Called as the program (argv None), the process ends
    here with os._exit and that code (loading.exit_program) after a model's code never returned (a guard thread
    still inside it) and after Ctrl-C: a KeyboardInterrupt raised inside exec() (a dataclass or a namedtuple being
    made while a library imports) marks the interpreter, which then ends itself with SIGINT at exit (CPython 3.11:
    run_eval_code_obj's _Py_UnhandledKeyboardInterrupt) although the interrupt was caught here: not code 130.
    A Ctrl-C after the command's end (while _run unwinds, or in the exit handlers that join worker pools) leaves its
    exit code as it is: the command is over and its outputs are written."""
    try:
        code = _run(list(sys.argv[1:] if argv is None else argv))
    except KeyboardInterrupt:  # between the command's end and _run's return (its finally restoring handlers)
        print(f"{PROG}: interrupted", file=sys.stderr)
        code = EXIT_INTERRUPTED
    if argv is None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # the exit handlers cannot end the process by SIGINT now
        loading = sys.modules.get("usv_predictor.models.loading")  # imported only by the commands that load a model
        if code == EXIT_INTERRUPTED or (loading is not None and loading.stuck_guard_threads()):
            from usv_predictor.models.loading import exit_program

            exit_program(code)
    return code


def _run(argv: list[str]) -> int:
    prog = PROG
    handles_sigterm = threading.current_thread() is threading.main_thread()  # only there can Python set handlers
    stops = (signal.SIGTERM, signal.SIGHUP)  # SIGHUP: the terminal went away; unwound like SIGTERM
    previous = {sig: signal.signal(sig, _on_sigterm) for sig in stops} if handles_sigterm else {}
    try:
        try:
            args = build_parser(argv).parse_args(argv)
        except SystemExit as done:  # --help printed; return instead of exiting the caller
            return int(done.code or 0)
        command = getattr(args, "_command", None)
        if command is None:
            raise _UsageError(PROG, "a command is required (see --help)")
        prog = f"{PROG} {command.NAME}"
        try:
            with output_locks(check_paths(command, args)):  # one writer per output
                result = command.run(args)
                if args.json is not None:
                    write_json_atomic(args.json, result)
        except SystemError as err:
            stop = _signal_behind(err)
            if stop is None:
                raise
            raise stop from None
    except _UsageError as err:
        print(f"{err.prog}: error: {err}", file=sys.stderr)
        return EXIT_ERROR
    except UsvPredictorError as err:
        print(f"{prog}: error: {one_line(str(err))}", file=sys.stderr)  # one line, whatever the message holds
        return EXIT_ERROR
    except OSError as err:  # the environment (a file vanished, a device failed): not a bug, still one line
        print(f"{prog}: error: {_error_line(err)}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except _Terminated as stop:
        if stop.signum == signal.SIGHUP:
            print(f"{prog}: hung up", file=sys.stderr)
            return EXIT_HUNG_UP
        print(f"{prog}: terminated", file=sys.stderr)
        return EXIT_TERMINATED
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
    return 0
