"""Breakpoints inserted where a gain-scheduled design's frozen check fails between two of them.

A loop-shaping design (:mod:`lpvflow.synth.loop_shaping_design`) is certified at its breakpoints; between
them its frozen check (:func:`lpvflow.synth.loop_shaping_design.frozen_margin_check`) asks
b(Gs(λ), K∞(λ)) ≥ 1/(1.1·γ_segment) on a grid ten times finer. A grid point that misses it says the
interpolation between the two breakpoints around it is too coarse for the loop there — e.g. where
``margin_goal`` lowered W1's lead at one breakpoint and not at its neighbour. As a gridded gain-scheduled
design is refined (LPVTools: add grid points where the analysis between them fails), the value of the
signal the breakpoints are given in halfway between those two becomes a breakpoint, its images through
``[experiment] scheduling`` are computed as the design file's own are
(:func:`lpvflow.pipeline.scheduling_values.images`), and the design is repeated — at most
:data:`MAX_INSERTED` times; the last design is returned whether or not it passes (its check says so).

It applies to breakpoints given as values of one signal
(:class:`lpvflow.pipeline.scheduling_values.SignalImages`) and to the loop-shaping designs' frozen grid
check (:class:`lpvflow.synth.loop_shaping_design.FrozenMarginCheck`); the other methods' checks and the LMI
witness are left to fail as they do.
Measured (benchmarks/README.md, "Breakpoints inserted where the frozen check fails"): the held-out
identification seed 4 of ``benchmarks/bench_adip_design.py --example adip`` stopped at synth with the
worst point 0.991 between −75° and −60°; with −67.5° inserted the worst point is 1.075 and the design passes
8 of 8 scenarios with b(Ĝ, K_fb) ≥ 1.52 × the ν-gap. Designs whose check passes are unchanged.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from lpvflow.pipeline.scheduling_values import SignalImages, images
from lpvflow.synth.certify import design_coordinates
from lpvflow.synth.design import Design
from lpvflow.synth.loop_shaping_design import FROZEN_PER_SEGMENT, FrozenMarginCheck

#: Breakpoints one design may insert.
MAX_INSERTED = 3


def failing_segment(design: Design) -> tuple[int, int] | None:
    """The breakpoint indices (i, i + 1) around the worst point of a failing frozen grid check, or None
    (the check passes, holds no grid, or fails at a breakpoint itself)."""
    check = design.certificate
    if (not isinstance(check, FrozenMarginCheck) or check.worst_ratio >= 1.0
            or design.plant.polytope.breakpoints is None):
        return None
    lams = design_coordinates(design.plant.polytope, design.plant.basis, FROZEN_PER_SEGMENT)
    mixed = np.flatnonzero(np.asarray(lams[check.worst_at]) > 1e-12)
    return (int(mixed[0]), int(mixed[-1])) if len(mixed) == 2 else None


def refined_design(design_once: Callable[[Mapping[str, Any]], Design], settings: Mapping[str, Any],
                   p_names: list[str], scheduling: Mapping[str, str] | None) -> tuple[Design, list[float]]:
    """(design, the signal values inserted as breakpoints, in the order inserted): ``design_once`` on
    ``settings``, then on settings with a breakpoint inserted (module docstring) while the frozen check
    fails between breakpoints given as values of one signal, at most :data:`MAX_INSERTED` times."""
    design = design_once(settings)
    inserted: list[float] = []
    given = current = settings.get("breakpoints")
    if not isinstance(given, SignalImages):
        return design, inserted
    while len(inserted) < MAX_INSERTED and (segment := failing_segment(design)) is not None:
        i, j = segment
        inserted.append(0.5 * (current.source.values[i] + current.source.values[j]))
        current = design_breakpoints(given, inserted, p_names, scheduling)
        design = design_once({**settings, "breakpoints": current})
    return design, inserted


def design_breakpoints(given: Any, inserted: list[float], p_names: list[str],
                       scheduling: Mapping[str, str] | None) -> Any:
    """The breakpoints a design used: ``given`` (``[synth] breakpoints``) with the ``inserted`` values (the
    synth stage's ``inserted_breakpoints``) added, their images recomputed, in the polytope's order
    (ascending first scheduling signal); ``given`` itself when nothing was inserted."""
    if not inserted or not isinstance(given, SignalImages):
        return given
    values = [*given.source.values, *inserted]
    rows = images(replace(given.source, values=tuple(values)), p_names, scheduling or {},
                  "[synth] breakpoints")
    order = np.argsort(rows[:, 0], kind="stable")
    source = replace(given.source, values=tuple(values[k] for k in order))
    return SignalImages(rows[order].tolist(), source)


def inserted_lines(info: Mapping[str, Any], given: Any) -> list[str]:
    """The certificate line naming the breakpoints a design inserted (``info["inserted_breakpoints"]``),
    or none."""
    inserted = info.get("inserted_breakpoints")
    if not inserted or not isinstance(given, SignalImages):
        return []
    values = ", ".join(given.source.shown(v) for v in inserted)
    return [f"breakpoints inserted where the frozen check failed between two: {given.source.signal} = "
            f"{values} (in that order; the checks above are the design's with them)"]
