"""One manoeuvre family: physics/manoeuvres.MANOEUVRE_KINDS is the one record per kind, and what `replay simulate`
and `replay convert` accept is read from it (the command-line spelling beside the data spelling)."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

from usv_predictor.physics import manoeuvres as mv
from usv_predictor.physics.actuators import ACTUATOR_LAYOUTS
from usv_predictor.replay import convert, simulate

ROOT = Path(__file__).resolve().parents[1]


def test_the_commands_read_the_one_record():
    assert simulate.KINDS == mv.SIMULATED_OPTIONS == ("turning-circle", "zigzag", "pullout", "spiral", "random")
    assert set(convert.MANOEUVRE_KINDS) == {"zigzag", "turning_circle", "pullout", "path_following"}
    assert simulate.DEFAULT_MANOEUVRE in mv.SIMULATED_OPTIONS


@pytest.mark.parametrize("layout", sorted(ACTUATOR_LAYOUTS))
@pytest.mark.parametrize("option", mv.SIMULATED_OPTIONS)
def test_a_simulated_kind_builds_a_manoeuvre_named_by_its_data_spelling(option, layout):
    """Each kind's builder makes a manoeuvre of the layout's family whose name starts with the kind's data spelling
    (turning-circle on the command line, turning_circle in the bag's name)."""
    kind = mv.simulated_kind(option)
    chosen = ACTUATOR_LAYOUTS[layout]
    turn, propulsion = chosen.turn_input.default, chosen.propulsion_input.default
    built = kind.build(chosen, turn, propulsion, -1, 15.0, 3, {"duration_s": 60.0} if option != "spiral" else {})
    assert built.name.startswith(f"{kind.name}_")
    assert callable(built.controller())


def test_an_unknown_or_unsimulated_kind_is_refused_by_name():
    with pytest.raises(ValueError, match="'path_following': expected one of turning-circle, zigzag"):
        mv.simulated_kind("path_following")
    with pytest.raises(ValueError, match="'turning_circle'"):
        mv.simulated_kind("turning_circle")  # the data spelling is not the command line's


def test_every_kind_a_reader_writes_is_a_converted_kind():
    """The readers' `kind=` literals (replay/convert/*.py) are all converted kinds of the record."""
    written = set()
    for path in sorted((ROOT / "usv_predictor" / "replay" / "convert").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.keyword) and node.arg == "kind" and isinstance(node.value, ast.Constant):
                written.add(node.value.value)
    assert written  # the scan finds them (it can fail)
    assert written <= set(mv.CONVERTED_KINDS)
