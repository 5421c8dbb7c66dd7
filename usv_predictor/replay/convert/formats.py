"""The public formats `replay convert` reads, one record each (FORMATS_BY_NAME: reader, file names, licence, epoch,
datum), and the discovery of their files: detect_format, find_sources, read_manoeuvres.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Mapping, Sequence

from usv_predictor.errors import DatasetError
from usv_predictor.replay.convert import dalian, fuzhou, hsva, marin
from usv_predictor.replay.convert.common import Format, Manoeuvre

# One record per public format (convert/common.Format), in the order `--format` lists them
FORMATS_BY_NAME: Mapping[str, Format] = {f.name: f for f in (hsva.FORMAT, marin.FORMAT, fuzhou.FORMAT, dalian.FORMAT)}
FORMATS = tuple(FORMATS_BY_NAME)  # the names
READERS: Mapping[str, Callable[[Path], Sequence[Manoeuvre]]] = {f.name: f.read for f in FORMATS_BY_NAME.values()}
LICENCE = {f.name: f.licence for f in FORMATS_BY_NAME.values()}
EPOCH_NS = {f.name: f.epoch_ns for f in FORMATS_BY_NAME.values() if f.epoch_ns is not None}  # others: the file's
DATUM_DEG = {f.name: f.datum_deg for f in FORMATS_BY_NAME.values() if f.datum_deg is not None}  # tank data
UNSUPPORTED_FORMATS: dict[str, str] = {}  # a format name -> why it is refused


def detect_format(path: Path) -> str:
    """The name of the format whose files are named like `path` (Format.matches); DatasetError when none."""
    name = Path(path).name
    for f in FORMATS_BY_NAME.values():
        if f.matches(name):
            return f.name
    *first, last = [f.files for f in FORMATS_BY_NAME.values()]
    raise DatasetError(f"{path}: unknown data format (expected {', '.join(first)}, {last}; give --format)")


def find_sources(inputs: Sequence[Path], fmt: str = "auto") -> list[tuple[Path, str]]:
    """(file, format) for every manoeuvre file among `inputs` (files or directories, sorted).

    Directories are searched (not recursively) for *.dat, *.csv and *.xlsx; other files (SOURCE.txt,
    ship_data.yml, open_water_characteristics.csv) are skipped.
    """
    found: list[tuple[Path, str]] = []
    for item in inputs:
        item = Path(item)
        if item.is_dir():
            candidates = sorted(p for p in item.iterdir() if p.suffix.lower() in (".dat", ".csv", ".xlsx")
                                and p.name != "open_water_characteristics.csv")
            if not candidates:
                raise DatasetError(f"{item}: no .dat, .csv or .xlsx manoeuvre files in this directory")
            for p in candidates:
                found.append((p, detect_format(p) if fmt == "auto" else fmt))
        elif item.is_file():
            found.append((item, detect_format(item) if fmt == "auto" else fmt))
        else:
            raise DatasetError(f"{item}: no such file or directory")
    for p, f in found:
        if f in UNSUPPORTED_FORMATS:
            raise DatasetError(f"{p}: {UNSUPPORTED_FORMATS[f]}")
        if f not in READERS:
            raise DatasetError(f"{p}: unknown format {f!r}; formats: {', '.join(FORMATS)}")
    return found


def read_manoeuvres(path: Path, fmt: str) -> list[Manoeuvre]:
    """Every manoeuvre of one file (one, or a MARIN turning circle and its pull-out)."""
    return list(READERS[fmt](Path(path)))
