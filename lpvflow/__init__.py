"""lpvflow: identify, realize, reduce, validate and control linear parameter-varying plants."""

import importlib

from lpvflow.errors import DataError, LpvflowError, ModelError

#: Public names imported on first use, so that ``lpvflow --help`` does not load numba and SciPy.
_LAZY = {"Basis": "lpvflow.basis", "Dataset": "lpvflow.data", "identify_arx": "lpvflow.identify.arx",
         "LPVLFR": "lpvflow.lfr", "LPVIO": "lpvflow.lpvio", "LPVSS": "lpvflow.models",
         "load": "lpvflow.models"}

__all__ = ["DataError", "LpvflowError", "ModelError", *_LAZY]
__version__ = "0.1.0"


def __getattr__(name: str) -> object:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'lpvflow' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
