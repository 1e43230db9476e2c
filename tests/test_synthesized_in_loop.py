"""The synthesized LPV controller as a gridded law (:meth:`SynthesizedController.as_gridded`) gives the
compiled in-loop simulation (:mod:`lpvflow.validate.loop_recursion`) the controller's own commands: on
random piecewise-polytope controllers (1-DOF and 2-DOF, with a trim table reaching past the breakpoints and
operating points), run on random records whose scheduling leaves the breakpoints at both ends, the
compiled commands equal :meth:`SynthesizedController.command` (the Python law) to rounding."""

from __future__ import annotations

import numpy as np
import pytest

from lpvflow.basis import Basis
from lpvflow.errors import DataError
from lpvflow.experiment.synthesized import SynthesizedController
from lpvflow.pipeline.ports import ControllerSignals, Port
from lpvflow.synth.controller import LPVController, Trim
from lpvflow.synth.polytope import BoxPolytope, PiecewisePolytope
from lpvflow.validate.closed_loop import controller_arrays
from lpvflow.validate.loop_recursion import controller_commands

MEASURED = ("arm", "tip")
SCHEDULING = "sin(arm)"


def random_controller(rng: np.random.Generator, structure: str) -> SynthesizedController:
    """A random stable-ish LPV controller on 5 breakpoints of sin(arm) in [−0.8, 0.8], its trim table on
    other breakpoints reaching ±1, random operating points."""
    n, N = 3, 5
    breakpoints = np.sort(rng.uniform(-0.8, 0.8, N))
    nw = 4 if structure == "2dof" else 2
    polytope = PiecewisePolytope(breakpoints[[0, -1]][None], np.column_stack([np.ones(N), breakpoints]),
                                 breakpoints=breakpoints)
    y_op, u_op = rng.uniform(-0.5, 0.5, 2), rng.uniform(-1.0, 1.0, 1)
    signals = ControllerSignals(
        tuple(Port(name, "rad", operating_point=v) for name, v in zip(MEASURED, y_op, strict=True)),
        (Port("p1", "1", expression=SCHEDULING),),
        (Port("voltage", "V", operating_point=float(u_op[0])),)).to_dict()
    law = LPVController(0.6 * rng.standard_normal((N, n, n)) / np.sqrt(n), rng.standard_normal((N, n, nw)),
                        rng.standard_normal((N, 1, n)), rng.standard_normal((N, 1, nw)), polytope,
                        Basis("affine", 1), 0.005, info={"signals": signals}, structure=structure,
                        trim=Trim([-1.0, 0.1, 1.0], rng.standard_normal((3, 1))))
    return SynthesizedController.from_controller(law)


@pytest.mark.parametrize("structure", ["1dof", "2dof"])
def test_compiled_commands_equal_the_python_law(structure: str) -> None:
    rng = np.random.default_rng(360 + len(structure))
    for _ in range(3):
        K = random_controller(rng, structure)
        n = 400
        y = np.column_stack([1.6 * np.sin(np.linspace(0, 6, n)) + 0.05 * rng.standard_normal(n),
                             0.1 * rng.standard_normal(n)])  # sin(arm) beyond both end breakpoints
        references = np.column_stack([rng.uniform(-1, 1, n), np.full(n, np.nan)])
        references[: n // 4, 0] = np.nan  # no reference given: r = y_op
        K.reset()
        expected = np.array([K.command(np.where(np.isnan(r), K.y_op, r), yk, np.array([np.sin(yk[0])]))
                             for r, yk in zip(references, y, strict=True)])
        G = K.as_gridded()
        read = np.ascontiguousarray(np.tile(y, 2) if structure == "2dof" else y)
        compiled = controller_commands(controller_arrays(G), read,
                                       np.ascontiguousarray(K.gridded_setpoints(references)), False)
        scale = np.max(np.abs(expected))
        np.testing.assert_allclose(compiled, expected, rtol=0, atol=1e-9 * scale)


def test_a_polytope_without_breakpoints_is_one_error() -> None:
    """Vertices of a box in two scheduling signals: λ is not the hat functions of one signal."""
    rng = np.random.default_rng(3)
    K = random_controller(rng, "1dof")
    corners = np.array([[1.0, a, b] for a in (-1.0, 1.0) for b in (-1.0, 1.0)])
    box = BoxPolytope(np.array([[-1.0, 1.0], [-1.0, 1.0]]), corners)
    law = LPVController(K.law.Ak[:4], K.law.Bk[:4], K.law.Ck[:4], K.law.Dk[:4], box, Basis("affine", 2),
                        0.005, info=K.law.info)
    with pytest.raises(DataError, match="piecewise polytope"):
        SynthesizedController(law, K.inputs, K.outputs, K.scheduling, K.y_op, K.u_op).as_gridded()
