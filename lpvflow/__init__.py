"""lpvflow: identify, realize, reduce, validate and control linear parameter-varying plants."""

from lpvflow.errors import DataError, LpvflowError, ModelError

__all__ = ["DataError", "LpvflowError", "ModelError"]
__version__ = "0.1.0"
