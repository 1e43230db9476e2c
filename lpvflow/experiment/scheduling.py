"""Scheduling columns computed from recorded signals: ``NAME=EXPRESSION`` such as ``sin_arm=sin(arm_angle)``.

An expression is arithmetic (+ - * / ** and unary minus) on numbers, signal names (plant inputs and
outputs) and the functions in :data:`FUNCTIONS`, evaluated element-wise with numpy. Nothing else is
accepted (no attributes, subscripts or calls to other names), so a user string cannot run code.
"""

from __future__ import annotations

import ast
import operator
from collections.abc import Callable, Mapping

import numpy as np

from lpvflow.errors import DataError

FUNCTIONS: dict[str, Callable[..., np.ndarray]] = {
    "sin": np.sin, "cos": np.cos, "tan": np.tan, "arctan2": np.arctan2, "sqrt": np.sqrt, "abs": np.abs,
    "exp": np.exp, "log": np.log, "tanh": np.tanh, "minimum": np.minimum, "maximum": np.maximum,
}
CONSTANTS = {"pi": np.pi}
_BINARY = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
           ast.Pow: operator.pow}
_UNARY = {ast.USub: operator.neg, ast.UAdd: operator.pos}

#: Default scheduling columns per FMU model name, used when the user names none:
#: computed from recorded signals, as a real experiment would (the FMU's ``diag_scheduling`` is the
#: noise-free value), and written even when they copy a signal so every plant's CSV has its p column.
PLANT_DEFAULTS: dict[str, dict[str, str]] = {
    "adip": {"sin_arm": "sin(arm_angle)"},
    "tanks": {"level": "lower_level"},
    "maglev": {"upper_position": "upper_disk_position"},
    "airpath": {"speed": "engine_speed"},
}


def parse_assignment(text: str) -> tuple[str, str]:
    """``NAME=EXPRESSION`` -> (name, expression), checking both are present and the name is an identifier."""
    name, eq, expression = text.partition("=")
    name, expression = name.strip(), expression.strip()
    if not eq or not name.isidentifier() or not expression:
        raise DataError(f"scheduling {text!r} must read NAME=EXPRESSION, e.g. sin_arm=sin(arm_angle)")
    return name, expression


def evaluate(expression: str, signals: Mapping[str, np.ndarray]) -> np.ndarray:
    """Evaluate ``expression`` on the named signal arrays; unknown names or syntax raise DataError."""
    try:
        tree = ast.parse(expression, mode="eval")
    except SyntaxError:
        raise DataError(f"scheduling expression {expression!r} is not valid arithmetic") from None

    def walk(node: ast.AST) -> np.ndarray | float:
        if isinstance(node, ast.Expression):
            return walk(node.body)
        if isinstance(node, ast.Constant) and isinstance(node.value, int | float):
            return float(node.value)
        if isinstance(node, ast.Name):
            if node.id in signals:
                return np.asarray(signals[node.id], dtype=float)
            if node.id in CONSTANTS:
                return CONSTANTS[node.id]
            raise DataError(
                f"scheduling expression {expression!r}: unknown name {node.id!r}; "
                f"signals: {', '.join(signals)}"
            )
        if isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
            return _BINARY[type(node.op)](walk(node.left), walk(node.right))
        if isinstance(node, ast.UnaryOp) and type(node.op) in _UNARY:
            return _UNARY[type(node.op)](walk(node.operand))
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in FUNCTIONS
                and not node.keywords):
            args = [walk(arg) for arg in node.args]
            try:
                return FUNCTIONS[node.func.id](*args)
            except TypeError:
                raise DataError(
                    f"scheduling expression {expression!r}: wrong number of arguments to {node.func.id}"
                ) from None
        raise DataError(
            f"scheduling expression {expression!r}: {ast.unparse(node)!r} is not allowed; use arithmetic, "
            f"signal names and {', '.join(FUNCTIONS)}"
        )

    n = len(next(iter(signals.values()))) if signals else 1
    with np.errstate(all="ignore"):
        value = np.broadcast_to(np.asarray(walk(tree), dtype=float), (n,)).copy()
    if not np.all(np.isfinite(value)):
        raise DataError(f"scheduling expression {expression!r} gives non-finite values on the recorded data")
    return value


def compile_expression(expression: str, names: list[str]) -> Callable[[np.ndarray], float]:
    """``expression`` as a function of one sample of the signals ``names`` (in that order), ~40 times
    faster than :func:`evaluate` per sample, for loops that evaluate it at every step.

    :func:`evaluate` checks the expression first (arithmetic on the names and the functions of
    :data:`FUNCTIONS` only), so evaluating its text with exactly those names and no builtins computes
    the same value and runs nothing else.
    """
    evaluate(expression, {name: np.zeros(1) for name in names})
    code = compile(expression, "<scheduling>", "eval")
    namespace = {"__builtins__": {}, **FUNCTIONS, **CONSTANTS}

    def value(sample: np.ndarray) -> float:
        return float(eval(code, namespace, dict(zip(names, np.asarray(sample).tolist(), strict=True))))

    return value
