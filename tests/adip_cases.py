"""Generalized plants of the exact ADIP linearizations (synthesis tests, benchmarks/bench_synth.py and
bench_rate_bounded.py): ZOH at Ts = 5 ms of fmu_plants/reference_models.adip_linearization, with the fixed
H∞ weights below (the bundled design's until session 12, on which the benchmark tables were measured) or
the bundled design's current ones."""

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


#: The H∞ weights the bundled design used through session 11 (W_S arm bandwidth 2 rad/s, pendulum 0.3): the
#: synthesis-core problem instances of the tests and benchmark tables; a 1-DOF upright controller with
#: these holds a 20° step through ±2 V of saturation (tests/test_antiwindup).
HINF_WEIGHTS = {
    "S": [{"bandwidth": 2.0, "hf_gain": 1.0}, {"num": [0.3], "den": [1]}],
    "R": [{"num": [1.0], "den": [1]}, {"num": [0.01], "den": [1]}],
    "K": {"num": [0.05], "den": [1]},
    "B": {"num": [0, 0.3], "den": [1, -0.7]},
    "integrator_shift": 1e-4,
}


def adip_vertex(arm_degrees: float, weights: dict | None = None) -> VertexPlant:
    """The mixed-sensitivity generalized plant (inputs [w, u], outputs [z, e]) at one arm angle."""
    a, b = rm.adip_linearization(np.deg2rad(arm_degrees), rm.default_parameters("adip"))
    G = control.c2d(control.ss(a, b, np.eye(2, 4), np.zeros((2, 1))), TS, method="zoh")
    W = weight_systems(HINF_WEIGHTS if weights is None else weights, 2, 1, TS)
    return VertexPlant.from_ss(augment(G, W, TS), nw=2, nz=3)
