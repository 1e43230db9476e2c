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
    """dx/dt of README "Equations"; x of shape (4,) or (4, K) and u of shape (1,) or (1, K) (one column
    per point, as the minimum-time solver evaluates them), complex-safe for the complex-step Jacobians.
    The 2×2 mass matrix [[a, c cos Δ], [c cos Δ, b]] is inverted by Cramer's rule."""
    phi1, phi2, w1, w2 = x
    a, b, c, d1, d2 = adip_coefficients(p)
    tau = adip_motor_gain(p) * (u[0] - p["gear_ratio"] * p["motor_emf_constant"] * w1)
    joint = p["pendulum_damping"] * (w2 - w1)
    friction = p["effect_coulomb"] * np.tanh(w1 / p["coulomb_velocity"])
    coupling = c * np.sin(phi1 - phi2)
    r1 = tau - p["arm_damping"] * w1 + joint - coupling * w2**2 + d1 * np.sin(phi1) - friction
    r2 = -joint + coupling * w1**2 + d2 * np.sin(phi2)
    m12 = c * np.cos(phi1 - phi2)
    det = a * b - m12**2
    return np.array([w1, w2, (b * r1 - m12 * r2) / det, (a * r2 - m12 * r1) / det])


def adip_outputs(x: np.ndarray, u: np.ndarray, p: dict) -> np.ndarray:
    return np.asarray(x)[:2]


def adip_equilibrium(phi1: float, p: dict) -> tuple[np.ndarray, np.ndarray]:
    """Arm at phi1, pendulum upright, at rest: the motor holds the gravity torque d1 sin(phi1)."""
    d1 = adip_coefficients(p)[3]
    return np.array([phi1, 0.0, 0.0, 0.0]), np.array([-d1 * np.sin(phi1) / adip_motor_gain(p)])


def adip_linearization(phi1: float, p: dict) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of dx/dt = A x + B u at the upright equilibrium with the arm at phi1 (complex step)."""
    return jacobians(adip_derivatives, *adip_equilibrium(phi1, p), p)


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


# ---------------------------------------------------------------- maglev


def maglev_forces(x: np.ndarray, u: np.ndarray, p: dict) -> tuple:
    """(F11, F21, F22, F12, Fm): coil i on disk j as F_ij = i / (a (gap + b)^N), magnet repulsion Fm."""
    y1, y2 = x[0], x[1]
    top = p["coil_separation"] - p["disk_thickness"]
    n = p["force_exponent"]

    def coil(current, gap):
        return current / (p["coil_a"] * (gap + p["coil_b"]) ** n)

    magnet = p["magnet_c"] / (y2 - y1 - p["disk_thickness"] + p["magnet_d"]) ** n
    return coil(u[0], y1), coil(u[1], top - y1), coil(u[1], top - y2), coil(u[0], y2), magnet


def maglev_derivatives(x: np.ndarray, u: np.ndarray, p: dict) -> np.ndarray:
    """Disk accelerations between the stops (the tests evaluate it there)."""
    f11, f21, f22, f12, fm = maglev_forces(x, u, p)
    m, g = p["disk_mass"], p["gravity"]
    fc, vc = p["effect_coulomb"], p["coulomb_velocity"]
    a1 = (f11 - f21 - fm - p["lower_friction"] * x[2] - fc * np.tanh(x[2] / vc)) / m - g
    a2 = (f22 - f12 + fm - p["upper_friction"] * x[3] - fc * np.tanh(x[3] / vc)) / m - g
    return np.array([x[2], x[3], a1, a2])


def maglev_outputs(x: np.ndarray, u: np.ndarray, p: dict) -> np.ndarray:
    return np.asarray(x)[:2]


def maglev_equilibrium_currents(y1: float, y2: float, p: dict) -> np.ndarray:
    """Currents that hold the disks at rest at (y1, y2): the force balance is linear in (i1, i2)."""
    x = np.array([y1, y2, 0.0, 0.0])
    per_amp = np.array([maglev_forces(x, e, p)[:4] for e in np.eye(2)])  # rows: i1 = 1, i2 = 1
    f11, f21, f22, f12 = per_amp.T
    fm = maglev_forces(x, np.zeros(2), p)[4]
    weight = p["disk_mass"] * p["gravity"]
    balance = np.array([[f11[0] - f21[0], f11[1] - f21[1]], [f22[0] - f12[0], f22[1] - f12[1]]])
    return np.linalg.solve(balance, np.array([weight + fm, weight - fm]))


# --------------------------------------------------------------- airpath


def airpath_flow_function(ratio, p: dict):
    """Psi(p_m / p_a): choked below the critical ratio, linearised to 0 above linear_flow_ratio."""
    k, linear = p["heat_capacity_ratio"], p["linear_flow_ratio"]
    critical = (2 / (k + 1)) ** (k / (k - 1))

    def unchoked(r):
        return np.sqrt(2 * k / (k - 1) * (r ** (2 / k) - r ** ((k + 1) / k)))

    if np.real(ratio) <= critical:
        return unchoked(critical) + 0 * ratio
    if np.real(ratio) < linear:
        return unchoked(ratio)
    return unchoked(linear) * (1 - ratio) / (1 - linear)


def airpath_flows(x: np.ndarray, u: np.ndarray, p: dict) -> tuple:
    """(throttle flow, cylinder flow) in kg/s for manifold pressure x[0] and inputs inside their ranges."""
    r, t, pa = p["gas_constant"], p["ambient_temperature"], p["ambient_pressure"]
    alpha = u[0] / 100 * np.pi / 2
    area = p["throttle_leak_area"] + np.pi * p["throttle_diameter"] ** 2 / 4 * (1 - np.cos(alpha))
    throttle = p["discharge_coefficient"] * area * pa / np.sqrt(r * t) * airpath_flow_function(x[0] / pa, p)
    nk = u[2] / 1000
    eta = (p["efficiency_e0"] + p["efficiency_e1"] * nk + p["efficiency_e2"] * nk**2) \
        * (1 - np.exp(-u[1] / 100 / p["lift_constant"]))
    cylinder = eta * x[0] * p["displacement"] * u[2] / (120 * r * t)
    return throttle, cylinder


def airpath_derivatives(x: np.ndarray, u: np.ndarray, p: dict) -> np.ndarray:
    throttle, cylinder = airpath_flows(x, u, p)
    gain = p["gas_constant"] * p["ambient_temperature"] / p["manifold_volume"]
    return np.array([gain * (throttle - cylinder)])


def airpath_outputs(x: np.ndarray, u: np.ndarray, p: dict) -> np.ndarray:
    """Measured outputs in their FMU units: throttle air flow [g/s], manifold pressure [kPa]."""
    return np.array([1000 * airpath_flows(x, u, p)[0], x[0] / 1000])
