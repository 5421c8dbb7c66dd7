"""Every exception usv_predictor raises on purpose; messages name the culprit (file, topic, field).

The modules that raise them import them from here (and keep the names importable, e.g. live.CycleSkipped).
"""
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


class ModelDidNotReturn(ModelError):
    """A guarded call into a model's code was still running at its limit (models/loading.call_guarded)."""


class ModelLoadAbandoned(ModelError):
    """A guarded call into a model's code given up on because the caller is stopping: not the model's fault."""


class KernelUnavailable(ModelError):
    """A model module the compiled kernel cannot run (models/kernel_rollout.py): its caller keeps the module's own
    rollout and says why."""


class DatasetError(UsvPredictorError):
    """A dataset cannot be built or read (empty split, too-short manoeuvre, wrong format)."""


class RecordingError(UsvPredictorError):
    """Signals that cannot become a Recording (missing role, too short, gaps); the message says which."""


class NotIdentifiableError(ModelError):
    """The data cannot determine some coefficients; the message names them and the options."""


class TrainingDiverged(ModelError):
    """Training stopped at a non-finite loss (NaN/inf): the message names the epoch, the loss and the likely cause
    (non-finite training data, a base model whose rollout diverges, a learning rate too large)."""


class EvaluationError(UsvPredictorError):
    """A recording cannot be evaluated as asked (no reference track, no truth, too short); says which."""


class FitCheckError(UsvPredictorError):
    """A model does not fit the bags far beyond what any environmental cause explains (analysis/fit_check.py): its
    steady speed or yaw rate at the recorded commands, or its length scale, is off; the message names the numbers."""


class DiagnosisError(UsvPredictorError):
    """The data cannot support a diagnosis; the message says what data would be needed."""


class PlotError(UsvPredictorError):
    """A figure cannot be written (directory not writable, disk full); names the file."""


class OutputError(UsvPredictorError):
    """An output cannot be written: not writable, no space left, it would replace or sit inside an input, or it
    holds a value JSON cannot (NaN/inf); the message names the path or the field."""


class InputRejected(UsvPredictorError):
    """One live input sample was refused (reason in the message; `kind` is its counter key)."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


class CycleSkipped(UsvPredictorError):
    """No live prediction this cycle; the message says why (no input yet, stale input, bad model output)."""


def one_line(err: BaseException | str) -> str:
    """The message of `err` on one line (an error message is one line naming the culprit): a YAML syntax error, also
    one wrapped in another library's error, as "problem (line L, column C)"; other multi-line text (or a str) joined
    by " / "."""
    if isinstance(err, str):
        return " / ".join(line.strip() for line in err.splitlines() if line.strip())
    cause: BaseException | None = err
    while cause is not None and getattr(cause, "problem_mark", None) is None:
        cause = cause.__cause__ or cause.__context__
    if cause is not None:
        mark = cause.problem_mark  # type: ignore[attr-defined]
        return f"{cause.problem} (line {mark.line + 1}, column {mark.column + 1})"  # type: ignore[attr-defined]
    lines = [line.strip() for line in str(err).splitlines() if line.strip()]
    return " / ".join(lines) or type(err).__name__
