"""Domain exceptions of the optimisation layer.

Every error raised on purpose by `optim` derives from `OptimError`; callers at the edges (CLI,
worker, HTTP) translate them into exit codes or responses. Messages name the offending field,
file or value so a user can act on them without reading a traceback.
"""

from __future__ import annotations


class OptimError(Exception):
    """Base class of the optimisation layer's errors."""


class ParamsError(OptimError, ValueError):
    """A parameter vector has the wrong length, is not finite, or does not match the spec."""


class EvaluationError(OptimError):
    """Evaluating candidates failed as a whole: a worker process died, a batch timed out,
    or every candidate of a generation raised."""


class CheckpointError(OptimError):
    """A checkpoint file cannot be read, or belongs to a different run (spec, seed, basis)."""


class InterpolationError(OptimError, ValueError):
    """Interpolation impossible: too few results, mixed families, or out of range."""


class BasisError(OptimError, ValueError):
    """A PCA basis cannot be built or does not fit the task it is used for."""


class ResultFileError(OptimError, ValueError):
    """A result (or basis) file is missing, not JSON, or has a bad field (named in the message)."""
