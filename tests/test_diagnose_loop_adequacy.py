"""The adequacy test of a model simulated in its identification loop (lpvflow/validate/loop_adequacy.py):
the settling time of the model's loop, and the in-loop simulation error tested against the exogenous
excitation, on a first-order plant under a static output feedback."""

from __future__ import annotations

import numpy as np
import pytest

from lpvflow.data import Dataset
from lpvflow.experiment.controller import LtiController
from lpvflow.identify.arx import identify_arx
from lpvflow.validate import residuals
from lpvflow.validate.closed_loop import Loop, simulate_in_loop
from lpvflow.validate.diagnose import ADEQUACY_GAIN, diagnose
from lpvflow.validate.extensions import Structure
from lpvflow.validate.loop_adequacy import explained_in_loop, loop_adequacy_lags, model_loop
from lpvflow.validate.noise_analysis import settling_samples

N = 4000


def _controller(gain: float) -> LtiController:
    """u = −gain·y + r (a static output feedback; the excitation r is added by the loop)."""
    return LtiController(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.array([[-gain]]), 1.0,
                         ("y",), ("u",), np.zeros(1), np.zeros(1))


def _record(a: float, b: float, gain: float, seed: int, noise: float = 0.01,
            actuator=lambda u, k: u) -> Dataset:
    """y(k) = a·y(k−1) + b·f(u(k−1), k−1), measured with white noise, under u = −gain·y_meas + r with r
    random levels held 1–10 samples; ``actuator`` is f (the identity: the plant the model describes).
    With ``noise=0`` and the identity it is the plant's noise-free response."""
    rng = np.random.default_rng(seed)
    r = np.repeat(rng.normal(size=N), rng.integers(1, 11, size=N))[:N]
    y, y_meas, u = np.zeros(N), np.zeros(N), np.zeros(N)
    for k in range(N):
        if k:
            y[k] = a * y[k - 1] + b * actuator(u[k - 1], k - 1)
        y_meas[k] = y[k] + noise * rng.normal()
        u[k] = -gain * y_meas[k] + r[k]
    p = np.repeat(rng.uniform(size=N), 50)[:N]  # a recorded scheduling signal the plant does not depend on
    return Dataset(u, y_meas, p, 1.0, ["u"], ["y"], ["p"])


def _model(a: float, b: float, gain: float):
    """The plant's own model: the ARX fit of its noise-free response in the loop (exact to rounding)."""
    return identify_arx(_record(a, b, gain, 0, noise=0.0), 1, 1, 1, "affine")


@pytest.mark.parametrize("seed", range(3))
def test_the_loop_settling_time_is_that_of_the_closed_loop_pole(seed):
    """Closed-loop pole ρ = a − b·gain: the pulse response b·δ·ρʲ (j ≥ 0 from the sample after the pulse)
    falls below 2 % of its peak after ⌈ln 0.02 / ln |ρ|⌉ samples, one more counting the pulse's own
    sample; an unstable plant (a > 1) has no open-loop settling time but its loop has one."""
    rng = np.random.default_rng(seed)
    rho = rng.uniform(0.5, 0.95)
    a = rng.uniform(1.02, 1.2) if seed == 0 else rng.uniform(0.3, 0.9)
    b = rng.uniform(0.5, 2.0)
    gain = (a - rho) / b
    data = _record(a, b, gain, seed)
    loop = Loop.from_record(data, _controller(gain))
    model = _model(a, b, gain)
    start = N // 2
    y = simulate_in_loop(model, data, loop)
    reference = model_loop(model, data, loop, start, y[start:])
    settle = reference.settling
    assert settle == 1 + int(np.ceil(np.log(0.02) / np.log(rho)))
    assert np.allclose(reference.inputs[:, -1], data.u[:, 0], atol=0.05)  # the model's loop input ≈ u
    if a > 1:
        assert settling_samples(model, data.p) == 0  # unstable frozen model: no open-loop settling time
    lags = loop_adequacy_lags(settle, N // 2)
    assert lags.max() == max(settle, 20)


def _adequacy(data: Dataset, a: float, b: float, gain: float) -> dict:
    est, val = data.split(0.5)
    loop = Loop.from_record(data, _controller(gain))
    model = _model(a, b, gain)
    y_val = simulate_in_loop(model, data, loop)[est.N :]
    reference = model_loop(model, data, loop, est.N, y_val)
    return explained_in_loop(est, val, reference, y_val, ADEQUACY_GAIN, 1e-3)


@pytest.mark.parametrize("seed", range(4))
def test_the_error_of_the_plants_own_model_in_its_loop_is_not_explained(seed):
    """The model is the plant: its in-loop simulation error is the loop's response to the sensor noise,
    independent of the excitation, although the plant input u (fed back from the noisy output) is
    correlated with it."""
    a, b, gain = 0.9, 0.5, 0.8
    data = _record(a, b, gain, seed, noise=0.05)
    result = _adequacy(data, a, b, gain)
    assert not result["significant"], result
    loop = Loop.from_record(data, _controller(gain))
    error = data.y[:, 0] - simulate_in_loop(_model(a, b, gain), data, loop)[:, 0]
    # u is not exogenous: its correlation with the error is outside the 99 % band of the open-loop test
    assert abs(np.corrcoef(error, data.u[:, 0])[0, 1]) > residuals.band99(N)


@pytest.mark.parametrize(("effect", "actuator"), [
    ("drifting gain", lambda u, k: u * (1 + 0.4 * k / N)),
    ("cubic input map", lambda u, k: u + 0.1 * u**3),
])
def test_an_effect_the_model_lacks_is_explained_by_the_excitation(effect, actuator):
    """The same loop with the plant's actuator changed and the plant's former model: the in-loop error
    has a part the excitation's history explains (≥ ADEQUACY_GAIN points, p < 10⁻³)."""
    a, b, gain = 0.9, 0.5, 0.8
    for seed in range(2):
        result = _adequacy(_record(a, b, gain, seed, actuator=actuator), a, b, gain)
        assert result["significant"], (effect, seed, result)


def test_diagnose_in_the_loop_says_unexplained_for_an_effect_outside_its_vocabulary():
    """End to end with the controller: an actuator gain drifting to 1.4 over the record is
    ``unexplained`` (before, in closed loop, the verdict could not be), its adequacy evidence the
    in-loop test; the plant without the drift is not."""
    a, b, gain = 0.9, 0.5, 0.8
    drift = _record(a, b, gain, 7, actuator=lambda u, k: u * (1 + 0.4 * k / N))
    result = diagnose(drift, Structure(1, 1, 1, "affine"), controller=_controller(gain),
                      causes=["input_delay", "model_order", "output_noise_bias"])
    assert result.cause == "unexplained", (result.cause, result.ranking, result.adequacy)
    assert result.adequacy["significant"] and "loop_settling_samples" in result.adequacy
    assert "the loop's excitation" in result.summary  # not "the input history": u is fed back
    clean = diagnose(_record(a, b, gain, 7), Structure(1, 1, 1, "affine"), controller=_controller(gain),
                     causes=["input_delay", "model_order", "output_noise_bias"])
    assert clean.cause != "unexplained", (clean.cause, clean.adequacy)
