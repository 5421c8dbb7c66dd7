"""The replay tool: rosbag2 recordings -> aligned time series -> datasets, models and reports.

Run as `python -m usv_predictor.replay <command>` (see cli.py). bagio.py is the only module of the
package that reads or writes bags; it converts messages through msg_adapters.
"""
from __future__ import annotations
