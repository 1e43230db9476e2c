"""Is a dead time named in closed loop one dead time, or does it stand in for sensor play? (step 6 of
:mod:`lpvflow.validate.diagnose`).

A dead time delays the plant input; the error of the model that has it does not depend on the direction
of the output's motion. A sensor with play (hysteresis) makes the reading lag the output after every
reversal, which an extra input delay imitates in part: in a loop that holds the *measured* outputs on
their set-points (the maglev), the controller moves the play into the input, and the best of the
vocabulary is a dead time. The error of that delayed model still steps with the direction of motion —
significantly, though the step is smaller than the open-loop materiality of
:mod:`lpvflow.validate.diagnose_direction` (DIRECTION_STEP standard deviations), which is there for the
approximate structures of open-loop plants (airpath clean records: 1.28 at t = 5.8), not for a dead time.

The test: :func:`~lpvflow.validate.diagnose_direction.direction_dependence` of the named delay's
in-loop validation simulation (the direction of motion's coefficient, prewhitened regression with
nuisance regressors, |t| beyond z at α/(2·outputs·bands)); an ``input_delay`` verdict in closed loop
whose model has a significant coefficient is ``unexplained``, whatever the step's size.

Measured on the closed-loop records of ``tests/diagnosis_fmu_cases.py`` (seeds 0–4): the maglev sensor
hysteresis (0.2 mm play), named ``input_delay`` on seeds 1–4, |t| = 9.4–12.7 at steps of 0.75–0.92
standard deviations (bound 3.8); the maglev 6 ms and ADIP 15 ms dead times (seeds 0–2) no significant
coefficient.
"""

from __future__ import annotations

import numpy as np

from lpvflow.validate.diagnose_direction import direction_dependence
from lpvflow.validate.extensions import Candidate, Context


def loop_delay_verdict(ctx: Context, cause: str, pool: dict[str, Candidate], adequacy: dict | None,
                       alpha: float) -> tuple[str, dict | None]:
    """Closed loop: ``unexplained`` when the named dead time's model leaves an error that depends
    significantly on the direction of the output's motion (module docstring), the test in
    ``adequacy["delay_direction"]``; otherwise the verdict unchanged."""
    if ctx.loop is None or cause != "input_delay" or cause not in pool or adequacy is None:
        return cause, adequacy
    model = pool[cause].fit
    if model.diverged:
        return cause, adequacy
    test = direction_dependence(ctx.val.y, model.y_val, ctx.val.u, alpha)
    if abs(test["t"]) <= test["bound"]:
        return cause, adequacy
    keys = ("t", "bound", "step_over_sigma", "output", "dead_band", "alpha")
    nk = np.asarray(pool[cause].parameters["nk"]).tolist()
    found = {k: test[k] for k in keys} | {"cause": cause, "nk": nk}
    return "unexplained", adequacy | {"delay_direction": found}
