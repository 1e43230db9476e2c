"""Identification experiments on FMU plants: excitation signals, open/closed-loop runs, CSV records."""

from lpvflow.experiment.controller import LtiController, load_controller
from lpvflow.experiment.fmu_experiment import run_fmu_experiment
from lpvflow.experiment.run import ExperimentRecord, run_experiment
from lpvflow.experiment.specs import SignalSpec, generate, parse_spec
from lpvflow.experiment.synthesized import SynthesizedController

__all__ = [
    "ExperimentRecord",
    "LtiController",
    "SignalSpec",
    "SynthesizedController",
    "generate",
    "load_controller",
    "parse_spec",
    "run_experiment",
    "run_fmu_experiment",
]
