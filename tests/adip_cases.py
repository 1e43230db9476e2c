"""Generalized plants of the exact ADIP linearizations with the bundled design's weights (synthesis tests
and benchmarks/bench_synth.py): ZOH at Ts = 5 ms of fmu_plants/reference_models.adip_linearization."""

import sys
import tomllib
from pathlib import Path

import control
import numpy as np

from lpvflow.pipeline.config import bundled_config
from lpvflow.synth.plant import VertexPlant, augment, weight_systems

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "fmu_plants"))
import reference_models as rm

TS = 0.005


def bundled_weights() -> dict:
    """The ``[synth] weights`` table of lpvflow/pipeline/examples/adip.toml."""
    return tomllib.loads(bundled_config("adip").read_text())["synth"]["weights"]


def adip_vertex(arm_degrees: float, weights: dict | None = None) -> VertexPlant:
    """The mixed-sensitivity generalized plant (inputs [w, u], outputs [z, e]) at one arm angle."""
    a, b = rm.adip_linearization(np.deg2rad(arm_degrees), rm.default_parameters("adip"))
    G = control.c2d(control.ss(a, b, np.eye(2, 4), np.zeros((2, 1))), TS, method="zoh")
    W = weight_systems(bundled_weights() if weights is None else weights, 2, 1, TS)
    return VertexPlant.from_ss(augment(G, W, TS), nw=2, nz=3)
