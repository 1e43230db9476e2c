"""Every DataError path of Dataset and its readers, through the Python API and the CLI."""

import numpy as np
import pytest
import scipy.io

from lpvflow.data import Dataset, column_names
from lpvflow.errors import DataError
from lpvflow.pipeline.cli import main


def write_csv(path, header, rows):
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(str(v) for v in r) for r in rows) + "\n")
    return path


@pytest.fixture
def good_rows():
    rng = np.random.default_rng(0)
    return [[0.1 * k, *rng.normal(size=3)] for k in range(200)]


def test_csv_roundtrip_with_time_column(tmp_path, good_rows):
    path = write_csv(tmp_path / "d.csv", ["time", "u", "y", "p"], good_rows)
    d = Dataset.read(path, ["u"], ["y"], ["p"])
    assert d.Ts == pytest.approx(0.1)
    assert d.u.shape == (200, 1) and d.u.dtype == np.float64
    np.testing.assert_allclose(d.y[:, 0], [r[2] for r in good_rows])


def test_parquet_and_mat_readers(tmp_path, good_rows):
    import pyarrow as pa
    import pyarrow.parquet as pq

    cols = dict(zip(["time", "u", "y", "p"], np.array(good_rows).T, strict=True))
    pq.write_table(pa.table(cols), tmp_path / "d.parquet")
    scipy.io.savemat(tmp_path / "d.mat", cols)
    for name in ("d.parquet", "d.mat"):
        d = Dataset.read(tmp_path / name, ["u"], ["y"], ["p"])
        assert d.Ts == pytest.approx(0.1) and d.N == 200


@pytest.mark.parametrize(
    ("header", "mutate", "cols", "message"),
    [
        (["time", "u", "y", "p"], None, (["u"], ["missing"], ["p"]), "column(s) ['missing'] not found"),
        (["time", "u", "y", "p"], lambda r: r[5].__setitem__(2, "nan"), None, "'y' has NaN/inf at sample 5"),
        (["time", "u", "y", "p"], lambda r: r[7].__setitem__(1, "inf"), None, "'u' has NaN/inf at sample 7"),
        (["time", "u", "y", "p"], lambda r: r[9].__setitem__(0, 0.95), None, "not uniformly spaced"),
        (["time", "u", "y", "p"], lambda r: r[9].__setitem__(0, 0.0), None, "not increasing at sample 9"),
        (["time", "u", "y", "p"], lambda r: r[3].__setitem__(3, "abc"), None, "'abc' is not a number"),
        (["time", "u", "y", "p"], lambda r: r[4].pop(), None, "line 6 has 3 fields"),
    ],
)
def test_csv_defects(tmp_path, good_rows, header, mutate, cols, message):
    if mutate:
        mutate(good_rows)
    path = write_csv(tmp_path / "d.csv", header, good_rows)
    u, y, p = cols or (["u"], ["y"], ["p"])
    with pytest.raises(DataError, match=message.replace("[", r"\[").replace("]", r"\]").replace("(", r"\(")
                       .replace(")", r"\)")):
        Dataset.read(path, u, y, p)


def test_array_defects():
    rng = np.random.default_rng(1)
    u, y, p = rng.normal(size=(50, 1)), rng.normal(size=(50, 1)), rng.normal(size=(50, 1))
    with pytest.raises(DataError, match="same number of samples"):
        Dataset(u, y[:40], p, 1.0)
    with pytest.raises(DataError, match="Ts must be a positive"):
        Dataset(u, y, p, 0.0)
    with pytest.raises(DataError, match="Ts must be a positive"):
        Dataset(u, y, p, -0.1)
    with pytest.raises(DataError, match="2 column"):
        Dataset(np.hstack([u, u]), y, p, 1.0, u_names=["a"])
    with pytest.raises(DataError, match="too few"):
        Dataset(u, y, p, 1.0).require_samples(60, "this model")


def test_missing_time_and_ts(tmp_path, good_rows):
    path = write_csv(tmp_path / "d.csv", ["clock", "u", "y", "p"], good_rows)
    with pytest.raises(DataError, match="no time column and no Ts"):
        Dataset.read(path, ["u"], ["y"], ["p"])
    assert Dataset.read(path, ["u"], ["y"], ["p"], Ts=0.5).Ts == 0.5
    with pytest.raises(DataError, match="disagrees with the time column"):
        Dataset.read(path, ["u"], ["y"], ["p"], time="clock", Ts=0.5)


def test_split_offsets_and_decimate():
    rng = np.random.default_rng(2)
    d = Dataset(rng.normal(size=(300, 1)) + 3, rng.normal(size=(300, 1)) - 1, rng.normal(size=(300, 1)), 0.1)
    est, val = d.split(0.6)
    assert (est.N, val.N) == (180, 120)
    centred = d.remove_offsets()
    assert abs(centred.u.mean()) < 1e-12 and centred.offsets["u"][0] == pytest.approx(d.u.mean())
    assert np.all(centred.p == d.p)
    dec = d.decimate(3)
    assert dec.N == 100 and dec.Ts == pytest.approx(0.3)
    with pytest.raises(DataError, match="whole number"):
        d.decimate(1.5)
    with pytest.raises(DataError, match="between 0 and 1"):
        d.split(1.2)


@pytest.mark.parametrize(
    ("mutate", "extra", "message"),
    [
        (None, ["--y", "nope"], "column(s) ['nope'] not found"),
        (lambda r: r[5].__setitem__(2, "nan"), [], "has NaN/inf at sample 5"),
        (lambda r: r[9].__setitem__(0, 0.95), [], "not uniformly spaced"),
        (lambda r: r[9].__setitem__(0, 0.0), [], "not increasing"),
        (lambda r: r.__delitem__(slice(12, None)), [], "too few"),
        (None, ["--Ts", "-1", "--time", "none_such"], "time column 'none_such' not found"),
        (None, ["--basis", "cubic"], "bad basis spec"),
        (None, ["--na", "2,x"], "bad order"),
    ],
)
def test_cli_bad_input_exit_2_one_line(tmp_path, good_rows, capsys, mutate, extra, message):
    if mutate:
        mutate(good_rows)
    path = write_csv(tmp_path / "d.csv", ["time", "u", "y", "p"], good_rows)
    args = ["identify", str(path), "--u", "u", "--y", "y", "--p", "p", "--basis", "poly:2",
            "-o", str(tmp_path / "m.json")]
    for i in range(0, len(extra), 2):  # later options override earlier ones
        args += extra[i : i + 2]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert message in err
    assert not (tmp_path / "m.json").exists()


def test_cli_never_overwrites_the_data_file(tmp_path, good_rows, capsys):
    path = write_csv(tmp_path / "d.csv", ["time", "u", "y", "p"], good_rows)
    before = path.read_bytes()
    assert main(["identify", str(path), "--u", "u", "--y", "y", "--p", "p", "-o", str(path)]) == 2
    assert "would overwrite the input" in capsys.readouterr().err
    assert path.read_bytes() == before


def test_cli_missing_data_file(tmp_path, capsys):
    assert main(["identify", str(tmp_path / "none.csv"), "--u", "u", "--y", "y", "--p", "p",
                 "-o", str(tmp_path / "m.json")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_cli_nonpositive_ts(tmp_path, good_rows, capsys):
    path = write_csv(tmp_path / "d.csv", ["clock", "u", "y", "p"], good_rows)
    assert main(["identify", str(path), "--u", "u", "--y", "y", "--p", "p", "--Ts", "0",
                 "-o", str(tmp_path / "m.json")]) == 2
    err = capsys.readouterr().err
    assert "Ts must be a positive" in err and err.count("\n") == 1


def test_csv_reads_only_the_named_columns_across_blocks(tmp_path, monkeypatch, good_rows):
    """Columns not asked for are not converted (text there is no error); blocks cut between lines."""
    import lpvflow.data

    monkeypatch.setattr(lpvflow.data, "CSV_BLOCK_BYTES", 64)  # many blocks, lines spanning block edges
    rows = [[*r, "note"] for r in good_rows]
    path = write_csv(tmp_path / "d.csv", ["time", "u", "y", "p", "comment"], rows)
    d = Dataset.read(path, ["u"], ["y"], ["p"])
    np.testing.assert_array_equal(d.p[:, 0], [r[3] for r in good_rows])
    assert d.N == 200 and d.Ts == pytest.approx(0.1)
    assert set(lpvflow.data.read_columns(path, ["y", "time"])) == {"y", "time"}
    assert lpvflow.data.column_names(path) == ["time", "u", "y", "p", "comment"]


@pytest.mark.parametrize("newline", ["\r\n", "\r"])
def test_csv_line_breaks(tmp_path, good_rows, newline):
    path = tmp_path / "d.csv"
    lines = ["time,u,y,p", *(",".join(str(float(v)) for v in r) for r in good_rows)]
    path.write_bytes(newline.join(lines).encode())
    d = Dataset.read(path, ["u"], ["y"], ["p"])
    assert d.N == 200
    np.testing.assert_array_equal(d.u[:, 0], [r[1] for r in good_rows])


def test_empty_cell_is_named_like_nan(tmp_path, good_rows):
    good_rows[12][2] = ""
    with pytest.raises(DataError, match="'y' has NaN/inf at sample 12"):
        Dataset.read(write_csv(tmp_path / "d.csv", ["time", "u", "y", "p"], good_rows), ["u"], ["y"], ["p"])


def test_diagnose_reads_the_data_file_once(tmp_path, monkeypatch, good_rows, capsys):
    import lpvflow.data

    reads = []
    original = lpvflow.data._line_blocks
    monkeypatch.setattr(lpvflow.data, "_line_blocks", lambda path: reads.append(path) or original(path))
    path = write_csv(tmp_path / "d.csv", ["time", "u", "y", "p", "q"], [[*r, 0.0] for r in good_rows])
    assert main(["diagnose", str(path), "--u", "u", "--y", "y", "--p", "p", "--split", "0.5",
                 "--json", str(tmp_path / "o.json")]) == 2  # too few samples: stops after reading
    assert "for validation" in capsys.readouterr().err
    assert reads == [path]


def test_csv_with_a_utf8_byte_order_mark_reads_like_without(tmp_path, good_rows):
    """Excel's "CSV UTF-8" starts with a byte-order mark; the first column is still named ``time``."""
    plain = write_csv(tmp_path / "plain.csv", ["time", "u", "y", "p"], good_rows)
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    a, b = (Dataset.read(path, ["u"], ["y"], ["p"]) for path in (plain, bom))
    assert b.Ts == a.Ts
    np.testing.assert_array_equal(b.y, a.y)
    assert column_names(bom) == ["time", "u", "y", "p"]


@pytest.mark.parametrize("content", [
    "latin-1 header", "png", "latin-1 after the header",
])
def test_csv_that_is_not_utf8_text_is_one_data_error(tmp_path, good_rows, content):
    text = write_csv(tmp_path / "d.csv", ["time", "u", "y", "p"], good_rows).read_bytes()
    if content == "latin-1 header":
        data = text.replace(b"time,u", b"time,\xe9u", 1)
    elif content == "png":
        data = b"\x89PNG\r\n\x1a\n" + bytes(np.random.default_rng(1).integers(0, 256, 4000, dtype=np.uint8))
    else:
        data = text.replace(b"\n", b"\n\xe9", 3)
    path = tmp_path / "d.csv"
    path.write_bytes(data)
    with pytest.raises(DataError, match=r"d\.csv is not CSV text in UTF-8"):
        Dataset.read(path, ["u"], ["y"], ["p"])



def test_data_files_are_parsed_without_arrow_worker_threads(tmp_path, good_rows, monkeypatch):
    """pyarrow's worker pool (C++ std::threads) still busy at interpreter exit aborts the process
    ("terminate called without an active exception", SIGABRT after the CLI's error line); the readers
    parse on the calling thread, so a read leaves no worker running."""
    import pyarrow as pa
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    calls = []
    read_csv, read_table = pacsv.read_csv, pq.read_table
    monkeypatch.setattr(pacsv, "read_csv", lambda *a, **k: calls.append(k["read_options"].use_threads)
                        or read_csv(*a, **k))
    monkeypatch.setattr(pq, "read_table", lambda *a, **k: calls.append(k.get("use_threads", True))
                        or read_table(*a, **k))
    cols = dict(zip(["time", "u", "y", "p"], np.array(good_rows).T, strict=True))
    pq.write_table(pa.table(cols), tmp_path / "d.parquet")
    for path in (write_csv(tmp_path / "d.csv", ["time", "u", "y", "p"], good_rows), tmp_path / "d.parquet"):
        assert Dataset.read(path, ["u"], ["y"], ["p"]).N == 200
    assert calls == [False, False]


def test_the_sampling_time_of_a_time_column_is_its_decimal_step(tmp_path):
    """Times written as k·Ts in decimal text differ by Ts only up to rounding; Ts comes back exact."""
    rng = np.random.default_rng(3)
    for Ts in (0.005, 0.01, 0.2, 1e-4, 0.04, 2.5):
        n = int(rng.integers(100, 50_000))
        t = np.arange(n) * Ts + 300.0  # a late start: the differences carry the rounding of large times
        path = write_csv(tmp_path / "d.csv", ["time", "u", "y", "p"],
                         [[repr(float(tk)), 1.0, 2.0, 3.0] for tk in t])
        assert Dataset.read(path, ["u"], ["y"], ["p"]).Ts == Ts
