"""Physics (numpy, no torch): vessel descriptions, the manoeuvring model, the sea, actuator layouts,
the simulator, trial manoeuvres, sensor models and the hidden effects (one Effect record each)."""
from __future__ import annotations
