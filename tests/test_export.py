"""Controller export: the FMU steps like LPVController (open and closed loop), MAT, JSON, CLI."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
import scipy.io
from fmpy import read_model_description
from fmpy.validation import validate_fmu

from lpvflow.basis import Basis
from lpvflow.errors import DataError
from lpvflow.experiment.controller import load_controller
from lpvflow.loop.fmu_controller import FmuController
from lpvflow.models import LPVSS, load
from lpvflow.pipeline.cli import main
from lpvflow.pipeline.config import bundled_config, load_config
from lpvflow.pipeline.export import export_fmu, export_json, export_mat
from lpvflow.pipeline.ports import controller_signals, describe_signals, design_signals
from lpvflow.pipeline.scenarios import Loop, Scenario, Signal
from lpvflow.pipeline.verify import simulate_loop
from lpvflow.synth.controller import LPVController
from lpvflow.synth.polytope import BoxPolytope, ParabolaTriangle, Polytope, TermBoxPolytope, _corners

ROOT = Path(__file__).resolve().parents[1]
ADIP = ROOT / "fmu_plants" / "build" / "adip.fmu"


def _random_controller(
    poly: Polytope, basis: Basis, seed: int, n: int = 3, ny: int = 2, nu: int = 2
) -> LPVController:
    rng = np.random.default_rng(seed)
    N = poly.n_vertices
    A = 0.6 * rng.standard_normal((N, n, n)) / np.sqrt(n)
    return LPVController(
        A,
        rng.standard_normal((N, n, ny)),
        rng.standard_normal((N, nu, n)),
        rng.standard_normal((N, nu, ny)),
        poly,
        basis,
        0.01,
    )


def _box_controller() -> LPVController:
    box = np.array([[-1.0, 1.0], [0.0, 2.0]])
    poly = BoxPolytope(box, np.column_stack([np.ones(4), _corners(box)]))
    return _random_controller(poly, Basis("affine", 2, p_min=(-1.0, 0.0), p_max=(1.0, 2.0)), 1)


def _parabola_controller() -> LPVController:
    a, b = -0.5, 1.5
    verts = np.array([[1.0, a, a * a], [1.0, 0.5 * (a + b), a * b], [1.0, b, b * b]])
    poly = ParabolaTriangle(np.array([[a, b]]), verts)
    return _random_controller(poly, Basis("poly", 1, degree=2, p_min=(a,), p_max=(b,)), 2)


def _term_box_controller() -> LPVController:
    basis = Basis.spline([0.2], 1)  # ψ = [1, p, |p − 0.2|³] on p ∈ [−1, 1]
    term_box = np.array([[-1.0, 1.0], [0.0, 1.2**3]])
    poly = TermBoxPolytope(
        np.array([[-1.0, 1.0]]), np.column_stack([np.ones(4), _corners(term_box)]), term_box
    )
    return _random_controller(poly, basis, 3, n=2, ny=1, nu=1)


CONTROLLERS = {
    "box": _box_controller,
    "parabola-triangle": _parabola_controller,
    "term-box": _term_box_controller,
}


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[LPVController, Path]]:
    folder = tmp_path_factory.mktemp("fmus")
    return {
        kind: (make(), export_fmu(make(), folder / f"K_{kind.replace('-', '_')}.fmu"))
        for kind, make in CONTROLLERS.items()
    }


@pytest.mark.parametrize("kind", list(CONTROLLERS))
def test_exported_fmu_steps_like_the_python_controller(exported: dict, kind: str) -> None:
    controller, path = exported[kind]
    rng = np.random.default_rng(7)
    lo, hi = controller.polytope.box[:, 0], controller.polytope.box[:, 1]
    p = rng.uniform(lo - 0.3 * (hi - lo), hi + 0.3 * (hi - lo), (400, len(lo)))  # also outside: clipped λ
    e = rng.standard_normal((400, controller.n_in))
    u_python = controller.simulate(e, p)
    fmu = FmuController(path)
    try:
        for _ in range(2):  # a reset restarts from x = 0
            fmu.reset()
            # the FMU reads r and y on separate ports and forms e = r − y: r = e, y = 0
            w = np.hstack([e, np.zeros_like(e)])
            u_fmu = np.array([fmu.step(wk, pk) for wk, pk in zip(w, p, strict=True)])
            assert np.max(np.abs(u_fmu - u_python)) <= 1e-9 * max(1.0, np.max(np.abs(u_python)))
    finally:
        fmu.close()
    assert np.std(u_python) > 0.1  # the comparison is not between zeros


def test_exported_fmu_validates_and_carries_binary_and_sources(exported: dict) -> None:
    controller, path = exported["box"]
    assert validate_fmu(str(path)) == []
    names = zipfile.ZipFile(path).namelist()
    assert any(n.startswith("binaries/") and n.endswith(".so") for n in names)
    for source in ("controller_fmu.c", "controller_data.h", "fmi2Functions.h"):
        assert f"sources/{source}" in names
    description = zipfile.ZipFile(path).read("modelDescription.xml").decode()
    assert f'stepSize="{controller.Ts!r}"' in description
    names = ("y1_ref", "y2_ref", "y1", "y2", "p1", "p2", "u1", "u2")  # defaults without a signal record
    assert all(f'name="{n}"' in description for n in names)


def _adip_lpv_controller() -> LPVController:
    """The ADIP's stabilizing LTI controller in the LPV convention e = r − y, a second vertex 5 % stronger."""
    lti = load_controller(ROOT / "fmu_plants" / "adip" / "stabilizing_controller.json")
    poly = BoxPolytope(np.array([[-0.96, 0.96]]), np.array([[1.0, -0.96], [1.0, 0.96]]))
    scale = np.array([1.0, 1.05])[:, None, None]
    stack = lambda M: np.array([M, M])  # noqa: E731
    return LPVController(
        stack(lti.A),
        -stack(lti.B),
        scale * stack(lti.C),
        -scale * stack(lti.D),
        poly,
        Basis("affine", 1, p_min=(-0.96,), p_max=(0.96,)),
        lti.Ts,
    )


def test_exported_fmu_with_the_plant_fmu_reproduces_the_python_closed_loop(tmp_path: Path) -> None:
    controller = _adip_lpv_controller()
    path = export_fmu(controller, tmp_path / "adip_K.fmu")
    loop = Loop(
        ("arm_angle", "pendulum_angle"),
        ("voltage",),
        ("sin(arm_angle)",),
        actuator_limits={"voltage": (-10.0, 10.0)},
    )
    scenario = Scenario(
        "step",
        2.0,
        reference={"arm_angle": Signal(steps=((0.2, 0.3),))},
        plant_parameters={"x0_pendulum_angle": 0.02},
        settling_band={"pendulum_angle": 0.02},
    )
    python = simulate_loop(controller, ADIP, scenario, loop)
    fmu = FmuController(path)
    try:
        exported_run = simulate_loop(fmu, ADIP, scenario, loop)
    finally:
        fmu.close()
    assert python.failure is None and exported_run.failure is None
    assert np.ptp(python.scheduling) > 0.1  # λ really varies along the run
    np.testing.assert_allclose(exported_run.outputs, python.outputs, rtol=0, atol=1e-9)
    np.testing.assert_allclose(exported_run.control, python.control, rtol=0, atol=1e-9)


def test_mat_round_trip_gives_matlab_layout(tmp_path: Path) -> None:
    controller = _parabola_controller()
    path = export_mat(controller, tmp_path / "K.mat", names={"measured": ["arm", "pendulum"]})
    mat = scipy.io.loadmat(path)
    N, n = controller.polytope.n_vertices, controller.order
    assert mat["Ak"].shape == (n, n, N) and mat["Bk"].shape == (n, 2, N)
    assert mat["Ck"].shape == (2, n, N) and mat["Dk"].shape == (2, 2, N)
    for i in range(N):
        for name in ("Ak", "Bk", "Ck", "Dk"):
            np.testing.assert_array_equal(mat[name][:, :, i], getattr(controller, name)[i])
    np.testing.assert_array_equal(mat["psi_vertices"], controller.polytope.psi_vertices)
    np.testing.assert_array_equal(mat["scheduling_box"], controller.polytope.box)
    assert mat["Ts"].item() == controller.Ts and str(mat["polytope_kind"][0]) == "parabola-triangle"
    assert [str(c[0]) for c in mat["measured_names"][0]] == ["arm", "pendulum"]
    assert [str(c[0]) for c in mat["reference_names"][0]] == ["arm_ref", "pendulum_ref"]
    assert [str(c[0]) for c in mat["actuated_names"][0]] == ["u1", "u2"]
    assert "vertex_inverse" in str(mat["interpolation"][0])
    exponents = mat["basis"]["exponents"][0, 0]
    np.testing.assert_array_equal(exponents, [[0], [1], [2]])
    # a MATLAB user's interpolation Σ λ_i Ak(:,:,i) gives the controller's frozen matrices
    p = 0.7
    lam = controller.coordinates(np.array([p]))
    np.testing.assert_allclose(mat["Ak"] @ lam, controller.matrices(np.array([p]))[0], atol=1e-14)
    # the parabola-triangle rule the MAT file states: λ = vertex_inverse ψ(p) (inside: no clipping)
    np.testing.assert_allclose(mat["vertex_inverse"] @ [1.0, p, p * p], lam, atol=1e-14)


def test_json_export_round_trips(tmp_path: Path) -> None:
    controller = _term_box_controller()
    loaded = load(export_json(controller, tmp_path / "K.json"))
    for name in ("Ak", "Bk", "Ck", "Dk"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(controller, name))
    assert loaded.polytope.kind == "term-box" and loaded.Ts == controller.Ts


def _error_line(capsys: pytest.CaptureFixture, argv: list[str]) -> str:
    try:
        status = main(argv)
    except SystemExit as exc:  # argparse usage errors
        status = exc.code
    assert status == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    return err


def test_export_cli_writes_each_format_and_refuses_bad_input(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    source = tmp_path / "K.json"
    _box_controller().save(source)
    original = source.read_bytes()
    assert main(["export", str(source), "--format", "mat", "-o", str(tmp_path / "K.mat")]) == 0
    assert main(["export", str(source), "--format", "json", "-o", str(tmp_path / "K2.json")]) == 0
    assert json.loads((tmp_path / "K2.json").read_text())["format"] == "lpvflow/lpv-controller"
    assert "input file" in _error_line(capsys, ["export", str(source), "--format", "json", "-o", str(source)])
    assert source.read_bytes() == original
    assert "does not exist" in _error_line(
        capsys, ["export", str(tmp_path / "none.json"), "--format", "mat", "-o", str(tmp_path / "x.mat")]
    )
    _error_line(capsys, ["export", str(source), "--format", "xls", "-o", str(tmp_path / "x.xls")])
    broken = json.loads(original)
    broken["Bk"] = broken["Bk"][:1]
    (tmp_path / "bad.json").write_text(json.dumps(broken))
    assert "Bk" in _error_line(
        capsys, ["export", str(tmp_path / "bad.json"), "--format", "fmu", "-o", str(tmp_path / "bad.fmu")]
    )
    assert not (tmp_path / "bad.fmu").exists()


def _adip_model() -> LPVSS:
    """A model with the ADIP's signal names (matrices irrelevant: only the names are read)."""
    basis = Basis("affine", 1, p_min=(-0.5,), p_max=(0.5,))
    return LPVSS(np.zeros((2, 1, 1)), np.zeros((2, 1, 1)), np.zeros((2, 2, 1)), np.zeros((2, 2, 1)), basis,
                 0.005, u_names=["voltage"], y_names=["arm_angle", "pendulum_angle"], p_names=["sin_arm"])


def _named_adip_controller(trim: float) -> LPVController:
    controller = _adip_lpv_controller()
    controller.info["signals"] = describe_signals(_adip_model(), {"sin_arm": "sin(arm_angle)"}, ADIP,
                                                  {"voltage": trim})
    return controller


def test_fmu_ports_carry_names_units_expressions_trim_and_the_interpolation_rule(tmp_path: Path) -> None:
    controller = _named_adip_controller(trim=0.7)
    path = export_fmu(controller, tmp_path / "K.fmu")
    description = read_model_description(str(path))
    ports = {v.name: v for v in description.modelVariables}
    assert list(ports) == ["arm_angle_ref", "pendulum_angle_ref", "arm_angle", "pendulum_angle", "sin_arm",
                           "voltage"]
    assert {n: v.unit for n, v in ports.items()} == {"arm_angle_ref": "rad", "pendulum_angle_ref": "rad",
                                                    "arm_angle": "rad", "pendulum_angle": "rad",
                                                    "sin_arm": None, "voltage": "V"}
    assert [v.causality for v in ports.values()] == ["input"] * 5 + ["output"]
    assert ports["sin_arm"].description == "scheduling sin_arm = sin(arm_angle)"
    assert ports["arm_angle_ref"].description.startswith("reference for arm_angle")
    assert ports["voltage"].description.startswith("actuated voltage (includes the operating point 0.7 V)")
    assert "box polytope over sin_arm ∈ [-0.96, 0.96]" in description.description
    # the FMU adds the trim: u = 0.7 + K(r − y); with r = y it outputs the trim alone
    fmu = FmuController(path)
    try:
        fmu.reset()
        assert fmu.structure == "2dof" and fmu.n_in == 4  # [r; y] on the named ports
        np.testing.assert_allclose(fmu.step(np.full(4, 0.2), np.zeros(1)), [0.7], atol=1e-12)
        e = np.array([0.1, -0.02])
        controller.reset()
        r, y = np.array([0.3, 0.0]), np.array([0.2, 0.02])  # e = r − y
        np.testing.assert_allclose(fmu.step(np.concatenate([r, y]), np.array([0.3])),
                                   0.7 + controller.step(e, np.array([0.3])),
                                   atol=1e-12)
    finally:
        fmu.close()


def test_mat_carries_names_units_expressions_and_operating_points(tmp_path: Path) -> None:
    mat = scipy.io.loadmat(export_mat(_named_adip_controller(trim=0.7), tmp_path / "K.mat"))
    cells = lambda key: [str(c[0]) if c.size else "" for c in mat[key][0]]  # noqa: E731
    assert cells("measured_names") == ["arm_angle", "pendulum_angle"]
    assert cells("reference_names") == ["arm_angle_ref", "pendulum_angle_ref"]
    assert cells("scheduling_names") == ["sin_arm"] and cells("scheduling_expressions") == ["sin(arm_angle)"]
    assert cells("actuated_names") == ["voltage"] and cells("actuated_units") == ["V"]
    assert cells("measured_units") == ["rad", "rad"]
    np.testing.assert_array_equal(mat["u_operating_point"], [[0.7]])
    np.testing.assert_array_equal(mat["y_operating_point"], [[0.0, 0.0]])
    assert "box polytope" in str(mat["interpolation"][0]) and mat["vertex_inverse"].size == 0


def test_signal_names_survive_the_controller_file(tmp_path: Path) -> None:
    controller = _named_adip_controller(trim=0.0)
    controller.save(tmp_path / "K.json")
    signals = controller_signals(load(tmp_path / "K.json"))
    assert [port.name for port in signals.measured] == ["arm_angle", "pendulum_angle"]
    assert signals.scheduling[0].expression == "sin(arm_angle)"


@pytest.mark.parametrize(
    ("names", "message"),
    [
        ({"measured": ["a"]}, "measured names list 1 names for 2 signals"),
        ({"actuated": ["arm_angle"]}, "must be distinct"),
        ({"measured": ["a", "a_ref"], "actuated": ["a_ref_ref"]}, "must be distinct"),
        ({"scheduling": ["1p"]}, "'1p' is not a valid signal name"),
        ({"inputs": ["a", "b"]}, "unknown signal role(s) ['inputs']"),
    ],
)
def test_bad_signal_names_give_one_line(names: dict, message: str) -> None:
    with pytest.raises(DataError) as info:
        controller_signals(_named_adip_controller(trim=0.0), names)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_the_bundled_adip_design_names_its_controller_ports(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """The synth stage's record: model names, [experiment] scheduling expression, FMU units/descriptions."""
    monkeypatch.chdir(ROOT)  # the bundled design's plant path is relative to the repository root
    config = load_config(bundled_config("adip"))
    controller = _adip_lpv_controller()
    controller.info["signals"] = design_signals(_adip_model(), config["experiment"]["scheduling"],
                                                config["design"]["plant"], config["verify"]["loop"])
    signals = controller_signals(controller)
    assert [(p.name, p.unit) for p in signals.measured] == [("arm_angle", "rad"), ("pendulum_angle", "rad")]
    assert (signals.scheduling[0].name, signals.scheduling[0].expression) == ("sin_arm", "sin(arm_angle)")
    assert (signals.actuated[0].name, signals.actuated[0].unit, signals.actuated[0].operating_point) == (
        "voltage", "V", 0.0)
    assert signals.actuated[0].description  # the plant FMU's description of its input


def test_data_column_names_become_port_names() -> None:
    model = _adip_model()
    model.y_names, model.p_names = ["arm angle", "2nd"], ["sin(arm)"]
    controller = _adip_lpv_controller()
    controller.info["signals"] = describe_signals(model)
    signals = controller_signals(controller)
    assert [p.name for p in signals.measured] == ["arm_angle", "s_2nd"]
    assert signals.measured[0].description == "column 'arm angle'"
    assert (signals.scheduling[0].name, signals.scheduling[0].expression) == ("sin_arm_", "sin(arm)")


def test_fmu_scheduling_inputs_start_at_the_operating_point_and_the_trim_is_named(tmp_path: Path) -> None:
    """The scheduling ports start at their expressions of the measured ports' start values (the arm at its
    operating angle, not the middle of the identified range), so an importer that leaves the inputs at
    their start values gets u_op + u_eq(p(y_op)) at rest; an expression of a signal without an operating
    point starts at the middle of the range."""
    from lpvflow.synth.controller import Trim

    rng = np.random.default_rng(7)
    expressions = {"sin_arm": "sin(arm_angle)", "inv_det": "1/(1 - 0.3785*cos(arm_angle)**2)",
                   "other": "2*diag_scheduling"}
    for arm, u_op in rng.uniform([-1.2, -2.0], [1.2, 2.0], size=(4, 2)):
        basis = Basis("affine", 3, p_min=(-0.2, 1.0, -1.0), p_max=(0.9, 1.7, 3.0))
        zeros = lambda *shape: np.zeros((4, *shape))  # noqa: E731
        model = LPVSS(zeros(1, 1), zeros(1, 1), zeros(2, 1), zeros(2, 1), basis, 0.005, u_names=["voltage"],
                      y_names=["arm_angle", "pendulum_angle"],
                      p_names=list(expressions))
        signals = describe_signals(model, expressions, ADIP, {"arm_angle": arm, "voltage": u_op})
        starts = [port["operating_point"] for port in signals["scheduling"]]
        np.testing.assert_allclose(starts, [np.sin(arm), 1 / (1 - 0.3785 * np.cos(arm) ** 2), 1.0],
                                   rtol=1e-15)
    trim = Trim([-1.0, 1.0], [[4.2], [-4.2]])
    controller = LPVController(np.zeros((2, 1, 1)), np.zeros((2, 1, 2)), np.zeros((2, 1, 1)),
                               np.zeros((2, 1, 2)), BoxPolytope(np.array([[-1.0, 1.0]]),
                                                       np.array([[1.0, -1.0], [1.0, 1.0]])),
                               Basis("affine", 1, p_min=(-0.2,), p_max=(0.9,)), 0.005, trim=trim)
    controller.info["signals"] = describe_signals(_adip_model(), {"sin_arm": "sin(arm_angle)"}, ADIP,
                                                  {"arm_angle": 0.0})
    path = export_fmu(controller, tmp_path / "K.fmu")
    description = read_model_description(str(path))
    ports = {v.name: v for v in description.modelVariables}
    assert float(ports["sin_arm"].start) == 0.0 and float(ports["arm_angle"].start) == 0.0
    assert ports["voltage"].description.startswith("actuated voltage (includes the trim feed-forward "
                                                   "u_eq(sin_arm))")
    assert description.defaultExperiment.stepSize == "0.005"
    fmu = FmuController(path)
    try:
        fmu.reset()
        at_rest = fmu.step(np.zeros(2), np.array([float(ports["sin_arm"].start)]))
    finally:
        fmu.close()
    np.testing.assert_array_equal(at_rest, [0.0])  # u_eq(sin 0°) = 0 V: the operating point
