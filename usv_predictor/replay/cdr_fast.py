"""Moved to msg_adapters.cdr (the node decodes its inputs with it too); kept so older imports still work."""
from __future__ import annotations

from msg_adapters.cdr import decode_many, has_fast_layout, supported_types

__all__ = ["decode_many", "has_fast_layout", "supported_types"]
