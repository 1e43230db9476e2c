"""BFR, VAF and MSE exactly as thesis (3.31)–(3.33) (notes_002 §0)."""

import numpy as np
import pytest

from lpvflow.errors import DataError
from lpvflow.validate.metrics import bfr, fit_report, mse, vaf


def test_metrics_by_hand():
    y = np.array([1.0, 2.0, 3.0, 6.0])
    y_hat = np.array([1.0, 2.5, 3.0, 5.0])
    # ȳ = 3; ‖y−ȳ‖ = √(4+1+0+9) = √14; ‖y−ŷ‖ = √(0.25+1) = √1.25
    assert bfr(y, y_hat)[0] == pytest.approx(100 * (1 - np.sqrt(1.25 / 14)))
    # var(y) = 14/4 = 3.5; e = [0, −0.5, 0, 1], mean 0.125, var = (0.015625+0.390625+0.015625+0.765625)/4
    assert vaf(y, y_hat)[0] == pytest.approx(100 * (1 - 0.296875 / 3.5))
    assert mse(y, y_hat)[0] == pytest.approx(1.25 / 8)  # 1/(2N) Σ e²


def test_metrics_are_clipped_at_zero_and_per_output():
    y = np.column_stack([np.arange(10.0), np.sin(np.arange(10.0))])
    wild = -10 * y
    assert np.all(bfr(y, wild) == 0) and np.all(vaf(y, wild) == 0)
    report = fit_report(y, y, ["a", "b"])
    assert report["outputs"] == ["a", "b"] and report["bfr"] == [100.0, 100.0]


def test_shape_mismatch_is_a_data_error():
    with pytest.raises(DataError, match="differ in shape"):
        bfr(np.zeros((5, 2)), np.zeros((5, 1)))
