"""lpvflow: identify, realize, reduce, validate and control linear parameter-varying plants."""

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.errors import DataError, LpvflowError, ModelError
from lpvflow.identify.arx import identify_arx
from lpvflow.lfr import LPVLFR
from lpvflow.models import LPVIO, LPVSS, load

__all__ = ["LPVIO", "LPVLFR", "LPVSS", "Basis", "DataError", "Dataset", "LpvflowError", "ModelError",
           "identify_arx", "load"]
__version__ = "0.1.0"
