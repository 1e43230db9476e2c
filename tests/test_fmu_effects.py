"""Effect parameters, determinism, bad input and the ADIP stabilizing controller, through lpvflow.fmu."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lpvflow.errors import DataError, ModelError
from lpvflow.fmu import open_fmu

ROOT = Path(__file__).resolve().parents[1]
PLANTS = sorted(p.parent.name for p in (ROOT / "fmu_plants").glob("*/modelDescription.xml"))


@pytest.fixture(scope="module")
def fmus() -> dict[str, Path]:
    subprocess.run([sys.executable, str(ROOT / "fmu_plants" / "build.py")], check=True, capture_output=True)
    return {name: ROOT / "fmu_plants" / "build" / f"{name}.fmu" for name in PLANTS}


def _tanks_run(path: Path, parameters: dict, voltages: np.ndarray, dt: float = 0.2) -> tuple[np.ndarray, ...]:
    """Measured lower level and the applied pump voltage for a voltage sequence, from empty tanks."""
    with open_fmu(path, outputs=["lower_level", "diag_applied_pump_voltage"]) as plant:
        plant.set_parameters(parameters)
        out = np.array([plant.step([v], dt) for v in voltages])
    return out[:, 0], out[:, 1]


STEP = np.r_[np.zeros(5), np.full(60, 8.0), np.full(40, 3.0)]


def test_dead_time_shifts_the_response_by_exactly_d_steps(fmus):
    y0, applied0 = _tanks_run(fmus["tanks"], {}, STEP)
    y3, applied3 = _tanks_run(fmus["tanks"], {"effect_input_delay": 0.6}, STEP)  # 0.6 s / 0.2 s = 3 steps
    np.testing.assert_array_equal(applied3[3:], applied0[:-3])
    np.testing.assert_array_equal(y3[3:], y0[:-3])
    np.testing.assert_array_equal(y3[:8], 0.0)


def test_dead_time_rounds_to_whole_communication_steps(fmus):
    _, exact = _tanks_run(fmus["tanks"], {"effect_input_delay": 0.4}, STEP)
    _, rounded = _tanks_run(fmus["tanks"], {"effect_input_delay": 0.43}, STEP)
    np.testing.assert_array_equal(exact, rounded)


def test_dead_zone_removes_inputs_below_the_width_and_shifts_the_rest(fmus):
    voltages = np.r_[np.full(30, 1.9), np.full(30, 6.0)]
    y, applied = _tanks_run(fmus["tanks"], {"effect_deadzone": 2.0}, voltages)
    np.testing.assert_array_equal(applied, np.r_[np.zeros(30), np.full(30, 4.0)])
    np.testing.assert_array_equal(y[:30], 0.0)
    assert y[-1] > 0.0


def test_saturation_clips_the_input(fmus):
    voltages = np.linspace(0.0, 12.0, 50)
    y_sat, applied = _tanks_run(fmus["tanks"], {"effect_saturation": 5.0}, voltages)
    np.testing.assert_array_equal(applied, np.minimum(voltages, 5.0))
    y_clip, _ = _tanks_run(fmus["tanks"], {}, np.minimum(voltages, 5.0))
    np.testing.assert_array_equal(y_sat, y_clip)


def test_sensor_offset_shifts_every_measured_output_by_exactly_the_offset(fmus):
    with open_fmu(fmus["adip"]) as plant:
        plant.set_parameters({"x0_pendulum_angle": 0.01})
        clean = np.array([plant.step([0.5], 0.005) for _ in range(100)])
        plant.set_parameters({"effect_sensor_offset": 0.02})
        shifted = np.array([plant.step([0.5], 0.005) for _ in range(100)])
    np.testing.assert_allclose(shifted - clean, 0.02, rtol=0, atol=1e-15)


def test_noise_is_white_with_the_given_std_and_reproducible_by_seed(fmus):
    voltages = np.full(4000, 8.0)
    clean, _ = _tanks_run(fmus["tanks"], {}, voltages)
    noisy, _ = _tanks_run(fmus["tanks"], {"effect_noise_std": 0.002, "effect_noise_seed": 7}, voltages)
    again, _ = _tanks_run(fmus["tanks"], {"effect_noise_std": 0.002, "effect_noise_seed": 7}, voltages)
    other, _ = _tanks_run(fmus["tanks"], {"effect_noise_std": 0.002, "effect_noise_seed": 8}, voltages)
    noise = noisy - clean
    assert noisy.tobytes() == again.tobytes()
    assert noisy.tobytes() != other.tobytes()
    assert abs(noise.std() / 0.002 - 1) < 0.05
    assert abs(noise.mean()) < 4 * 0.002 / np.sqrt(len(noise))
    assert abs(np.corrcoef(noise[:-1], noise[1:])[0, 1]) < 0.05


@pytest.mark.parametrize("name", PLANTS)
def test_same_inputs_and_seed_give_identical_output_bytes_on_every_plant(fmus, name):
    def run(seed: int) -> bytes:
        with open_fmu(fmus[name]) as plant:
            plant.set_parameters({"effect_noise_std": 1e-3, "effect_noise_seed": seed})
            u0 = np.array([plant.start_value(n) for n in plant.input_names])
            return np.array([plant.step(u0 * (1 + 0.01 * np.sin(k)), 0.01) for k in range(300)]).tobytes()

    assert run(3) == run(3)
    assert run(3) != run(4)


def test_airpath_effects_act_on_the_actuators_but_never_on_the_engine_speed(fmus):
    inputs = np.c_[np.r_[np.full(5, 20.0), np.full(20, 30.0)], np.full(25, 80.0),
                   np.r_[np.full(5, 2000.0), np.full(20, 3000.0)]]
    names = ["diag_applied_throttle_position", "diag_applied_valve_lift", "diag_applied_engine_speed"]
    with open_fmu(fmus["airpath"], outputs=names) as plant:
        plant.set_parameters({"effect_input_delay": 0.03, "effect_deadzone": 1.0, "effect_saturation": 25.0})
        applied = np.array([plant.step(u, 0.01) for u in inputs])
    np.testing.assert_array_equal(applied[:, 2], inputs[:, 2])  # speed: no delay, no dead zone, no clip
    np.testing.assert_array_equal(applied[3:, 0], np.minimum(inputs[:-3, 0] - 1.0, 25.0))
    np.testing.assert_array_equal(applied[:, 1], 25.0)  # 80 % lift: dead zone to 79 %, clipped to 25 %


def test_coulomb_friction_opposes_the_arm_motion(fmus):
    with open_fmu(fmus["adip"], outputs=["diag_der_arm_rate"]) as plant:
        plant.set_parameters({"x0_arm_rate": 1.0})
        free = plant.reset()[0]
        plant.set_parameters({"effect_coulomb": 0.05})
        braked = plant.reset()[0]
        plant.set_parameters({"x0_arm_rate": -1.0})
        braked_reverse = plant.reset()[0]
        plant.set_parameters({"effect_coulomb": 0.0})
        free_reverse = plant.reset()[0]
    assert braked < free
    assert braked_reverse > free_reverse
    np.testing.assert_allclose(free - braked, braked_reverse - free_reverse, rtol=1e-12)


@pytest.mark.parametrize("name", PLANTS)
@pytest.mark.parametrize(("parameter", "value"), [("effect_deadzone", -1.0), ("effect_saturation", -0.5),
                                                  ("effect_noise_std", -0.1), ("effect_input_delay", -0.01),
                                                  ("effect_noise_seed", -3)])
def test_out_of_range_effect_values_give_one_clear_line(fmus, name, parameter, value):
    with open_fmu(fmus[name]) as plant, pytest.raises(DataError) as error:
        plant.set_parameters({parameter: value})
    message = str(error.value)
    assert "\n" not in message
    assert parameter in message and "out of range" in message


def test_rejected_parameter_is_dropped_and_the_plant_stays_usable(fmus):
    with open_fmu(fmus["tanks"]) as plant:
        with pytest.raises(DataError):
            plant.set_parameters({"effect_deadzone": -1.0})
        assert plant.step([8.0], 0.2)[0] > 0.0


def test_unknown_path_missing_name_and_bad_step_give_one_clear_line(fmus, tmp_path):
    with pytest.raises(DataError, match="FMU file not found"):
        open_fmu(tmp_path / "nope.fmu")
    (tmp_path / "broken.fmu").write_text("not a zip")
    with pytest.raises(ModelError, match="not a readable FMU"):
        open_fmu(tmp_path / "broken.fmu")
    with open_fmu(fmus["tanks"]) as plant:
        with pytest.raises(DataError, match="unknown parameter 'pump_gian'"):
            plant.set_parameters({"pump_gian": 1.0})
        with pytest.raises(DataError, match="must be > 0"):
            plant.step([1.0], 0.0)
        with pytest.raises(DataError, match="must be > 0"):
            plant.step([1.0], -0.2)
        with pytest.raises(DataError, match="inputs must be exactly pump_voltage"):
            plant.step({"voltage": 1.0}, 0.2)
    with pytest.raises(DataError, match="unknown output 'level'"):
        open_fmu(fmus["tanks"], outputs=["level"])


def test_dead_time_refuses_a_changing_communication_step(fmus):
    with open_fmu(fmus["tanks"]) as plant:
        plant.set_parameters({"effect_input_delay": 0.4})
        plant.step([1.0], 0.2)
        with pytest.raises(DataError, match="constant communication step"):
            plant.step([1.0], 0.1)


def test_adip_stabilizing_controller_returns_the_pendulum_upright(fmus):
    spec = json.loads((ROOT / "fmu_plants" / "adip" / "stabilizing_controller.json").read_text())
    assert spec["format"] == "lpvflow/lti-controller" and spec["version"] == 1
    a, b, c, d = (np.array(spec[k]) for k in "ABCD")
    y_op, u_op = np.array(spec["y_operating_point"]), np.array(spec["u_operating_point"])
    with open_fmu(fmus["adip"], outputs=spec["inputs"]) as plant:
        assert list(plant.input_names) == spec["outputs"]
        plant.set_parameters({"x0_pendulum_angle": 0.02, "effect_saturation": 10.0})
        y, xc, trace, voltages = plant.reset(), np.zeros(len(a)), [], []
        for _ in range(int(3.0 / spec["Ts"])):
            e = y - y_op
            u = u_op + c @ xc + d @ e
            xc = a @ xc + b @ e
            y = plant.step(u, spec["Ts"])
            trace.append(y)
            voltages.append(u[0])
    trace = np.array(trace)
    assert np.max(np.abs(trace)) < 0.2  # bounded: arm and pendulum stay within ~11 degrees
    assert np.max(np.abs(trace[-100:])) < 1e-3  # back at the upright equilibrium after 3 s
    assert np.max(np.abs(voltages)) < 10.0  # within the amplifier limit
