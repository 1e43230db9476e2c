"""What a closed-loop run did, per scenario: tracking metrics, the verdict and the requirements.

Metrics per tracked output (after t_c, the start of the last reference change; Δ its size, r_f the
final reference; the final window is the last 10 % of the run, at least one sample):

    settling_time       time from t_c after which |y − r_f| ≤ band for the rest of the run
                        (band = settling_band if given, else 0.02·|Δ|); None if outside at the end
    overshoot           max(0, max sign(Δ)·(y − r_f)) in output units, and 100·overshoot/|Δ| in %
    peak_deviation      max |y − r_f|
    steady_state_error  |mean(r_f − y)| over the final window
    settled             the output stays inside the band over the whole final window
    iae, ise            integrated tracking error from t_c to the end of the run, Ts·Σ|r_f − y| (output
                        units·s) and Ts·Σ(r_f − y)² (units²·s): one number for speed, overshoot and
                        oscillation together, comparable between controllers on the same scenario

per measured output that is not tracked: after_settling = max |y − r| from the instant the last tracked
output settled to the end of the run (None if one never settles) — e.g. the pendulum while the arm holds;
per actuated input: peak_control max |u| (after the limits) and saturation_time = Ts·#{k: u_c(k) outside
the limits}; per run, the scheduling the loop visited: ``range`` [min p_i, max p_i] per signal and, for a
scheduled LPV controller, its design ``box`` (the scheduling box of its polytope, inside which the
synthesis certificate holds; outside it the convex coordinates are clipped to the nearest face),
``time_outside_box`` = Ts·#{k: p(k) ∉ box} and ``first_outside_box`` (s, or None).
Verdict: stable ⇔ the run finished with finite signals inside ``output_bounds`` and every
tracked output settled. A scenario's ``requirements`` (settling time, overshoot, after-settling bounds)
are checked besides: ``requirements_failed`` lists what the run misses; ``passed`` ⇔ stable and none.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from lpvflow.errors import DataError
from lpvflow.pipeline.scenarios import Loop, Requirements, Scenario, Signal


@dataclass
class ClosedLoopRun:
    """Signals of one closed-loop run, sample k at time[k]; ``failure`` says why it stopped early."""

    label: str
    time: np.ndarray
    reference: np.ndarray
    outputs: np.ndarray
    commanded: np.ndarray
    control: np.ndarray
    scheduling: np.ndarray
    measured: tuple[str, ...]
    actuated: tuple[str, ...]
    failure: str | None = None
    #: (n_p, 2) design box of a scheduled LPV controller (None for LTI laws and controller FMUs).
    scheduling_box: np.ndarray | None = None


def scheduling_coverage(run: ClosedLoopRun) -> dict | None:
    """Visited scheduling range, and the time spent outside the controller's design box (module docstring);
    None when the loop has no scheduling signal."""
    p = run.scheduling[np.isfinite(run.scheduling).all(axis=1)]  # the samples before a failure
    if p.size == 0:
        return None
    coverage: dict = {"range": np.column_stack([p.min(axis=0), p.max(axis=0)]).tolist(), "box": None,
                      "time_outside_box": None, "first_outside_box": None}
    if run.scheduling_box is None:
        return coverage
    lo, hi = run.scheduling_box[:, 0], run.scheduling_box[:, 1]
    slack = 1e-9 * np.maximum(1.0, np.abs(run.scheduling_box)).max(axis=1)
    outside = np.any((p < lo - slack) | (p > hi + slack), axis=1)
    Ts = float(run.time[1] - run.time[0])
    coverage.update(box=run.scheduling_box.tolist(), time_outside_box=float(Ts * outside.sum()),
                    first_outside_box=float(run.time[np.argmax(outside)]) if outside.any() else None)
    return coverage


#: Fraction of the run forming the final window of the steady-state checks.
FINAL_WINDOW = 0.1


#: Default settling band, relative to the size of the last reference change.
RELATIVE_BAND = 0.02


def _last_change(signal: Signal | None) -> float | None:
    times = signal.change_times if signal is not None else []
    return max(times) if times else None


def tracking_metrics(
    time: np.ndarray, y: np.ndarray, reference: Signal | None, r_default: float, band: float | None, what: str
) -> dict:
    """Metrics of one output y (module docstring); ``reference`` None means constant r_default."""
    t_c = _last_change(reference)
    r_f = reference.sample(time[-1:])[0] if reference is not None else r_default
    if t_c is None:
        t_c, delta = float(time[0]), 0.0
    else:
        delta = r_f - reference.sample(np.array([t_c - 1e-6]))[0]
    if band is None:
        band = RELATIVE_BAND * abs(delta)
        if band == 0.0:
            raise DataError(f"{what}: the reference does not change; give settling_band for it")
    k_c = int(np.searchsorted(time, t_c - 1e-9))
    err = y[k_c:] - r_f
    Ts = float(time[1] - time[0]) if len(time) > 1 else 0.0
    outside = np.flatnonzero(~(np.abs(err) <= band))
    settle = k_c if outside.size == 0 else k_c + int(outside[-1]) + 1
    window = len(time) - max(1, math.ceil(FINAL_WINDOW * len(time)))
    overshoot = max(0.0, float(np.max(np.sign(delta) * err))) if delta != 0 else None
    return {
        "settling_time": float(time[settle] - t_c) if settle < len(time) else None,
        "settled": bool(settle <= window),
        "band": float(band),
        "reference_change": float(delta),
        "change_time": float(t_c),
        "overshoot": overshoot,
        "overshoot_percent": None if overshoot is None else 100.0 * overshoot / abs(delta),
        "peak_deviation": float(np.max(np.abs(err))),
        "steady_state_error": float(abs(np.mean(r_f - y[window:]))),
        "iae": float(Ts * np.sum(np.abs(err))),
        "ise": float(Ts * np.sum(err**2)),
    }


def tracked_outputs(scenario: Scenario, loop: Loop) -> list[str]:
    if scenario.tracked is not None:
        return list(scenario.tracked)
    changing = [n for n in loop.measured if n in scenario.reference and scenario.reference[n].change_times]
    names = changing + [n for n in loop.measured if n in scenario.settling_band and n not in changing]
    if not names:
        raise DataError(
            f"scenario {scenario.name!r}: nothing to check; give a reference step or a "
            "settling_band for an output"
        )
    return names


def run_metrics(run: ClosedLoopRun, scenario: Scenario, loop: Loop) -> dict:
    """Metrics and stability verdict of one run (module docstring)."""
    Ts = float(run.time[1] - run.time[0])
    y_op = loop.y_operating_point or (0.0,) * len(loop.measured)
    clipped = np.isfinite(run.commanded) & (run.commanded != run.control)
    applied = np.where(np.isfinite(run.control), np.abs(run.control), -np.inf)
    controls = {
        name: {
            "peak_control": float(applied[:, j].max()) if np.isfinite(applied[:, j].max()) else None,
            "saturation_time": float(Ts * np.sum(clipped[:, j])),
        }
        for j, name in enumerate(run.actuated)
    }
    result = {
        "controller": run.label,
        "stable": False,
        "reason": run.failure,
        "outputs": {},
        "controls": controls,
        "scheduling": scheduling_coverage(run),
    }
    if run.failure is not None:
        if scenario.requirements is not None:
            result["requirements_failed"] = ["the run failed (see reason)"]
        return result
    for name in tracked_outputs(scenario, loop):
        i = loop.measured.index(name)
        result["outputs"][name] = tracking_metrics(
            run.time,
            run.outputs[:, i],
            scenario.reference.get(name),
            y_op[i],
            scenario.settling_band.get(name),
            f"scenario {scenario.name!r}, output {name}",
        )
    unsettled = [name for name, m in result["outputs"].items() if not m["settled"]]
    result["stable"] = not unsettled
    result["reason"] = f"not settled: {', '.join(unsettled)}" if unsettled else "bounded and settled"
    result["after_settling"] = after_settling_peaks(run, scenario, loop, result["outputs"])
    if scenario.requirements is not None:
        result["requirements_failed"] = requirement_failures(
            scenario.requirements, result["outputs"], result["after_settling"])
    return result


def after_settling_peaks(run: ClosedLoopRun, scenario: Scenario, loop: Loop, tracked: Mapping[str, dict]
                         ) -> dict[str, float | None]:
    """max |y − r| of every measured output that is not tracked, from the instant the last tracked output
    settled (t_c + settling_time) to the end of the run; None for all when a tracked output never settled."""
    settled_at = [m["change_time"] + m["settling_time"] for m in tracked.values()
                  if m["settling_time"] is not None]
    others = [name for name in loop.measured if name not in tracked]
    if len(settled_at) < len(tracked):
        return dict.fromkeys(others)
    k = int(np.searchsorted(run.time, max(settled_at, default=run.time[0]) - 1e-9))
    y_op = loop.y_operating_point or (0.0,) * len(loop.measured)
    peaks = {}
    for name in others:
        i = loop.measured.index(name)
        signal = scenario.reference.get(name)
        r = signal.sample(run.time[k:]) if signal is not None else y_op[i]
        peaks[name] = float(np.max(np.abs(run.outputs[k:, i] - r)))
    return peaks


def requirement_failures(requirements: Requirements, tracked: Mapping[str, dict],
                         after_settling: Mapping[str, float | None]) -> list[str]:
    """The requirements a finished run misses, one phrase each (empty: all met)."""
    failures = []
    for name, m in tracked.items():
        limit = requirements.settling_time
        if limit is not None and (m["settling_time"] is None or m["settling_time"] > limit):
            settling = m["settling_time"]
            took = "does not settle" if settling is None else f"settles in {settling:.3g} s"
            failures.append(f"{name} {took} (limit {limit:g} s)")
        limit = requirements.overshoot
        if limit is not None and m["overshoot"] is not None and m["overshoot"] > limit:
            failures.append(f"{name} overshoot {m['overshoot']:.3g} (limit {limit:g})")
    for name, limit in requirements.after_settling.items():
        peak = after_settling.get(name)
        if peak is None:
            failures.append(f"{name} after settling: not measured, the tracked outputs do not settle")
        elif peak > limit:
            failures.append(f"{name} after settling {peak:.3g} (limit {limit:g})")
    return failures
