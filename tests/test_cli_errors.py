"""Every bad input a newcomer met (issue 25) gives one line naming what is wrong, exit status 2, and
leaves the user's files alone; Ctrl-C gives exit 130 and removes the interrupted stage's files; a
design folder is locked while a run writes it; the stage cache notices changed artifacts; a failed
certificate stops a design before verify and export.

Design runs here use stand-in stages (``design.STAGES`` patched) where the stage's work is not the
point, so the file runs in a few seconds.
"""

from __future__ import annotations

import dataclasses
import json
import os
import tempfile
import warnings
import zipfile
from pathlib import Path

import pytest

from lpvflow.basis import SchedulingRangeWarning
from lpvflow.models import atomic_write_json
from lpvflow.pipeline import cli_export, design
from lpvflow.pipeline.cache import folder_lock
from lpvflow.pipeline.cli import main, package_version
from lpvflow.pipeline.config import SCHEMA
from tests.design_files import tanks_head

ROOT = Path(__file__).resolve().parents[1]
TANKS = ROOT / "fmu_plants" / "build" / "tanks.fmu"

#: The rest of the design after the shared tanks head (100 s of data: fast, not a good model).
DESIGN_TAIL = """na = 2
split = 0.6

[reduce]

[validate]
grid = 3

[synth]
method = "common"
box = [[0.05, 0.2]]
weights.S = { bandwidth = 0.05, hf_gain = 0.5 }
weights.K = { num = [0.1], den = [1] }

[verify.loop]
measured = ["lower_level"]
actuated = ["pump_voltage"]
scheduling = ["lower_level"]

[[verify.scenario]]
name = "step"
duration = 50.0
reference = { lower_level = { steps = [[1.0, 0.01]] } }

[export]
formats = ["json"]
"""


def design_text(plant: object, out: object) -> str:
    """A valid tanks design writing into ``out``: the shared head (:func:`tests.design_files.tanks_head`,
    100 s of data, seed 0) and :data:`DESIGN_TAIL`."""
    return tanks_head(plant, out, duration=100.0, seed=0) + DESIGN_TAIL


def run_cli(capsys: pytest.CaptureFixture, *argv: object) -> tuple[int, str]:
    """Exit status and stderr of ``lpvflow ARGV`` run in this process."""
    status = main([str(a) for a in argv])
    return status, capsys.readouterr().err


def one_line(err: str, *fragments: str) -> None:
    """stderr is exactly one line, contains every fragment and no traceback or source path."""
    assert err.count("\n") == 1, err
    assert "Traceback" not in err and ".py" not in err, err
    for fragment in fragments:
        assert fragment in err, err


@pytest.fixture
def design_file(tmp_path: Path) -> Path:
    """A valid design; its folder already holds a previous run's report."""
    path = tmp_path / "design.toml"
    path.write_text(design_text(TANKS, tmp_path / "out"))
    folder = tmp_path / "out" / "tanks"
    folder.mkdir(parents=True)
    (folder / "report.html").write_text("previous good report")
    return path


# ------------------------------------------------------------------------------- bad design values
@pytest.mark.parametrize(("old", "new", "fragment"), [
    ("na = 2", 'na = "two"', "[identify] na = 'two' must be an integer ≥ 1"),
    ("Ts = 1.0", 'Ts = "fast"', "[experiment] Ts = 'fast' must be a number in (0, inf]"),
    ("box = [[0.05, 0.2]]", 'box = "wide"', "[synth] box = 'wide' must be a list of [lo, hi] intervals"),
    ("box = [[0.05, 0.2]]", "box = [[0.2, 0.05]]", "with lo < hi"),
    ("split = 0.6", "split = 1.5", "[identify] split = 1.5 must be a number in (0, 1)"),
    ("duration = 100.0", "duration = -5", "[experiment] duration = -5 must be a number in (0, inf]"),
    ("duration = 100.0", "duration = 100.0\noutput_bounds = { lower_level = [0.3, 0.1] }",
     "[experiment] output_bounds.lower_level = [0.3, 0.1] must be [min, max] with min < max"),
    ('method = "common"', 'methd = "common"', "[synth] has unknown key(s) ['methd']; known: "),
    ('box = [[0.05, 0.2]]', 'bx = [[0.05, 0.2]]', "[synth] has unknown key(s) ['bx']; known: "),
    ("weights.K", "weights.Q", "[synth] weights has unknown key(s) ['Q']"),
    ('formats = ["json"]', 'formats = ["pdf"]', '[export] formats'),
    ('name = "tanks"', 'name = "../tanks"', "[design] name = '../tanks' must be a folder name"),
    ("duration = 50.0", 'duration = "long"', "duration must be a finite number"),
])
def test_a_bad_design_value_is_one_line_exit_2_and_keeps_the_previous_report(
        capsys, design_file, old, new, fragment):
    design_file.write_text(design_file.read_text().replace(old, new, 1))
    status, err = run_cli(capsys, "design", design_file)
    assert status == 2
    one_line(err, "lpvflow design: error: design.toml: ", fragment)
    folder = design_file.parent / "out" / "tanks"
    assert sorted(p.name for p in folder.iterdir()) == ["report.html"]
    assert (folder / "report.html").read_text() == "previous good report"


@pytest.mark.parametrize(("table", "fragment"), [
    ("[synth]\nbx = [[0, 1]]\nweights.S = { bandwidth = 1.0 }\nweights.K = { num = [1], den = [1] }\n",
     f"[synth] has unknown key(s) ['bx']; known: {sorted(SCHEMA['synth'])}"),
    ("[synth]\nmethd = 'common'\n", "[synth] has unknown key(s) ['methd']"),
    ("[polytope]\nbox = [[0, 1]]\n[weights]\nS = {}\n", "synth settings now live in [synth]"),
])
def test_synth_refuses_unknown_keys_before_solving(capsys, tmp_path, table, fragment):
    config, model = tmp_path / "synth.toml", tmp_path / "model.json"
    config.write_text(table)
    model.write_text("{}")  # never read: the configuration is refused first
    status, err = run_cli(capsys, "synth", model, "--config", config, "-o", tmp_path / "k.json")
    assert status == 2
    one_line(err, "lpvflow synth: error: synth.toml: ", fragment)
    assert not (tmp_path / "k.json").exists()


def test_a_text_file_named_fmu_is_refused_before_anything_is_written(capsys, design_file):
    fake = design_file.parent / "x.fmu"
    fake.write_text("not an FMU")
    design_file.write_text(design_file.read_text().replace(str(TANKS), str(fake)))
    status, err = run_cli(capsys, "design", design_file)
    assert status == 2
    one_line(err, "[design] plant:", "x.fmu is not a readable FMU")
    assert (design_file.parent / "out" / "tanks" / "report.html").read_text() == "previous good report"


def without_binary(tmp_path: Path, damage: bool = False) -> Path:
    """tanks.fmu without its linux64 binary (``damage``: with a binary that is not a shared library)."""
    target = tmp_path / ("damaged.fmu" if damage else "nobinary.fmu")
    with zipfile.ZipFile(TANKS) as source, zipfile.ZipFile(target, "w") as copy:
        for item in source.infolist():
            if item.filename.startswith("binaries/linux64/"):
                if damage:
                    copy.writestr(item, b"not a shared library")
            else:
                copy.writestr(item, source.read(item))
    return target


@pytest.mark.parametrize(("damage", "fragment"), [
    (False, "has no linux64 binary (binaries/linux64/tanks.so)"),
    (True, "the FMU's binary cannot be loaded")])
def test_an_fmu_without_a_usable_binary_is_one_line_and_leaves_no_temporary_folder(
        capsys, tmp_path, monkeypatch, damage, fragment):
    fmu = without_binary(tmp_path, damage)
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))  # where fmpy extracts FMUs
    status, err = run_cli(capsys, "experiment", fmu, "--duration", 1, "--input", "pump_voltage=const:value=5",
                          "-o", tmp_path / "data.csv")
    assert status == 2
    one_line(err, fragment)
    assert list(scratch.iterdir()) == [] and not (tmp_path / "data.csv").exists()
    assert Path.cwd().exists()  # fmpy's failed load leaves the process in the deleted binary folder


# ------------------------------------------------------------------------------------ output paths
@pytest.mark.parametrize("argv", [
    ["identify", "{data}", "--u", "a", "--y", "b", "--p", "c", "-o", "/proc/model.json"],
    ["simulate", "{model}", "{data}", "--u", "a", "--y", "b", "--p", "c", "--plot", "/proc/fit.png"],
    ["experiment", str(TANKS), "--duration", "1", "--input", "pump_voltage=const:value=5",
     "-o", "/proc/data.csv"],
    ["export", "{model}", "--format", "json", "-o", "/proc/k.json"],
    ["verify", "{model}", "--plant", str(TANKS), "--scenario", "{data}", "--json", "{tmp}/v.json",
     "--figures", "/proc/figures"],
    ["validate", "{model}", "{data}", "--u", "a", "--y", "b", "--p", "c", "--json", "/proc/v.json"],
    ["diagnose", "{data}", "--u", "a", "--y", "b", "--p", "c", "--json", "/proc/d.json"],
])
def test_an_unwritable_output_is_one_line_before_any_work(capsys, tmp_path, argv):
    paths = {"data": tmp_path / "data.csv", "model": tmp_path / "model.json", "tmp": tmp_path}
    status, err = run_cli(capsys, *(a.format(**paths) for a in argv))
    assert status == 2
    one_line(err, f"lpvflow {argv[0]}: error: cannot write ", "/proc", "choose a writable folder")


def test_an_output_inside_a_file_is_one_line(capsys, tmp_path):
    (tmp_path / "file").write_text("x")
    status, err = run_cli(capsys, "export", tmp_path / "k.json", "--format", "json",
                          "-o", tmp_path / "file" / "k.json")
    assert status == 2
    one_line(err, "is a file, not a folder")


@pytest.mark.parametrize("output_dir", ["/proc/lpvflow", "{tmp}/file"])
def test_a_design_output_dir_that_cannot_hold_the_design_is_one_line(capsys, design_file, output_dir):
    (design_file.parent / "file").write_text("x")
    text = design_file.read_text().replace(str(design_file.parent / "out"),
                                           output_dir.format(tmp=design_file.parent))
    design_file.write_text(text)
    status, err = run_cli(capsys, "design", design_file)
    assert status == 2
    one_line(err, "the design folder ([design] output_dir / name)")
    assert (design_file.parent / "file").read_text() == "x"


def test_no_output_may_be_an_input_or_config_of_the_same_command(capsys, tmp_path):
    config, model = tmp_path / "synth.toml", tmp_path / "model.json"
    config.write_text("[synth]\n")
    model.write_text("{}")
    status, err = run_cli(capsys, "synth", model, "--config", config, "-o", config)
    assert status == 2
    one_line(err, f"output {config} would overwrite the input file {config} of this command")
    assert config.read_text() == "[synth]\n"
    data, sidecar = tmp_path / "data.csv", tmp_path / "data.csv.json"
    data.write_text("t,u,y,p\n")
    sidecar.write_text("{}")
    status, err = run_cli(capsys, "identify", data, "--u", "u", "--y", "y", "--p", "p", "-o", sidecar)
    assert status == 2
    one_line(err, f"would overwrite the sidecar of the input file {data}")
    assert sidecar.read_text() == "{}"


def test_a_design_input_inside_the_design_folder_is_refused(capsys, design_file):
    folder = design_file.parent / "out" / "tanks"
    moved = folder / "design.toml"
    moved.write_text(design_file.read_text())
    status, err = run_cli(capsys, "design", moved)
    assert status == 2
    one_line(err, "is inside the design folder")


# ------------------------------------------------------------------- interrupt, lock, cache, certificate
def stand_in(name: str, write: dict[str, str], outputs: dict | None = None, reads: str | None = None):
    """A stage that writes ``write`` (name -> text) and returns ``outputs`` (plus what it read)."""
    def run(ctx: design.stages.StageContext) -> tuple[dict, list[str]]:
        for file, text in write.items():
            ctx.path(file).write_text(text() if callable(text) else text)
        read = ctx.path(reads).read_text() if reads else None
        return {**(outputs or {}), "read": read}, list(write)
    return run


def patch_stages(monkeypatch: pytest.MonkeyPatch, runs: dict) -> None:
    """Replace the runners of the named stages; the others become no-ops writing nothing."""
    stages = tuple(dataclasses.replace(s, run=runs.get(s.name, stand_in(s.name, {}))) for s in design.STAGES)
    monkeypatch.setattr(design, "STAGES", stages)


def test_ctrl_c_exits_130_in_one_line_and_removes_the_stage_files(capsys, design_file, monkeypatch):
    def interrupted(ctx: design.stages.StageContext) -> tuple[dict, list[str]]:
        ctx.path("data.csv").write_text("time,pump_voltage\n0,")  # half a file
        raise KeyboardInterrupt

    patch_stages(monkeypatch, {"experiment": interrupted})
    status, err = run_cli(capsys, "design", design_file)
    assert status == 130
    assert err.splitlines()[-1] == "lpvflow design: interrupted by Ctrl-C" and "Traceback" not in err
    folder = design_file.parent / "out" / "tanks"
    assert not (folder / "data.csv").exists() and not (folder / "experiment.json").exists()
    assert (folder / "report.html").read_text() == "previous good report"


def test_a_second_run_on_a_locked_design_folder_is_refused(capsys, design_file, monkeypatch):
    patch_stages(monkeypatch, {})
    folder = design_file.parent / "out" / "tanks"
    with folder_lock(folder):
        status, err = run_cli(capsys, "design", design_file)
    assert status == 2
    one_line(err, f"design folder {folder} is being written by another lpvflow run (pid {os.getpid()})",
             "wait for it to finish")
    assert (folder / "report.html").read_text() == "previous good report"
    assert run_cli(capsys, "design", design_file)[0] == 0  # released


def test_the_stage_cache_checks_the_artifacts_a_stage_wrote_and_reads(design_file, monkeypatch):
    counter = iter(range(100))
    patch_stages(monkeypatch, {
        "experiment": stand_in("experiment", {"data.csv": lambda: f"time,run\n0,{next(counter)}\n"}),
        "identify": stand_in("identify", {"model_full.json": "m"}, reads="data.csv"),
        "synth": stand_in("synth", {"controller.json": "K"}, {"certificate_ok": True}),
        "export": stand_in("export", {"exported_controller.json": "exported K"}, reads="controller.json"),
    })
    folder = design_file.parent / "out" / "tanks"

    def statuses() -> dict[str, str]:
        summary = design.run_design(design_file, log=lambda _: None)
        return {n: s["status"] for n, s in summary["stages"].items() if n in ("experiment", "identify",
                                                                             "synth", "export")}

    assert set(statuses().values()) == {"ran"}
    assert set(statuses().values()) == {"cached"}
    # another run (or a hand edit) replaced an artifact: the stage that wrote it reruns
    (folder / "exported_controller.json").write_text("someone else's controller")
    assert statuses() == {"experiment": "cached", "identify": "cached", "synth": "cached", "export": "ran"}
    assert (folder / "exported_controller.json").read_text() == "exported K"
    # an upstream stage reruns with new bytes under the same key: its readers (and theirs) rerun too
    (folder / "experiment.json").unlink()
    assert set(statuses().values()) == {"ran"}
    assert json.loads((folder / "identify.json").read_text())["outputs"]["read"] == "time,run\n0,1\n"


def test_a_failed_certificate_stops_the_design_before_verify_and_export(capsys, design_file, monkeypatch):
    failing = stand_in("synth", {"controller.json": "K"}, {"certificate_ok": False})
    patch_stages(monkeypatch, {"synth": failing})
    status, err = run_cli(capsys, "design", design_file)
    assert status == 1
    assert err.splitlines()[-1].startswith("design did not pass: stage synth failed")
    summary = json.loads((design_file.parent / "out" / "tanks" / "summary.json").read_text())
    assert summary["failed"]["stage"] == "synth" and "certificate" in summary["failed"]["error"]
    assert {n for n, s in summary["stages"].items() if s["status"] in ("ran", "cached")} == {
        "experiment", "identify", "reduce", "validate", "synth"}


# -------------------------------------------------------------------------- version, warnings, umask
def test_version(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0 and capsys.readouterr().out == f"lpvflow {package_version()}\n"
    assert package_version()[0].isdigit()


def test_warnings_reach_the_user_as_one_line_in_lpvflow_words(capsys, tmp_path, monkeypatch):
    def noisy(args: object) -> int:
        for _ in range(3):
            warnings.warn("Solution may be inaccurate. Try another solver, adjusting the solver settings, "
                          "or solve with verbose=True for more information.", UserWarning, stacklevel=1)
            warnings.warn("scheduling outside the identified range [[0.0], [1.0]]: the model extrapolates "
                          "there", SchedulingRangeWarning, stacklevel=1)
        return 0

    monkeypatch.setattr(cli_export, "run", noisy)
    status, err = run_cli(capsys, "export", tmp_path / "k.json", "--format", "json",
                          "-o", tmp_path / "o.json")
    assert status == 0
    assert err.splitlines() == [  # cvxpy's warning comes with a status lpvflow's solves check themselves
        "lpvflow export: warning: scheduling outside the identified range [[0.0], [1.0]]: the model "
        "extrapolates there"]


def test_written_files_follow_the_umask(tmp_path):
    previous = os.umask(0o027)
    try:
        atomic_write_json(tmp_path / "a.json", {})
    finally:
        os.umask(previous)
    assert (tmp_path / "a.json").stat().st_mode & 0o777 == 0o640


# -------------------------------------------------------------------------------------- experiment
def test_experiment_takes_the_fmu_step_and_refuses_an_unexcited_run(capsys, tmp_path):
    out = tmp_path / "data.csv"
    status, err = run_cli(capsys, "experiment", TANKS, "--duration", 2, "-o", out)
    assert status == 2 and not out.exists()
    one_line(err, "no --input and no --controller", "--input NAME=SPEC")
    status = main(["experiment", str(TANKS), "--duration", "2", "--input", "pump_voltage=const:value=5",
                   "-o", str(out)])
    assert status == 0
    sidecar = json.loads((tmp_path / "data.csv.json").read_text())
    assert sidecar["Ts"] == 0.2  # tanks' modelDescription.xml: DefaultExperiment stepSize="0.2"
    assert (out.stat().st_mode & 0o777) == 0o666 & ~_umask()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_a_design_without_ts_runs_its_experiment_at_the_fmu_step(design_file):
    from lpvflow.pipeline.config import load_config
    from lpvflow.pipeline.context import StageContext
    from lpvflow.pipeline.stages import experiment

    design_file.write_text(design_file.read_text().replace("Ts = 1.0\nduration = 100.0", "duration = 2.0"))
    config = load_config(design_file)
    assert config["experiment"]["Ts"] is None
    outputs, _ = experiment(StageContext(design_file.parent, config))
    assert outputs["Ts"] == 0.2 and outputs["samples"] == 10  # 2 s of 0.2 s steps
