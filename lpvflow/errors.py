"""Exception types shared by every stage.

Every user-facing defect is reported as one of these, with one line naming the field
and what to do; the CLI turns them into exit status 2 without a traceback.
"""


class LpvflowError(Exception):
    """Base class of every error lpvflow raises on purpose."""


class DataError(LpvflowError, ValueError):
    """Bad measured data: missing column, NaN/inf, length mismatch, bad time axis, too few samples."""


class ModelError(LpvflowError, ValueError):
    """A model that cannot be used as asked: wrong shapes, unknown file format or version, ill-posed."""


class SynthesisError(ModelError):
    """No (reliable) solution: infeasible LMIs, a failed solve or a failed re-check."""
