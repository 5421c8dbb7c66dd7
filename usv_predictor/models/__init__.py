"""Learned and grey-box motion models (torch). `dnn`: the feed-forward network of seed 000 Fig. 1."""
from __future__ import annotations
