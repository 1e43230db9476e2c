"""The design-file schema: one layout for `design`, `synth --config` and `verify --scenario`, documented
key by key in docs/design_file.md, and the bundled examples load from any working directory."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from lpvflow.errors import DataError
from lpvflow.pipeline.config import (
    BUNDLED,
    OPTIONAL,
    REQUIRED,
    SCHEMA,
    bundled_config,
    check_table,
    load_config,
    load_scenarios,
    load_tables,
    repository_root,
)

DOC = repository_root() / "docs" / "design_file.md"


@pytest.mark.parametrize("table", list(SCHEMA))
def test_every_key_is_documented_with_its_default(table: str) -> None:
    text = DOC.read_text()
    section = text.split(f"## [{table}]")[1].split("\n## ")[0]
    rows = {m.group(1): m.group(2) for m in re.finditer(r"^\| `(\w+)` \|[^|]*\| ([^|]*) \|", section, re.M)}
    assert set(rows) == set(SCHEMA[table])
    for name, key in SCHEMA[table].items():
        assert (rows[name].strip() == "required") == (key.default is REQUIRED), name
    assert ("(optional" in text.split(f"## [{table}]")[1].splitlines()[0]) == (table in OPTIONAL)


@pytest.mark.parametrize("name", BUNDLED)
def test_bundled_examples_find_their_files_from_any_folder(name: str, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    config = load_config(bundled_config(name), root=repository_root())
    assert Path(config["design"]["plant"]).is_file()
    assert config["design"]["plant"].startswith(str(repository_root() / "fmu_plants"))
    with pytest.raises(DataError, match="relative to the working directory"):
        load_config(bundled_config(name))  # a user's file: relative to where lpvflow runs


def test_a_design_file_is_a_synth_config_and_a_scenario_file() -> None:
    path = bundled_config("adip-fast")
    tables = load_tables(path, need=("synth",))
    assert tables["synth"]["method"] == "observer" and tables["synth"]["structure"] == "2dof"
    assert len(tables["synth"]["box"]) == 3 and [len(b) for b in tables["synth"]["breakpoints"]] == [3] * 13
    assert tables["synth"]["reference_filter"] == {"bandwidth": 2.12, "damping": 1.0}
    weights = tables["synth"]["weights"]
    assert set(weights.given) == {"S", "R", "K", "B"} and weights.integrator_shift == 1e-4
    scenarios = load_scenarios(path)
    assert scenarios.loop.actuated == ("voltage",)
    assert [s.name for s in scenarios.scenarios][:2] == ["arm to +30 deg", "arm to -30 deg"]


def test_a_partial_file_is_enough_for_the_table_a_command_needs(tmp_path: Path) -> None:
    path = tmp_path / "synth.toml"
    path.write_text('[synth]\nsolver = "scs"\nweights.S = { bandwidth = 1.0 }\n'
                    'weights.K = { num = [1], den = [1] }\n')
    synth = load_tables(path, need=("synth",))["synth"]
    assert synth["solver"] == "SCS" and synth["method"] == "common" and synth["box"] is None
    with pytest.raises(DataError, match=r"synth.toml lacks the table\(s\) \['\[verify\]'\]"):
        load_scenarios(path)


@pytest.mark.parametrize(("table", "given", "fragment"), [
    ("experiment", {"Ts": float("inf"), "duration": 1.0}, "[experiment] Ts = inf must be a number"),
    ("experiment", {"Ts": True, "duration": 1.0}, "[experiment] Ts = True must be a number"),
    ("identify", {"u": ["a"], "y": ["b"], "p": ["c"], "na": 2.0}, "[identify] na = 2.0 must be an integer"),
    ("identify", {"u": "a", "y": ["b"], "p": ["c"]}, "[identify] u = 'a' must be a list of distinct names"),
    ("identify", {"u": ["a", "a"], "y": ["b"], "p": ["c"]}, "must be a list of distinct names"),
    ("identify", {"u": ["a"], "y": ["b"], "p": ["c"], "basis": "cubic"}, "[identify] basis: bad basis spec"),
    ("identify", {"u": ["a"], "y": ["b"], "p": ["c"], "remove_offsets": 1}, "must be true or false"),
    ("synth", {"weights": {"S": {}}}, "[synth] weights lacks ['K']"),
    ("synth", {"weights": {"S": {}, "K": 3}}, "[synth] weights.K = 3 must be a table"),
    ("synth", {"weights": {"S": {}, "K": {}, "integrator_shift": 0.5}}, "integrator_shift = 0.5 must be"),
    ("synth", {"weights": {"S": {"bandwidth": 1.0}, "K": {"num": [1], "den": [1]}}, "solver": "mosek"},
     "[synth] solver = 'MOSEK' must be one of"),
    ("synth", {"weights": {"S": {}, "K": {"num": [1], "den": [1]}}},
     "[synth] weights: weight W_S: give num/den"),
    ("synth", {"weights": {"S": {"bandwidth": 1.0}, "K": {"num": [1, 2], "den": [1]}}},
     "[synth] weights: weight W_K is not proper"),
    ("synth", {"weights": {"S": {"bandwidth": 1.0}, "K": {"num": [1], "den": [1]}},
               "vertex_weights": [{}, {"S": [{"bandwidth": -1.0}]}]},
     "[synth] vertex_weights[1]: weight W_S[0]: bandwidth -1.0 rad/s must be > 0"),
    ("validate", {"grid": 1}, "[validate] grid = 1 must be an integer ≥ 2"),
    ("experiment", {"Ts": 1.0, "duration": 1.0, "parameters": {"x0": "a"}}, "parameters.x0 = 'a'"),
])
def test_types_and_ranges(table: str, given: dict, fragment: str) -> None:
    with pytest.raises(DataError) as info:
        check_table(table, given, "d.toml")
    assert fragment in str(info.value) and "\n" not in str(info.value)
