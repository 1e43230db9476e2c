"""Synthetic LPV data with one hidden effect each, for the diagnosis tests and benchmark.

Base plant (shifted form, affine in p):  y(k) + a₁(p(k−1)) y(k−1) + a₂(p(k−2)) y(k−2)
  = b₁(p(k−1)) u(k−1) + b₂(p(k−2)) u(k−2),  a₁ = −1.3 + 0.25p, a₂ = 0.55 − 0.1p, b₁ = 1 + 0.3p,
b₂ = 0.4 − 0.2p (frozen pole radius ≤ 0.81); p random levels in [−1, 1] held 10–40 samples;
u uniform in [−1, 1] held 1–5 samples.
The effect is applied to that plant; the diagnosis always gets the nominal structure na=nb=2, nk=1,
affine basis. Noise: equation (ARX) noise e(k) entering like y(k) = … + e(k), scaled so that the
noise-free-to-noise output power ratio is ``snr_db`` — inside the model set, so that without an effect
the nominal structure is right. ``colored_noise`` instead adds white *measurement* noise at the output
(an output-error noise model, coloured as equation noise), which biases least squares.
"""

from __future__ import annotations

import numpy as np
import scipy.signal

from lpvflow.data import Dataset
from lpvflow.validate.extensions import Structure

NOMINAL = Structure(na=2, nb=2, nk=1, basis="affine")


def held_levels(rng, n, lo, hi, hold_min, hold_max):
    out = np.empty(n)
    k = 0
    while k < n:
        h = rng.integers(hold_min, hold_max + 1)
        out[k : k + h] = rng.uniform(lo, hi)
        k += h
    return out


def simulate_plant(u, p, *, nk=1, lag=0.0, quad=0.0, q=None, q_gain=0.0, friction=0.0, e=None):
    """The base plant with optional structural effects and equation noise e (see module docstring)."""
    n = len(u)
    y = np.zeros(n)
    e = np.zeros(n) if e is None else e
    a1 = -1.3 + 0.25 * p + quad * p**2
    a2 = 0.55 - 0.1 * p - 0.5 * quad * p**2
    b1 = 1 + 0.3 * p + (q_gain * q if q is not None else 0)
    b2 = 0.4 - 0.2 * p
    for k in range(n):
        acc = 0.0
        for i, a in ((1, a1), (2, a2)):
            if k - i >= 0:
                acc -= a[k - i] * y[k - i]
        for j, b in ((0, b1), (1, b2)):
            t = k - nk - j
            if t >= 0:
                v = np.sign(y[t] - y[t - 1]) if (friction and t >= 1) else 0.0
                acc += b[t] * (u[t] - friction * v)
        y[k] = acc + e[k]
    if lag:  # an unmodelled sensor lag yf(k) = lag·yf(k−1) + (1 − lag)·y(k): one more pole
        y = scipy.signal.lfilter([1 - lag], [1, -lag], y)
    return y


def make_case(effect: str, seed: int, snr_db: float = 30.0, n: int = 4000, deadzone: float = 0.3):
    """(data, channels, expected parameter) for one hidden effect, 'none', or effects joined by '+'
    (then the expected parameter is the last one's)."""
    effects = effect.split("+")
    rng = np.random.default_rng(seed)
    u = held_levels(rng, n, -1, 1, 1, 5)
    p = held_levels(rng, n, -1, 1, 10, 40)
    q = held_levels(rng, n, -1, 1, 10, 40)  # a recorded channel
    r = held_levels(rng, n, -1, 1, 10, 40)  # an unrelated recorded channel
    channels = {"q": q, "r": r}
    expected = None
    u_plant = u
    if "input_nonlinearity" in effects:
        expected = deadzone
        u_plant = np.sign(u) * np.maximum(np.abs(u) - expected, 0)
    kwargs = {}
    if "input_delay" in effects:
        kwargs["nk"], expected = 3, 3
    if "model_order" in effects:
        kwargs["lag"], expected = 0.7, 3  # a third pole at 0.7: na must reach 3
    if "scheduling_dependence" in effects:
        kwargs["quad"], expected = 0.35, 2
    if "scheduling_variable" in effects:
        kwargs["q"], kwargs["q_gain"], expected = q, 0.6, "q"
    if "friction" in effects:
        kwargs["friction"], expected = 0.2, 0.2
    y_clean = simulate_plant(u_plant, p, **kwargs)
    noise = rng.normal(size=n)
    if "colored_noise" in effects:
        y_meas = y_clean + noise * np.std(y_clean) * 10 ** (-snr_db / 20)
    else:
        # Scale the noise by its linear-path response, then run the plant once more with it, so that
        # nonlinear plants (friction) see the noise inside a consistent trajectory.
        response = simulate_plant(u_plant, p, e=noise, **{**kwargs, "friction": 0.0})
        response -= simulate_plant(u_plant, p, **{**kwargs, "friction": 0.0})
        scale = np.std(y_clean) / np.std(response) * 10 ** (-snr_db / 20)
        y_meas = simulate_plant(u_plant, p, e=scale * noise, **kwargs)
    if "offset" in effects:
        expected = 0.5
        y_meas = y_meas + expected
    data = Dataset(u[:, None], y_meas[:, None], p[:, None], 0.01, ["u"], ["y"], ["p"])
    return data, channels, expected
