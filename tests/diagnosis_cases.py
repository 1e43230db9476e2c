"""Synthetic LPV data with one hidden effect each, for the diagnosis tests and benchmark.

Base plant (shifted form, affine in p):  y(k) + a₁(p(k−1)) y(k−1) + a₂(p(k−2)) y(k−2)
  = b₁(p(k−1)) u(k−1) + b₂(p(k−2)) u(k−2),  a₁ = −1.3 + 0.25p, a₂ = 0.55 − 0.1p, b₁ = 1 + 0.3p,
b₂ = 0.4 − 0.2p (frozen pole radius ≤ 0.81); p random levels in [−1, 1] held 10–40 samples;
u uniform in [−1, 1] held 1–5 samples.
The effect is applied to that plant; the diagnosis always gets the nominal structure na=nb=2, nk=1,
affine basis. Noise: equation (ARX) noise e(k) entering like y(k) = … + e(k), scaled so that the
noise-free-to-noise output power ratio is ``snr_db`` — inside the model set, so that without an effect
the nominal structure is right. ``sensor_noise`` instead adds white *measurement* noise at the output
(an output-error noise model, coloured as equation noise), which biases least squares; ``ar2_noise``
adds measurement noise coloured by 1/(1 − 1.5q⁻¹ + 0.7q⁻²) (poles 0.75 ± 0.37j), both at ``snr_db``.
Their expected parameter is the noise's standard deviation relative to the noise-free output's.

Effects of issue 26 (outside the base plant's input path or output map):

* ``friction_velocity`` — a first-order plant whose *output is the velocity*:
  v(k+1) = a(p(k)) v(k) + b(p(k)) (u(k) − F_c sign v(k)), a = 0.85 + 0.1p, b = 0.5 + 0.2p, F_c = 0.2;
* ``backlash`` — a play operator of total width 0.3 (dead band ±0.15 with memory) on the input;
* ``sensor_saturation`` — the measured output clipped to ±s, s = 60 % of the noise-free peak;
* ``out_of_vocabulary`` — an even input map u + 0.8 (u² − 1/3) (zero mean for u uniform in [−1, 1]),
  which no extension of the vocabulary describes.
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


def play(u: np.ndarray, width: float) -> np.ndarray:
    """Backlash (play operator): the output moves only when the input pushes it past ±width/2."""
    out = np.empty_like(u)
    half, state = width / 2, 0.0
    for k, x in enumerate(u):
        state = min(max(state, x - half), x + half)
        out[k] = state
    return out


def simulate_velocity_plant(u, p, friction=0.0, e=None):
    """The friction_velocity plant of the module docstring; e is equation noise."""
    v = np.zeros(len(u))
    e = np.zeros(len(u)) if e is None else e
    for k in range(len(u) - 1):
        v[k + 1] = ((0.85 + 0.1 * p[k]) * v[k] + (0.5 + 0.2 * p[k]) * (u[k] - friction * np.sign(v[k]))
                    + e[k + 1])
    return v


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
    if "backlash" in effects:
        expected = 0.3
        u_plant = play(u, expected)
    if "out_of_vocabulary" in effects:
        u_plant = u + 0.8 * (u**2 - 1 / 3)
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
    plant = simulate_plant
    if "friction_velocity" in effects:
        plant, kwargs, expected = simulate_velocity_plant, {"friction": 0.2}, 0.2
    y_clean = plant(u_plant, p, **kwargs)
    noise = rng.normal(size=n)
    if "ar2_noise" in effects:
        noise = scipy.signal.lfilter([1.0], [1.0, -1.5, 0.7], noise)
    if "sensor_noise" in effects or "ar2_noise" in effects:
        expected = 10 ** (-snr_db / 20)
        y_meas = y_clean + noise / np.std(noise) * np.std(y_clean) * expected
    else:
        # Scale the noise by its linear-path response, then run the plant once more with it, so that
        # nonlinear plants (friction) see the noise inside a consistent trajectory.
        response = plant(u_plant, p, e=noise, **{**kwargs, "friction": 0.0})
        response -= plant(u_plant, p, **{**kwargs, "friction": 0.0})
        scale = np.std(y_clean) / np.std(response) * 10 ** (-snr_db / 20)
        y_meas = plant(u_plant, p, e=scale * noise, **kwargs)
    if "sensor_saturation" in effects:
        expected = 0.6 * float(np.max(np.abs(y_clean)))
        y_meas = np.clip(y_meas, -expected, expected)
    if "offset" in effects:
        expected = 0.5
        y_meas = y_meas + expected
    data = Dataset(u[:, None], y_meas[:, None], p[:, None], 0.01, ["u"], ["y"], ["p"])
    return data, channels, expected
