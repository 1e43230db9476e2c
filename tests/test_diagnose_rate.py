"""An input rate limiter is ``unexplained``: the error of the verdict's model follows the plant's response
to the deficit of a rate-limited input (lpvflow/validate/diagnose_rate.py)."""

import numpy as np
import pytest
import scipy.signal

from lpvflow.data import Dataset
from lpvflow.validate.diagnose import diagnose
from lpvflow.validate.diagnose_rate import rate_dependence, rate_limited
from tests.diagnosis_cases import NOMINAL, held_levels, simulate_plant

RNG = np.random.default_rng(36)
SEEDS = [int(s) for s in RNG.integers(4000, 5000, size=2)]


def _rate_limited_case(seed: int, step: float | None) -> Dataset:
    """The synthetic plant of tests/diagnosis_cases.py driven by held levels in [−1, 1] through a rate
    limiter of ``step`` per sample (None: the clean twin), 3 % white sensor noise."""
    rng = np.random.default_rng(seed)
    n = 4000
    u = held_levels(rng, n, -1, 1, 1, 5)
    p = held_levels(rng, n, -1, 1, 10, 40)
    y = simulate_plant(rate_limited(u, step) if step else u, p)
    y = y + 0.03 * np.std(y) * rng.normal(size=n)
    return Dataset(u[:, None], y[:, None], p[:, None], 0.01, ["u"], ["y"], ["p"])


def test_rate_limited_matches_its_definition():
    rng = np.random.default_rng(2)
    u = rng.uniform(-1, 1, 200)
    applied = rate_limited(u, 0.1)
    assert applied[0] == u[0]
    assert np.all(np.abs(np.diff(applied)) <= 0.1 + 1e-12)
    moved = np.abs(u[1:] - applied[:-1]) <= 0.1  # reachable within one step: followed exactly
    assert np.allclose(applied[1:][moved], u[1:][moved])


@pytest.mark.parametrize("seed", SEEDS)
def test_rate_limiter_is_unexplained_and_its_clean_twin_none(seed):
    """``unexplained`` — by this test, or earlier by the adequacy test (a strong limit leaves a large
    error) — and the nominal model's error carries the deficit's response."""
    data = _rate_limited_case(seed, 0.1)
    result = diagnose(data, NOMINAL, {})
    assert result.cause == "unexplained", result.summary
    val = data.split(0.5)[1]
    nominal = rate_dependence(val.y, result.nominal_y_val, val.u, 1e-3)
    assert nominal["significant"] and nominal["t"] > nominal["bound"], nominal
    if "input_rate" in result.parameters:
        test = result.parameters["input_rate"]
        assert test["size_over_sigma"] >= test["threshold"] and "rate-limited input" in result.summary
    clean = diagnose(_rate_limited_case(seed, None), NOMINAL, {})
    assert clean.cause == "none", clean.summary


def _smooth_record(rng: np.random.Generator, n: int = 3000) -> tuple[np.ndarray, np.ndarray]:
    """(u, ŷ): random held levels through a first-order lag, as a model's simulation."""
    u = np.repeat(rng.uniform(-1, 1, n // 20 + 1), 20)[:n]
    return u, scipy.signal.lfilter([0.1], [1, -0.9], u)


def test_no_rate_dependence_in_coloured_noise_and_a_linear_misfit():
    """Level: 20 random records whose error is AR(1) noise plus a gain and lag misfit linear in the
    input history: never significant."""
    rng = np.random.default_rng(0)
    for _ in range(20):
        u, y_sim = _smooth_record(rng)
        noise = scipy.signal.lfilter([1], [1, -rng.uniform(0, 0.9)], rng.normal(0, 0.02, len(u)))
        misfit = rng.uniform(0.9, 1.1) * scipy.signal.lfilter([0.12], [1, -0.88], u)
        result = rate_dependence((y_sim + misfit + noise)[:, None], y_sim[:, None], u[:, None], 1e-3)
        assert not result["significant"], result


def test_rate_limit_on_the_input_is_found():
    """Power: the same records with the plant driven through a rate limiter of 1/10 … 1/40 of the input's
    range per sample (20 draws): significant, material and positive (the plant sees the deficit)."""
    rng = np.random.default_rng(1)
    for _ in range(20):
        u, y_sim = _smooth_record(rng)
        limited = rate_limited(u, rng.uniform(0.05, 0.2))
        y = scipy.signal.lfilter([0.1], [1, -0.9], limited) + rng.normal(0, 0.02, len(u))
        result = rate_dependence(y[:, None], y_sim[:, None], u[:, None], 1e-3)
        assert result["significant"] and result["t"] > result["bound"], result
