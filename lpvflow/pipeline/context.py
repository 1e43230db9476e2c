"""The state a design stage works in: its folder, its settings, the outputs of the stages before it and
the experiment record, read once."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lpvflow.data import Dataset, read_columns

#: The experiment record every stage after the experiment reads.
DATA_FILE = "data.csv"


@dataclass
class StageContext:
    """The design folder, the settings the stage receives (a
    :class:`~lpvflow.pipeline.settings.StageSettings`, or a whole checked design file) and the outputs of
    the stages run so far. :meth:`columns` reads ``data.csv`` once per context (one pass of the design)."""

    folder: Path
    config: Mapping[str, Mapping[str, Any] | None]
    outputs: dict[str, dict] = field(default_factory=dict)
    _columns: dict[str, np.ndarray] | None = field(default=None, repr=False)

    def path(self, name: str) -> Path:
        return self.folder / name

    def columns(self) -> dict[str, np.ndarray]:
        """Every column of the experiment record ``data.csv``, read on the first call."""
        if self._columns is None:
            self._columns = read_columns(self.path(DATA_FILE))
        return self._columns

    def dataset(self, u: list[str], y: list[str], p: list[str]) -> Dataset:
        """The experiment record as a :class:`~lpvflow.data.Dataset` over the named columns (its time
        column gives Ts); a column the record lacks is one DataError line listing the columns it has."""
        return Dataset.from_columns(self.columns(), DATA_FILE, u, y, p, time="auto")
