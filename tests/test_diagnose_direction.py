"""Sensor play (hysteresis on the measured output) is ``unexplained``: the error of the verdict's model
steps with the direction of the output's motion (lpvflow/validate/diagnose_direction.py)."""

import numpy as np
import pytest
import scipy.signal

from lpvflow.data import Dataset
from lpvflow.validate.diagnose import diagnose
from lpvflow.validate.diagnose_direction import direction_dependence, held_direction
from tests.diagnosis_cases import NOMINAL, make_case, play

RNG = np.random.default_rng(35)
SEEDS = [int(s) for s in RNG.integers(3000, 4000, size=2)]


def _with_play(seed: int, width: float) -> tuple[Dataset, dict]:
    """The effect-free synthetic case at 30 dB equation noise, its output read through a play operator of
    total width ``width`` standard deviations of the output (0: the clean twin)."""
    data, channels, _ = make_case("none", seed=seed, snr_db=30)
    y = data.y[:, 0]
    measured = play(y, width * np.std(y)) if width else y
    read = Dataset(data.u, measured[:, None], data.p, data.Ts, data.u_names, data.y_names, data.p_names)
    return read, channels


@pytest.mark.parametrize("seed", SEEDS)
def test_sensor_play_is_unexplained_and_its_clean_twin_none(seed):
    data, channels = _with_play(seed, 0.1)
    result = diagnose(data, NOMINAL, channels)
    assert result.cause == "unexplained", result.summary
    test = result.parameters["motion_direction"]
    assert test["significant"] and test["step_over_sigma"] >= test["threshold"]
    assert abs(test["t"]) > test["bound"]
    assert test["cause"] == "none"  # the verdict it overturns
    assert "direction of the output's motion" in result.summary
    twin, channels = _with_play(seed, 0.0)
    clean = diagnose(twin, NOMINAL, channels)
    assert clean.cause == "none", clean.summary


def test_white_sensor_noise_stays_output_noise_bias():
    data, channels, _ = make_case("sensor_noise", seed=SEEDS[0], snr_db=20)
    result = diagnose(data, NOMINAL, channels)
    assert result.cause == "output_noise_bias", result.summary
    y_model = result.winner.fit.y_val
    val = data.split(0.5)[1]
    assert not direction_dependence(val.y, y_model, val.u, 1e-3)["significant"]


def test_backlash_stays_named():
    data, channels, width = make_case("backlash", seed=SEEDS[1])
    result = diagnose(data, NOMINAL, channels)
    assert result.cause == "backlash", result.summary
    assert result.parameters["width"] == pytest.approx(width, rel=0.2)


def _smooth_record(rng: np.random.Generator, n: int = 3000) -> tuple[np.ndarray, np.ndarray]:
    """(u, ŷ): random held levels through a first-order lag, as a model's simulation."""
    u = np.repeat(rng.uniform(-1, 1, n // 20 + 1), 20)[:n]
    return u[:, None], scipy.signal.lfilter([0.1], [1, -0.9], u)[:, None]


def test_no_direction_dependence_in_coloured_noise_and_a_linear_misfit():
    """Level: 20 random records whose error is AR(1) noise plus a gain and lag misfit linear in the
    input history (which correlates with the direction of motion): never material and significant."""
    rng = np.random.default_rng(0)
    for _ in range(20):
        u, y_sim = _smooth_record(rng)
        noise = scipy.signal.lfilter([1], [1, -rng.uniform(0, 0.9)], rng.normal(0, 0.02, len(u)))
        misfit = rng.uniform(0.9, 1.1) * scipy.signal.lfilter([0.12], [1, -0.88], u[:, 0])
        result = direction_dependence((misfit + noise)[:, None], y_sim, u, 1e-3)
        assert not result["significant"], result


def test_play_on_the_output_is_found_with_its_step():
    """Power: the same records read through a play operator of width w (20 draws): a significant
    direction step of about w (the sensor lags by w/2 each way) and more than DIRECTION_STEP innovation
    standard deviations."""
    rng = np.random.default_rng(1)
    for _ in range(20):
        u, y_sim = _smooth_record(rng)
        width = rng.uniform(0.05, 0.2) * np.std(y_sim)
        y = play(y_sim[:, 0], width) + rng.normal(0, 0.1 * width, len(u))
        result = direction_dependence(y[:, None], y_sim, u, 1e-3)
        assert result["significant"], result


def test_held_direction_keeps_the_last_move_beyond_the_band():
    y = np.array([0.0, 0.5, 1.0, 1.05, 0.98, 0.6, 0.62, 0.61])
    assert held_direction(y, 0.1).tolist() == [0, 1, 1, 1, 1, -1, -1, -1]
    assert held_direction(y, 0.0)[3:5].tolist() == [1, -1]
