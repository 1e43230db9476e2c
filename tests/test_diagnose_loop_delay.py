"""A dead time named in closed loop must leave no direction dependence
(lpvflow/validate/diagnose_loop_delay.py): the decision on random records, and maglev bench records."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import scipy.signal

from lpvflow.validate.diagnose import diagnose
from lpvflow.validate.diagnose_direction import DIRECTION_STEP
from lpvflow.validate.diagnose_loop_delay import loop_delay_verdict
from tests.diagnosis_cases import play
from tests.diagnosis_fmu_cases import make_record


def _verdict(y: np.ndarray, y_sim: np.ndarray, u: np.ndarray, loop: object | None) -> tuple[str, dict]:
    """loop_delay_verdict on an ``input_delay`` verdict whose model simulates ``y_sim``."""
    ctx = SimpleNamespace(loop=loop, val=SimpleNamespace(y=y, u=u))
    pool = {"input_delay": SimpleNamespace(fit=SimpleNamespace(diverged=False, y_val=y_sim),
                                           parameters={"nk": np.array([3])})}
    return loop_delay_verdict(ctx, "input_delay", pool, {}, 1e-3)


@pytest.mark.parametrize("seed", range(3))
def test_a_small_significant_play_step_makes_a_loop_delay_unexplained(seed):
    """A smooth random record read through a play of 2–4 % of its standard deviation under white noise
    of the same size: in closed loop the delay verdict is ``unexplained`` with the test (its step below
    the open-loop materiality DIRECTION_STEP); in open loop, and without the play, it stays."""
    rng = np.random.default_rng(seed)
    n = 4000
    u = np.repeat(rng.uniform(-1, 1, n // 20 + 1), 20)[:n]
    y_sim = scipy.signal.lfilter([0.1], [1, -0.9], u)
    width = rng.uniform(0.02, 0.04) * np.std(y_sim)
    noise = rng.normal(0, width, n)
    y = play(y_sim, width) + noise
    cause, adequacy = _verdict(y[:, None], y_sim[:, None], u[:, None], loop=object())
    assert cause == "unexplained", adequacy
    test = adequacy["delay_direction"]
    assert abs(test["t"]) > test["bound"] and test["step_over_sigma"] < DIRECTION_STEP and test["nk"] == [3]
    assert _verdict(y[:, None], y_sim[:, None], u[:, None], loop=None)[0] == "input_delay"
    assert _verdict((y_sim + noise)[:, None], y_sim[:, None], u[:, None], loop=object())[0] == "input_delay"


@pytest.mark.slow
@pytest.mark.parametrize(("effect", "seed", "expected"), [("sensor hysteresis", 1, "unexplained"),
                                                          ("dead time 6 ms", 0, "input_delay")])
def test_maglev_delay_verdicts(effect, seed, expected):
    """Maglev 0.2 mm sensor play (``input_delay`` without the test) and a 6 ms dead time (right)."""
    record = make_record("maglev", effect, seed)
    result = diagnose(record.data, record.structure, record.channels, **record.diagnose_arguments())
    assert result.cause == expected, (result.cause, result.adequacy)
    if expected == "unexplained":
        assert "delay_direction" in result.parameters and "dead time" in result.summary
