"""Every file an lpvflow command writes carries ``format``/``version`` and loads with ``lpvflow.load`` in a
fresh interpreter (no module imported first that would register its loader); other versions are refused."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lpvflow.errors import ModelError
from lpvflow.models import load
from lpvflow.pipeline import design
from lpvflow.pipeline.cli import main
from tests.diagnosis_cases import make_case
from tests.test_cli_errors import design_file, patch_stages  # noqa: F401 (design_file: a fixture)
from tests.test_cli_validate import true_system
from tests.test_export import _adip_lpv_controller

ROOT = Path(__file__).resolve().parents[1]
COLUMNS = ["--u", "volt", "--y", "level", "--p", "theta"]
SCENARIO = """
[verify.loop]
measured = ["arm_angle", "pendulum_angle"]
actuated = ["voltage"]
scheduling = ["sin(arm_angle)"]

[[verify.scenario]]
name = "hold"
duration = 0.5
settling_band = { pendulum_angle = 0.01 }
"""

#: file written → (format, type name lpvflow.load returns)
EXPECTED = {
    "model.json": ("lpvflow/lpvss", "LPVSS"),
    "model_io.json": ("lpvflow/lpvio", "LPVIO"),
    "lfr.json": ("lpvflow/lpvlfr", "LPVLFR"),
    "simulation.json": ("lpvflow/simulation", "dict"),
    "validation.json": ("lpvflow/validation", "dict"),
    "diagnosis.json": ("lpvflow/diagnosis", "dict"),
    "exp.csv.json": ("lpvflow/experiment", "dict"),
    "lpv_controller.json": ("lpvflow/lpv-controller", "LPVController"),
    "exported.json": ("lpvflow/lpv-controller", "LPVController"),
    "lti_controller.json": ("lpvflow/lti-controller", "LtiController"),
    "verification.json": ("lpvflow/verification", "dict"),
    "extended.json": ("lpvflow/extended-model", "ExtendedModel"),
}


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One file of every kind, each written by the command (or, for the synthesized controller, the
    writer the synth stage calls) that produces it."""
    folder = tmp_path_factory.mktemp("written")
    rng = np.random.default_rng(5)
    n, Ts = 1000, 0.05
    u, p = rng.normal(size=(n, 1)), np.sin(np.arange(n) / 150.0)[:, None]
    y = true_system().simulate(u, p) + 0.01 * rng.normal(size=(n, 1))
    data = folder / "data.csv"
    np.savetxt(data, np.column_stack([np.arange(n) * Ts, u, p, y]), delimiter=",",
               header="time,volt,theta,level", comments="")
    f = lambda name: str(folder / name)  # noqa: E731
    commands = [
        ["identify", str(data), *COLUMNS, "-o", f("model.json")],
        ["identify", str(data), *COLUMNS, "--method", "static-arx", "-o", f("model_io.json")],
        ["identify", str(data), *COLUMNS, "--method", "kcca-lfr", "--order", "2", "-o", f("lfr.json")],
        ["simulate", f("model.json"), str(data), *COLUMNS, "--json", f("simulation.json")],
        ["validate", f("model.json"), str(data), *COLUMNS, "--grid", "2", "--json", f("validation.json")],
        ["diagnose", str(data), *COLUMNS, "--causes", "offset", "--json", f("diagnosis.json")],
        ["experiment", str(ROOT / "fmu_plants" / "build" / "tanks.fmu"), "--Ts", "0.5", "--duration", "5",
         "--input", "pump_voltage=prbs:amp=1,clock=2,order=3", "-o", f("exp.csv")],
    ]
    _adip_lpv_controller().save(folder / "lpv_controller.json")
    (folder / "lti_controller.json").write_bytes(
        (ROOT / "fmu_plants" / "adip" / "stabilizing_controller.json").read_bytes())
    (folder / "scenario.toml").write_text(SCENARIO)
    dead_zone, _, _ = make_case("input_nonlinearity", seed=11, n=2000)
    np.savetxt(folder / "dead_zone.csv", np.column_stack([dead_zone.u, dead_zone.y, dead_zone.p]),
               delimiter=",", header="u,y,p", comments="")
    commands += [
        ["export", f("lpv_controller.json"), "--format", "json", "-o", f("exported.json")],
        ["verify", f("lpv_controller.json"), "--plant", str(ROOT / "fmu_plants" / "build" / "adip.fmu"),
         "--scenario", f("scenario.toml"), "--json", f("verification.json")],
        ["diagnose", f("dead_zone.csv"), "--u", "u", "--y", "y", "--p", "p", "--Ts", "0.01",
         "--causes", "input_nonlinearity", "--json", f("dead_zone_diagnosis.json"),
         "--model-out", f("extended.json")],
    ]
    for command in commands:
        assert main(command) in (0, 1), command  # 1: a finding (e.g. validate's ν-gap), file still written
    return folder


def test_every_written_file_loads_in_a_fresh_interpreter(written: Path) -> None:
    files = [str(written / name) for name in EXPECTED]
    script = ("import sys, lpvflow\n"
              "for path in sys.argv[1:]:\n"
              "    print(type(lpvflow.load(path)).__name__)\n")
    result = subprocess.run([sys.executable, "-c", script, *files], capture_output=True, text=True,
                            check=False)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == [kind for _, kind in EXPECTED.values()]
    for name, (fmt, _) in EXPECTED.items():
        document = json.loads((written / name).read_text())
        assert (document["format"], document["version"]) == (fmt, 1), name


@pytest.mark.parametrize("name", list(EXPECTED))
def test_another_version_is_refused_with_one_line(written: Path, tmp_path: Path, name: str) -> None:
    document = json.loads((written / name).read_text())
    document["version"] = 99
    path = tmp_path / name
    path.write_text(json.dumps(document))
    with pytest.raises(ModelError) as info:
        load(path)
    message = str(info.value)
    assert "version 99" in message and "\n" not in message


def test_a_file_without_format_names_the_known_kinds(tmp_path: Path) -> None:
    path = tmp_path / "x.json"
    path.write_text(json.dumps({"bfr": [1.0]}))
    with pytest.raises(ModelError, match=r"unknown format ''; expected one of .*lpvflow/lti-controller.*"
                                         r"lpvflow/verification"):
        load(path)


def test_a_design_folder_s_summary_and_stage_records_load(design_file, monkeypatch) -> None:  # noqa: F811
    patch_stages(monkeypatch, {})
    design.run_design(design_file, log=lambda _: None)
    folder = design_file.parent / "out" / "tanks"
    loaded = {path.stem: load(path) for path in folder.glob("*.json")}
    assert loaded["summary"]["format"] == "lpvflow/design"
    stages = {name: record for name, record in loaded.items() if name != "summary"}
    assert {"experiment", "identify", "synth", "verify", "export"} <= set(stages) <= {
        stage.name for stage in design.STAGES}
    for name, record in stages.items():
        assert (record["format"], record["version"], record["stage"]) == ("lpvflow/stage", 1, name)
    again = design.run_design(design_file, log=lambda _: None)["stages"]
    assert {again[name]["status"] for name in stages} == {"cached"}  # the records still serve as the cache
