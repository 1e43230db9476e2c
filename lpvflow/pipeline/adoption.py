"""The adoption stage: the design with and without the diagnosed model extension, compared in closed loop."""

from __future__ import annotations

from collections.abc import Callable

from lpvflow.errors import LpvflowError
from lpvflow.models import load
from lpvflow.pipeline.context import StageContext
from lpvflow.pipeline.loop_metrics import run_metrics
from lpvflow.pipeline.verify import plot_runs, simulate_loop

#: A design stage: the context in, (outputs, artifacts) out.
StageFunction = Callable[[StageContext], tuple[dict, list[str]]]


def adoption_refusal(result) -> str | None:
    """Why a diagnosis' extended model cannot replace the design model (None: it can): it adds inputs,
    or it is fitted on a mapped input or output (an input map, a play operator, a clipped output,
    y − sensor offset, inputs and scheduling delayed in the data) that a controller design model does
    not carry, or it is not in shifted form."""
    mapped = result.cause in ("input_nonlinearity", "backlash", "sensor_saturation") or (
        result.cause == "offset" and result.parameters.get("kind") == "sensor") or (
        result.cause == "input_delay" and result.parameters.get("delayed_scheduling"))
    if result.winner.inputs_added or mapped or result.winner.fit.model.form != "shifted":
        return (f"the {result.cause} extension changes the model's inputs or is fitted on a mapped input "
                "or output; the design model stays as identified")
    return None


#: Per tracked output, the verification metrics the before/after adoption table compares.
ADOPTION_METRICS = ("settling_time", "overshoot_percent", "iae", "ise", "steady_state_error")


def adoption(
    ctx: StageContext, reduce_stage: StageFunction, synth_stage: StageFunction
) -> tuple[dict, list[str]]:
    """Closed-loop gain of adopting the diagnosed extension ([diagnose] adopt = true).

    "Before" is the design without adoption: the identified model goes through the same reduce and
    synth stages (``reduce_stage``, ``synth_stage``; same configuration, in the sub-folder
    ``before_adoption/``); "after" is this design's
    LPV controller. Both run on every verification scenario on the plant FMU (which has the effect),
    and per scenario and tracked output the table gives settling time, overshoot, IAE and ISE of the
    tracking error (:mod:`lpvflow.pipeline.verify`) before and after; ``iae_total`` sums the IAE
    over scenarios and outputs (None when a run failed). A failure of the "before" design is reported,
    not raised: the design itself is the adopted one.
    """
    diagnosis = ctx.outputs.get("diagnose", {})
    if not diagnosis.get("adopted"):
        return {"compared": False, "reason": "no extension was adopted ([diagnose] adopt = false, cause "
                                             f"{diagnosis.get('cause')!r} or adoption refused)"}, []
    before = StageContext(ctx.path("before_adoption"), ctx.config)
    before.folder.mkdir(exist_ok=True)
    before.path("model_full.json").write_bytes(ctx.path("model_full.json").read_bytes())
    try:
        reduced, _ = reduce_stage(before)
        synthesized, _ = synth_stage(before)
    except LpvflowError as exc:
        return {"compared": False, "reason": f"the design on the identified model failed: {exc}"}, []
    cfg = ctx.config["verify"]
    loop = cfg["loop"]
    controllers = (("before adoption", load(before.path("controller.json"))),
                   ("after adoption", load(ctx.path("controller.json"))))
    plant = ctx.config["design"]["plant"]
    rows, artifacts, totals = [], [], {"before": 0.0, "after": 0.0}
    for i, scenario in enumerate(cfg["scenario"]):
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
