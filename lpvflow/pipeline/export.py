"""Export an LPVController as an FMI 2.0 Co-Simulation FMU, a MATLAB .mat file or its JSON file.

Ports are named after the plant signals (:class:`~lpvflow.pipeline.ports.ControllerSignals`, stored in
the controller's ``info["signals"]`` by the synth stage, :func:`lpvflow.pipeline.ports.describe_signals`):
for every measured output ``y`` the inputs ``y_ref`` (its reference) and ``y`` (its measurement), the
scheduling signals by name (each with the expression that computes it from plant signals, e.g.
``sin_arm = sin(arm_angle)``), the actuated plant inputs by name as outputs; each with its unit,
description and operating point.
Controllers without that record get ``y1``, ``p1``, ``u1``….

FMU (:func:`export_fmu`): fixed communication step = the controller's Ts. The ports are the same for
both controller structures (:mod:`lpvflow.synth.controller`); the C engine
(``controller_fmu/controller_fmu.c``) forms the controller input w = y_ref − y (``"1dof"``) or
w = [y_ref − y_op; y − y_op] (``"2dof"``, y_op the measured outputs' operating point, as
:meth:`lpvflow.synth.controller.LPVController.input_of`), evaluates the convex coordinates λ(p) of
the design polytope exactly as
:meth:`lpvflow.synth.polytope.Polytope.coordinates_at` (of ψ(p), or the hat functions of the first
scheduling signal for a ``"piecewise"`` polytope; the rule is spelled out in the FMU's description,
:func:`interpolation_rule`), and

    u(k) = u_op + u_eq(p(k)) + Σ_i λ_i (Ck_i x(k) + Dk_i w(k)),    x(k+1) = Σ_i λ_i (Ak_i x(k) + Bk_i w(k)),

x(0) = 0, u_op the actuated inputs' operating point, u_eq the controller's trim feed-forward
(:class:`lpvflow.synth.controller.Trim`: per input ``np.interp`` of the first scheduling signal in its
table, zero without one). The vertex data go into a generated
``controller_data.h``; the archive holds the platform binary and every source (engine, generated
header, FMI 2.0 headers shipped with fmpy) and is checked with ``fmpy.validation.validate_fmu``
before it replaces the target.

MAT (:func:`export_mat`), for ``load('K.mat')`` in MATLAB or ``scipy.io.loadmat``:
``Ak`` (n, n, N), ``Bk`` (n, ny, N), ``Ck`` (nu, n, N), ``Dk`` (nu, ny, N) — vertex i is
``Ak(:,:,i)`` —, ``psi_vertices`` (N, n_psi) the basis vector at each vertex, ``polytope_kind``,
``interpolation`` (the rule λ(p) as text), ``vertex_inverse`` (N, N: λ = vertex_inverse ψ before
clipping, parabola-triangle only, else empty), ``scheduling_box`` (n_p, 2), ``term_box`` (m, 2, empty
unless term-box), ``basis`` (struct: kind, n_p, degree, cross, exponents (n_psi, n_p), knots,
term_names, p_min, p_max), ``Ts``; per role (``measured``, ``reference``, ``scheduling``,
``actuated``) the cell arrays ``<role>_names``, ``<role>_units``, ``<role>_descriptions``, and
``scheduling_expressions``, ``y_operating_point``, ``u_operating_point`` (the operating point added to
u), ``structure`` (``"1dof"``: the controller input is reference − measured; ``"2dof"``: [reference −
y_operating_point; measured − y_operating_point], in the order of ``reference_names`` then
``measured_names``), ``trim_p`` (M,) and ``trim_u``
(M, nu) (the trim table, u_eq(p) = interp1(trim_p, trim_u, clamp(p_1)); empty without one),
``breakpoints`` (N, piecewise only, else empty), and ``format``/``version``; with anti-windup
(:mod:`lpvflow.synth.controller`) also ``antiwindup_L``
(n, nu, N), ``u_min``, ``u_max``. The FMU applies the same anti-windup law.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import tempfile
import uuid
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from string import Template
from xml.sax.saxutils import escape, quoteattr

import fmpy
import numpy as np
import scipy.io
from fmpy.validation import validate_fmu

from lpvflow.errors import DataError, ModelError
from lpvflow.loop.loader import LPV_FORMAT, load_controller_file
from lpvflow.models import user_mode
from lpvflow.pipeline.ports import ControllerSignals, Port, controller_signals
from lpvflow.synth.controller import LPVController

FORMATS = ("fmu", "json", "mat")
TEMPLATE_DIR = Path(__file__).resolve().parent / "controller_fmu"
FMI_HEADERS = [
    Path(fmpy.__file__).parent / "c-code" / name
    for name in ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
]
_POLYTOPE_CODES = {
    "box": "POLYTOPE_BOX",
    "parabola-triangle": "POLYTOPE_PARABOLA_TRIANGLE",
    "term-box": "POLYTOPE_TERM_BOX",
    "piecewise": "POLYTOPE_PIECEWISE",
    "point": "POLYTOPE_POINT",
}


def interpolation_rule(controller: LPVController, signals: ControllerSignals) -> str:
    """How the FMU and MAT user get the vertex weights λ(p) of this controller's polytope, in words
    (:meth:`lpvflow.synth.polytope.Polytope.rule`)."""
    basis = controller.basis
    p_names = [port.name for port in signals.scheduling]
    psi = f"ψ(p) = [{', '.join(basis.term_names)}] with (p0, p1, …) = ({', '.join(p_names)})"
    return controller.polytope.rule(psi, p_names)


def trim_rule(controller: LPVController, signals: ControllerSignals) -> str:
    """How the trim feed-forward u_eq(p) is computed, in words ("" without a trim table)."""
    trim = controller.trim
    if trim is None:
        return ""
    name = signals.scheduling[0].name
    return (f"u_eq({name}) per actuated input: linear interpolation of the trim table over {name} = "
            f"[{', '.join(f'{v:g}' for v in trim.p)}], clamped at its ends")


def load_lpv_controller(path: str | Path) -> LPVController:
    """The ``lpvflow/lpv-controller`` of a JSON file (:func:`lpvflow.loop.loader.load_controller_file`);
    any other file is one ModelError line."""
    return load_controller_file(path, (LPV_FORMAT,), "export")


def _atomic_replace(path: Path, write: callable, suffix: str) -> Path:
    """Call ``write(tmp)`` on a temporary file next to ``path``, then rename it onto ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    user_mode(fd)
    os.close(fd)
    try:
        write(Path(tmp))
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def _check_finite(controller: LPVController) -> None:
    for name in ("Ak", "Bk", "Ck", "Dk"):
        if not np.all(np.isfinite(getattr(controller, name))):
            raise ModelError(f"controller {name} has non-finite entries; it cannot be exported")


# ----------------------------------------------------------------------------------------- JSON
def export_json(controller: LPVController, path: str | Path) -> Path:
    """The controller file itself (``lpvflow/lpv-controller``), re-validated by a load round trip."""
    _check_finite(controller)
    document = controller.to_dict()
    LPVController.from_dict(json.loads(json.dumps(document)))
    path = Path(path)
    controller.save(path)
    return path


# ------------------------------------------------------------------------------------------ MAT
def _cell(values: Sequence[str]) -> np.ndarray:
    cell = np.empty((1, len(values)), dtype=object)
    for i, v in enumerate(values):
        cell[0, i] = v
    return cell


def export_mat(
    controller: LPVController, path: str | Path, names: Mapping[str, Sequence[str]] | None = None
) -> Path:
    """MATLAB .mat file with the layout of the module docstring (vertex index last)."""
    _check_finite(controller)
    signals = controller_signals(controller, names)
    basis, poly = controller.basis, controller.polytope
    tables = poly.tables()
    basis_struct = {
        "kind": basis.kind,
        "n_p": basis.n_p,
        "degree": basis.degree,
        "cross": int(basis.cross),
        "exponents": np.array(basis.exponents, dtype=float).reshape(-1, basis.n_p),
        "knots": _cell([json.dumps(list(k)) for k in basis.knots]),
        "term_names": _cell(basis.term_names),
        "p_min": np.array(basis.p_min if basis.p_min is not None else [], dtype=float),
        "p_max": np.array(basis.p_max if basis.p_max is not None else [], dtype=float),
    }
    content = {
        "format": "lpvflow/lpv-controller-mat",
        "version": 1,
        "Ak": np.moveaxis(controller.Ak, 0, -1),
        "Bk": np.moveaxis(controller.Bk, 0, -1),
        "Ck": np.moveaxis(controller.Ck, 0, -1),
        "Dk": np.moveaxis(controller.Dk, 0, -1),
        "psi_vertices": poly.psi_vertices,
        "polytope_kind": poly.kind,
        "scheduling_box": poly.box,
        "term_box": poly.term_box if poly.term_box is not None else np.zeros((0, 2)),
        "basis": basis_struct,
        "Ts": float(controller.Ts),
        "interpolation": interpolation_rule(controller, signals),
        "vertex_inverse": tables.get("vertex_inverse", np.zeros((0, 0))),
        "scheduling_expressions": _cell([port.expression or port.name for port in signals.scheduling]),
        "y_operating_point": np.array([port.operating_point for port in signals.measured]),
        "u_operating_point": np.array([port.operating_point for port in signals.actuated]),
        "structure": controller.structure,
        "trim_p": controller.trim.p if controller.trim is not None else np.zeros(0),
        "trim_u": controller.trim.u if controller.trim is not None else np.zeros((0, controller.n_out)),
        "breakpoints": tables.get("breakpoints", np.zeros(0)),
    }
    if controller.antiwindup is not None:  # x⁺ += Σλ_i L_i (clip(u_op + u, u_min, u_max) − u_op − u)
        aw = controller.antiwindup
        content |= {"antiwindup_L": np.moveaxis(aw.L, 0, -1), "u_min": aw.u_min, "u_max": aw.u_max}
    roles = {"measured": signals.measured, "reference": signals.measured, "scheduling": signals.scheduling,
             "actuated": signals.actuated}
    for role, ports in roles.items():
        suffix = "_ref" if role == "reference" else ""
        content[f"{role}_names"] = _cell([port.name + suffix for port in ports])
        content[f"{role}_units"] = _cell([port.unit for port in ports])
        content[f"{role}_descriptions"] = _cell([_port_description(role, port, _offsets(controller, signals,
                                                                                          port))
                                                 for port in ports])

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as stream:
            scipy.io.savemat(stream, content, do_compression=True, oned_as="row")

    return _atomic_replace(Path(path), write, ".mat")


# ------------------------------------------------------------------------------------------ FMU
def _c_number(value: float) -> str:
    value = float(value)
    if np.isinf(value):  # an actuator without a limit on one side
        return "HUGE_VAL" if value > 0 else "-HUGE_VAL"
    return repr(value)


def _c_array(name: str, values: np.ndarray) -> str:
    """``static const double NAME[len] = {...};`` (at least one element: C has no empty arrays)."""
    flat = np.asarray(values, dtype=float).reshape(-1)
    items = [_c_number(v) for v in flat] or ["0.0"]
    return f"static const double {name}[{len(items)}] = {{\n    " + ",\n    ".join(items) + "\n};\n"


def _basis_code(controller: LPVController) -> str:
    """C function psi = ψ(p) with the arithmetic of :meth:`lpvflow.basis.Basis.eval`."""
    basis = controller.basis
    lines = ["static void basis(const double *p, double *psi) {"]
    if basis.kind == "spline":
        lines.append("    psi[0] = 1.0;")
        j = 1
        for i, knots in enumerate(basis.knots):
            lines.append(f"    psi[{j}] = p[{i}];")
            j += 1
            for knot in knots:
                lines.append(f"    psi[{j}] = pow(fabs(p[{i}] - ({_c_number(knot)})), 3.0);")
                j += 1
    else:
        for j, exponents in enumerate(basis.exponents):
            factors = []
            for i, v in enumerate(exponents):
                if v == 1:
                    factors.append(f"p[{i}]")
                elif v == 2:
                    factors.append(f"(p[{i}] * p[{i}])")
                elif v > 2:
                    factors.append(f"pow(p[{i}], {float(v)!r})")
            lines.append(f"    psi[{j}] = " + " * ".join(["1.0", *factors]) + ";")
    lines.append("}")
    return "\n".join(lines) + "\n"


def _c_matrix(name: str, rows: np.ndarray) -> str:
    """``static const double NAME[r][c] = {{...}, ...};``."""
    body = ",\n    ".join("{" + ", ".join(_c_number(v) for v in row) + "}" for row in rows)
    return f"static const double {name}[{len(rows)}][{len(rows[0])}] = {{\n    {body}\n}};\n"


def _polytope_code(controller: LPVController) -> str:
    """The polytope's tables (:meth:`lpvflow.synth.polytope.Polytope.tables`) as C arrays, names in
    capitals."""
    return "".join(_c_matrix(name.upper(), values) if np.ndim(values) == 2 else _c_array(name.upper(), values)
                   for name, values in controller.polytope.tables().items())


def _check_exportable(controller: LPVController) -> None:
    _check_finite(controller)
    poly, basis = controller.polytope, controller.basis
    expected = poly.expected_vertices
    if poly.n_vertices != expected or poly.psi_vertices.shape[1] != basis.n_psi:
        raise ModelError(
            f"the {poly.kind} polytope has {poly.n_vertices} vertices of size "
            f"{poly.psi_vertices.shape[1]}; expected {expected} of size {basis.n_psi}"
        )


def controller_data_header(
    controller: LPVController, identifier: str, guid: str, signals: ControllerSignals
) -> str:
    """The generated ``controller_data.h`` (sizes, vertex matrices, basis, polytope, names)."""
    n, n_in, n_out = controller.order, controller.n_in, controller.n_out  # n_in: width of w
    names = [port.name for port, _ in _fmu_variables(controller, signals)]
    y_op = [port.operating_point for port in signals.measured]
    text = [
        f"/* Generated by lpvflow export for {identifier}; do not edit. */",
        "#include <math.h>",
        f'#define MODEL_IDENTIFIER "{identifier}"',
        f'#define MODEL_GUID "{guid}"',
        f"#define TS {_c_number(controller.Ts)}",
        f"#define N_X {n}",
        f"#define N_X_ALLOC {max(n, 1)}",
        f"#define N_IN {n_in}",
        f"#define N_MEAS {controller.n_measured}",
        f"#define STRUCTURE_2DOF {int(controller.structure == '2dof')}",
        f"#define N_OUT {n_out}",
        f"#define N_P {controller.basis.n_p}",
        f"#define N_PSI {controller.basis.n_psi}",
        f"#define N_VERT {controller.polytope.n_vertices}",
        "#define POLYTOPE_BOX 0",
        "#define POLYTOPE_PARABOLA_TRIANGLE 1",
        "#define POLYTOPE_TERM_BOX 2",
        "#define POLYTOPE_PIECEWISE 3",
        "#define POLYTOPE_POINT 4",
        f"#define POLYTOPE_KIND {_POLYTOPE_CODES[controller.polytope.kind]}",
        f"static const char *const REAL_NAME[{len(names)}] = {{"
        + ", ".join(f'"{name}"' for name in names)
        + "};",
    ]
    return (
        "\n".join(text)
        + "\n"
        + _c_array("P_START", [port.operating_point for port in _scheduling_ports(controller, signals)])
        + _c_array("Y_OP", y_op)
        + _c_array("U_OP", [port.operating_point for port in signals.actuated])
        + "".join(_c_array(name.upper(), getattr(controller, name)) for name in ("Ak", "Bk", "Ck", "Dk"))
        + _antiwindup_code(controller, signals)
        + _trim_code(controller)
        + _polytope_code(controller)
        + _basis_code(controller)
    )


def _antiwindup_code(controller: LPVController, signals: ControllerSignals) -> str:
    """HAS_ANTIWINDUP, the gains AW_L and the range U_MIN, U_MAX of the controller's anti-windup law
    (:mod:`lpvflow.synth.controller`); its trim must be the FMU's U_OP."""
    aw = controller.antiwindup
    if aw is None:
        return "#define HAS_ANTIWINDUP 0\n"
    u_op = np.array([port.operating_point for port in signals.actuated])
    if not np.allclose(aw.u_offset, u_op, rtol=1e-12, atol=1e-12):
        raise ModelError(f"the anti-windup trim {aw.u_offset.tolist()} differs from the actuated operating "
                         f"points {u_op.tolist()} of the controller's signal record")
    return ("#define HAS_ANTIWINDUP 1\n" + _c_array("AW_L", aw.L) + _c_array("U_MIN", aw.u_min)
            + _c_array("U_MAX", aw.u_max))


def _trim_code(controller: LPVController) -> str:
    """HAS_TRIM and the trim table TRIM_P (M), TRIM_U (M × N_OUT, row-major) of u_eq(p)."""
    trim = controller.trim
    if trim is None:
        return "#define HAS_TRIM 0\n"
    return (f"#define HAS_TRIM 1\n#define TRIM_M {len(trim.p)}\n" + _c_array("TRIM_P", trim.p)
            + _c_array("TRIM_U", trim.u))


def _scheduling_ports(controller: LPVController, signals: ControllerSignals) -> list[Port]:
    """The scheduling ports with the middle of the design box as start value where none is recorded."""
    recorded = controller.info.get("signals") or {}
    if recorded.get("scheduling"):
        return list(signals.scheduling)
    return [replace(port, operating_point=float(c))
            for port, c in zip(signals.scheduling, controller.polytope.box.mean(axis=1), strict=True)]


def _offsets(controller: LPVController, signals: ControllerSignals, port: Port) -> str:
    """What an actuated output adds to the controller's law: its operating point and the trim u_eq(p)."""
    parts = [f"the operating point {port.operating_point:g}{' ' + port.unit if port.unit else ''}"] \
        if port.operating_point else []
    if controller.trim is not None:
        parts.append(f"the trim feed-forward u_eq({signals.scheduling[0].name})")
    return " and ".join(parts)


def _port_description(role: str, port: Port, trim: str = "") -> str:
    """The FMU/MAT description of a port: role, the plant's description, the scheduling expression;
    ``trim``: what an actuated output adds to the controller's law (:func:`_offsets`)."""
    words = {"reference": f"reference for {port.name}", "measured": f"measured {port.name}",
             "scheduling": f"scheduling {port.name} = {port.expression or port.name}",
             "actuated": f"actuated {port.name}" + (f" (includes {trim})" if trim else "")}[role]
    return f"{words}: {port.description}" if port.description else words


def _fmu_variables(controller: LPVController, signals: ControllerSignals) -> list[tuple[Port, str]]:
    """(port, role) in value-reference order: references, measured outputs, scheduling, actuated."""
    return ([(replace(port, name=f"{port.name}_ref"), "reference") for port in signals.measured]
            + [(port, "measured") for port in signals.measured]
            + [(port, "scheduling") for port in _scheduling_ports(controller, signals)]
            + [(port, "actuated") for port in signals.actuated])


def _model_description(
    controller: LPVController, identifier: str, guid: str, signals: ControllerSignals
) -> str:
    variables, outputs, units = [], [], set()
    for vr, (port, role) in enumerate(_fmu_variables(controller, signals)):
        unit = f" unit={quoteattr(port.unit)}" if port.unit else ""
        units.add(port.unit)
        named = replace(port, name=port.name.removesuffix("_ref")) if role == "reference" else port
        description = _port_description(role, named, _offsets(controller, signals, port))
        if role == "actuated":
            causality, real, extra = "output", f"<Real{unit}/>", ' initial="calculated"'
            outputs.append(f'      <Unknown index="{vr + 1}"/>')
        else:
            causality, real, extra = "input", f'<Real{unit} start="{_c_number(port.operating_point)}"/>', ""
        variables.append(
            f'    <ScalarVariable name={quoteattr(port.name)} valueReference="{vr}" causality="{causality}" '
            f'variability="continuous"{extra} description={quoteattr(description)}>\n'
            f"      {real}\n    </ScalarVariable>"
        )
    template = Template((TEMPLATE_DIR / "modelDescription.xml.in").read_text())
    law = ("2-DOF, controller input w = [y_ref − y_op; y − y_op] (y_op the start values of y)"
           if controller.structure == "2dof"
           else "1-DOF, controller input w = y_ref − y")
    trim = trim_rule(controller, signals)
    description = (
        f"lpvflow gain-scheduled controller: {controller.order} states, {controller.polytope.n_vertices} "
        f"vertices ({controller.polytope.kind}), Ts = {controller.Ts:g} s; {law}; "
        f"λ(p): {interpolation_rule(controller, signals)}" + (f"; trim {trim}" if trim else "")
    )
    unit_definitions = "".join(f'    <Unit name={quoteattr(u)}/>\n' for u in sorted(units) if u)
    return template.substitute(
        model_identifier=identifier,
        guid=guid,
        description=escape(description, {'"': "&quot;"}),
        Ts=_c_number(controller.Ts),
        unit_definitions=f"  <UnitDefinitions>\n{unit_definitions}  </UnitDefinitions>\n" if unit_definitions
        else "",
        variables="\n".join(variables),
        outputs="\n".join(outputs),
    )


def _identifier(path: Path) -> str:
    stem = re.sub(r"\W", "_", path.stem) or "controller"
    return stem if stem[0].isalpha() else f"controller_{stem}"


def _compile(sources: Path, library: Path) -> None:
    compiler = os.environ.get("CC", "gcc")
    if shutil.which(compiler) is None:
        raise ModelError(f"C compiler {compiler!r} not found; install gcc or set CC to build the FMU")
    command = [
        compiler,
        "-shared",
        "-fPIC",
        "-O2",
        "-std=c99",
        "-ffp-contract=off",
        "-Wall",
        "-Wextra",
        "-Werror",
        "-I",
        str(sources),
        str(sources / "controller_fmu.c"),
        "-o",
        str(library),
        "-lm",
    ]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        first = next((line for line in result.stderr.splitlines() if "error" in line), result.stderr.strip())
        raise ModelError(f"compiling the controller FMU failed: {first}")


def export_fmu(
    controller: LPVController, path: str | Path, names: Mapping[str, Sequence[str]] | None = None
) -> Path:
    """Generate, compile, zip and validate the controller FMU (module docstring); returns its path."""
    _check_exportable(controller)
    path = Path(path)
    signals = controller_signals(controller, names)
    identifier = _identifier(path)
    digest = hashlib.sha256(json.dumps([controller.to_dict(), signals.to_dict()]).encode())
    guid = "{" + str(uuid.uuid5(uuid.NAMESPACE_URL, "lpvflow:" + digest.hexdigest())) + "}"
    with tempfile.TemporaryDirectory(prefix="lpvflow_fmu_") as tmp:
        stage = Path(tmp) / "fmu"
        sources, binaries = stage / "sources", stage / "binaries" / fmpy.platform
        sources.mkdir(parents=True)
        binaries.mkdir(parents=True)
        for source in [TEMPLATE_DIR / "controller_fmu.c", *FMI_HEADERS]:
            shutil.copy2(source, sources / source.name)
        (sources / "controller_data.h").write_text(
            controller_data_header(controller, identifier, guid, signals)
        )
        (stage / "modelDescription.xml").write_text(_model_description(controller, identifier, guid, signals))
        _compile(sources, binaries / f"{identifier}{fmpy.sharedLibraryExtension}")

        def write(archive_path: Path) -> None:
            with zipfile.ZipFile(archive_path, "w", zipfile.ZIP_DEFLATED) as archive:
                for file in sorted(stage.rglob("*")):
                    if file.is_file():
                        archive.write(file, file.relative_to(stage).as_posix())
            problems = validate_fmu(str(archive_path))
            if problems:
                raise ModelError(f"the generated FMU does not validate: {problems[0]}")

        return _atomic_replace(path, write, ".fmu")


def export_controller(
    controller: LPVController, path: str | Path, fmt: str, names: Mapping[str, Sequence[str]] | None = None
) -> Path:
    """Write ``controller`` as ``fmt`` (fmu, json or mat) to ``path``, whose extension must be ``.fmt``
    (a MAT file named ``k.fmu`` would be taken for an FMU by every tool that opens it)."""
    if fmt in FORMATS and Path(path).suffix.lower() != f".{fmt}":
        raise DataError(f"output {Path(path).name} does not end in .{fmt}, the format written; name it "
                        f"{Path(path).with_suffix(f'.{fmt}').name} or choose the format its extension names")
    if fmt == "fmu":
        return export_fmu(controller, path, names)
    if fmt == "mat":
        return export_mat(controller, path, names)
    if fmt == "json":
        return export_json(controller, path)
    raise DataError(f"unknown export format {fmt!r}; use one of {', '.join(FORMATS)}")
