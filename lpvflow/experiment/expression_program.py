"""A scheduling expression (:mod:`lpvflow.experiment.scheduling`) as a postfix program that compiled
loops evaluate per sample (:func:`run_program`, numba).

The program is the expression's syntax tree in post-order: each instruction pushes a number or a signal
of the sample, or replaces the top one or two stack entries by an operator or function of them. The
expression is checked by :func:`~lpvflow.experiment.scheduling.evaluate` first, so the program holds
only arithmetic on the named signals and the functions of
:data:`~lpvflow.experiment.scheduling.FUNCTIONS`, and computes what the expression's numpy evaluation
computes (to round-off of the math library).
"""

from __future__ import annotations

import ast

import numba
import numpy as np

from lpvflow.errors import DataError
from lpvflow.experiment.scheduling import CONSTANTS, evaluate

CONST, SIGNAL = 0, 1
#: Operator and function codes with their number of arguments.
BINARY = {ast.Add: 2, ast.Sub: 3, ast.Mult: 4, ast.Div: 5, ast.Pow: 6}
UNARY = {ast.USub: 10, ast.UAdd: 11}
CALLS = {"arctan2": (7, 2), "minimum": (8, 2), "maximum": (9, 2), "sin": (12, 1), "cos": (13, 1),
         "tan": (14, 1), "sqrt": (15, 1), "abs": (16, 1), "exp": (17, 1), "log": (18, 1), "tanh": (19, 1)}


def expression_program(expression: str, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """(codes, arguments) of ``expression`` in the signals ``names`` (a sample's order); the argument
    of a number is its value, of a signal its index in ``names``. Raises DataError as
    :func:`~lpvflow.experiment.scheduling.evaluate` does, or for a function without a code here."""
    evaluate(expression, {name: np.zeros(1) for name in names})
    codes: list[int] = []
    arguments: list[float] = []

    def emit(code: int, argument: float = 0.0) -> None:
        codes.append(code)
        arguments.append(argument)

    def walk(node: ast.AST) -> None:
        if isinstance(node, ast.Expression):
            walk(node.body)
        elif isinstance(node, ast.Constant):
            emit(CONST, float(node.value))
        elif isinstance(node, ast.Name):
            if node.id in names:
                emit(SIGNAL, float(names.index(node.id)))
            else:
                emit(CONST, float(CONSTANTS[node.id]))
        elif isinstance(node, ast.BinOp):
            walk(node.left)
            walk(node.right)
            emit(BINARY[type(node.op)])
        elif isinstance(node, ast.UnaryOp):
            walk(node.operand)
            emit(UNARY[type(node.op)])
        else:  # a call of FUNCTIONS (evaluate accepted nothing else)
            name = node.func.id
            if name not in CALLS or len(node.args) != CALLS[name][1]:
                raise DataError(f"scheduling expression {expression!r}: {name} takes "
                                f"{CALLS[name][1] if name in CALLS else '?'} argument(s) in a compiled loop")
            for arg in node.args:
                walk(arg)
            emit(CALLS[name][0])

    walk(ast.parse(expression, mode="eval"))
    return np.array(codes, dtype=np.int64), np.array(arguments, dtype=float)


@numba.njit(cache=True, error_model="numpy")
def run_program(codes: np.ndarray, arguments: np.ndarray, sample: np.ndarray, stack: np.ndarray) -> float:
    """The value of the program (codes, arguments) on one ``sample`` of its signals; ``stack`` is scratch
    space of at least ``len(codes)`` entries."""
    top = 0
    for q in range(codes.shape[0]):
        code = codes[q]
        if code == 0:
            stack[top] = arguments[q]
            top += 1
        elif code == 1:
            stack[top] = sample[int(arguments[q])]
            top += 1
        elif code <= 9:
            b = stack[top - 1]
            a = stack[top - 2]
            top -= 1
            if code == 2:
                r = a + b
            elif code == 3:
                r = a - b
            elif code == 4:
                r = a * b
            elif code == 5:
                r = a / b
            elif code == 6:
                r = a ** b
            elif code == 7:
                r = np.arctan2(a, b)
            elif code == 8:
                r = min(a, b) if not (np.isnan(a) or np.isnan(b)) else np.nan
            else:
                r = max(a, b) if not (np.isnan(a) or np.isnan(b)) else np.nan
            stack[top - 1] = r
        else:
            a = stack[top - 1]
            if code == 10:
                r = -a
            elif code == 11:
                r = a
            elif code == 12:
                r = np.sin(a)
            elif code == 13:
                r = np.cos(a)
            elif code == 14:
                r = np.tan(a)
            elif code == 15:
                r = np.sqrt(a)
            elif code == 16:
                r = abs(a)
            elif code == 17:
                r = np.exp(a)
            elif code == 18:
                r = np.log(a)
            else:
                r = np.tanh(a)
            stack[top - 1] = r
    return stack[0]


@numba.njit(cache=True)
def program_values(codes: np.ndarray, arguments: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """The program's value on every row of ``samples`` (n, signals)."""
    stack = np.empty(codes.shape[0] + 1)
    values = np.empty(samples.shape[0])
    for k in range(samples.shape[0]):
        values[k] = run_program(codes, arguments, samples[k], stack)
    return values
