"""Locate the package's shared files (config/, bags/, models/) in a source tree or an installation.

Order: the source checkout this module sits in; the ament index (colcon install, AMENT_PREFIX_PATH);
<sys.prefix>/share/usv_predictor (pip install into a virtualenv).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

PACKAGE = "usv_predictor"


def share_root() -> Path:
    """The directory holding config/ (and bags/, models/) for this installation."""
    source_root = Path(__file__).resolve().parent.parent
    if (source_root / "package.xml").is_file() and (source_root / "config").is_dir():
        return source_root
    if os.environ.get("AMENT_PREFIX_PATH"):
        try:
            from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

            try:
                return Path(get_package_share_directory(PACKAGE))
            except PackageNotFoundError:
                pass
        except ImportError:
            pass
    installed = Path(sys.prefix) / "share" / PACKAGE
    if installed.is_dir():
        return installed
    raise FileNotFoundError(
        f"cannot find the shared files of {PACKAGE}: looked in {source_root}, the ament index and {installed}"
    )


def share_path(*parts: str) -> Path:
    """share_path('config', 'predictor.yaml') -> absolute path (may not exist)."""
    return share_root().joinpath(*parts)
