"""Closed-loop two-step identification (thesis §3.4, Algorithm 3.2; notes_002 §2.4)."""

from pathlib import Path

import numpy as np
import pytest

from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.identify.arx import identify_arx
from lpvflow.identify.two_step import identify_two_step, laguerre_bank, reconstruct_noise_free
from lpvflow.validate.metrics import frozen_response_error

pytestmark = pytest.mark.filterwarnings("ignore::lpvflow.basis.SchedulingRangeWarning")
ROOT = Path(__file__).resolve().parents[1]
ADIP_FMU = ROOT / "fmu_plants" / "build" / "adip.fmu"
ADIP_CONTROLLER = ROOT / "fmu_plants" / "adip" / "stabilizing_controller.json"


def test_laguerre_bank_is_orthonormal_for_white_input():
    """Laguerre filters are orthonormal: driven by white noise their outputs are uncorrelated, unit gain."""
    r = np.random.default_rng(0).normal(size=(200_000, 1))
    X = laguerre_bank(r, 0.7, 4)[1000:]
    np.testing.assert_allclose(X.T @ X / len(X), np.eye(4), atol=0.02)


def test_step_one_removes_noise_from_a_nonlinear_fading_memory_signal():
    rng = np.random.default_rng(1)
    r = rng.normal(size=4000)
    clean = np.tanh(np.convolve(r, 0.8 ** np.arange(30))[: len(r)] / 2)
    noise = 0.2 * rng.normal(size=len(r))
    rebuilt = reconstruct_noise_free(r, clean + noise, pole=0.8, n_filters=8, hidden=(10,))
    assert np.std(rebuilt[:, 0] - clean) < 0.25 * np.std(noise)


@pytest.mark.parametrize(
    "excitation, kwargs, message",
    [(np.ones(300), {}, "constant"), (np.arange(299.0), {}, "samples"),
     (np.arange(300.0), {"pole": 1.0}, "pole"), (np.arange(300.0), {"signals": "x"}, "signals")],
)
def test_bad_step_one_input_raises_data_error(excitation, kwargs, message):
    rng = np.random.default_rng(2)
    data = Dataset(rng.normal(size=300), rng.normal(size=300), rng.uniform(size=300), 1.0)
    with pytest.raises(DataError, match=message):
        identify_two_step(data, excitation, 1, 1, 1, "affine", **kwargs)


def adip_closed_loop(noise: float, seed: int = 1, duration: float = 120.0, every: int = 4
                     ) -> tuple[Dataset, np.ndarray]:
    """ADIP in closed loop with its stabilizing controller, multisine excitation added to the voltage;
    every 4th sample kept (Ts = 20 ms; the signals are band-limited to 5 Hz)."""
    from lpvflow.experiment import run_fmu_experiment

    rec = run_fmu_experiment(ADIP_FMU, None, duration, controller=ADIP_CONTROLLER,
                             excitation={"voltage": "multisine:f_lo=0.05,f_hi=5,rms=1.5"},
                             parameters={"effect_noise_std": noise}, seed=seed, progress=False)
    c = {name: values[::every] for name, values in rec.columns.items()}
    y = np.column_stack([c["arm_angle"], c["pendulum_angle"]])
    data = Dataset(c["voltage"], y, c["sin_arm"], rec.Ts * every,
                   ["voltage"], ["arm", "pendulum"], ["sin_arm"])
    return data, c["voltage_excitation"]


@pytest.mark.skipif(not ADIP_FMU.exists(), reason="adip FMU not built (make fmus)")
def test_two_step_removes_the_closed_loop_bias_of_direct_identification_on_adip():
    """Closed-loop ADIP, 3 mrad measurement noise on both angles (fed back by the controller: the
    voltage differs by ~1.2 V rms from the noise-free run). The reference is the same LPR-ARX (na = nb
    = 2, poly:2 in sin φ1) fitted to the noise-free run with the same excitation."""
    clean, r = adip_closed_loop(0.0)
    noisy, r_noisy = adip_closed_loop(0.003)
    np.testing.assert_array_equal(r, r_noisy)
    reference = identify_arx(clean, 2, 2, 1, "poly:2")
    direct = frozen_response_error(identify_arx(noisy, 2, 2, 1, "poly:2"), reference)
    two_step = frozen_response_error(identify_two_step(noisy, r, 2, 2, 1, "poly:2"), reference)
    assert direct > 0.5  # the bias to remove: direct LS is far from the noise-free fit
    assert two_step < 0.25 * direct, (two_step, direct)
