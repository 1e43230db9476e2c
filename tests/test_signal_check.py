"""`lpvflow design` checks every table's signal names against the plant FMU and the experiment record
before it writes anything (lpvflow.pipeline.signal_check)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from lpvflow.errors import DataError
from lpvflow.pipeline.cli import main
from lpvflow.pipeline.config import bundled_config, load_config

ROOT = Path(__file__).resolve().parents[1]
ADIP = bundled_config("adip").read_text()


def _design(tmp_path: Path, text: str) -> Path:
    """The bundled ADIP design with absolute input paths and its output inside ``tmp_path``."""
    text = text.replace('plant = "fmu_plants/', f'plant = "{ROOT}/fmu_plants/')
    text = text.replace('controller = "fmu_plants/', f'controller = "{ROOT}/fmu_plants/')
    text = text.replace('[design]\n', f'[design]\noutput_dir = "{tmp_path / "out"}"\n', 1)
    path = tmp_path / "design.toml"
    path.write_text(text)
    return path


def _swap(old: str, new: str):
    def edit(text: str) -> str:
        assert old in text, old
        return text.replace(old, new, 1)
    return edit


#: (edit of the bundled ADIP design, words the one-line message must contain)
MISTAKES = [
    (_swap('u = ["voltage"]', 'u = ["volts"]'), "[identify] u: 'volts'"),
    (_swap('p = ["sin_arm", "inv_det", "cos_inv_det"]', 'p = ["sin_arm", "inv_det", "cos_arm"]'),
     "[identify] p: 'cos_arm'"),
    (_swap('f_lo=0.1,f_hi=5,rms=0.5', 'f_lo=0.1,rms=0.5'), "multisine needs f_hi"),
    (_swap('setpoint = { arm_angle', 'setpoint = { arm_angel'), "[experiment] setpoint: 'arm_angel'"),
    (_swap('noise = { arm_angle = 1e-4', 'noise = { arm = 1e-4'), "[experiment] noise: 'arm'"),
    (_swap('output_bounds = { pendulum_angle', 'output_bounds = { pendulum'),
     "[experiment] output_bounds: 'pendulum'"),
    (_swap('sin_arm = "sin(arm_angle)"', 'sin_arm = "sin(arm_angel)"'), "[experiment] scheduling.sin_arm"),
    (_swap('increments = ["arm_angle"]', 'increments = ["voltage"]'), "[identify] increments: 'voltage'"),
    (_swap('measured = ["arm_angle", "pendulum_angle"]', 'measured = ["pendulum_angle", "arm_angle"]'),
     "[verify.loop] measured"),
    (_swap('actuator_limits = { voltage', 'actuator_limits = { volts'), "[verify.loop] actuator_limits"),
    (_swap('actuated = ["voltage"]\n', 'actuated = ["voltage"]\nscheduling = ["sin(arm_angle)", "0", "0"]\n'),
     "[verify.loop] scheduling computes inv_det"),
    (_swap('reference = { arm_angle = { steps = [[0.5, 0.5236]] } }',
           'reference = { pendulum = { steps = [[0.5, 0.5236]] } }'), "reference: 'pendulum'"),
]


@pytest.mark.parametrize(("edit", "words"), MISTAKES)
def test_a_wrong_signal_name_is_one_line_before_anything_runs(tmp_path, capsys, edit, words):
    path = _design(tmp_path, edit(ADIP))
    with pytest.raises(DataError, match=re.escape(words)):
        load_config(path)
    assert main(["design", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err and words in err
    assert not (tmp_path / "out").exists()  # no design folder, no lock, no experiment


def test_random_unknown_columns_are_refused_in_every_column_list(tmp_path):
    """A random column name the experiment does not record, put in a random [identify] list, is named."""
    rng = np.random.default_rng(7)
    lists = {"u": 'u = ["voltage"]', "y": 'y = ["arm_angle", "pendulum_angle"]',
             "p": 'p = ["sin_arm", "inv_det", "cos_inv_det"]'}
    for _ in range(6):
        key = str(rng.choice(list(lists)))
        name = "col_" + "".join(rng.choice(list("abcdefghij"), size=5))
        line = lists[key]
        path = _design(tmp_path, ADIP.replace(line, line[:-1] + f', "{name}"]', 1))
        with pytest.raises(DataError, match=re.escape(f"[identify] {key}: '{name}'")):
            load_config(path)


def test_the_loop_scheduling_is_taken_from_the_experiment_when_left_out(tmp_path):
    config = load_config(_design(tmp_path, ADIP))
    assert config["verify"]["loop"].scheduling == (
        "sin(arm_angle)", "1/(1 - 0.3785*cos(arm_angle)**2)", "cos(arm_angle)/(1 - 0.3785*cos(arm_angle)**2)")


# ------------------------------------------------------------------ scheduling values of one plant signal
KAPPA = 0.3785  # the bundled ADIP's κ (its [experiment] scheduling)


def _adip_images(angle: np.ndarray) -> np.ndarray:
    det = 1 - KAPPA * np.cos(angle) ** 2
    return np.column_stack([np.sin(angle), 1 / det, np.cos(angle) / det])


def test_points_given_as_arm_angles_are_the_scheduling_images(tmp_path):
    """[validate] points, [synth] breakpoints, baseline_at and box given as random arm angles (degrees)
    become the rows (sin φ, 1/(1 − κ cos² φ), cos φ/(1 − κ cos² φ)) of the experiment's expressions."""
    rng = np.random.default_rng(11)
    angles = np.sort(rng.uniform(-80, 80, 7))
    lo, hi = np.sort(rng.uniform(-85, 85, 2))
    text = re.sub(r"^points = .*$", f'points = {{ signal = "arm_angle", range = [{lo}, {hi}], count = 5, '
                  'unit = "deg" }', ADIP, flags=re.M)
    text = re.sub(r"^breakpoints = .*$", 'breakpoints = { signal = "arm_angle", unit = "deg", values = '
                  f'[{", ".join(map(str, angles))}] }}', text, flags=re.M)
    text = re.sub(r"^baseline_at = .*$", f'baseline_at = {{ signal = "arm_angle", values = [{angles[3]}], '
                  'unit = "deg" }', text, flags=re.M)
    text = re.sub(r"^box = .*$", f'box = {{ signal = "arm_angle", range = [{lo}, {hi}], unit = "deg" }}',
                  text, flags=re.M)
    config = load_config(_design(tmp_path, text))
    np.testing.assert_allclose(config["validate"]["points"],
                               _adip_images(np.radians(np.linspace(lo, hi, 5))), rtol=1e-12)
    np.testing.assert_allclose(config["synth"]["breakpoints"], _adip_images(np.radians(angles)), rtol=1e-12)
    np.testing.assert_allclose(config["synth"]["baseline_at"], _adip_images(np.radians(angles[3:4]))[0])
    dense = _adip_images(np.radians(np.linspace(lo, hi, 100_001)))
    np.testing.assert_allclose(config["synth"]["box"], np.column_stack([dense.min(0), dense.max(0)]),
                               atol=1e-6)


@pytest.mark.parametrize(("value", "words"), [
    ('{ signal = "arm_angle", range = [-75, 75], unit = "grad" }', 'unit = \'grad\' must be "rad" or "deg"'),
    ('{ signal = "arm_angle", range = [-75, 75] }', "a range needs count = N ≥ 2"),
    ('{ signal = "arm_angle", range = [75, -75], count = 3 }', "must be [lo, hi] with lo < hi"),
    ('{ signal = "pendulum_angle", values = [0.1] }', "is not a function of pendulum_angle alone"),
])
def test_a_bad_scheduling_value_table_is_one_line(tmp_path, capsys, value, words):
    path = _design(tmp_path, re.sub(r"^points = .*$", f"points = {value}", ADIP, flags=re.M))
    assert main(["design", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err and "[validate] points" in err
    assert not (tmp_path / "out").exists()
