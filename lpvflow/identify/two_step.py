"""Closed-loop two-step LPV identification (thesis §3.4, Algorithm 3.2).

In closed loop (thesis Fig. 3.2) the measured input ũ and the scheduling θ̃ = f(ỹ) carry the
measurement noise fed back by the controller, so least squares on them is biased. Every signal of
a stable closed loop is, apart from noise, a (nonlinear, fading-memory) function of the external
excitation r alone. The method therefore

1. fits, for each measured signal s ∈ {u, y, p}, a model ŝ(k) = g(r(k), r(k−1), …) and takes ŝ as
   the noise-free signal;
2. identifies the LPV-ARX (:func:`identify_arx`, or spline SLS) on the reconstructed signals.

Step-1 model [our documented alternative to the thesis's NNARX]: a Wiener-type nonlinear FIR
model, a Laguerre filter bank on r followed by a small neural network (scikit-learn
``MLPRegressor``, one tanh hidden layer):

    x_1 = √(1−a²)/(1 − a q⁻¹) r,   x_{i+1} = (q⁻¹ − a)/(1 − a q⁻¹) x_i,   ŝ(k) = MLP(x(k)).

It works in *simulation mode* by construction: ŝ depends on past excitation only, never on
measured (noisy) samples, which is what removes the noise (one-step NNARX
predictions still contain past noisy values). Training it is a static regression, so no
recurrent training is needed; fading-memory operators are uniformly approximated by such filter
banks followed by a static nonlinearity (Boyd & Chua 1985). The output y is reconstructed too:
with measurement noise on y, lagged noisy outputs in the ARX regressor are the second bias source
(the thesis reconstructs ỹ for the scheduling, Fig. 3.4). The filter pole a, the number of
filters and the hidden-layer size are the tuning (thesis: "limit the number of hidden neurons").
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import scipy.signal
from sklearn.exceptions import ConvergenceWarning
from sklearn.neural_network import MLPRegressor

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.identify.arx import identify_arx
from lpvflow.identify.spline_sls import free_knot_count, identify_spline_sls
from lpvflow.lpvio import LPVIO


def laguerre_bank(r: np.ndarray, pole: float, n_filters: int) -> np.ndarray:
    """Outputs (N, n_r·n_filters) of the discrete Laguerre filters (module docstring) driven by r (N, n_r)."""
    if not 0 <= pole < 1:
        raise DataError(f"Laguerre pole must be in [0, 1), got {pole}")
    if int(n_filters) != n_filters or n_filters < 1:
        raise DataError(f"n_filters must be a whole number >= 1, got {n_filters}")
    r = np.asarray(r, dtype=float).reshape(len(r), -1)
    out = np.empty((len(r), r.shape[1] * int(n_filters)))
    x = scipy.signal.lfilter([np.sqrt(1 - pole**2)], [1.0, -pole], r, axis=0)
    for i in range(int(n_filters)):
        out[:, i * r.shape[1] : (i + 1) * r.shape[1]] = x
        x = scipy.signal.lfilter([-pole, 1.0], [1.0, -pole], x, axis=0)
    return out


def reconstruct_noise_free(
    excitation: np.ndarray, targets: np.ndarray, pole: float = 0.9, n_filters: int = 16,
    hidden: tuple[int, ...] = (20,), alpha: float = 1e-3, seed: int = 0, max_iter: int = 500,
) -> np.ndarray:
    """Step 1: fit ŝ = MLP(Laguerre(r)) to the measured ``targets`` (N, n_s) and return ŝ (N, n_s).

    Features and targets are standardised on the data; the network is trained by L-BFGS on the
    squared error with L2 weight ``alpha``; ``seed`` fixes its initial weights.
    """
    r = np.asarray(excitation, dtype=float).reshape(len(excitation), -1)
    targets = np.asarray(targets, dtype=float).reshape(len(targets), -1)
    if len(r) != len(targets):
        raise DataError(f"the excitation has {len(r)} samples but the data has {len(targets)}")
    if not np.all(np.isfinite(r)):
        raise DataError("the excitation contains NaN or inf: remove or interpolate those samples")
    if not np.all(r.std(axis=0) > 0):
        raise DataError("the excitation is constant: step 1 needs the external excitation signal r")
    X = laguerre_bank(r, pole, n_filters)
    mx, sx = X.mean(axis=0), np.where(X.std(axis=0) > 0, X.std(axis=0), 1.0)
    mt, st = targets.mean(axis=0), np.where(targets.std(axis=0) > 0, targets.std(axis=0), 1.0)
    net = MLPRegressor(hidden_layer_sizes=tuple(hidden), activation="tanh", solver="lbfgs", alpha=alpha,
                       max_iter=max_iter, random_state=seed)
    with warnings.catch_warnings():  # hitting max_iter is a regularisation choice, not a failure
        warnings.simplefilter("ignore", ConvergenceWarning)
        scaled = (targets - mt) / st
        net.fit((X - mx) / sx, scaled[:, 0] if scaled.shape[1] == 1 else scaled)
    return net.predict((X - mx) / sx).reshape(len(r), -1) * st + mt


def reconstruct_dataset(data: Dataset, excitation: np.ndarray, signals: str = "uyp", **step1) -> Dataset:
    """``data`` with the chosen signal groups (of ``u``, ``y``, ``p``) replaced by step-1 reconstructions."""
    unknown = set(signals) - set("uyp")
    if unknown or not signals:
        raise DataError(f"signals must be a combination of 'u', 'y', 'p', got {signals!r}")
    groups = [s for s in "uyp" if s in signals]
    targets = np.column_stack([getattr(data, s) for s in groups])
    rebuilt = reconstruct_noise_free(excitation, targets, **step1)
    widths = np.cumsum([0] + [getattr(data, s).shape[1] for s in groups])
    return replace(data, **{s: rebuilt[:, widths[i] : widths[i + 1]] for i, s in enumerate(groups)})


def identify_two_step(
    data: Dataset, excitation: np.ndarray, na, nb, nk, basis: Basis | str = "affine", form: str = "shifted",
    signals: str = "uyp", pole: float = 0.9, n_filters: int = 16, hidden: tuple[int, ...] = (20,),
    alpha: float = 1e-3, seed: int = 0, starts: int = 5,
) -> LPVIO:
    """Two-step closed-loop LPV-ARX: step 1 :func:`reconstruct_dataset`, step 2 LS on the result.

    ``basis`` as in :func:`identify_arx`, or ``spline:free:K`` for K estimated knots per scheduling
    signal (:func:`identify_spline_sls` with ``starts``).
    """
    rebuilt = reconstruct_dataset(data, excitation, signals, pole=pole, n_filters=n_filters, hidden=hidden,
                                  alpha=alpha, seed=seed)
    n_knots = free_knot_count(basis) if isinstance(basis, str) else None
    if n_knots is not None:
        return identify_spline_sls(rebuilt, na, nb, nk, n_knots, form=form, starts=starts, seed=seed)
    return identify_arx(rebuilt, na, nb, nk, basis, form=form)
