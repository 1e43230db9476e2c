"""The γ-level search shared by the synthesis methods and the rate-bounded analysis.

A level γ *passes* when the caller's ``certified(γ)`` returns a result: an SDP at that level returned a
point and the controller or storage rebuilt from it passed an independent numpy re-check. A failing level
proves nothing (the solver may have stalled), so the search never stops at a multiple of an estimate:

1. **Up** from ``start``: γ_k = start·(1 + δ·4^k), k = 0, 1, … (the last one ``gamma_max``) until a level
   passes; none up to ``gamma_max`` → None.
2. **Down**, only when the first level passed and no floor is given: γ = start/(1 + δ·4^k)
   until a level fails (the estimate ``start`` may lie above the optimum).
3. **Bisection** (geometric) between the highest failing level — or the floor — and the
   lowest passing one, to a relative width δ.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

#: Default largest level tried before a synthesis reports that none passed.
GAMMA_MAX = 1e6


def lowest_certified_level(certified: Callable[[float], Any | None], start: float, suboptimality: float,
                           gamma_max: float = GAMMA_MAX, lower: float | None = None) -> Any | None:
    """Steps 1–3 of the module docstring; returns the result at the lowest passing level, or None.

    Args:
        certified: γ ↦ a result with attribute ``gamma`` when the level passes, else None.
        start: the first level's base (an estimate of the optimum, > 0).
        suboptimality: δ, the relative width of the final bracket.
        gamma_max: the largest level tried.
        lower: a floor: no level below it is tried (no downward search; the bisection's lower end) —
            a proven lower bound on every passing level, or an estimate of the optimum (then the result
            is within 1 + δ of it or of a failing level, not necessarily of the optimum).
    """
    start = min(start, gamma_max)
    best, failed, k = None, lower, 0
    while best is None:
        gamma = min(start * (1.0 + suboptimality * 4.0**k), gamma_max)
        best = certified(gamma)
        if best is None:
            if gamma >= gamma_max:
                return None
            failed = gamma
        k += 1
    if k == 1 and lower is None:
        k = 0
        while failed is None:
            gamma = start / (1.0 + suboptimality * 4.0**k)
            better = certified(gamma) if gamma > 1e-9 * start else None  # γ → 0 passing: stop there
            if better is None:
                failed = gamma
            else:
                best, k = better, k + 1
    return bisect_levels(certified, failed if failed is not None else 0.0, best, suboptimality)


def bisect_levels(certified: Callable[[float], Any | None], floor: float, best: Any, suboptimality: float
                  ) -> Any:
    """Step 3 of the module docstring: geometric bisection between ``floor`` (a failing level or the
    search's floor; 0: none) and ``best`` (a passing result) to a relative width δ = ``suboptimality``."""
    while floor > 0 and best.gamma / floor > 1 + suboptimality:
        mid = float(np.sqrt(floor * best.gamma))
        better = certified(mid)
        floor, best = (floor, better) if better is not None else (mid, best)
    return best
