"""Minimum-time ADIP arm transfers (fmu_plants/adip/min_time.py), on a coarse grid to stay fast.

Each profile is checked against an independent integration: scipy's RK45 on
reference_models.adip_derivatives, interval by interval with the voltage held.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

ROOT = Path(__file__).resolve().parents[1]


def _module(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


mt = _module("min_time", ROOT / "fmu_plants" / "adip" / "min_time.py")
rm = _module("reference_models", ROOT / "fmu_plants" / "reference_models.py")

P = rm.default_parameters("adip")
COARSE = {"interval": 0.05, "max_substep": 0.005, "state_scale": mt.ADIP_STATE_SCALE}
# RK4 with ≈ 4 ms sub-steps against RK45 at rtol 1e-10 over ≈ 0.7 s of an unstable plant: measured
# ≤ 1.4e-6 rad and 5.5e-6 rad/s (75°, 10 V); a wrong profile misses by orders of magnitude more
LANDING_TOLERANCE = np.array([1e-4, 1e-4, 1e-3, 1e-3])  # rad, rad, rad/s, rad/s


def solve(degrees: float, vmax: float, **options) -> mt.Transfer:
    x0, u0 = rm.adip_equilibrium(0.0, P)
    xf, uf = rm.adip_equilibrium(np.deg2rad(degrees), P)
    return mt.minimum_time_transfer(rm.adip_derivatives, x0, xf, u0, uf, vmax, P, **(COARSE | options))


def resimulated_end(result: mt.Transfer) -> np.ndarray:
    x = np.zeros(4)
    for t0, t1, u in zip(result.grid[:-1], result.grid[1:], result.voltage, strict=True):
        x = solve_ivp(
            lambda t, x, u=u: rm.adip_derivatives(x, u, P), (t0, t1), x, method="RK45", rtol=1e-10, atol=1e-12
        ).y[:, -1]
    return x


@pytest.fixture(scope="module")
def transfers() -> dict[tuple[float, float], mt.Transfer]:
    return {(deg, v): solve(deg, v) for deg, v in ((30, 10.0), (75, 10.0), (75, 8.0))}


@pytest.mark.parametrize("key", [(30, 10.0), (75, 10.0), (75, 8.0)])
def test_profile_is_within_the_limit_and_lands_on_the_target_at_rest(transfers, key):
    result = transfers[key]
    degrees, vmax = key
    assert result.success, result.status
    assert np.all(np.abs(result.voltage) <= vmax + 1e-9)
    assert result.max_defect < 1e-8
    assert result.T == pytest.approx(result.grid[-1]) and len(result.grid) == len(result.voltage) + 1
    end = resimulated_end(result)
    target = np.array([np.deg2rad(degrees), 0.0, 0.0, 0.0])
    assert np.all(np.abs(end - target) < LANDING_TOLERANCE), end - target
    # the limit is active: the optimal profile uses the full voltage
    assert np.abs(result.voltage).max() == pytest.approx(vmax)


def test_minimum_time_grows_with_the_angle_and_shrinks_with_the_voltage(transfers):
    assert transfers[(30, 10.0)].T < transfers[(75, 10.0)].T < transfers[(75, 8.0)].T
    assert 0.3 < transfers[(30, 10.0)].T and transfers[(75, 8.0)].T < 1.5


def test_negative_target_is_the_mirror_image(transfers):
    mirrored = solve(-75, 10.0)
    assert mirrored.T == pytest.approx(transfers[(75, 10.0)].T, rel=1e-6)
    np.testing.assert_allclose(mirrored.voltage, -transfers[(75, 10.0)].voltage, atol=1e-4)


def test_a_band_is_reached_sooner_than_rest_and_a_fixed_duration_is_kept(transfers):
    band = np.array([np.deg2rad(1.0), np.deg2rad(1.0), 0.05, 0.05])
    banded = solve(75, 10.0, band=band)
    assert banded.success, banded.status
    assert banded.T < transfers[(75, 10.0)].T
    end = resimulated_end(banded) - np.array([np.deg2rad(75), 0.0, 0.0, 0.0])
    assert np.all(np.abs(end) <= band + LANDING_TOLERANCE)
    fixed = solve(30, 10.0, duration=0.6)
    assert fixed.success and fixed.T == 0.6 and len(fixed.voltage) == 12
    assert np.abs(fixed.voltage).max() < 10.0  # slack in time: the energy optimum stays off the bound


@pytest.mark.parametrize("vmax", [4.0, 3.0])
def test_voltage_below_the_holding_voltage_is_rejected(vmax):
    holding = abs(rm.adip_equilibrium(np.deg2rad(75), P)[1][0])
    with pytest.raises(ValueError, match=rf"holding voltage \|u_eq\| = {holding:.4g} of the target"):
        solve(75, vmax)
