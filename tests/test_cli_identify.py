"""`lpvflow identify` / `lpvflow simulate` end to end on CSV data."""

import json
import re

import numpy as np
import pytest

import lpvflow
from lpvflow.basis import Basis
from lpvflow.lpvio import LPVIO
from lpvflow.pipeline.cli import main
from lpvflow.validate.metrics import bfr


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


@pytest.mark.parametrize(("method", "extra"), [
    ("iv-oe", []), ("oe", []), ("pbsid", ["--order", "2"]),
    ("lpr-arx", ["--order", "2"]), ("cva", []), ("kcca-lfr-affine", ["--order", "2"]),
])
def test_every_method_writes_a_loadable_model_that_fits(tmp_path, lpr_csv, capsys, method, extra):
    """Noise-free data of a 2-state shifted-form model: each method's model reloads and simulates it.

    The bounds are loose where a method's model class does not contain the system exactly
    (subspace and LFR approximations); the exact IO estimators must be near-perfect.
    """
    path, _ = lpr_csv
    model = tmp_path / f"{method}.json"
    cols = ["--u", "volt", "--y", "angle", "--p", "theta"]
    basis = ["--basis", "poly:2"] if method not in ("pbsid", "cva", "kcca-lfr-affine") else []
    assert main(["identify", str(path), *cols, *basis, "--method", method, *extra, "-o", str(model)]) == 0
    out = capsys.readouterr().out
    bfr_value = float(out.split("BFR angle ")[1].split(" %")[0])
    assert bfr_value > (99.0 if method in ("iv-oe", "oe", "lpr-arx") else 60.0), out
    loaded = lpvflow.load(model)
    assert loaded.simulate(np.zeros((5, 1)), np.zeros((5, 1))).shape == (5, 1)


def test_two_step_needs_its_excitation_column(tmp_path, lpr_csv, capsys):
    path, _ = lpr_csv
    assert main(["identify", str(path), "--u", "volt", "--y", "angle", "--p", "theta", "--method", "two-step",
                 "-o", str(tmp_path / "m.json")]) == 2
    assert "needs --excitation" in capsys.readouterr().err


def test_armax_on_data_with_innovation_noise(tmp_path, capsys):
    """ARMAX needs noise: on noise-free data its C polynomial is unidentifiable (and refused)."""
    rng = np.random.default_rng(8)
    n = 3000
    A = np.zeros((1, 2, 1, 1))
    A[0, :, 0, 0] = [-0.7, 0.1]
    B = np.zeros((2, 2, 1, 1))
    B[1, :, 0, 0] = [1.0, 0.3]
    C = np.zeros((1, 2, 1, 1))
    C[0, 0, 0, 0] = 0.5
    true = LPVIO(A, B, Basis.affine(), 0.1, C=C)
    u, p = rng.normal(size=(n, 1)), rng.uniform(-1, 1, size=(n, 1))
    y = true.simulate(u, p, e=0.1 * rng.normal(size=(n, 1)))
    path = tmp_path / "d.csv"
    np.savetxt(path, np.column_stack([np.arange(n) * 0.1, u, p, y]), delimiter=",", header="time,u,p,y",
               comments="")
    model = tmp_path / "armax.json"
    assert main(["identify", str(path), "--u", "u", "--y", "y", "--p", "p", "--na", "1", "--nb", "1",
                 "--method", "armax", "--nc", "1", "-o", str(model)]) == 0
    loaded = lpvflow.load(model)
    assert loaded.K is not None  # the innovation gain of Schulz eq. (4)
    assert loaded.io.C[0, 0, 0, 0] == pytest.approx(0.5, abs=0.05)


def test_a_model_identified_in_deviations_records_its_operating_point(tmp_path, lpr_csv):
    """`identify --remove-offsets` on a record with large input and output offsets writes the record's
    means into the model (``operating_point``), and `simulate` on the recorded signals gives
    y₀ + G(u − u₀): its BFR is that formula's, not the deviation model's on the raw signals."""
    path, _ = lpr_csv
    table = np.loadtxt(path, delimiter=",", skiprows=1)
    table[:, 1] += 3.0  # volt around 3
    table[:, 3] += -40.0  # angle around −40
    shifted = tmp_path / "shifted.csv"
    np.savetxt(shifted, table, delimiter=",", header="time,volt,theta,angle", comments="")
    model, fit = tmp_path / "model.json", tmp_path / "fit.json"
    cols = ["--u", "volt", "--y", "angle", "--p", "theta"]
    assert main(["identify", str(shifted), *cols, "--basis", "poly:2", "--remove-offsets",
                 "-o", str(model)]) == 0
    io = lpvflow.load(model).io
    u, p, y = table[:, 1:2], table[:, 2:3], table[:, 3:4]
    np.testing.assert_allclose(io.operating_point["u"], u.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(io.operating_point["y"], y.mean(axis=0), rtol=1e-12)
    assert main(["simulate", str(model), str(shifted), *cols, "--json", str(fit)]) == 0
    reported = json.loads(fit.read_text())["bfr"][0]
    expected = bfr(y, y.mean(axis=0) + io.simulate(u - u.mean(axis=0), p))
    assert reported == pytest.approx(expected, abs=1e-9)
    assert reported > 95.0 > bfr(y, io.simulate(u, p))


@pytest.mark.parametrize("point, message", [
    ({"u": [1.0]}, "operating_point must give the input and output means"),
    ({"u": [1.0, 2.0], "y": [0.0]}, "operating_point['u'] must hold 1 finite number(s)"),
    ({"u": [1.0], "y": [float("nan")]}, "operating_point['y'] must hold 1 finite number(s)"),
])
def test_a_bad_operating_point_is_one_line(point, message):
    with pytest.raises(lpvflow.errors.ModelError, match=re.escape(message)):
        LPVIO(np.zeros((1, 2, 1, 1)), np.ones((2, 2, 1, 1)), Basis.poly(1), 0.1, operating_point=point)


def test_the_operating_point_survives_the_model_file(tmp_path):
    io = LPVIO(np.full((1, 2, 1, 1), -0.2), np.ones((2, 2, 1, 1)), Basis.poly(1), 0.1,
               operating_point={"u": [2.0], "y": [-1.5]})
    io.save(tmp_path / "io.json")
    assert lpvflow.load(tmp_path / "io.json").operating_point == {"u": [2.0], "y": [-1.5]}
    assert "operating_point" not in LPVIO(io.A, io.B, io.basis, io.Ts).to_dict()
