"""Zero-phase prefilter of identification data (``[identify] prefilter``): its spec and the filter."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import scipy.signal

from lpvflow.data import Dataset
from lpvflow.errors import DataError


def prefiltered(data: Dataset, spec: str) -> Dataset:
    """``data`` with its inputs and outputs filtered by the ``[identify] prefilter``: ``"none"``,
    ``"lowpass:F"`` or ``"bandpass:F1,F2"`` (Hz), a 2nd-order Butterworth filter run forwards and backwards
    (zero phase, ``scipy.signal.sosfiltfilt``); the scheduling signals stay as measured. Filtering u and y
    by the same L(q) leaves an LTI relation between them unchanged and weights the equation error of
    ARX by L, which keeps the quantization and sensor noise above F out of the fit (Ljung, *System
    Identification*, 2nd ed., §14.4); for LPV data it is exact only while the scheduling varies slowly
    compared with the filter."""
    if spec == "none":
        return data

    kind, band = parse_prefilter(spec)
    if band[-1] >= 0.5 / data.Ts:
        raise DataError(f"[identify] prefilter = {spec!r}: the frequencies must lie below the Nyquist "
                        f"frequency {0.5 / data.Ts:g} Hz of the data")
    cutoff = band if kind == "bandpass" else band[0]
    sos = scipy.signal.butter(2, cutoff, kind, fs=1.0 / data.Ts, output="sos")
    return replace(data, u=scipy.signal.sosfiltfilt(sos, data.u, axis=0),
                   y=scipy.signal.sosfiltfilt(sos, data.y, axis=0))


def parse_prefilter(spec: str) -> tuple[str, list[float]]:
    """``"lowpass:F"`` → ("lowpass", [F]); ``"bandpass:F1,F2"`` → ("bandpass", [F1, F2])."""
    kind, _, body = spec.partition(":")
    try:
        band = [float(v) for v in body.split(",")]
    except ValueError:
        band = []
    count = {"lowpass": 1, "bandpass": 2}.get(kind)
    if count is None or len(band) != count or not all(np.isfinite(band)) or min(band) <= 0 or (
            count == 2 and band[0] >= band[1]):
        raise DataError(f"[identify] prefilter = {spec!r} must be \"none\", \"lowpass:F\" or "
                        "\"bandpass:F1,F2\" with 0 < F1 < F2 in Hz")
    return kind, band
