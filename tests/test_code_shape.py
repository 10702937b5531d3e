"""The shape rule of issue 24: no function in pipeline/ or cli/ longer than MAX_LINES, numba kernels aside.

Length is counted as the AST prints the function (its ``def`` line and one line per statement, a docstring as one,
comments and a formatter's line breaks not at all), so that ruff's formatting, which spreads a long call over
several lines, does not move a function across the limit: measured in physical lines the limit would change with
the formatter's style, not with what the function does.

A long function is split into a short one that reads like its data flow and named steps; a compiled kernel
(``@njit``) stays whole because splitting it costs calls in the hot loop. The few functions allowed to be longer
for now are listed with the reason; an entry that no longer applies fails too, so the list only shrinks.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("pipeline", "cli")
MAX_LINES = 80
#: Compiled kernels: the decorators that make one (by their last name: ``njit``, ``numba.njit(...)``; a
#: ``kernel_cache.subroutine`` is compiled into the kernels that call it).
KERNEL_DECORATORS = {"njit", "jit", "vectorize", "guvectorize", "cfunc", "subroutine"}

#: "path::qualified name" -> why it may be longer for now. Remove the entry when its split lands.
ALLOWED: dict[str, str] = {}


def _is_kernel(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    for dec in fn.decorator_list:
        node = dec.func if isinstance(dec, ast.Call) else dec
        name = node.attr if isinstance(node, ast.Attribute) else getattr(node, "id", "")
        if name in KERNEL_DECORATORS:
            return True
    return False


def function_lengths(source: str) -> dict[str, int]:
    """The length of each non-kernel function as the AST prints it (see the module's docstring), by qualified name
    (``Class.method``, ``outer.<locals>.inner``); a kernel's nested functions are part of the kernel."""
    out: dict[str, int] = {}

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                if _is_kernel(child):
                    continue
                name = prefix + child.name
                out[name] = 1 + sum(len(ast.unparse(stmt).splitlines()) for stmt in child.body)
                visit(child, name + ".<locals>.")
            elif isinstance(child, ast.ClassDef):
                visit(child, prefix + child.name + ".")
            else:
                visit(child, prefix)

    visit(ast.parse(source), "")
    return out


def _all_lengths() -> dict[str, int]:
    lengths = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            for name, n in function_lengths(path.read_text(encoding="utf-8")).items():
                lengths[f"{rel}::{name}"] = n
    return lengths


def test_the_measure_counts_functions_and_methods_but_not_kernels():
    body = "".join(f"    x{i} = {i}\n" for i in range(MAX_LINES))  # with the def: one line too many
    method_body = "".join("    " + line for line in body.splitlines(keepends=True))
    source = (
        f"def long():\n{body}"
        f"class C:\n    def method(self):\n{method_body}"
        f"@njit(cache=True)\ndef kernel():\n{body}"
        f"@numba.njit\ndef kernel2():\n{body}"
        "def short():\n    return 1\n"
    )
    lengths = function_lengths(source)
    assert lengths == {"long": MAX_LINES + 1, "C.method": MAX_LINES + 1, "short": 2}


def test_no_function_is_longer_than_the_limit():
    lengths = _all_lengths()
    too_long = [
        f"{name}: {n} lines"
        for name, n in sorted(lengths.items(), key=lambda kv: -kv[1])
        if n > MAX_LINES and name not in ALLOWED
    ]
    assert not too_long, (
        f"functions longer than {MAX_LINES} lines (split them into named steps, issue 24):\n" + "\n".join(too_long)
    )


@pytest.mark.parametrize("name", sorted(ALLOWED))
def test_each_allowed_exception_still_applies(name):
    lengths = _all_lengths()
    assert name in lengths, f"{name} is gone: remove it from ALLOWED"
    assert lengths[name] > MAX_LINES, f"{name} is {lengths[name]} lines now: remove it from ALLOWED"
