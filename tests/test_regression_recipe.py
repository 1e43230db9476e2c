"""docs/regression_tests.md: its scenario file and test run as written (in a pytest subprocess), a missed
requirement fails with the requirement's message, an exported controller FMU works the same way."""

import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from lpvflow.errors import DataError
from lpvflow.pipeline.config import load_scenarios
from lpvflow.pipeline.export import export_fmu
from lpvflow.testing import assert_closed_loop
from tests.test_export import _adip_lpv_controller

ROOT = Path(__file__).resolve().parents[1]
RECIPE = ROOT / "docs" / "regression_tests.md"
ADIP = ROOT / "fmu_plants" / "build" / "adip.fmu"
CONTROLLER = ROOT / "fmu_plants" / "adip" / "stabilizing_controller.json"
ARM_STEP = """
[[verify.scenario]]
name = "arm step 0.2 rad"
duration = 4.0
reference = { arm_angle = { steps = [[0.5, 0.2]] } }
settling_band = { arm_angle = 0.01 }
requirements = { settling_time = 2.0, overshoot = 0.05, after_settling = { pendulum_angle = 0.01 } }
"""


def _block(language: str, first_line: str) -> str:
    """The fenced ``language`` block of the recipe that starts with ``first_line``."""
    blocks = re.findall(rf"```{language}\n(.*?)```", RECIPE.read_text(), flags=re.S)
    return next(b for b in blocks if b.startswith(first_line))


@pytest.fixture
def scenario_file(tmp_path: Path) -> Path:
    path = tmp_path / "adip_scenarios.toml"
    path.write_text(_block("toml", "# tests/adip_scenarios.toml"))
    return path


def test_the_documented_test_passes_under_pytest(scenario_file: Path) -> None:
    test = scenario_file.with_name("test_closed_loop.py")
    test.write_text(_block("python", "# tests/test_closed_loop.py"))
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(test)],
                            cwd=ROOT, capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stdout[-2000:]
    assert "1 passed" in result.stdout


def test_a_missed_requirement_fails_with_its_message(scenario_file: Path) -> None:
    text = scenario_file.read_text().replace("settling_time = 1.0", "settling_time = 0.3")
    scenario_file.write_text(text + ARM_STEP)
    with pytest.raises(AssertionError) as info:
        assert_closed_loop(CONTROLLER, ADIP, scenario_file)
    documented = _block("text", "AssertionError: ").strip()
    assert f"AssertionError: {info.value}" == documented


def test_an_exported_controller_fmu_and_scenario_objects(scenario_file: Path, tmp_path: Path) -> None:
    parsed = load_scenarios(scenario_file)
    fmu = export_fmu(_adip_lpv_controller(), tmp_path / "K.fmu")
    verification = assert_closed_loop(fmu, ADIP, parsed.scenarios, parsed.loop)
    metrics = verification.to_dict()["scenarios"][0]["controller"]
    assert metrics["outputs"]["pendulum_angle"]["settling_time"] < 1.0
    with pytest.raises(DataError, match="no loop wiring"):
        assert_closed_loop(fmu, ADIP, parsed.scenarios)


def test_the_documented_requirements_parse() -> None:
    scenario = tomllib.loads(_block("toml", "# tests/adip_scenarios.toml"))["verify"]["scenario"][0]
    assert scenario["requirements"] == {"settling_time": 1.0, "after_settling": {"arm_angle": 0.2}}
