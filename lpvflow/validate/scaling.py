"""Signal scaling for scale-dependent frozen measures (ν-gap, generalized stability margin b(P, K)).

Both depend on the units of u and y. :class:`SignalScaling` applies D_y⁻¹ G D_u to plants and
D_u⁻¹ K D_y to controllers, D_u, D_y diagonal (e.g. the standard deviations of the data's inputs and
outputs), so that unit changes of the signals do not decide the result (Vinnicombe 2001, §2.6: scale
the signals to comparable sizes before computing the gap).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import control
import numpy as np


class SignalScaling:
    """Plants D_y⁻¹ G D_u and controllers D_u⁻¹ K D_y; the identity when ``enabled`` is false."""

    def __init__(self, u_scale: np.ndarray, y_scale: np.ndarray, enabled: bool = True) -> None:
        self.enabled = enabled
        self.Du = np.diag(np.where(u_scale > 0, u_scale, 1.0))
        self.Dy = np.diag(np.where(y_scale > 0, y_scale, 1.0))

    def plant(self, G: control.StateSpace) -> control.StateSpace:
        if not self.enabled:
            return G
        Dy_inv = np.linalg.inv(self.Dy)
        return control.ss(G.A, G.B @ self.Du, Dy_inv @ G.C, Dy_inv @ G.D @ self.Du, G.dt)

    def controller(self, K: control.StateSpace | None) -> control.StateSpace | None:
        if K is None or not self.enabled:
            return K
        Du_inv = np.linalg.inv(self.Du)
        return control.ss(K.A, K.B @ self.Dy, Du_inv @ K.C, Du_inv @ K.D @ self.Dy, K.dt)

    def plant_at(self, reference: Callable[[np.ndarray], control.StateSpace] | None):
        """p ↦ scaled reference(p), or None."""
        return None if reference is None else (lambda p: self.plant(reference(p)))

    def model(self, model: Any) -> ScaledModel:
        """An object whose ``frozen(p)`` is the scaled ``model.frozen(p)``."""
        return ScaledModel(model, self)


@dataclass
class ScaledModel:
    """``frozen(p)`` of a model, scaled by :class:`SignalScaling`."""

    model: Any
    scaling: SignalScaling

    def frozen(self, p: np.ndarray) -> control.StateSpace:
        return self.scaling.plant(self.model.frozen(p))
