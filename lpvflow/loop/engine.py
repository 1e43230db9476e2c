"""The one closed-loop engine: a controller of the protocol (:mod:`lpvflow.loop.protocol`) and a plant
(an FMU, :class:`lpvflow.experiment.plant.Plant`, or an identified model,
:class:`lpvflow.loop.model_plant.ModelPlant`) stepped
together at the controller's Ts. The experiment, the model-in-the-loop validation and verification
close their loops here; what differs between them (sensor models and disturbances on the measurement,
excitation, limits and disturbances on the command, stopping rules, what is recorded) enters through
the hooks of :func:`close_loop`. The diagnosis' input-output model in the identification loop
(:mod:`lpvflow.validate.closed_loop`) runs this sampling convention compiled
(:mod:`lpvflow.validate.loop_recursion`): dozens of whole-record loops per diagnosis.

Sampling convention: at t_k = k Ts read the plant outputs y(k), compute the scheduling p(k) and the
command u(k) = K.step(r(k), y_K(k), p(k)), hold the plant inputs from t_k to t_k + Ts.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np

from lpvflow.errors import LpvflowError
from lpvflow.loop.protocol import LoopController


class LoopPlant(Protocol):
    """What the engine needs of a plant: its signal names, outputs() at the current time and step()."""

    input_names: list[str]
    output_names: list[str]

    def outputs(self) -> np.ndarray: ...

    def step(self, u: np.ndarray, t: float, dt: float) -> None: ...


def close_loop(
    K: LoopController,
    plant: LoopPlant,
    n: int,
    references: np.ndarray,
    *,
    scheduling_names: Sequence[str] | None = None,
    measure: Callable[[int, np.ndarray], np.ndarray] | None = None,
    signals: Callable[[int, np.ndarray], np.ndarray] | None = None,
    actuate: Callable[[int, np.ndarray, np.ndarray], np.ndarray] | None = None,
    stop: Callable[[int, np.ndarray], str | None] | None = None,
    record: Callable[[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None], None] | None = None,
    plant_failure: Callable[[int, LpvflowError], str] | None = None,
    Ts: float | None = None,
    respond: Callable[[int, np.ndarray], np.ndarray] | None = None,
    passes: int = 0,
) -> str | None:
    """Run K and ``plant`` for ``n`` samples; returns why the run stopped early, or None.

    Per sample k: y = ``measure(k, plant.outputs())`` (default: as the plant gives them, in
    ``plant.output_names`` order); ``stop(k, y)`` may end the run with a reason; p = K's schedule of
    ``signals(k, y)`` (default y; named ``scheduling_names``, default the plant's outputs) and
    ``references[k]`` (ny, NaN: hold the operating point); u_c = K.step(references[k], y of K's inputs,
    p) — a non-finite u_c ends the run ("diverged: controller output non-finite at t = …"); the plant
    input vector u = ``actuate(k, u_c, p)`` (default: u_c on K's outputs, the other inputs at their start
    values, ``plant.start_value``); ``record(k, y, p, u_c, u)`` (u None when u_c ended the run); the plant
    steps by Ts (default the controller's). A plant step that fails raises, or with ``plant_failure``
    ends the run with its reason.

    A plant whose output at t_k depends on its input at t_k (direct feedthrough: an algebraic loop with
    K) gives ``respond(k, u)``, its output with u as the present input; y(k) is then resolved from
    ``plant.outputs()`` by ``passes`` fixed-point passes y ← respond(k, actuate(k, K.output(r, y, p), p)),
    p the schedule of y, K's state not advanced (``K``: a
    :class:`~lpvflow.loop.protocol.FeedthroughController`), before ``measure`` and the step."""
    names = list(plant.output_names if scheduling_names is None else scheduling_names)
    schedule = K.scheduling(names)
    y_index = [plant.output_names.index(name) for name in K.inputs]
    u_index = [plant.input_names.index(name) for name in K.outputs]
    if actuate is None:
        held = np.array([plant.start_value(name) for name in plant.input_names], dtype=float)

        def actuate(k: int, u_c: np.ndarray, p: np.ndarray) -> np.ndarray:
            u = held.copy()
            u[u_index] = u_c
            return u

    Ts = K.Ts if Ts is None else Ts
    K.reset()
    for k in range(n):
        t = k * Ts
        y = np.asarray(plant.outputs(), dtype=float)
        for _ in range(passes):
            p = schedule(y if signals is None else signals(k, y), references[k])
            y = respond(k, actuate(k, K.output(references[k], y[y_index], p), p))
        if measure is not None:
            y = measure(k, y)
        if stop is not None and (reason := stop(k, y)) is not None:
            return reason
        p = schedule(y if signals is None else signals(k, y), references[k])
        u_c = K.step(references[k], y[y_index], p)
        if not np.all(np.isfinite(u_c)):
            if record is not None:
                record(k, y, p, u_c, None)
            return f"diverged: controller output non-finite at t = {t:g} s"
        u = actuate(k, u_c, p)
        if record is not None:
            record(k, y, p, u_c, u)
        try:
            plant.step(u, t, Ts)
        except LpvflowError as exc:
            if plant_failure is None:
                raise
            return plant_failure(k, exc)
    return None
