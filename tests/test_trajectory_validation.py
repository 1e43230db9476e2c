"""The robustness stage's model-in-the-loop against plant-in-the-loop runs
(lpvflow.pipeline.trajectory_validation) on the fast tanks design: the stage's numbers against the model and
controller simulated here with numpy, a wrong model's difference growing with its error, summary.json and the
report's table."""

from __future__ import annotations

import html
import json
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from lpvflow.basis import SchedulingRangeWarning
from lpvflow.models import LPVSS, load
from lpvflow.pipeline.config import load_config
from lpvflow.pipeline.context import StageContext
from lpvflow.pipeline.design import ROBUSTNESS, run_design
from lpvflow.pipeline.rate_certificate import rate_certificate
from lpvflow.pipeline.robustness import measurement_feedback
from lpvflow.pipeline.settings import StageSettings
from lpvflow.pipeline.trajectory_validation import trajectory_validation
from lpvflow.pipeline.verify import simulate_loop
from tests.design_files import tanks_head, tanks_synth
from tests.test_robustness import TANKS

ROOT = Path(__file__).resolve().parents[1]
PLANT = ROOT / "fmu_plants" / "build" / "tanks.fmu"

#: Both tanks start at 8 cm, the equilibrium of the 6.76 V operating input; the lower level is moved by
#: +4 cm and −3 cm (levels the identification data visited: 5–18 cm).
VERIFY = """
[verify.loop]
measured = ["lower_level"]
actuated = ["pump_voltage"]
u_operating_point = [6.76]
plant_parameters = { x0_upper_level = 0.08, x0_lower_level = 0.08 }

[[verify.scenario]]
name = "level 8 -> 12 cm"
duration = 240.0
reference = { lower_level = { initial = 0.08, steps = [[20.0, 0.04]] } }

[[verify.scenario]]
name = "level 8 -> 5 cm"
duration = 240.0
reference = { lower_level = { initial = 0.08, steps = [[20.0, -0.03]] } }
"""


@pytest.fixture(scope="module")
def design(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, Path, Path]:
    """The tanks design of tests/test_robustness.py (remove_offsets, a 1-DOF "common" controller) with the
    two level moves above: its summary, design folder and design file."""
    root = tmp_path_factory.mktemp("trajectory_design")
    path = root / "design.toml"
    path.write_text(tanks_head(PLANT, root / "out") + TANKS.format(u_scale=2.0, y_scale=0.05)
                    + tanks_synth('method = "common"') + VERIFY)
    summary = run_design(path, log=lambda _: None)
    return summary, root / "out" / "tanks", path


def model_in_the_loop(model: LPVSS, controller, offsets: dict, r: np.ndarray, y_start: float,
                      u_op: float) -> np.ndarray:
    """The lower level of the model in the loop of the 1-DOF controller, written out: the model at rest at
    y_start ([A − I, B; C, 0][x; v] = [0; y_start − y₀] at p = y_start), then per sample p = y,
    u = u_op + C_K(p) x_K + D_K(p)(r − y), x_K⁺ = A_K(p) x_K + B_K(p)(r − y),
    x⁺ = A(p) x + B(p)(u − u₀), y = y₀ + C x (the model identified in deviations from (u₀, y₀))."""
    u0, y0 = offsets["u"][0], offsets["y"][0]
    A, B, C, _ = model.matrices(np.array([y_start]))
    nx = model.nx
    rest = np.linalg.solve(np.block([[A - np.eye(nx), B], [C, np.zeros((1, 1))]]),
                           np.concatenate([np.zeros(nx), [y_start - y0]]))
    x, xk = rest[:nx], np.zeros(controller.order)
    y = np.empty(len(r))
    for k in range(len(r)):
        y[k] = y0 + (C @ x)[0]
        p = np.array([y[k]])
        Ak, Bk, Ck, Dk = controller.matrices(p)
        e = np.array([r[k] - y[k]])
        u = u_op + Ck @ xk + Dk @ e + controller.feedforward(p)
        xk = Ak @ xk + Bk @ e
        A, B, C, _ = model.matrices(p)
        x = A @ x + B @ (u - u0)
    return y


def stage_context(folder: Path, path: Path) -> StageContext:
    """The robustness stage's context over the design folder: the settings it declares."""
    return StageContext(folder, StageSettings(load_config(path), ROBUSTNESS.reads))


def test_the_stage_reports_the_difference_of_the_model_and_the_plant_in_the_loop_computed_here(design):
    """Per scenario, the stage's largest |y_plant − y_model| equals the difference between the plant FMU
    in the loop (the verify stage's co-simulation) and the model in the loop simulated above with numpy,
    to 1e-9 m; the model's error is visible (over 0.2 mm) and small against the moves (3–4 cm)."""
    summary, folder, path = design
    config = load_config(path)
    loop, scenarios = config["verify"]["loop"], config["verify"]["scenario"]
    stage = summary["stages"]["robustness"]["outputs"]
    assert json.loads((folder / "summary.json").read_text())["stages"]["robustness"]["outputs"] == stage
    model, controller = load(folder / "model.json"), load(folder / "controller.json")
    assert controller.structure == "1dof" and controller.antiwindup is None
    offsets = summary["stages"]["identify"]["outputs"]["offsets"]
    assert [row["scenario"] for row in stage["trajectory"]] == [s.name for s in scenarios]
    for row, scenario in zip(stage["trajectory"], scenarios, strict=True):
        on_plant = simulate_loop(controller, PLANT, scenario, loop)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SchedulingRangeWarning)
            y_model = model_in_the_loop(model, controller, offsets, on_plant.reference[:, 0],
                                        on_plant.outputs[0, 0], 6.76)
        expected = np.max(np.abs(on_plant.outputs[:, 0] - y_model))
        assert row["largest_difference"]["lower_level"] == pytest.approx(expected, abs=1e-9)
        assert 2e-4 < expected < 0.01, expected
        step = np.max(np.abs(np.diff(on_plant.outputs[:, 0])))  # the plant run's fastest move per sample
        assert row["largest_step"]["lower_level"] == pytest.approx(step, abs=1e-12) and step > 0
        assert row["plant_failure"] is None and row["model_failure"] is None


def test_a_wrong_model_gain_makes_the_reported_difference_grow(design):
    """The same stage function with the model's input matrix B scaled by 1.15, 1.4 and 0.6 (a wrong gain)
    under the same controller: the largest difference grows with the error on every scenario."""
    _, folder, path = design
    model, controller = load(folder / "model.json"), load(folder / "controller.json")
    ctx = stage_context(folder, path)

    def largest(factor: float) -> list[float]:
        wrong = LPVSS(A=model.A, B=factor * model.B, C=model.C, D=model.D, basis=model.basis, Ts=model.Ts,
                      u_names=model.u_names, y_names=model.y_names, p_names=model.p_names)
        rows = trajectory_validation(ctx, wrong, controller)["trajectory"]
        return [row["largest_difference"]["lower_level"] for row in rows]

    right, slightly, very, low = largest(1.0), largest(1.15), largest(1.4), largest(0.6)
    for i in range(len(right)):
        assert right[i] < slightly[i] < very[i], (right, slightly, very)
        assert low[i] > 2 * right[i], (right, low)


def test_the_report_shows_the_difference_per_scenario_and_the_worst_in_the_card(design):
    """report.html: the robustness section's table has one row per scenario with the stage's value (m, 3
    digits) and how each run ended; the card's robustness line names the largest one and its scenario."""
    summary, folder, _ = design
    rows = summary["stages"]["robustness"]["outputs"]["trajectory"]
    page = html.unescape((folder / "report.html").read_text())
    table = page.split("Model in the loop against plant in the loop")[1].split("</table>")[0]
    found = [re.findall(r"<td>(.*?)</td>", row) for row in re.findall(r"<tr>(.*?)</tr>", table)]
    assert [cells for cells in found if cells] == [
        [row["scenario"], f"{row['largest_difference']['lower_level']:.3g}", "ran to the end",
         "ran to the end"] for row in rows]
    assert "largest lower_level difference [m]" in table
    worst = max(rows, key=lambda row: row["largest_difference"]["lower_level"])
    assert (f"model vs plant in the loop, largest difference: lower_level "
            f"{worst['largest_difference']['lower_level']:.3g} m ({worst['scenario']})") in page


def test_the_rate_certificate_is_a_note_for_a_controller_without_breakpoints(design):
    """The tanks controller is scheduled on a box, not on breakpoints: the stage's rate certificate says
    why it was not assessed instead of running an SDP."""
    summary, folder, path = design
    model, controller = load(folder / "model.json"), load(folder / "controller.json")
    assert controller.polytope.kind != "piecewise"
    rows = summary["stages"]["robustness"]["outputs"]["trajectory"]
    out = rate_certificate(stage_context(folder, path), model, controller, rows,
                           lambda p: measurement_feedback(controller, p))
    assert list(out) == ["rate_certificate_note"] and "needs a controller on breakpoints" in \
        out["rate_certificate_note"]
