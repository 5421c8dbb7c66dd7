"""The house rule (DESIGN.md): folders by layer, and a layer imports only the layers above it.

Every import of every module (module level and inside functions, read with `ast`, nothing is run) is
mapped to its layer; an import of a lower layer fails the test, naming the file, the line and the rule.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "usv_predictor"
# top to bottom; a layer may import itself and the layers before it
LAYERS = ("ground", "msg_adapters", "physics", "data", "models", "fitting", "analysis", "node", "replay")
GROUND_FLOOR = {"errors", "frames", "records", "config", "atomic", "bounded", "__init__"}  # usv_predictor/<name>.py


def layer_of_file(path: Path) -> str:
    rel = path.relative_to(ROOT).parts
    if rel[0] == "msg_adapters":
        return "msg_adapters"
    if len(rel) == 2:  # usv_predictor/<module>.py
        return "ground"
    return rel[1]


def layer_of_module(name: str) -> str | None:
    """Layer of an absolute module name; None for anything outside the project (numpy, rclpy, ...)."""
    parts = name.split(".")
    if parts[0] == "msg_adapters":
        return "msg_adapters"
    if parts[0] != "usv_predictor":
        return None
    if len(parts) == 1 or parts[1] in GROUND_FLOOR:
        return "ground"
    return parts[1]


def imported_modules(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in the file, `from X import y` counted as X and X.y."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            found.append((node.lineno, base))
            found += [(node.lineno, f"{base}.{alias.name}") for alias in node.names]
    return found


def source_files() -> list[Path]:
    files = sorted((ROOT / "usv_predictor").rglob("*.py")) + sorted((ROOT / "msg_adapters").rglob("*.py"))
    return [f for f in files if "__pycache__" not in f.parts]


def violations(path: Path) -> list[str]:
    own = layer_of_file(path)
    out = []
    for line, module in imported_modules(path):
        target = layer_of_module(module)
        if target is None or target not in LAYERS:
            continue
        if LAYERS.index(target) > LAYERS.index(own):
            out.append(f"{path.relative_to(ROOT)}:{line} ({own}) imports {module} ({target}), a lower layer")
    return out


def test_every_module_sits_in_a_layer_folder():
    flat = sorted(p.stem for p in PACKAGE.glob("*.py") if p.stem not in GROUND_FLOOR)
    assert flat == [], f"modules outside the ground floor must live in a layer folder: {flat}"
    folders = sorted(p.name for p in PACKAGE.iterdir() if p.is_dir() and p.name != "__pycache__")
    assert folders == sorted(LAYERS[2:]), f"layer folders {folders}, expected {sorted(LAYERS[2:])}"


@pytest.mark.parametrize("path", source_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_module_imports_a_lower_layer(path):
    assert violations(path) == []


def test_the_check_fails_on_an_upward_import(tmp_path, monkeypatch):
    """The rule can fail: a physics module importing the replay tool is caught, with file and line."""
    fake_root = tmp_path
    bad = fake_root / "usv_predictor" / "physics" / "bad.py"
    bad.parent.mkdir(parents=True)
    bad.write_text("import math\n\n\ndef f():\n    from usv_predictor.replay.cli import main\n    return main\n")
    good = fake_root / "usv_predictor" / "replay" / "good.py"
    good.parent.mkdir(parents=True)
    good.write_text("from ..physics import bad\nfrom usv_predictor.errors import ConfigError\n")
    monkeypatch.setattr(__import__(__name__), "ROOT", fake_root)
    assert violations(bad) == ["usv_predictor/physics/bad.py:5 (physics) imports usv_predictor.replay.cli (replay), "
                               "a lower layer", "usv_predictor/physics/bad.py:5 (physics) imports "
                               "usv_predictor.replay.cli.main (replay), a lower layer"]
    assert violations(good) == []


def test_the_rclpy_shell_is_the_only_rclpy_import():
    importers = sorted(str(p.relative_to(ROOT)) for p in source_files()
                       if any(m.split(".")[0] == "rclpy" for _, m in imported_modules(p)))
    assert importers == ["usv_predictor/node/node.py"]


def test_no_command_imports_another_command():
    """Thin commands: what two commands share lives in a library module (or replay/options.py), not in a command."""
    commands = sorted((PACKAGE / "replay").glob("cmd_*.py"))
    assert len(commands) >= 9
    imports = {str(p.relative_to(ROOT)): sorted({m for _, m in imported_modules(p)
                                                 if m.rsplit(".", 1)[-1].startswith("cmd_")
                                                 or ".cmd_" in m}) for p in commands}
    assert {path: found for path, found in imports.items() if found} == {}


def exception_classes(path: Path) -> list[str]:
    """Classes of the file deriving from one of usv_predictor.errors' exceptions (read with ast)."""
    import usv_predictor.errors as errors

    known = {name for name, value in vars(errors).items() if isinstance(value, type) and issubclass(value, Exception)}
    tree = ast.parse(path.read_text(), filename=str(path))
    return [node.name for node in ast.walk(tree) if isinstance(node, ast.ClassDef)
            and any(isinstance(b, ast.Name) and b.id in known or isinstance(b, ast.Attribute) and b.attr in known
                    for b in node.bases)]


def test_every_exception_is_defined_in_errors_py():
    elsewhere = {str(p.relative_to(ROOT)): exception_classes(p) for p in source_files() if p != PACKAGE / "errors.py"}
    assert {path: names for path, names in elsewhere.items() if names} == {}
    assert len(exception_classes(PACKAGE / "errors.py")) >= 12  # the check reads them (it can fail)


def test_the_exceptions_keep_their_old_homes():
    from usv_predictor import errors
    from usv_predictor.analysis import diagnosis, evaluation, plots
    from usv_predictor.data import recording
    from usv_predictor.fitting import identification
    from usv_predictor.node import live

    assert live.InputRejected is errors.InputRejected
    assert live.CycleSkipped is errors.CycleSkipped
    assert recording.RecordingError is errors.RecordingError
    assert evaluation.EvaluationError is errors.EvaluationError
    assert plots.PlotError is errors.PlotError
    assert diagnosis.DiagnosisError is errors.DiagnosisError
    assert identification.NotIdentifiableError is errors.NotIdentifiableError
    assert issubclass(errors.NotIdentifiableError, errors.ModelError)
    assert errors.InputRejected("range", "too big").kind == "range"


def test_nanoseconds_per_second_is_written_once():
    """records.NS_PER_S is the one definition; no other module writes 10**9 (or 1e9) as a literal."""
    literal = {str(p.relative_to(ROOT)): [node.lineno for node in ast.walk(ast.parse(p.read_text()))
                                          if isinstance(node, ast.Constant) and not isinstance(node.value, bool)
                                          and isinstance(node.value, (int, float)) and node.value == 1e9]
               for p in source_files()}
    written = {path: len(lines) for path, lines in literal.items() if lines}
    assert written == {"usv_predictor/records.py": 1}
