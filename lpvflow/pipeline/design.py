"""`lpvflow design`: experiment → identify → [diagnose] → reduce → validate → synth → robustness →
verify → [adoption] → export → report.

Each stage runs only when its cache key changed (:mod:`lpvflow.pipeline.cache`); artifacts live in
``<output_dir>/<name>/``, locked while a run writes it. A stage that fails with an lpvflow error, or a
controller that fails its certificate, ends the run there (no verify, no export): the report is still
written, with the error, and the run counts as a failed finding (exit status 1). Bad input (the design
file's tables, keys, types and ranges, missing or unusable plant or controller files, an unwritable
output folder) is refused before anything is written (exit 2). Ctrl-C removes the files the
interrupted stage had written so far (exit 130).
Without a [synth] table the run ends after validation; so does a run whose identified model fails
the ν-gap/b(P, K) gate of the validate stage ([validate] gate, :func:`lpvflow.pipeline.gate.gate_verdict`),
with the reason as the failure. The robustness stage (:mod:`lpvflow.pipeline.robustness`) reports
b(Ĝ, K_fb) of the synthesized controller against the ν-gap at the validate points; with [synth]
robustness_gate = true a controller whose b is not above the ν-gap at a point ends the run there
(:func:`lpvflow.pipeline.robustness.robustness_verdict`), else the verdict does not read it; it also
reports the model-in-the-loop against the plant-in-the-loop under that controller on the [verify]
scenarios (never part of the verdict). With
[diagnose] adopt = true and an adopted extension, the adoption stage designs and verifies the identified
model too and compares the two controllers in closed loop (:func:`lpvflow.pipeline.adoption.adoption`).
With [experiment] iterate = N the experiment → synth stages first run N rounds, each under the
controller the round before designed (identification for control, :func:`_run_stages`); when the final
pass's model or controller is rejected before verify, the design falls back to the model of the round
before (:func:`_run_final_pass`).
"""

from __future__ import annotations

import dataclasses
import functools
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from lpvflow.errors import DataError, LpvflowError
from lpvflow.experiment.plant import sha256_of
from lpvflow.models import atomic_write_json, report_header
from lpvflow.pipeline import cache, interrupt, stages
from lpvflow.pipeline.adoption import StageFunction, adoption
from lpvflow.pipeline.cli_paths import writable_folder
from lpvflow.pipeline.config import INPUT_FILES, Config, load_config
from lpvflow.pipeline.context import DATA_FILE, StageContext
from lpvflow.pipeline.coordinates import EARLIER_RECORDS
from lpvflow.pipeline.gate import JUDGED_BY_ROBUSTNESS
from lpvflow.pipeline.refine import check_refine
from lpvflow.pipeline.robustness import robustness
from lpvflow.pipeline.settings import ALL, Reads, StageSettings, union


@dataclass(frozen=True)
class Stage:
    """A design stage: ``run`` gets a :class:`~lpvflow.pipeline.context.StageContext` holding exactly the
    keys of ``reads`` (table → keys, :data:`~lpvflow.pipeline.settings.ALL` for a whole table) and its cache
    key hashes those values; it runs only when every table of ``requires`` is in the design file."""

    name: str
    run: StageFunction
    requires: tuple[str, ...]  # tables that must be present for the stage to run
    reads: Reads  # the design-file keys it reads
    upstream: tuple[str, ...]  # stages whose artifacts it reads
    file_keys: tuple[tuple[str, str], ...] = ()  # (table, key) of files whose bytes it reads


#: The [identify] keys that say which columns are the model's signals and which part estimates.
_SIGNALS = ("u", "y", "p", "split", "remove_offsets", "remove_trim")

_PLANT = (("design", "plant"),)
_CONTROLLER = (("experiment", "controller"),)
EXPERIMENT = Stage(
    "experiment", stages.experiment, ("design", "experiment"),
    {"design": ("plant",), "experiment": ("Ts", "duration", "controller", "inputs", "excitation", "setpoint",
                                          "parameters", "scheduling", "seed", "quantization", "noise",
                                          "output_bounds")},
    (), _PLANT + _CONTROLLER)
IDENTIFY = Stage("identify", stages.identify, ("identify",),
                 {"identify": ALL, "experiment": ("controller", "scheduling"), "design": ("plant",)},
                 ("experiment",), _PLANT + _CONTROLLER)
DIAGNOSE = Stage("diagnose", stages.diagnose, ("diagnose", "identify"),
                 {"diagnose": ALL, "identify": (*_SIGNALS, "increments", "method"),
                  "experiment": ("controller", "scheduling")}, ("identify",), _CONTROLLER)
REDUCE = Stage("reduce", stages.reduce_model, ("reduce",), {"reduce": ALL}, ("identify", "diagnose"))
VALIDATE = Stage("validate", stages.validate, ("validate", "identify", "experiment"),
                 {"validate": ALL, "identify": (*_SIGNALS, "increments"),
                  "experiment": ("controller", "scheduling", "parameters"), "design": ("plant",)},
                 ("reduce",), _PLANT + _CONTROLLER)
SYNTH = Stage("synth", stages.synth, ("synth",),
              {"synth": ALL, "verify": ("loop",), "experiment": ("scheduling",), "design": ("plant",)},
              ("reduce", "validate"), _PLANT)
ROBUSTNESS = Stage("robustness", robustness, ("synth", *VALIDATE.requires),
                   {"validate": ("scaling",), "synth": ("robustness_gate", "rate_certificate", "breakpoints"),
                    "identify": (*_SIGNALS, "increments"), "experiment": ("controller", "scheduling"),
                    "verify": ("loop", "scenario"), "design": ("plant",)},
                   ("reduce", "validate", "synth"), _PLANT + _CONTROLLER)
VERIFY = Stage("verify", stages.verify, ("design", "verify"), {"design": ("plant",), "verify": ALL},
               ("synth",), _PLANT)
ADOPTION = Stage("adoption",
                 functools.partial(adoption, reduce_stage=stages.reduce_model, synth_stage=stages.synth),
                 ("design", "diagnose", "reduce", "synth", "verify"),
                 union({"verify": ("loop", "scenario"), "design": ("plant",)}, REDUCE.reads, SYNTH.reads),
                 ("identify", "diagnose", "synth"), _PLANT)
EXPORT = Stage("export", stages.export, ("export",), {"export": ALL}, ("synth",))

STAGES = (EXPERIMENT, IDENTIFY, DIAGNOSE, REDUCE, VALIDATE, SYNTH, ROBUSTNESS, VERIFY, ADOPTION, EXPORT)


def run_design(config_path: str | Path, log: Callable[[str], None] = print, root: Path | None = None) -> dict:
    """Run (or reuse) every stage, write ``summary.json`` and ``report.html``; return the summary.

    The design file is checked completely before anything is written; relative input paths are
    resolved against ``root`` (default: the working directory). The design folder is locked for the
    run (:func:`lpvflow.pipeline.cache.folder_lock`).
    """
    config = load_config(config_path, root)
    folder = Path(config["design"]["output_dir"]) / config["design"]["name"]
    inputs = [Path(config_path), *(Path(config[t][k]) for t, k in INPUT_FILES if config[t][k])]
    inside = [str(p) for p in inputs if p.resolve().is_relative_to(folder.resolve())]
    if inside:
        raise DataError(f"{inside[0]} is inside the design folder {folder}, which the run rewrites; "
                        "move it or change [design] output_dir or name")
    check_iterate(config)
    check_refine(config)
    writable_folder(folder, "the design folder ([design] output_dir / name)")
    with cache.folder_lock(folder):
        return _run_stages(config, str(config_path), folder, log)


def check_iterate(config: Config) -> None:
    """One DataError line when ``[experiment] iterate`` cannot run: the rounds need a ``[synth]`` table (the
    controller each round designs), and that controller drives the model inputs, so their signals must be
    ``[experiment] excitation``, not open-loop ``inputs``; ``[identify] rounds = "all"`` estimates from
    several records (the methods with ``several_records`` in
    :data:`~lpvflow.identify.methods.IDENTIFICATION_METHODS`) without offsets (one operating
    point per record would be several models). The keys of the rounds need ``iterate``."""
    from lpvflow.identify.methods import method_names

    experiment, identify = config["experiment"], config["identify"]
    rounds = experiment["iterate"]
    if not rounds:
        given = [f"[experiment] {key}" for key in ("iterate_setpoint", "iterate_excitation")
                 if experiment[key]]
        given += ['[identify] rounds = "all"'] if identify["rounds"] == "all" else []
        if given:
            raise DataError(f"{given[0]} applies to the rounds of [experiment] iterate, which is 0; set "
                            "iterate or remove it")
        return
    if identify["rounds"] == "all" and identify["method"] not in method_names(several_records=True):
        raise DataError(f'[identify] rounds = "all" estimates from several records, which method '
                        f'{identify["method"]!r} does not; use "lpr-arx"')
    if identify["rounds"] == "all" and identify["remove_offsets"]:
        raise DataError('[identify] rounds = "all" with remove_offsets: each record has its own means; '
                        "remove one of them")
    if config["synth"] is None:
        raise DataError(f"[experiment] iterate = {rounds} needs a [synth] table: each round runs the "
                        "experiment under the controller the round before designed")
    driven = sorted(set(config["experiment"]["inputs"]) & set(config["identify"]["u"]))
    if driven:
        raise DataError(f"[experiment] iterate = {rounds}: the designed controller drives "
                        f"{', '.join(driven)}; give its signal as [experiment] excitation, not inputs")


#: The stages an ``[experiment] iterate`` round repeats (identification for control).
ROUND_STAGES = ("experiment", "identify", "diagnose", "reduce", "validate", "synth")


def _run_stages(config: Config, config_path: str, folder: Path, log: Callable[[str], None]) -> dict:
    """The stages of :func:`run_design` in the locked ``folder``.

    With ``[experiment] iterate = N`` (identification for control) N rounds of the stages
    :data:`ROUND_STAGES` run first, round i in ``iteration_<i>/`` with round i − 1's ``controller.json``
    (the configured controller for round 0) as the experiment controller, same set-points, excitation and
    duration; then every stage runs in ``folder`` with the controller of round N − 1, so the summary's
    stages are the last round's as without iterations. A round that fails (a stage error, the ν-gap gate,
    the certificate) ends the run: its stages become the summary's. A final pass that fails before verify
    falls back to the round before (:func:`_run_final_pass`). ``summary["iterations"]`` lists each
    round's key numbers (:func:`_round_numbers`), the last entry the final design in ``folder``."""
    from lpvflow.pipeline.report import write_report

    summary: dict = report_header("design") | {"name": config["design"]["name"], "config": config_path,
                                               "stages": {}}
    controller, failed, rounds = config["experiment"]["controller"], None, []
    earlier: list[dict] = []
    round_stages = tuple(stage for stage in STAGES if stage.name in ROUND_STAGES)
    for n in range(config["experiment"]["iterate"]):
        sub = folder / f"iteration_{n}"
        sub.mkdir(exist_ok=True)
        outcome: dict = {}
        round_config = _without_refine(_without_margin_goal(_round_config(config, controller, n, earlier)))
        failed = _run_pass(round_stages, round_config,
                           sub, outcome, lambda line, n=n: log(f"iteration {n}: {line}"))
        rounds.append(_round_numbers(n, sub.name, controller, outcome))
        if failed:
            failed["stage"] = f"{failed['stage']} (iteration {n})"
            summary["stages"] = {name: _in_subfolder(record, sub.name) for name, record in outcome.items()}
            break
        earlier.append(earlier_record(sub, controller))
        controller = str(sub / "controller.json")
    if failed is None:
        failed = _run_final_pass(config, controller, earlier, folder, summary, rounds, log)
    if rounds:
        summary["iterations"] = rounds
    summary["failed"] = failed
    summary["verdict"] = _verdict(summary)
    for r in rounds:  # the verdict line says that identification for control fell back (_run_final_pass)
        if r.get("rejected"):
            summary["verdict"]["reason"] += (f"; iteration {r['iteration']} was rejected at "
                                             f"{r['rejected_stage']}, the design uses iteration "
                                             f"{r['iteration'] - 1}'s record")
    summary["stage_seconds"] = {n: s.get("seconds") for n, s in summary["stages"].items()}
    before = _file_states(folder)
    try:  # the summary and the report are undone together on Ctrl-C, like a stage's files
        atomic_write_json(folder / "summary.json", summary)
        write_report(folder, summary)
        interrupt.raise_if_requested()
    except BaseException as exc:
        if not isinstance(exc, KeyboardInterrupt) and not interrupt.requested():
            raise
        _remove_changed(folder, before)
        log("summary and report interrupted: their files were removed")
        raise KeyboardInterrupt from None
    log(f"report: {folder / 'report.html'}")
    return summary


#: The file in ``iteration_<N>/`` that marks a rejected final pass (its failure, :func:`_run_final_pass`).
REJECTED_MARK = "rejected.json"
#: The stages whose failure rejects the model of the final pass or the controller designed from it (every
#: stage before verify): after identification-for-control rounds the design then falls back to the model
#: of the round before (:func:`_run_final_pass`).
ACCEPTANCE_STAGES = ("experiment", "identify", "diagnose", "reduce", "validate", "synth", "robustness")


def _run_final_pass(config: Config, controller: str | None, earlier: list[dict], folder: Path, summary: dict,
                    rounds: list[dict], log: Callable[[str], None]) -> dict | None:
    """The final pass of :func:`_run_stages` in ``folder`` under the last round's ``controller``; returns its
    failure or None and appends its entry to ``rounds`` (after identification-for-control rounds).

    Identification for control must not leave the design worse than the round before it: when the final
    pass under round N − 1's controller fails in one of :data:`ACCEPTANCE_STAGES` — its experiment loses the
    plant, its model fails the validate gate, its synthesis fails, or its controller's b(Ĝ, K_fb) fails the
    robustness gate — that pass's stage files move to ``iteration_<N>/`` with :data:`REJECTED_MARK` (its
    ``rounds`` entry carries ``"rejected"``, the failure) and the final pass runs again as with N − 1
    rounds: under round N − 2's experiment controller, whose record round N − 1 identified and validated
    (the configured controller when N = 1), with the final settings. One step back, not more; a failure of
    that pass ends the run. A rerun judges the rejected pass again in ``iteration_<N>/``, where its stage
    records are (reused while their keys hold); if it passes now, its files move back and the design goes
    on from it. On held-out identification seeds of the bundled ADIP the last round made a passing model
    fail (seeds 11, 12: unstable frozen pole, ν-gap 0.18 against round 0's 0.066) or lost the pendulum
    (seeds 8, 14) (benchmarks/README.md, "Falling back to the round before")."""
    def final_config(controller: str | None, earlier: list[dict]) -> Config:
        final = _round_config(config, controller, len(earlier), earlier)
        return _judged_by_robustness(final) if earlier else final

    final, n = final_config(controller, earlier), len(earlier)
    if not earlier:
        return _run_pass(STAGES, final, folder, summary["stages"], log)
    rejected, outcome, failed = folder / f"iteration_{n}", {}, None
    if (rejected / REJECTED_MARK).is_file():
        failed = _run_pass(tuple(s for s in STAGES if s.name in ACCEPTANCE_STAGES), final, rejected, outcome,
                           lambda line: log(f"iteration {n} (rejected by an earlier run): {line}"))
        if failed is None:  # accepted now: its records go back to the design folder, which goes on from them
            _move_stage_files(outcome, rejected, folder)
            (rejected / REJECTED_MARK).unlink()
            outcome = {}
    if failed is None:
        failed = _run_pass(STAGES, final, folder, outcome, log)
        if failed and failed["stage"] in ACCEPTANCE_STAGES:
            _move_stage_files(outcome, folder, rejected)
    if not failed or failed["stage"] not in ACCEPTANCE_STAGES:
        summary["stages"] = outcome
        rounds.append(_round_numbers(n, ".", controller, outcome))
        return failed
    atomic_write_json(rejected / REJECTED_MARK, failed)
    moved = any("artifacts" in record for record in outcome.values())
    reason = f"stage {failed['stage']} failed: {failed['error']}"
    rounds.append(_round_numbers(n, f"iteration_{n}" if moved else None, controller, outcome)
                  | {"rejected": reason, "rejected_stage": failed["stage"]})
    log(f"iteration {n} rejected ({reason}); " + (f"its files are in iteration_{n}/; " if moved else "")
        + f"the final pass runs again on the record of iteration {n - 1}'s experiment")
    controller = earlier[-1]["controller"]
    failed = _run_pass(STAGES, final_config(controller, earlier[:-1]), folder, summary["stages"], log)
    rounds.append(_round_numbers(n - 1, ".", controller, summary["stages"]) | {"fallback": True})
    return failed


def _move_stage_files(outcome: dict, folder: Path, destination: Path) -> None:
    """Move the stage records (``<stage>.json``) and artifacts of the pass ``outcome`` from ``folder`` to
    ``destination`` (created; files of an earlier run there are replaced)."""
    destination.mkdir(exist_ok=True)
    for name, record in outcome.items():
        if "artifacts" not in record:  # a stage that failed or did not run left no record
            continue
        for relative in (f"{name}.json", *record["artifacts"]):
            target = destination / relative
            target.parent.mkdir(parents=True, exist_ok=True)
            (folder / relative).replace(target)


def _in_subfolder(record: dict, sub: str) -> dict:
    """A stage record of a round with its artifacts named relative to the design folder."""
    if "artifacts" not in record:
        return record
    return record | {"artifacts": [f"{sub}/{artifact}" for artifact in record["artifacts"]]}


def _round_config(config: Config, controller: str | None, n: int, earlier: list[dict]) -> Config:
    """``config`` as round ``n`` sees it: ``controller`` as the ``[experiment] controller``, from round 1 on
    the ``iterate_setpoint`` / ``iterate_excitation`` (when given) as its set-points and excitation, and
    ``iterate`` set to 0 in the stages' view, so a round's cache keys do not depend on how many rounds
    follow it; with ``[identify] rounds = "all"`` the earlier rounds' records (:func:`earlier_record`) as
    ``[identify]`` :data:`~lpvflow.pipeline.coordinates.EARLIER_RECORDS`."""
    experiment = {**config["experiment"], "controller": controller, "iterate": 0}
    if n > 0:
        experiment |= {key: experiment[f"iterate_{key}"] or experiment[key]
                       for key in ("setpoint", "excitation")}
    identify = config["identify"]
    if identify["rounds"] == "all":
        identify = {**identify, EARLIER_RECORDS: list(earlier)}
    return {**config, "experiment": experiment, "identify": identify}


def _judged_by_robustness(config: Config) -> Config:
    """The final pass's ``config`` after identification-for-control rounds: with ``[synth] robustness_gate =
    true``, ``[validate]`` :data:`~lpvflow.pipeline.gate.JUDGED_BY_ROBUSTNESS` — the model is judged by
    b(Ĝ, K_fb) of the controller the design ships, not by b(Ĝ, K_id) of the last round's
    (:func:`~lpvflow.pipeline.gate.gate_verdict`). Measured on held-out identification seeds 2 and 7 of the
    bundled ADIP: their final models miss the K_id test at +75° by 1.4 % and 0.8 %, while the shipped
    controller's b exceeds 1.5 × their ν-gap at every gate point and all 8 steps settle (benchmarks/README.md,
    "The final gate of an identification-for-control design")."""
    synth = config["synth"]
    if synth is None or not synth["robustness_gate"]:
        return config
    return {**config, "validate": {**config["validate"], JUDGED_BY_ROBUSTNESS: True}}


def _without_refine(config: Config) -> Config:
    """An identification-for-control round's ``config``: ``[identify] refine`` off. The refinement is for the
    model the design ships (the final one, :mod:`lpvflow.pipeline.refine`); a round's model only designs the
    controller of the next experiment, as in the probe it was measured with (benchmarks/README.md)."""
    return {**config, "identify": {**config["identify"], "refine": "none"}}


def _without_margin_goal(config: Config) -> Config:
    """An identification-for-control round's ``config``: ``[synth] margin_goal`` off. The goal is on the
    controller the design ships; a round's controller only runs the next experiment, judged by the
    identification gate b(Ĝ, K_id) > ν-gap (with the goal in round 0, bundled ADIP seed 5: the lead lowered
    at −75°, and the model of the next round failed that gate at all nine points, ν-gap 1)."""
    synth = config["synth"]
    if synth is None or synth["margin_goal"] is None:
        return config
    return {**config, "synth": dataclasses.replace(synth, margin_goal=None)}


def earlier_record(sub: Path, controller: str | None) -> dict:
    """A finished round's record for the rounds after it: its ``data.csv`` (path and SHA-256, so a stage
    reading it reruns when it changes) and the experiment controller it was recorded under (whose trim
    ``[identify] remove_trim`` takes out of it)."""
    data = sub / DATA_FILE
    return {"data": str(data), "sha256": sha256_of(data), "controller": controller,
            "controller_sha256": sha256_of(controller) if controller else None}


def _round_numbers(n: int, folder: str, controller: str | None, outcome: dict) -> dict:
    """Key numbers of one identification-for-control round from its stages' records: the experiment
    controller, the model order, validation (fit BFR per output, largest ν-gap, smallest b(P, K_id), the
    gate), synthesis (γ, the baseline's γ) and the stage times."""
    def outputs(name: str) -> dict:
        return outcome.get(name, {}).get("outputs") or {}

    validate = outputs("validate")
    return {"iteration": n, "folder": folder, "experiment_controller": controller,
            "scheduling_range": outputs("identify").get("scheduling_range"),
            "order": outputs("reduce").get("order"),
            "fit_bfr": (validate.get("fit") or {}).get("bfr"),
            "max_nugap": max(validate["nugap"]) if validate.get("nugap") else None,
            "min_b_P_Kid": min(validate["b_P_Kid"]) if validate.get("b_P_Kid") else None,
            "gate": validate.get("gate"),
            "gamma": outputs("synth").get("gamma"), "baseline_gamma": outputs("synth").get("baseline_gamma"),
            "stage_seconds": {name: record.get("seconds") for name, record in outcome.items()}}


def _run_pass(
    pass_stages: tuple[Stage, ...], config: Config, folder: Path, outcome: dict, log: Callable[[str], None]
) -> dict | None:
    """Run (or reuse) ``pass_stages`` in ``folder`` with ``config``, recording each stage's status, outputs
    and artifacts in ``outcome``; returns the failure ``{"stage", "error"}`` that ended the pass, or None."""
    ctx = StageContext(folder, config)  # data.csv is read once per pass (StageContext.columns)
    keys: dict[str, str] = {}
    artifacts_of: dict[str, list[str]] = {}
    code = cache.code_digest()  # any change to lpvflow's code reruns every stage
    count = len(pass_stages)
    for i, stage in enumerate(pass_stages, 1):
        missing = [t for t in stage.requires if config[t] is None]
        if missing:
            outcome[stage.name] = {"status": "not configured"}
            log(f"[{i}/{count}] {stage.name}: skipped (no {', '.join(f'[{t}]' for t in missing)} table)")
            continue
        settings = StageSettings(config, stage.reads)
        ctx.config = settings
        files = [config[t][k] for t, k in stage.file_keys if config[t] and config[t][k]]
        files += [folder / a for u in stage.upstream for a in artifacts_of.get(u, [])]
        upstream = [keys.get(u, "not configured") for u in stage.upstream]
        key = cache.stage_key({"code": code, **settings.payload()}, upstream, files)
        keys[stage.name] = key
        record = cache.load_record(folder, stage.name, key)
        if record is not None:
            log(f"[{i}/{count}] {stage.name}: unchanged, reused ({record['seconds']:.1f} s when run)")
            status = "cached"
        else:
            log(f"[{i}/{count}] {stage.name} …")
            t0 = time.perf_counter()
            before = _file_states(folder)
            try:
                try:
                    outputs, artifacts = stage.run(ctx)
                except LpvflowError as exc:
                    outcome[stage.name] = {"status": "failed", "error": str(exc)}
                    log(f"[{i}/{count}] {stage.name} failed: {exc}")
                    return {"stage": stage.name, "error": str(exc)}
                interrupt.raise_if_requested()  # a Ctrl-C something inside the stage swallowed
                record = cache.save_record(folder, stage.name, key, outputs, artifacts,
                                           time.perf_counter() - t0)
            except BaseException as exc:
                if not isinstance(exc, KeyboardInterrupt) and not interrupt.requested():
                    raise
                _remove_changed(folder, before)
                log(f"[{i}/{count}] {stage.name} interrupted: its unfinished files were removed")
                raise KeyboardInterrupt from None
            log(f"[{i}/{count}] {stage.name}: done in {record['seconds']:.1f} s")
            status = "ran"
        ctx.outputs[stage.name] = record["outputs"]
        artifacts_of[stage.name] = record["artifacts"]
        outcome[stage.name] = {"status": status, "seconds": record["seconds"],
                               "outputs": record["outputs"], "artifacts": record["artifacts"]}
        gate = record["outputs"].get("gate") if stage.name in ("validate", "robustness") else None
        if gate and gate.get("passed") is False:
            log(f"[{i}/{count}] {stage.name}: {gate['reason']}")
            return {"stage": stage.name, "error": gate["reason"]}
        if record["outputs"].get("certificate_ok") is False:
            error = ("the controller failed its certificate (see the synth checks); verify and export "
                     "were not run")
            log(f"[{i}/{count}] {stage.name}: {error}")
            return {"stage": stage.name, "error": error}
    return None


def _file_states(folder: Path) -> dict[Path, tuple[int, int]]:
    """(mtime, size) of every file under ``folder`` but the lock."""
    return {p: (st.st_mtime_ns, st.st_size) for p in folder.rglob("*")
            if p.is_file() and p.name != cache.LOCK_NAME and (st := p.stat())}


def _remove_changed(folder: Path, before: dict[Path, tuple[int, int]]) -> None:
    """Delete the files created or rewritten since ``before`` (an interrupted stage's partial output)."""
    for path, state in _file_states(folder).items():
        if before.get(path) != state:
            path.unlink(missing_ok=True)


#: Failed scenarios a verdict names; the rest are counted (every one is in the report's tables).
LISTED_FAILURES = 3


def _verdict(summary: dict) -> dict:
    """Pass when no stage failed and the LPV controller met every verification scenario; else the first
    LISTED_FAILURES failed scenarios, why, and where the first of them to leave the design box did."""
    if summary["failed"]:
        return {"pass": False, "reason": f"stage {summary['failed']['stage']} failed"}
    scenarios = summary["stages"].get("verify", {}).get("outputs", {}).get("scenarios", [])
    failing = [(r, r["controller"]["reason"]) for r in scenarios if not r["controller"]["stable"]]
    failing += [(r, f"misses {', '.join(missed)}") for r in scenarios
                if r["controller"]["stable"] and (missed := r["controller"].get("requirements_failed"))]
    if failing:
        from lpvflow.pipeline.verify import box_text, coverage_note

        data = summary["stages"].get("identify", {}).get("outputs", {}).get("scheduling_range")
        data_note = f" (identification data {box_text(zip(*data, strict=True))})" if data else ""
        reasons, noted = [], False
        for r, reason in failing[:LISTED_FAILURES]:
            note = "" if noted else coverage_note(r["controller"])  # the first run that left the box says so
            noted = noted or bool(note)
            reasons.append(f"{r['name']}: {reason}" + (f"; {note}{data_note}" if note else ""))
        if len(failing) > LISTED_FAILURES:
            reasons.append(f"and {len(failing) - LISTED_FAILURES} more (the report's scenario tables)")
        return {"pass": False, "reason": "; ".join(reasons)}
    return {"pass": True, "reason": "every configured stage ran and every scenario passed"}


def verdict_line(summary: dict) -> str:
    """The one line ``lpvflow design`` ends with: passed or not, the scenarios each controller passes and
    the verdict's reason, e.g. "design did not pass: LPV controller passes 2 of 4 scenarios, LTI
    baseline 4 of 4; arm to +75 deg: …"."""
    from lpvflow.pipeline.report_card import scenario_tally

    verdict = summary["verdict"]
    head = "design passed" if verdict["pass"] else "design did not pass"
    return f"{head}: " + "; ".join(part for part in (scenario_tally(summary), verdict["reason"]) if part)


def main_design(config_path: str | Path, root: Path | None = None) -> int:
    """``lpvflow design``: progress and, last, the verdict line (:func:`verdict_line`) on stderr; 0 when
    the design passes, 1 when it does not (bad input raises: exit 2, and Ctrl-C exits 130, in
    :mod:`lpvflow.pipeline.cli`; a Ctrl-C is never lost and never follows the verdict,
    :mod:`lpvflow.pipeline.interrupt`)."""
    with interrupt.recorded():
        summary = run_design(config_path, log=lambda line: print(line, file=sys.stderr, flush=True),
                             root=root)
        interrupt.settled()  # Ctrl-C from here on is ignored: the verdict printed is the exit status
        print(verdict_line(summary), file=sys.stderr, flush=True)
    return 0 if summary["verdict"]["pass"] else 1
