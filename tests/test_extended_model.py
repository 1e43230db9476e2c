"""The extended model `lpvflow diagnose` saves runs: `lpvflow simulate` on it reproduces the diagnosed
validation BFR for every kind of extension the diagnosis names on the synthetic bench, and it
refuses data without the columns its map needs."""

from __future__ import annotations

import dataclasses
import json
import warnings

import numpy as np
import pytest

from lpvflow import load
from lpvflow.basis import SchedulingRangeWarning
from lpvflow.data import Dataset
from lpvflow.errors import ModelError
from lpvflow.pipeline.cli import main
from lpvflow.validate.extended_model import ExtendedModel
from tests.diagnosis_cases import make_case, simulate_plant

#: Effect (make_case) → (cause the diagnosis names, kind of the saved map or None, make_case options).
BENCH = {
    "input_nonlinearity": ("input_nonlinearity", "dead_zone", {}),
    "backlash": ("backlash", "backlash", {}),
    "sensor_saturation": ("sensor_saturation", "sensor_clip", {}),
    "friction": ("friction", "friction", {}),
    "friction_velocity": ("friction", "friction", {}),
    "offset": ("offset", "sensor_offset", {}),
    "input_delay": ("input_delay", None, {}),
    "model_order": ("model_order", None, {}),
    "scheduling_dependence": ("scheduling_dependence", None, {}),
    "scheduling_variable": ("scheduling_variable", None, {}),
    "sensor_noise": ("output_noise_bias", None, {"seed": 17, "snr_db": 10, "n": 4000}),
    "ar2_noise": ("colored_noise", None, {"seed": 39, "snr_db": 3, "n": 4000}),
}


def plant_input_case(effect: str, seed: int) -> tuple[Dataset, dict]:
    """The base plant driven by a saturated input (limit 0.5) or by the input plus a constant 0.3
    (an equation constant), the recorded input unmapped; 1 % white output noise."""
    base, channels, _ = make_case("none", seed=seed, n=2000)
    u, p = base.u[:, 0], base.p[:, 0]
    drive = np.clip(u, -0.5, 0.5) if effect == "saturation" else u + 0.3
    y = simulate_plant(drive, p)
    y = y + 0.01 * np.std(y) * np.random.default_rng(seed).standard_normal(len(y))
    return Dataset(u[:, None], y[:, None], p[:, None], 0.01, ["u"], ["y"], ["p"]), channels


def write_csv(path, data: Dataset, channels: dict) -> None:
    columns = [np.arange(data.N) * data.Ts, data.u[:, 0], data.y[:, 0], data.p[:, 0], *channels.values()]
    header = ",".join(["time", "u", "y", "p", *channels])
    np.savetxt(path, np.column_stack(columns), delimiter=",", header=header, comments="")


def diagnose_then_simulate(tmp_path, data: Dataset, channels: dict, *options: str
                           ) -> tuple[dict, ExtendedModel, dict]:
    """CLI diagnose (with ``options``) → the saved extended model → CLI simulate --json on the same
    record."""
    csv = tmp_path / "d.csv"
    write_csv(csv, data, channels)
    report_path = tmp_path / "diag.json"
    assert main(["diagnose", str(csv), "--u", "u", "--y", "y", "--p", "p", "--na", "2", "--nb", "2",
                 "--nk", "1", "--json", str(report_path), *options]) == 0
    report = json.loads(report_path.read_text())
    extended = load(report["extended_model"])
    assert isinstance(extended, ExtendedModel)
    sim_path = tmp_path / "sim.json"
    assert main(["simulate", report["extended_model"], str(csv), "--u", "u", "--y", "y",
                 "--p", *extended.p_names, "--json", str(sim_path)]) == 0
    return report, extended, json.loads(sim_path.read_text())


def check_reproduced(report: dict, extended: ExtendedModel, simulated: dict, cause: str, kind: str | None):
    assert report["cause"] == cause, report["ranking"]
    assert (extended.map.kind if extended.map else None) == kind
    assert extended.validation_start == simulated["validation"]["start"]
    assert simulated["validation"]["bfr"] == pytest.approx(report["bfr_after"], abs=0.1)
    assert report["bfr_after"][0] > report["bfr_before"][0] + 1.0  # the extension mattered


@pytest.mark.parametrize("effect", sorted(BENCH))
def test_simulate_reproduces_the_diagnosed_bfr(tmp_path, effect):
    cause, kind, options = BENCH[effect]
    data, channels, _ = make_case(effect, **({"seed": 11, "n": 2000} | options))
    check_reproduced(*diagnose_then_simulate(tmp_path, data, channels), cause, kind)


@pytest.mark.parametrize("effect, kind", [("saturation", "saturation"), ("bias", "offset_inputs")])
def test_plant_input_maps_reproduce_the_diagnosed_bfr(tmp_path, effect, kind):
    seed = int(np.random.default_rng(35).integers(100, 10_000))
    data, channels = plant_input_case(effect, seed)
    cause = "input_nonlinearity" if effect == "saturation" else "offset"
    check_reproduced(*diagnose_then_simulate(tmp_path, data, channels), cause, kind)


def test_a_model_diagnosed_without_offsets_runs_on_the_recorded_signals(tmp_path):
    """--remove-offsets: the saved model takes the recorded (offset) input and output columns."""
    data, channels, _ = make_case("input_nonlinearity", seed=11, n=2000)
    recorded = dataclasses.replace(data, u=data.u + 1.5, y=data.y + 20.0)
    report, extended, simulated = diagnose_then_simulate(tmp_path, recorded, channels, "--remove-offsets")
    check_reproduced(report, extended, simulated, "input_nonlinearity", "dead_zone")
    assert extended.offsets["y"][0] == pytest.approx(20.0 + data.y.mean())
    assert simulated["bfr"][0] > 90  # the whole record, in the recorded units


def test_without_the_map_the_fit_is_lost(tmp_path):
    """The saved saturation matters: the same model without its map simulates worse."""
    data, channels = plant_input_case("saturation", seed=7)
    report, extended, _ = diagnose_then_simulate(tmp_path, data, channels)
    start = extended.validation_start
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SchedulingRangeWarning)
        bare = extended.model.simulate(data.u, data.p)[start:]
    error = np.linalg.norm(data.y[start:] - bare) / np.linalg.norm(data.y[start:] - data.y[start:].mean())
    assert 100 * (1 - error) < report["bfr_after"][0] - 5


def test_data_without_the_maps_column_is_refused(tmp_path, capsys):
    data, channels, _ = make_case("input_nonlinearity", seed=11, n=2000)
    report, _, _ = diagnose_then_simulate(tmp_path, data, channels)
    capsys.readouterr()
    out = tmp_path / "again.json"
    status = main(["simulate", report["extended_model"], str(tmp_path / "d.csv"), "--u", "q", "--y", "y",
                   "--p", "p", "--json", str(out)])
    err = capsys.readouterr().err.strip()
    assert status == 2 and len(err.splitlines()) == 1
    assert "['u']" in err and "--u u" in err
    assert not out.exists()


def test_a_scheduling_channel_model_needs_that_channel(tmp_path, capsys):
    data, channels, _ = make_case("scheduling_variable", seed=11, n=2000)
    report, extended, _ = diagnose_then_simulate(tmp_path, data, channels)
    assert extended.p_names == ["p", "q"]
    capsys.readouterr()
    status = main(["simulate", report["extended_model"], str(tmp_path / "d.csv"), "--u", "u", "--y", "y",
                   "--p", "p"])
    err = capsys.readouterr().err.strip()
    assert status == 2 and len(err.splitlines()) == 1 and "--p p q" in err


def test_an_unknown_map_or_version_is_refused(tmp_path):
    data, channels, _ = make_case("backlash", seed=11, n=2000)
    report, _, _ = diagnose_then_simulate(tmp_path, data, channels)
    document = json.loads(open(report["extended_model"]).read())
    for change in ({"map": {"kind": "gremlin"}}, {"version": 99}):
        path = tmp_path / "changed.json"
        path.write_text(json.dumps(document | change))
        with pytest.raises(ModelError):
            load(path)
