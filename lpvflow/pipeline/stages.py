"""The design stages: each reads the settings it declares (:mod:`lpvflow.pipeline.settings`) and the
artifacts of the stages before it, and writes its own artifacts.

Every stage returns ``(outputs, artifacts)``: a JSON-ready dict of the numbers it produced and the
file names (relative to the design folder) it wrote. :mod:`lpvflow.pipeline.design` wires them,
caches them (:mod:`lpvflow.pipeline.cache`) and reports them; the adoption stage is
:func:`lpvflow.pipeline.adoption.adoption`.
"""

from __future__ import annotations

import warnings
from dataclasses import replace
from typing import Any

import numpy as np

from lpvflow.basis import SchedulingRangeWarning
from lpvflow.errors import DataError, LpvflowError
from lpvflow.experiment.fmu_experiment import run_fmu_experiment
from lpvflow.experiment.loader import load_experiment_controller
from lpvflow.identify.methods import estimate, method_of
from lpvflow.identify.prefilter import prefiltered
from lpvflow.identify.realize import integrate_outputs
from lpvflow.identify.reduce import max_frozen_radius, plot_singular_values, reduce_keeping_radius
from lpvflow.lfr import LPVLFR, require_affine
from lpvflow.models import load
from lpvflow.pipeline.adoption import adoption_refusal
from lpvflow.pipeline.antiwindup import antiwindup
from lpvflow.pipeline.breakpoint_refinement import inserted_lines
from lpvflow.pipeline.cli_identify import plot_fit
from lpvflow.pipeline.context import DATA_FILE, StageContext
from lpvflow.pipeline.controller_design import design_controller, extrapolation_note
from lpvflow.pipeline.coordinates import estimation_records, read_data, two_step_excitation
from lpvflow.pipeline.export import export_controller
from lpvflow.pipeline.frozen_references import (
    fmu_reference,
    frozen_experiment_controller,
    signal_scaling,
    trim_closed,
)
from lpvflow.pipeline.gate import JUDGED_BY_ROBUSTNESS, gate_verdict
from lpvflow.pipeline.model_diagnosis import diagnose_model, extended_model, loop_controller
from lpvflow.pipeline.model_loop import closed_loop_simulation
from lpvflow.pipeline.refine import refined_model
from lpvflow.pipeline.residual_plot import one_step_residuals
from lpvflow.pipeline.step_sweep import largest_steps
from lpvflow.pipeline.verify import fmu_units, plot_runs, run_verification
from lpvflow.synth.design import synthesize_design
from lpvflow.synth.polytope import scheduling_box
from lpvflow.validate.diagnose_plot import plot_diagnosis
from lpvflow.validate.extensions import Structure
from lpvflow.validate.frozen import compare_frozen
from lpvflow.validate.metrics import fit_report
from lpvflow.validate.plots import bode_overlay, gap_margin_plot
from lpvflow.validate.robust_stability import optimal_margin


def experiment(ctx: StageContext) -> tuple[dict, list[str]]:
    """Experiment on the plant FMU (closed loop under a controller; ``left_design_box``: design_box_exit)."""
    cfg = ctx.config["experiment"]
    record = run_fmu_experiment(
        ctx.config["design"]["plant"], cfg["Ts"], cfg["duration"], inputs=cfg["inputs"] or None,
        controller=cfg["controller"], excitation=cfg["excitation"] or None,
        parameters=cfg["parameters"] or None, scheduling_columns=cfg["scheduling"] or None,
        seed=cfg["seed"], output=ctx.path(DATA_FILE), progress=None, setpoint=cfg["setpoint"] or None,
        quantization=cfg["quantization"] or None, noise=cfg["noise"] or None,
        output_bounds=cfg["output_bounds"] or None,
    )
    outputs = {"samples": len(record.time), "Ts": record.Ts, "ranges": {
        name: [float(np.min(v)), float(np.max(v))] for name, v in record.columns.items() if name != "time"}}
    if cfg["controller"] and (left := load_experiment_controller(cfg["controller"]).design_box_exit(
            record.time, record.columns)):
        outputs["left_design_box"] = left
    return outputs, ["data.csv", "data.csv.json"]


def identify(ctx: StageContext) -> tuple[dict, list[str]]:
    """The ``[identify] method`` estimator (:func:`lpvflow.identify.methods.estimate`, any method of
    ``lpvflow identify``) on the estimation part, as a state-space model: IO models realized exactly
    (``LPVIO.to_ss``), pbsid and cva as estimated, an LFR converted when its dependence is affine
    (kcca-lfr-affine). IO models get the one-step-ahead equation-error residuals on the validation part
    (BFR, Ljung–Box p-value, residuals.png); state-space models do not (their fit is the validate stage's).
    With ``[identify] rounds = "all"`` the estimation data are every round's estimation part
    (:func:`~lpvflow.pipeline.coordinates.estimation_records`). Two-step takes the external excitation
    of :func:`~lpvflow.pipeline.coordinates.two_step_excitation`. The estimator sees the signals of
    :func:`model_coordinates` (the residuals are theirs: an output in ``increments`` has its increments'
    residuals); outputs in ``increments`` are integrated back into the saved model. With ``[identify] refine
    = "closed-loop-oe"`` the least-squares model is refined on its records simulated in their loops
    (:mod:`lpvflow.pipeline.refine`) before it is realized."""
    cfg = ctx.config["identify"]
    method = cfg["method"]  # the schema refuses static-arx: no state-space realization
    est, val = read_data(ctx, model_signals=True)
    records = estimation_records(ctx, est)
    excitation = two_step_excitation(ctx, est.N) if method_of(method).needs_excitation else None
    try:
        equation_records = [prefiltered(record, cfg["prefilter"]) for record in records]
        model = estimate(equation_records, method, cfg["na"],
                         cfg["nb"], cfg["nk"], cfg["basis"], ridge=cfg["ridge"], nc=cfg["nc"],
                         excitation=excitation, past=cfg["past"], order=cfg["order"])
    except LpvflowError as exc:
        raise DataError(f"[identify] method = {method!r}: {exc}") from None
    outputs: dict[str, Any] = {"method": method}
    if cfg["refine"] != "none":
        refinement = refined_model(ctx, model, equation_records)
        model = refinement.model
        outputs["refine"] = refinement.summary()
    if len(records) > 1:
        outputs["estimation_records"] = [record.N for record in records]
    artifacts = ["model_full.json"]
    if method_of(method).result == "io":
        model = replace(model, operating_point=est.offsets)  # what remove_offsets took off (or nothing)
        ss, units = model.to_ss(), fmu_units(ctx.config["design"]["plant"])
        outputs |= one_step_residuals(model, val, ctx.path("residuals.png"), units)
        artifacts.append("residuals.png")
    else:
        try:
            ss = require_affine(model) if isinstance(model, LPVLFR) else model
        except LpvflowError as exc:
            raise DataError(f"[identify] method = {method!r}: {exc}; use \"kcca-lfr-affine\"") from None
    if cfg["increments"]:
        ss = integrate_outputs(ss, cfg["increments"])
    ss.save(ctx.path("model_full.json"))
    if cfg["remove_trim"]:
        outputs["input"] = f"{', '.join(ss.u_names)} minus the trim u_op(θ) of the experiment controller"
    outputs |= {"nx": ss.nx, "offsets": est.offsets,
                "scheduling_range": [list(ss.basis.p_min), list(ss.basis.p_max)]}
    return outputs, artifacts


def diagnose(ctx: StageContext) -> tuple[dict, list[str]]:
    """Diagnosis of the identified model (the identify stage's input-output model, before reduction) on
    its validation part, through the path of `lpvflow diagnose`
    (:func:`~lpvflow.pipeline.model_diagnosis.diagnose_model`): the record in the model's signals
    (``remove_trim``, ``remove_offsets`` about the estimation part's means, as identify used them), every
    model simulated in the loop of the experiment controller (LTI or gridded; set-points as recorded,
    the experiment's scheduling expressions recomputed from the simulated outputs). The named cause's
    extended model is saved as `lpvflow diagnose` saves it (``diagnosis.extended.json``,
    :func:`~lpvflow.pipeline.model_diagnosis.extended_model`). With ``adopt`` the model of that
    file (realized in state space, ``model_extended.json``) replaces the identified one for the rest of
    the design when
    :func:`~lpvflow.pipeline.adoption.adoption_refusal` lets it (it keeps the model's inputs, outputs
    and signal maps)."""
    cfg, ident, experiment = ctx.config["diagnose"], ctx.config["identify"], ctx.config["experiment"]
    if ident["increments"]:
        raise DataError("[diagnose] cannot diagnose a model identified through [identify] increments (it "
                        "diagnoses the measured outputs): drop increments or the [diagnose] table")
    if method_of(ident["method"]).result != "io":
        raise DataError(f"[diagnose] needs an input-output model; [identify] method = {ident['method']!r} "
                        "gives a state-space one: use an IO method (lpr-arx, oe, iv-oe, ...)")
    io = load(ctx.path("model_full.json")).io
    controller = (loop_controller(experiment["controller"],
                                  "[diagnose], which simulates the [experiment] controller's loop,")
                  if experiment["controller"] else None)
    result, data = diagnose_model(
        ctx.columns(), ctx.dataset(ident["u"], ident["y"], ident["p"]), Structure.of_model(io),
        split=ident["split"], candidates=cfg["candidates"], model=io, controller=controller,
        scheduling=experiment["scheduling"], remove_trim=ident["remove_trim"],
        remove_offsets=ident["remove_offsets"], operating_point=ident["split"])
    plot_diagnosis(result, data, ctx.path("diagnosis.png"), ident["split"])
    outputs = {"cause": result.cause, "parameters": result.parameters, "summary": result.summary,
               "bfr_before": result.bfr_before, "bfr_after": result.bfr_after,
               "ranking": [{k: r[k] for k in ("cause", "bfr_gain", "p_value")} for r in result.ranking],
               "adopted": False, "model": "model_full.json", "extended_model": None}
    extended = extended_model(result, data, ident["split"], ident["remove_trim"], controller)
    if extended is not None:  # `lpvflow simulate` runs it (--controller: in the experiment's loop)
        extended.save(ctx.path("diagnosis.extended.json"))
        outputs["extended_model"] = "diagnosis.extended.json"
    if cfg["adopt"] and result.winner is not None:
        refusal = adoption_refusal(result)
        if refusal:
            outputs["adoption_refused"] = refusal
        else:
            load(ctx.path("diagnosis.extended.json")).model.to_ss().save(ctx.path("model_extended.json"))
            outputs.update(adopted=True, model="model_extended.json")
    artifacts = (["diagnosis.png"] + (["diagnosis.extended.json"] if extended is not None else [])
                 + (["model_extended.json"] if outputs["adopted"] else []))
    return outputs, artifacts


def reduce_model(ctx: StageContext) -> tuple[dict, list[str]]:
    """LPV Ho-Kalman-like reduction (Schulz et al. Lemma 1) of the identified (or adopted) model; order
    from ``[reduce] order`` or automatic, raised until no spurious unstable mode appears
    (:func:`lpvflow.identify.reduce.reduce_keeping_radius`)."""
    ss = load(ctx.path(ctx.outputs.get("diagnose", {}).get("model", "model_full.json")))
    reduced, rule = reduce_keeping_radius(ss, ctx.config["reduce"]["order"])
    reduced.save(ctx.path("model.json"))
    plot_singular_values(reduced.reduction, ctx.path("singular_values.png"))
    return ({"order": reduced.nx, "full_order": ss.nx, "order_rule": rule,
             "max_frozen_radius": max_frozen_radius(reduced), "full_max_frozen_radius": max_frozen_radius(ss),
             "singular_values": reduced.reduction["singular_values"]},
            ["model.json", "singular_values.png"])


def validate(ctx: StageContext) -> tuple[dict, list[str]]:
    """Fit on validation data (closed-loop simulation under the experiment's controller) and, on a grid
    of frozen scheduling values, the generalized stability margin b(Ĝ(θ), K_id) and — with
    ``reference = "linearization"`` or ``"local"`` — the ν-gap δν(G_FMU(θ), Ĝ(θ)) to the plant FMU at
    its equilibrium with that scheduling value, and the gate's margin b − δν at each point (thesis
    Fig. 6.11; Vinnicombe, *Uncertainty and Feedback*, 2001: δν < b over the range means K_id stabilizes
    every frozen plant the model is that close to)."""
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
        plot_fit(ctx.path("fit.png"), val, y_sim, fmu_units(ctx.config["design"]["plant"]))
        artifacts.append("fit.png")
    reference = fmu_reference(ctx, model)
    K, K_note, trim_feedback = frozen_experiment_controller(ctx, model, reference)
    compared = reference if trim_feedback is None else trim_closed(reference, trim_feedback)
    scale = signal_scaling(cfg["scaling"], est, model)
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
                scaled_K = None if K is None else (lambda p: scale.controller(K(p)))  # K: p ↦ K_id(θ(p))
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
        if JUDGED_BY_ROBUSTNESS in cfg:  # the largest b any shipped controller can have (gate_verdict)
            outputs["b_opt"] = [optimal_margin(scale.plant(model.frozen(np.asarray(row["p"]))))
                                for row in rows]
    outputs["gate"] = gate_verdict(outputs, cfg["gate"], ctx.outputs.get("experiment"),
                                   JUDGED_BY_ROBUSTNESS in cfg)
    return outputs, artifacts


def synth(ctx: StageContext) -> tuple[dict, list[str]]:
    """Gain-scheduled controller of the ``[synth]`` table as ``lpvflow synth --config`` writes it
    (:func:`lpvflow.pipeline.controller_design.design_controller`) and the LTI baseline designed by the
    same table at one frozen point (``baseline_at``, default the centre of the scheduling box; one common
    Lyapunov matrix there is exact). ``margin_goal`` is taken against the validate stage's ν-gap at its
    points (``validated_nugap``, when it computed one); the baseline is designed without it."""
    cfg = ctx.config["synth"]
    model = load(ctx.path("model.json"))
    loop = ctx.config["verify"]["loop"] if ctx.config["verify"] else None
    validate = ctx.outputs.get("validate", {})
    nugap = {"points": validate["theta"], "nugap": validate["nugap"]} if validate.get("nugap") else None
    design = design_controller(model, {**cfg, "validated_nugap": nugap}, loop=loop,
                               scheduling=ctx.config["experiment"]["scheduling"],
                               plant_fmu=ctx.config["design"]["plant"])
    design.controller.save(ctx.path("controller.json"))
    centre = scheduling_box(model, cfg["box"]).mean(axis=1).tolist()
    at = cfg["baseline_at"] if cfg["baseline_at"] is not None else centre
    baseline = synthesize_design(model, {**cfg, "margin_goal": None}, box=[[v, v] for v in at])
    # the same port record: a 2-DOF baseline reads r and y relative to the same operating point
    baseline.controller.info["signals"] = design.controller.info["signals"]
    baseline.controller.antiwindup = antiwindup(baseline.controller, loop, design.controller.info["signals"])
    baseline.controller.save(ctx.path("baseline.json"))
    return ({"method": cfg["method"], "structure": cfg["structure"], "scheduling": cfg.get("scheduling"),
             "gamma": design.gamma,
             "baseline_gamma": baseline.gamma, "baseline_at": at,
             "certificate": (design.certificate.lines()
                             + inserted_lines(design.controller.info, cfg["breakpoints"])),
             "certificate_ok": bool(design.certificate.ok),
             "inserted_breakpoints": design.controller.info.get("inserted_breakpoints", []),
             "solve_seconds": design.seconds, "order": design.controller.order,
             "polytope": design.plant.polytope.kind, "box_note": extrapolation_note(model, cfg["box"])},
            ["controller.json", "baseline.json"])


def verify(ctx: StageContext) -> tuple[dict, list[str]]:
    """Closed loop on the plant FMU: the LPV controller and the LTI baseline on the same scenarios."""
    cfg = ctx.config["verify"]
    loop, scenarios = cfg["loop"], cfg["scenario"]
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


def export(ctx: StageContext) -> tuple[dict, list[str]]:
    """The controller as FMU / JSON / MAT."""
    controller = load(ctx.path("controller.json"))
    written = []
    for fmt in ctx.config["export"]["formats"]:
        path = export_controller(controller, ctx.path(f"exported_controller.{fmt}"), fmt)
        written.append(path.name)
    return {"files": written}, written
