"""What one design stage receives from the design file: exactly the keys it declares.

The design file is read and checked once (:func:`lpvflow.pipeline.config.load_config`): every table
becomes a frozen dataclass of its keys (:data:`lpvflow.pipeline.config.TABLES`) and every value is typed
by its checker (``[verify] loop`` a :class:`~lpvflow.pipeline.scenarios.Loop`, ``[verify] scenario``
a list of :class:`~lpvflow.pipeline.scenarios.Scenario`, the rest numbers, strings, lists and tables).
Each stage of :mod:`lpvflow.pipeline.design` declares the ``(table, keys)`` it reads; it gets a
:class:`StageSettings` holding those keys only, and its cache key is computed from
:meth:`StageSettings.payload`, the same values. Reading an undeclared key raises
:class:`UndeclaredSetting` (a programming error, not bad input), so a stage cannot depend on a setting its
cache key does not contain.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any

#: A stage's declaration: table → the keys it reads (``ALL`` for every key of the table).
Reads = Mapping[str, tuple[str, ...]]

#: Every key of a table.
ALL: tuple[str, ...] = ("*",)


class UndeclaredSetting(LookupError):
    """A stage read a design-file key its :class:`~lpvflow.pipeline.design.Stage` does not declare."""


class TableView(Mapping[str, Any]):
    """The declared keys of one checked table (read-only)."""

    def __init__(self, table: str, values: Mapping[str, Any], keys: tuple[str, ...]) -> None:
        self._table = table
        self._values = values
        self._keys = tuple(values) if keys == ALL else keys

    def __getitem__(self, key: str) -> Any:
        if key not in self._keys:
            raise UndeclaredSetting(f"a stage read [{self._table}] {key} without declaring it (it declares "
                                    f"{list(self._keys)}); add it to its reads in lpvflow.pipeline.design")
        return self._values[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._keys)

    def __contains__(self, key: object) -> bool:
        return key in self._keys

    def __len__(self) -> int:
        return len(self._keys)


class StageSettings(Mapping[str, TableView | None]):
    """The design-file keys one stage reads: table → :class:`TableView` (None for an optional table the
    file leaves out)."""

    def __init__(self, config: Mapping[str, Mapping[str, Any] | None], reads: Reads) -> None:
        self._tables = {table: None if config[table] is None else TableView(table, config[table], keys)
                        for table, keys in reads.items()}

    def __getitem__(self, table: str) -> TableView | None:
        if table not in self._tables:
            raise UndeclaredSetting(f"a stage read the table [{table}] without declaring it (it declares "
                                    f"{sorted(self._tables)})")
        return self._tables[table]

    def __iter__(self) -> Iterator[str]:
        return iter(self._tables)

    def __len__(self) -> int:
        return len(self._tables)

    def payload(self) -> dict[str, dict[str, Any] | None]:
        """The values the stage receives, table → key → value (its cache key hashes these)."""
        return {table: None if view is None else dict(view) for table, view in self._tables.items()}


def union(*reads: Reads) -> dict[str, tuple[str, ...]]:
    """The keys read by all of ``reads`` together (a stage that runs other stages reads theirs too)."""
    merged: dict[str, tuple[str, ...]] = {}
    for declaration in reads:
        for table, keys in declaration.items():
            before = merged.get(table, ())
            merged[table] = ALL if ALL in (before, keys) else tuple(dict.fromkeys(before + keys))
    return merged
