"""``[synth] trim``: checked by the design-file schema (one line naming the key), attached by the synth stage
to the LPV controller and to the LTI baseline, and written into both controller files."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from lpvflow.basis import Basis
from lpvflow.errors import DataError
from lpvflow.models import LPVSS, load
from lpvflow.pipeline import stages
from lpvflow.pipeline.config import load_tables
from lpvflow.synth.controller import LPVController
from lpvflow.synth.design import trim as design_trim
from lpvflow.synth.polytope import BoxPolytope

SYNTH = '[synth]\nweights.S = { bandwidth = 1.0 }\nweights.K = { num = [1], den = [1] }\n'


def _synth_table(tmp_path: Path, trim: str) -> dict:
    path = tmp_path / "design.toml"
    path.write_text(SYNTH + f"trim = {trim}\n")
    return load_tables(path, need=("synth",))["synth"]


def test_a_trim_table_is_read_as_breakpoints_and_rows(tmp_path: Path) -> None:
    table = _synth_table(tmp_path, "{ p = [-1.0, 0, 1], u = [[4.21, 0], [0, 1], [-4.21, 2]] }")
    assert table["trim"] == {"p": [-1.0, 0.0, 1.0], "u": [[4.21, 0.0], [0.0, 1.0], [-4.21, 2.0]]}
    assert load_tables(_write(tmp_path, SYNTH), need=("synth",))["synth"]["trim"] is None  # optional


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "plain.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize(("trim", "message"), [
    ("{ p = [0.0, 1.0, 0.5], u = [[1], [2], [3]] }",
     "[synth] trim.p = [0.0, 1.0, 0.5] must be strictly ascending breakpoints of the first scheduling "
     "signal"),
    ("{ p = [0.0, 0.0], u = [[1], [2]] }", "[synth] trim.p = [0.0, 0.0] must be strictly ascending"),
    ("{ p = [0.0, 1.0], u = [[1]] }", "[synth] trim.u = [[1]] must be 2 rows (one per breakpoint of "
                                      "[synth] trim.p)"),
    ("{ p = [0.0, 1.0], u = [[1, 2], [3]] }", "[synth] trim.u = [[1, 2], [3]] must be 2 rows"),
    ("{ p = [0.0, 1.0], u = [1, 2] }", "[synth] trim.u = [1, 2] must be 2 rows"),
    ("{ p = [0.0, 1.0], u = [['a'], [2]] }", "[synth] trim.u = 'a' must be a number"),
    ("{ p = [], u = [] }", "[synth] trim.p = [] must be a list of breakpoints"),
    ("{ p = [0.0] }", "[synth] trim = {'p': [0.0]} must be a table { p = [p_1, …], u = [[u_1 …], …] }"),
    ("[1.0, 2.0]", "[synth] trim = [1.0, 2.0] must be a table"),
])
def test_a_bad_trim_table_is_one_line_naming_the_key(tmp_path: Path, trim: str, message: str) -> None:
    with pytest.raises(DataError) as info:
        _synth_table(tmp_path, trim)
    assert message in str(info.value) and "\n" not in str(info.value)
    assert str(info.value).startswith("design.toml: ")


def _controller(nu: int) -> LPVController:
    poly = BoxPolytope(np.array([[-1.0, 1.0]]), np.array([[1.0, -1.0], [1.0, 1.0]]))
    return LPVController(np.zeros((2, 1, 1)), np.zeros((2, 1, 2)), np.zeros((2, nu, 1)), np.zeros((2, nu, 2)),
                         poly, Basis("affine", 1, p_min=(-1.0,), p_max=(1.0,)), 0.01)


def test_the_trim_helper_builds_the_trim_and_checks_its_width() -> None:
    settings = {"trim": {"p": [-1.0, 1.0], "u": [[4.0], [-4.0]]}}
    trim = design_trim(settings, _controller(1))
    assert trim.value(np.array([0.5]))[0] == pytest.approx(-2.0)
    with pytest.raises(DataError, match=r"^\[synth\] trim.u rows have 1 value\(s\); the controller drives"):
        design_trim(settings, _controller(2))
    assert design_trim({"trim": None}, _controller(1)) is None


def test_the_synth_stage_gives_the_lpv_controller_and_the_baseline_the_trim(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import lpvflow.synth.design

    def fake_synthesize(plant: object, solver: str) -> SimpleNamespace:  # a controller, no SDP
        return SimpleNamespace(gamma=1.0, controller=_controller(1),
                               report=SimpleNamespace(seconds=0.0), plant=plant)

    monkeypatch.setattr(lpvflow.synth.design, "synthesize", fake_synthesize)
    monkeypatch.setattr(lpvflow.synth.design, "certify",
                        lambda *args: SimpleNamespace(lines=lambda: [], ok=True))
    basis = Basis("affine", 1, p_min=(-1.0,), p_max=(1.0,))
    C = np.array([[[1.0], [1.0]], [[0.0], [0.0]]])
    LPVSS(np.array([[[0.5]], [[0.1]]]), np.array([[[1.0]], [[0.0]]]), C, np.zeros((2, 2, 1)), basis,
          0.01).save(tmp_path / "model.json")
    trim = {"p": [-1.0, 0.0, 1.0], "u": [[4.21], [0.0], [-4.21]]}
    config = {"synth": {"weights": {"S": {"num": [0.5], "den": [1]}, "K": {"num": [0.1], "den": [1]}},
                        "box": None, "method": "common", "solver": "CLARABEL", "baseline_at": None,
                        "trim": trim, "structure": "1dof", "breakpoints": None, "vertex_weights": None,
                        "rate_bound": None},
              "design": {"plant": None}, "experiment": {"scheduling": {}}, "verify": None}
    stages.synth(stages.StageContext(tmp_path, config))
    for name in ("controller.json", "baseline.json"):
        controller = load(tmp_path / name)
        np.testing.assert_array_equal(controller.trim.p, trim["p"])
        np.testing.assert_array_equal(controller.trim.u, trim["u"])
