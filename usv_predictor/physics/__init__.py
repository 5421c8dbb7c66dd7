"""Physics (numpy, no torch): vessel descriptions, hull models and actuator layouts (one record each), the
manoeuvring model, the sea, the simulator, trial manoeuvres, sensor models and the hidden effects (one Effect
record each)."""
from __future__ import annotations
