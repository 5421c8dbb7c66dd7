"""`python -m usv_predictor.replay <command>`."""
from __future__ import annotations

import sys

from usv_predictor.replay.cli import main

sys.exit(main())
