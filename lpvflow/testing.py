"""Closed-loop regression tests as users write them: one call per test (recipe: docs/regression_tests.md).

    from lpvflow.testing import assert_closed_loop

    def test_pendulum_recovers_from_a_nudge():
        assert_closed_loop("controller.json", "plant.fmu", "scenarios.toml")

The scenario file is the one ``lpvflow verify --scenario`` reads (``[verify.loop]`` and
``[[verify.scenario]]`` with ``requirements``; layout in docs/design_file.md). A scenario fails when
the controller misses one of its requirements or fails its stability verdict; the AssertionError then
lists, per failing scenario, the requirement messages of ``lpvflow verify`` (e.g. ``arm_angle settles in 2.1 s
(limit 1.5 s)``), so the test report says what regressed.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from lpvflow.errors import DataError
from lpvflow.loop.loader import VERIFY_KINDS, load_controller_file
from lpvflow.pipeline.config import load_scenarios
from lpvflow.pipeline.scenarios import Loop, Scenario
from lpvflow.pipeline.verify import Baseline, Verification, run_verification


def assert_closed_loop(
    controller: str | Path | Baseline,
    plant_fmu: str | Path,
    scenarios: str | Path | Sequence[Scenario],
    loop: Loop | None = None,
) -> Verification:
    """Run ``controller`` against the plant FMU on every scenario; raise AssertionError unless it is
    stable and meets every requirement.

    Args:
        controller: a controller file (``lpvflow/lpv-controller`` or ``lpvflow/lti-controller`` JSON, or a
            controller FMU written by ``lpvflow export``) or a controller object (e.g. ``lpvflow.load``'s).
        plant_fmu: the plant FMU (FMI 2.0 Co-Simulation).
        scenarios: a scenario TOML file, or :class:`~lpvflow.pipeline.scenarios.Scenario` objects.
        loop: the loop wiring; default the file's ``[verify.loop]`` (required with Scenario objects).

    Returns:
        The :class:`~lpvflow.pipeline.verify.Verification` (metrics per scenario) for further checks.
    """
    if isinstance(scenarios, str | Path):
        parsed = load_scenarios(scenarios)
        loop, scenarios = loop or parsed.loop, parsed.scenarios
    if loop is None:
        raise DataError("no loop wiring: give a scenario file with a [verify.loop] table or pass loop=")
    law = load_controller_file(controller, VERIFY_KINDS, "verify") if isinstance(controller, str | Path) \
        else controller
    try:
        verification = run_verification(law, plant_fmu, scenarios, loop)
    finally:
        if law is not controller:  # loaded here: release what it holds (an FMU instance)
            law.close()
    failures = [f"scenario {result.scenario.name!r}: {problem}"
                for result in verification.results for problem in _problems(result.metrics[0])]
    if failures:
        raise AssertionError(f"closed loop on {Path(plant_fmu).name} fails {len(failures)} check(s):\n  "
                             + "\n  ".join(failures))
    return verification


def _problems(metrics: dict) -> list[str]:
    """The requirement messages of one run, else its failed stability verdict (empty: it passes)."""
    failed = metrics.get("requirements_failed") or []
    if not metrics["stable"]:
        return [f"unstable ({metrics['reason']})", *[f for f in failed if f != "the run failed (see reason)"]]
    return failed
