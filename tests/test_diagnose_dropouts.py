"""Actuator dropouts in closed loop (lpvflow/validate/diagnose_dropouts.py): the commanded input held at
its last value in short windows, found in the model's one-step errors; a synthetic plant under a static
output feedback with random plant parameters and its clean twin, and the bench's plant records."""

from __future__ import annotations

import numpy as np
import pytest

from lpvflow.data import Dataset
from lpvflow.experiment.controller import LtiController
from lpvflow.identify.arx import identify_arx
from lpvflow.validate.diagnose import diagnose
from lpvflow.validate.diagnose_dropouts import MIN_HOLD, held_windows
from tests.diagnosis_fmu_cases import make_record, outcome

N = 4000


def _controller(gain: float) -> LtiController:
    """u = −gain·y + r (static output feedback; the loop adds the excitation r)."""
    return LtiController(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.array([[-gain]]), 1.0,
                         ("y",), ("u",), np.zeros(1), np.zeros(1))


def _plant(seed: int) -> tuple[float, float, float]:
    """A random first-order plant y(k) = a·y(k−1) + b·u(k−1) (unstable, a in 1.02–1.1, on odd seeds) and
    a static gain that places the loop's pole a − b·gain in 0.5–0.8."""
    rng = np.random.default_rng(100 + seed)
    a = rng.uniform(1.02, 1.1) if seed % 2 else rng.uniform(0.7, 0.95)
    b = rng.uniform(0.3, 1.0)
    return a, b, (a - rng.uniform(0.5, 0.8)) / b


def _record(seed: int, noise: float, hold: int = 0) -> Dataset:
    """The loop of :func:`_plant` with the excitation r random levels held 1–10 samples and white sensor
    noise of ``noise``; with ``hold`` > 0 the actuator keeps its last value during random windows of
    ``hold`` samples (one window in ten) while the recorded command moves on."""
    a, b, gain = _plant(seed)
    rng = np.random.default_rng(seed)
    r = np.repeat(rng.normal(size=N), rng.integers(1, 11, size=N))[:N]
    windows = np.arange(N) // max(hold, 1)
    stuck = (rng.random(windows[-1] + 1) < 0.1)[windows] if hold else np.zeros(N, bool)
    y, y_meas, u, applied = np.zeros(N), np.zeros(N), np.zeros(N), np.zeros(N)
    for k in range(N):
        if k:
            y[k] = a * y[k - 1] + b * applied[k - 1]
        y_meas[k] = y[k] + noise * rng.normal()
        u[k] = -gain * y_meas[k] + r[k]
        applied[k] = applied[k - 1] if stuck[k] and k else u[k]
    p = np.repeat(rng.uniform(size=N), 50)[:N]  # a recorded scheduling signal the plant does not depend on
    return Dataset(u, y_meas, p, 1.0, ["u"], ["y"], ["p"])


def _held(data: Dataset) -> dict:
    """The test with the plant's own structure fitted by least squares on the record."""
    return held_windows(identify_arx(data, 1, 1, 1, "affine"), data, 1e-3)


@pytest.mark.parametrize("seed", range(3))
def test_dropouts_in_the_loop_are_found_and_the_clean_twin_is_not(seed):
    """Dropouts of 5 samples (one window in ten) under 2 % sensor noise: significant, many windows; the
    same loop without them, noise-free and with the noise: no window beyond the bound."""
    test = _held(_record(seed, 0.02, hold=5))
    assert test["significant"] and test["windows"] >= 5 * test["min_windows"], test
    for noise in (0.0, 0.02):
        clean = _held(_record(seed, noise))
        assert clean["windows"] == 0 and not clean["significant"], (noise, clean)


@pytest.mark.parametrize(("plant", "seed", "before"), [("adip", 0, "none"), ("adip", 1, "none")])
def test_actuator_dropouts_in_a_plant_loop_are_unexplained(plant, seed, before):
    """The bench's ADIP records with actuator dropouts (4 samples, tests/diagnosis_fmu_cases.py), named
    ``before`` without the test: ``unexplained`` with the held-input test and its numbers in the
    parameters and the summary."""
    record = make_record(plant, "actuator dropouts", seed)
    result = diagnose(record.data, record.structure, record.channels, **record.diagnose_arguments())
    assert result.cause == "unexplained", (result.cause, result.adequacy)
    test = result.parameters["held_input"]
    assert test["cause"] == before and test["input"] == "voltage"
    assert test["windows"] >= 10 * test["min_windows"] and test["largest_ratio"] > test["bound"]
    assert "held at its last value" in result.summary


@pytest.mark.parametrize("seed", [2, 9])
def test_clean_adip_records_with_a_window_beyond_the_bound_stay_clean(seed):
    """The clean ADIP records closest to the bound (seed 2: one window of 4 samples at Λ = 62, seed 9:
    Λ = 23, bound 35.5): no held input, the verdict stays a noise verdict."""
    record = make_record("adip", "clean", seed)
    result = diagnose(record.data, record.structure, record.channels, **record.diagnose_arguments())
    assert outcome(record, result.cause, result.parameters) == "right", (result.cause, result.adequacy)
    assert "held_input" not in (result.adequacy or {})


@pytest.mark.slow
def test_maglev_dropouts_are_unexplained():
    """The maglev record with 0.2 s current dropouts, seed 0 (``output_noise_bias`` without the test):
    windows of about 100 samples."""
    record = make_record("maglev", "actuator dropouts", 0)
    result = diagnose(record.data, record.structure, record.channels, **record.diagnose_arguments())
    assert result.cause == "unexplained", (result.cause, result.adequacy)
    test = result.parameters["held_input"]
    assert test["cause"] == "output_noise_bias" and test["input"] == "lower_coil_current"
    assert all(80 <= n <= 120 for n in test["lengths"]), test


def test_the_held_input_test_keeps_its_level_on_random_clean_loops():
    """20 random plants and noise levels, the plant's own structure fitted by least squares on the
    record: never significant, and at most one window beyond the bound in all 20."""
    windows = 0
    for seed in range(20):
        noise = np.random.default_rng(seed).uniform(0.005, 0.1)
        data = _record(seed, noise)
        test = _held(data)
        assert not test["significant"], (seed, test)
        windows += test["windows"]
    assert windows <= 1


def test_the_held_input_test_finds_random_dropout_lengths():
    """Power: 10 random plants, dropout lengths MIN_HOLD … 40 samples (adjacent stuck windows make
    longer holds), 2 % sensor noise: significant."""
    rng = np.random.default_rng(7)
    for seed in range(10):
        hold = int(rng.integers(MIN_HOLD, 41))
        data = _record(seed, 0.02, hold=hold)
        test = _held(data)
        assert test["significant"], (seed, hold, test)
