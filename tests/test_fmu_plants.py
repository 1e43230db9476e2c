"""FMU plant models (fmu_plants/): FMI validity, physics against the README equations, effects.

The reference equations are fmu_plants/reference_models.py, written from the READMEs
independently of the C code; the FMUs expose their states (x0_* parameters, diag_state_*
and diag_der_* outputs) so their right-hand side can be differentiated from outside.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from fmpy import simulate_fmu
from fmpy.validation import validate_fmu

from lpvflow.fmu import open_fmu

ROOT = Path(__file__).resolve().parents[1]
PLANTS = sorted(p.parent.name for p in (ROOT / "fmu_plants").glob("*/modelDescription.xml"))
_spec = importlib.util.spec_from_file_location("reference_models",
                                               ROOT / "fmu_plants" / "reference_models.py")
rm = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(rm)

STATES = {
    "adip": ["arm_angle", "pendulum_angle", "arm_rate", "pendulum_rate"],
    "airpath": ["manifold_pressure"],
    "maglev": ["lower_disk_position", "upper_disk_position", "lower_disk_velocity", "upper_disk_velocity"],
    "tanks": ["upper_level", "lower_level"],
}
MODELS = {name: (getattr(rm, f"{name}_derivatives"), getattr(rm, f"{name}_outputs")) for name in STATES}


OPERATING_POINTS = {  # two per plant, off equilibrium so that every Jacobian entry is exercised
    "adip": [(np.array([0.1, -0.05, 0.3, -0.2]), np.array([1.0])),
             (np.array([1.1, 0.2, -1.0, 0.5]), np.array([-4.0]))],
    "airpath": [(np.array([50e3]), np.array([20.0, 80.0, 2000.0])),  # choked throttle
                (np.array([80e3]), np.array([35.0, 60.0, 3500.0]))],  # unchoked throttle
    "maglev": [(np.array([0.015, 0.08, 0.01, -0.02]), np.array([0.9, 0.05])),
               (np.array([0.02, 0.07, -0.03, 0.01]), np.array([1.2, -0.5]))],
    "tanks": [(np.array([0.12, 0.08]), np.array([7.0])), (np.array([0.25, 0.02]), np.array([3.0]))],
}


@pytest.fixture(scope="module")
def fmus() -> dict[str, Path]:
    subprocess.run([sys.executable, str(ROOT / "fmu_plants" / "build.py")], check=True, capture_output=True)
    return {name: ROOT / "fmu_plants" / "build" / f"{name}.fmu" for name in PLANTS}


def _derivative_at(plant, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(dx/dt, measured y) of the FMU at state x and input u, read right after initialisation."""
    states = STATES[plant.name]
    plant.set_parameters({f"x0_{s}": float(v) for s, v in zip(states, x, strict=True)})
    y = plant.reset(inputs=u)
    return plant.get([f"diag_der_{s}" for s in states]), y


def _fd_jacobians(plant, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, ...]:
    """Central differences through the FMU: df/dx, df/du, dy/dx."""
    jac_x, jac_u, jac_y = [], [], []
    for j in range(len(x)):
        h = 1e-6 * max(abs(x[j]), 1e-2)
        e = np.eye(len(x))[j] * h
        (fp, yp), (fm, ym) = _derivative_at(plant, x + e, u), _derivative_at(plant, x - e, u)
        jac_x.append((fp - fm) / (2 * h))
        jac_y.append((yp - ym) / (2 * h))
    for j in range(len(u)):
        h = 1e-6 * max(abs(u[j]), 1.0)
        e = np.eye(len(u))[j] * h
        jac_u.append((_derivative_at(plant, x, u + e)[0] - _derivative_at(plant, x, u - e)[0]) / (2 * h))
    return np.array(jac_x).T, np.array(jac_u).T, np.array(jac_y).T


def _relative_error(estimate: np.ndarray, exact: np.ndarray) -> float:
    return float(np.max(np.abs(estimate - exact)) / np.max(np.abs(exact)))


@pytest.mark.parametrize("name", PLANTS)
def test_fmu_validates_and_simulates_with_defaults(fmus, name):
    assert validate_fmu(str(fmus[name])) == []
    result = simulate_fmu(str(fmus[name]))
    assert len(result) > 10
    assert all(np.all(np.isfinite(result[field])) for field in result.dtype.names)


@pytest.mark.parametrize("name", PLANTS)
def test_fmu_contains_binary_and_rebuildable_sources(fmus, name):
    import zipfile

    files = set(zipfile.ZipFile(fmus[name]).namelist())
    assert {f"binaries/linux64/{name}.so", f"sources/{name}.c", "sources/plant_fmu.c",
            "sources/plant_fmu.h", "sources/model_variables.h", "sources/fmi2Functions.h"} <= files


def test_build_is_idempotent_and_skips_up_to_date_plants(fmus):
    before = {name: path.stat().st_mtime_ns for name, path in fmus.items()}
    out = subprocess.run([sys.executable, str(ROOT / "fmu_plants" / "build.py")], check=True,
                         capture_output=True, text=True).stdout
    assert out.count("up to date") == len(PLANTS)
    assert before == {name: path.stat().st_mtime_ns for name, path in fmus.items()}


@pytest.mark.parametrize("name", PLANTS)
def test_fd_linearization_through_fmu_matches_reference_jacobian(fmus, name):
    f, g = MODELS[name]
    with open_fmu(fmus[name]) as plant:
        p = rm.default_parameters(name)
        for x, u in OPERATING_POINTS[name]:
            jac_x, jac_u, jac_y = _fd_jacobians(plant, x, u)
            exact_x, exact_u = rm.jacobians(f, x, u, p)
            exact_y, _ = rm.jacobians(g, x, u, p)
            assert _relative_error(jac_x, exact_x) < 1e-5
            assert _relative_error(jac_u, exact_u) < 1e-5
            assert _relative_error(jac_y, exact_y) < 1e-5


def test_tanks_settle_at_torricelli_equilibrium(fmus):
    p = rm.default_parameters("tanks")
    level = rm.tanks_equilibrium(8.0, p)
    with open_fmu(fmus["tanks"]) as plant:
        derivative, _ = _derivative_at(plant, level, np.array([8.0]))
        assert np.max(np.abs(derivative)) < 1e-12
        plant.set_parameters({"x0_upper_level": 0.0, "x0_lower_level": 0.0})
        for _ in range(4000):
            y = plant.step([8.0], 0.5)
        np.testing.assert_allclose(y, level[1], rtol=1e-6)


def test_tanks_overflow_holds_levels_at_tank_height(fmus):
    with open_fmu(fmus["tanks"]) as plant:
        for _ in range(3000):
            y = plant.step([20.0], 0.5)
        levels = plant.get(["diag_state_upper_level", "diag_state_lower_level"])
        assert levels[0] == rm.default_parameters("tanks")["tank_height"]
        assert y[0] < levels[0]


@pytest.mark.parametrize("phi1_deg", [0.0, 40.0, -75.0])
def test_adip_upright_equilibrium_holds_for_any_arm_angle(fmus, phi1_deg):
    p = rm.default_parameters("adip")
    x, u = rm.adip_equilibrium(np.deg2rad(phi1_deg), p)
    with open_fmu(fmus["adip"]) as plant:
        derivative, y = _derivative_at(plant, x, u)
        assert np.max(np.abs(derivative)) < 1e-12
        np.testing.assert_array_equal(y, x[:2])


def test_adip_upright_has_the_unstable_real_poles_the_model_implies(fmus):
    p = rm.default_parameters("adip")
    with open_fmu(fmus["adip"]) as plant:
        for phi1 in (0.0, np.deg2rad(60)):
            x, u = rm.adip_equilibrium(phi1, p)
            jac_x, _, _ = _fd_jacobians(plant, x, u)
            poles = np.linalg.eigvals(jac_x)
            exact = np.linalg.eigvals(rm.jacobians(rm.adip_derivatives, x, u, p)[0])
            np.testing.assert_allclose(np.sort(poles.real), np.sort(exact.real), rtol=1e-5)
            unstable = poles[poles.real > 0]
            # both links are inverted: the arm and the pendulum each contribute one real unstable pole
            assert len(unstable) == 2
            assert np.all(np.abs(unstable.imag) < 1e-9)


def test_adip_energy_is_conserved_without_friction(fmus):
    frictionless = {"arm_damping": 0.0, "pendulum_damping": 0.0, "motor_emf_constant": 0.0,
                    "x0_arm_angle": 0.3, "x0_pendulum_angle": -0.2}
    with open_fmu(fmus["adip"], outputs=["diag_energy"]) as plant:
        plant.set_parameters(frictionless)
        energy = [plant.reset()[0]] + [plant.step([0.0], 0.005)[0] for _ in range(2000)]
        states = plant.get([f"diag_state_{s}" for s in STATES["adip"]])
    energy = np.array(energy)
    assert np.ptp(energy) / energy[0] < 1e-6
    expected = rm.adip_energy(np.array([0.3, -0.2, 0.0, 0.0]), rm.default_parameters("adip"))
    assert abs(energy[0] - expected) < 1e-12
    assert np.max(np.abs(states[2:])) > 5.0  # the links really swung (large motion, not a trivial rest)


def test_maglev_rests_on_the_lower_stop_with_the_upper_disk_floating(fmus):
    p = rm.default_parameters("maglev")
    with open_fmu(fmus["maglev"]) as plant:
        y0 = plant.reset()
        for _ in range(500):
            y = plant.step([0.0, 0.0], 0.002)
    np.testing.assert_array_equal(y0, [0.0, p["x0_upper_disk_position"]])
    assert y[0] == 0.0
    # the magnet repulsion alone carries the upper disk: c / (y2 - w + d)^N = m g
    gap = (p["magnet_c"] / (p["disk_mass"] * p["gravity"])) ** (1 / p["force_exponent"])
    np.testing.assert_allclose(y[1], p["disk_thickness"] - p["magnet_d"] + gap, rtol=1e-9)


@pytest.mark.parametrize("upper", [0.07, 0.08, 0.09])
def test_maglev_levitates_where_the_force_balance_puts_it(fmus, upper):
    p = rm.default_parameters("maglev")
    currents = rm.maglev_equilibrium_currents(0.015, upper, p)
    with open_fmu(fmus["maglev"]) as plant:
        derivative, _ = _derivative_at(plant, np.array([0.015, upper, 0.0, 0.0]), currents)
        assert np.max(np.abs(derivative)) < 1e-9
        plant.set_parameters({"x0_lower_disk_position": 0.016, "x0_upper_disk_position": upper - 0.001})
        for _ in range(5000):  # 10 s from 1 mm off: lightly damped (decay rate c/2m = 0.83/s), locally stable
            y = plant.step(currents, 0.002)
    np.testing.assert_allclose(y, [0.015, upper], atol=1e-6)


def test_airpath_settles_where_throttle_and_cylinder_flows_balance(fmus):
    from scipy.optimize import brentq

    p = rm.default_parameters("airpath")
    u = np.array([30.0, 70.0, 3000.0])
    pressure = brentq(lambda q: rm.airpath_derivatives(np.array([q]), u, p)[0], 1e3,
                      p["ambient_pressure"] - 1)
    with open_fmu(fmus["airpath"]) as plant:
        for _ in range(300):
            y = plant.step(u, 0.01)
        cylinder = plant.get(["diag_cylinder_air_flow"])[0]
    np.testing.assert_allclose(y, rm.airpath_outputs(np.array([pressure]), u, p), rtol=1e-7)
    np.testing.assert_allclose(cylinder, y[0], rtol=1e-7)  # at rest the cylinders take the throttle flow
