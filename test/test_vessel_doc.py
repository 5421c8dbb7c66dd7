"""docs/vessel.md documents every field of the vessel file: each field of the Vessel dataclasses (every section of
physics/vessel.SECTIONS, the top-level keys) has its row in the table of its section, and no row names a field that
does not exist (a renamed or removed field fails here until the page follows)."""
from __future__ import annotations

import re
from dataclasses import fields
from pathlib import Path

import pytest

from usv_predictor.physics.vessel import SECTIONS, TOP_LEVEL_KEYS

DOC = Path(__file__).resolve().parents[1] / "docs" / "vessel.md"
ROW = re.compile(r"^\| `([A-Za-z_0-9]+)` \|", re.MULTILINE)


def _chapters() -> dict[str, str]:
    """'## heading' -> its text up to the next '## '."""
    parts = re.split(r"^## ", DOC.read_text(), flags=re.MULTILINE)[1:]
    return {part.splitlines()[0]: part for part in parts}


def _rows(heading_start: str) -> list[str]:
    chapters = [text for heading, text in _chapters().items() if heading.startswith(heading_start)]
    assert len(chapters) == 1, f"docs/vessel.md needs one chapter '## {heading_start}...', found {len(chapters)}"
    return ROW.findall(chapters[0])


def _expected() -> dict[str, list[str]]:
    out = {"Top level": list(TOP_LEVEL_KEYS)}
    out.update({f"`{key}`": [f.name for f in fields(cls)] for key, cls in SECTIONS.items()})
    return out


@pytest.mark.parametrize("chapter", list(_expected()))
def test_every_field_of_the_section_has_its_row_and_no_row_is_made_up(chapter):
    documented, actual = _rows(chapter), _expected()[chapter]
    assert [name for name in actual if name not in documented] == [], f"fields missing from docs/vessel.md {chapter}"
    assert [name for name in documented if name not in actual] == [], f"rows of no field in docs/vessel.md {chapter}"
    assert len(documented) == len(set(documented)), f"a field documented twice in {chapter}"


def test_the_page_counts_every_field():
    total = sum(len(names) for names in _expected().values())
    assert total >= 70
    assert sum(len(_rows(c)) for c in _expected()) == total
