"""Diagnosis in the loop of a gain-scheduled (gridded) controller with its trim and the record's means
removed (lpvflow.validate.closed_loop.Loop): the maglev example's identification set-up."""

from __future__ import annotations

import numpy as np
import pytest

from lpvflow.data import Dataset
from lpvflow.experiment.loader import load_experiment_controller
from lpvflow.experiment.plant import open_plant
from lpvflow.experiment.run import run_experiment
from lpvflow.validate.closed_loop import Loop, loop_signals
from tests.diagnosis_fmu_cases import BUILD, MAGLEV_CONTROLLER, MAGLEV_SCHEDULING

INPUTS = ["lower_coil_current", "upper_coil_current"]
OUTPUTS = ["lower_disk_position", "upper_disk_position"]


def _record(seed: int) -> dict[str, np.ndarray]:
    """4 s of the maglev under its scheduled controller: a random set-point ramp, random excitation."""
    rng = np.random.default_rng(seed)
    plant = open_plant(BUILD / "maglev.fmu", {"x0_lower_disk_position": 0.015,
                                              "x0_upper_disk_position": 0.08})
    rms, amplitude = rng.uniform(0.01, 0.03), rng.uniform(0.002, 0.006)
    try:
        record = run_experiment(
            plant, 0.002, 4.0, None, load_experiment_controller(MAGLEV_CONTROLLER),
            {name: f"multisine:f_lo=0.5,f_hi=20,rms={rms:.4f},phases=random" for name in INPUTS},
            MAGLEV_SCHEDULING, seed, progress=False,
            setpoint={"upper_disk_position": f"triangle:amp={amplitude:.4f},period=4,offset=0.08"},
            noise={name: 2e-6 for name in OUTPUTS})
    finally:
        plant.close()
    return record.columns


@pytest.mark.parametrize("seed", range(2))
def test_the_excitation_of_a_trimmed_gridded_loop_is_the_recorded_one(seed):
    """Model inputs u − u_op(θ) less their mean, outputs less theirs: the controller, run on the outputs
    plus their means and the recorded set-points with its trim taken off, leaves r = the recorded
    excitation less the input mean; the record's own outputs give back its inputs and its scheduling."""
    c = _record(seed)
    K = load_experiment_controller(MAGLEV_CONTROLLER)
    n = len(c["time"])
    u = np.column_stack([c[name] for name in INPUTS]) - K.trim_along(c, n)
    data = Dataset(u, np.column_stack([c[name] for name in OUTPUTS]), c["upper_disk_position"], 0.002, INPUTS,
                   OUTPUTS, ["y2"]).remove_offsets()
    setpoints = np.column_stack([np.full(n, np.nan), c["upper_disk_position_setpoint"]])
    loop = Loop.from_record(data, K, MAGLEV_SCHEDULING, setpoints, trim_removed=True)
    excitation = np.column_stack([c[f"{name}_excitation"] for name in INPUTS])
    np.testing.assert_allclose(loop.excitation, excitation - data.offsets["u"], rtol=0, atol=1e-12)
    u_loop, p_loop = loop_signals(data.y, data, loop)
    np.testing.assert_allclose(u_loop, data.u, rtol=0, atol=1e-12)
    np.testing.assert_allclose(p_loop, data.p, rtol=0, atol=1e-15)
    # without the trim removed, or without the set-points, the recovered r is not the excitation
    for wrong in (Loop.from_record(data, K, MAGLEV_SCHEDULING, setpoints),
                  Loop.from_record(data, K, MAGLEV_SCHEDULING, None, trim_removed=True)):
        assert np.max(np.abs(wrong.excitation - loop.excitation)) > 1e-3


@pytest.mark.parametrize("seed", range(3))
def test_a_gridded_laws_output_is_its_next_command_without_advancing_it(seed):
    """The feedthrough passes of a model with a lag-0 term ask the law for u(k) without stepping it."""
    rng = np.random.default_rng(300 + seed)
    law = load_experiment_controller(MAGLEV_CONTROLLER).loop_law()
    law.reset()
    for _ in range(int(rng.integers(1, 20))):
        law.step(np.array([np.nan, 0.08]), np.array([0.015, 0.08]) + 1e-3 * rng.standard_normal(2),
                 np.array([rng.uniform(0.07, 0.09)]))
    r = np.array([np.nan, rng.uniform(0.075, 0.085)])
    y, p = np.array([0.015, 0.08]) + 1e-3 * rng.standard_normal(2), np.array([rng.uniform(0.07, 0.09)])
    first, again = law.output(r, y, p), law.output(r, y, p)
    np.testing.assert_array_equal(first, again)
    np.testing.assert_allclose(law.step(r, y, p), first, rtol=1e-13, atol=1e-13)


def test_the_cli_diagnoses_in_the_gridded_loop_with_trim_and_offsets_removed(tmp_path):
    """`diagnose --controller GRIDDED --remove-trim --remove-offsets` on an experiment's CSV (set-point
    columns included) scores the nominal model exactly as diagnose() does on the record made by hand."""
    import json

    from lpvflow.pipeline.cli import main
    from lpvflow.validate.diagnose import diagnose
    from lpvflow.validate.extensions import Structure

    c = _record(2)
    csv, report = tmp_path / "d.csv", tmp_path / "r.json"
    names = list(c)
    np.savetxt(csv, np.column_stack([c[name] for name in names]), delimiter=",", header=",".join(names),
               comments="")
    assert main(["diagnose", str(csv), "--u", *INPUTS, "--y", *OUTPUTS, "--p", "y2", "--na", "2", "--nb", "2",
                 "--basis", "poly:2", "--controller", str(MAGLEV_CONTROLLER), "--scheduling",
                 "y2=upper_disk_position", "--remove-trim", "--remove-offsets", "--causes", "offset",
                 "--json", str(report)]) == 0
    K = load_experiment_controller(MAGLEV_CONTROLLER)
    n = len(c["time"])
    data = Dataset(np.column_stack([c[name] for name in INPUTS]) - K.trim_along(c, n),
                   np.column_stack([c[name] for name in OUTPUTS]), c["y2"], 0.002, INPUTS, OUTPUTS,
                   ["y2"]).remove_offsets()
    setpoints = np.column_stack([np.full(n, np.nan), c["upper_disk_position_setpoint"]])
    direct = diagnose(data, Structure(2, 2, 1, "poly:2"), causes=["offset"], controller=K,
                      scheduling=MAGLEV_SCHEDULING, setpoints=setpoints, remove_trim=True)
    written = json.loads(report.read_text())
    np.testing.assert_allclose(written["bfr_before"], direct.bfr_before, atol=1e-6)
    slopes = [[row["drift_slope"] for row in where["outputs"]] for where in (written["where"], direct.where)]
    np.testing.assert_allclose(slopes[0], slopes[1], rtol=1e-6)  # the same nominal simulation error
