"""The few exceptions usv_predictor raises; messages name the culprit (file, topic, field)."""
from __future__ import annotations


class UsvPredictorError(Exception):
    """Base class of every error this package raises on purpose."""


class ConfigError(UsvPredictorError):
    """A configuration file, preset or parameter is missing, malformed or out of range."""


class BagError(UsvPredictorError):
    """A rosbag2 recording cannot be read or written as asked."""


class AdapterError(UsvPredictorError):
    """A ROS message cannot be converted to or from plain numbers."""


class ModelError(UsvPredictorError):
    """A model file is missing, corrupt, or does not match the configuration (the message says what differs)."""


class DatasetError(UsvPredictorError):
    """A dataset cannot be built or read (empty split, too-short manoeuvre, wrong format)."""
