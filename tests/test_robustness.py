"""The robustness stage: b(Ĝ, K_fb) of the synthesized controller's feedback part at the validate points,
checked against an independent frequency-grid formula, in summary.json and the report, not in the verdict.

b(G, K) for u = K y is computed here from its definition, 1/sup_ω σ_max([I; K](I − GK)⁻¹[I  G])(e^{jω}),
on a dense unit-circle grid refined around its peak, with internal stability from the closed loop's
eigenvalues — no lpvflow margin code.
"""

import json
import warnings
from pathlib import Path

import control
import numpy as np
import pytest

from lpvflow.basis import Basis, SchedulingRangeWarning
from lpvflow.models import load
from lpvflow.pipeline.cli import main
from lpvflow.pipeline.design import run_design
from lpvflow.pipeline.robustness import measurement_feedback
from lpvflow.synth.controller import LPVController
from lpvflow.synth.loop_shaping import central_ncf_controller
from lpvflow.synth.polytope import PointPolytope
from lpvflow.validate.robust_stability import generalized_margin
from tests.design_files import tanks_head, tanks_synth

ROOT = Path(__file__).resolve().parents[1]


def _response(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, z: np.ndarray) -> np.ndarray:
    """C (zI − A)⁻¹ B + D at every z, shape (len(z), outputs, inputs)."""
    n = A.shape[0]
    if n == 0:
        return np.broadcast_to(D, (len(z), *D.shape)).astype(complex)
    resolvent = z[:, None, None] * np.eye(n) - A
    return C @ np.linalg.solve(resolvent, np.broadcast_to(B, (len(z), *B.shape))) + D


def _peak(G: tuple, K: tuple, omega: np.ndarray) -> tuple[float, int]:
    z = np.exp(1j * omega)
    g, k = _response(*G, z), _response(*K, z)
    ny = g.shape[1]
    inner = np.linalg.inv(np.eye(ny) - g @ k)
    left = np.concatenate([np.broadcast_to(np.eye(ny), (len(z), ny, ny)), k], axis=1)
    right = np.concatenate([np.broadcast_to(np.eye(ny), (len(z), ny, ny)), g], axis=2)
    sigma = np.linalg.svd(left @ inner @ right, compute_uv=False)[:, 0]
    return float(sigma.max()), int(sigma.argmax())


def grid_margin(G: tuple, K: tuple) -> float:
    """b(G, K) for u = K y from its definition (module docstring): 0 when a closed-loop eigenvalue is on or
    outside the unit circle."""
    AG, BG, CG, DG = G
    AK, BK, CK, DK = K
    E = np.linalg.inv(np.eye(CG.shape[0]) - DG @ DK)
    closed = np.block([[AG + BG @ DK @ E @ CG, BG @ (CK + DK @ E @ DG @ CK)],
                       [BK @ E @ CG, AK + BK @ E @ DG @ CK]])
    if np.max(np.abs(np.linalg.eigvals(closed))) >= 1.0:
        return 0.0
    # ω > 0: a plant pole at z = 1 (an integrator) makes G(1) infinite while T stays finite near it
    omega = np.linspace(0.0, np.pi, 40001)[1:]
    omega = np.unique(np.concatenate([omega, np.logspace(-7, np.log10(np.pi), 20001)]))
    peak, i = _peak(G, K, omega)
    fine = np.linspace(omega[max(i - 1, 0)], omega[min(i + 1, len(omega) - 1)], 4001)
    return 1.0 / max(peak, _peak(G, K, fine)[0])


def _matrices(system: control.StateSpace) -> tuple:
    return tuple(np.asarray(M, dtype=float) for M in (system.A, system.B, system.C, system.D))


def run_bundled_design(name: str, folder: Path) -> tuple[dict, Path]:
    """``lpvflow design --example name`` written into ``folder``: (summary, the design's output folder)."""
    from lpvflow.pipeline.config import bundled_config, repository_root

    text = bundled_config(name).read_text()
    text = text.replace(f'name = "{name}"', f'name = "{name}"\noutput_dir = "{folder}"')
    (folder / "design.toml").write_text(text)
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(repository_root())
        summary = run_design(folder / "design.toml", log=lambda _: None)
    written = json.loads((folder / name / "summary.json").read_text())
    assert written["verdict"] == summary["verdict"]
    return summary, folder / name


def assert_shipped_b_above_nugap(summary: dict, folder: Path, Du: np.ndarray, Dy: np.ndarray,
                                 points: int) -> None:
    """At each of the ``points`` validate points θ: b(Ĝ(θ), K_fb(θ)) by :func:`grid_margin` — the frozen
    model and the 2-DOF controller's measurement columns in validate's scaling D_u, D_y — is at least
    max(1.5·ν-gap, 0.05) and equals the robustness stage's b within 1 %; the stage says guaranteed."""
    stage = summary["stages"]["robustness"]["outputs"]
    validate = summary["stages"]["validate"]["outputs"]
    model, controller = load(folder / "model.json"), load(folder / "controller.json")
    assert controller.info["method"] == "loop-shaping" and len(stage["rows"]) == points
    ny = Dy.shape[0]
    for row, theta, gap in zip(stage["rows"], validate["theta"], validate["nugap"], strict=True):
        AG, BG, CG, DG = _matrices(model.frozen(np.array(theta)))
        AK, BK, CK, DK = _matrices(controller.frozen(np.array(theta)))
        G = (AG, BG @ Du, np.linalg.solve(Dy, CG), np.linalg.solve(Dy, DG) @ Du)
        K_fb = (AK, BK[:, ny:] @ Dy, np.linalg.solve(Du, CK), np.linalg.solve(Du, DK[:, ny:]) @ Dy)
        b = grid_margin(G, K_fb)
        assert b >= max(1.5 * gap, 0.05), (theta, b, gap)
        assert row["b"] == pytest.approx(b, rel=0.01)
    assert stage["guaranteed"] is True


def _random_plant(rng: np.random.Generator, n: int, ny: int, nu: int) -> control.StateSpace:
    A = rng.standard_normal((n, n))
    A *= rng.uniform(0.5, 1.2) / np.max(np.abs(np.linalg.eigvals(A)))  # stable or unstable
    return control.ss(A, rng.standard_normal((n, nu)), rng.standard_normal((ny, n)), np.zeros((ny, nu)), 0.01)


def _wrapped(K: control.StateSpace, structure: str, rng: np.random.Generator) -> LPVController:
    """A controller (u = K y) as the LTI point controller of the given structure: 1dof reads r − y, so it
    is −K; 2dof reads [r; y], so K is its measurement columns, with a random reference part in front."""
    A, B, C, D = _matrices(K)
    if structure == "1dof":
        Bk, Dk = B, -D
        C = -C
    else:
        Bk, Dk = np.hstack([rng.standard_normal(B.shape), B]), np.hstack([rng.standard_normal(D.shape), D])
    point = PointPolytope(np.array([[0.0, 0.0]]), np.array([[1.0, 0.0]]))
    return LPVController(A[None], Bk[None], C[None], Dk[None], point, Basis("affine", 1), 0.01,
                         structure=structure)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("structure", ["1dof", "2dof"])
def test_feedback_part_has_the_margin_of_the_controller_it_was_built_from(seed, structure):
    """A central loop-shaping controller K (u = K y, b(G, K) ≥ 1/γ by construction) wrapped as a 1-DOF
    controller (it reads r − y) or as the measurement columns of a 2-DOF one: its feedback part gives
    the b of (G, K), within 1 % of the grid formula; the wrong sign would give another loop."""
    rng = np.random.default_rng(seed)
    G = _random_plant(rng, int(rng.integers(2, 5)), int(rng.integers(1, 3)), 1)
    K, gamma = central_ncf_controller(G, gamma_factor=float(rng.uniform(1.05, 1.5)))
    K_fb = measurement_feedback(_wrapped(K, structure, rng), np.array([0.0]))
    expected = grid_margin(_matrices(G), _matrices(K))
    assert expected >= (1.0 - 1e-3) / gamma
    assert generalized_margin(G, K_fb) == pytest.approx(expected, rel=0.01)
    assert grid_margin(_matrices(G), _matrices(-K_fb)) != pytest.approx(expected, rel=0.1)


#: A fast design (about 7 s): the stable tanks, LPV model of the lower level, the "common" LMI controller
#: (1-DOF), validated against the FMU's linearizations at three levels with fixed signal scales.
TANKS = """na = 2
nb = 2
nk = 1
basis = "poly:2"
split = 0.6
remove_offsets = true

[reduce]
order = 2

[validate]
grid = 3
reference = "linearization"
scaling = {{ pump_voltage = {u_scale}, lower_level = {y_scale} }}
"""


def test_design_reports_b_of_its_controller_against_the_nugap_without_changing_the_verdict(tmp_path):
    """The tanks design: at every validate point the stage's b equals the grid formula's b of the frozen
    model and the controller's feedback (−K for a 1-DOF controller), both scaled as [validate] scaling
    says, within 1 %; its ν-gap is the validate stage's; summary.json carries the rows. The controller's b
    is below the ν-gap at the empty-tank end (ν-gap 0.69, b 0.36 with scales 2 V and 0.05 m), so the
    report says "not guaranteed" naming that point, and the design still passes (the stage only
    reports)."""
    u_scale, y_scale = 2.0, 0.05
    path = tmp_path / "design.toml"
    path.write_text(tanks_head(ROOT / "fmu_plants" / "build" / "tanks.fmu", tmp_path / "out")
                    + TANKS.format(u_scale=u_scale, y_scale=y_scale) + tanks_synth('method = "common"'))
    summary = run_design(path, log=lambda _: None)
    folder = tmp_path / "out" / "tanks"
    assert summary["verdict"]["pass"] is True
    stage = json.loads((folder / "summary.json").read_text())["stages"]["robustness"]["outputs"]
    assert stage == summary["stages"]["robustness"]["outputs"]
    validate = summary["stages"]["validate"]["outputs"]
    rows = stage["rows"]
    assert [row["theta"] for row in rows] == validate["theta"] and len(rows) == 3
    assert [row["nugap"] for row in rows] == validate["nugap"]
    model, controller = load(folder / "model.json"), load(folder / "controller.json")
    assert controller.structure == "1dof"
    for row in rows:
        with warnings.catch_warnings():  # the box's upper end, to the last bit
            warnings.simplefilter("ignore", SchedulingRangeWarning)
            AG, BG, CG, DG = _matrices(model.frozen(np.array(row["theta"])))
        AK, BK, CK, DK = _matrices(controller.frozen(np.array(row["theta"])))
        G = (AG, BG * u_scale, CG / y_scale, DG * u_scale / y_scale)
        K_fb = (AK, -BK * y_scale, CK / u_scale, -DK * y_scale / u_scale)  # u = K(r − y): feedback −K
        assert row["b"] == pytest.approx(grid_margin(G, K_fb), rel=0.01)
        assert row["b_above_nugap"] == (row["b"] > row["nugap"])
        assert row["delay_margin_samples"] >= 1 and 0 < row["input_disk_margin"] < 2
    failing = [row for row in rows if not row["b_above_nugap"]]
    assert failing and len(failing) < len(rows) and stage["guaranteed"] is False
    assert stage["not_guaranteed_at"] == [row["theta"] for row in failing]
    report = (folder / "report.html").read_text()
    assert f"robust stability (Vinnicombe): not guaranteed at {len(failing)} of 3 points (" in report
    # the level is the lower level itself, shown to 3 digits of the 0.18 m span
    named = [f"lower_level {round(row['theta'][0], 4) + 0.0:g} m" for row in failing]
    assert all(name in report for name in named)
    assert "robustness_physical.png" in report


@pytest.mark.parametrize("gate", [True, False])
def test_robustness_gate_stops_a_design_whose_b_is_below_the_nugap_naming_the_point(tmp_path, capsys, gate):
    """The tanks design of the test above (its controller's b is below the ν-gap at the empty-tank end)
    with [synth] robustness_gate: on, ``lpvflow design`` exits 1 after the robustness stage with one line
    naming the point where b − ν-gap is smallest (b from the grid formula here) and runs no verification;
    off, the same design passes."""
    u_scale, y_scale = 2.0, 0.05
    path = tmp_path / "design.toml"
    path.write_text(tanks_head(ROOT / "fmu_plants" / "build" / "tanks.fmu", tmp_path / "out")
                    + TANKS.format(u_scale=u_scale, y_scale=y_scale) + tanks_synth('method = "common"')
                    + f"robustness_gate = {str(gate).lower()}\n")
    status = main(["design", str(path)])
    captured = capsys.readouterr()
    out = captured.out + captured.err
    folder = tmp_path / "out" / "tanks"
    summary = json.loads((folder / "summary.json").read_text())
    if not gate:
        assert status == 0 and summary["stages"]["robustness"]["outputs"]["gate"]["passed"] is None
        return
    assert status == 1 and "verify" not in summary["stages"]
    model, controller = load(folder / "model.json"), load(folder / "controller.json")
    validate = summary["stages"]["validate"]["outputs"]
    excess = []
    for theta, gap in zip(validate["theta"], validate["nugap"], strict=True):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SchedulingRangeWarning)
            AG, BG, CG, DG = _matrices(model.frozen(np.array(theta)))
        AK, BK, CK, DK = _matrices(controller.frozen(np.array(theta)))
        G = (AG, BG * u_scale, CG / y_scale, DG * u_scale / y_scale)
        b = grid_margin(G, (AK, -BK * y_scale, CK / u_scale, -DK * y_scale / u_scale))
        excess.append((b - gap, theta, b, gap))
    worst = min(excess, key=lambda row: row[0])
    assert worst[0] < 0  # independently: b is below the ν-gap there
    lines = [line for line in out.splitlines() if "robustness: the controller" in line]
    assert len(lines) == 1
    where = ", ".join(f"{v:.3g}" for v in worst[1])
    assert f"worst θ = {where}: b(Ĝ, K_fb) " in lines[0] and f"ν-gap {worst[3]:.3g})" in lines[0]
    stated_b = float(lines[0].split("b(Ĝ, K_fb) ")[1].split(" ")[0])
    assert stated_b == pytest.approx(worst[2], rel=0.01)
