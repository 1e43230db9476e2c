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
    """No controller was returned, and why (every raise states it): ``category`` is ``"infeasible"`` (the
    LMIs have no solution at any level tried, proven by an accurate solve), ``"accuracy"`` (the solver
    could not reach the accuracy a certificate needs) or ``"assumption"`` (the plant violates an
    assumption of the method)."""

    CATEGORIES = ("infeasible", "accuracy", "assumption")

    def __init__(self, message: str, category: str) -> None:
        if category not in self.CATEGORIES:
            raise ValueError(f"unknown SynthesisError category {category!r}")
        super().__init__(message)
        self.category = category


class CentralLevelError(SynthesisError):
    """A :class:`SynthesisError` of the central controller built at ``factor`` × a certified optimum (the
    optimum itself was found): a larger factor is the remedy the caller can name."""

    def __init__(self, message: str, category: str, factor: float) -> None:
        super().__init__(message, category)
        self.factor = factor
