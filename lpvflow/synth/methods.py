"""The synthesis methods: one registry from a ``[synth] method`` name to the function that designs it.

``lpvflow synth --config``, the design file's schema (:mod:`lpvflow.pipeline.config`, the allowed values
of ``[synth] method`` and their description) and the design's synth stage all read this registry, through
:func:`lpvflow.synth.design.synthesize_design`. A method is

* one module with a function ``design(model, plant, settings, frozen_model) -> Design``
  (:class:`lpvflow.synth.design.Design`): ``model`` the reduced :class:`~lpvflow.models.LPVSS`, ``plant``
  the generalized plant of the table's weights (:func:`lpvflow.synth.plant.generalized_plant`),
  ``settings`` the checked ``[synth]`` table, ``frozen_model`` the model the certificate's frozen check
  uses (None when the design's own plant must be used: scheduled weights or tied scheduling signals);
* one line in :data:`SYNTHESIS_METHODS` (its ``entry`` is ``"module:function"``, imported on first use so
  reading a design file does not import the solvers);
* its ``[synth]`` keys in the schema and ``docs/design_file.md``, if it has keys of its own.

``docs/synthesis_methods.md`` walks through adding one. The LTI baseline of the design stage is the
method itself designed at one frozen point when its ``point_design`` says it can be (loop shaping), else
the common-Lyapunov design there.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class SynthesisMethod:
    """One synthesis method: ``summary`` (one line, shown by ``lpvflow synth`` and in the schema's key
    description), ``keys`` (numeric ``[synth]`` keys only this method reads, printed with their values),
    ``entry`` (``"module:function"`` of its design function), ``gamma_is`` (what the γ it reports is) and
    ``point_design`` (the design stage's LTI baseline is this method at one frozen point, not the
    common-Lyapunov design there)."""

    summary: str
    entry: str
    keys: tuple[str, ...] = ()
    gamma_is: str = "certified level"
    point_design: bool = False

    def design_function(self) -> Callable:
        """The design function named by ``entry``."""
        module, _, name = self.entry.partition(":")
        return getattr(importlib.import_module(module), name)


#: ``[synth] method`` → its method. The first is the default.
SYNTHESIS_METHODS: dict[str, SynthesisMethod] = {
    "common": SynthesisMethod("one common Lyapunov matrix",
                              "lpvflow.synth.design:design_common"),
    "rate-bounded": SynthesisMethod("rate-bounded parameter-dependent Lyapunov function",
                                    "lpvflow.synth.design:design_rate_bounded", ("rate_bound",)),
    "observer": SynthesisMethod("observer-based: frozen LQG designs at the breakpoints, interpolated",
                                "lpvflow.synth.design:design_observer",
                                gamma_is="largest frozen closed-loop norm"),
    "loop-shaping": SynthesisMethod("H∞ loop shaping: LMI designs of the shaped plant at the breakpoints, "
                                    "interpolated", "lpvflow.synth.loop_shaping_design:design",
                                    ("crossover", "integral_ratio"), gamma_is="largest breakpoint level",
                                    point_design=True),
}
