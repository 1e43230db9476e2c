"""Measured data of an LPV plant: inputs u, outputs y, scheduling p, sampling time Ts.

Every defect is a :class:`lpvflow.DataError` with one line naming the field and what to do,
never a numpy traceback. Readers: CSV with a header row, Parquet, MATLAB .mat.
"""

from __future__ import annotations

import csv
from collections.abc import Collection, Iterable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import scipy.io

from lpvflow.errors import DataError

#: Relative tolerance on the spacing of a time column before it counts as non-uniform.
TIME_TOLERANCE = 1e-6
#: MATLAB classes read as data columns (numeric and logical variables).
_MAT_NUMERIC = {"double", "single", "logical", *(f"{s}int{b}" for s in ("", "u") for b in (8, 16, 32, 64))}
#: Bytes of CSV text pyarrow parses at a time (whole lines; also the chunk size of the row count).
CSV_BLOCK_BYTES = 1 << 20
#: Text encoding of CSV files: UTF-8, with the byte-order mark spreadsheet programs (Excel) write dropped.
CSV_ENCODING = "utf-8-sig"


def _matrix(name: str, values: np.ndarray | list, names: list[str]) -> np.ndarray:
    a = np.asarray(values, dtype=float)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise DataError(f"{name} must be a vector or an (N, n) array, got {a.ndim} dimensions")
    bad = ~np.isfinite(a)
    if bad.any():
        k, c = np.argwhere(bad)[0]
        label = names[c] if c < len(names) else f"{name}[{c}]"
        raise DataError(
            f"column {label!r} has NaN/inf at sample {k} ({int(bad[:, c].sum())} bad values): "
            "remove or interpolate those samples"
        )
    return a


@dataclass(frozen=True)
class Dataset:
    """One experiment: u (N, nu), y (N, ny), p (N, n_p) as float64, sampling time Ts in seconds.

    ``offsets`` records what :meth:`remove_offsets` subtracted, so predictions can be mapped back.
    """

    u: np.ndarray
    y: np.ndarray
    p: np.ndarray
    Ts: float
    u_names: list[str] = field(default_factory=list)
    y_names: list[str] = field(default_factory=list)
    p_names: list[str] = field(default_factory=list)
    offsets: dict[str, list[float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for attr, prefix in (("u", "u"), ("y", "y"), ("p", "p")):
            names = list(getattr(self, f"{attr}_names"))
            arr = _matrix(attr, getattr(self, attr), names)
            if not names:
                names = [f"{prefix}{i}" for i in range(arr.shape[1])]
            if len(names) != arr.shape[1]:
                raise DataError(f"{attr} has {arr.shape[1]} column(s) but {len(names)} name(s): {names}")
            object.__setattr__(self, attr, arr)
            object.__setattr__(self, f"{attr}_names", names)
        lengths = {"u": len(self.u), "y": len(self.y), "p": len(self.p)}
        if len(set(lengths.values())) != 1:
            raise DataError(f"u, y and p must have the same number of samples, got {lengths}")
        if not (np.isfinite(self.Ts) and self.Ts > 0):
            raise DataError(f"sampling time Ts must be a positive number of seconds, got {self.Ts}")
        if self.N < 2:
            raise DataError(f"a dataset needs at least 2 samples, got {self.N}")

    @property
    def N(self) -> int:
        return len(self.y)

    def require_samples(self, needed: int, what: str) -> None:
        """Raise unless there is at least one sample more than ``needed`` (e.g. parameters + lags)."""
        if self.N <= needed:
            raise DataError(
                f"{self.N} samples are too few for {what} (needs more than {needed}): "
                "record longer data or lower the orders/basis degree"
            )

    # ----------------------------------------------------------------------------- operations
    def split(self, fraction: float = 0.5) -> tuple[Dataset, Dataset]:
        """Estimation and validation parts: the first ``fraction`` of the samples and the rest."""
        if not 0 < fraction < 1:
            raise DataError(f"split fraction must be between 0 and 1, got {fraction}")
        k = round(self.N * fraction)
        if k < 2 or self.N - k < 2:
            raise DataError(f"{self.N} samples cannot be split at {fraction}: both parts need 2 or more")
        return self.select(slice(0, k)), self.select(slice(k, self.N))

    def select(self, rows: slice) -> Dataset:
        return replace(self, u=self.u[rows], y=self.y[rows], p=self.p[rows])

    def remove_offsets(self, signals: str = "uy") -> Dataset:
        """Subtract the mean of the chosen signals (default inputs and outputs, never scheduling)."""
        changes, offsets = {}, dict(self.offsets)
        for s in signals:
            if s not in "uyp":
                raise DataError(f"unknown signal group {s!r}; use a combination of 'u', 'y', 'p'")
            mean = getattr(self, s).mean(axis=0)
            changes[s] = getattr(self, s) - mean
            offsets[s] = (np.asarray(offsets.get(s, 0.0)) + mean).tolist()
        return replace(self, offsets=offsets, **changes)

    def decimate(self, factor: int) -> Dataset:
        """Down-sample by an integer factor with an anti-aliasing filter (scipy.signal.decimate).

        Scheduling is decimated without filtering (it must stay a sample of the true p).
        """
        if int(factor) != factor or factor < 1:
            raise DataError(f"decimation factor must be a whole number >= 1, got {factor}")
        import scipy.signal  # slow to import; only decimation needs it

        factor = int(factor)
        if factor == 1:
            return self
        if self.N // factor < 30:
            raise DataError(f"decimating {self.N} samples by {factor} leaves too few samples (< 30)")
        filt = lambda a: scipy.signal.decimate(a, factor, axis=0, zero_phase=True)  # noqa: E731
        return replace(self, u=filt(self.u), y=filt(self.y), p=self.p[::factor], Ts=self.Ts * factor)

    # ------------------------------------------------------------------------------- readers
    @classmethod
    def from_columns(
        cls, table: Mapping[str, np.ndarray], source: str, u: list[str], y: list[str], p: list[str],
        time: str | None = None, Ts: float | None = None,
    ) -> Dataset:
        """Build from a name → column mapping; checks names, the time axis and Ts.

        ``time="auto"`` uses a ``time``/``t``/``Time`` column if the table has one.
        """
        if time == "auto":
            time = time_column(table)
        check_columns(table, source, u, y, p, time)
        if time is not None:
            ts_from_time = _uniform_step(np.asarray(table[time], dtype=float), time)
            if Ts is not None and abs(Ts - ts_from_time) > TIME_TOLERANCE * ts_from_time:
                raise DataError(f"Ts={Ts} disagrees with the time column step {ts_from_time:g}; drop one")
            Ts = ts_from_time
        if Ts is None:
            raise DataError(f"{source}: no time column and no Ts given; pass --Ts or name the time column")

        def stack(cols: list[str]) -> np.ndarray:
            if len(cols) == 1:  # a view of the column, not a copy: a 10⁶-row read stays under 2× its data
                return np.asarray(table[cols[0]], dtype=float).reshape(-1, 1)
            return np.column_stack([np.asarray(table[c], dtype=float) for c in cols])

        return cls(stack(u), stack(y), stack(p), float(Ts), list(u), list(y), list(p))

    @classmethod
    def read(cls, path: str | Path, u: list[str], y: list[str], p: list[str],
             time: str | None = "auto", Ts: float | None = None) -> Dataset:
        """Read CSV (header row), Parquet or .mat; ``time="auto"`` uses a ``time``/``t`` column if present.

        Only the named columns (and the time column) are read.
        """
        path = Path(path)
        names = column_names(path)
        if time == "auto":
            time = time_column(names)
        check_columns(names, path.name, u, y, p, time)
        table = read_columns(path, [*u, *y, *p, *([time] if time is not None else [])])
        return cls.from_columns(table, path.name, u, y, p, time=time, Ts=Ts)


def check_columns(
    names: Collection[str], source: str, u: list[str], y: list[str], p: list[str], time: str | None
) -> None:
    """Refuse (one DataError line) an empty role or a column the data do not have, listing the columns."""
    for role, cols in (("--u", u), ("--y", y), ("--p", p)):
        if not cols:
            raise DataError(f"no {role} column named; pass at least one column name")
        missing = [c for c in cols if c not in names]
        if missing:
            raise DataError(
                f"{source}: column(s) {missing} not found (given for {role}); available: {sorted(names)}"
            )
    if time is not None and time not in names:
        raise DataError(f"{source}: time column {time!r} not found; available: {sorted(names)}")


def read_columns(path: str | Path, columns: Iterable[str] | None = None) -> dict[str, np.ndarray]:
    """Numeric columns of a CSV (header row), Parquet or .mat file by name: only ``columns`` (those the
    file has; :func:`column_names` lists them all), or every column when ``columns`` is None."""
    path = _data_file(path)
    wanted = None if columns is None else list(dict.fromkeys(columns))
    suffix = path.suffix.lower()
    if suffix in (".csv", ".txt"):
        return _read_csv(path, wanted)
    if suffix in (".parquet", ".pq"):
        return _read_parquet(path, wanted)
    return _read_mat(path, wanted)


def column_names(path: str | Path) -> list[str]:
    """The column names of a data file: its header (CSV), schema (Parquet) or numeric variables (.mat)."""
    path = _data_file(path)
    suffix = path.suffix.lower()
    if suffix in (".csv", ".txt"):
        return _csv_header(path)
    if suffix in (".parquet", ".pq"):
        import pyarrow.parquet as pq

        try:
            return list(pq.read_schema(path).names)
        except Exception as exc:  # pyarrow raises several unrelated types for a bad file
            raise DataError(f"{path.name} is not a readable Parquet file ({exc.__class__.__name__})") \
                from None
    try:
        return [name for name, _, kind in scipy.io.whosmat(path) if kind in _MAT_NUMERIC]
    except Exception as exc:  # scipy raises ValueError/TypeError/MatReadError for a bad file
        raise DataError(f"{path.name} is not a readable MATLAB file ({exc.__class__.__name__})") from None


def time_column(names: Collection[str]) -> str | None:
    """The conventional time column among ``names`` (a table or a header): ``time``, ``t`` or ``Time``."""
    return next((c for c in ("time", "t", "Time") if c in names), None)


def _data_file(path: str | Path) -> Path:
    path = Path(path)
    if not path.exists():
        raise DataError(f"data file {str(path)!r} does not exist")
    if path.suffix.lower() not in (".csv", ".txt", ".parquet", ".pq", ".mat"):
        raise DataError(f"{path.name}: unknown data format {path.suffix.lower()!r}; "
                        "use .csv, .parquet or .mat")
    return path


def _uniform_step(t: np.ndarray, name: str) -> float:
    """The sampling time of a time column t_k = t_0 + k·Ts, refused when a step is off the median step by
    more than TIME_TOLERANCE: (t_last − t_0)/(N − 1) rounded to 12 significant digits, the decimal step
    the column stands for (0.005, not the 0.0049999999999954525 that differences of rounded times give)."""
    if len(t) < 2 or not np.all(np.isfinite(t)):
        raise DataError(f"time column {name!r} needs at least 2 finite values")
    dt = np.diff(t)
    if np.any(dt <= 0):
        k = int(np.argmax(dt <= 0))
        raise DataError(f"time column {name!r} is not increasing at sample {k + 1} (t={t[k + 1]:g})")
    step = float(np.median(dt))
    deviation = dt - step
    worst = int(np.argmax(np.abs(deviation, out=deviation)))
    if abs(dt[worst] - step) > TIME_TOLERANCE * step + 1e-12:
        raise DataError(
            f"time column {name!r} is not uniformly spaced (step {dt[worst]:g} at sample {worst + 1}, "
            f"median {step:g}): resample the data to a fixed step first"
        )
    return float(f"{(t[-1] - t[0]) / (len(t) - 1):.12g}")


def _csv_header(path: Path) -> list[str]:
    with path.open(newline="", encoding=CSV_ENCODING) as fh:
        try:
            header = [h.strip() for h in next(csv.reader(fh))]
        except StopIteration:
            raise DataError(f"{path.name} is empty; expected a header row and data") from None
        except (UnicodeDecodeError, csv.Error):
            raise DataError(f"{path.name} is not CSV text in UTF-8 (a binary file or another "
                            "encoding); save the data as CSV (UTF-8)") from None
    if len(set(header)) != len(header):
        raise DataError(f"{path.name}: duplicate column names in the header {header}")
    return header


def _read_csv(path: Path, columns: list[str] | None) -> dict[str, np.ndarray]:
    """``columns`` (every column when None) as float64; empty cells and ``nan`` become NaN (refused later
    by the Dataset checks with their sample).

    The file is cut into blocks of whole lines (one record per line) and pyarrow's CSV reader parses
    each block straight into one preallocated array, so the peak memory is the selected columns plus
    one block (pyarrow's own reader of a whole file reads ahead and allocates ~3× the columns).
    """
    import pyarrow as pa
    import pyarrow.csv as pacsv

    header = _csv_header(path)
    selected = header if columns is None else [c for c in columns if c in header]
    read_options = pacsv.ReadOptions(column_names=header, use_threads=False)
    convert_options = pacsv.ConvertOptions(include_columns=selected,
                                           column_types=dict.fromkeys(selected, pa.float64()))
    rows = _max_rows(path)
    values = [np.empty(rows) for _ in selected]  # one allocation per column: each can be freed on its own
    filled = 0
    try:
        for block in _line_blocks(path):
            table = pacsv.read_csv(pa.py_buffer(block), read_options=read_options,
                                   convert_options=convert_options)
            for row, name in enumerate(selected):
                values[row][filled:filled + table.num_rows] = table.column(name).to_numpy()
            filled += table.num_rows
    except pa.ArrowInvalid as exc:
        _raise_csv_defect(path, header, selected)
        raise DataError(f"{path.name}: {str(exc).splitlines()[0]}") from None
    return {name: values[row][:filled] for row, name in enumerate(selected)}


def _line_blocks(path: Path) -> Iterator[bytes]:
    """The data lines of a CSV (after the header) in blocks of about CSV_BLOCK_BYTES, each ending at a
    line break (LF, CRLF or CR)."""
    with path.open("rb") as fh:
        tail, in_header = b"", True
        while chunk := fh.read(CSV_BLOCK_BYTES):
            text = tail + chunk
            if in_header:  # drop the header line (the blank line a CRLF leaves is skipped by pyarrow)
                ends = [i for i in (text.find(b"\n"), text.find(b"\r")) if i >= 0]
                if not ends:
                    tail = text
                    continue
                text, in_header = text[min(ends) + 1:], False
            cut = max(text.rfind(b"\n"), text.rfind(b"\r")) + 1
            tail = text[cut:]
            if cut:
                yield text[:cut]
        if not in_header and tail.strip():
            yield tail


def _max_rows(path: Path) -> int:
    """An upper bound on the data rows of a CSV: its line breaks (LF, or CR for CR-only files) + 1."""
    lf = cr = 0
    with path.open("rb") as fh:
        while chunk := fh.read(CSV_BLOCK_BYTES):
            lf, cr = lf + chunk.count(b"\n"), cr + chunk.count(b"\r")
    return max(lf, cr) + 1


def _raise_csv_defect(path: Path, header: list[str], selected: list[str]) -> None:
    """After pyarrow refused the file: find the first short/long line or non-number in a selected column
    and raise it as a DataError with its line number (the file is only scanned on this error path)."""
    wanted = [header.index(c) for c in selected]
    with path.open(newline="", encoding=CSV_ENCODING, errors="replace") as fh:
        reader = csv.reader(fh)
        next(reader)
        for row in reader:
            if not row:
                continue
            line = reader.line_num
            if len(row) != len(header):
                raise DataError(f"{path.name}: line {line} has {len(row)} fields, "
                                f"the header has {len(header)}")
            for i in wanted:
                try:
                    float(row[i])
                except ValueError:
                    raise DataError(
                        f"{path.name}: line {line}, column {header[i]!r}: {row[i]!r} is not a number"
                    ) from None


def _read_parquet(path: Path, columns: list[str] | None) -> dict[str, np.ndarray]:
    import pyarrow.parquet as pq

    try:
        table = pq.read_table(path, columns=None if columns is None else
                              [c for c in columns if c in pq.read_schema(path).names], use_threads=False)
    except Exception as exc:  # pyarrow raises several unrelated types for a bad file
        raise DataError(f"{path.name} is not a readable Parquet file ({exc.__class__.__name__})") from None
    return {name: table.column(name).to_numpy(zero_copy_only=False) for name in table.column_names}


def _read_mat(path: Path, columns: list[str] | None) -> dict[str, np.ndarray]:
    try:
        raw = scipy.io.loadmat(path, squeeze_me=True, variable_names=columns)
    except Exception as exc:  # scipy raises ValueError/TypeError/MatReadError for a bad file
        raise DataError(f"{path.name} is not a readable MATLAB file ({exc.__class__.__name__})") from None
    return {k: np.atleast_1d(np.asarray(v, dtype=float)) for k, v in raw.items()
            if not k.startswith("__") and np.asarray(v).dtype.kind in "fiu"}
