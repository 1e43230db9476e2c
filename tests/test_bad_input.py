"""A newcomer's mistakes on every command: each gives one line on stderr naming what is wrong, exit
status 2, no traceback, and leaves every file alone (the inputs and the output target are hashed
before and after; no file appears or disappears).

The commands run in this process (:func:`lpvflow.pipeline.cli.main`) on one folder of small files made
once per module; the stage-level checks of a design file are in test_cli_errors.py.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from lpvflow.pipeline.cli import main
from tests.test_cli_errors import TANKS, design_text
from tests.test_cli_validate import true_system
from tests.test_export import _adip_lpv_controller
from tests.test_load_all import SCENARIO

ROOT = Path(__file__).resolve().parents[1]
ADIP = ROOT / "fmu_plants" / "build" / "adip.fmu"
COLUMNS = ("--u", "volt", "--y", "level", "--p", "theta")
SYNTH = """
[synth]
method = "common"
box = [[-1.0, 1.0]]
weights.S = { bandwidth = 1.0, hf_gain = 0.5 }
weights.K = { num = [0.1], den = [1] }
"""


def _csv(path: Path, header: list[str], rows: np.ndarray) -> Path:
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(f"{v:.9g}" for v in r) for r in rows) + "\n")
    return path


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Data of a 1x1 LPV system (and of a 2x2 one), models identified on them, controllers, an exported
    controller FMU, a scenario, a synth table, a design file, and files that are not what they claim."""
    d = tmp_path_factory.mktemp("bad_input")
    rng = np.random.default_rng(11)
    n, Ts = 600, 0.05
    u, p = rng.normal(size=(n, 1)), np.sin(np.arange(n) / 90.0)[:, None]
    y = true_system().simulate(u, p) + 0.01 * rng.normal(size=(n, 1))
    t = np.arange(n)[:, None] * Ts
    rows = np.hstack([t, u, p, y])
    data = _csv(d / "data.csv", ["time", "volt", "theta", "level"], rows)
    u2 = rng.normal(size=(n, 1))
    _csv(d / "two.csv", ["time", "volt", "volt2", "theta", "level", "level2"],
         np.hstack([t, u, u2, p, y, y + 0.5 * u2]))
    assert main(["identify", str(data), *COLUMNS, "-o", str(d / "model.json")]) == 0
    assert main(["identify", str(d / "two.csv"), "--u", "volt", "volt2", "--y", "level", "level2", "--p",
                 "theta", "-o", str(d / "other_plant.json")]) in (0, 1)
    _adip_lpv_controller().save(d / "k.json")
    assert main(["export", str(d / "k.json"), "--format", "fmu", "-o", str(d / "k.fmu")]) == 0
    (d / "lti.json").write_bytes((ROOT / "fmu_plants" / "adip" / "stabilizing_controller.json").read_bytes())
    (d / "scenario.toml").write_text(SCENARIO)
    (d / "synth.toml").write_text(SYNTH)
    (d / "design.toml").write_text(design_text(TANKS, d / "out"))
    (d / "out" / "tanks").mkdir(parents=True)
    (d / "out" / "tanks" / "report.html").write_text("previous good report")
    text = data.read_bytes()
    (d / "latin.csv").write_bytes(text.replace(b"theta", b"th\xe9ta", 1))
    (d / "image.csv").write_bytes(b"\x89PNG\r\n\x1a\n" + rng.integers(0, 256, 3000, dtype=np.uint8).tobytes())
    (d / "image.png").write_bytes((d / "image.csv").read_bytes())
    (d / "empty.csv").write_text("")
    (d / "header_only.csv").write_text("time,volt,theta,level\n")
    (d / "twice.csv").write_text("time,volt,volt,level\n0,1,2,3\n")
    lines = text.decode().splitlines()
    for name, row, value in (("nan.csv", 9, "nan"), ("word.csv", 12, "abc")):
        broken = [*lines]
        broken[row] = ",".join([*broken[row].split(",")[:3], value])
        (d / name).write_text("\n".join(broken) + "\n")
    (d / "short.csv").write_text("\n".join([*lines[:5], "0.25,1", *lines[6:]]) + "\n")
    (d / "jitter.csv").write_text("\n".join([*lines[:7], "0.31" + lines[7][lines[7].index(","):],
                                              *lines[8:]]) + "\n")
    (d / "fake.mat").write_text("not a MATLAB file")
    (d / "fake.parquet").write_text("not a Parquet file")
    (d / "fake.fmu").write_text("not an FMU")
    (d / "notes.txt").write_text("some notes")
    (d / "not_toml.toml").write_text("[synth\nmethod = ")
    (d / "latin.toml").write_bytes(b"[design]\nname = \"r\xe9glage\"\n")
    (d / "list.json").write_text("[1, 2, 3]")
    model = json.loads((d / "model.json").read_text())
    (d / "future.json").write_text(json.dumps({**model, "version": 99}))
    (d / "sub").mkdir()
    return d


def snapshot(folder: Path) -> dict[str, str]:
    """sha256 of every file under ``folder`` (new, changed and removed files all show)."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


#: (command line with {d} for the folder, fragment the one line must contain)
CASES: dict[str, tuple[str, str]] = {
    # ------------------------------------------------------------------------------------- identify
    "identify latin-1 csv": ("identify {d}/latin.csv --u volt --y level --p theta -o {d}/m.json",
                             "latin.csv is not CSV text in UTF-8"),
    "identify png named csv": ("identify {d}/image.csv --u volt --y level --p theta -o {d}/m.json",
                               "image.csv is not CSV text in UTF-8"),
    "identify png": ("identify {d}/image.png --u volt --y level --p theta -o {d}/m.json",
                     "unknown data format '.png'"),
    "identify missing data": ("identify {d}/none.csv --u volt --y level --p theta -o {d}/m.json",
                              "does not exist"),
    "identify unknown column": ("identify {d}/data.csv --u volt --y lvl --p theta -o {d}/m.json",
                                "column(s) ['lvl'] not found"),
    "identify bad basis": ("identify {d}/data.csv --u volt --y level --p theta --basis cubic -o {d}/m.json",
                           "bad basis spec"),
    "identify bad order": ("identify {d}/data.csv --u volt --y level --p theta --na x -o {d}/m.json",
                           "bad order"),
    "identify unknown method": ("identify {d}/data.csv --u volt --y level --p theta --method magic "
                                "-o {d}/m.json", "invalid choice: 'magic'"),
    "identify two-step without excitation": ("identify {d}/data.csv --u volt --y level --p theta "
                                             "--method two-step -o {d}/m.json", "needs --excitation"),
    "identify output over the data": ("identify {d}/data.csv --u volt --y level --p theta -o {d}/data.csv",
                                      "would overwrite the input file"),
    "identify output over a sidecar": ("identify {d}/data.csv --u volt --y level --p theta "
                                       "-o {d}/data.csv.json", "would overwrite the sidecar"),
    "identify output is a folder": ("identify {d}/data.csv --u volt --y level --p theta -o {d}/sub",
                                    "is a folder"),
    "identify output in a missing folder": ("identify {d}/data.csv --u volt --y level --p theta "
                                            "-o {d}/notes.txt/m.json",
                                            "m.json: {d}/notes.txt is a file, not a folder"),
    "identify empty csv": ("identify {d}/empty.csv --u volt --y level --p theta -o {d}/m.json", "is empty"),
    "identify header only": ("identify {d}/header_only.csv --u volt --y level --p theta -o {d}/m.json",
                             "at least 2"),
    "identify duplicate header": ("identify {d}/twice.csv --u volt --y level --p theta -o {d}/m.json",
                                  "duplicate column names"),
    "identify nan": ("identify {d}/nan.csv --u volt --y level --p theta -o {d}/m.json", "NaN/inf"),
    "identify word in data": ("identify {d}/word.csv --u volt --y level --p theta -o {d}/m.json",
                              "'abc' is not a number"),
    "identify short line": ("identify {d}/short.csv --u volt --y level --p theta -o {d}/m.json",
                            "has 2 fields"),
    "identify jittered time": ("identify {d}/jitter.csv --u volt --y level --p theta -o {d}/m.json",
                               "not uniformly spaced"),
    "identify missing time column": ("identify {d}/data.csv --u volt --y level --p theta --time clock "
                                     "-o {d}/m.json", "time column 'clock' not found"),
    "identify Ts against the time column": ("identify {d}/data.csv --u volt --y level --p theta --Ts 0.1 "
                                            "-o {d}/m.json", "disagrees with the time column"),
    "identify fake mat": ("identify {d}/fake.mat --u volt --y level --p theta -o {d}/m.json",
                          "not a readable MATLAB file"),
    "identify fake parquet": ("identify {d}/fake.parquet --u volt --y level --p theta -o {d}/m.json",
                              "not a readable Parquet file"),
    "identify a model as data": ("identify {d}/model.json --u volt --y level --p theta -o {d}/m.json",
                                 "unknown data format '.json'"),
    "identify no --y": ("identify {d}/data.csv --u volt --p theta -o {d}/m.json",
                        "the following arguments are required: --y"),
    "identify negative ridge": ("identify {d}/data.csv --u volt --y level --p theta --ridge -1 "
                                "-o {d}/m.json", "ridge"),
    # ------------------------------------------------------------------------------------- simulate
    "simulate a model of another plant": ("simulate {d}/other_plant.json {d}/data.csv --u volt --y level "
                                          "--p theta", "the model is 2x2"),
    "simulate a controller": ("simulate {d}/k.json {d}/data.csv --u volt --y level --p theta",
                              "holds no LPV model"),
    "simulate data as model": ("simulate {d}/data.csv {d}/data.csv --u volt --y level --p theta",
                               "is not a lpvflow JSON file"),
    "simulate a list as model": ("simulate {d}/list.json {d}/data.csv --u volt --y level --p theta",
                                 "unknown format"),
    "simulate a future version": ("simulate {d}/future.json {d}/data.csv --u volt --y level --p theta",
                                  "version 99"),
    "simulate missing model": ("simulate {d}/none.json {d}/data.csv --u volt --y level --p theta",
                               "does not exist"),
    "simulate latin-1 data": ("simulate {d}/model.json {d}/latin.csv --u volt --y level --p theta",
                              "is not CSV text in UTF-8"),
    "simulate plot over the model": ("simulate {d}/model.json {d}/data.csv --u volt --y level --p theta "
                                     "--plot {d}/model.json", "would overwrite the input file"),
    "simulate json into a folder": ("simulate {d}/model.json {d}/data.csv --u volt --y level --p theta "
                                    "--json {d}/sub", "is a folder"),
    "simulate same output twice": ("simulate {d}/model.json {d}/data.csv --u volt --y level --p theta "
                                   "--json {d}/fit.out --plot {d}/fit.out", "is given twice"),
    "simulate unknown column": ("simulate {d}/model.json {d}/data.csv --u volt --y level --p angle",
                                "column(s) ['angle'] not found"),
    "simulate too many columns": ("simulate {d}/model.json {d}/two.csv --u volt volt2 --y level --p theta",
                                  "the model is 1x1"),
    # ------------------------------------------------------------------------------------- validate
    "validate a model of another plant": ("validate {d}/other_plant.json {d}/data.csv --u volt --y level "
                                          "--p theta", "the model is 2x2"),
    "validate zero grid": ("validate {d}/model.json {d}/data.csv --u volt --y level --p theta --grid 0",
                           "grid"),
    "validate data as controller": ("validate {d}/model.json {d}/data.csv --u volt --y level --p theta "
                                    "--controller {d}/data.csv", "is not valid JSON"),
    "validate controller of another plant": ("validate {d}/model.json {d}/data.csv --u volt --y level "
                                             "--p theta --controller {d}/k.json", "controller"),
    "validate missing reference": ("validate {d}/model.json {d}/data.csv --u volt --y level --p theta "
                                   "--reference {d}/none.fmu --fmu-scheduling diag_scheduling", "not found"),
    "validate json over the model": ("validate {d}/model.json {d}/data.csv --u volt --y level --p theta "
                                     "--json {d}/model.json", "would overwrite the input file"),
    "validate png data": ("validate {d}/model.json {d}/image.csv --u volt --y level --p theta",
                          "is not CSV text in UTF-8"),
    "validate text as reference": ("validate {d}/model.json {d}/data.csv --u volt --y level --p theta "
                                   "--reference {d}/fake.fmu --fmu-scheduling diag_scheduling",
                                   "is not a readable FMU"),
    "validate figures in a file": ("validate {d}/model.json {d}/data.csv --u volt --y level --p theta "
                                   "--figures {d}/notes.txt", "is a file, not a folder"),
    # ------------------------------------------------------------------------------------- diagnose
    "diagnose split out of range": ("diagnose {d}/data.csv --u volt --y level --p theta --split 1.5",
                                    "split"),
    "diagnose unknown cause": ("diagnose {d}/data.csv --u volt --y level --p theta --causes gremlins",
                               "invalid choice: 'gremlins'"),
    "diagnose latin-1 data": ("diagnose {d}/latin.csv --u volt --y level --p theta",
                              "is not CSV text in UTF-8"),
    "diagnose json over the data": ("diagnose {d}/data.csv --u volt --y level --p theta --json {d}/data.csv",
                                    "would overwrite the input file"),
    "diagnose unknown candidate": ("diagnose {d}/data.csv --u volt --y level --p theta --candidates speed",
                                   "speed"),
    "diagnose data as controller": ("diagnose {d}/data.csv --u volt --y level --p theta --controller "
                                    "{d}/data.csv", "is not valid JSON"),
    "diagnose lpv controller": ("diagnose {d}/data.csv --u volt --y level --p theta --controller "
                                "{d}/k.json", "diagnose --controller runs"),
    "diagnose bad basis": ("diagnose {d}/data.csv --u volt --y level --p theta --basis round",
                           "bad basis spec"),
    # ---------------------------------------------------------------------------------------- synth
    "synth missing config": ("synth {d}/model.json --config {d}/none.toml -o {d}/c.json", "none.toml"),
    "synth config not TOML": ("synth {d}/model.json --config {d}/not_toml.toml -o {d}/c.json",
                              "not_toml.toml"),
    "synth data as config": ("synth {d}/model.json --config {d}/data.csv -o {d}/c.json", "data.csv"),
    "synth data as model": ("synth {d}/data.csv --config {d}/synth.toml -o {d}/c.json",
                            "is not a lpvflow JSON file"),
    "synth controller as model": ("synth {d}/k.json --config {d}/synth.toml -o {d}/c.json", "k.json"),
    "synth output over the model": ("synth {d}/model.json --config {d}/synth.toml -o {d}/model.json",
                                    "would overwrite the input file"),
    "synth model of another plant": ("synth {d}/other_plant.json --config {d}/synth.toml -o {d}/c.json",
                                     "B2 of the generalized plant depends on the scheduling parameter"),
    "synth missing model": ("synth {d}/none.json --config {d}/synth.toml -o {d}/c.json", "does not exist"),
    # --------------------------------------------------------------------------------------- verify
    "verify a controller FMU as plant": ("verify {d}/k.json --plant {d}/k.fmu --scenario {d}/scenario.toml "
                                         "--json {d}/v.json",
                                         "k is a controller written by `lpvflow export`, not a plant"),
    "verify missing plant": ("verify {d}/k.json --plant {d}/none.fmu --scenario {d}/scenario.toml "
                             "--json {d}/v.json", "not found"),
    "verify text as plant": ("verify {d}/k.json --plant {d}/fake.fmu --scenario {d}/scenario.toml "
                             "--json {d}/v.json", "is not a readable FMU"),
    "verify synth table as scenario": ("verify {d}/k.json --plant " + str(ADIP) + " --scenario "
                                       "{d}/synth.toml --json {d}/v.json", "verify"),
    "verify broken TOML": ("verify {d}/k.json --plant " + str(ADIP) + " --scenario {d}/not_toml.toml "
                           "--json {d}/v.json", "not_toml.toml"),
    "verify data as controller": ("verify {d}/data.csv --plant " + str(ADIP) + " --scenario "
                                  "{d}/scenario.toml --json {d}/v.json", "data.csv"),
    "verify json over the controller": ("verify {d}/k.json --plant " + str(ADIP) + " --scenario "
                                        "{d}/scenario.toml --json {d}/k.json", "would overwrite the input"),
    "verify missing baseline": ("verify {d}/k.json --plant " + str(ADIP) + " --scenario {d}/scenario.toml "
                                "--json {d}/v.json --baseline {d}/none.json", "none.json"),
    "verify model as controller": ("verify {d}/model.json --plant " + str(ADIP) + " --scenario "
                                   "{d}/scenario.toml --json {d}/v.json", "model.json"),
    "verify tanks plant for the adip loop": ("verify {d}/k.json --plant " + str(TANKS) + " --scenario "
                                             "{d}/scenario.toml --json {d}/v.json", "arm_angle"),
    # --------------------------------------------------------------------------------------- export
    "export mat named fmu": ("export {d}/k.json --format mat -o {d}/k2.fmu", "does not end in .mat"),
    "export fmu named mat": ("export {d}/k.json --format fmu -o {d}/k2.mat", "does not end in .fmu"),
    "export json named txt": ("export {d}/k.json --format json -o {d}/k2.txt", "does not end in .json"),
    "export a model": ("export {d}/model.json --format json -o {d}/k2.json", "has format 'lpvflow/lpvss'"),
    "export an LTI controller": ("export {d}/lti.json --format json -o {d}/k2.json",
                                 "export runs 'lpvflow/lpv-controller' controllers"),
    "export over the controller": ("export {d}/k.json --format json -o {d}/k.json",
                                   "would overwrite the input file"),
    "export unknown format": ("export {d}/k.json --format pdf -o {d}/k.pdf", "invalid choice: 'pdf'"),
    "export missing controller": ("export {d}/none.json --format json -o {d}/k2.json", "does not exist"),
    "export the FMU as controller": ("export {d}/k.fmu --format json -o {d}/k2.json", "k.fmu"),
    "export without format": ("export {d}/k.json -o {d}/k2.json",
                              "the following arguments are required: --format"),
    # ----------------------------------------------------------------------------------- experiment
    "experiment output named like a sidecar": ("experiment " + str(TANKS) + " --duration 2 --input "
                                               "pump_voltage=const:value=5 -o {d}/data.csv.json",
                                               "an experiment is written as CSV"),
    "experiment output txt": ("experiment " + str(TANKS) + " --duration 2 --input pump_voltage=const:value=5 "
                              "-o {d}/notes.txt", "an experiment is written as CSV; name the output"),
    "experiment controller FMU as plant": ("experiment {d}/k.fmu --duration 2 --input "
                                           "arm_angle=const:value=0 --set effect_noise_std=0.1 -o {d}/e.csv",
                                           "it is a controller written by `lpvflow export`, not a plant"),
    "experiment unknown parameter": ("experiment " + str(TANKS) + " --duration 2 --input "
                                     "pump_voltage=const:value=5 --set pump_gian=2 -o {d}/e.csv",
                                     "unknown parameter 'pump_gian'; known: "),
    "experiment parameter not a number": ("experiment " + str(TANKS) + " --duration 2 --input "
                                          "pump_voltage=const:value=5 --set pump_gain=big -o {d}/e.csv",
                                          "is not a number"),
    "experiment bad signal spec": ("experiment " + str(TANKS) + " --duration 2 --input "
                                   "pump_voltage=prbs:amp=1 -o {d}/e.csv", "prbs needs"),
    "experiment unknown input": ("experiment " + str(TANKS) + " --duration 2 --input "
                                 "pump=const:value=5 -o {d}/e.csv", "pump"),
    "experiment negative duration": ("experiment " + str(TANKS) + " --duration -1 --input "
                                     "pump_voltage=const:value=5 -o {d}/e.csv", "duration"),
    "experiment zero Ts": ("experiment " + str(TANKS) + " --duration 2 --Ts 0 --input "
                           "pump_voltage=const:value=5 -o {d}/e.csv", "Ts"),
    "experiment no input": ("experiment " + str(TANKS) + " --duration 2 -o {d}/e.csv",
                            "no --input and no --controller"),
    "experiment missing plant": ("experiment {d}/none.fmu --duration 2 --input pump_voltage=const:value=5 "
                                 "-o {d}/e.csv", "not found"),
    "experiment data as plant": ("experiment {d}/data.csv --duration 2 --input pump_voltage=const:value=5 "
                                 "-o {d}/e.csv", "is not a readable FMU"),
    "experiment data as controller": ("experiment " + str(ADIP) + " --duration 2 --controller {d}/data.csv "
                                      "-o {d}/e.csv", "data.csv"),
    "experiment bad scheduling expression": ("experiment " + str(TANKS) + " --duration 2 --input "
                                             "pump_voltage=const:value=5 --scheduling s=sin(lower_level "
                                             "-o {d}/e.csv", "sin(lower_level"),
    "experiment scheduling of an unknown signal": ("experiment " + str(TANKS) + " --duration 2 --input "
                                                   "pump_voltage=const:value=5 --scheduling s=height "
                                                   "-o {d}/e.csv", "height"),
    "experiment negative quantization": ("experiment " + str(TANKS) + " --duration 2 --input "
                                         "pump_voltage=const:value=5 --quantization lower_level=-1 "
                                         "-o {d}/e.csv", "quantization"),
    "experiment noise not a number": ("experiment " + str(TANKS) + " --duration 2 --input "
                                      "pump_voltage=const:value=5 --noise lower_level=abc -o {d}/e.csv",
                                      "is not a number"),
    "experiment bound reversed": ("experiment " + str(TANKS) + " --duration 2 --input "
                                  "pump_voltage=const:value=5 --bound lower_level=1,0 -o {d}/e.csv",
                                  "must read MIN,MAX with MIN < MAX"),
    "experiment output leaves its bound": ("experiment " + str(TANKS) + " --duration 2 --input "
                                           "pump_voltage=const:value=5 --bound lower_level=-1,1e-9 "
                                           "-o {d}/e.csv", "lower_level = "),
    "experiment input given twice": ("experiment " + str(TANKS) + " --duration 2 --input "
                                     "pump_voltage=const:value=5 --input pump_voltage=const:value=6 "
                                     "-o {d}/e.csv", "given twice"),
    "experiment input without a value": ("experiment " + str(TANKS) + " --duration 2 --input pump_voltage "
                                         "-o {d}/e.csv", "must read NAME=VALUE"),
    "experiment output over the plant": ("experiment " + str(TANKS) + " --duration 2 --input "
                                         "pump_voltage=const:value=5 -o " + str(TANKS), "would overwrite"),
    # --------------------------------------------------------------------------------------- design
    "design missing file": ("design {d}/none.toml", "none.toml"),
    "design broken TOML": ("design {d}/not_toml.toml", "not_toml.toml"),
    "design latin-1 TOML": ("design {d}/latin.toml", "latin.toml is not UTF-8 text"),
    "design data as design": ("design {d}/data.csv", "data.csv"),
    "design a synth table only": ("design {d}/synth.toml", "synth.toml"),
    "design file and example": ("design {d}/design.toml --example adip", "not both"),
    "design unknown example": ("design --example segway", "invalid choice: 'segway'"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_a_mistake_is_one_line_exit_2_and_changes_no_file(capsys, folder, case):
    argv, fragment = CASES[case]
    if argv.split()[0] in ("validate", "diagnose") and "--json" not in argv:
        argv += " --json {d}/report.json"  # required there
    before = snapshot(folder)
    try:
        status = main(argv.format(d=folder).split())
    except SystemExit as exit_:  # argparse's usage errors
        status = exit_.code
    captured = capsys.readouterr()
    err = captured.err
    assert status == 2, err
    assert err.count("\n") == 1 and err.startswith("lpvflow "), err
    assert "Traceback" not in err and ".py" not in err, err
    assert fragment.format(d=folder) in err, err
    assert snapshot(folder) == before


def test_a_toml_file_with_a_byte_order_mark_reads_like_without(folder, tmp_path):
    from lpvflow.pipeline.config import read_toml

    marked = tmp_path / "design.toml"
    marked.write_bytes(b"\xef\xbb\xbf" + (folder / "design.toml").read_bytes())
    assert read_toml(marked) == read_toml(folder / "design.toml")


@pytest.mark.slow
def test_a_refused_simulation_exits_cleanly_every_time(folder):
    """20 fresh processes: exit 2 after the one line, never SIGABRT at interpreter teardown (a native
    thread pool still running when the process exits after an early error)."""
    import subprocess
    import sys

    argv = [sys.executable, "-m", "lpvflow.pipeline.cli", *CASES["simulate a model of another plant"][0]
            .format(d=folder).split()]
    for _ in range(20):
        result = subprocess.run(argv, capture_output=True, text=True, check=False)
        assert (result.returncode, result.stderr.count("\n")) == (2, 1), result.stderr
