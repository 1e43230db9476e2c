"""The prediction-error criterion of an error under an AR noise model
(:func:`lpvflow.validate.residuals.prewhitened_log_det`), on random AR processes with a fixed seed."""

from __future__ import annotations

import numpy as np
import scipy.signal

from lpvflow.validate.residuals import prewhitened_log_det


def _stable_ar(rng: np.random.Generator, order: int) -> np.ndarray:
    """1 + a₁q⁻¹ + … with random roots inside radius 0.95 (real pairs keep it real)."""
    roots = rng.uniform(-0.95, 0.95, order)
    return np.poly(roots)


def test_an_ar_error_is_scored_by_its_innovations_not_its_colour():
    """e = w / A(q), w white N(0, Σ) per output: the whitened log det is log det Σ (to sampling error),
    the raw one larger by the colour's gain, whatever the AR polynomials."""
    rng = np.random.default_rng(20261128)
    for _ in range(20):
        n, ny = 20_000, int(rng.integers(1, 3))
        sigma = rng.uniform(0.1, 3.0, ny)
        w = rng.standard_normal((n, ny)) * sigma
        e = np.column_stack([scipy.signal.lfilter([1.0], _stable_ar(rng, int(rng.integers(1, 4))), w[:, j])
                             for j in range(ny)])
        expected = float(np.sum(np.log(sigma**2)))
        assert abs(prewhitened_log_det(e, 20) - expected) < 0.05 * ny
        raw = float(np.linalg.slogdet(np.atleast_2d(np.cov(e.T)))[1])
        assert raw > prewhitened_log_det(e, 20)


def test_a_white_error_keeps_its_level_and_a_dead_error_is_infinite():
    rng = np.random.default_rng(7)
    for _ in range(10):
        s = rng.uniform(1e-6, 1e3)
        e = rng.standard_normal(5_000) * s
        assert abs(prewhitened_log_det(e, 20) - np.log(s**2)) < 0.1
    assert prewhitened_log_det(np.zeros((500, 2)), 5) == np.inf
