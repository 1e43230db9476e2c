"""The anti-windup law a design attaches to its synthesized controller, from the verification loop's
actuator limits."""

from __future__ import annotations

import numpy as np

from lpvflow.pipeline.scenarios import Loop
from lpvflow.synth.controller import AntiWindup, LPVController, observer_gains


def antiwindup(
    controller: LPVController, loop: Loop | None, signals: dict, gains: np.ndarray | None = None
) -> AntiWindup | None:
    """The anti-windup law of a synthesized controller (:class:`lpvflow.synth.controller.AntiWindup`) for
    the actuator limits of the verification ``loop`` around the actuated inputs' operating points (the
    port record ``signals``), with the design's own ``gains`` (the observer design's) or
    :func:`lpvflow.synth.controller.observer_gains`; None when there is no loop or it limits none of the
    controller's outputs."""
    if loop is None:
        return None
    limits = loop.actuator_limits
    names = [port["name"] for port in signals["actuated"]]
    if not any(name in limits for name in names):
        return None
    lo, hi = (np.array([limits.get(name, (-np.inf, np.inf))[i] for name in names]) for i in (0, 1))
    u_op = np.array([port["operating_point"] for port in signals["actuated"]])
    L = observer_gains(controller.Ak, controller.Ck) if gains is None else gains
    return AntiWindup(L, lo, hi, u_op)
