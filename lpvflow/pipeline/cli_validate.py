"""`lpvflow validate`: fit on data, frozen ν-gap table, b(P, K) and δν < b, margins, stability certificate.

    lpvflow validate MODEL.json DATA --u .. --y .. --p .. [--reference MODEL.json|PLANT.fmu
                     --fmu-scheduling EXPR ..] [--controller CTRL.json] [--grid N] --json OUT.json
                     [--figures DIR]

Controller conventions (validate uses u = −K y, lpvflow/validate/margins.py): an lpvflow/lpv-controller
acts on e = r − y (lpvflow/synth/controller.py), so with r = 0 its frozen K(θ) is used as is; an
lpvflow/lti-controller acts as u = u_op + K (y − y_op) (lpvflow/experiment/controller.py), so −K is
used (operating points do not enter the small-signal loop). A static-form LPV-ARX is validated
through its shifted-form realization: at constant θ both forms are the same LTI model.

Exit status 0 when every check passes, 1 when the controller does not stabilize the model at some
grid point or δν < b fails somewhere, 2 on bad input.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path

import numpy as np

from lpvflow.data import Dataset
from lpvflow.errors import DataError, ModelError
from lpvflow.experiment.controller import FORMAT as LTI_CONTROLLER_FORMAT
from lpvflow.loop.loader import LPV_FORMAT, load_controller_file
from lpvflow.lpvio import LPVIO
from lpvflow.models import LPVSS, atomic_write_json, load, report_header
from lpvflow.pipeline.cli_identify import add_data_arguments, simulate_any
from lpvflow.pipeline.cli_paths import check_paths, declare
from lpvflow.pipeline.cli_values import assignments, numbers
from lpvflow.validate.fmu_reference import FmuLinearization, FmuLocalModels
from lpvflow.validate.frozen import compare_frozen, scheduling_grid
from lpvflow.validate.metrics import fit_report
from lpvflow.validate.plots import bode_overlay, gap_margin_plot
from lpvflow.validate.stability import quadratic_stability

#: Frozen points shown in the Bode overlay (evenly picked from the grid).
BODE_POINTS = 5


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", help="model file (lpvflow/lpvss or lpvflow/lpvio)")
    add_data_arguments(p)
    p.add_argument("--reference", metavar="MODEL.json|PLANT.fmu",
                   help="reference for the frozen nu-gap: another model file or an FMU plant")
    p.add_argument("--fmu-scheduling", nargs="+", metavar="EXPR",
                   help="FMU reference: scheduling value per model scheduling signal, as arithmetic on FMU "
                        "input/output names (e.g. diag_scheduling, sin(arm_angle))")
    p.add_argument("--fmu-reference", choices=("linearization", "local-arx"), default="linearization",
                   help="FMU reference: finite-difference linearization (default) or a local ARX "
                        "identified from a small-signal experiment at each grid point")
    p.add_argument("--fmu-start", nargs="+", default=[], metavar="NAME=VALUE",
                   help="FMU reference: start values of states/inputs for the equilibrium search")
    p.add_argument("--fmu-hold", nargs="+", default=[], metavar="OUTPUT=VALUE",
                   help="FMU reference: outputs held at these values in the equilibria, needed when the "
                        "plant has more inputs than scheduling signals (the design file's [validate] hold; "
                        "e.g. lower_disk_position=0.015 for the maglev)")
    p.add_argument("--controller", metavar="CTRL.json",
                   help="lpvflow/lti-controller or lpvflow/lpv-controller file: adds b(P,K), "
                        "pass/fail of nu-gap < b and margins")
    p.add_argument("--grid", type=int, default=5, help="frozen points per scheduling signal (default 5)")
    p.add_argument("--json", dest="json_out", required=True, help="report file to write (JSON)")
    p.add_argument("--figures", metavar="DIR", help="write PNG figures into this folder")
    p.set_defaults(func=run_validate)
    declare(p, inputs=("model", "data", "reference", "controller"), outputs=("json_out",),
            folders=("figures",))


def run_validate(args: argparse.Namespace) -> int:
    inputs = [args.model, args.data] + [f for f in (args.reference, args.controller) if f]
    figure_paths = {}
    if args.figures:
        figure_paths = {"bode": Path(args.figures) / "frozen_bode.png",
                        "nugap": Path(args.figures) / "nugap_vs_b.png"}
        check_paths(inputs, list(figure_paths.values()))
    model = _load_model(args.model)
    data = Dataset.read(args.data, args.u, args.y, args.p, time=args.time, Ts=args.Ts)
    fit = fit_report(data.y, simulate_any(model, data), data.y_names)
    frozen_model = _frozen_model(model)
    controller, controller_note = _load_loop_controller(args.controller)
    if controller is not None and controller.n_p not in (None, frozen_model.basis.n_p):
        raise ModelError(f"the controller is scheduled on {controller.n_p} signal(s), the model on "
                         f"{frozen_model.basis.n_p}; give a controller designed for this model")
    reference, reference_note = _reference(args, frozen_model)
    try:
        rows = compare_frozen(frozen_model, reference, args.grid, controller)
        if figure_paths:
            Path(args.figures).mkdir(parents=True, exist_ok=True)
            points = [p for p, _ in scheduling_grid(_box(frozen_model), args.grid)]
            picked = np.unique(np.linspace(0, len(points) - 1, BODE_POINTS).round().astype(int))
            shown = [points[i] for i in picked]
            bode_overlay(figure_paths["bode"], frozen_model.frozen,
                         None if reference is None else _frozen_callable(reference), shown)
            if reference is not None:
                gap_margin_plot(figure_paths["nugap"], rows)
            else:
                del figure_paths["nugap"]
    finally:
        if hasattr(reference, "close"):
            reference.close()
    certificate = _certificate(model, frozen_model)
    unstabilized = [r["p"] for r in rows if "stability_margin_b" in r and r["stability_margin_b"] == 0.0]
    failing = [r["p"] for r in rows if r.get("passes") is False]
    report = {
        **report_header("validation"),
        "model": args.model,
        "data": args.data,
        "fit": fit,
        "frozen": {
            "grid_points_per_signal": args.grid,
            "box": _box(frozen_model).tolist(),
            "reference": reference_note,
            "controller": controller_note,
            "feedback_convention": "u = -K y (negative feedback), b(P,K) = 1/||T(P,K)||_inf",
            "rows": rows,
        },
        "nugap_test": (
            {"applicable": True, "passes_everywhere": not failing, "failing_points": failing}
            if reference is not None and controller is not None else
            {"applicable": False, "reason": "needs both --reference and --controller"}
        ),
        "margins": "per grid point in frozen.rows[*].margins" if controller is not None
        else "not applicable: no controller given",
        "closed_loop_unstable_points": unstabilized,
        "quadratic_stability": certificate,
        "figures": {name: str(path) for name, path in figure_paths.items()},
    }
    atomic_write_json(args.json_out, _json_safe(report))
    _print_summary(fit, rows, failing, unstabilized, certificate, args.json_out)
    return 1 if failing or unstabilized else 0


def _load_model(path: str) -> LPVSS | LPVIO:
    model = load(path)
    if not isinstance(model, LPVSS | LPVIO):
        raise ModelError(f"{path} holds no LPV model (it is a {type(model).__name__}); "
                         "give an lpvss or lpvio file")
    return model


def _frozen_model(model: LPVSS | LPVIO) -> LPVSS:
    """State-space model whose frozen(θ) is the LTI model at constant θ (module docstring)."""
    if isinstance(model, LPVSS):
        return model
    return dataclasses.replace(model, form="shifted").to_ss()


def _box(model: LPVSS) -> np.ndarray:
    if model.basis.p_min is None:
        raise ModelError("the model has no recorded scheduling range; identify it with lpvflow identify")
    return np.column_stack([model.basis.p_min, model.basis.p_max])


def _load_loop_controller(path: str | None) -> tuple[object, str | None]:
    """The controller K of the loop u = −K y, an LTI or LPV controller frozen at each point (``frozen(p)``
    on e = r − y, module docstring), and a note saying so."""
    if path is None:
        return None, None
    controller = load_controller_file(path, (LTI_CONTROLLER_FORMAT, LPV_FORMAT), "validate --controller")
    return controller, f"{path} (its law on e = r - y frozen at theta: K(theta) in u = -K y)"


def _reference(args: argparse.Namespace, model: LPVSS) -> tuple[object, str | None]:
    if args.reference is None:
        given = [option for option, value in (("--fmu-scheduling", args.fmu_scheduling),
                                              ("--fmu-start", args.fmu_start), ("--fmu-hold", args.fmu_hold))
                 if value]
        if given:
            raise DataError(f"{', '.join(given)} needs --reference PLANT.fmu")
        return None, None
    if Path(args.reference).suffix.lower() == ".fmu":
        if not args.fmu_scheduling or len(args.fmu_scheduling) != model.basis.n_p:
            raise DataError("an FMU reference needs --fmu-scheduling with one expression per scheduling "
                            f"signal of the model ({model.basis.n_p}), e.g. --fmu-scheduling diag_scheduling")
        start, hold = (numbers(assignments(texts, option, "lower_disk_position=0.015"), option)
                       for option, texts in (("--fmu-start", args.fmu_start), ("--fmu-hold", args.fmu_hold)))
        kind = FmuLinearization if args.fmu_reference == "linearization" else FmuLocalModels
        reference = kind(args.reference, model.Ts, args.fmu_scheduling, start, hold=hold)
        return reference, (f"{args.reference} ({args.fmu_reference} at equilibria with scheduling "
                           f"{', '.join(args.fmu_scheduling)})")
    if args.fmu_scheduling or args.fmu_start or args.fmu_hold:
        raise DataError("--fmu-scheduling, --fmu-start and --fmu-hold apply only to an FMU reference "
                        "(PLANT.fmu)")
    reference = _frozen_model(_load_model(args.reference))
    if (reference.ny, reference.nu, reference.basis.n_p) != (model.ny, model.nu, model.basis.n_p):
        raise ModelError(f"the reference is {reference.ny}x{reference.nu} with {reference.basis.n_p} "
                         f"scheduling signal(s), the model {model.ny}x{model.nu} with {model.basis.n_p}; "
                         "give a matching one")
    return reference, f"{args.reference} (frozen LPV model)"


def _frozen_callable(reference: object) -> object:
    return reference.frozen if hasattr(reference, "frozen") else reference


def _certificate(model: LPVSS | LPVIO, frozen_model: LPVSS) -> dict:
    """Quadratic stability of the model for arbitrarily fast scheduling, or why it does not apply."""
    if isinstance(model, LPVIO) and model.form == "static":
        return {"applicable": False,
                "reason": "not applicable: a static-form LPV-ARX has no static-dependence state space"}
    if not frozen_model.basis.is_affine:
        return {"applicable": False,
                "reason": f"not applicable: the basis ({frozen_model.basis.kind}) is not affine in p, "
                          "so the frozen models span no polytope of the box"}
    certificate = quadratic_stability(frozen_model)
    result = {"applicable": True, "certified": certificate.certified, "reason": certificate.reason,
              "solver": certificate.solver}
    if certificate.certified:
        result["lyapunov_matrix"] = np.asarray(certificate.P).tolist()
    return result


def _json_safe(value: object) -> object:
    """Non-finite floats as the strings "inf"/"-inf" (null for NaN), so the file is strict JSON."""
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    if isinstance(value, float | np.floating) and not math.isfinite(value):
        return None if math.isnan(value) else ("inf" if value > 0 else "-inf")
    return value


def _print_summary(fit: dict, rows: list[dict], failing: list, unstabilized: list, certificate: dict,
                   json_out: str) -> None:
    print("fit: " + ", ".join(f"{n} BFR {b:.2f} % VAF {v:.2f} %"
                              for n, b, v in zip(fit["outputs"], fit["bfr"], fit["vaf"], strict=True)))
    if "nugap" in rows[0]:
        print(f"frozen nu-gap over {len(rows)} grid points: max {max(r['nugap'] for r in rows):.4g}")
    if "stability_margin_b" in rows[0]:
        print(f"b(P,K): min {min(r['stability_margin_b'] for r in rows):.4g}"
              + (f"; closed loop unstable at {len(unstabilized)} point(s)" if unstabilized else ""))
    if "passes" in rows[0]:
        print("nu-gap < b at every grid point" if not failing
              else f"nu-gap < b FAILS at {len(failing)} of {len(rows)} grid points")
    print("quadratic stability: " + ("certified" if certificate.get("certified") else certificate["reason"]))
    print(f"report written to {json_out}")
