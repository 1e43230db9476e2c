"""Design the discrete-time LTI controller that stabilizes the ADIP FMU at the upright point.

Design (README "Stabilizing controller"): linearize the README equations at phi1 = phi2 = 0, V = 0
(fmu_plants/reference_models.py), discretize with zero-order hold at Ts = 5 ms, take the LQR
state feedback u = -K x (python-control `dlqr`, weights Q, R below) and a predictor observer
x^(k+1) = Ad x^ + Bd u + L (y - Cd x^) whose gain is the dual LQR (`dlqr(Ad', Cd', W, V)`).
Written as the lpvflow/lti-controller JSON, i.e. xc(k+1) = A xc + B (y - y_op),
u = u_op + C xc + D (y - y_op), with A = Ad - Bd K - L Cd, B = L, C = -K, D = 0.

Run: .venv/bin/python fmu_plants/adip/stabilizing_controller.py  (rewrites the JSON next to it)
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import control
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
import reference_models as rm  # noqa: E402

TS = 0.005
STATE_WEIGHT = np.diag([10.0, 60.0, 0.1, 0.1])  # arm, pendulum [1/rad^2], rates [s^2/rad^2]
INPUT_WEIGHT = np.array([[10.0]])  # [1/V^2]
PROCESS_NOISE = np.diag([1e-6, 1e-6, 1e-2, 1e-2])  # observer design weights
SENSOR_NOISE = np.diag([1e-6, 1e-6])


def design(parameters: dict | None = None, design_angle: float = 0.0) -> dict:
    """The controller dictionary in the lpvflow/lti-controller format (version 1).

    ``design_angle`` (rad): take the gains from the linearization at the upright equilibrium with that
    arm angle instead of 0 (the operating point stays φ1 = φ2 = 0, V = 0), e.g. for identification
    controllers that hold a wider arm range.
    """
    p = parameters or rm.default_parameters("adip")
    x_op, u_op = rm.adip_equilibrium(0.0, p)
    a, b = rm.adip_linearization(design_angle, p)
    c = np.eye(2, 4)
    plant = control.c2d(control.ss(a, b, c, np.zeros((2, 1))), TS, method="zoh")
    k, _, _ = control.dlqr(plant.A, plant.B, STATE_WEIGHT, INPUT_WEIGHT)
    l_t, _, _ = control.dlqr(plant.A.T, plant.C.T, PROCESS_NOISE, SENSOR_NOISE)
    observer = l_t.T
    return {
        "format": "lpvflow/lti-controller",
        "version": 1,
        "Ts": TS,
        "A": (plant.A - plant.B @ k - observer @ plant.C).tolist(),
        "B": observer.tolist(),
        "C": (-k).tolist(),
        "D": np.zeros((1, 2)).tolist(),
        "inputs": ["arm_angle", "pendulum_angle"],
        "outputs": ["voltage"],
        "y_operating_point": list(rm.adip_outputs(x_op, u_op, p)),
        "u_operating_point": list(u_op),
    }


def main() -> None:
    controller = design()
    target = HERE / "stabilizing_controller.json"
    target.write_text(json.dumps(controller, indent=1) + "\n")
    print(f"wrote {target}")


if __name__ == "__main__":
    main()
