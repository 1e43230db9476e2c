"""Excitation signals for identification experiments (pure numpy, seeded).

Every generator returns a float64 array of ``n`` samples at sampling time ``Ts`` (implicit: the
generators work on sample indices). Random choices come only from the ``numpy.random.Generator``
passed in, so the same seed gives the same signal bit for bit.

- :func:`multisine` — sum of cosines with equal amplitudes on the FFT grid of one period,
  Schroeder phases (low crest factor) or random phases.
- :func:`prbs` — maximum-length pseudo-random binary sequence from a Fibonacci LFSR.
- :func:`aprbs` — amplitude-modulated PRBS: random levels held for random durations.
- :func:`triangle` — slow triangle wave 0 → A → −A → 0 per period (a set-point sweep).
- :func:`random_levels` — piecewise-constant scheduling/exogenous trajectory with optional
  linear ramps between the levels (bounded rate, e.g. engine speed).

References: M. R. Schroeder, "Synthesis of low-peak-factor signals and binary sequences with low
autocorrelation", IEEE Trans. Inf. Theory 16 (1970) 85–89; R. Pintelon, J. Schoukens, "System
Identification: a Frequency Domain Approach", 2nd ed., Wiley 2012, §5.2 (multisines, PRBS);
O. Nelles, "Nonlinear System Identification", Springer 2001, §17.7 (APRBS).
"""

from __future__ import annotations

import numpy as np

from lpvflow.errors import DataError

#: Primitive feedback polynomials x^n + ... + 1 of the Fibonacci LFSR, given by their tap
#: exponents (Xilinx XAPP052 table, Alfke 1996). Each gives a maximum-length sequence of period
#: 2^n - 1; ``tests/test_signals.py`` checks the period of every entry.
PRBS_TAPS: dict[int, tuple[int, ...]] = {
    2: (2, 1),
    3: (3, 2),
    4: (4, 3),
    5: (5, 3),
    6: (6, 5),
    7: (7, 6),
    8: (8, 6, 5, 4),
    9: (9, 5),
    10: (10, 7),
    11: (11, 9),
    12: (12, 6, 4, 1),
    13: (13, 4, 3, 1),
    14: (14, 5, 3, 1),
    15: (15, 14),
    16: (16, 15, 13, 4),
    17: (17, 14),
    18: (18, 11),
}


def _check_count(name: str, value: int, minimum: int = 1) -> int:
    if int(value) != value or value < minimum:
        raise DataError(f"{name}={value} must be an integer >= {minimum}")
    return int(value)


def _check_range(lo: float, hi: float) -> None:
    if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
        raise DataError(f"level range lo={lo}, hi={hi} must be finite with lo <= hi")


def multisine_lines(period: int, Ts: float, f_lo: float, f_hi: float) -> np.ndarray:
    """Harmonic indices k with f_lo <= k / (period * Ts) <= f_hi, 1 <= k < period / 2.

    The excited lines lie on the FFT grid of one period, so an integer number of periods has its
    power only in those FFT bins (no leakage). DC and the Nyquist bin are never excited.
    """
    period = _check_count("period (samples)", period, 2)
    if not (0 <= f_lo < f_hi):
        raise DataError(f"multisine band [{f_lo}, {f_hi}] Hz must satisfy 0 <= f_lo < f_hi")
    df = 1.0 / (period * Ts)
    k = np.arange(1, (period + 1) // 2)
    lines = k[(k * df >= f_lo * (1 - 1e-12)) & (k * df <= f_hi * (1 + 1e-12))]
    if lines.size == 0:
        raise DataError(
            f"multisine band [{f_lo}, {f_hi}] Hz holds no line of the grid df={df:g} Hz below "
            f"Nyquist {0.5 / Ts:g} Hz; widen the band or lengthen the period"
        )
    return lines


def schroeder_phases(n_lines: int) -> np.ndarray:
    """Schroeder phases φ_i = -π i (i - 1) / F, i = 1..F, for F lines of equal amplitude (1970, eq. 11)."""
    i = np.arange(1, n_lines + 1)
    return -np.pi * i * (i - 1) / n_lines


def multisine(
    n: int,
    Ts: float,
    f_lo: float,
    f_hi: float,
    period: int | None = None,
    rms: float | None = None,
    peak: float | None = None,
    phases: str = "schroeder",
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Periodic multisine x(k) = a Σ_i cos(2π k_i k / P + φ_i) over the band [f_lo, f_hi] Hz.

    P = ``period`` samples (default ``n``); the lines k_i are :func:`multisine_lines`. The phases
    φ_i are Schroeder's (``phases="schroeder"``) or uniform on [0, 2π) from ``rng``
    (``phases="random"``). Give exactly one of ``rms`` (a = rms·sqrt(2/F), the RMS over one
    period) or ``peak`` (a scaled so that max |x| over one period equals ``peak``).
    """
    n = _check_count("n (samples)", n)
    period = n if period is None else period
    lines = multisine_lines(period, Ts, f_lo, f_hi)
    if (rms is None) == (peak is None):
        raise DataError("multisine needs exactly one of rms= or peak=")
    level = rms if rms is not None else peak
    if not (np.isfinite(level) and level > 0):
        raise DataError(f"multisine amplitude {level} must be a positive finite number")
    if phases == "schroeder":
        phi = schroeder_phases(lines.size)
    elif phases == "random":
        if rng is None:
            raise DataError("multisine with random phases needs a numpy random Generator")
        phi = rng.uniform(0.0, 2.0 * np.pi, size=lines.size)
    else:
        raise DataError(f"multisine phases={phases!r} is unknown; use 'schroeder' or 'random'")
    spectrum = np.zeros(period // 2 + 1, dtype=complex)
    spectrum[lines] = 0.5 * period * np.exp(1j * phi)  # irfft of this is Σ_i cos(2π k_i k / P + φ_i)
    one_period = np.fft.irfft(spectrum, n=period)
    if rms is not None:
        one_period *= rms * np.sqrt(2.0 / lines.size)
    else:
        one_period *= peak / np.max(np.abs(one_period))
    return np.resize(one_period, n)


def crest_factor(x: np.ndarray) -> float:
    """Crest factor max|x| / rms(x) of a zero-mean signal."""
    x = np.asarray(x, dtype=float)
    return float(np.max(np.abs(x)) / np.sqrt(np.mean(x**2)))


def mls_bits(order: int, rng: np.random.Generator) -> np.ndarray:
    """One period (2^order - 1 bits, values 0/1) of the maximum-length sequence of ``PRBS_TAPS[order]``.

    Fibonacci LFSR: b(j) = b(j - t_1) ⊕ ... ⊕ b(j - t_m) with the taps t of the primitive polynomial.
    The nonzero initial state is drawn from ``rng`` (it selects the cyclic shift of the sequence).
    """
    if order not in PRBS_TAPS:
        raise DataError(f"PRBS order {order} is not tabulated; use one of {min(PRBS_TAPS)}..{max(PRBS_TAPS)}")
    length = 2**order - 1
    taps = PRBS_TAPS[order]
    state = int(rng.integers(1, 2**order))
    bits = np.empty(length, dtype=np.int8)
    for j in range(length):
        bits[j] = state & 1
        feedback = 0
        for t in taps:
            feedback ^= (state >> (order - t)) & 1
        state = (state >> 1) | (feedback << (order - 1))
    return bits


def prbs(
    n: int, order: int, clock: int, lo: float, hi: float, rng: np.random.Generator
) -> np.ndarray:
    """PRBS with levels {lo, hi}: each bit of the maximum-length sequence held ``clock`` samples.

    The period is (2^order - 1)·clock samples; the ±1 sequence has circular autocorrelation
    R(0) = M and R(τ) = -1 for 0 < τ < M (M = 2^order - 1), so it is nearly white up to
    1/(2·clock·Ts) Hz. The sequence repeats when n exceeds one period.
    """
    n = _check_count("n (samples)", n)
    clock = _check_count("PRBS clock (samples)", clock)
    _check_range(lo, hi)
    bits = np.repeat(mls_bits(order, rng), clock)
    return np.where(np.resize(bits, n) == 1, hi, lo).astype(float)


def _random_holds(n: int, min_hold: int, max_hold: int, rng: np.random.Generator) -> np.ndarray:
    """Hold lengths drawn uniformly from {min_hold, ..., max_hold} until they cover n samples."""
    min_hold = _check_count("min_hold (samples)", min_hold)
    max_hold = _check_count("max_hold (samples)", max_hold)
    if max_hold < min_hold:
        raise DataError(f"max_hold={max_hold} must be >= min_hold={min_hold} (samples)")
    holds = rng.integers(min_hold, max_hold + 1, size=n // min_hold + 1)
    cover = int(np.searchsorted(np.cumsum(holds), n)) + 1
    return holds[:cover]


def aprbs(
    n: int, lo: float, hi: float, min_hold: int, max_hold: int, rng: np.random.Generator
) -> np.ndarray:
    """Amplitude-modulated PRBS: levels uniform on [lo, hi], each held a uniform random number of
    samples in [min_hold, max_hold] (Nelles 2001, §17.7). Only the last hold may be cut short by n.
    """
    n = _check_count("n (samples)", n)
    _check_range(lo, hi)
    holds = _random_holds(n, min_hold, max_hold, rng)
    levels = rng.uniform(lo, hi, size=holds.size)
    return np.repeat(levels, holds)[:n]


def random_levels(
    n: int,
    lo: float,
    hi: float,
    min_hold: int,
    max_hold: int,
    rng: np.random.Generator,
    ramp: int = 0,
) -> np.ndarray:
    """Random-level trajectory: uniform levels on [lo, hi] held for uniform random durations in
    [min_hold, max_hold] samples; with ``ramp`` > 0 each change is a straight line over the first
    ``ramp`` samples of the new hold (ramp < min_hold), so |Δx| <= (hi - lo)/ramp per sample.
    This bounds the rate of a scheduling signal (e.g. engine speed) as the plant would.
    """
    x = aprbs(n, lo, hi, min_hold, max_hold, rng)
    ramp = _check_count("ramp (samples)", ramp, 0)
    if ramp == 0:
        return x
    if ramp >= min_hold:
        raise DataError(f"ramp={ramp} samples must be shorter than min_hold={min_hold} samples")
    starts = np.flatnonzero(np.diff(x)) + 1
    out = x.copy()
    for s in starts:
        before, after = x[s - 1], x[s]
        stop = min(s + ramp, n)
        frac = np.arange(1, stop - s + 1) / ramp
        out[s:stop] = before + frac * (after - before)
    return out


def triangle(n: int, period: int, amp: float) -> np.ndarray:
    """Triangle wave of ``period`` samples and amplitude ``amp``: from 0 up to amp at period/4, down to
    −amp at 3·period/4 and back to 0 at period (slope 4·amp/period per sample), repeated over n samples.
    """
    n = _check_count("n (samples)", n)
    period = _check_count("triangle period (samples)", period, 4)
    if not np.isfinite(amp):
        raise DataError(f"triangle amp={amp} must be finite")
    phase = (np.arange(n) / period + 0.25) % 1.0  # 0.25 ↦ 0 rising
    return amp * (1.0 - 4.0 * np.abs(phase - 0.5))
