"""Export an LPVController as an FMI 2.0 Co-Simulation FMU, a MATLAB .mat file or its JSON file.

FMU (:func:`export_fmu`): inputs e (the controller inputs, r − y of the 1-DOF loop) and p (the
scheduling signals), outputs u, fixed communication step = the controller's Ts. The C engine
(``controller_fmu/controller_fmu.c``) evaluates ψ(p), the convex coordinates λ(ψ) of the design
polytope exactly as :meth:`lpvflow.synth.polytope.Polytope.coordinates`, and

    u(k) = Σ_i λ_i (Ck_i x(k) + Dk_i e(k)),    x(k+1) = Σ_i λ_i (Ak_i x(k) + Bk_i e(k)),  x(0) = 0.

The vertex data go into a generated ``controller_data.h``; the archive holds the platform binary
and every source (engine, generated header, FMI 2.0 headers shipped with fmpy) and is checked with
``fmpy.validation.validate_fmu`` before it replaces the target.

MAT (:func:`export_mat`), for ``load('K.mat')`` in MATLAB or ``scipy.io.loadmat``:
``Ak`` (n, n, N), ``Bk`` (n, ny, N), ``Ck`` (nu, n, N), ``Dk`` (nu, ny, N) — vertex i is
``Ak(:,:,i)`` —, ``psi_vertices`` (N, n_psi) the basis vector at each vertex, ``polytope_kind``,
``scheduling_box`` (n_p, 2), ``term_box`` (m, 2, empty unless term-box), ``basis`` (struct: kind,
n_p, degree, cross, exponents (n_psi, n_p), knots, term_names, p_min, p_max), ``Ts``, the cell
arrays ``input_names``, ``scheduling_names``, ``output_names``, and ``format``/``version``.

Signal names come from the controller's ``info`` (``input_names``, ``scheduling_names``,
``output_names``) or ``names=``, else ``e1…``, ``p1…``, ``u1…``.
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
from dataclasses import dataclass
from pathlib import Path
from string import Template
from xml.sax.saxutils import escape, quoteattr

import fmpy
import numpy as np
import scipy.io
from fmpy.validation import validate_fmu

from lpvflow.errors import DataError, LpvflowError, ModelError
from lpvflow.models import load, user_mode
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
}
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


@dataclass(frozen=True)
class ControllerSignals:
    """Names of the controller inputs e, scheduling signals p and outputs u."""

    inputs: tuple[str, ...]
    scheduling: tuple[str, ...]
    outputs: tuple[str, ...]


def controller_signals(
    controller: LPVController, names: Mapping[str, Sequence[str]] | None = None
) -> ControllerSignals:
    """Names from ``names`` or ``controller.info`` (keys input_names, scheduling_names, output_names)."""
    given = {**controller.info, **(names or {})}
    sizes = {
        "input_names": ("e", controller.n_in),
        "scheduling_names": ("p", controller.basis.n_p),
        "output_names": ("u", controller.n_out),
    }
    chosen = {}
    for key, (prefix, n) in sizes.items():
        values = tuple(given.get(key) or (f"{prefix}{i + 1}" for i in range(n)))
        if len(values) != n:
            raise DataError(f"{key} lists {len(values)} names for {n} signals: {list(values)}")
        bad = [v for v in values if not isinstance(v, str) or not _NAME.match(v)]
        if bad:
            raise DataError(f"{key}: {bad[0]!r} is not a valid signal name (letters, digits, _)")
        chosen[key] = values
    every = [*chosen["input_names"], *chosen["scheduling_names"], *chosen["output_names"]]
    if len(set(every)) != len(every):
        raise DataError(f"controller signal names must be distinct, got {every}")
    return ControllerSignals(chosen["input_names"], chosen["scheduling_names"], chosen["output_names"])


def load_lpv_controller(path: str | Path) -> LPVController:
    """Read an ``lpvflow/lpv-controller`` JSON file; any defect is one ModelError line."""
    try:
        controller = load(path)
    except LpvflowError:
        raise
    except (ValueError, TypeError, IndexError) as exc:
        raise ModelError(f"controller file {path} has malformed matrices ({exc})") from None
    if not isinstance(controller, LPVController):
        raise ModelError(f"{path} is a {type(controller).__name__}, not an lpvflow/lpv-controller file")
    return controller


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
        "input_names": _cell(signals.inputs),
        "scheduling_names": _cell(signals.scheduling),
        "output_names": _cell(signals.outputs),
    }

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as stream:
            scipy.io.savemat(stream, content, do_compression=True, oned_as="row")

    return _atomic_replace(Path(path), write, ".mat")


# ------------------------------------------------------------------------------------------ FMU
def _c_number(value: float) -> str:
    return repr(float(value))


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


def _polytope_code(controller: LPVController) -> str:
    poly = controller.polytope
    if poly.kind == "parabola-triangle":
        inverse = np.linalg.inv(poly.psi_vertices.T)
        rows = ",\n    ".join("{" + ", ".join(_c_number(v) for v in row) + "}" for row in inverse)
        return f"static const double VERTEX_INVERSE[{len(inverse)}][{len(inverse)}] = {{\n    {rows}\n}};\n"
    bounds = poly.box if poly.kind == "box" else poly.term_box
    rows = ",\n    ".join("{" + ", ".join(_c_number(v) for v in row) + "}" for row in bounds)
    return f"static const double TERM_BOUNDS[{len(bounds)}][2] = {{\n    {rows}\n}};\n"


def _check_exportable(controller: LPVController) -> None:
    _check_finite(controller)
    poly, basis = controller.polytope, controller.basis
    if poly.kind not in _POLYTOPE_CODES:
        raise ModelError(f"unknown polytope kind {poly.kind!r}; export knows {', '.join(_POLYTOPE_CODES)}")
    expected = 3 if poly.kind == "parabola-triangle" else 2 ** (basis.n_psi - 1)
    if poly.n_vertices != expected or poly.psi_vertices.shape[1] != basis.n_psi:
        raise ModelError(
            f"the {poly.kind} polytope has {poly.n_vertices} vertices of size "
            f"{poly.psi_vertices.shape[1]}; expected {expected} of size {basis.n_psi}"
        )


def controller_data_header(
    controller: LPVController, identifier: str, guid: str, signals: ControllerSignals
) -> str:
    """The generated ``controller_data.h`` (sizes, vertex matrices, basis, polytope, names)."""
    n, n_in, n_out = controller.order, controller.n_in, controller.n_out
    names = [*signals.inputs, *signals.scheduling, *signals.outputs]
    p_start = controller.polytope.box.mean(axis=1)
    text = [
        f"/* Generated by lpvflow export for {identifier}; do not edit. */",
        "#include <math.h>",
        f'#define MODEL_IDENTIFIER "{identifier}"',
        f'#define MODEL_GUID "{guid}"',
        f"#define TS {_c_number(controller.Ts)}",
        f"#define N_X {n}",
        f"#define N_X_ALLOC {max(n, 1)}",
        f"#define N_IN {n_in}",
        f"#define N_OUT {n_out}",
        f"#define N_P {controller.basis.n_p}",
        f"#define N_PSI {controller.basis.n_psi}",
        f"#define N_VERT {controller.polytope.n_vertices}",
        "#define POLYTOPE_BOX 0",
        "#define POLYTOPE_PARABOLA_TRIANGLE 1",
        "#define POLYTOPE_TERM_BOX 2",
        f"#define POLYTOPE_KIND {_POLYTOPE_CODES[controller.polytope.kind]}",
        f"static const char *const REAL_NAME[{len(names)}] = {{"
        + ", ".join(f'"{name}"' for name in names)
        + "};",
    ]
    return (
        "\n".join(text)
        + "\n"
        + _c_array("P_START", p_start)
        + "".join(_c_array(name.upper(), getattr(controller, name)) for name in ("Ak", "Bk", "Ck", "Dk"))
        + _polytope_code(controller)
        + _basis_code(controller)
    )


def _model_description(
    controller: LPVController, identifier: str, guid: str, signals: ControllerSignals
) -> str:
    variables, outputs = [], []
    rows = (
        [(name, "input", f"controller input {i + 1} (r - y)", "0.0") for i, name in enumerate(signals.inputs)]
        + [
            (name, "input", f"scheduling signal {i + 1}", _c_number(start))
            for i, (name, start) in enumerate(
                zip(signals.scheduling, controller.polytope.box.mean(axis=1), strict=True)
            )
        ]
        + [
            (name, "output", f"controller output {i + 1} (plant input)", None)
            for i, name in enumerate(signals.outputs)
        ]
    )
    for vr, (name, causality, description, start) in enumerate(rows):
        if causality == "input":
            real = f'<Real start="{start}"/>'
            extra = ""
        else:
            real, extra = "<Real/>", ' initial="calculated"'
            outputs.append(f'      <Unknown index="{vr + 1}"/>')
        variables.append(
            f'    <ScalarVariable name={quoteattr(name)} valueReference="{vr}" causality="{causality}" '
            f'variability="continuous"{extra} description={quoteattr(description)}>\n'
            f"      {real}\n    </ScalarVariable>"
        )
    template = Template((TEMPLATE_DIR / "modelDescription.xml.in").read_text())
    description = (
        f"lpvflow gain-scheduled controller: {controller.order} states, {controller.polytope.n_vertices} "
        f"vertices ({controller.polytope.kind}), Ts = {controller.Ts:g} s"
    )
    return template.substitute(
        model_identifier=identifier,
        guid=guid,
        description=escape(description),
        Ts=_c_number(controller.Ts),
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
    digest = hashlib.sha256(json.dumps([controller.to_dict(), signals.__dict__], default=list).encode())
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
    """Write ``controller`` as ``fmt`` (fmu, json or mat) to ``path``."""
    if fmt == "fmu":
        return export_fmu(controller, path, names)
    if fmt == "mat":
        return export_mat(controller, path, names)
    if fmt == "json":
        return export_json(controller, path)
    raise DataError(f"unknown export format {fmt!r}; use one of {', '.join(FORMATS)}")
