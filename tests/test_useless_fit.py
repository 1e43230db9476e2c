"""A fit that explains none of an output is reported in one line (exit 1), never a silent BFR 0 %."""

from pathlib import Path

import numpy as np
import pytest

from lpvflow.data import Dataset
from lpvflow.identify.fit_check import UselessFitWarning, useless_fit_message
from lpvflow.identify.kcca_lfr import identify_kcca_lfr
from lpvflow.pipeline.cli import main

ROOT = Path(__file__).resolve().parents[1]


def test_kcca_lfr_on_the_tanks_data_exits_1_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    data = tmp_path / "tanks.csv"
    tanks = ROOT / "fmu_plants" / "build" / "tanks.fmu"
    assert main(["experiment", str(tanks), "--Ts", "1", "--duration", "600",
                 "--input", "pump_voltage=prbs:amp=1,clock=10,order=6,offset=5", "-o", str(data)]) == 0
    capsys.readouterr()
    columns = ["--u", "pump_voltage", "--y", "lower_level", "--p", "level"]
    assert main(["identify", str(data), *columns, "--method", "kcca-lfr-affine", "--order", "2",
                 "-o", str(tmp_path / "lfr.json")]) == 1
    captured = capsys.readouterr()
    assert captured.err.count("\n") == 1 and "Traceback" not in captured.err
    assert captured.err.startswith(
        "warning: kcca-lfr-affine: useless fit on the estimation data, lower_level BFR 0.00 %")
    assert (tmp_path / "lfr.json").exists()  # written, for inspection
    assert main(["identify", str(data), *columns, "-o", str(tmp_path / "arx.json")]) == 0  # LPR-ARX fits it
    assert capsys.readouterr().err == ""


def _noise_data(n: int = 600) -> Dataset:
    rng = np.random.default_rng(4)
    return Dataset(rng.normal(size=(n, 1)), rng.normal(size=(n, 1)), rng.uniform(-1, 1, (n, 1)), 0.1,
                   ["u"], ["y"], ["p"])


def test_every_cli_method_reports_output_unrelated_to_the_input(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    data = _noise_data()
    path = tmp_path / "noise.csv"
    np.savetxt(path, np.column_stack([np.arange(data.N) * data.Ts, data.u, data.y, data.p]), delimiter=",",
               header="time,u,y,p", comments="")
    for method in ("lpr-arx", "static-arx", "oe"):
        assert main(["identify", str(path), "--u", "u", "--y", "y", "--p", "p", "--method", method,
                     "-o", str(tmp_path / f"{method}.json")]) == 1, method
        assert f"warning: {method}: useless fit" in capsys.readouterr().err


def test_kcca_lfr_warns_from_python() -> None:
    with pytest.warns(UselessFitWarning, match="kcca-lfr: useless fit on the estimation data, y BFR"):
        identify_kcca_lfr(_noise_data(400), 2, affine=True)


def test_message_names_only_the_unexplained_outputs() -> None:
    fit = {"outputs": ["a", "b", "c"], "bfr": [80.0, 3.0, float("nan")], "mse": [0.1, 2.0, float("inf")]}
    message = useless_fit_message(fit, "oe")
    assert "b BFR 3.00 %" in message and "c BFR nan %" in message and "a BFR" not in message
    assert useless_fit_message({**fit, "bfr": [80.0, 50.0, 6.0]}, "oe") is None
