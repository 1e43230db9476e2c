"""`lpvflow validate` end to end: fit, frozen ν-gap vs b(P, K), margins, certificate, figures, bad input."""

import json
from pathlib import Path

import control as ct
import numpy as np
import pytest

import lpvflow
from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.experiment import run_fmu_experiment
from lpvflow.experiment.controller import LtiController
from lpvflow.lpvio import LPVIO
from lpvflow.pipeline.cli import main
from lpvflow.synth.controller import LPVController
from lpvflow.synth.polytope import polytope_of
from lpvflow.validate.fmu_reference import FmuLinearization
from lpvflow.validate.margins import stability_margin
from lpvflow.validate.nugap import nugap
from tests.fmu_builds import built_fmu

ROOT = Path(__file__).resolve().parents[1]
Ts = 0.05
COLUMNS = ["--u", "volt", "--y", "level", "--p", "theta"]


def true_system(b_sign=1.0):
    """y(k) + a1(p) y(k−1) + a2(p) y(k−2) = b1(p) u(k−1) + b2(p) u(k−2), stable on p ∈ [−1, 1]."""
    A = np.zeros((2, 2, 1, 1))
    A[0, :, 0, 0], A[1, :, 0, 0] = [-1.2, 0.2], [0.5, -0.1]
    B = np.zeros((3, 2, 1, 1))
    B[1, :, 0, 0], B[2, :, 0, 0] = [b_sign * 1.0, 0.3], [0.5, -0.2]
    return LPVIO(A, B, Basis.affine(1), Ts)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Noisy data of the true system, the LPV-ARX identified from it, the true model and controllers."""
    folder = tmp_path_factory.mktemp("validate")
    rng = np.random.default_rng(5)
    n = 1500
    u, p = rng.normal(size=(n, 1)), np.sin(np.arange(n) / 150.0)[:, None]
    y = true_system().simulate(u, p) + 0.01 * rng.normal(size=(n, 1))
    data = folder / "data.csv"
    np.savetxt(data, np.column_stack([np.arange(n) * Ts, u, p, y]), delimiter=",",
               header="time,volt,theta,level", comments="")
    model = lpvflow.identify_arx(Dataset(u, y, p, Ts, ["volt"], ["level"], ["theta"]), 2, 2, 1).to_ss()
    model.save(folder / "model.json")
    reference = true_system().to_ss()
    reference.basis = model.basis  # same recorded scheduling range
    reference.save(folder / "reference.json")
    far = true_system(b_sign=-1.0).to_ss()
    far.basis = model.basis
    far.save(folder / "far.json")
    lti = LtiController.from_statespace(ct.ss([], [], [], [[-0.1]], Ts), ["level"], ["volt"])
    (folder / "lti.json").write_text(json.dumps(lti.to_dict()))
    polytope = polytope_of(model)
    # u(k) = g(p) e(k−1): one state, because an order-0 LPVController does not survive its JSON
    # round trip (empty Ak/Bk/Ck lose their shapes in LPVController.from_dict)
    gains = np.array([0.05 if psi[1] < 0 else 0.15 for psi in polytope.psi_vertices]).reshape(-1, 1, 1)
    one, zero = np.ones_like(gains), np.zeros_like(gains)
    LPVController(zero, one, gains, zero, polytope, model.basis, Ts).save(folder / "lpv.json")
    return folder


def run(*argv):
    return main(["validate", *map(str, argv)])


def test_validate_against_true_model_with_lti_controller(files, tmp_path, capsys):
    out, figures = tmp_path / "report.json", tmp_path / "figs"
    status = run(files / "model.json", files / "data.csv", *COLUMNS, "--reference", files / "reference.json",
                 "--controller", files / "lti.json", "--grid", 4, "--json", out, "--figures", figures)
    printed = capsys.readouterr().out
    assert status == 0, printed
    report = json.loads(out.read_text())
    model, reference = lpvflow.load(files / "model.json"), lpvflow.load(files / "reference.json")
    assert report["fit"]["bfr"][0] > 95
    rows = report["frozen"]["rows"]
    assert [r["p"][0] for r in rows] == pytest.approx(np.linspace(*model.basis.p_min, *model.basis.p_max, 4))
    K = ct.ss([], [], [], [[0.1]], Ts)  # the file's u = −0.1 y is K = 0.1 in u = −K y
    for row in rows:
        p = np.array(row["p"])
        assert row["nugap"] == pytest.approx(nugap(reference.frozen(p), model.frozen(p)).value, abs=1e-12)
        assert row["stability_margin_b"] == pytest.approx(stability_margin(model.frozen(p), K), rel=1e-9)
        assert row["passes"] and row["nugap"] < 0.05
        assert row["margins"]["gain_margin"] > 1 and row["margins"]["disk_margin"] > 0
    assert report["nugap_test"] == {"applicable": True, "passes_everywhere": True, "failing_points": []}
    assert report["quadratic_stability"]["certified"]
    for name in ("frozen_bode.png", "nugap_vs_b.png"):
        png = (figures / name).read_bytes()
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    assert "nu-gap < b at every grid point" in printed


def test_lpv_controller_is_used_frozen_and_a_far_reference_fails_with_status_1(files, tmp_path, capsys):
    out = tmp_path / "report.json"
    status = run(files / "model.json", files / "data.csv", *COLUMNS, "--reference", files / "far.json",
                 "--controller", files / "lpv.json", "--grid", 3, "--json", out)
    assert status == 1
    assert "FAILS" in capsys.readouterr().out
    report = json.loads(out.read_text())
    model, controller = lpvflow.load(files / "model.json"), lpvflow.load(files / "lpv.json")
    for row in report["frozen"]["rows"]:
        p = np.array(row["p"])
        expected = stability_margin(model.frozen(p), controller.frozen(p))
        assert row["stability_margin_b"] == pytest.approx(expected, rel=1e-9)
        assert row["passes"] == (row["nugap"] < row["stability_margin_b"])
    assert report["nugap_test"]["failing_points"]
    assert report["figures"] == {}


def test_without_reference_or_controller_reports_fit_and_certificate_only(files, tmp_path, capsys):
    out = tmp_path / "report.json"
    assert run(files / "model.json", files / "data.csv", *COLUMNS, "--json", out) == 0
    report = json.loads(out.read_text())
    assert report["nugap_test"]["applicable"] is False
    assert report["margins"].startswith("not applicable")
    assert all(set(row) == {"p", "kind"} for row in report["frozen"]["rows"])


def test_non_affine_basis_certificate_is_not_applicable(files, tmp_path):
    data = np.loadtxt(files / "data.csv", delimiter=",", skiprows=1)
    model = lpvflow.identify_arx(Dataset(data[:, 1:2], data[:, 3:4], data[:, 2:3], Ts), 2, 2, 1, "poly:2")
    model.save(tmp_path / "poly.json")
    out = tmp_path / "report.json"
    assert run(tmp_path / "poly.json", files / "data.csv", *COLUMNS, "--json", out) == 0
    certificate = json.loads(out.read_text())["quadratic_stability"]
    assert certificate["applicable"] is False and "not affine" in certificate["reason"]


@pytest.fixture(scope="module")
def tanks_model(tmp_path_factory):
    fmu = built_fmu("tanks")
    folder = tmp_path_factory.mktemp("tanks")
    voltage = "aprbs:lo=4,hi=10,min_hold=10,max_hold=60"
    record = run_fmu_experiment(fmu, 0.2, 3000, inputs={"pump_voltage": voltage}, output=folder / "data.csv",
                                progress=False)
    data = Dataset.read(folder / "data.csv", ["pump_voltage"], ["lower_level"], ["level"])
    lpvflow.identify_arx(data, 2, 2, 1).to_ss().save(folder / "model.json")
    assert record.Ts == 0.2
    return fmu, folder


def test_fmu_reference_gives_the_gap_to_the_linearization(tanks_model, tmp_path):
    fmu, folder = tanks_model
    out = tmp_path / "report.json"
    status = run(folder / "model.json", folder / "data.csv", "--u", "pump_voltage", "--y", "lower_level",
                 "--p", "level", "--reference", fmu, "--fmu-scheduling", "diag_scheduling", "--grid", 3,
                 "--json", out)
    assert status == 0
    rows = json.loads(out.read_text())["frozen"]["rows"]
    model = lpvflow.load(folder / "model.json")
    with FmuLinearization(fmu, 0.2, "diag_scheduling") as linearize:
        for row in rows:
            p = np.array(row["p"])
            assert row["nugap"] == pytest.approx(nugap(linearize(p), model.frozen(p)).value, abs=1e-9)
            assert 0 <= row["nugap"] < 1


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (["--json", "{data}"], "would overwrite the input"),
        (["--reference", "{fmu}", "--json", "{out}"], "--fmu-scheduling"),
        (["--fmu-scheduling", "level", "--json", "{out}"], "needs --reference"),
        (["--fmu-hold", "lower_level=0.1", "--json", "{out}"], "--fmu-hold needs --reference"),
        (["--reference", "{fmu}", "--fmu-scheduling", "diag_scheduling", "--fmu-hold", "nowhere=0.1",
          "--json", "{out}"], "held outputs nowhere are not outputs"),
        (["--reference", "{fmu}", "--fmu-scheduling", "diag_scheduling", "--fmu-hold", "lower_level=high",
          "--json", "{out}"], "lower_level='high': the value is not a number"),
        (["--reference", "{model}", "--fmu-hold", "lower_level=0.1", "--json", "{out}"],
         "apply only to an FMU reference"),
        (["--controller", "{model}", "--json", "{out}"], "holds no controller"),
        (["--controller", "{wide}", "--json", "{out}"], "must be 1x1"),
        (["--grid", "1", "--json", "{out}"], "at least 2 points"),
        (["--reference", "{missing}", "--json", "{out}"], "does not exist"),
    ],
)
def test_bad_input_exits_2_with_one_line(files, tmp_path, capsys, extra, words):
    wide = LtiController.from_statespace(ct.ss([], [], [], [[0.1], [0.2]], Ts), ["level"], ["volt", "x"])
    (tmp_path / "wide.json").write_text(json.dumps(wide.to_dict()))
    names = {"data": files / "data.csv", "fmu": ROOT / "fmu_plants" / "build" / "tanks.fmu",
             "model": files / "model.json", "wide": tmp_path / "wide.json", "out": tmp_path / "r.json",
             "missing": tmp_path / "missing.json"}
    args = [a.format(**names) for a in extra]
    before = (files / "data.csv").read_bytes()
    assert run(files / "model.json", files / "data.csv", *COLUMNS, *args) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1 and "Traceback" not in err
    assert (files / "data.csv").read_bytes() == before
    assert not (tmp_path / "r.json").exists()


def test_mismatched_data_columns_exit_2(files, tmp_path, capsys):
    status = run(files / "model.json", files / "data.csv", "--u", "volt", "theta", "--y", "level",
                 "--p", "theta", "--json", tmp_path / "r.json")
    assert status == 2 and "the model is 1x1" in capsys.readouterr().err


def test_fmu_local_arx_reference_is_within_its_gap_to_the_linearization(tanks_model, tmp_path):
    """δν is a metric: |δν(local, Ĝ) − δν(lin, Ĝ)| ≤ δν(local, lin), below 1e-4 for 1 % swings
    (test_fmu_reference.py)."""
    fmu, folder = tanks_model
    gaps = {}
    for kind in ("linearization", "local-arx"):
        out = tmp_path / f"{kind}.json"
        assert run(folder / "model.json", folder / "data.csv", "--u", "pump_voltage", "--y", "lower_level",
                   "--p", "level", "--reference", fmu, "--fmu-scheduling", "diag_scheduling",
                   "--fmu-reference", kind, "--grid", 2, "--json", out) == 0
        gaps[kind] = np.array([row["nugap"] for row in json.loads(out.read_text())["frozen"]["rows"]])
    assert np.all(np.abs(gaps["local-arx"] - gaps["linearization"]) < 1e-4)


def test_fmu_hold_pins_the_reference_equilibria(tmp_path):
    """The maglev has two coil currents and one scheduling signal (the upper disk), so its equilibria
    form a curve; ``--fmu-hold`` pins the lower disk as ``[validate] hold`` does in a design. The model is
    the FMU's own linearization at (lower 1.5 cm, upper at the middle of the range), held constant: with
    the hold every row's ν-gap is the one to the held linearization at that point (0 at the middle),
    without it the equilibrium search leaves the lower disk elsewhere and the gaps differ."""
    fmu, Ts, upper = built_fmu("maglev"), 0.002, [0.074, 0.087]
    start = {"lower_disk_position": 0.015, "upper_disk_position": 0.08, "lower_coil_current": 0.927,
             "upper_coil_current": -0.045}
    hold = {"lower_disk_position": 0.015}
    with FmuLinearization(fmu, Ts, ["upper_disk_position"], start, hold=hold) as held:
        G = held(np.array([np.mean(upper)]))
    constant = [np.stack([M, np.zeros_like(M)]) for M in (G.A, G.B, G.C, G.D)]
    model = lpvflow.LPVSS(*constant, Basis("affine", 1, p_min=(upper[0],), p_max=(upper[1],)), Ts,
                          u_names=["lower_coil_current", "upper_coil_current"],
                          y_names=["lower_disk_position", "upper_disk_position"], p_names=["upper"])
    model.save(tmp_path / "model.json")
    rng = np.random.default_rng(36)
    n = 60
    u, p = 0.01 * rng.standard_normal((n, 2)), np.linspace(*upper, n)[:, None]
    y = model.simulate(u, p)
    np.savetxt(tmp_path / "data.csv", np.column_stack([np.arange(n) * Ts, u, y, p]), delimiter=",",
               header="time,i_lower,i_upper,y_lower,y_upper,upper", comments="")
    columns = ["--u", "i_lower", "i_upper", "--y", "y_lower", "y_upper", "--p", "upper"]
    common = ["--reference", fmu, "--fmu-scheduling", "upper_disk_position", "--grid", 3,
              "--fmu-start", *[f"{k}={v}" for k, v in start.items()]]
    gaps = {}
    for name, option in (("held", ["--fmu-hold", "lower_disk_position=0.015"]), ("free", [])):
        out = tmp_path / f"{name}.json"
        assert run(tmp_path / "model.json", tmp_path / "data.csv", *columns, *common, *option,
                   "--json", out) == 0
        rows = json.loads(out.read_text())["frozen"]["rows"]
        gaps[name] = np.array([row["nugap"] for row in rows])
        points = [np.array(row["p"]) for row in rows]
    with FmuLinearization(fmu, Ts, ["upper_disk_position"], start, hold=hold) as held:
        expected = [nugap(held(q), model.frozen(q)).value for q in points]
    np.testing.assert_allclose(gaps["held"], expected, atol=1e-9)
    assert min(gaps["held"]) < 1e-6
    assert np.max(np.abs(gaps["free"] - gaps["held"])) > 1e-3
