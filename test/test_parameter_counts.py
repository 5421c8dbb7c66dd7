"""No function of the package takes more than MAX_PARAMETERS parameters (self and cls not counted): a longer list
is an option record (a frozen dataclass with one commented field each, e.g. replay.dataset.DatasetRequest).

Every module of usv_predictor and msg_adapters (but the __main__ ones, which run the program when imported) is
imported and walked with `inspect`: its functions and the methods
of its classes. The numba kernels of physics/kernel.py are no Python functions (numba dispatchers) and are not
counted: a compiled kernel takes scalars and arrays, never a record.
"""
from __future__ import annotations

import dataclasses
import importlib
import inspect
import pkgutil
from types import ModuleType

import usv_predictor
import msg_adapters

MAX_PARAMETERS = 10


def modules() -> list[ModuleType]:
    found = []
    for package in (usv_predictor, msg_adapters):
        found.append(package)
        for info in pkgutil.walk_packages(package.__path__, prefix=f"{package.__name__}."):
            if info.name.rpartition(".")[2] != "__main__":  # importing it runs the program
                found.append(importlib.import_module(info.name))
    return found


def parameters(function: object) -> list[str]:
    return [name for name in inspect.signature(function).parameters if name not in ("self", "cls")]


def generated(cls: type, attribute: str) -> bool:
    """The constructor a record's fields generate (a dataclass's __init__, a NamedTuple's __new__): a record is
    built by keyword, field by field; its length is the record's, not an argument list's."""
    if attribute == "__init__" and dataclasses.is_dataclass(cls):
        return cls.__dataclass_params__.init  # type: ignore[attr-defined]
    return attribute == "__new__" and issubclass(cls, tuple) and hasattr(cls, "_fields")


def own_functions(module: ModuleType) -> dict[str, object]:
    """qualified name -> function, for the functions and methods defined in `module` (not those it imports, not the
    constructors records generate)."""
    out: dict[str, object] = {}
    for name, value in vars(module).items():
        if inspect.isfunction(value) and value.__module__ == module.__name__:
            out[f"{module.__name__}.{name}"] = value
        elif inspect.isclass(value) and value.__module__ == module.__name__:
            for attribute, member in vars(value).items():
                if generated(value, attribute):
                    continue
                function = member.__func__ if isinstance(member, (staticmethod, classmethod)) else member
                if inspect.isfunction(function) and function.__module__ == module.__name__:
                    out[f"{module.__name__}.{name}.{attribute}"] = function
    return out


def test_no_function_takes_more_than_ten_parameters():
    counted = {qualified: parameters(function) for module in modules()
               for qualified, function in own_functions(module).items()}
    assert len(counted) > 1000  # the walk sees the package (it can fail)
    assert {name: len(params) for name, params in counted.items() if len(params) > MAX_PARAMETERS} == {}


def test_the_walk_counts_methods_and_finds_a_long_list():
    from usv_predictor.replay import dataset, identify

    functions = own_functions(dataset)
    assert parameters(functions["usv_predictor.replay.dataset.dataset_from_bags"]) == [
        "request", "vessel", "warn", "progress"]
    assert "usv_predictor.replay.identify.IdentifyRequest.__post_init__" in own_functions(identify)
    assert "usv_predictor.replay.identify.IdentifyRequest.__init__" not in own_functions(identify)  # a record's

    def long(a, b, c, d, e, f, g, h, i, j, k):  # noqa: ANN001 - eleven parameters
        return a

    assert len(parameters(long)) == MAX_PARAMETERS + 1
