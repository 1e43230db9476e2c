"""Model extensions, one per cause the diagnosis can name.

Each extension is fitted on the estimation split (its own free choice — a delay, a degree, a width
— selected by the one-step loss or BIC on the estimation data only) and simulated on the
validation split, where :mod:`lpvflow.validate.diagnose` scores it against the nominal model.
Every simulation runs over the whole record from a zero past and is scored on its validation part
(:func:`simulate_validation`): the estimation split is the warm-up, so the validation part starts
from the model's own state instead of from zero (on a slow plant far from y = 0 the zero-start
transient would dominate every validation error).

Static input maps (Hammerstein extension, applied before the LPV dynamics):

    dead zone   f_w(u) = sign(u) · max(|u| − w, 0)
    saturation  f_s(u) = clip(u, −s, s)
    backlash    x(k) = min(max(x(k−1), u(k) − w/2), u(k) + w/2)   (a dead band ±w/2 with memory)

A clipping sensor is an output map: y_meas = clip(y, lo, hi) (:func:`sensor_saturation`).
Coulomb friction enters as an extra input sign(v(k)) with the input's lags, v(k) = y(k) − y(k−1)
for a position output or v(k) = y(k) for a velocity output; its validation simulation takes v
from the model's *own* simulated output, sample by sample (:func:`friction_simulation`), never
from the measured output.
Offset adds the inputs 1 and t/N with a lag-0 constant coefficient: c₀ + c₁·t/N, or is a sensor
offset y_meas = y + o (the model fitted to y_meas − o; in closed loop the controller reads y + o).

Closed-loop data (``Context.loop`` set, :mod:`lpvflow.validate.closed_loop`): every model is
simulated in the identification loop instead, with the extension's input map, extra inputs and
velocity sign applied to the input the loop produces; the choices made on estimation data stay the
same (one-step loss and BIC), except the model order's simulation BIC and the sensor offset's level
and BIC (the estimation-data loop-simulation loss), also run in the loop.
Simulations run on first use of a fit's validation output (:class:`Fit`): a diagnosis fits about a
hundred variants and scores one per cause.
"""

from __future__ import annotations

from collections.abc import Callable

from lpvflow.validate.closed_loop_iv import closed_loop_iv  # noqa: F401
from lpvflow.validate.extension_core import (  # noqa: F401  (the diagnosis' building blocks, re-exported)
    Candidate,
    Context,
    Fit,
    LoopSimulation,
    Structure,
    bounded,
    fit,
    joined,
    loop_simulator,
    output_error,
    simulate_validation,
)
from lpvflow.validate.extensions_maps import (  # noqa: F401
    backlash,
    dead_zone,
    friction,
    friction_simulation,
    input_nonlinearity,
    play,
    saturation,
    sensor_saturation,
)
from lpvflow.validate.extensions_noise import (  # noqa: F401
    input_delay_in_loop,
    output_noise_bias,
    refit_in_loop,
)
from lpvflow.validate.extensions_structural import (  # noqa: F401
    input_delay,
    model_order,
    offset,
    scheduling_dependence,
    scheduling_variable,
    simulation_bic,
)

CAUSES = (
    "input_delay", "model_order", "scheduling_dependence", "scheduling_variable",
    "input_nonlinearity", "backlash", "sensor_saturation", "friction", "output_noise_bias",
    "colored_noise", "offset", "unexplained", "ambiguous", "none",
)



EXTENSIONS: dict[str, Callable[[Context], Candidate | None]] = {
    "input_delay": input_delay,
    "model_order": model_order,
    "scheduling_dependence": scheduling_dependence,
    "scheduling_variable": scheduling_variable,
    "input_nonlinearity": input_nonlinearity,
    "backlash": backlash,
    "sensor_saturation": sensor_saturation,
    "friction": friction,
    "output_noise_bias": output_noise_bias,
    "offset": offset,
}

