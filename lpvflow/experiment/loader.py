"""The controllers an experiment (and the design's stages) can run, read through the one controller
loader (:func:`lpvflow.loop.loader.load_controller_file`): an ``lpvflow/lpv-controller`` is read wired
to the plant signals by its ``info["signals"]`` (:mod:`lpvflow.experiment.synthesized`)."""

from __future__ import annotations

from pathlib import Path

from lpvflow.experiment.synthesized import SynthesizedController
from lpvflow.loop.loader import JSON_KINDS, LPV_FORMAT, READERS, load_controller_file, lpv_controller
from lpvflow.loop.protocol import ExperimentController


def _wired(doc: dict, source: str) -> SynthesizedController:
    return SynthesizedController.from_controller(lpv_controller(doc, source), source)


def load_experiment_controller(path: str | Path) -> ExperimentController:
    """An ``lpvflow/lti-controller``, ``lpvflow/gridded-controller`` or ``lpvflow/lpv-controller`` JSON
    file (module docstring)."""
    return load_controller_file(path, JSON_KINDS, "an experiment", {**READERS, LPV_FORMAT: _wired})
