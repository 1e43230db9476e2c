"""`lpvflow design`: experiment → identify → [diagnose] → reduce → validate → synth → verify →
[adoption] → export → report.

Each stage runs only when its cache key changed (:mod:`lpvflow.pipeline.cache`); artifacts live in
``<output_dir>/<name>/``, locked while a run writes it. A stage that fails with an lpvflow error, or a
controller that fails its certificate, ends the run there (no verify, no export): the report is still
written, with the error, and the run counts as a failed finding (exit status 1). Bad input (the design
file's tables, keys, types and ranges, missing or unusable plant or controller files, an unwritable
output folder) is refused before anything is written (exit 2). Ctrl-C removes the files the
interrupted stage had written so far (exit 130).
Without a [synth] table the run ends after validation; so does a run whose identified model fails
the ν-gap/b(P, K) gate of the validate stage ([validate] gate, :func:`lpvflow.pipeline.stages.gate_verdict`),
with the reason as the failure. With [diagnose] adopt = true and an adopted
extension, the adoption stage designs and verifies the identified model too and compares the two
controllers in closed loop (:func:`lpvflow.pipeline.stages.adoption`).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from lpvflow.errors import DataError, LpvflowError
from lpvflow.models import atomic_write_json, report_header
from lpvflow.pipeline import cache, stages
from lpvflow.pipeline.cli_paths import writable_folder
from lpvflow.pipeline.config import INPUT_FILES, Config, load_config


@dataclass(frozen=True)
class Stage:
    name: str
    run: object  # Callable[[StageContext], tuple[dict, list[str]]]
    tables: tuple[str, ...]  # config tables the stage reads
    upstream: tuple[str, ...]  # stages whose artifacts it reads
    file_keys: tuple[tuple[str, str], ...] = ()  # (table, key) of files whose bytes it reads


STAGES = (
    Stage("experiment", stages.experiment, ("design", "experiment"), (),
          (("design", "plant"), ("experiment", "controller"))),
    Stage("identify", stages.identify, ("identify",), ("experiment",)),
    Stage("diagnose", stages.diagnose, ("diagnose", "identify"), ("identify",)),
    Stage("reduce", stages.reduce_model, ("reduce",), ("identify", "diagnose")),
    Stage("validate", stages.validate, ("validate", "identify", "experiment"), ("reduce",),
          (("experiment", "controller"),)),
    Stage("synth", stages.synth, ("synth",), ("reduce",)),
    Stage("verify", stages.verify, ("design", "verify"), ("synth",), (("design", "plant"),)),
    Stage("adoption", stages.adoption, ("design", "diagnose", "reduce", "synth", "verify"),
          ("identify", "diagnose", "synth"), (("design", "plant"),)),
    Stage("export", stages.export, ("export",), ("synth",)),
)


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
    writable_folder(folder, "the design folder ([design] output_dir / name)")
    with cache.folder_lock(folder):
        return _run_stages(config, str(config_path), folder, log)


def _run_stages(config: Config, config_path: str, folder: Path, log: Callable[[str], None]) -> dict:
    """The stages of :func:`run_design` in the locked ``folder``."""
    from lpvflow.pipeline.report import write_report

    ctx = stages.StageContext(folder, config)
    keys: dict[str, str] = {}
    artifacts_of: dict[str, list[str]] = {}
    code = cache.code_digest()  # any change to lpvflow's code reruns every stage
    summary: dict = report_header("design") | {"name": config["design"]["name"], "config": config_path,
                                               "stages": {}}
    failed = None
    for i, stage in enumerate(STAGES, 1):
        if any(config[t] is None for t in stage.tables):
            summary["stages"][stage.name] = {"status": "not configured"}
            continue
        files = [config[t][k] for t, k in stage.file_keys if config[t][k]]
        files += [folder / a for u in stage.upstream for a in artifacts_of.get(u, [])]
        upstream = [keys.get(u, "not configured") for u in stage.upstream]
        key = cache.stage_key({"code": code, **{t: config[t] for t in stage.tables}}, upstream, files)
        keys[stage.name] = key
        record = cache.load_record(folder, stage.name, key)
        if record is not None:
            log(f"[{i}/{len(STAGES)}] {stage.name}: unchanged, reused ({record['seconds']:.1f} s when run)")
            status = "cached"
        else:
            log(f"[{i}/{len(STAGES)}] {stage.name} …")
            t0 = time.perf_counter()
            before = _file_states(folder)
            try:
                outputs, artifacts = stage.run(ctx)
            except LpvflowError as exc:
                failed = {"stage": stage.name, "error": str(exc)}
                summary["stages"][stage.name] = {"status": "failed", "error": str(exc)}
                log(f"[{i}/{len(STAGES)}] {stage.name} failed: {exc}")
                break
            except KeyboardInterrupt:
                _remove_changed(folder, before)
                log(f"[{i}/{len(STAGES)}] {stage.name} interrupted: its unfinished files were removed")
                raise
            record = cache.save_record(folder, stage.name, key, outputs, artifacts, time.perf_counter() - t0)
            log(f"[{i}/{len(STAGES)}] {stage.name}: done in {record['seconds']:.1f} s")
            status = "ran"
        ctx.outputs[stage.name] = record["outputs"]
        artifacts_of[stage.name] = record["artifacts"]
        summary["stages"][stage.name] = {"status": status, "seconds": record["seconds"],
                                         "outputs": record["outputs"], "artifacts": record["artifacts"]}
        gate = record["outputs"].get("gate") if stage.name == "validate" else None
        if gate and gate.get("passed") is False:
            failed = {"stage": stage.name, "error": gate["reason"]}
            log(f"[{i}/{len(STAGES)}] {stage.name}: {gate['reason']}")
            break
        if record["outputs"].get("certificate_ok") is False:
            failed = {"stage": stage.name, "error": "the controller failed its certificate (see the synth "
                                                    "checks); verify and export were not run"}
            log(f"[{i}/{len(STAGES)}] {stage.name}: {failed['error']}")
            break
    summary["failed"] = failed
    summary["verdict"] = _verdict(summary)
    summary["stage_seconds"] = {n: s.get("seconds") for n, s in summary["stages"].items()}
    atomic_write_json(folder / "summary.json", summary)
    write_report(folder, summary)
    log(f"report: {folder / 'report.html'}")
    return summary


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
    from lpvflow.pipeline.report import scenario_tally

    verdict = summary["verdict"]
    head = "design passed" if verdict["pass"] else "design did not pass"
    return f"{head}: " + "; ".join(part for part in (scenario_tally(summary), verdict["reason"]) if part)


def main_design(config_path: str | Path, root: Path | None = None) -> int:
    """``lpvflow design``: progress and, last, the verdict line (:func:`verdict_line`) on stderr; 0 when
    the design passes, 1 when it does not (bad input raises: exit 2, and Ctrl-C exits 130, in
    :mod:`lpvflow.pipeline.cli`)."""
    summary = run_design(config_path, log=lambda line: print(line, file=sys.stderr, flush=True), root=root)
    print(verdict_line(summary), file=sys.stderr, flush=True)
    return 0 if summary["verdict"]["pass"] else 1
