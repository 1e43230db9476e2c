"""The augmented ARCH test of lpvflow/validate/error_clustering.py: an error whose variance follows the
exogenous signals is not flagged, one that bursts at random times is; in a loop, an actuator that drops
out for a while is ``unexplained`` where the same loop without dropouts is not."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

from lpvflow.data import Dataset
from lpvflow.experiment.controller import LtiController
from lpvflow.validate.diagnose import diagnose
from lpvflow.validate.error_clustering import CLUSTERING_SHARE, clustered_variance
from lpvflow.validate.extensions import Structure
from tests.diagnosis_fmu_cases import make_record, outcome

N = 4000
ALPHA = 1e-3


def _coloured(rng: np.random.Generator, n: int) -> np.ndarray:
    """White Gaussian noise through a random stable second-order filter."""
    poles = rng.uniform(0.3, 0.95, size=2)
    return scipy.signal.lfilter([1.0], np.poly(poles), rng.normal(size=n))


def _levels(rng: np.random.Generator, n: int) -> np.ndarray:
    """Random levels held 1–20 samples (an excitation)."""
    return np.repeat(rng.normal(size=n), rng.integers(1, 21, size=n))[:n]


@pytest.mark.parametrize("seed", range(10))
def test_an_error_whose_size_follows_the_exogenous_moves_is_not_clustered(seed):
    """Level: a coloured Gaussian error whose standard deviation grows with the size of the
    excitation's last move (a time-invariant misfit's error) — the exogenous regressors take that up —
    and a coloured error independent of everything: not significant, the share well under the
    threshold."""
    rng = np.random.default_rng(seed)
    x = _levels(rng, N)
    move = np.abs(np.diff(x, prepend=x[0]))
    y_sim = scipy.signal.lfilter([0.5], [1.0, -0.8], x)
    for error in (_coloured(rng, N) * (0.2 + move), _coloured(rng, N)):
        result = clustered_variance((y_sim + error)[:, None], y_sim[:, None], x[:, None], ALPHA)
        assert not result["significant"], result
        assert result["per_output"][0]["share"] < CLUSTERING_SHARE / 2


@pytest.mark.parametrize("seed", range(10))
def test_an_error_that_bursts_at_random_times_is_clustered(seed):
    """Power: a coloured error whose driving white noise is four times larger in bursts of 10–100
    samples at random times (one window in ten), unrelated to the excitation — a disturbance that comes
    and goes, reaching the output through the plant's dynamics. (Three times larger: shares 0.09–0.20
    on these draws, the 10-sample bursts under CLUSTERING_SHARE.)"""
    rng = np.random.default_rng(100 + seed)
    x = _levels(rng, N)
    y_sim = scipy.signal.lfilter([0.5], [1.0, -0.8], x)
    length = int(rng.integers(10, 101))
    burst = np.repeat(rng.random(N // length + 1) < 0.1, length)[:N]
    poles = rng.uniform(0.3, 0.95, size=2)
    error = scipy.signal.lfilter([1.0], np.poly(poles), rng.normal(size=N) * np.where(burst, 4.0, 1.0))
    result = clustered_variance((y_sim + error)[:, None], y_sim[:, None], x[:, None], ALPHA)
    assert result["significant"], (length, result)


def _controller(gain: float) -> LtiController:
    """u = −gain·y + r (a static output feedback; the excitation r is added by the loop)."""
    return LtiController(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.array([[-gain]]), 1.0,
                         ("y",), ("u",), np.zeros(1), np.zeros(1))


def _loop_record(seed: int, stuck: np.ndarray | None = None, delay: int = 1) -> Dataset:
    """y(k) = 0.9·y(k−1) + 0.5·u_a(k−delay) measured with white noise of 0.002 under u = −0.8·y_meas + r,
    r random levels held 1–10 samples; u_a = u except where ``stuck`` is set, where the actuator keeps
    its last value (dropouts). The recorded input is the commanded u."""
    rng = np.random.default_rng(seed)
    r = np.repeat(rng.normal(size=N), rng.integers(1, 11, size=N))[:N]
    y, y_meas, u, applied = np.zeros(N), np.zeros(N), np.zeros(N), np.zeros(N)
    for k in range(N):
        if k >= delay:
            y[k] = 0.9 * y[k - 1] + 0.5 * applied[k - delay]
        y_meas[k] = y[k] + 0.002 * rng.normal()
        u[k] = -0.8 * y_meas[k] + r[k]
        applied[k] = applied[k - 1] if (stuck is not None and stuck[k] and k) else u[k]
    p = np.repeat(rng.uniform(size=N), 50)[:N]  # a recorded scheduling signal the plant does not depend on
    return Dataset(u, y_meas, p, 1.0, ["u"], ["y"], ["p"])


def _dropouts(seed: int, length: int = 4) -> np.ndarray:
    """Windows of ``length`` samples, each stuck with probability 0.1."""
    rng = np.random.default_rng(1000 + seed)
    return np.repeat(rng.random(N // length + 1) < 0.1, length)[:N]


CAUSES = ["input_delay", "model_order", "output_noise_bias"]


@pytest.mark.parametrize("seed", range(2))
def test_actuator_dropouts_in_a_loop_are_unexplained_and_the_clean_twin_is_not(seed):
    """End to end with the controller: the actuator stuck at its last value in one window of 4 samples
    in ten is ``unexplained``, its evidence the clustering of the error's variance; the same loop
    without dropouts (same excitation and noise) is not."""
    structure = Structure(1, 1, 1, "affine")
    result = diagnose(_loop_record(seed, _dropouts(seed)), structure, controller=_controller(0.8),
                      causes=CAUSES)
    assert result.cause == "unexplained", (result.cause, result.ranking, result.adequacy)
    assert result.adequacy["variance_clustering"]["significant"]
    clean = diagnose(_loop_record(seed), structure, controller=_controller(0.8), causes=CAUSES)
    assert clean.cause in ("none", "output_noise_bias"), (clean.cause, clean.adequacy)
    assert not clean.adequacy["variance_clustering"]["significant"]


def test_a_dead_time_in_the_loop_is_still_named():
    """An in-vocabulary effect in the same loop, a dead time of 3 samples, is still ``input_delay``:
    its extended model's error does not cluster."""
    result = diagnose(_loop_record(5, delay=3), Structure(1, 1, 1, "affine"), controller=_controller(0.8),
                      causes=CAUSES)
    assert result.cause == "input_delay", (result.cause, result.ranking, result.adequacy)
    assert result.parameters["nk"] == 3
    assert not result.adequacy["extended_model"]["variance_clustering"]["significant"]


@pytest.mark.parametrize(("effect", "seed"), [("actuator dropouts", 0), ("clean", 0)])
def test_adip_actuator_dropouts_are_unexplained_and_a_clean_record_is_not_flagged(effect, seed):
    """The ADIP FMU in its loop with the voltage stuck for 20 ms in one window in ten
    (tests/diagnosis_fmu_cases.py): ``none`` before this test, now ``unexplained`` by the clustering
    of its error's variance; the clean record of the same seed stays a noise verdict, not flagged."""
    record = make_record("adip", effect, seed)
    result = diagnose(record.data, record.structure, record.channels, **record.diagnose_arguments())
    assert outcome(record, result.cause, result.parameters, result.not_identifiable) == "right", result.cause
    clustering = result.adequacy["variance_clustering"]
    assert clustering["significant"] == (effect != "clean"), clustering
