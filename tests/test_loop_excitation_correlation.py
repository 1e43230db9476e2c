"""The closed-loop adequacy test's residual cross-correlation against the excitation
(:func:`lpvflow.validate.loop_adequacy.correlated_with_excitation`): its level on errors independent of
the excitation whatever their colour, its power on an error that depends on the excitation, and the
diagnosis' decision on two ADIP records of the plant bench (tests/diagnosis_fmu_cases.py)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from lpvflow.validate.diagnose import diagnose
from lpvflow.validate.loop_adequacy import correlated_with_excitation
from tests.diagnosis_fmu_cases import make_record, outcome

N = 4000


def _coloured(rng: np.random.Generator, n: int) -> np.ndarray:
    """White noise through a random stable AR(2) filter with poles of radius 0.5–0.95."""
    radius, angle = rng.uniform(0.5, 0.95), rng.uniform(0.0, np.pi)
    return lfilter([1.0], [1.0, -2 * radius * np.cos(angle), radius**2], rng.standard_normal(n))


@pytest.mark.parametrize("seed", range(20))
def test_an_error_independent_of_the_excitation_passes_whatever_its_colour(seed):
    rng = np.random.default_rng(seed)
    excitation = np.column_stack([_coloured(rng, N), rng.standard_normal(N)])
    error = np.column_stack([_coloured(rng, N), _coloured(rng, N)])
    result = correlated_with_excitation(error, np.zeros_like(error), excitation, 1e-3)
    assert not result["significant"], result
    assert result["pairs"] == 4


@pytest.mark.parametrize("seed", range(10))
def test_an_error_with_a_small_part_driven_by_the_excitation_fails(seed):
    rng = np.random.default_rng(100 + seed)
    excitation = rng.standard_normal((N, 1))
    driven = lfilter([0.0, 0.3], [1.0, -0.8], excitation[:, 0])  # a missed first-order response
    noise = _coloured(rng, N)
    error = (noise + 0.5 * np.std(noise) / np.std(driven) * driven)[:, None]
    result = correlated_with_excitation(error, np.zeros_like(error), excitation, 1e-3)
    assert result["significant"], result
    assert result["largest"] > result["bound"]


@pytest.mark.parametrize(("effect", "seed", "expected"), [("rate limiter", 1, "unexplained"),
                                                          ("clean", 0, None)])
def test_adip_rate_limiter_is_unexplained_and_a_clean_record_is_not_flagged(effect, seed, expected):
    record = make_record("adip", effect, seed)
    result = diagnose(record.data, record.structure, record.channels, **record.diagnose_arguments())
    assert outcome(record, result.cause, result.parameters, result.not_identifiable) == "right", result.cause
    correlation = result.adequacy["excitation_correlation"]
    assert correlation["significant"] == (expected == "unexplained"), correlation
    if expected:
        assert result.cause == expected
