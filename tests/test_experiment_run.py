"""Experiment loop, controller files, scheduling expressions and the CSV record, on a plant written
in Python (a discrete StateSpace stepped one sample at a time), so the loop law can be checked
against python-control's own interconnection."""

import csv
import json

import control
import numpy as np
import pytest

from lpvflow.data import Dataset
from lpvflow.errors import DataError, ModelError
from lpvflow.experiment import LtiController, load_controller, run_experiment
from lpvflow.experiment.record import check_output_path, csv_text, write_record
from lpvflow.experiment.run import sidecar_path, signal_rng
from lpvflow.experiment.scheduling import evaluate, parse_assignment
from lpvflow.experiment.specs import generate, parse_spec

TS = 0.01


class StateSpacePlant:
    """x(k+1) = A x + B u, y = C x for a discrete python-control StateSpace; inputs start at u0."""

    def __init__(self, sys, u0, name="toy"):
        self.sys, self.x = sys, np.zeros(sys.nstates)
        self.model_name = name
        self.input_names = [f"u{i}" for i in range(sys.ninputs)]
        self.output_names = [f"y{i}" for i in range(sys.noutputs)]
        self.u0 = dict(zip(self.input_names, u0, strict=True))
        self.closed = False

    def start_value(self, name):
        return self.u0[name]

    def parameter_values(self):
        return {"effect_noise_std": 0.0, "gain": 1.0}

    def outputs(self):
        return self.sys.C @ self.x

    def step(self, u, t, Ts):
        self.x = self.sys.A @ self.x + self.sys.B @ u

    def close(self):
        self.closed = True


def unstable_plant():
    """Two inputs, one output; pole at 1.05 (open-loop unstable)."""
    return control.ss([[1.05, 0.1], [0.0, 0.9]], [[0.0, 0.0], [1.0, 0.5]], [[1.0, 0.0]], [[0.0, 0.0]], TS)


def stabilising_controller():
    """One-state controller on y0 driving u0 (grid search; closed-loop spectral radius 0.85)."""
    return control.ss([[0.5]], [[1.0]], [[0.4]], [[-1.1]], TS, inputs=["y0"], outputs=["u0"])


def test_open_loop_applies_signals_around_the_operating_value():
    plant = StateSpacePlant(control.ss([[0.9]], [[1.0, 2.0]], [[1.0]], [[0.0, 0.0]], TS), u0=[0.5, -1.0])
    rec = run_experiment(plant, TS, 5.0, inputs={"u0": "prbs:order=6,clock=0.02,amp=0.1"}, seed=4,
                         progress=False)
    u0, u1, y = rec.columns["u0"], rec.columns["u1"], rec.columns["y0"]
    assert set(np.unique(u0)) == {0.4, 0.6}  # PRBS around the start value 0.5
    np.testing.assert_array_equal(u1, -1.0)  # undriven input held at its start value
    expected = generate(parse_spec("prbs:order=6,clock=0.02,amp=0.1"), 500, TS, signal_rng(4, "u0"), 0.5)
    np.testing.assert_array_equal(u0, expected)
    # y(k) is recorded before u(k) is applied: y(k+1) = 0.9 y(k) + u0(k) + 2 u1(k)
    np.testing.assert_allclose(y[1:], 0.9 * y[:-1] + u0[:-1] + 2 * u1[:-1], atol=1e-12)
    assert y[0] == 0.0
    np.testing.assert_allclose(np.diff(rec.time), TS, rtol=1e-9)
    assert list(rec.columns) == ["time", "u0", "u1", "y0"]


def test_closed_loop_matches_python_control_interconnection():
    G, K = unstable_plant(), stabilising_controller()
    assert np.max(np.abs(G.poles())) > 1
    assert np.max(np.abs(control.feedback(G[0, 0], K, sign=1).poles())) < 0.86
    plant = StateSpacePlant(G, u0=[0.0, 0.0])
    u_op = np.array([0.3])
    ctrl = LtiController.from_statespace(K, y_op=np.array([0.0]), u_op=u_op)
    excitation = {"u0": "multisine:f_lo=0.5,f_hi=10,rms=0.2"}
    rec = run_experiment(plant, TS, 3.0, controller=ctrl, excitation=excitation,
                         inputs={"u1": "aprbs:lo=-0.1,hi=0.1,min_hold=0.05,max_hold=0.2"}, seed=1,
                         progress=False)
    r = rec.columns["u0_excitation"]
    # reference: u0 = u_op + K y0 + r, u1 given; closed loop from [r + u_op, u1] to [y0, u0]
    G_named = control.ss(G.A, G.B, G.C, G.D, TS, inputs=["u0", "u1"], outputs=["y0"])
    sum_block = control.summing_junction(inputs=["r", "k"], output="u0")
    K_named = control.ss(K.A, K.B, K.C, K.D, TS, inputs=["y0"], outputs=["k"])
    loop = control.interconnect([G_named, K_named, sum_block], inplist=["r", "u1"], outlist=["y0", "u0"])
    t = rec.time
    resp = control.forced_response(loop, T=t, U=np.vstack([r + u_op[0], rec.columns["u1"]]))
    np.testing.assert_allclose(rec.columns["y0"], resp.outputs[0], atol=1e-10)
    np.testing.assert_allclose(rec.columns["u0"], resp.outputs[1], atol=1e-10)
    assert np.max(np.abs(rec.columns["y0"])) < 5  # the controller keeps the unstable plant bounded
    assert rec.metadata["mode"] == "closed-loop"
    assert rec.metadata["controller"]["u_operating_point"] == [0.3]


def test_setpoint_replaces_the_operating_point_and_is_recorded_as_an_excitation():
    """u = u_op + K(y − s): the recorded input equals the controller run offline on y − s, and
    ``u0_excitation`` is exactly what the y_op-form law needs added (module docstring of run)."""
    G, K = unstable_plant(), stabilising_controller()
    y_op, u_op = np.array([0.2]), np.array([0.3])
    ctrl = LtiController.from_statespace(K, y_op=y_op, u_op=u_op)
    setpoint = {"y0": "levels:lo=-0.5,hi=0.5,min_hold=0.3,max_hold=0.6,ramp=0.1"}
    rec = run_experiment(StateSpacePlant(G, u0=[0.0, 0.0]), TS, 3.0, controller=ctrl, setpoint=setpoint,
                         seed=2, progress=False)
    s, y, u = rec.columns["y0_setpoint"], rec.columns["y0"], rec.columns["u0"]
    assert s.min() >= -0.5 and s.max() <= 0.5 and np.ptp(s) > 0.3  # the levels moved
    law = control.ss(K.A, K.B, K.C, K.D, TS)
    t = rec.time
    np.testing.assert_allclose(u, u_op[0] + control.forced_response(law, T=t, U=y - s).outputs, atol=1e-12)
    y_op_form = u_op[0] + control.forced_response(law, T=t, U=y - y_op[0]).outputs
    np.testing.assert_allclose(rec.columns["u0_excitation"], u - y_op_form, atol=1e-12)
    assert rec.metadata["setpoint"]["y0"]["kind"] == "levels"
    assert rec.metadata["columns"]["setpoint"] == ["y0_setpoint"]
    centred = run_experiment(StateSpacePlant(G, u0=[0.0, 0.0]), TS, 1.0, controller=ctrl, seed=2,
                             progress=False, setpoint={"y0": "multisine:f_lo=1,f_hi=5,rms=0.01"})
    assert abs(centred.columns["y0_setpoint"].mean() - y_op[0]) < 1e-9  # a multisine is centred on y_op


def test_diverging_run_is_reported_not_recorded():
    plant = StateSpacePlant(control.ss([[1e150]], [[1.0]], [[1e150]], [[0.0]], TS), u0=[1.0])
    with np.errstate(over="ignore"), pytest.raises(ModelError, match=r"non-finite at t=.*diverged"):
        run_experiment(plant, TS, 1.0, progress=False)


def test_leaving_the_output_bounds_ends_the_run_at_the_first_sample_outside():
    """The open-loop unstable plant (pole 1.05) under a constant input: its output grows; with bounds the
    run ends at the first sample whose output is outside them, named with its value and time; bounds it
    never reaches leave the record as it is without them."""
    inputs = {"u0": "const:value=1", "u1": "const:value=0"}
    free = run_experiment(StateSpacePlant(unstable_plant(), u0=[0.0, 0.0]), TS, 2.0, inputs, progress=False)
    y = free.columns["y0"]
    first = int(np.argmax(y > 3.0))
    assert 0 < first < len(y) - 1
    with pytest.raises(ModelError, match=rf"y0 = {y[first]:.4g} left its bounds \[-1, 3\] at "
                       rf"t={first * TS:g} s.*smaller, or widen the bounds") as info:
        run_experiment(StateSpacePlant(unstable_plant(), u0=[0.0, 0.0]), TS, 2.0, inputs, progress=False,
                       output_bounds={"y0": (-1.0, 3.0)})
    assert "\n" not in str(info.value)
    wide = run_experiment(StateSpacePlant(unstable_plant(), u0=[0.0, 0.0]), TS, 2.0, inputs, progress=False,
                          output_bounds={"y0": (-1.0, 2.0 * y.max())})
    assert all(np.array_equal(wide.columns[name], free.columns[name]) for name in free.columns)
    assert wide.metadata["output_bounds"] == {"y0": [-1.0, 2.0 * y.max()]}


@pytest.mark.parametrize(
    ("kwargs", "error", "message"),
    [
        ({"Ts": 0.0}, DataError, "Ts=0.0 must be a positive"),
        ({"Ts": -0.01}, DataError, "must be a positive"),
        ({"duration": 0.015}, DataError, "at least two communication steps"),
        ({"duration": 1.005}, DataError, "not a whole number of steps"),
        ({"inputs": {"throttle": "const:value=1"}}, ModelError, "'throttle' not in FMU toy"),
        ({"inputs": {"u0": "multisine:f_lo=1"}}, DataError, "needs f_hi"),
        ({"excitation": {"u0": "const:value=1"}}, DataError, "give a controller"),
        ({"setpoint": {"y0": "const:value=1"}}, DataError, "a set-point is what a controller tracks"),
        ({"setpoint": {"z": "const:value=1"}}, ModelError, "set-point output 'z' not in FMU toy"),
        ({"seed": -1}, DataError, "non-negative integer"),
        ({"scheduling_columns": {"p": "sin(arm)"}}, DataError, "unknown name 'arm'"),
        ({"scheduling_columns": {"y0": "u0"}}, DataError, "clashes"),
        ({"output_bounds": {"z": (0.0, 1.0)}}, ModelError, "bounded output 'z' not in FMU toy"),
        ({"output_bounds": {"y0": (1.0, 0.0)}}, DataError,
         r"output bounds of y0 = \(1.0, 0.0\) must be \[min, max\] with min < max"),
    ],
)
def test_bad_open_loop_arguments(kwargs, error, message):
    plant = StateSpacePlant(unstable_plant(), u0=[0.0, 0.0])
    args = {"Ts": TS, "duration": 0.5} | kwargs
    with pytest.raises(error, match=message) as info:
        run_experiment(plant, progress=False, **args)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("controller", "kwargs", "message"),
    [
        (stabilising_controller(), {"inputs": {"u0": "const:value=1"}}, "driven by the controller"),
        (stabilising_controller(), {"excitation": {"u1": "const:value=1"}}, "does not drive"),
        (control.ss(0.5, 1.0, 1.0, 0.0, TS, inputs=["pos"], outputs=["u0"]), {}, "'pos' not in"),
        (control.ss(0.5, 1.0, 1.0, 0.0, TS, inputs=["y0"], outputs=["volt"]), {}, "'volt' not in"),
        (control.ss(0.5, 1.0, 1.0, 0.0, 0.02, inputs=["y0"], outputs=["u0"]), {}, "differs"),
        (stabilising_controller(), {"setpoint": {"y1": "const:value=1"}}, "y1: the controller does not read"),
    ],
)
def test_bad_closed_loop_arguments(controller, kwargs, message):
    plant = StateSpacePlant(control.ss(unstable_plant().A, unstable_plant().B, [[1.0, 0.0], [0.0, 1.0]],
                                       np.zeros((2, 2)), TS), u0=[0.0, 0.0])  # outputs y0 (read), y1
    with pytest.raises((DataError, ModelError), match=message):
        run_experiment(plant, TS, 0.5, controller=LtiController.from_statespace(controller), progress=False,
                       **kwargs)


def test_controller_file_round_trip_and_refusals(tmp_path):
    ctrl = LtiController.from_statespace(stabilising_controller(), y_op=[0.1], u_op=[2.0])
    path = tmp_path / "k.json"
    path.write_text(json.dumps(ctrl.to_dict()))
    back = load_controller(path)
    for key in ("A", "B", "C", "D", "y_op", "u_op"):
        np.testing.assert_array_equal(getattr(back, key), getattr(ctrl, key))
    assert (back.Ts, back.inputs, back.outputs) == (TS, ("y0",), ("u0",))

    static = ctrl.to_dict() | {"A": [], "B": [], "C": [], "D": [[-1.5]]}
    path.write_text(json.dumps(static))
    assert load_controller(path).A.shape == (0, 0)

    for doc, message in [
        (ctrl.to_dict() | {"version": 2}, "version 2"),
        (ctrl.to_dict() | {"format": "lpvflow/lpvss"}, "not of format"),
        (ctrl.to_dict() | {"B": [[1.0, 2.0]]}, r"B has shape \(1, 2\), expected \(1, 1\)"),
        (ctrl.to_dict() | {"Ts": 0}, "positive sampling time"),
        ({k: v for k, v in ctrl.to_dict().items() if k != "C"}, "lacks C"),
    ]:
        path.write_text(json.dumps(doc))
        with pytest.raises(ModelError, match=message):
            load_controller(path)
    path.write_text("{not json")
    with pytest.raises(ModelError, match="not valid JSON"):
        load_controller(path)
    with pytest.raises(ModelError, match="does not exist"):
        load_controller(tmp_path / "missing.json")
    with pytest.raises(ModelError, match="discrete"):
        LtiController.from_statespace(control.ss([[-1.0]], [[1.0]], [[1.0]], [[0.0]]))


def test_scheduling_expressions_are_arithmetic_only():
    signals = {"arm": np.array([0.0, np.pi / 2]), "speed": np.array([1000.0, 3000.0])}
    np.testing.assert_allclose(evaluate("sin(arm)", signals), [0.0, 1.0])
    np.testing.assert_allclose(evaluate("speed / 60 * 2 * pi", signals), signals["speed"] * np.pi / 30)
    np.testing.assert_allclose(evaluate("-arm ** 2 + 1", signals), [1.0, 1 - np.pi**2 / 4])
    assert parse_assignment(" sin_arm = sin(arm) ") == ("sin_arm", "sin(arm)")
    for text, message in [
        ("__import__('os').getcwd()", "not allowed"),
        ("arm.real", "not allowed"),
        ("arm[0]", "not allowed"),
        ("sin(arm, arm, arm)", "wrong number of arguments"),
        ("log(arm)", "non-finite"),
        ("sin(arm", "not valid arithmetic"),
    ]:
        with pytest.raises(DataError, match=message):
            evaluate(text, signals)
    for text in ("sin(arm)", "1p=arm", "p="):
        with pytest.raises(DataError, match="NAME=EXPRESSION"):
            parse_assignment(text)


def _record(seed=0):
    plant = StateSpacePlant(unstable_plant(), u0=[0.0, 0.2])
    return run_experiment(plant, TS, 2.0, controller=LtiController.from_statespace(stabilising_controller()),
                          excitation={"u0": "multisine:f_lo=1,f_hi=20,rms=0.1"},
                          inputs={"u1": "levels:lo=0,hi=1,min_hold=0.1,max_hold=0.3"},
                          scheduling_columns={"p": "tanh(y0) + u1"}, seed=seed, progress=False)


def test_csv_round_trips_exactly_and_reads_as_dataset(tmp_path):
    rec = _record()
    out = tmp_path / "data.csv"
    side = write_record(rec, out, protected=[tmp_path / "plant.fmu"])
    assert side == tmp_path / "data.csv.json" and sidecar_path(out) == side
    with out.open(newline="") as stream:
        header = next(csv.reader(stream))
    assert header == ["time", "u0", "u1", "y0", "u0_excitation", "p"]
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    for j, name in enumerate(header):
        np.testing.assert_array_equal(table[:, j], rec.columns[name])  # exact, not approximate
    np.testing.assert_allclose(rec.columns["p"], np.tanh(rec.columns["y0"]) + rec.columns["u1"])
    data = Dataset.read(out, u=["u0", "u1"], y=["y0"], p=["p"])
    assert data.Ts == pytest.approx(TS) and data.N == 200
    meta = json.loads(side.read_text())
    assert meta["format"] == "lpvflow/experiment" and meta["csv"] == "data.csv"
    assert meta["seed"] == 0 and meta["excitation"]["u0"]["text"] == "multisine:f_lo=1,f_hi=20,rms=0.1"
    assert meta["parameters"] == {"effect_noise_std": 0.0, "gain": 1.0}
    assert meta["columns"]["scheduling"] == ["p"] and meta["scheduling"] == {"p": "tanh(y0) + u1"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.csv", "data.csv.json"]  # no temp files left


def test_csv_bytes_depend_on_the_seed_only():
    assert csv_text(_record(seed=5)) == csv_text(_record(seed=5))
    assert csv_text(_record(seed=5)) != csv_text(_record(seed=6))


def test_output_may_not_overwrite_inputs(tmp_path):
    fmu = tmp_path / "plant.fmu"
    fmu.write_bytes(b"not touched")
    with pytest.raises(DataError, match="would overwrite the input"):
        check_output_path(fmu, protected=[fmu])
    with pytest.raises(DataError, match="would overwrite the input"):
        check_output_path(tmp_path / "k", protected=[tmp_path / "k.json"])  # the sidecar would hit it
    with pytest.raises(DataError, match="does not exist"):
        check_output_path(tmp_path / "missing" / "data.csv")
    with pytest.raises(DataError, match="is a folder"):
        check_output_path(tmp_path)
    assert fmu.read_bytes() == b"not touched"


def test_fmu_scheduling_output_is_the_default_and_diagnostics_are_opt_in():
    sys = control.ss([[0.9]], [[1.0]], [[1.0], [2.0]], [[0.0], [0.0]], TS)
    plant = StateSpacePlant(sys, u0=[1.0], name="unlisted")
    plant.output_names = ["y0", "diag_scheduling"]
    rec = run_experiment(plant, TS, 0.5, progress=False)
    assert list(rec.columns) == ["time", "u0", "y0", "scheduling"]
    np.testing.assert_array_equal(rec.columns["scheduling"], 2 * rec.columns["y0"])
    plant = StateSpacePlant(sys, u0=[1.0], name="unlisted")
    plant.output_names = ["y0", "diag_scheduling"]
    rec = run_experiment(plant, TS, 0.5, progress=False, record_diagnostics=True, scheduling_columns={})
    assert list(rec.columns) == ["time", "u0", "y0", "diag_scheduling"]
