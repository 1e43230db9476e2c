"""The design stages: each reads its config table and upstream artifacts, writes its own artifacts.

Every stage returns ``(outputs, artifacts)``: a JSON-ready dict of the numbers it produced and the
file names (relative to the design folder) it wrote. :mod:`lpvflow.pipeline.design` wires them,
caches them (:mod:`lpvflow.pipeline.cache`) and reports them.
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from lpvflow.basis import SchedulingRangeWarning
from lpvflow.data import Dataset
from lpvflow.errors import DataError, LpvflowError
from lpvflow.models import LPVSS, load


@dataclass
class StageContext:
    """The design folder, the whole configuration and the outputs of the stages run so far."""

    folder: Path
    config: dict[str, dict[str, Any]]
    outputs: dict[str, dict] = field(default_factory=dict)

    def path(self, name: str) -> Path:
        return self.folder / name


# ------------------------------------------------------------------------------------- experiment
def experiment(ctx: StageContext) -> tuple[dict, list[str]]:
    """Identification experiment on the plant FMU (closed loop when a controller is given)."""
    from lpvflow.experiment.fmu_experiment import run_fmu_experiment

    cfg = ctx.config["experiment"]
    record = run_fmu_experiment(
        ctx.config["design"]["plant"], cfg["Ts"], cfg["duration"], inputs=cfg["inputs"] or None,
        controller=cfg["controller"], excitation=cfg["excitation"] or None,
        parameters=cfg["parameters"] or None, scheduling_columns=cfg["scheduling"] or None,
        seed=cfg["seed"], output=ctx.path("data.csv"), progress=None, setpoint=cfg["setpoint"] or None,
        quantization=cfg["quantization"] or None, noise=cfg["noise"] or None,
    )
    ranges = {name: [float(np.min(v)), float(np.max(v))]
              for name, v in record.columns.items() if name != "time"}
    return {"samples": len(record.time), "Ts": record.Ts, "ranges": ranges}, ["data.csv", "data.csv.json"]


def read_data(ctx: StageContext, model_signals: bool = False) -> tuple[Dataset, Dataset]:
    """Estimation and validation parts, as measured or (``model_signals``) in the signals the model is
    identified in (:func:`model_coordinates`); with ``remove_offsets`` both have the estimation part's mean
    inputs and outputs subtracted (the model then works in deviations from that operating point)."""
    cfg = ctx.config["identify"]
    data = Dataset.read(ctx.path("data.csv"), cfg["u"], cfg["y"], cfg["p"])
    est, val = (model_coordinates(ctx, data) if model_signals else data).split(cfg["split"])
    if not cfg["remove_offsets"]:
        return est, val
    return without_offsets(est, est), without_offsets(val, est)


def model_coordinates(ctx: StageContext, data: Dataset) -> Dataset:
    """The whole record ``data`` in the signals the model is identified in.

    * ``[identify] remove_trim``: each input the experiment controller drives minus that controller's
      trim u_op(θ(k)) (:func:`controller_trim`). The model then describes the plant with the trim closed
      around it. On the ADIP the trim V_eq(φ1) = −d1 sin φ1 / (motor gain) cancels the arm's gravity torque
      d1 sin φ1; left in, that torque has to be carried by LPV coefficients of the absolute arm angle, whose
      frozen value is the secant d1 sin φ1/φ1 instead of the linearization's d1 cos φ1 (ν-gap 0.19 at ±75°
      between the two exact frozen models).
    * ``[identify] increments``: the listed outputs replaced by their increments y(k) − y(k−1) (0 at k = 0);
      :func:`identify` integrates the model back (:func:`lpvflow.identify.realize.integrate_outputs`).
      Coefficients scheduled on a measured, fast-moving p(k) multiply the increments (small, like the
      other signals) instead of an absolute angle of up to 1.3 rad, so an error in their timing stays small.
    """
    cfg = ctx.config["identify"]
    changes: dict[str, np.ndarray] = {}
    if cfg["remove_trim"]:
        changes["u"] = data.u - controller_trim(ctx, data)
    if cfg["increments"]:
        unknown = [name for name in cfg["increments"] if name not in data.y_names]
        if unknown:
            raise DataError(f"[identify] increments {unknown} are not model outputs {data.y_names}")
        y = data.y.copy()
        rows = [data.y_names.index(name) for name in cfg["increments"]]
        y[:, rows] = np.diff(data.y[:, rows], axis=0, prepend=data.y[:1, rows])
        changes["y"] = y
    return replace(data, **changes)


def controller_trim(ctx: StageContext, data: Dataset) -> np.ndarray:
    """The experiment controller's trim at every sample of ``data`` (the whole record), (N, nu) over the
    model inputs (0 for inputs it does not drive): a gridded controller's u_op(θ(k)), θ(k) its scheduling
    expression of the recorded measurements and set-points (``<output>_setpoint``, 0 where not recorded)
    and u_op interpolated linearly on its grid, clipped at the ends, as the controller ran
    (:meth:`~lpvflow.experiment.controller.GriddedController.at`); an LTI controller's constant u_op; an LPV
    controller's u_op + u_eq(p(k)), p(k) its scheduling expressions of the recorded outputs
    (:meth:`~lpvflow.experiment.synthesized.SynthesizedController.trim_along`)."""
    from lpvflow.data import read_columns
    from lpvflow.experiment.controller import GriddedController, load_experiment_controller
    from lpvflow.experiment.scheduling import evaluate
    from lpvflow.experiment.synthesized import SynthesizedController

    path = ctx.config["experiment"]["controller"]
    if not path:
        raise DataError("[identify] remove_trim needs an [experiment] controller (its trim is removed)")
    K = load_experiment_controller(path)
    missing = [name for name in K.outputs if name not in data.u_names]
    if missing:
        raise DataError(f"[identify] remove_trim: the experiment controller drives {missing}, which are not "
                        f"model inputs {data.u_names}")
    trim = np.zeros_like(data.u)
    columns = [data.u_names.index(name) for name in K.outputs]
    if not isinstance(K, GriddedController | SynthesizedController):
        trim[:, columns] = K.u_op
        return trim
    table = read_columns(ctx.path("data.csv"))
    if isinstance(K, SynthesizedController):
        trim[:, columns] = K.trim_along(table, data.N)
        return trim
    signals = {name: table[name][: data.N] for name in K.inputs}
    signals |= {f"{name}_setpoint": table.get(f"{name}_setpoint", np.zeros(len(table["time"])))[: data.N]
                for name in K.inputs}
    theta = np.broadcast_to(evaluate(K.scheduling, signals), (data.N,))
    trim[:, columns] = np.column_stack([np.interp(theta, K.grid, column) for column in K.u_op.T])
    return trim


def without_offsets(data: Dataset, est: Dataset) -> Dataset:
    """``data`` minus the mean inputs and outputs of ``est`` (the operating point), recorded in
    ``offsets``."""
    u0, y0 = est.u.mean(axis=0), est.y.mean(axis=0)
    return replace(data, u=data.u - u0, y=data.y - y0, offsets={"u": u0.tolist(), "y": y0.tolist()})


# -------------------------------------------------------------------------------------- identify
def identify(ctx: StageContext) -> tuple[dict, list[str]]:
    """The ``[identify] method`` estimator (:func:`lpvflow.pipeline.cli_identify.estimate`, any method of
    ``lpvflow identify``) on the estimation part, as a state-space model: IO models realized exactly
    (``LPVIO.to_ss``), pbsid and cva as estimated, an LFR converted when its dependence is affine
    (kcca-lfr-affine). IO models get the one-step-ahead equation-error residuals on the validation part
    (BFR, Ljung–Box p-value, residuals.png); state-space models do not (their fit is the validate stage's).
    Two-step takes the external excitation from the column ``[identify] excitation`` (default: the
    experiment's ``<input>_excitation`` column of the first input). The estimator sees the signals of
    :func:`model_coordinates` (the residuals are theirs: an output in ``increments`` has its increments'
    residuals); outputs in ``increments`` are integrated back into the saved model."""
    from lpvflow.identify.arx import prediction_residuals
    from lpvflow.lfr import LPVLFR, require_affine
    from lpvflow.pipeline.cli_identify import IO_METHODS, estimate

    cfg = ctx.config["identify"]
    method = cfg["method"]
    if method == "static-arx":
        raise DataError("[identify] method = \"static-arx\" has no state-space realization (static "
                        "dependence); use \"lpr-arx\" or another shifted-form method")
    est, val = read_data(ctx, model_signals=True)
    excitation = None
    if method == "two-step":
        from lpvflow.data import read_columns

        column = cfg["excitation"] or f"{cfg['u'][0]}_excitation"
        table = read_columns(ctx.path("data.csv"))
        if column not in table:
            raise DataError(f"[identify] method = \"two-step\" needs the excitation column {column!r}, which "
                            "the data lack; set [identify] excitation to a column of data.csv")
        excitation = table[column][: est.N]
    try:
        model = estimate(prefiltered(est, cfg["prefilter"]), method, cfg["na"], cfg["nb"], cfg["nk"],
                         cfg["basis"], ridge=cfg["ridge"], nc=cfg["nc"], excitation=excitation,
                         past=cfg["past"], order=cfg["order"])
    except LpvflowError as exc:
        raise DataError(f"[identify] method = {method!r}: {exc}") from None
    outputs: dict[str, Any] = {"method": method}
    artifacts = ["model_full.json"]
    if method in IO_METHODS:
        io, ss = model, model.to_ss()
        residuals = prediction_residuals(io, val)
        from lpvflow.pipeline.verify import fmu_units

        units = fmu_units(ctx.config["design"]["plant"])
        one_step = 100 * (1 - np.linalg.norm(residuals, axis=0)
                          / np.linalg.norm(val.y[io.max_lag:] - val.y[io.max_lag:].mean(axis=0), axis=0))
        outputs |= {"one_step_bfr_validation": one_step.tolist(),
                    "ljung_box_p_value": plot_residuals(ctx.path("residuals.png"), residuals, val.Ts,
                                                        val.y_names, units)}
        artifacts.append("residuals.png")
    else:
        try:
            ss = require_affine(model) if isinstance(model, LPVLFR) else model
        except LpvflowError as exc:
            raise DataError(f"[identify] method = {method!r}: {exc}; use \"kcca-lfr-affine\"") from None
    if cfg["increments"]:
        from lpvflow.identify.realize import integrate_outputs

        ss = integrate_outputs(ss, cfg["increments"])
    ss.save(ctx.path("model_full.json"))
    if cfg["remove_trim"]:
        outputs["input"] = f"{', '.join(ss.u_names)} minus the trim u_op(θ) of the experiment controller"
    outputs |= {"nx": ss.nx, "offsets": est.offsets,
                "scheduling_range": [list(ss.basis.p_min), list(ss.basis.p_max)]}
    return outputs, artifacts


def prefiltered(data: Dataset, spec: str) -> Dataset:
    """``data`` with its inputs and outputs filtered by the ``[identify] prefilter``: ``"none"``,
    ``"lowpass:F"`` or ``"bandpass:F1,F2"`` (Hz), a 2nd-order Butterworth filter run forwards and backwards
    (zero phase, ``scipy.signal.sosfiltfilt``); the scheduling signals stay as measured. Filtering u and y
    by the same L(q) leaves an LTI relation between them unchanged and weights the equation error of
    ARX by L, which keeps the quantization and sensor noise above F out of the fit (Ljung, *System
    Identification*, 2nd ed., §14.4); for LPV data it is exact only while the scheduling varies slowly
    compared with the filter."""
    if spec == "none":
        return data
    import scipy.signal

    kind, band = parse_prefilter(spec)
    if band[-1] >= 0.5 / data.Ts:
        raise DataError(f"[identify] prefilter = {spec!r}: the frequencies must lie below the Nyquist "
                        f"frequency {0.5 / data.Ts:g} Hz of the data")
    cutoff = band if kind == "bandpass" else band[0]
    sos = scipy.signal.butter(2, cutoff, kind, fs=1.0 / data.Ts, output="sos")
    return replace(data, u=scipy.signal.sosfiltfilt(sos, data.u, axis=0),
                   y=scipy.signal.sosfiltfilt(sos, data.y, axis=0))


def parse_prefilter(spec: str) -> tuple[str, list[float]]:
    """``"lowpass:F"`` → ("lowpass", [F]); ``"bandpass:F1,F2"`` → ("bandpass", [F1, F2])."""
    kind, _, body = spec.partition(":")
    try:
        band = [float(v) for v in body.split(",")]
    except ValueError:
        band = []
    count = {"lowpass": 1, "bandpass": 2}.get(kind)
    if count is None or len(band) != count or not all(np.isfinite(band)) or min(band) <= 0 or (
            count == 2 and band[0] >= band[1]):
        raise DataError(f"[identify] prefilter = {spec!r} must be \"none\", \"lowpass:F\" or "
                        "\"bandpass:F1,F2\" with 0 < F1 < F2 in Hz")
    return kind, band


def plot_residuals(
    path: Path, residuals: np.ndarray, Ts: float, names: list[str], units: dict[str, str] | None = None,
    lags: int = 50,
) -> list[float]:
    """Residual time series and autocorrelation r̂_ee(τ), τ ≤ ``lags``, with the 99 % band ±2.58/√N of a
    white sequence, one row per output (PNG); returns the Ljung–Box p-value (20 lags) per output."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lpvflow.validate.residuals import autocorrelation, band99, ljung_box

    t = np.arange(len(residuals)) * Ts
    fig, axes = plt.subplots(len(names), 2, figsize=(10, 2.4 * len(names)), squeeze=False)
    p_values = []
    for (ax_t, ax_r), name, e in zip(axes, names, residuals.T, strict=True):
        p_values.append(ljung_box(e)[1])
        ax_t.plot(t, e, lw=0.5)
        unit = (units or {}).get(name)
        ax_t.set(xlabel="time [s]", ylabel=f"ε {name} [{unit}]" if unit else f"ε {name}")
        band = band99(len(e))
        r = autocorrelation(e, lags)  # fewer than lags + 1 values for a residual shorter than lags
        ax_r.stem(np.arange(len(r)), r, basefmt=" ")
        ax_r.axhspan(-band, band, color="tab:green", alpha=0.2)
        ax_r.set(xlabel="lag", ylabel="r̂_εε", title=f"Ljung–Box p = {p_values[-1]:.2g}")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return p_values


# -------------------------------------------------------------------------------------- diagnose
def adoption_refusal(result) -> str | None:
    """Why a diagnosis' extended model cannot replace the design model (None: it can): it adds inputs,
    or it is fitted on a mapped input or output (an input map, a play operator, a clipped output,
    y − sensor offset) that a controller design model does not carry, or it is not in shifted form."""
    mapped = result.cause in ("input_nonlinearity", "backlash", "sensor_saturation") or (
        result.cause == "offset" and result.parameters.get("kind") == "sensor")
    if result.winner.inputs_added or mapped or result.winner.fit.model.form != "shifted":
        return (f"the {result.cause} extension changes the model's inputs or is fitted on a mapped input "
                "or output; the design model stays as identified")
    return None


def diagnose(ctx: StageContext) -> tuple[dict, list[str]]:
    """Diagnosis of the identify structure on the experiment data (issue 8); with ``adopt`` the
    extended model replaces the identified one for the rest of the design.

    Only extensions that keep the model's inputs and outputs can be adopted (a dead time, orders, a
    richer basis, another estimator): offset, friction, actuator-map, backlash and sensor-saturation
    extensions add inputs or are fitted on mapped signals (an input map, a play operator, a clipped
    output, y − offset) a controller design model cannot carry, so they are reported but not adopted.

    With an experiment controller (closed-loop data) every model is simulated in the identification
    loop with the experiment's scheduling expressions (as :func:`closed_loop_simulation` does).
    With ``remove_offsets`` the diagnosed record has the same offsets subtracted as the identify stage's
    data (:func:`read_data`, :func:`without_offsets`), so an adopted model works in the same deviation
    coordinates.
    """
    from lpvflow.data import read_columns
    from lpvflow.experiment.controller import LtiController, load_experiment_controller
    from lpvflow.validate.diagnose import diagnose as run_diagnosis
    from lpvflow.validate.diagnose_plot import plot_diagnosis
    from lpvflow.validate.extensions import Structure

    cfg, ident = ctx.config["diagnose"], ctx.config["identify"]
    if ident["remove_trim"] or ident["increments"]:
        raise DataError("[diagnose] works on the measured signals: it cannot be combined with [identify] "
                        "remove_trim or increments")
    table = read_columns(ctx.path("data.csv"))  # read once: the dataset and the candidate columns
    data = Dataset.from_columns(table, "data.csv", ident["u"], ident["y"], ident["p"], time="auto")
    experiment = ctx.config["experiment"]
    if ident["remove_offsets"]:
        if experiment["controller"]:
            raise DataError("[diagnose] with [identify] remove_offsets needs open-loop data (the experiment "
                            "controller acts on the measured signals, not on deviations)")
        data = without_offsets(data, data.split(ident["split"])[0])  # the identify stage's operating point
    missing = [c for c in cfg["candidates"] if c not in table]
    if missing:
        raise DataError(f"[diagnose] candidate column(s) {missing} are not in the experiment data")
    structure = Structure(ident["na"], ident["nb"], ident["nk"], ident["basis"])
    controller = load_experiment_controller(experiment["controller"]) if experiment["controller"] else None
    if controller is not None and not isinstance(controller, LtiController):
        raise DataError("[diagnose] simulates the identification loop with an lpvflow/lti-controller only; "
                        f"the [experiment] controller is a scheduled one ({controller.to_dict()['format']})")
    result = run_diagnosis(data, structure, {c: table[c] for c in cfg["candidates"]}, split=cfg["split"],
                           controller=controller, scheduling=experiment["scheduling"])
    plot_diagnosis(result, data, ctx.path("diagnosis.png"), cfg["split"])
    outputs = {"cause": result.cause, "parameters": result.parameters, "summary": result.summary,
               "bfr_before": result.bfr_before, "bfr_after": result.bfr_after,
               "ranking": [{k: r[k] for k in ("cause", "bfr_gain", "p_value")} for r in result.ranking],
               "adopted": False, "model": "model_full.json"}
    if cfg["adopt"] and result.winner is not None:
        refusal = adoption_refusal(result)
        if refusal:
            outputs["adoption_refused"] = refusal
        else:
            result.winner.fit.model.to_ss().save(ctx.path("model_extended.json"))
            outputs.update(adopted=True, model="model_extended.json")
    artifacts = ["diagnosis.png"] + (["model_extended.json"] if outputs["adopted"] else [])
    return outputs, artifacts


# ---------------------------------------------------------------------------------------- reduce
def reduce_model(ctx: StageContext) -> tuple[dict, list[str]]:
    """LPV Ho-Kalman-like reduction (Schulz et al. Lemma 1); order from the config or automatic.

    The reduction does not preserve stability. With an automatic order, the order is raised from the
    singular-value choice until the reduced model's largest frozen spectral radius over the scheduling
    range exceeds the full model's by at most ``RADIUS_TOLERANCE`` (so no spurious unstable mode).
    """
    from lpvflow.identify.reduce import plot_singular_values, reduce

    ss = load(ctx.path(ctx.outputs.get("diagnose", {}).get("model", "model_full.json")))
    order = ctx.config["reduce"]["order"]
    reduced = reduce(ss, order=order)
    rule = "given" if order is not None else "singular values"
    if order is None:
        limit = _max_frozen_radius(ss) + RADIUS_TOLERANCE
        while reduced.nx < ss.nx and _max_frozen_radius(reduced) > limit:
            reduced = reduce(ss, order=reduced.nx + 1)
            rule = "raised until the frozen spectral radius matches the full model's"
    reduced.save(ctx.path("model.json"))
    plot_singular_values(reduced.reduction, ctx.path("singular_values.png"))
    return ({"order": reduced.nx, "full_order": ss.nx, "order_rule": rule,
             "max_frozen_radius": _max_frozen_radius(reduced),
             "full_max_frozen_radius": _max_frozen_radius(ss),
             "singular_values": reduced.reduction["singular_values"]},
            ["model.json", "singular_values.png"])


#: How much a reduced model's frozen spectral radius may exceed the full model's.
RADIUS_TOLERANCE = 1e-3


def _max_frozen_radius(model: LPVSS, points: int = 9) -> float:
    """Largest spectral radius of A(θ) on a grid over the recorded scheduling box."""
    lo, hi = np.asarray(model.basis.p_min), np.asarray(model.basis.p_max)
    grid = lo + np.linspace(0, 1, points)[:, None] * (hi - lo)
    return float(max(np.max(np.abs(np.linalg.eigvals(model.matrices(p)[0]))) for p in grid))


# -------------------------------------------------------------------------------------- validate
def closed_loop_simulation(model: LPVSS, data: Dataset, ctx: StageContext) -> np.ndarray:
    """Simulate the model in the experiment's loop: the identification controller and its excitation.

    An unstable plant's model cannot be simulated open loop; the thesis validates the ADIP model by
    the closed loop T(Ĝ, K_id) (notes_002 §6.4). The scheduling p(k) is recomputed from the simulated
    outputs with the experiment's scheduling expressions (quasi-LPV, as on the plant); y(k) uses C at
    p(k−1), which is exact for the observable-form realizations (C independent of p). A gridded
    (gain-scheduled) controller runs its own law on the simulated outputs and the recorded set-points
    (``<output>_setpoint``) and excitation (``<input>_excitation``); so does an LPV controller
    (:class:`~lpvflow.experiment.synthesized.SynthesizedController`: references from the recorded set-points,
    else its operating points, scheduling from the simulated outputs). With ``[identify] remove_trim`` the
    model's input is the controller's output without its trim u_op (:func:`model_coordinates`).
    """
    from lpvflow.data import read_columns
    from lpvflow.experiment.controller import GriddedController, load_experiment_controller
    from lpvflow.experiment.scheduling import compile_expression
    from lpvflow.experiment.synthesized import SynthesizedController

    cfg = ctx.config["experiment"]
    if not cfg["controller"]:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SchedulingRangeWarning)
            return model.simulate(data.u, data.p)
    K = load_experiment_controller(cfg["controller"])
    table = read_columns(ctx.path("data.csv"))
    start = len(table["time"]) - data.N
    zero = np.zeros(len(table["time"]))
    excitation = np.column_stack([table.get(f"{n}_excitation", zero)[start:] for n in K.outputs])
    check_wiring(K, data.u_names, data.y_names, "[validate] closed-loop fit")
    u_index = [data.u_names.index(n) for n in K.outputs]
    y_index = [data.y_names.index(n) for n in K.inputs]
    expressions = [compile_expression(cfg["scheduling"][name], data.y_names) for name in data.p_names]
    gridded = isinstance(K, GriddedController)
    with_trim = not ctx.config["identify"]["remove_trim"]
    if gridded:
        given = [j for j, n in enumerate(K.inputs) if f"{n}_setpoint" in table]
        setpoints = np.zeros((data.N, len(K.inputs)))
        for j in given:
            setpoints[:, j] = table[f"{K.inputs[j]}_setpoint"][start:]
        theta_of = K.scheduling_function()
    synthesized = isinstance(K, SynthesizedController)
    if synthesized:
        references = np.column_stack([table[f"{n}_setpoint"][start:] if f"{n}_setpoint" in table
                                      else np.full(data.N, y0)
                                      for n, y0 in zip(K.inputs, K.y_op, strict=True)])
        schedule = K.scheduling_function(data.y_names)
        K.reset()
    x, xc = np.zeros(model.nx), np.zeros(0 if synthesized else K.A.shape[-2])
    y_sim = np.zeros_like(data.y)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SchedulingRangeWarning)
        C = model.matrices(data.p[0])[2]
        for k in range(data.N):
            y = C @ x  # C at p(k−1): one matrix evaluation per sample
            y_sim[k] = y
            p = np.array([scheduling_of(y) for scheduling_of in expressions])
            A, B, C, _ = model.matrices(p)
            u = np.zeros(model.nu)
            if gridded:
                Ak, Bk, Ck, Dk, y_bar, u_op = K.at(theta_of(np.concatenate([y[y_index], setpoints[k]])))
                y_bar[given] = setpoints[k, given]
                dy = y[y_index] - y_bar
                u[u_index] = with_trim * u_op + Ck @ xc + Dk @ dy + excitation[k]
                xc = Ak @ xc + Bk @ dy
            elif synthesized:
                p_K = schedule(y)
                u[u_index] = K.command(references[k], y[y_index], p_K) + excitation[k]
                if not with_trim:
                    u[u_index] -= K.trim(p_K)
            else:
                dy = y[y_index] - K.y_op
                u[u_index] = with_trim * K.u_op + K.C @ xc + K.D @ dy + excitation[k]
                xc = K.A @ xc + K.B @ dy
            x = A @ x + B @ u
            if not np.all(np.abs(x) < 1e12):
                raise DataError(f"the identified model's closed loop diverges at sample {k}: it does not "
                                "describe the plant under the identification controller")
    return y_sim


def check_wiring(K, u_names: list[str], y_names: list[str], where: str) -> None:
    """One DataError line when the experiment controller ``K`` reads an output or drives an input that
    is not a model signal (``where`` names the check)."""
    unknown = [n for n in K.inputs if n not in y_names] + [n for n in K.outputs if n not in u_names]
    if unknown:
        raise DataError(f"{where}: the experiment controller reads {list(K.inputs)} and drives "
                        f"{list(K.outputs)}; {unknown[0]!r} is not a model signal {u_names + y_names}")


def validate(ctx: StageContext) -> tuple[dict, list[str]]:
    """Fit on validation data (closed-loop simulation under the experiment's controller) and, on a grid
    of frozen scheduling values, the generalized stability margin b(Ĝ(θ), K_id) and — with
    ``reference = "linearization"`` or ``"local"`` — the ν-gap δν(G_FMU(θ), Ĝ(θ)) to the plant FMU at
    its equilibrium with that scheduling value, and the gate's margin b − δν at each point (thesis
    Fig. 6.11, notes_002 §6.4: δν < b over the range means K_id stabilizes every frozen plant the model is
    that close to)."""
    from lpvflow.pipeline.cli_identify import plot_fit
    from lpvflow.validate.frozen import compare_frozen
    from lpvflow.validate.metrics import fit_report
    from lpvflow.validate.plots import bode_overlay, gap_margin_plot

    cfg = ctx.config["validate"]
    model = load(ctx.path("model.json"))
    est, val = read_data(ctx)
    artifacts = []
    fit_failure = None
    try:
        y_sim = closed_loop_simulation(model, val, ctx)
    except DataError as exc:  # a finding about the model, reported; the frozen checks still run
        fit, fit_failure = None, str(exc)
    else:
        fit = fit_report(val.y, y_sim, val.y_names)
        from lpvflow.pipeline.verify import fmu_units

        plot_fit(ctx.path("fit.png"), val, y_sim, fmu_units(ctx.config["design"]["plant"]))
        artifacts.append("fit.png")
    reference = _fmu_reference(ctx, model)
    K, K_note, trim_feedback = _frozen_experiment_controller(ctx, model, reference)
    compared = reference if trim_feedback is None else _trim_closed(reference, trim_feedback)
    scale = _scaling(cfg["scaling"], est, model)
    box = np.column_stack([model.basis.p_min, model.basis.p_max])
    points = cfg["points"]
    if points and any(len(point) != model.basis.n_p for point in points):
        raise DataError(f"[validate] points: each point needs {model.basis.n_p} value(s), one per scheduling "
                        f"signal {model.p_names}")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SchedulingRangeWarning)
            rows = []
            if K is not None or reference is not None:
                frozen_K = K is not None and not hasattr(K, "A")  # a gridded K_id: p ↦ K_id(θ(p))
                scaled_K = (lambda p: scale.controller(K(p))) if frozen_K else scale.controller(K)
                rows = compare_frozen(scale.model(model), scale.plant_at(compared), cfg["grid"], scaled_K,
                                      box=box, points=points or None)
            if reference is not None:
                points = [np.asarray(row["p"]) for row in rows]
                shown = [points[i] for i in sorted({0, len(points) // 2, len(points) - 1})]
                bode_overlay(ctx.path("bode.png"), model.frozen, compared, shown)
                gap_margin_plot(ctx.path("nugap.png"), rows)
                artifacts += ["bode.png", "nugap.png"]
    finally:
        if reference is not None:
            reference.close()
    outputs: dict[str, Any] = {"fit": fit, "scaling": cfg["scaling"], "theta": [row["p"] for row in rows],
                               "b_P_Kid": [row["stability_margin_b"] for row in rows
                                           if "stability_margin_b" in row]}
    if fit_failure:
        outputs["fit_failure"] = fit_failure
    if K_note:
        outputs["b_P_Kid_note"] = K_note
    if reference is not None:
        outputs["reference"] = cfg["reference"]
        outputs["nugap"] = [row["nugap"] for row in rows]
        if K is not None:
            outputs["gate_margin"] = [row["stability_margin_b"] - row["nugap"] for row in rows]
            outputs["nugap_below_b_everywhere"] = all(row["passes"] for row in rows)
    outputs["gate"] = gate_verdict(outputs, cfg["gate"])
    return outputs, artifacts


def gate_verdict(outputs: dict, enabled: bool) -> dict:
    """The ν-gap/b(P, K) gate of the validate stage: ``{"passed": bool | None, "reason": str}``.

    The model passes when δν(G_FMU(θ), Ĝ(θ)) < b(Ĝ(θ), K_id) at every frozen grid point, i.e. the
    identification controller provably stabilizes every frozen plant as close to the model as the FMU
    is (Vinnicombe's robust-stability test; thesis Fig. 6.11). ``passed`` is False when it fails, with the
    worst point in the reason (the design then stops after validate when the gate is on), and None when
    it was not evaluated (gate off, or no FMU reference or no experiment controller to compute it)."""
    if not enabled:
        return {"passed": None, "reason": "gate off ([validate] gate = false)"}
    if "nugap_below_b_everywhere" not in outputs:
        return {"passed": None, "reason": "not evaluated: the ν-gap test needs [validate] reference = "
                                          "\"linearization\" or \"local\" and an [experiment] controller"}
    gaps, margins, theta = outputs["nugap"], outputs["b_P_Kid"], outputs["theta"]
    worst = int(np.argmax(np.asarray(gaps) - np.asarray(margins)))
    where = ", ".join(f"{v:.3g}" for v in theta[worst])
    if outputs["nugap_below_b_everywhere"]:
        return {"passed": True, "reason": f"ν-gap < b(P, K_id) at all {len(gaps)} frozen points (closest at "
                                          f"θ = {where}: ν-gap {gaps[worst]:.3g} < b {margins[worst]:.3g})"}
    failing = sum(g >= b for g, b in zip(gaps, margins, strict=True))
    reason = (f"the identified model fails the ν-gap test at {failing} of {len(gaps)} frozen points "
              f"(worst θ = {where}: ν-gap {gaps[worst]:.3g} ≥ b(P, K_id) {margins[worst]:.3g}); "
              "it is not used for synthesis")
    return {"passed": False, "reason": reason}


def _scaling(setting: str | dict, est: Dataset, model: LPVSS):
    """The ν-gap's signal scaling: the estimation data's standard deviations (``"data"``), none, or the
    scales of a table ``{ signal = scale }`` naming every model input and output."""
    from lpvflow.validate.scaling import SignalScaling

    if isinstance(setting, dict):
        missing = [n for n in [*model.u_names, *model.y_names] if n not in setting]
        extra = sorted(set(setting) - set(model.u_names) - set(model.y_names))
        if missing or extra:
            what = (f"; missing {missing}" if missing else "") + (f"; unknown {extra}" if extra else "")
            raise DataError(f"[validate] scaling needs one scale per model input and output "
                            f"{[*model.u_names, *model.y_names]}{what}")
        return SignalScaling(np.array([setting[n] for n in model.u_names]),
                             np.array([setting[n] for n in model.y_names]))
    return SignalScaling(est.u.std(axis=0), est.y.std(axis=0), enabled=setting == "data")


def _frozen_experiment_controller(
    ctx: StageContext, model: LPVSS, reference
) -> tuple[object, str | None, object]:
    """K_id for b(Ĝ(θ), K_id), in negative feedback over the model's signals, a note (or None), and the
    trim's feedback (or None).

    An LTI experiment controller is the same at every θ. A scheduled one (gridded or LPV) is linearized
    (:meth:`~lpvflow.experiment.controller.GriddedController.operating_laws`,
    :meth:`~lpvflow.experiment.synthesized.SynthesizedController.operating_laws`: frozen at its own
    scheduling value, with the trim's feedback) at the FMU equilibrium with that θ (the reference's
    operating point, set-points equal to the outputs there); without an FMU reference that point is
    unknown and b is not computed (the note says so). With ``[identify] remove_trim`` the model's input is
    u − u_op(θ), so K_id is the controller frozen without the trim's feedback, and the third item is
    p ↦ that feedback T(p), the static gain with u = −T y (−∂u_op/∂y at the equilibrium), which
    :func:`_trim_closed` closes around the FMU linearization: the loop (G_FMU, K_id with trim) is the loop
    (G_FMU closed by T, K_id without it)."""
    from lpvflow.experiment.controller import LtiController, load_experiment_controller

    path = ctx.config["experiment"]["controller"]
    if not path:
        return None, None, None
    K = load_experiment_controller(path)
    check_wiring(K, model.u_names, model.y_names, "[validate] b(Ĝ(θ), K_id)")
    if isinstance(K, LtiController):  # a constant trim has no feedback
        return K.negative_feedback(model.y_names, model.u_names), None, None
    if reference is None:
        return None, ("b(Ĝ(θ), K_id) needs the operating point of the scheduled experiment controller at "
                      "each θ; set [validate] reference = \"linearization\" to compute it"), None
    operating = reference.reference
    trim_removed = ctx.config["identify"]["remove_trim"]

    @functools.cache
    def laws(p: tuple[float, ...]) -> tuple:
        point = operating.equilibrium(np.array(p))
        outputs = dict(zip(operating.plant.output_names, point.y, strict=True))
        return tuple(law.negative_feedback(model.y_names, model.u_names) for law in K.operating_laws(outputs))

    def frozen(p: np.ndarray):
        linearized, bare = laws(tuple(np.asarray(p, dtype=float).tolist()))
        return bare if trim_removed else linearized

    def trim_feedback(p: np.ndarray) -> np.ndarray:
        linearized, bare = laws(tuple(np.asarray(p, dtype=float).tolist()))
        return linearized.D - bare.D

    return frozen, None, trim_feedback if trim_removed else None


def _trim_closed(reference, trim_feedback):
    """p ↦ the frozen reference G(p) with the trim's feedback closed around it, u = u_model − T(p) y: the
    plant as the model sees it with ``[identify] remove_trim``."""
    import control

    return lambda p: control.feedback(reference(p), trim_feedback(p), sign=-1)


def _fmu_reference(ctx: StageContext, model: LPVSS):
    """The plant FMU as frozen reference p ↦ discrete LTI over the model's inputs and outputs, or None.

    Scheduling expressions: the experiment's definition of each model scheduling column (e.g.
    ``sin_arm = "sin(arm_angle)"``), else the column name itself (a plant signal). The FMU gets the
    experiment's parameters except the measurement-noise effect (finite differences need exact outputs)."""
    from lpvflow.validate.fmu_reference import FmuLinearization, FmuLocalModels, SelectedChannels

    cfg = ctx.config["validate"]
    kind = cfg["reference"]
    if kind == "none":
        return None
    classes = {"linearization": FmuLinearization, "local": FmuLocalModels}
    if kind not in classes:
        raise DataError(f"[validate] reference = {kind!r}; use \"none\", \"linearization\" or \"local\"")
    definitions = ctx.config["experiment"]["scheduling"]
    expressions = [definitions.get(name, name) for name in model.p_names]
    parameters = {name: value for name, value in ctx.config["experiment"]["parameters"].items()
                  if not name.startswith("effect_noise")}
    reference = classes[kind](ctx.config["design"]["plant"], model.Ts, expressions,
                              start=cfg["operating_point"], parameters=parameters)
    try:
        return SelectedChannels(reference, model.u_names, model.y_names)
    except DataError as exc:
        reference.close()
        raise DataError(f"[validate] {exc}") from None


# ----------------------------------------------------------------------------------------- synth
def synth(ctx: StageContext) -> tuple[dict, list[str]]:
    """Gain-scheduled H∞ controller of the ``[synth]`` table (:func:`lpvflow.synth.design.synthesize_design`)
    and the LTI baseline designed by the same table at one frozen point (``baseline_at``, default the
    centre of the scheduling box; one common Lyapunov matrix there is exact)."""
    from lpvflow.synth.design import synthesize_design
    from lpvflow.synth.polytope import scheduling_box

    cfg = ctx.config["synth"]
    model = load(ctx.path("model.json"))
    design = synthesize_design(model, cfg)
    controller = design.controller
    signals = design_signals(ctx, model)
    controller.info["signals"] = signals
    controller.antiwindup = antiwindup(ctx, controller, signals, design.antiwindup_gains)
    controller.save(ctx.path("controller.json"))
    centre = scheduling_box(model, cfg["box"]).mean(axis=1).tolist()
    at = cfg["baseline_at"] if cfg["baseline_at"] is not None else centre
    baseline = synthesize_design(model, cfg, box=[[v, v] for v in at])
    baseline.controller.antiwindup = antiwindup(ctx, baseline.controller, signals)
    baseline.controller.save(ctx.path("baseline.json"))
    return ({"method": cfg["method"], "structure": cfg["structure"], "gamma": design.gamma,
             "gamma_lower": design.gamma_lower, "baseline_gamma": baseline.gamma, "baseline_at": at,
             "certificate": design.certificate.lines(), "certificate_ok": bool(design.certificate.ok),
             "solve_seconds": design.seconds, "order": controller.order,
             "polytope": design.plant.polytope.kind},
            ["controller.json", "baseline.json"])


def antiwindup(ctx: StageContext, controller, signals: dict, gains: np.ndarray | None = None):
    """The anti-windup law of a synthesized controller (:class:`lpvflow.synth.controller.AntiWindup`) for
    the actuator limits of ``[verify.loop]`` around the actuated inputs' operating points, with the
    design's own ``gains`` (the observer design's) or :func:`lpvflow.synth.controller.observer_gains`;
    None when the design has no verification loop or limits none of the controller's outputs."""
    from lpvflow.pipeline.scenarios import parse_loop
    from lpvflow.synth.controller import AntiWindup, observer_gains

    if not ctx.config["verify"]:
        return None
    limits = parse_loop(ctx.config["verify"]["loop"]).actuator_limits
    names = [port["name"] for port in signals["actuated"]]
    if not any(name in limits for name in names):
        return None
    lo, hi = (np.array([limits.get(name, (-np.inf, np.inf))[i] for name in names]) for i in (0, 1))
    u_op = np.array([port["operating_point"] for port in signals["actuated"]])
    L = observer_gains(controller.Ak, controller.Ck) if gains is None else gains
    return AntiWindup(L, lo, hi, u_op)


def design_signals(ctx: StageContext, model: LPVSS) -> dict:
    """The controller's port record (:func:`lpvflow.pipeline.export.describe_signals`): the model's
    signal names, the experiment's scheduling expressions, units and descriptions from the plant FMU,
    operating points from ``[verify.loop]`` (else the FMU's input start values, as verify uses)."""
    from lpvflow.pipeline.export import describe_signals
    from lpvflow.pipeline.scenarios import parse_loop

    operating_point = {}
    if ctx.config["verify"]:
        loop = parse_loop(ctx.config["verify"]["loop"])
        pairs = ((loop.measured, loop.y_operating_point), (loop.actuated, loop.u_operating_point))
        for names, values in pairs:
            operating_point |= dict(zip(names, values, strict=True)) if values is not None else {}
    return describe_signals(model, ctx.config["experiment"]["scheduling"], ctx.config["design"]["plant"],
                            operating_point)


# ---------------------------------------------------------------------------------------- verify
def verify(ctx: StageContext) -> tuple[dict, list[str]]:
    """Closed loop on the plant FMU: the LPV controller and the LTI baseline on the same scenarios."""
    from lpvflow.pipeline.scenarios import parse_loop, parse_scenario
    from lpvflow.pipeline.verify import plot_runs, run_verification

    cfg = ctx.config["verify"]
    loop = parse_loop(cfg["loop"])
    scenarios = [parse_scenario(doc, i) for i, doc in enumerate(cfg["scenario"])]
    controller, baseline = load(ctx.path("controller.json")), load(ctx.path("baseline.json"))
    plant = ctx.config["design"]["plant"]
    result = run_verification(controller, plant, scenarios, loop, baseline)
    artifacts = []
    for i, scenario_result in enumerate(result.results):
        name = f"verify_{i}.png"
        plot_runs(scenario_result.runs, ctx.path(name), title=scenarios[i].name, plant=plant)
        artifacts.append(name)
    outputs = result.to_dict()
    if cfg["largest_step"]:
        outputs["largest_held_step"] = largest_steps(cfg["largest_step"], scenarios, plant, loop,
                                                     {"lpv": controller, "baseline": baseline})
    return outputs, artifacts


def largest_steps(spec: dict, scenarios: list, plant: str, loop, controllers: dict) -> dict:
    """``[verify] largest_step``: for each controller, the largest step of the named scenario it holds
    (:func:`lpvflow.pipeline.step_sweep.largest_held_step`, bisection to its default resolution)."""
    from lpvflow.errors import DataError
    from lpvflow.pipeline.step_sweep import DEFAULT_RESOLUTION, largest_held_step, step_output

    template = next((s for s in scenarios if s.name == spec["scenario"]), None)
    if template is None:
        raise DataError(f"[verify] largest_step.scenario = {spec['scenario']!r} names no scenario; "
                        f"known: {[s.name for s in scenarios]}")
    output = step_output(template, None)[0]
    record = {"output": output, "criterion": spec["criterion"], "resolution": DEFAULT_RESOLUTION}
    for key, law in controllers.items():
        record[key] = largest_held_step(law, plant, loop, template, criterion=spec["criterion"])
    return record


# -------------------------------------------------------------------------------------- adoption
#: Per tracked output, the verification metrics the before/after adoption table compares.
ADOPTION_METRICS = ("settling_time", "overshoot_percent", "iae", "ise", "steady_state_error")


def adoption(ctx: StageContext) -> tuple[dict, list[str]]:
    """Closed-loop gain of adopting the diagnosed extension ([diagnose] adopt = true).

    "Before" is the design without adoption: the identified model goes through the same reduce and
    synth stages (same configuration, in the sub-folder ``before_adoption/``); "after" is this design's
    LPV controller. Both run on every verification scenario on the plant FMU (which has the effect),
    and per scenario and tracked output the table gives settling time, overshoot, IAE and ISE of the
    tracking error (:mod:`lpvflow.pipeline.verify`) before and after; ``iae_total`` sums the IAE
    over scenarios and outputs (None when a run failed). A failure of the "before" design is reported,
    not raised: the design itself is the adopted one.
    """
    from lpvflow.errors import LpvflowError
    from lpvflow.pipeline.scenarios import parse_loop, parse_scenario
    from lpvflow.pipeline.verify import plot_runs, run_metrics, simulate_loop

    diagnosis = ctx.outputs.get("diagnose", {})
    if not diagnosis.get("adopted"):
        return {"compared": False, "reason": "no extension was adopted ([diagnose] adopt = false, cause "
                                             f"{diagnosis.get('cause')!r} or adoption refused)"}, []
    before = StageContext(ctx.path("before_adoption"), ctx.config)
    before.folder.mkdir(exist_ok=True)
    before.path("model_full.json").write_bytes(ctx.path("model_full.json").read_bytes())
    try:
        reduced, _ = reduce_model(before)
        synthesized, _ = synth(before)
    except LpvflowError as exc:
        return {"compared": False, "reason": f"the design on the identified model failed: {exc}"}, []
    cfg = ctx.config["verify"]
    loop = parse_loop(cfg["loop"])
    controllers = (("before adoption", load(before.path("controller.json"))),
                   ("after adoption", load(ctx.path("controller.json"))))
    plant = ctx.config["design"]["plant"]
    rows, artifacts, totals = [], [], {"before": 0.0, "after": 0.0}
    for i, doc in enumerate(cfg["scenario"]):
        scenario = parse_scenario(doc, i)
        runs = [simulate_loop(K, plant, scenario, loop, label) for label, K in controllers]
        plot_runs(runs, ctx.path(f"adoption_{i}.png"), title=f"{scenario.name}: before/after adoption",
                  plant=plant)
        artifacts.append(f"adoption_{i}.png")
        metrics = dict(zip(("before", "after"), (run_metrics(r, scenario, loop) for r in runs), strict=True))
        for output in list(metrics["after"]["outputs"] or metrics["before"]["outputs"]) or ["–"]:
            row = {"scenario": scenario.name, "output": output}
            for key, m in metrics.items():
                values = m["outputs"].get(output, {})
                row[key] = {"stable": m["stable"], "reason": m["reason"],
                            **{name: values.get(name) for name in ADOPTION_METRICS}}
                iae = row[key]["iae"]
                totals[key] = None if totals[key] is None or iae is None else totals[key] + iae
            rows.append(row)
    return ({"compared": True, "model_before": f"identified, order {reduced['order']}",
             "model_after": f"{diagnosis['cause']} {diagnosis['parameters']}, order "
                            f"{ctx.outputs['reduce']['order']}",
             "gamma_before": synthesized["gamma"], "gamma_after": ctx.outputs["synth"]["gamma"],
             "iae_total_before": totals["before"], "iae_total_after": totals["after"], "rows": rows},
            artifacts)


# ---------------------------------------------------------------------------------------- export
def export(ctx: StageContext) -> tuple[dict, list[str]]:
    """The controller as FMU / JSON / MAT."""
    from lpvflow.pipeline.export import export_controller

    controller = load(ctx.path("controller.json"))
    written = []
    for fmt in ctx.config["export"]["formats"]:
        path = export_controller(controller, ctx.path(f"exported_controller.{fmt}"), fmt)
        written.append(path.name)
    return {"files": written}, written
