"""The pipeline's structure: no import cycles, each stage's cache key made of exactly the settings it
reads, the design file parsed once, ``lpvflow synth --config`` writing the synth stage's controller."""

from __future__ import annotations

import ast
import dataclasses
import json
import re
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import lpvflow
from lpvflow.basis import Basis
from lpvflow.models import LPVSS
from lpvflow.pipeline import design as design_module
from lpvflow.pipeline.cli import main
from lpvflow.pipeline.config import INPUT_FILES, SCHEMA, load_config
from lpvflow.pipeline.context import StageContext
from lpvflow.pipeline.settings import ALL, StageSettings, TableView, UndeclaredSetting
from tests.design_files import tanks_head, tanks_synth

PACKAGE = Path(lpvflow.__file__).resolve().parent
ROOT = PACKAGE.parent
ADIP_FMU = ROOT / "fmu_plants" / "build" / "adip.fmu"


# --------------------------------------------------------------------------------------- import graph
def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph() -> dict[str, set[str]]:
    """lpvflow module → the lpvflow modules its file imports anywhere (module level or inside a
    function; ``if TYPE_CHECKING`` blocks excluded: they never run), and the packages whose
    ``__init__`` such an import runs (lpvflow's own ``__init__`` imports lazily and is left out)."""
    files = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph = {}
    for name, path in files.items():
        tree = ast.parse(path.read_text())
        typing_only = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If)
                       and "TYPE_CHECKING" in ast.unparse(node.test) for n in ast.walk(node)}
        targets = set()
        for node in ast.walk(tree):
            if id(node) in typing_only:
                continue
            if isinstance(node, ast.Import):
                targets |= {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                targets |= {f"{node.module}.{a.name}" for a in node.names} | {node.module}
        # importing a.b.c runs the package a.b's __init__ first: an edge to it as well
        parents = {".".join(t.split(".")[:i]) for t in targets for i in range(2, t.count(".") + 1)}
        graph[name] = {t for t in targets | parents
                       if t in files and t != name and not name.startswith(t + ".") and t != "lpvflow"}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_cycle_finder_finds_a_planted_cycle():
    """The check itself: a random acyclic graph has no cycle, one back edge makes one."""
    rng = np.random.default_rng(0)
    names = [f"m{i}" for i in range(30)]
    graph = {n: {names[j] for j in range(i + 1, 30) if rng.random() < 0.2} for i, n in enumerate(names)}
    assert cycles(graph) == []
    graph["m25"].add("m3")
    assert any("m3" in c and "m25" in c for c in cycles(graph))


def test_no_module_of_lpvflow_imports_itself_back():
    """No two files import each other, directly or around a loop, at module level or inside functions."""
    assert cycles(import_graph()) == []


#: No module branches on a controller class: ``run_fmu_experiment`` asks any controller object for the
#: controller an experiment runs (``experiment_controller()``, lpvflow.loop.protocol.ExperimentController).
CONTROLLER_TYPE_TESTS_ALLOWED: set[tuple[str, str]] = set()


def controller_type_tests(tree: ast.AST) -> list[str]:
    """The controller class names ``isinstance`` tests in ``tree`` (``X | Y`` and tuples split)."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "isinstance" \
                and len(node.args) == 2:
            found += [n.id for n in ast.walk(node.args[1]) if isinstance(n, ast.Name)
                      and (n.id.endswith("Controller") or n.id.startswith("Synthesized"))]
    return found


def test_the_controller_check_finds_planted_branches():
    planted = "if isinstance(K, LtiController | GriddedController): pass\nisinstance(x, (int, FmuController))"
    assert controller_type_tests(ast.parse(planted)) == ["LtiController", "GriddedController",
                                                         "FmuController"]
    assert controller_type_tests(ast.parse("isinstance(x, str | Path)")) == []


def test_no_module_branches_on_a_controller_class():
    """Every controller kind gives the loops what they need through its methods (the loop protocol,
    ``loop_law``, ``verification_law``, ``scheduled``, ``n_p``, ``frozen``, ``close``) and the one loader
    takes the kinds its caller runs: no isinstance on a controller class."""
    found = {(str(path.relative_to(ROOT)), name) for path in sorted(PACKAGE.rglob("*.py"))
             for name in controller_type_tests(ast.parse(path.read_text(encoding="utf-8")))}
    assert found == CONTROLLER_TYPE_TESTS_ALLOWED


# ------------------------------------------------------------------------------------ source hygiene
#: A docstring or comment citing a file outside the repository: the method notes (``notes_004 §2.3``),
#: the seed files (``seed 004``) or the issue tracker (``issue 26, item 2``).
OUTSIDE_REFERENCE = re.compile(r"notes_00|\bseed 00\d|\bissue \d+", re.IGNORECASE)


def outside_references(text: str) -> list[str]:
    """The lines of ``text`` that cite something outside the repository."""
    return [line.strip() for line in text.splitlines() if OUTSIDE_REFERENCE.search(line)]


def test_the_citation_check_finds_planted_references():
    """The check itself: paper citations pass, a notes file, a seed file or an issue number does not."""
    fine = "thesis §6.1, eq. (6.3); van Wingerden & Verhaegen (2009), Sec. 5.2; rng seed 1001; issues"
    assert outside_references(fine) == []
    for planted in ["(notes_004 §2.3)", "Seed 003 (Mejari et al.)", "(issue 26, item 2)", "see Issue 4"]:
        assert outside_references(f"{fine}\n    {planted}") == [planted]


def test_docstrings_cite_papers_not_files_outside_the_repository():
    """No lpvflow module cites the method notes, the seed files or an issue number: a reader of the
    repository has the papers and their sections, not those files."""
    found = {str(path.relative_to(ROOT)): lines for path in sorted(PACKAGE.rglob("*.py"))
             if (lines := outside_references(path.read_text(encoding="utf-8")))}
    assert found == {}


#: The longest a module of lpvflow may be: one that grows past it holds more than one job.
MAX_MODULE_LINES = 600


def test_no_module_of_lpvflow_is_over_600_lines():
    long = {str(path.relative_to(ROOT)): n for path in sorted(PACKAGE.rglob("*.py"))
            if (n := len(path.read_text(encoding="utf-8").splitlines())) > MAX_MODULE_LINES}
    assert long == {}


# ---------------------------------------------------------------------------------- settings and keys
def _recording_stages(ran: list[str]) -> tuple:
    """The design's stages with their work replaced by a record of the run (no files, no FMU)."""
    def fake(name: str):
        def run(ctx: StageContext) -> tuple[dict, list[str]]:
            ran.append(name)
            return {}, []
        return run
    return tuple(dataclasses.replace(stage, run=fake(stage.name)) for stage in design_module.STAGES)


def _downstream(names: set[str]) -> set[str]:
    out = set(names)
    while True:
        more = {s.name for s in design_module.STAGES if set(s.upstream) & out} - out
        if not more:
            return out
        out |= more


def _readers_keys(stage) -> set[tuple[str, str]]:
    """The (table, key) pairs a stage declares."""
    return {(table, key) for table, keys in stage.reads.items()
            for key in (SCHEMA[table] if keys == ALL else keys)}


def _readers(table: str, key: str) -> set[str]:
    return {s.name for s in design_module.STAGES
            if table in s.reads and (s.reads[table] == ALL or key in s.reads[table])}


def test_changing_any_key_reruns_exactly_the_stages_that_read_it(tmp_path):
    """Every key of every table, changed alone: the stages that read it and the stages downstream of
    them rerun, every other stage is reused (the real cache: keys, records in a folder). Keys naming
    input files (the plant, the experiment controller) change to another file."""
    inputs = tmp_path / "inputs"
    inputs.mkdir()
    files = {}
    for table, key in INPUT_FILES:
        for version in ("", " changed"):
            files[f"{table}.{key}{version}"] = inputs / f"{table}.{key}{version}"
            files[f"{table}.{key}{version}"].write_text(version)
    config = {table: {key: f"{table}.{key}" for key in keys} for table, keys in SCHEMA.items()}
    for table, key in INPUT_FILES:
        config[table][key] = str(files[f"{table}.{key}"])
    folder = tmp_path / "design"
    folder.mkdir()
    ran: list[str] = []
    stages = _recording_stages(ran)
    assert design_module._run_pass(stages, config, folder, {}, lambda _: None) is None
    assert ran == [s.name for s in stages]  # first pass: everything
    for table, keys in SCHEMA.items():
        for key in keys:
            ran.clear()
            value = f"{table}.{key} changed"
            changed = {**config, table: {**config[table], key: str(files.get(value, value))}}
            design_module._run_pass(stages, changed, folder, {}, lambda _: None)
            assert set(ran) == _downstream(_readers(table, key)), f"[{table}] {key}"
            design_module._run_pass(stages, config, folder, {}, lambda _: None)  # back to the first keys


def test_a_stage_cannot_read_a_key_it_does_not_declare():
    config = {table: {key: 0 for key in keys} for table, keys in SCHEMA.items()}
    settings = StageSettings(config, {"synth": ("method",), "verify": ALL})
    assert settings["synth"]["method"] == 0 and set(settings["verify"]) == set(SCHEMA["verify"])
    with pytest.raises(UndeclaredSetting, match=r"\[synth\] weights"):
        settings["synth"]["weights"]
    with pytest.raises(UndeclaredSetting, match=r"\[identify\]"):
        settings["identify"]


def test_synth_stage_reads_what_its_controller_depends_on():
    """The stale-cache defect: the synth stage's controller carries [verify.loop]'s anti-windup limits and
    operating points, the [experiment] scheduling expressions and the plant's units."""
    reads = design_module.SYNTH.reads
    assert "loop" in reads["verify"] and "scheduling" in reads["experiment"] and "plant" in reads["design"]


# ------------------------------------------------------------------------- synth CLI = synth stage
DESIGN = """
[design]
name = "small"
plant = "{plant}"
output_dir = "{out}"

[experiment]
duration = 1.0
scheduling = {{ sin_arm = "sin(arm_angle)" }}

[identify]
u = ["voltage"]
y = ["arm_angle"]
p = ["sin_arm"]

[reduce]

[validate]

[synth]
weights.S = {{ num = [0.5], den = [1] }}
weights.K = {{ num = [0.1], den = [1] }}

[verify.loop]
measured = ["arm_angle"]
actuated = ["voltage"]
scheduling = ["sin(arm_angle)"]
u_operating_point = [{u_op}]
actuator_limits = {{ voltage = [-10.0, 10.0] }}

[[verify.scenario]]
name = "step"
duration = 1.0
reference = {{ arm_angle = {{ steps = [[0.1, 0.2]] }} }}
"""


def _small_model(seed: int) -> LPVSS:
    rng = np.random.default_rng(seed)
    basis = Basis("affine", 1, p_min=(-0.5,), p_max=(0.5,))
    A = np.stack([[[0.5 + 0.3 * rng.random()]], [[0.1 * rng.standard_normal()]]])
    B = np.stack([[[1.0]], [[0.0]]])
    return LPVSS(A, B, np.array([[[1.0]], [[0.0]]]), np.zeros((2, 1, 1)), basis, 0.01,
                 u_names=["voltage"], y_names=["arm_angle"], p_names=["sin_arm"])


@pytest.mark.parametrize("seed", [1, 2])
def test_synth_cli_writes_the_controller_the_design_stage_writes(tmp_path, seed):
    u_op = float(np.random.default_rng(seed).uniform(-3, 3))
    path = tmp_path / "design.toml"
    path.write_text(DESIGN.format(plant=ADIP_FMU, out=tmp_path / "out", u_op=u_op))
    folder = tmp_path / "stage"
    folder.mkdir()
    _small_model(seed).save(folder / "model.json")
    config = load_config(path)
    design_module.SYNTH.run(StageContext(folder, StageSettings(config, design_module.SYNTH.reads)))
    out = str(tmp_path / "K.json")
    assert main(["synth", str(folder / "model.json"), "--config", str(path), "-o", out]) == 0
    by_stage = json.loads((folder / "controller.json").read_text())
    by_cli = json.loads((tmp_path / "K.json").read_text())
    for record in (by_stage, by_cli):  # the solver's wall-clock time is the only thing allowed to differ
        record["info"] = {k: v for k, v in record["info"].items() if "seconds" not in k}
    assert by_cli == by_stage
    actuated = by_cli["info"]["signals"]["actuated"][0]
    assert actuated["operating_point"] == pytest.approx(u_op) and actuated["unit"] == "V"
    assert by_cli["info"]["signals"]["scheduling"][0]["expression"] == "sin(arm_angle)"
    assert by_cli["antiwindup"] is not None


# ---------------------------------------------------------------------------------------- parse once
def _spy_everywhere(monkeypatch, function, spy) -> None:
    """Replace ``function`` by ``spy`` in its own module and in every loaded lpvflow module that imported
    it by name, so that no caller escapes the count (modules imported later take the spy from its own
    module)."""
    for name, module in list(sys.modules.items()):
        if name.split(".")[0] == "lpvflow" and getattr(module, function.__name__, None) is function:
            monkeypatch.setattr(module, function.__name__, spy)


def test_verify_loop_is_parsed_once_when_the_file_is_read(tmp_path, monkeypatch):
    import lpvflow.pipeline.key_checks as key_checks

    calls = []
    original = key_checks.parse_loop
    _spy_everywhere(monkeypatch, original, lambda doc: calls.append(doc) or original(doc))
    path = tmp_path / "design.toml"
    path.write_text(DESIGN.format(plant=ADIP_FMU, out=tmp_path / "out", u_op=0.0))
    config = load_config(path)
    assert len(calls) == 1
    loop = config["verify"]["loop"]
    assert loop.actuator_limits == {"voltage": (-10.0, 10.0)}
    assert StageSettings(config, design_module.SYNTH.reads)["verify"]["loop"] is loop  # handed on as parsed


def toy_design(model, plant, settings, frozen_model):
    """A synthesis method's design function (docs/synthesis_methods.md, place 1): the common design,
    marked as this method's."""
    from lpvflow.synth.design import design_common

    design = design_common(model, plant, settings, frozen_model)
    design.controller.info["designed_by"] = "toy"
    return design


def test_a_synthesis_method_is_a_design_function_and_one_registry_line(tmp_path, capsys, monkeypatch):
    """docs/synthesis_methods.md: adding a method is one module (here :func:`toy_design`), one line in
    SYNTHESIS_METHODS and its docs; the schema accepts the name and ``lpvflow synth`` runs it, prints its
    summary and writes its controller with nothing else changed."""
    from lpvflow.synth.methods import SYNTHESIS_METHODS, SynthesisMethod

    monkeypatch.setitem(SYNTHESIS_METHODS, "toy", SynthesisMethod("a toy: the common design, marked",
                                                                   f"{__name__}:toy_design"))
    rng = np.random.default_rng(4)
    A = np.stack([np.diag(rng.uniform(0.3, 0.8, 2)), 0.05 * rng.standard_normal((2, 2))])
    B, C = rng.standard_normal((2, 1)), rng.standard_normal((1, 2))  # B, C constant: A alone varies with p
    model = LPVSS(A, np.stack([B, 0 * B]), np.stack([C, 0 * C]), np.zeros((2, 1, 1)),
                  Basis("affine", 1, p_min=(0.0,), p_max=(1.0,)), 0.1, u_names=["u"], y_names=["y"],
                  p_names=["p"])
    model.save(tmp_path / "model.json")
    (tmp_path / "synth.toml").write_text('[synth]\nmethod = "toy"\nweights.S = { bandwidth = 0.5, '
                                         'hf_gain = 0.5 }\nweights.K = { num = [0.1], den = [1] }\n')
    status = main(["synth", str(tmp_path / "model.json"), "--config", str(tmp_path / "synth.toml"),
                   "-o", str(tmp_path / "k.json")])
    out, err = capsys.readouterr()
    assert status == 0, err
    assert out.startswith("a toy: the common design, marked, polytope box with 2 vertices")
    assert lpvflow.load(tmp_path / "k.json").info["designed_by"] == "toy"


def test_synthesis_error_is_one_of_lpvflows_error_types():
    """The class the solvers raise is lpvflow.errors.SynthesisError (lpvflow.synth.sdp re-exports it)."""
    from lpvflow.errors import ModelError, SynthesisError
    from lpvflow.synth.sdp import SynthesisError as raised

    assert raised is SynthesisError and issubclass(SynthesisError, ModelError)


TANKS = ROOT / "fmu_plants" / "build" / "tanks.fmu"

TANKS_DESIGN = """basis = "poly:2"
split = 0.6
remove_offsets = true

[reduce]
order = 2

[validate]
grid = 3
""" + tanks_synth() + """
[verify.loop]
measured = ["lower_level"]
actuated = ["pump_voltage"]
u_operating_point = [6.76]
actuator_limits = { pump_voltage = [0.0, 13.0] }

[[verify.scenario]]
name = "level 8 -> 12 cm"
duration = 300.0
reference = { lower_level = { initial = 0.08, steps = [[50.0, 0.04]] } }
"""


def test_one_design_run_reads_the_data_once_and_parses_the_loop_once(tmp_path, monkeypatch):
    """A whole run (experiment → … → verify on the tanks FMU): the stages read data.csv once, and
    [verify.loop] is parsed once, when the design file is read; the stages get the parsed loop; no Python
    warning escapes."""
    import lpvflow.data
    import lpvflow.pipeline.key_checks as key_checks
    import lpvflow.pipeline.report as report_module
    from lpvflow.pipeline.design import run_design

    reads, parses, in_report = [], [], [False]
    original_read, original_parse = lpvflow.data.read_columns, key_checks.parse_loop
    original_report = report_module.write_report

    def read(path, columns=None):
        if Path(path).name == "data.csv" and not in_report[0]:
            reads.append(columns)
        return original_read(path, columns)

    def report(*args, **kwargs):  # the report's own figure of the record is not a stage's read
        in_report[0] = True
        try:
            return original_report(*args, **kwargs)
        finally:
            in_report[0] = False

    current, accessed = [None], {}  # the stage running; stage → {(table, key)} it read
    original_item = TableView.__getitem__

    def item(view, key):
        accessed.setdefault(current[0], set()).add((view._table, key))
        return original_item(view, key)

    def watched(stage):
        def run(ctx):
            current[0] = stage.name
            try:
                return stage.run(ctx)
            finally:
                current[0] = None  # the cache key's reads between stages are the pipeline's
        return dataclasses.replace(stage, run=run)

    monkeypatch.setattr(TableView, "__getitem__", item)
    monkeypatch.setattr(design_module, "STAGES", tuple(watched(stage) for stage in design_module.STAGES))
    _spy_everywhere(monkeypatch, original_read, read)
    _spy_everywhere(monkeypatch, original_parse, lambda doc: parses.append(doc) or original_parse(doc))
    monkeypatch.setattr(report_module, "write_report", report)
    path = tmp_path / "design.toml"
    path.write_text(tanks_head(TANKS, tmp_path / "out") + TANKS_DESIGN)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        summary = run_design(path, log=lambda _: None)
    # no Python warning escapes the run; the box reaching past the identified range (0.18 against the
    # record's 0.1798) is said in the synth stage's words instead of a SchedulingRangeWarning
    assert [str(w.message) for w in caught] == []
    note = summary["stages"]["synth"]["outputs"]["box_note"]
    assert note.startswith("reaches past the identified range: level [0.05, 0.18] against [0, 0.1"), note
    ran = {name for name, stage in summary["stages"].items() if stage["status"] == "ran"}
    assert {"identify", "validate", "synth", "verify"} <= ran, summary["failed"]
    assert len(reads) == 1 and reads[0] is None  # every column, once, for every stage after the experiment
    assert len(parses) == 1
    controller = lpvflow.load(tmp_path / "out" / "tanks" / "controller.json")
    assert controller.antiwindup is not None  # the parsed loop's limits reached the synth stage
    # every stage that ran read its own table (if it has one: adoption and robustness have none), and only
    # keys it declares (the settings it received)
    for stage in design_module.STAGES:
        if stage.name in ran:
            if stage.name in SCHEMA:
                assert stage.name in {table for table, _ in accessed[stage.name]}, stage.name
            assert accessed[stage.name] <= _readers_keys(stage), stage.name


# ------------------------------------------------------------------------------ one loop engine
def _exact_model(G, reach: float) -> LPVSS:
    """The LTI plant G (inputs u0, u1, output y0) as an LPVSS scheduled on p, identified on ±reach."""
    zero = np.zeros((G.nstates, G.nstates))
    return LPVSS(np.stack([G.A, zero]), np.stack([G.B, 0 * G.B]), np.stack([G.C, 0 * G.C]),
                 np.zeros((2, 1, 2)), Basis("affine", 1, p_min=(-reach,), p_max=(reach,)), G.dt,
                 u_names=["u0", "u1"], y_names=["y0"], p_names=["p"])


@pytest.mark.parametrize("seed", [2, 5])
def test_the_model_in_the_loop_reproduces_an_lti_experiment_with_set_points(tmp_path, seed):
    """On an exact model the validate stage's closed-loop simulation (the loop engine with the model as
    plant) reproduces an LTI experiment with random set-points and excitation: the set-points' effect is
    in the recorded excitation (lpvflow.experiment.run), so it is counted once."""

    from lpvflow.data import Dataset
    from lpvflow.experiment import LtiController, run_experiment
    from lpvflow.experiment.record import write_record
    from lpvflow.pipeline.model_loop import closed_loop_simulation
    from tests.test_experiment_run import StateSpacePlant, stabilising_controller, unstable_plant

    G = unstable_plant()
    rng = np.random.default_rng(seed)
    y_op, u_op = rng.uniform(-0.5, 0.5, 1), rng.uniform(-0.5, 0.5, 1)
    path = tmp_path / "K.json"
    path.write_text(json.dumps(LtiController.from_statespace(stabilising_controller(), y_op=y_op,
                                                             u_op=u_op).to_dict()))
    record = run_experiment(StateSpacePlant(G, u0=[0.0, 0.0]), G.dt, 3.0,
                            controller=LtiController.from_statespace(stabilising_controller(), y_op=y_op,
                                                                     u_op=u_op),
                            setpoint={"y0": "levels:lo=-0.5,hi=0.5,min_hold=0.3,max_hold=0.6"},
                            excitation={"u0": "multisine:f_lo=1,f_hi=10,rms=0.1"},
                            scheduling_columns={"p": "y0"}, seed=seed, progress=False)
    write_record(record, tmp_path / "data.csv")
    model = _exact_model(G, 1.0)
    data = Dataset.read(tmp_path / "data.csv", ["u0", "u1"], ["y0"], ["p"])
    config = {"experiment": {"controller": str(path), "scheduling": {"p": "y0"}},
              "identify": {"remove_trim": False}}
    y_sim = closed_loop_simulation(model, data, StageContext(tmp_path, config))
    assert np.ptp(data.y) > 0.3
    np.testing.assert_allclose(y_sim, data.y, atol=1e-9)


@pytest.mark.parametrize("seed", [3, 7])
def test_the_model_in_the_loop_with_offsets_feeds_the_controller_plant_coordinates(tmp_path, seed):
    """With ``remove_offsets`` the model works in deviations from the estimation data's means (u₀, y₀);
    in the validate stage's closed-loop simulation the controller must read y₀ + y_model (its operating
    point y_op is in plant units) and the model get u − u₀. Compared with the same loop written out here;
    the loop with the controller reading the deviations differs (the check can fail)."""

    from lpvflow.experiment import LtiController, run_experiment
    from lpvflow.experiment.record import write_record
    from lpvflow.pipeline.coordinates import read_data
    from lpvflow.pipeline.model_loop import closed_loop_simulation
    from tests.test_experiment_run import StateSpacePlant, stabilising_controller, unstable_plant

    G = unstable_plant()
    rng = np.random.default_rng(seed)
    y_op, u_op = rng.uniform(1.0, 2.0, 1), rng.uniform(-0.5, 0.5, 1)
    K = LtiController.from_statespace(stabilising_controller(), y_op=y_op, u_op=u_op)
    path = tmp_path / "K.json"
    path.write_text(json.dumps(K.to_dict()))
    record = run_experiment(StateSpacePlant(G, u0=[0.0, 0.0]), G.dt, 3.0, controller=K,
                            excitation={"u0": "multisine:f_lo=1,f_hi=10,rms=0.1"},
                            scheduling_columns={"p": "y0"}, seed=seed, progress=False)
    write_record(record, tmp_path / "data.csv")
    zero = np.zeros((G.nstates, G.nstates))
    model = LPVSS(np.stack([G.A, zero]), np.stack([G.B, 0 * G.B]), np.stack([G.C, 0 * G.C]),
                  np.zeros((2, 1, 2)), Basis("affine", 1, p_min=(-1.0,), p_max=(3.0,)), G.dt,
                  u_names=["u0", "u1"], y_names=["y0"], p_names=["p"])
    config = {"experiment": {"controller": str(path), "scheduling": {"p": "y0"}},
              "identify": {"u": ["u0", "u1"], "y": ["y0"], "p": ["p"], "split": 0.7, "remove_offsets": True,
                           "remove_trim": False, "increments": []}}
    ctx = StageContext(tmp_path, config)
    val = read_data(ctx)[1]
    y_sim = closed_loop_simulation(model, val, ctx)
    offsets = read_data(ctx, model_signals=True)[0].offsets
    u0, y0 = np.array(offsets["u"]), np.array(offsets["y"])
    excitation = ctx.columns()["u0_excitation"][-val.N:]

    def loop(read_offset: np.ndarray) -> np.ndarray:
        x, xc, out = np.zeros(G.nstates), np.zeros(K.A.shape[0]), []
        for e in excitation:
            y = G.C @ x
            out.append(y.copy())
            dy = read_offset + y - K.y_op
            u = np.array([(K.u_op + K.C @ xc + K.D @ dy)[0] + e, 0.0])
            xc = K.A @ xc + K.B @ dy
            x = G.A @ x + G.B @ (u - u0)
        return np.array(out)

    assert abs(y0[0]) > 0.1  # the data are not centred on 0
    np.testing.assert_allclose(y_sim, loop(y0), atol=1e-9)
    assert np.max(np.abs(loop(np.zeros(1)) - loop(y0))) > 0.1


@pytest.mark.parametrize("seed", [3, 8])
def test_the_model_in_the_loop_runs_around_the_operating_point_it_was_identified_at(tmp_path, seed):
    """With ``remove_offsets`` the model describes deviations from (u₀, y₀); the validate stage's
    closed-loop fit runs it as the plant y₀ + y fed u − u₀ under the experiment controller (which reads
    and drives the plant's signals), the input the controller does not drive at its recorded values, and
    returns deviations: on the exact model of a plant started at rest at (u₀, y₀) it reproduces the
    record."""
    from lpvflow.data import Dataset
    from lpvflow.experiment import LtiController, run_experiment
    from lpvflow.experiment.record import write_record
    from lpvflow.pipeline.model_loop import closed_loop_simulation
    from tests.test_experiment_run import StateSpacePlant, stabilising_controller, unstable_plant

    G = unstable_plant()
    rng = np.random.default_rng(seed)
    u0 = rng.uniform(-1.0, 1.0, 2)
    x0 = np.linalg.solve(np.eye(G.nstates) - G.A, G.B @ u0)  # the plant at rest at (u0, y0)
    y0 = G.C @ x0
    K = LtiController.from_statespace(stabilising_controller(), y_op=y0, u_op=u0[:1])
    path = tmp_path / "K.json"
    path.write_text(json.dumps(K.to_dict()))
    plant = StateSpacePlant(G, u0=u0)
    plant.x = x0.copy()
    record = run_experiment(plant, G.dt, 3.0, inputs={"u1": "multisine:f_lo=1,f_hi=10,rms=0.2"},
                            controller=K, excitation={"u0": "multisine:f_lo=1,f_hi=10,rms=0.1"},
                            scheduling_columns={"p": "y0"}, seed=seed, progress=False)
    write_record(record, tmp_path / "data.csv")
    model = _exact_model(G, 5.0)
    measured = Dataset.read(tmp_path / "data.csv", ["u0", "u1"], ["y0"], ["p"])
    offsets = {"u": u0.tolist(), "y": y0.tolist()}
    data = dataclasses.replace(measured, u=measured.u - u0, y=measured.y - y0, offsets=offsets)
    config = {"experiment": {"controller": str(path), "scheduling": {"p": "y0"}},
              "identify": {"remove_trim": False}}
    ctx = StageContext(tmp_path, config, {"identify": {"offsets": offsets}})
    y_sim = closed_loop_simulation(model, data, ctx)
    assert np.ptp(data.y) > 0.05 and np.all(np.abs(y0) > 0.0)
    np.testing.assert_allclose(y_sim, data.y, atol=1e-9)
