"""What the validate stage compares the model with at frozen scheduling values: the plant FMU's frozen
linearization, the identification controller frozen at each value, and the signal scaling of the ν-gap."""

from __future__ import annotations

import functools

import control
import numpy as np

from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.experiment.loader import load_experiment_controller
from lpvflow.models import LPVSS
from lpvflow.pipeline.context import StageContext
from lpvflow.pipeline.model_loop import check_wiring
from lpvflow.validate.fmu_reference import FmuLinearization, FmuLocalModels, SelectedChannels
from lpvflow.validate.scaling import SignalScaling


def signal_scaling(setting: str | dict, est: Dataset, model: LPVSS):
    """The ν-gap's signal scaling: the estimation data's standard deviations (``"data"``), none, or the
    scales of a table ``{ signal = scale }`` naming every model input and output."""
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


def frozen_experiment_controller(
    ctx: StageContext, model: LPVSS, reference
) -> tuple[object, str | None, object]:
    """K_id for b(Ĝ(θ), K_id) as p ↦ K_id(θ(p)) in negative feedback over the model's signals (or None),
    a note (or None), and the trim's feedback (or None).

    An LTI experiment controller is the same at every θ. A scheduled one (gridded or LPV) is linearized
    (:meth:`~lpvflow.experiment.controller.GriddedController.operating_laws`,
    :meth:`~lpvflow.experiment.synthesized.SynthesizedController.operating_laws`: frozen at its own
    scheduling value, with the trim's feedback) at the FMU equilibrium with that θ (the reference's
    operating point, set-points equal to the outputs there); without an FMU reference that point is
    unknown and b is not computed (the note says so). With ``[identify] remove_trim`` the model's input is
    u − u_op(θ), so K_id is the controller frozen without the trim's feedback, and the third item is
    p ↦ that feedback T(p), the static gain with u = −T y (−∂u_op/∂y at the equilibrium), which
    :func:`trim_closed` closes around the FMU linearization: the loop (G_FMU, K_id with trim) is the loop
    (G_FMU closed by T, K_id without it)."""
    path = ctx.config["experiment"]["controller"]
    if not path:
        return None, None, None
    K = load_experiment_controller(path)
    check_wiring(K, model.u_names, model.y_names, "[validate] b(Ĝ(θ), K_id)")
    if not K.scheduled:  # the same law at every θ; a constant trim has no feedback
        fixed = K.negative_feedback(model.y_names, model.u_names)
        return (lambda p: fixed), None, None
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


def trim_closed(reference, trim_feedback):
    """p ↦ the frozen reference G(p) with the trim's feedback closed around it, u = u_model − T(p) y: the
    plant as the model sees it with ``[identify] remove_trim``."""
    return lambda p: control.feedback(reference(p), trim_feedback(p), sign=-1)


def fmu_reference(ctx: StageContext, model: LPVSS):
    """The plant FMU as frozen reference p ↦ discrete LTI over the model's inputs and outputs, or None.

    Scheduling expressions: the experiment's definition of each model scheduling column (e.g.
    ``sin_arm = "sin(arm_angle)"``), else the column name itself (a plant signal). The FMU gets the
    experiment's parameters except the measurement-noise effect (finite differences need exact outputs).
    ``[validate] hold`` pins outputs at given values in the equilibria (more inputs than scheduling
    signals leave them free otherwise)."""
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
                              start=cfg["operating_point"], parameters=parameters, hold=cfg["hold"])
    try:
        return SelectedChannels(reference, model.u_names, model.y_names)
    except DataError as exc:
        reference.close()
        raise DataError(f"[validate] {exc}") from None
