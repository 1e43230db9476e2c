"""`lpvflow identify` / `lpvflow simulate` end to end on CSV data."""

import json

import numpy as np
import pytest

import lpvflow
from lpvflow.basis import Basis
from lpvflow.models import LPVIO
from lpvflow.pipeline.cli import main


@pytest.fixture
def lpr_csv(tmp_path):
    A = np.zeros((2, 3, 1, 1))
    A[0, :, 0, 0], A[1, :, 0, 0] = [-1.2, 0.2, 0.05], [0.5, -0.1, 0.02]
    B = np.zeros((3, 3, 1, 1))
    B[1, :, 0, 0], B[2, :, 0, 0] = [1.0, 0.3, 0.1], [0.5, -0.2, 0.05]
    true = LPVIO(A, B, Basis.poly(2), 0.01)
    rng = np.random.default_rng(3)
    n = 2000
    u, p = rng.normal(size=(n, 1)), rng.uniform(-1, 1, size=(n, 1))
    y = true.simulate(u, p)
    path = tmp_path / "data.csv"
    np.savetxt(path, np.column_stack([np.arange(n) * 0.01, u, p, y]), delimiter=",",
               header="time,volt,theta,angle", comments="")
    return path, true


def test_identify_then_simulate(tmp_path, lpr_csv, capsys):
    path, true = lpr_csv
    model = tmp_path / "model.json"
    cols = ["--u", "volt", "--y", "angle", "--p", "theta"]
    assert main(["identify", str(path), *cols, "--basis", "poly:2", "-o", str(model)]) == 0
    assert "state order 2" in capsys.readouterr().out
    ss = lpvflow.load(model)
    assert ss.u_names == ["volt"] and ss.Ts == pytest.approx(0.01)
    np.testing.assert_allclose(ss.io.B, true.B, atol=1e-8)
    out = tmp_path / "fit.json"
    assert main(["simulate", str(model), str(path), *cols, "--json", str(out),
                 "--plot", str(tmp_path / "fit.png")]) == 0
    report = json.loads(out.read_text())
    assert report["outputs"] == ["angle"] and report["bfr"][0] > 99.99
    assert (tmp_path / "fit.png").stat().st_size > 1000


def test_static_method_writes_the_io_model_only(tmp_path, lpr_csv, capsys):
    path, _ = lpr_csv
    model = tmp_path / "static.json"
    assert main(["identify", str(path), "--u", "volt", "--y", "angle", "--p", "theta",
                 "--method", "static-arx", "-o", str(model)]) == 0
    assert "no static state-space realization" in capsys.readouterr().out
    assert isinstance(lpvflow.load(model), LPVIO)


def test_simulate_refuses_a_model_data_mismatch(tmp_path, lpr_csv, capsys):
    path, _ = lpr_csv
    model = tmp_path / "model.json"
    assert main(["identify", str(path), "--u", "volt", "--y", "angle", "--p", "theta", "-o", str(model)]) == 0
    capsys.readouterr()
    assert main(["simulate", str(model), str(path), "--u", "volt", "theta", "--y", "angle",
                 "--p", "theta"]) == 2
    err = capsys.readouterr().err
    assert "1x1 with 1 scheduling" in err and err.count("\n") == 1
