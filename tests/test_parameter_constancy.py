"""The split-sample parameter-constancy test (lpvflow/validate/parameter_constancy.py): a plant whose
coefficients are the same on both splits is not flagged; a drifting actuator gain is, and on the airpath
FMU record it turns the diagnosis' ``none`` into ``unexplained`` (benchmarks/README.md, 'Parameter
constancy')."""

from __future__ import annotations

import numpy as np

from lpvflow.data import Dataset
from lpvflow.validate.diagnose import diagnose
from lpvflow.validate.parameter_constancy import CONSTANCY_GAIN, split_constancy
from tests.diagnosis_cases import NOMINAL, held_levels, simulate_plant
from tests.diagnosis_fmu_cases import make_record, outcome

ALPHA = 1e-3


def _synthetic(seed: int, drift: float) -> Dataset:
    """The synthetic bench plant (tests/diagnosis_cases.py) at 30 dB equation noise, its input gain
    rising linearly from 1 to 1 + ``drift`` over the record."""
    rng = np.random.default_rng(seed)
    n = 4000
    u = held_levels(rng, n, -1, 1, 1, 5)
    p = held_levels(rng, n, -1, 1, 10, 40)
    applied = u * (1 + drift * np.arange(n) / n)
    clean = simulate_plant(applied, p)
    e = rng.normal(size=n)
    response = simulate_plant(applied, p, e=e) - clean
    y = simulate_plant(applied, p, e=e * np.std(clean) / np.std(response) * 10 ** (-30 / 20))
    return Dataset(u[:, None], y[:, None], p[:, None], 0.01, ["u"], ["y"], ["p"])


def _constancy(data: Dataset) -> dict:
    est, val = data.split(0.5)
    return split_constancy(est, val, NOMINAL, ALPHA)


def test_constant_coefficients_are_not_flagged():
    """Ten random records of a time-invariant plant inside the model set: S stays far below the
    threshold (measured 0.004–0.26 points) and the test never rejects."""
    for seed in range(10):
        check = _constancy(_synthetic(100 + seed, 0.0))
        assert not check["significant"], (seed, check)
        assert check["statistic"] < CONSTANCY_GAIN / 4, (seed, check)


def test_a_drifting_gain_is_flagged():
    """Ten random records whose input gain drifts by 40 %: both halves lose with the other's
    coefficients, the test rejects at α (measured S = 20.1–25.3, p = 9.5·10⁻⁷)."""
    for seed in range(10):
        check = _constancy(_synthetic(100 + seed, 0.4))
        assert check["significant"], (seed, check)
        assert check["estimation_gain"] > 0 and check["validation_gain"] > 0, (seed, check)


def test_airpath_drifting_gain_is_unexplained_and_clean_record_is_not():
    """The airpath FMU record with a drifting throttle gain (seed 0) was ``none``: the input history
    explains no more of its error than on clean records. The constancy test makes it ``unexplained``;
    the clean record of the same seed stays ``none``."""
    drifting = make_record("airpath", "drifting gain", 0)
    result = diagnose(drifting.data, drifting.structure, drifting.channels, **drifting.diagnose_arguments())
    assert result.cause == "unexplained", result.summary
    assert result.adequacy["parameter_constancy"]["significant"]
    clean = make_record("airpath", "clean", 0)
    result = diagnose(clean.data, clean.structure, clean.channels, **clean.diagnose_arguments())
    assert outcome(clean, result.cause, result.parameters) == "right", result.summary
    assert "parameter_constancy" not in result.adequacy
