"""Run an identification experiment on a plant, open or closed loop, and record what happened.

Sampling convention (per communication step k, t_k = k·Ts): read y(k) from the plant, form u(k),
record (t_k, u(k), y(k)), then advance the plant from t_k to t_k + Ts with u(k) held (zero-order
hold). So y(k) depends on u(k-1), u(k-2), ... only, as the discrete models of lpvflow assume.

Open loop: u_j(k) = s_j(k) for every input j with a signal s_j; the others stay at their start
value. Closed loop with an :class:`~lpvflow.experiment.controller.LtiController` K:

    xc(k+1) = A xc(k) + B (y_K(k) - y_op),
    u_K(k)  = u_op + C xc(k) + D (y_K(k) - y_op) + r(k),

where y_K are the plant outputs K reads, u_K the plant inputs it drives, and r the excitation added
to its output (recorded as ``<input>_excitation``); inputs K does not drive may still get a signal
(e.g. an exogenous engine speed). This is the setting of Boonto (2011), Fig. 3.2 (r_2 added to u).

Set-points move the operating point during the run: a signal s_i(k) on an output K reads replaces
y_op,i (multisine and prbs are centred on y_op,i, the other kinds are absolute; recorded as
``<output>_setpoint``). K is linear, so K acting on y − s equals K acting on y − y_op plus the signal
r_s = K(y_op − s) — K's response, from rest, to y_op − s alone — added to its output; r + r_s is what
``<input>_excitation`` records, so every consumer of the record (the closed-loop validation, the
diagnosis loops) sees the set-point as part of the one external signal at the controller output.

A :class:`~lpvflow.experiment.controller.GriddedController` (gain-scheduled on θ, an expression of the
outputs it reads and their set-points) runs its own law at every step (its docstring):
ȳ(k) = y_op(θ(k)) with the set-points in place of their outputs' entries,
u_K(k) = u_op(θ) + C(θ) xc + D(θ) (y_K − ȳ) + r(k). Its set-points are absolute for every kind
(multisine, prbs and triangle centred on 0 unless they give ``offset``); only the excitation r is
recorded as ``<input>_excitation``, the set-points as ``<output>_setpoint``.

A :class:`~lpvflow.experiment.synthesized.SynthesizedController` (an ``lpvflow/lpv-controller`` of
``lpvflow synth`` or the design pipeline, wired by its ``info["signals"]``) runs the law of
:mod:`lpvflow.pipeline.verify` (its module docstring): the set-points of the outputs it reads are its
references r (the outputs' operating points where none is given; multisine, prbs and triangle centred
on them), w = r − y (1-DOF) or [r − y_op; y − y_op] (2-DOF, y_op the outputs' operating points), the
scheduling p(k) its expressions of the measured plant outputs, and
u_K(k) = u_op + u_eq(p) + C(p) xc + D(p) w (clipped to its anti-windup range) + r_e(k)
with the excitation r_e recorded as ``<input>_excitation``, the set-points as ``<output>_setpoint``.

Every kind runs through the closed-loop engine (:func:`lpvflow.loop.engine.close_loop`) as a
controller of the loop protocol (:mod:`lpvflow.loop.protocol`); an open-loop run is the engine with
:class:`~lpvflow.loop.protocol.OpenLoop`.

Sensors (``quantization``, ``noise``, per plant output): what the controller reads and the record holds
is y_m(k) = q·round((y(k) + v(k))/q) with v white Gaussian of the given standard deviation (seeded per
output) and q the quantization step (an encoder of 4096 counts per revolution: q = 2π/4096 rad); either
may be left out. Scheduling columns are computed from the measured values, as on a real rig.

Output bounds (``output_bounds``, per plant output ``(min, max)``): the run ends as failed at the first
sample whose measured output leaves them — a rig's safety limit; a closed loop that lost its plant (a
fallen pendulum) gives no data about the operating range it was meant to cover.
"""

from __future__ import annotations

import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from lpvflow.errors import DataError, ModelError
from lpvflow.experiment import scheduling
from lpvflow.experiment.controller import GriddedController, LtiController
from lpvflow.experiment.plant import Plant
from lpvflow.experiment.specs import SignalSpec, generate, parse_spec
from lpvflow.experiment.synthesized import SynthesizedController
from lpvflow.intervals import interval
from lpvflow.loop.engine import close_loop
from lpvflow.loop.protocol import OpenLoop, check_names

#: Tolerance on the controller Ts matching the experiment Ts.
_STEP_TOLERANCE = 1e-9
#: FMU outputs with this prefix are diagnostics (noise-free states, derivatives, applied inputs):
#: not recorded unless asked for, but usable in scheduling expressions.
DIAGNOSTIC_PREFIX = "diag_"
#: Output through which an FMU names its scheduling variable; recorded as column ``scheduling``
#: when neither the user nor :data:`scheduling.PLANT_DEFAULTS` chooses one.
FMU_SCHEDULING_OUTPUT = "diag_scheduling"


@dataclass
class ExperimentRecord:
    """Recorded columns (``time`` first, then inputs, outputs, excitations, scheduling) and metadata."""

    columns: dict[str, np.ndarray]
    Ts: float
    metadata: dict[str, object] = field(default_factory=dict)

    @property
    def time(self) -> np.ndarray:
        return self.columns["time"]


def signal_rng(seed: int, name: str) -> np.random.Generator:
    """Random generator of the signal on ``name``: depends on the seed and the name only, so adding
    or reordering other signals does not change it."""
    return np.random.default_rng([int(seed), zlib.crc32(name.encode())])


def step_count(Ts: float, duration: float) -> int:
    """Number of samples N = duration / Ts; refuse Ts <= 0 and durations that are not whole steps."""
    if not (np.isfinite(Ts) and Ts > 0):
        raise DataError(f"communication step Ts={Ts} must be a positive number of seconds")
    if not (np.isfinite(duration) and duration >= 2 * Ts):
        raise DataError(f"duration={duration} s must be at least two communication steps of {Ts:g} s")
    n = round(duration / Ts)
    if abs(duration / Ts - n) > 1e-6:
        raise DataError(f"duration={duration:g} s is not a whole number of steps Ts={Ts:g} s")
    return n


def _as_specs(signals: Mapping[str, str | SignalSpec] | None) -> dict[str, SignalSpec]:
    return {name: spec if isinstance(spec, SignalSpec) else parse_spec(spec)
            for name, spec in (signals or {}).items()}


def run_experiment(
    plant: Plant,
    Ts: float,
    duration: float,
    inputs: Mapping[str, str | SignalSpec] | None = None,
    controller: LtiController | GriddedController | SynthesizedController | None = None,
    excitation: Mapping[str, str | SignalSpec] | None = None,
    scheduling_columns: Mapping[str, str] | None = None,
    seed: int = 0,
    progress: bool | None = None,
    record_diagnostics: bool = False,
    setpoint: Mapping[str, str | SignalSpec] | None = None,
    quantization: Mapping[str, float] | None = None,
    noise: Mapping[str, float] | None = None,
    output_bounds: Mapping[str, tuple[float, float]] | None = None,
) -> ExperimentRecord:
    """Drive ``plant`` for ``duration`` seconds at step Ts; see the module docstring for the law.

    ``inputs``/``excitation`` map plant input names to signal specs (text or :class:`SignalSpec`),
    ``setpoint`` maps plant outputs the controller reads to theirs;
    ``scheduling_columns`` maps new column names to expressions of input/output names (default:
    :func:`default_scheduling`); ``quantization`` and ``noise`` map plant outputs to the quantization
    step and the white-noise standard deviation of their sensor, ``output_bounds`` to the interval the
    run must keep them in (module docstring; leaving it is one ModelError line). Outputs named
    ``diag_*`` are recorded only with ``record_diagnostics``. ``progress=None`` shows a tqdm bar only on a
    terminal.
    """
    n = step_count(Ts, duration)
    if int(seed) != seed or seed < 0:
        raise DataError(f"seed={seed} must be a non-negative integer")
    input_specs, excitation_specs = _as_specs(inputs), _as_specs(excitation)
    setpoint_specs = _as_specs(setpoint)
    model = plant.model_name
    check_names("input", list(input_specs), plant.input_names, model)
    check_names("excitation input", list(excitation_specs), plant.input_names, model)
    check_names("set-point output", list(setpoint_specs), plant.output_names, model)
    sensors = _sensor_model(quantization, noise, plant.output_names, model)
    outside = _bounds_check(output_bounds, plant.output_names, model, Ts)
    if controller is None and (excitation_specs or setpoint_specs):
        what = "an excitation is added to a controller output" if excitation_specs else \
            "a set-point is what a controller tracks"
        raise DataError(f"{what}; give a controller (or use --input for an open-loop signal)")
    K = OpenLoop() if controller is None else controller.loop_law()
    K.check_plant(plant.output_names, plant.input_names, model)
    if controller is not None:
        if abs(controller.Ts - Ts) > _STEP_TOLERANCE * Ts:
            raise ModelError(f"controller Ts={controller.Ts:g} s differs from the experiment Ts={Ts:g} s")
        both = sorted(set(controller.outputs) & set(input_specs))
        if both:
            raise DataError(f"input {', '.join(both)} is driven by the controller; use --excitation for it")
        not_driven = sorted(set(excitation_specs) - set(controller.outputs))
        if not_driven:
            raise DataError(f"excitation on {', '.join(not_driven)}: the controller does not drive it")
        not_read = sorted(set(setpoint_specs) - set(controller.inputs))
        if not_read:
            raise DataError(f"set-point on {', '.join(not_read)}: the controller does not read it "
                            f"(it reads {', '.join(controller.inputs)})")

    u_open = np.empty((n, len(plant.input_names)))
    for j, name in enumerate(plant.input_names):
        spec = input_specs.get(name)
        operating = plant.start_value(name)
        u_open[:, j] = operating if spec is None else generate(spec, n, Ts, signal_rng(seed, name), operating)
    r = {name: generate(spec, n, Ts, signal_rng(seed, "excitation:" + name), 0.0)
         for name, spec in excitation_specs.items()}
    origin = dict(zip(K.inputs, K.setpoint_origin, strict=True))
    s = {name: generate(spec, n, Ts, signal_rng(seed, "setpoint:" + name), origin[name])
         for name, spec in setpoint_specs.items()}
    # the set-points of the outputs K reads (NaN: none given) as K takes them: its references, or a
    # command added to its output (module docstring of lpvflow.loop.protocol)
    setpoints = np.column_stack([s.get(name, np.full(n, np.nan)) for name in K.inputs]) if K.inputs \
        else np.zeros((n, 0))
    references = K.references_of(setpoints)
    added = K.setpoint_command(setpoints) if setpoint_specs else None
    if added is not None:
        r = {name: r.get(name, 0.0) + added[:, j] for j, name in enumerate(K.outputs)}

    y = np.empty((n, len(plant.output_names)))
    u = u_open.copy()
    measure = sensors(n, seed)
    u_index = [plant.input_names.index(name) for name in K.outputs]
    r_matrix = np.column_stack([r.get(name, np.zeros(n)) for name in K.outputs]) if K.outputs else None
    show = None if progress is None else not progress
    bar = tqdm(total=n, unit="step", desc=f"experiment {model}", disable=show)

    def measured(k: int, y_plant: np.ndarray) -> np.ndarray:
        y[k] = measure(k, y_plant)
        return y[k]

    def stop(k: int, y_k: np.ndarray) -> None:  # the scheduling and the law need finite outputs
        if not np.all(np.isfinite(y_k)):
            bad = plant.output_names[int(np.argmin(np.isfinite(y_k)))]
            raise ModelError(f"plant output {bad} is non-finite at t={k * Ts:g} s; the run diverged")
        if (left := outside(k, y_k)) is not None:
            raise ModelError(left)

    def actuate(k: int, u_c: np.ndarray, p: np.ndarray) -> np.ndarray:
        if r_matrix is not None:
            u[k, u_index] = u_c + r_matrix[k]
        return u[k]

    def record(k: int, y_k: np.ndarray, p: np.ndarray, u_c: np.ndarray, u_k: np.ndarray | None) -> None:
        if k % 1000 == 999 or k == n - 1:
            bar.update(k + 1 - bar.n)

    try:
        failure = close_loop(K, plant, n, references, measure=measured, stop=stop, actuate=actuate,
                             record=record, Ts=Ts)
    finally:
        bar.close()
    if failure:
        raise ModelError(f"the experiment's closed loop {failure}; the run diverged")

    signals = dict(zip(plant.input_names, u.T, strict=True)) | dict(zip(plant.output_names, y.T, strict=True))
    outputs = [name for name in plant.output_names
               if record_diagnostics or not name.startswith(DIAGNOSTIC_PREFIX)]
    columns: dict[str, np.ndarray] = {"time": np.round(np.arange(n) * Ts, 12)}
    columns |= {name: signals[name] for name in [*plant.input_names, *outputs]}
    columns |= {f"{name}_excitation": values for name, values in r.items()}
    columns |= {f"{name}_setpoint": values for name, values in s.items()}
    chosen = dict(default_scheduling(plant) if scheduling_columns is None else scheduling_columns)
    for name, expression in chosen.items():
        if name in columns:
            raise DataError(f"scheduling column {name!r} clashes with a recorded signal; choose another name")
        columns[name] = scheduling.evaluate(expression, signals)

    metadata = {
        "model_name": model,
        "Ts": Ts,
        "duration": n * Ts,
        "n_samples": n,
        "seed": int(seed),
        "mode": "open-loop" if controller is None else "closed-loop",
        "inputs": {name: spec.to_dict() for name, spec in input_specs.items()},
        "operating_values": {name: plant.start_value(name) for name in plant.input_names},
        "excitation": {name: spec.to_dict() for name, spec in excitation_specs.items()},
        "setpoint": {name: spec.to_dict() for name, spec in setpoint_specs.items()},
        "controller": None if controller is None else controller.to_dict(),
        "sensors": {"quantization": dict(quantization or {}), "noise": dict(noise or {})},
        "output_bounds": {name: list(pair) for name, pair in (output_bounds or {}).items()},
        "scheduling": chosen,
        "parameters": plant.parameter_values(),
        "columns": {"time": ["time"], "inputs": list(plant.input_names), "outputs": outputs,
                    "excitation": [f"{name}_excitation" for name in r],
                    "setpoint": [f"{name}_setpoint" for name in s], "scheduling": list(chosen)},
    }
    return ExperimentRecord(columns=columns, Ts=Ts, metadata=metadata)


def _sensor_model(
    quantization: Mapping[str, float] | None,
    noise: Mapping[str, float] | None,
    outputs: list[str],
    model: str,
):
    """``make(n, seed)`` returning ``measure(k, y)``: y with each sensor's noise and quantization applied."""
    quantization, noise = dict(quantization or {}), dict(noise or {})
    check_names("quantized output", list(quantization), outputs, model)
    check_names("noisy output", list(noise), outputs, model)
    for kind, table, strict in (("quantization step", quantization, True), ("noise standard deviation",
                                                                            noise, False)):
        for name, value in table.items():
            if not (np.isfinite(value) and (value > 0 if strict else value >= 0)):
                sign = "positive" if strict else "non-negative"
                raise DataError(f"{kind} of {name} = {value} must be a {sign} finite number")
    q = np.array([quantization.get(name, 0.0) for name in outputs])
    quantized = q > 0
    q_safe = np.where(quantized, q, 1.0)

    def make(n: int, seed: int):
        v = np.zeros((n, len(outputs)))
        for j, name in enumerate(outputs):
            if noise.get(name, 0.0) > 0:
                v[:, j] = noise[name] * signal_rng(seed, "noise:" + name).standard_normal(n)
        if not quantized.any() and not noise:
            return lambda k, y: y

        def measure(k: int, y: np.ndarray) -> np.ndarray:
            y = np.asarray(y, dtype=float) + v[k]
            return np.where(quantized, np.round(y / q_safe) * q_safe, y)

        return measure

    return make


def _bounds_check(
    output_bounds: Mapping[str, tuple[float, float]] | None, outputs: list[str], model: str, Ts: float
):
    """``outside(k, y)``: None while every bounded output of y is within its (min, max), else the line
    naming the first that left them, its value and the time."""
    bounds = dict(output_bounds or {})
    if not bounds:
        return lambda k, y: None
    check_names("bounded output", list(bounds), outputs, model)
    pairs = [interval(pair, f"output bounds of {name}") for name, pair in bounds.items()]
    index = np.array([outputs.index(name) for name in bounds], dtype=int)
    lo, hi = (np.array(side) for side in zip(*pairs, strict=True))

    def outside(k: int, y: np.ndarray) -> str | None:
        values = np.asarray(y, dtype=float)[index]
        left = np.flatnonzero((values < lo) | (values > hi))
        if left.size == 0:
            return None
        j = int(left[0])
        return (f"plant output {list(bounds)[j]} = {values[j]:.4g} left its bounds [{lo[j]:g}, {hi[j]:g}] "
                f"at t={k * Ts:g} s; the controller did not hold this experiment (the record is not "
                "data of the range it was meant to cover): make the set-point moves or the excitation "
                "smaller, or widen the bounds")

    return outside


def default_scheduling(plant: Plant) -> dict[str, str]:
    """Scheduling columns when the user names none: the plant's entry in
    :data:`scheduling.PLANT_DEFAULTS`, else ``scheduling = diag_scheduling`` if the FMU has that output."""
    if plant.model_name in scheduling.PLANT_DEFAULTS:
        return dict(scheduling.PLANT_DEFAULTS[plant.model_name])
    if FMU_SCHEDULING_OUTPUT in plant.output_names:
        return {"scheduling": FMU_SCHEDULING_OUTPUT}
    return {}


def sidecar_path(csv_path: str | Path) -> Path:
    """The metadata file written next to the CSV: ``data.csv`` -> ``data.csv.json``."""
    csv_path = Path(csv_path)
    return csv_path.with_name(csv_path.name + ".json")
