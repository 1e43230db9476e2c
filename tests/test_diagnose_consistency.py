"""A named dead time must be one dead time (lpvflow/validate/diagnose_consistency.py): the named delay
re-estimated on the least-squares equations after small and after large input moves. A real dead time
holds on both; the delay that imitates an input rate limiter does not (benchmarks/README.md, 'One dead
time after small and large moves')."""

from __future__ import annotations

import numpy as np

from lpvflow.data import Dataset
from lpvflow.validate.diagnose import diagnose
from lpvflow.validate.diagnose_consistency import delay_consistency
from lpvflow.validate.extensions import EXTENSIONS, Context, fit
from tests.diagnosis_cases import NOMINAL, held_levels, simulate_plant
from tests.diagnosis_fmu_cases import make_record, outcome

ALPHA = 1e-3


def _rate_limited(u: np.ndarray, rate: float) -> np.ndarray:
    """u_a(k) = u_a(k−1) + clip(u(k) − u_a(k−1), −rate, rate)."""
    out = np.empty_like(u)
    out[0] = u[0]
    for k in range(1, len(u)):
        out[k] = out[k - 1] + np.clip(u[k] - out[k - 1], -rate, rate)
    return out


def _synthetic(seed: int, kind: str) -> Dataset:
    """The synthetic bench plant (tests/diagnosis_cases.py) under 30 dB equation noise, input levels held
    5–30 samples, with a dead time of 2–5 samples drawn from the seed or a rate limit of 0.05 per sample."""
    rng = np.random.default_rng(seed)
    n = 4000
    u = held_levels(rng, n, -1, 1, 5, 30)
    p = held_levels(rng, n, -1, 1, 10, 40)
    nk = int(rng.integers(2, 6)) if kind == "dead time" else 1
    applied = _rate_limited(u, 0.05) if kind == "rate limiter" else u
    clean = simulate_plant(applied, p, nk=nk)
    e = rng.normal(size=n)
    response = simulate_plant(applied, p, nk=nk, e=e) - clean
    y = simulate_plant(applied, p, nk=nk, e=e * np.std(clean) / np.std(response) * 10 ** (-30 / 20))
    return Dataset(u[:, None], y[:, None], p[:, None], 0.01, ["u"], ["y"], ["p"])


def _check(data: Dataset) -> dict | None:
    est, val = data.split(0.5)
    ctx = Context(est, val, NOMINAL, fit(est, val, 2, 2, 1, NOMINAL.basis_for(1)), {})
    delay = EXTENSIONS["input_delay"](ctx)
    return None if delay is None else delay_consistency(ctx, delay, ALPHA)


def test_a_dead_time_holds_after_small_and_large_moves():
    """Ten random dead times: the named delay is the best one on both groups, never rejected."""
    for seed in range(10):
        check = _check(_synthetic(seed, "dead time"))
        assert check is not None and not check["inconsistent"], (seed, check)
        assert check["small_moves"] == check["large_moves"] == check["named"], (seed, check)


def test_the_delay_a_rate_limiter_imitates_is_rejected_on_a_group():
    """Rate limit 0.05 per sample on moves of up to 2: least squares names a delay of 2 samples, which the
    equations after small or after large moves reject (χ²₁ at α/2 per group) on seeds 1–8 of 0–9 (seed 0:
    likelihood ratios 0 and 7.9, under 12.1; seed 9: no delay named)."""
    rejected = [seed for seed in range(10) if (check := _check(_synthetic(seed, "rate limiter")))
                and check["inconsistent"]]
    assert len(rejected) >= 7, rejected


def test_tanks_rate_limiter_named_a_dead_time_is_unexplained():
    """Tanks FMU, pump rate-limited to 0.1 V/s (seed 2): least squares named nk = 5 (+16.6 points); after
    small moves the delay is 8, and nk = 5 is rejected there (likelihood ratio 23.2)."""
    record = make_record("tanks", "rate limiter", 2)
    result = diagnose(record.data, record.structure, record.channels, **record.diagnose_arguments())
    assert result.cause == "unexplained", result.summary
    check = result.parameters["inconsistent_parameter"]
    assert check["named"] == 5 and check["inconsistent"]
    assert max(check["likelihood_ratio"]) > 12.1


def test_airpath_dead_time_stays_a_dead_time():
    """Airpath FMU, 30 ms dead time (seed 0, least-squares verdict with the actuator-delay map): nk [4, 4]
    on both groups."""
    record = make_record("airpath", "dead time 30 ms", 0)
    result = diagnose(record.data, record.structure, record.channels, **record.diagnose_arguments())
    assert outcome(record, result.cause, result.parameters) == "right", result.summary
    assert not result.noise_round
