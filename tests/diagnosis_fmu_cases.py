"""FMU records with one hidden effect each, for the diagnosis bench on plant data.

Every record is made by the experiment machinery (:func:`lpvflow.experiment.run.run_experiment` on
the bundled FMUs) with realistic white sensor noise (``run_experiment``'s sensor model) and one of:

* nothing (a *clean* record: the nominal structure is adequate, the only verdicts that are not a
  false alarm are ``none`` and a noise verdict);
* an in-vocabulary effect set through the FMU's ``effect_*`` parameters (fmu_plants/README.md);
* an effect outside the diagnosis' vocabulary, made by wrapping the plant (:class:`ImpairedPlant`):
  an input rate limiter, a drifting actuator gain, actuator dropouts (the input stuck at its last
  value for a while) and sensor hysteresis (a play operator on the measured output, before the
  noise). The expected verdict is ``unexplained``.

Plants, experiments and nominal structures (the structure the user would take from the plant's
README or example):

* tanks — open loop, pump random levels 4–11 V held 5–40 s, Ts = 1 s, 4000 s; y = p = lower level,
  na = 3, nb = 2, nk = 1, poly:3 (tests/test_diagnose_fmu.py); level sensor noise 0.2 mm.
* airpath — open loop, throttle 5–40 %, valve lift 30–100 %, speed 1000–4000 rpm, Ts = 10 ms, 40 s;
  y = manifold pressure, p = (speed in krpm, throttle fraction), na = nb = 1, nk = 1, poly:2;
  pressure sensor noise 0.3 kPa.
* adip — closed loop under fmu_plants/adip/stabilizing_controller.json, Ts = 5 ms, 40 s, multisine
  excitation on the voltage; y = (arm, pendulum), p = sin(arm), na = nb = 2, nk = 1, affine; angle
  noise 20 µrad.
* maglev — the bundled example's identification (lpvflow/pipeline/examples/maglev.toml): closed loop
  under the gain-scheduled controller fmu_plants/maglev/scheduled_controller.json (lower disk held at
  1.5 cm, trim u*(y2) = the holding currents), the upper disk's set-point a triangle 8 → 8.75 → 7.25 →
  8 cm, random-phase multisines of 0.02 A rms (0.5–20 Hz) on both coils, Ts = 2 ms; y = both
  positions, p = y2 (the measured upper disk position, recomputed from the simulated outputs in the
  loop); na = nb = 2, nk = 1, poly:2; the model's inputs are the currents minus the trim
  (``remove_trim``) and the record's means are removed (``remove_offsets``); every model is simulated
  in the loop with the set-points as recorded. Duration and split: see ``PLANTS`` (the example
  records 80 s with a 40 s sweep and estimates on 70 %); position noise 2 µm.

All random choices come from the record's seed (signals through ``run_experiment``'s seed, the
sensor noise from it, the wrappers' dropout times from ``numpy.random.default_rng(seed)``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import numpy as np

from lpvflow.data import Dataset
from lpvflow.experiment.controller import GriddedController, LtiController
from lpvflow.experiment.loader import load_experiment_controller
from lpvflow.experiment.plant import open_plant
from lpvflow.experiment.run import run_experiment
from lpvflow.validate.extensions import Structure

ROOT = Path(__file__).resolve().parents[1]
BUILD = ROOT / "fmu_plants" / "build"
ADIP_CONTROLLER = ROOT / "fmu_plants" / "adip" / "stabilizing_controller.json"
MAGLEV_CONTROLLER = ROOT / "fmu_plants" / "maglev" / "scheduled_controller.json"
MAGLEV_SCHEDULING = {"y2": "upper_disk_position"}
ADIP_SCHEDULING = {"sin_arm": "sin(arm_angle)"}
#: Maglev record length [s], set-point sweep period [s] and estimation fraction (module docstring).
MAGLEV_DURATION, MAGLEV_SWEEP, MAGLEV_SPLIT = 40.0, 20.0, 0.5
#: Stall torque per volt at the ADIP arm shaft (fmu_plants/adip/README.md): F_c [N·m] / 0.1284 in V.
SRV02_TORQUE_PER_VOLT = 0.9 * 70 * 0.69 * 7.68e-3 / 2.6
ADIP_COULOMB_VOLTS = 0.04 / SRV02_TORQUE_PER_VOLT  # 0.04 N·m of Coulomb friction in input units


@dataclass(frozen=True)
class PlantSetup:
    """One plant's experiment, nominal structure and sensor noise (module docstring)."""

    fmu: str
    Ts: float
    duration: float
    structure: Structure
    noise: dict[str, float]
    inputs: dict[str, str] = field(default_factory=dict)
    excitation: dict[str, str] = field(default_factory=dict)
    parameters: dict[str, float] = field(default_factory=dict)
    controller: Path | None = None  # closed loop under this controller file
    scheduling: dict[str, str] = field(default_factory=dict)  # scheduling columns of the loop
    setpoint: dict[str, str] = field(default_factory=dict)
    remove_trim: bool = False  # model inputs: the recorded ones minus the controller's trim
    split: float = 0.5  # estimation fraction of the diagnosis


PLANTS = {
    "tanks": PlantSetup("tanks", 1.0, 4000.0, Structure(3, 2, 1, "poly:3"), {"lower_level": 2e-4},
                        inputs={"pump_voltage": "levels:lo=4,hi=11,min_hold=5,max_hold=40"}),
    "airpath": PlantSetup(
        "airpath", 0.01, 40.0, Structure(1, 1, 1, "poly:2"), {"manifold_pressure": 0.3},
        inputs={"throttle_position": "levels:lo=5,hi=40,min_hold=0.05,max_hold=0.5",
                "valve_lift": "levels:lo=30,hi=100,min_hold=0.5,max_hold=2",
                "engine_speed": "levels:lo=1000,hi=4000,min_hold=0.5,max_hold=2"}),
    "adip": PlantSetup("adip", 0.005, 40.0, Structure(2, 2, 1, "affine"),
                       {"arm_angle": 2e-5, "pendulum_angle": 2e-5},
                       excitation={"voltage": "multisine:f_lo=0.05,f_hi=20,rms=1.5,period=20,phases=random"},
                       controller=ADIP_CONTROLLER, scheduling=ADIP_SCHEDULING),
    "maglev": PlantSetup(
        "maglev", 0.002, MAGLEV_DURATION, Structure(2, 2, 1, "poly:2"),
        {"lower_disk_position": 2e-6, "upper_disk_position": 2e-6},
        excitation={"lower_coil_current": "multisine:f_lo=0.5,f_hi=20,rms=0.02,phases=random",
                    "upper_coil_current": "multisine:f_lo=0.5,f_hi=20,rms=0.02,phases=random"},
        parameters={"x0_lower_disk_position": 0.015, "x0_upper_disk_position": 0.08},
        controller=MAGLEV_CONTROLLER, scheduling=MAGLEV_SCHEDULING,
        setpoint={"upper_disk_position": f"triangle:amp=0.0075,period={MAGLEV_SWEEP},offset=0.08"},
        remove_trim=True, split=MAGLEV_SPLIT),
}


@dataclass(frozen=True)
class Effect:
    """A hidden effect: FMU parameters or a plant wrapper, the verdict it should get and the
    parameter (name in the diagnosis' parameters, true value) to recover within 20 % (None: only the
    verdict is checked)."""

    expected: str
    parameters: dict[str, float] = field(default_factory=dict)
    wrapper: str | None = None
    check: tuple[str, object] | None = None
    inputs: dict[str, str] = field(default_factory=dict)  # replaces the plant's input design


#: In-vocabulary effects per plant (fmu_plants/README.md, "Effect parameters").
IN_VOCABULARY = {
    "tanks": {
        "dead time 3 s": Effect("input_delay", {"effect_input_delay": 3.0}, check=("nk", 4)),
        "pump saturation 8 V": Effect("input_nonlinearity", {"effect_saturation": 8.0}, check=("limit", 8.0)),
        "pump dead zone 3 V": Effect("input_nonlinearity", {"effect_deadzone": 3.0}, check=("width", 3.0),
                                     inputs={"pump_voltage": "levels:lo=1,hi=9,min_hold=20,max_hold=60"}),
        "level sensor offset 1 cm": Effect("offset", {"effect_sensor_offset": 0.01},
                                           check=("output_offset", 0.01)),
        "level sensor noise 1 mm": Effect("output_noise_bias", {"effect_noise_std": 1e-3}),
    },
    "airpath": {
        "dead time 30 ms": Effect("input_delay", {"effect_input_delay": 0.03}, check=("nk", [4, 4])),
        "pressure sensor noise 4 kPa": Effect("output_noise_bias", {"effect_noise_std": 4.0}),
    },
    "adip": {
        "Coulomb friction 0.04 N·m": Effect("friction", {"effect_coulomb": 0.04},
                                            check=("coulomb_level_input_units", ADIP_COULOMB_VOLTS)),
        "angle sensor offset 10 mrad": Effect("offset", {"effect_sensor_offset": 0.01},
                                              check=("output_offset", [0.01, 0.01])),
        "dead time 15 ms": Effect("input_delay", {"effect_input_delay": 0.015}, check=("nk", 4)),
    },
    "maglev": {
        "dead time 6 ms": Effect("input_delay", {"effect_input_delay": 0.006}, check=("nk", [4, 4])),
        "Coulomb friction 0.02 N": Effect("friction", {"effect_coulomb": 0.02}),
    },
}

#: Effects outside the vocabulary (module docstring), on every plant of IMPAIRMENT.
OUT_OF_VOCABULARY = ("rate limiter", "drifting gain", "actuator dropouts", "sensor hysteresis")
#: Wrapper sizes per plant: rate limit (input units per second), final gain of the first actuator
#: (linear drift from 1), dropout length (s) and hysteresis width (output units). ADIP (closed loop):
#: the voltage's median slew rate on a clean record is 91 V/s (99 %: 342 V/s), so 150 V/s limits
#: part of it; 2 mrad of play on angles of 0.1 / 0.04 rad standard deviation.
IMPAIRMENT = {
    "tanks": {"rate": 0.1, "gain": 1.4, "dropout": 30.0, "hysteresis": 5e-3},
    "airpath": {"rate": 100.0, "gain": 1.4, "dropout": 0.3, "hysteresis": 3.0},
    "maglev": {"rate": 1.0, "gain": 1.4, "dropout": 0.2, "hysteresis": 2e-4},
    "adip": {"rate": 150.0, "gain": 1.4, "dropout": 0.02, "hysteresis": 2e-3},
}


@dataclass
class ImpairedPlant:
    """A plant with an out-of-vocabulary effect on its first actuator input or its measured outputs.

    rate limiter  u_a(k) = u_a(k−1) + clip(u(k) − u_a(k−1), −r·Ts, r·Ts)
    drifting gain u_a(k) = u(k)·(1 + (g − 1)·k/N) on the first input (deviation from its start value)
    dropouts      u_a(k) = u_a(k−1) during random windows (one per 10 windows of the given length)
    hysteresis    y_m(k) = play(y(k)) with total width w on every measured output (tests/diagnosis_cases.play)
    """

    inner: object
    kind: str
    size: float
    n: int
    seed: int
    _k: int = 0
    _last: np.ndarray | None = None
    _held: np.ndarray | None = None
    _stuck: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.model_name = self.inner.model_name
        self.input_names = self.inner.input_names
        self.output_names = self.inner.output_names
        self._start = self.inner.start_value(self.input_names[0])
        self._measured = np.array([not name.startswith("diag_") for name in self.output_names])

    def start_value(self, name: str) -> float:
        return self.inner.start_value(name)

    def parameter_values(self) -> dict:
        return self.inner.parameter_values()

    def outputs(self) -> np.ndarray:
        y = np.array(self.inner.outputs(), float)
        if self.kind == "sensor hysteresis":
            if self._held is None:
                self._held = y.copy()
            half = self.size / 2
            self._held = np.minimum(np.maximum(self._held, y - half), y + half)
            y[self._measured] = self._held[self._measured]
        return y

    def step(self, u: np.ndarray, t: float, Ts: float) -> None:
        applied = np.array(u, float)
        first = applied[0]
        if self.kind == "rate limiter":
            prev = first if self._last is None else self._last[0]
            first = prev + np.clip(first - prev, -self.size * Ts, self.size * Ts)
        elif self.kind == "drifting gain":
            first = self._start + (first - self._start) * (1 + (self.size - 1) * self._k / self.n)
        elif self.kind == "actuator dropouts":
            if self._stuck is None:
                self._stuck = _dropout_mask(self.n, max(1, round(self.size / Ts)), self.seed)
            if self._last is not None and self._stuck[self._k]:
                first = self._last[0]
        applied[0] = first
        self._last = applied
        self._k += 1
        self.inner.step(applied, t, Ts)

    def close(self) -> None:
        self.inner.close()


def _dropout_mask(n: int, length: int, seed: int) -> np.ndarray:
    """Windows of ``length`` samples, each stuck with probability 0.1 (at least one window)."""
    rng = np.random.default_rng(seed)
    windows = np.arange(n) // length
    stuck = rng.random(windows[-1] + 1) < 0.1
    stuck[rng.integers(len(stuck))] = True
    return stuck[windows]


@dataclass
class Record:
    """A generated record: the data the diagnosis sees and what it should find."""

    plant: str
    effect: str
    seed: int
    data: Dataset
    channels: dict[str, np.ndarray]
    structure: Structure
    expected: str
    check: tuple[str, object] | None
    controller: LtiController | GriddedController | None = None
    scheduling: dict[str, str] | None = None
    setpoints: np.ndarray | None = None  # (N, outputs the controller reads), NaN where none
    remove_trim: bool = False
    split: float = 0.5

    def diagnose_arguments(self) -> dict:
        """The keyword arguments of :func:`~lpvflow.validate.diagnose.diagnose` for this record (the
        user's set-up: its split, and the loop of a closed-loop record)."""
        return {"controller": self.controller, "scheduling": self.scheduling, "setpoints": self.setpoints,
                "remove_trim": self.remove_trim, "split": self.split}

    @property
    def label(self) -> str:
        return f"{self.plant}/{self.effect}/seed {self.seed}"


def _effect(plant: str, effect: str) -> Effect:
    if effect == "clean":
        return Effect("none")
    if effect in OUT_OF_VOCABULARY:
        return Effect("unexplained", wrapper=effect)
    return IN_VOCABULARY[plant][effect]


@cache
def make_record(plant: str, effect: str, seed: int) -> Record:
    """The record of ``plant`` with ``effect`` ("clean", a key of IN_VOCABULARY[plant] or one of
    OUT_OF_VOCABULARY) for experiment seed ``seed`` (cached: each record is made once per session)."""
    setup, spec = PLANTS[plant], _effect(plant, effect)
    parameters = setup.parameters | spec.parameters
    if "effect_noise_std" in parameters:
        parameters["effect_noise_seed"] = seed + 1
    inner = open_plant(BUILD / f"{setup.fmu}.fmu", parameters)
    n = round(setup.duration / setup.Ts)
    wrapped = (ImpairedPlant(inner, spec.wrapper, IMPAIRMENT[plant][_size_key(spec.wrapper)], n, seed)
               if spec.wrapper else inner)
    controller = load_experiment_controller(setup.controller) if setup.controller else None
    try:
        record = run_experiment(wrapped, setup.Ts, setup.duration, spec.inputs or setup.inputs or None,
                                controller, setup.excitation or None, setup.scheduling, seed, progress=False,
                                noise=setup.noise, setpoint=setup.setpoint or None)
    finally:
        wrapped.close()
    columns = dict(record.columns)
    setpoints = None
    if controller is not None:
        setpoints = np.column_stack([columns.get(f"{name}_setpoint", np.full(len(columns["time"]), np.nan))
                                     for name in controller.inputs])
    if setup.remove_trim:
        trim = controller.trim_along(columns, len(columns["time"]))
        for j, name in enumerate(controller.outputs):
            columns[name] = columns[name] - trim[:, j]
    data, channels = _dataset(plant, columns, record.Ts)
    return Record(plant, effect, seed, data, channels, setup.structure, spec.expected, spec.check,
                  controller, setup.scheduling or None, setpoints, setup.remove_trim, setup.split)


def _size_key(wrapper: str) -> str:
    return {"rate limiter": "rate", "drifting gain": "gain", "actuator dropouts": "dropout",
            "sensor hysteresis": "hysteresis"}[wrapper]


def _dataset(plant: str, c: dict[str, np.ndarray], Ts: float) -> tuple[Dataset, dict[str, np.ndarray]]:
    if plant == "tanks":
        return Dataset(c["pump_voltage"], c["lower_level"], c["lower_level"], Ts, ["V"], ["h2"], ["h2"]), {}
    if plant == "airpath":
        p = np.column_stack([c["engine_speed"] / 1000, c["throttle_position"] / 100])
        data = Dataset(np.column_stack([c["throttle_position"], c["valve_lift"]]), c["manifold_pressure"], p,
                       Ts, ["throttle", "lift"], ["p_m"], ["speed_krpm", "throttle_fraction"])
        return data, {"throttle": c["throttle_position"], "valve_lift": c["valve_lift"]}
    if plant == "adip":
        return Dataset(c["voltage"], np.column_stack([c["arm_angle"], c["pendulum_angle"]]), c["sin_arm"], Ts,
                       ["voltage"], ["arm_angle", "pendulum_angle"], ["sin_arm"]), {}
    u = np.column_stack([c["lower_coil_current"], c["upper_coil_current"]])
    y = np.column_stack([c["lower_disk_position"], c["upper_disk_position"]])
    return Dataset(u, y, c["upper_disk_position"], Ts, ["lower_coil_current", "upper_coil_current"],
                   ["lower_disk_position", "upper_disk_position"], ["y2"]).remove_offsets(), {}


def bench_records(seeds: tuple[int, ...], clean_seeds: tuple[int, ...]) -> list[tuple[str, str, int]]:
    """(plant, effect, seed) of the full bench: every in-vocabulary effect and every out-of-vocabulary
    one (the plants of IMPAIRMENT) at every seed, clean records at every clean seed on every plant."""
    keys = [(plant, effect, seed) for plant, effects in IN_VOCABULARY.items() for effect in effects
            for seed in seeds]
    keys += [(plant, effect, seed) for plant in IMPAIRMENT for effect in OUT_OF_VOCABULARY for seed in seeds]
    keys += [(plant, "clean", seed) for plant in PLANTS for seed in clean_seeds]
    return keys


def within(value, truth, rel: float = 0.2) -> bool:
    """``value`` equal to an integer ``truth`` (a delay: int or list of ints), else every element within
    ``rel`` of ``truth``."""
    exact = all(isinstance(t, int) for t in np.atleast_1d(np.asarray(truth, object)))
    value, truth = np.atleast_1d(np.asarray(value, float)), np.atleast_1d(np.asarray(truth, float))
    if value.shape != truth.shape:
        return False
    if exact:
        return bool(np.all(value == truth))
    return bool(np.all(np.abs(value - truth) <= rel * np.abs(truth)))


def outcome(record: Record, cause: str, parameters: dict,
            not_identifiable: Mapping[str, str] | None = None) -> str:
    """'right', 'false alarm', 'not identifiable (stated)' (the diagnosis says the data cannot determine
    the expected cause, ``Diagnosis.not_identifiable``), or what went wrong."""
    if record.expected == "none":
        return "right" if cause in ("none", "output_noise_bias", "colored_noise") else "false alarm"
    if cause != record.expected:
        return "not identifiable (stated)" if record.expected in (not_identifiable or {}) else "wrong"
    if record.check is None:
        return "right"
    name, truth = record.check
    return "right" if name in parameters and within(parameters[name], truth) else "parameter off"
