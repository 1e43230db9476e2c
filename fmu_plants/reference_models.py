"""The plant equations of fmu_plants/*/README.md, written in Python independently of the C code.

Used to check the FMUs (tests/test_fmu_physics.py) and to design the stabilizing controller
(adip/stabilizing_controller.py). Each `<plant>_derivatives(x, u, p)` returns dx/dt for state x,
inputs u (after the effects) and a parameter dict p (names as in modelDescription.xml);
`<plant>_outputs(x, u, p)` returns the noise-free measured outputs. `jacobians` differentiates
them by the complex step, Im f(x + i h e_j) / h with h = 1e-30, which is exact to rounding
(no truncation error), so it stands for the analytic Jacobian.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Callable
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
Model = Callable[[np.ndarray, np.ndarray, dict], np.ndarray]


def default_parameters(plant: str) -> dict[str, float]:
    """Start values of every Real parameter in fmu_plants/<plant>/modelDescription.xml."""
    root = ET.parse(HERE / plant / "modelDescription.xml").getroot()
    values = {}
    for var in root.iter("ScalarVariable"):
        real = var.find("Real")
        if var.get("causality") == "parameter" and real is not None:
            values[var.get("name")] = float(real.get("start"))
    return values


def jacobians(f: Model, x: np.ndarray, u: np.ndarray, p: dict, step: float = 1e-30) -> tuple:
    """(df/dx, df/du) of f(x, u, p) by the complex step."""
    x = np.asarray(x, dtype=complex)
    u = np.asarray(u, dtype=complex)
    columns_x = [np.imag(f(x + 1j * step * e, u, p)) / step for e in np.eye(len(x))]
    columns_u = [np.imag(f(x, u + 1j * step * e, p)) / step for e in np.eye(len(u))]
    return np.array(columns_x).T, np.array(columns_u).T


# ------------------------------------------------------------------ ADIP


def adip_coefficients(p: dict) -> tuple[float, float, float, float, float]:
    """a, b, c, d1, d2 of the ADIP mass matrix and gravity terms (README, "Equations")."""
    a = p["arm_inertia"] + p["arm_mass"] * p["arm_com"] ** 2 + p["pendulum_mass"] * p["arm_length"] ** 2 \
        + p["motor_inertia"]
    b = p["pendulum_inertia"] + p["pendulum_mass"] * p["pendulum_com"] ** 2
    c = p["pendulum_mass"] * p["arm_length"] * p["pendulum_com"]
    d1 = (p["arm_mass"] * p["arm_com"] + p["pendulum_mass"] * p["arm_length"]) * p["gravity"]
    d2 = p["pendulum_mass"] * p["pendulum_com"] * p["gravity"]
    return a, b, c, d1, d2


def adip_motor_gain(p: dict) -> float:
    """Torque per volt at standstill, eta_g Kg eta_m kt / Rm."""
    return p["gear_efficiency"] * p["gear_ratio"] * p["motor_efficiency"] * p["motor_torque_constant"] \
        / p["motor_resistance"]


def adip_derivatives(x: np.ndarray, u: np.ndarray, p: dict) -> np.ndarray:
    phi1, phi2, w1, w2 = x
    a, b, c, d1, d2 = adip_coefficients(p)
    tau = adip_motor_gain(p) * (u[0] - p["gear_ratio"] * p["motor_emf_constant"] * w1)
    joint = p["pendulum_damping"] * (w2 - w1)
    friction = p["effect_coulomb"] * np.tanh(w1 / p["coulomb_velocity"])
    rhs = np.array([tau - p["arm_damping"] * w1 + joint - c * np.sin(phi1 - phi2) * w2**2
                    + d1 * np.sin(phi1) - friction,
                    -joint + c * np.sin(phi1 - phi2) * w1**2 + d2 * np.sin(phi2)])
    mass = np.array([[a, c * np.cos(phi1 - phi2)], [c * np.cos(phi1 - phi2), b]])
    return np.concatenate([[w1, w2], np.linalg.solve(mass, rhs)])


def adip_outputs(x: np.ndarray, u: np.ndarray, p: dict) -> np.ndarray:
    return np.asarray(x)[:2]


def adip_equilibrium(phi1: float, p: dict) -> tuple[np.ndarray, np.ndarray]:
    """Arm at phi1, pendulum upright, at rest: the motor holds the gravity torque d1 sin(phi1)."""
    d1 = adip_coefficients(p)[3]
    return np.array([phi1, 0.0, 0.0, 0.0]), np.array([-d1 * np.sin(phi1) / adip_motor_gain(p)])


def adip_energy(x: np.ndarray, p: dict) -> float:
    phi1, phi2, w1, w2 = x
    a, b, c, d1, d2 = adip_coefficients(p)
    return 0.5 * a * w1**2 + 0.5 * b * w2**2 + c * np.cos(phi1 - phi2) * w1 * w2 \
        + d1 * (1 + np.cos(phi1)) + d2 * (1 + np.cos(phi2))


# ----------------------------------------------------------------- tanks


def tanks_derivatives(x: np.ndarray, u: np.ndarray, p: dict) -> np.ndarray:
    """Torricelli outflow; valid inside the tank (0 < h < H), where the tests evaluate it."""
    h1, h2 = x
    inflow = p["pump_gain"] * u[0]
    q1 = p["upper_outlet_area"] * np.sqrt(2 * p["gravity"] * h1)
    q2 = p["lower_outlet_area"] * np.sqrt(2 * p["gravity"] * h2)
    return np.array([inflow - q1, q1 - q2]) / p["tank_area"]


def tanks_outputs(x: np.ndarray, u: np.ndarray, p: dict) -> np.ndarray:
    return np.asarray(x)[1:]


def tanks_equilibrium(voltage: float, p: dict) -> np.ndarray:
    """h1 = (kp u / (a1 sqrt(2g)))^2 and h2 = (a1 / a2)^2 h1."""
    h1 = (p["pump_gain"] * voltage / p["upper_outlet_area"]) ** 2 / (2 * p["gravity"])
    return np.array([h1, h1 * (p["upper_outlet_area"] / p["lower_outlet_area"]) ** 2])
