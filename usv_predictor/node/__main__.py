"""`python -m usv_predictor.node`: the predictor node (as `ros2 run usv_predictor predictor`)."""
from __future__ import annotations

import sys

from usv_predictor.node import main

sys.exit(main())
