"""The design-file schema (TOML): one table per stage, every key typed and range-checked on load.

The same tables serve every command that reads TOML: ``lpvflow design`` reads the whole file,
``lpvflow synth --config`` its ``[synth]`` table and ``lpvflow verify --scenario`` its ``[verify]``
table (``[verify.loop]`` and ``[[verify.scenario]]``); any design file works for all three. Unknown
tables or keys are refused with the known ones listed, so that a typo never silently falls back to a
default. ``docs/design_file.md`` documents every key (a test keeps it complete).
The value checkers the schema pairs with its keys are in :mod:`lpvflow.pipeline.key_checks`.

Relative paths (``plant``, ``controller``, ``output_dir``) are taken relative to the working directory;
in the bundled examples (``lpvflow design --example NAME``) the input files are relative to the
repository root, so the examples run from any working directory.
"""

from __future__ import annotations

import dataclasses
import tomllib
from collections.abc import Iterator, Mapping
from importlib import resources
from pathlib import Path
from typing import Any

from lpvflow.errors import DataError, LpvflowError
from lpvflow.fmu import check_fmu
from lpvflow.pipeline.key_checks import (
    REQUIRED,
    Key,
    basis,
    boolean,
    box,
    breakpoints,
    folder_name,
    formats,
    integer,
    interval,
    largest_step,
    loop,
    mapping,
    margin_goal,
    method,
    names,
    number,
    observer,
    point,
    points,
    prefilter,
    reference_filter,
    reference_model,
    scaling,
    scenarios,
    signal_spec,
    string,
    trim,
    vertex_weights,
    weights,
)
from lpvflow.pipeline.scenarios import ScenarioFile
from lpvflow.pipeline.scheduling_values import with_images
from lpvflow.pipeline.signal_check import check_signals
from lpvflow.synth.methods import SYNTHESIS_METHODS

# -------------------------------------------------------------------------------------------- schema
SCHEMA: dict[str, dict[str, Key]] = {
    "design": {
        "name": Key(REQUIRED, folder_name, "name of the design: its artifacts go to <output_dir>/<name>/"),
        "plant": Key(REQUIRED, string(), "plant FMU (FMI 2.0 Co-Simulation with a linux64 binary)"),
        "output_dir": Key("build/design", string(), "folder of the design folders"),
    },
    "experiment": {
        "Ts": Key(None, number(0.0, open_low=True),
                  "sampling time (communication step) in s, > 0; default: the controller's, else the FMU's"),
        "duration": Key(REQUIRED, number(0.0, open_low=True), "experiment length in s, > 0"),
        "controller": Key(None, string(), "stabilizing controller JSON (lpvflow/lti-controller, "
                          "lpvflow/gridded-controller or lpvflow/lpv-controller): closed-loop experiment"),
        "inputs": Key({}, mapping(signal_spec, '"SPEC"'),
                      "signal per plant input driven directly (open loop)"),
        "excitation": Key({}, mapping(signal_spec, '"SPEC"'),
                          "signal added to the controller output per input"),
        "setpoint": Key({}, mapping(signal_spec, '"SPEC"'),
                        "set-point per plant output read by the controller"),
        "parameters": Key({}, mapping(number(), "number"), "FMU parameters set before initialisation"),
        "scheduling": Key({}, mapping(string(), '"EXPR"'), "extra columns computed from plant signals"),
        "seed": Key(0, integer(0), "seed of the random excitation signals"),
        "quantization": Key({}, mapping(number(0.0, open_low=True), "step"),
                            "sensor quantization step per plant output, > 0 (e.g. 2π/4096 rad)"),
        "noise": Key({}, mapping(number(0.0), "std"),
                     "sensor white-noise standard deviation per plant output, ≥ 0"),
        "output_bounds": Key({}, mapping(interval, "[min, max]"),
                             "plant outputs the run must stay within: leaving them ends the experiment "
                             "as failed (a lost pendulum is not data)"),
        "iterate": Key(0, integer(0), "identification for control: after synth, rerun experiment → synth "
                       "this many times with the just-designed controller as experiment controller"),
        "iterate_setpoint": Key({}, mapping(signal_spec, '"SPEC"'),
                                "set-points of the iterate rounds 1…N (default: setpoint)"),
        "iterate_excitation": Key({}, mapping(signal_spec, '"SPEC"'),
                                  "excitation of the iterate rounds 1…N (default: excitation)"),
    },
    "identify": {
        "u": Key(REQUIRED, names(), "input columns"),
        "y": Key(REQUIRED, names(), "output columns"),
        "p": Key(REQUIRED, names(), "scheduling columns"),
        "na": Key(2, integer(1), "output lags"),
        "nb": Key(2, integer(1), "input lags"),
        "nk": Key(1, integer(0), "input delay in samples"),
        "basis": Key("affine", basis, "scheduling basis: affine, poly:D, poly:D:nocross, spline:K1,K2,…"),
        "split": Key(0.7, number(0.0, 1.0, open_low=True, open_high=True),
                     "fraction of the data used for estimation, in (0, 1); the rest validates"),
        "ridge": Key(0.0, number(0.0), "ridge regularization, ≥ 0"),
        "remove_offsets": Key(False, boolean, "work in deviations from the estimation data's means"),
        "method": Key("lpr-arx", method, "estimator: any method of `lpvflow identify` but static-arx"),
        "order": Key(None, integer(1), "state order of pbsid, cva, kcca-lfr (default: their own choice)"),
        "nc": Key(None, integer(1), "armax noise-polynomial order (default na)"),
        "past": Key(None, integer(1), "pbsid past window (default chosen from the order)"),
        "excitation": Key(None, string(), "external excitation column of two-step "
                          "(default <first input>_excitation)"),
        "prefilter": Key("none", prefilter, "filter on u and y before estimation: none, lowpass:F, "
                         "bandpass:F1,F2 (Hz)"),
        "remove_trim": Key(False, boolean, "identify from the inputs minus the [experiment] controller's "
                           "trim u_op(θ(k)) (the model's input is then u − u_op)"),
        "increments": Key([], names(empty=True), "outputs identified through their increments y(k) − y(k−1) "
                          "and integrated back in the model"),
        "rounds": Key("last", string(("last", "all")), "with [experiment] iterate: estimate from the "
                      "last round's record (last) or from the estimation parts of every round's (all)"),
        "refine": Key("none", string(("none", "closed-loop-oe")), "closed-loop-oe: refine the least-squares "
                      "model on its records simulated in their loops (the design's final model only)"),
        "refine_iterations": Key(5, integer(1), "trust-region steps of refine"),
        "refine_scales": Key({}, mapping(number(0.0, open_low=True), "positive number"),
                             "refine: per output, the scale s of its in-loop simulation error"),
    },
    "diagnose": {
        "adopt": Key(False, boolean, "let the diagnosed extension replace the identified model (extensions "
                     "that keep its inputs, outputs and signals)"),
        "candidates": Key([], names(empty=True), "extra data columns that may be missing scheduling "
                          "variables"),
    },
    "reduce": {
        "order": Key(None, integer(1), "model order after reduction (default: automatic)"),
    },
    "validate": {
        "grid": Key(7, integer(2), "frozen scheduling points checked"),
        "reference": Key("none", string(("none", "linearization", "local")), "frozen FMU reference"),
        "operating_point": Key({}, mapping(number(), "number"), "FMU start values for the linearization"),
        "hold": Key({}, mapping(number(), "number"), "FMU outputs held at these values in the reference's "
                    "equilibria (pins them when the plant has more inputs than scheduling signals)"),
        "scaling": Key("data", scaling, "signal scaling of the ν-gap: data, none or { signal = scale }"),
        "points": Key([], points, "frozen scheduling points checked instead of the grid"),
        "gate": Key(True, boolean, "stop the design after validate when the model fails the ν-gap test"),
    },
    "synth": {
        "method": Key("common", string(SYNTHESIS_METHODS.keys()),
                      "; ".join(f"{name}: {m.summary}" for name, m in SYNTHESIS_METHODS.items())),
        "rate_bound": Key(None, number(0.0, open_low=True),
                          "rate-bounded: largest |p(k+1) − p(k)| per sample (default: any rate)"),
        "crossover": Key(None, number(0.0, open_low=True),
                         "loop-shaping: crossover of the shaped loop, rad/s (default: π/(20·Ts))"),
        "integral_ratio": Key(10.0, number(0.0, open_low=True),
                              "loop-shaping: crossover / integral corner of the integral action (> 0)"),
        "level_factor": Key(1.01, number(1.0, open_low=True),
                            "loop-shaping: central controllers' level over hinfsyn's optimum γ_LMI (> 1)"),
        "integral_outputs": Key(None, names(), "loop-shaping: outputs whose error the controller integrates "
                                "(in W2; default: integral action at every plant input, in W1)"),
        "washout_outputs": Key(None, names(), "loop-shaping: outputs the loop stabilizes but does not hold "
                               "at a value: W2 = s/(s + crossover/washout_ratio) on them (a sensor offset on "
                               "them moves nothing in steady state)"),
        "washout_ratio": Key(20.0, number(0.0, open_low=True),
                             "loop-shaping: crossover / washout corner of washout_outputs (> 0)"),
        "output_weights": Key(None, mapping(number(0.0, open_low=True), "weight > 0"),
                              "loop-shaping: { output = weight }: a constant output weight W2 = diag(weight) "
                              "in the scaling signals (default 1); a heavier output is held more stiffly"),
        "scaling": Key(None, mapping(number(0.0, open_low=True), "scale > 0"),
                       "loop-shaping: { signal = scale } for every model input and output: the loop is "
                       "shaped in D_y⁻¹·G·D_u (default: none)"),
        "margin_goal": Key(None, margin_goal, "loop-shaping: { nugap_factor = f, at_least = b }: at every "
                           "breakpoint the lead is lowered until b(Ĝ, K_fb) ≥ max(f·ν-gap, b) of the "
                           "validate points it takes part in"),
        "scheduling": Key("frozen", string(("frozen", "common")),
                          "loop-shaping: frozen (a W1 and a design per breakpoint, checked at frozen points) "
                          "or common (one W1 and one Lyapunov matrix over all breakpoints: any rate)"),
        "reference_model": Key(None, reference_model, "loop-shaping (2dof): { control_weight = ρ }, u = u_m "
                               "+ K(y − y_m) with a model copy under an LQ gain as reference model"),
        "robustness_gate": Key(False, boolean, "stop the design after the robustness stage when the "
                               "controller's b(Ĝ, K_fb) is not above the ν-gap at a validate point"),
        "rate_certificate": Key(False, boolean, "robustness stage: the largest scheduling rate at which the "
                                "shipped loop's stability is certified, next to the verify runs' peak rate"),
        "breakpoints": Key(None, breakpoints, "piecewise polytope: ascending values (or rows) end to end"),
        "structure": Key("1dof", string(("1dof", "2dof")), "1dof: controller reads r − y; 2dof: [r; y]"),
        "weights": Key(REQUIRED, weights, "mixed-sensitivity weights S, K, [B, T, R, N], [integrator_shift]"),
        "vertex_weights": Key(None, vertex_weights, "scheduled weights: per vertex, replacing entries"),
        "box": Key(None, box, "scheduling box [[lo, hi], …] (default: the model's recorded range)"),
        "solver": Key("CLARABEL", string(("CLARABEL", "SCS"), upper=True), "SDP solver"),
        "baseline_at": Key(None, point, "scheduling point of the LTI baseline (default: box centre)"),
        "trim": Key(None, trim, "trim feed-forward u_eq(p): { p = [...], u = [[...], ...] }, interpolated"),
        "observer": Key({}, observer, "observer: Kalman noise { input, state, disturbance, noise }"),
        "reference_filter": Key(None, reference_filter, "observer, loop-shaping (2dof): { bandwidth = rad/s, "
                                "damping } on r"),
    },
    "verify": {
        "loop": Key(REQUIRED, loop, "how the controller is wired to the plant FMU ([verify.loop])"),
        "scenario": Key(REQUIRED, scenarios, "closed-loop runs ([[verify.scenario]])"),
        "largest_step": Key(None, largest_step, "{ scenario = NAME, criterion = bounded|passes }: the "
                            "largest step of that scenario each controller holds"),
    },
    "export": {
        "formats": Key(["fmu", "json", "mat"], formats, "controller files to write: fmu, json, mat"),
    },
}

#: Tables a design may leave out: without [diagnose] the identified model goes straight to reduction;
#: without [synth] the run ends after validation (identification only).
OPTIONAL = ("diagnose", "synth", "verify", "export")

BUNDLED = ("adip", "maglev", "airpath", "adip-fast")

#: Table -> keys holding input files, resolved and checked on load.
INPUT_FILES = (("design", "plant"), ("experiment", "controller"))


def repository_root() -> Path:
    """The folder holding ``lpvflow/`` and ``fmu_plants/`` (a source checkout)."""
    return Path(__file__).resolve().parents[2]


def bundled_config(name: str = BUNDLED[0]) -> Path:
    """Path of a bundled example configuration (``adip``, ``maglev``, ``airpath``, ``adip-fast``)."""
    if name not in BUNDLED:
        raise DataError(f"no bundled design {name!r}; bundled: {', '.join(BUNDLED)}")
    return Path(str(resources.files("lpvflow.pipeline") / "examples" / f"{name}.toml"))


def read_toml(path: str | Path) -> dict[str, Any]:
    """The TOML document at ``path``; a missing or unreadable file is a one-line DataError."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"design file {str(path)!r} does not exist; give the path of a .toml file")
    try:
        return tomllib.loads(path.read_text(encoding="utf-8-sig"))  # a byte-order mark (Notepad) dropped
    except UnicodeDecodeError:
        raise DataError(f"{path.name} is not UTF-8 text (TOML files are UTF-8); save it as UTF-8") from None
    except tomllib.TOMLDecodeError as exc:
        raise DataError(f"{path.name} is not valid TOML: {exc}") from None


class Table(Mapping[str, Any]):
    """Base of the typed tables: a frozen dataclass whose fields are the table's keys, read as attributes
    (``config["identify"].na``) or as a mapping (``config["identify"]["na"]``)."""

    def __getitem__(self, key: str) -> Any:
        if key not in self.__dataclass_fields__:
            raise KeyError(key)
        return getattr(self, key)

    def __iter__(self) -> Iterator[str]:
        return iter(self.__dataclass_fields__)

    def __len__(self) -> int:
        return len(self.__dataclass_fields__)


#: One frozen dataclass per table of :data:`SCHEMA` (``TABLES["identify"]`` has the fields u, y, p, na, …).
TABLES: dict[str, type[Table]] = {
    table: dataclasses.make_dataclass(f"{table.capitalize()}Table", list(keys), bases=(Table,), frozen=True,
                                      eq=True)
    for table, keys in SCHEMA.items()
}

#: A checked design file: table → its typed table (None: an optional table the file leaves out).
Config = dict[str, Table | None]


def check_table(table: str, given: Any, source: str) -> Table:
    """One table, typed (:data:`TABLES`), with its defaults filled in; unknown or missing keys and bad
    values raise DataError."""
    keys = SCHEMA[table]
    if not isinstance(given, dict):
        raise DataError(f"{source}: [{table}] must be a table")
    extra = sorted(set(given) - set(keys))
    if extra:
        raise DataError(f"{source}: [{table}] has unknown key(s) {extra}; known: {sorted(keys)}")
    missing = [k for k, key in keys.items() if key.default is REQUIRED and k not in given]
    if missing:
        raise DataError(f"{source}: [{table}] lacks {missing}")
    checked = {}
    for name, key in keys.items():
        if name in given:
            try:
                checked[name] = key.check(given[name], f"[{table}] {name}")
            except DataError as exc:
                raise DataError(f"{source}: {exc}") from None
        else:
            checked[name] = key.default
    return TABLES[table](**checked)


def load_tables(path: str | Path, need: tuple[str, ...], images: bool = True) -> Config:
    """Every table of a design file, checked; ``need`` lists the tables the caller requires.

    Tables absent from the file are None. Used by ``synth --config`` (need ``synth``) and
    ``verify --scenario`` (need ``verify``); :func:`load_config` is the whole design.
    """
    raw = read_toml(path)
    source = Path(path).name
    unknown = sorted(set(raw) - set(SCHEMA))
    if unknown:
        hint = ("; scenario files now use [verify.loop] and [[verify.scenario]]"
                if {"loop", "scenario"} & set(unknown) else "")
        hint += ("; synth settings now live in [synth] (box, weights)"
                 if {"polytope", "weights"} & set(unknown) else "")
        raise DataError(f"{source}: unknown table(s) {unknown}; known: {sorted(SCHEMA)}{hint}")
    missing = [t for t in need if t not in raw]
    if missing:
        raise DataError(f"{source} lacks the table(s) {['[' + t + ']' for t in missing]} "
                        "(layout: docs/design_file.md)")
    with_loop_scheduling(raw)
    config = {table: check_table(table, raw[table], source) if table in raw else None for table in SCHEMA}
    return scheduling_images(config, source) if images else config


def scheduling_images(config: Config, source: str) -> Config:
    """``config`` with scheduling points given as values of one plant signal replaced by their images
    (:mod:`lpvflow.pipeline.scheduling_values`)."""
    try:
        return with_images(config, dataclasses.replace)
    except DataError as exc:
        raise DataError(f"{source}: {exc}") from None


def with_loop_scheduling(raw: dict[str, Any]) -> None:
    """The scheduling map is declared once: a ``[verify.loop]`` without ``scheduling`` takes, per
    ``[identify] p`` column, its ``[experiment] scheduling`` expression (the column itself when it is a
    plant signal). A file that gives both has them compared (:mod:`lpvflow.pipeline.signal_check`)."""
    loop = raw.get("verify", {}).get("loop") if isinstance(raw.get("verify"), dict) else None
    identify, experiment = raw.get("identify"), raw.get("experiment")
    if not (isinstance(loop, dict) and "scheduling" not in loop and isinstance(identify, dict)):
        return
    p = identify.get("p")
    definitions = experiment.get("scheduling") if isinstance(experiment, dict) else None
    definitions = definitions if isinstance(definitions, dict) else {}
    if isinstance(p, list) and all(isinstance(name, str) for name in p):
        loop["scheduling"] = [definitions.get(name, name) for name in p]


def load_config(path: str | Path, root: Path | None = None) -> Config:
    """Read and check a whole design file; every table with its defaults filled in (None: optional,
    absent). Relative input files are resolved against ``root`` (default: the working directory)
    and must be usable: the plant a readable FMU with a linux64 binary, the controller an existing file.
    """
    source = Path(path).name
    config = load_tables(path, tuple(t for t in SCHEMA if t not in OPTIONAL), images=False)
    if config["synth"] is None and (config["verify"] or config["export"]):
        raise DataError(f"{source}: [verify] and [export] need a [synth] table (a controller to use)")
    for table, key in INPUT_FILES:
        value = config[table][key]
        if value is None:
            continue
        resolved = (root or Path.cwd()) / value
        if not resolved.is_file():
            where = "the repository root" if root else "the working directory"
            raise DataError(f"{source}: [{table}] {key} {value!r} does not exist (relative paths are "
                            f"relative to {where}; run `make fmus` to build the plants)")
        config[table] = dataclasses.replace(config[table], **{key: str(resolved)})
    try:
        description = check_fmu(config["design"]["plant"])
    except LpvflowError as exc:
        raise DataError(f"{source}: [design] plant: {exc}") from None
    try:
        check_signals(config, description)
    except DataError as exc:
        raise DataError(f"{source}: {exc}") from None
    return scheduling_images(config, source)


def load_scenarios(path: str | Path) -> ScenarioFile:
    """The ``[verify]`` table of a design file (:mod:`lpvflow.pipeline.scenarios`), as
    ``lpvflow verify --scenario`` reads it; every defect is a one-line DataError."""
    verify = load_tables(path, need=("verify",))["verify"]
    return ScenarioFile(verify["loop"], verify["scenario"])
