"""Identification experiments on FMU plants: excitation signals, open/closed-loop runs, CSV records.

The public names are imported on first use, so that importing one module of the package (e.g. the
controller classes, which the loop engine needs) does not import the experiment runner and its
dependencies first."""

import importlib

_LAZY = {"ExperimentRecord": "lpvflow.experiment.run", "LtiController": "lpvflow.experiment.controller",
         "SignalSpec": "lpvflow.experiment.specs", "SynthesizedController": "lpvflow.experiment.synthesized",
         "generate": "lpvflow.experiment.specs", "load_controller": "lpvflow.experiment.controller",
         "parse_spec": "lpvflow.experiment.specs", "run_experiment": "lpvflow.experiment.run",
         "run_fmu_experiment": "lpvflow.experiment.fmu_experiment"}

__all__ = sorted(_LAZY)


def __getattr__(name: str) -> object:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'lpvflow.experiment' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
