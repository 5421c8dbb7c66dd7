"""No import circle inside a folder: beside the layer rule (test_layers.py), the modules of one package folder import
one another in one direction only.

Every import of every module (module level and inside functions, read with `ast`, nothing is run) that names a module
of the same folder is an edge; a circle of edges (A imports B ... imports A) fails the test, naming the modules and
the lines. `from folder import name` is an edge to folder/name.py when that is a module, else to the folder's
`__init__.py`; a module's implicit import of its own package's `__init__` is no edge (Python runs it first anyway).
"""
from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from test_layers import ROOT, imported_modules, source_files


def module_name(path: Path) -> str:
    """usv_predictor/fitting/identification.py -> usv_predictor.fitting.identification (a package: its folder)."""
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def folder_of(path: Path) -> str:
    return ".".join(path.relative_to(ROOT).parts[:-1])


def imports_in_folder(path: Path, modules: Mapping[str, Path]) -> dict[str, int]:
    """The modules of the file's own folder that it imports -> the first line importing each (test_layers' reading
    of the imports: `from X import y` names X and X.y, and only names that are modules count)."""
    own, folder = module_name(path), folder_of(path)
    named = imported_modules(path)
    edges: dict[str, int] = {}
    for line, name in named:
        target = modules.get(name)
        if target is None or name == own or folder_of(target) != folder:
            continue
        if target.name == "__init__.py" and path.name != "__init__.py":
            continue  # its own package's __init__: run before the module in any case
        edges.setdefault(name, line)
    return edges


def import_graph() -> dict[str, dict[str, int]]:
    modules = {module_name(p): p for p in source_files()}
    return {name: imports_in_folder(path, modules) for name, path in modules.items()}


def circles(graph: Mapping[str, Mapping[str, int]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each a circle of imports."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, {}):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def described(component: list[str], graph: Mapping[str, Mapping[str, int]]) -> str:
    return "; ".join(f"{a} imports {b} (line {graph[a][b]})" for a in component for b in component if b in graph[a])


def test_no_module_imports_in_a_circle_inside_its_folder():
    graph = import_graph()
    assert [described(c, graph) for c in circles(graph)] == []


def test_the_graph_sees_function_local_imports_and_names_a_circle():
    """The check can fail: the identification modules' function-local imports are edges, and a made-up circle
    is found."""
    graph = import_graph()
    assert "usv_predictor.fitting.identification" in graph["usv_predictor.fitting.hull_models"]
    assert "usv_predictor.models.kernel_rollout" in graph["usv_predictor.models.loading"]  # inside a function
    assert "usv_predictor.node" not in graph["usv_predictor.node.node"]  # its own package: no edge
    made_up = {**graph, "usv_predictor.fitting.identification": {"usv_predictor.fitting.hull_models": 1}}
    fitting = [f"usv_predictor.fitting.{m}" for m in ("hull_models", "identification", "interaction",
                                                       "output_error", "small_craft_identification")]
    assert circles(made_up) == [fitting]  # hull_models imports all four, which import identification: one circle
