"""Motion models (torch): the artifact file format and one file per model family
(`dnn`: seed 000's network; `greybox`: the MMG grey box; `hybrid`: grey box + learned residual)."""
from __future__ import annotations
