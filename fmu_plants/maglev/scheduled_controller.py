"""Design the gain-scheduled identification controller of the maglev: it holds the lower disk at 1.5 cm
while the upper disk follows a set-point across 6.8–9.2 cm.

Why a controller and a trim: the maglev's linearization changes strongly along the operating curve (the
upper disk's DC gain from its coil grows five-fold from 7.5 to 8.6 cm with the lower disk at 1.5 cm), and
the holding currents change with it (the upper coil's from −0.30 A at 7.5 cm to +0.11 A at 8.6 cm). An
LPV model identified from absolute currents has to carry that change of the holding currents in its
coefficients of the absolute disk position, and its frozen models are then secants of the force law
around the data's mean instead of its tangents (DC gain 1.42 against 0.93 of the linearization at 7.5 cm,
2.31 against 4.66 at 8.6 cm: ν-gap 0.27 and 0.21 there). With the holding currents u*(y2) as the trim of
a controller scheduled on the measured upper disk position, ``[identify] remove_trim`` identifies the
plant from u − u*(y2): the force law's change along the curve is then carried by the trim, and the model
is the plant with the trim's feedback closed (``lpvflow.pipeline.frozen_references.trim_closed``).

Design: on a grid of upper disk positions y2 = 6.8…9.2 cm (1 mm steps) take the exact linearization of
the README equations at the equilibrium (y1, y2) = (1.5 cm, y2) (``fmu_plants/reference_models.py``:
``maglev_derivatives``, ``maglev_equilibrium_currents``), close the trim's feedback (∂u*/∂y2) δy2 around
it (the trim is read from the measured y2; it leaves the upper disk without restoring force along the
curve), sample it with a zero-order hold at Ts = 2 ms and design an H∞ loop-shaping controller
(McFarlane & Glover 1990) in the scaling 0.1 A per coil, 2 mm per disk (the design's ``[validate]
scaling``) with the weight W1 of ``lpvflow.synth.loop_shaping.integrator_lead_weight`` (integral action,
lead at the crossover) normalized to cross 1 at 20 rad/s, central controller at 1.01·γ_opt. Its
b(G, K) in that scaling is 0.14–0.19 on the gate points 7.5–8.6 cm (0.01–0.02 at a 5 rad/s crossover).

The controller u = u*(y2) + K(y2)(y − ȳ) (K in positive feedback), ȳ = (1.5 cm, y2) with the upper disk's
set-point in place of its entry, is written as ``lpvflow/gridded-controller`` JSON
(``lpvflow.experiment.controller.GriddedController``), scheduled on the measured upper disk position.

Run: .venv/bin/python fmu_plants/maglev/scheduled_controller.py  (rewrites the JSON next to it)
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import control
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE.parents[1]))
import reference_models as rm  # noqa: E402

from lpvflow.synth.loop_shaping import (  # noqa: E402
    central_ncf_controller,
    crossover_normalized,
    integrator_lead_weight,
)

TS = 0.002
LOWER_DISK = 0.015  # m, held
GRID = np.round(np.arange(0.068, 0.0921, 0.001), 6)  # upper disk positions, m
INPUT_SCALE = np.diag([0.1, 0.1])  # D_u [A]
OUTPUT_SCALE = np.diag([0.002, 0.002])  # D_y [m]
CROSSOVER = 20.0  # rad/s


def trimmed_linearization(y2: float, p: dict) -> tuple[control.StateSpace, np.ndarray]:
    """The plant at (LOWER_DISK, y2) with the trim's feedback closed, sampled at TS, and u*(y2)."""
    u_eq = rm.maglev_equilibrium_currents(LOWER_DISK, y2, p)
    A, B = rm.jacobians(rm.maglev_derivatives, np.array([LOWER_DISK, y2, 0.0, 0.0]), u_eq, p)[:2]
    step = 1e-7
    slope = (rm.maglev_equilibrium_currents(LOWER_DISK, y2 + step, p)
             - rm.maglev_equilibrium_currents(LOWER_DISK, y2 - step, p)) / (2 * step)
    A = A + B @ np.outer(slope, np.eye(4)[1])  # u = δu + u*(y2): ∂u*/∂y2 feeds back the upper disk
    G = control.sample_system(control.ss(A, B, np.eye(2, 4), np.zeros((2, 2))), TS, "zoh")
    return G, u_eq


def point_design(y2: float, p: dict) -> dict:
    """The controller matrices, y_op and u_op at upper disk position ``y2`` (m)."""
    G, u_eq = trimmed_linearization(y2, p)
    scaled = control.ss(G.A, G.B @ INPUT_SCALE, np.linalg.inv(OUTPUT_SCALE) @ G.C, G.D, TS)
    W1 = crossover_normalized(scaled, integrator_lead_weight(TS, CROSSOVER, 2), CROSSOVER)
    K_inf, _ = central_ncf_controller(control.series(W1, scaled))
    K = (control.ss([], [], [], INPUT_SCALE, TS) * W1 * K_inf
         * control.ss([], [], [], np.linalg.inv(OUTPUT_SCALE), TS))
    return {"A": K.A.tolist(), "B": K.B.tolist(), "C": K.C.tolist(), "D": K.D.tolist(),
            "y_operating_point": [LOWER_DISK, float(y2)], "u_operating_point": u_eq.tolist()}


def design(parameters: dict | None = None) -> dict:
    """The controller dictionary in the ``lpvflow/gridded-controller`` format (version 1)."""
    p = parameters or rm.default_parameters("maglev")
    return {
        "format": "lpvflow/gridded-controller",
        "version": 1,
        "Ts": TS,
        "inputs": ["lower_disk_position", "upper_disk_position"],
        "outputs": ["lower_coil_current", "upper_coil_current"],
        "scheduling": "upper_disk_position",
        "grid": GRID.tolist(),
        "points": [point_design(float(y2), p) for y2 in GRID],
        "description": "maglev identification controller: H-infinity loop shaping (crossover 20 rad/s) "
                       "on the exact linearization with the holding-current trim closed, every 1 mm of upper "
                       "disk position with the lower disk at 1.5 cm; trim u*(y2) and gains scheduled on the "
                       "measured upper disk position; fmu_plants/maglev/scheduled_controller.py",
    }


def main() -> None:
    target = HERE / "scheduled_controller.json"
    target.write_text(json.dumps(design()) + "\n")
    print(f"wrote {target}")


if __name__ == "__main__":
    main()
