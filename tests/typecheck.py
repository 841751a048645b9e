"""Run mypy on pliant/ (configuration in pyproject.toml) and fail on any error in host Python.

Warp kernels and functions (``@wp.kernel``, ``@wp.func``) are written in Warp's kernel language, not in
Python: their annotations are calls (``wp.array(dtype=wp.vec3)``), which mypy rejects as types
(``valid-type``), and their bodies use builtins whose Python stubs are approximations (``i, j = wp.tid()``
reads as unpacking an ``int``; ``vec3 * float`` as a ``float``). Warp's code generator type-checks those
bodies itself, strictly, when a module is built (every kernel is built by the test suite, and for CUDA by
tests/test_cuda_compile.py). So this script drops the errors whose line lies inside such a function's
span (decorators, signature and body), found with ``ast``, and reports every other one. A per-module
``disable_error_code`` would have hidden the same codes in the launchers beside the kernels too.

    python tests/typecheck.py            # exit 1 and the errors when host code has any
    python tests/typecheck.py --any      # list the plain-Python ``Any`` annotations (see plain_any)

Run by ``make test`` (so by ``.ci/run``).
"""

from __future__ import annotations

import ast
import os
import re
import sys
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ERROR = re.compile(r"^(?P<path>[^:\s]+\.py):(?P<line>\d+):(?:\d+:)? error: ")
KERNEL_DECORATORS = ("wp.kernel", "wp.func", "wp.func_native", "warp.kernel", "warp.func", "warp.func_native")


def is_warp_function(node: ast.AST) -> bool:
    """Whether ``node`` is a function decorated with ``@wp.kernel``, ``@wp.func`` or ``@wp.func_native``
    (with or without arguments, e.g. ``@wp.kernel(enable_backward=False)``)."""
    if not isinstance(node, ast.FunctionDef):
        return False
    for dec in node.decorator_list:
        target = dec.func if isinstance(dec, ast.Call) else dec
        if ast.unparse(target) in KERNEL_DECORATORS:
            return True
    return False


@cache
def warp_spans(path: str) -> tuple[tuple[int, int], ...]:
    """(first, last) source lines of every Warp kernel/function in ``path``, decorators included."""
    tree = ast.parse((ROOT / path).read_text(encoding="utf-8"))
    spans = []
    for node in ast.walk(tree):
        if is_warp_function(node):
            assert isinstance(node, ast.FunctionDef)
            first = min([node.lineno] + [d.lineno for d in node.decorator_list])
            spans.append((first, node.end_lineno or node.lineno))
    return tuple(spans)


def host_errors(report: str) -> tuple[list[str], int]:
    """The lines of mypy's ``report`` that are errors outside Warp kernels (with their notes), and the
    number of errors dropped because they lie inside one."""
    kept: list[str] = []
    dropped = 0
    keep_notes = False
    for line in report.splitlines():
        m = ERROR.match(line)
        if m:
            inside = any(a <= int(m["line"]) <= b for a, b in warp_spans(m["path"]))
            dropped += inside
            keep_notes = not inside
            if not inside:
                kept.append(line)
        elif ": note: " in line and keep_notes:
            kept.append(line)
    return kept, dropped


def _is_plain_any(node: ast.expr | None) -> bool:
    """Whether an annotation is ``Any`` on its own (or ``Any | None``, ``Optional[Any]``, the string
    ``"Any"``): the annotation then says nothing. ``dict[str, Any]``, ``list[Any]`` and ``Callable[..., Any]``
    are not counted: they still name the container."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        try:
            node = ast.parse(node.value, mode="eval").body
        except SyntaxError:
            return False
    if isinstance(node, ast.Name):
        return node.id == "Any"
    if isinstance(node, ast.Attribute):
        return node.attr == "Any" and ast.unparse(node.value) == "typing"
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.BitOr):
        none = [isinstance(side, ast.Constant) and side.value is None for side in (node.left, node.right)]
        return (none[1] and _is_plain_any(node.left)) or (none[0] and _is_plain_any(node.right))
    if isinstance(node, ast.Subscript) and ast.unparse(node.value) in ("Optional", "typing.Optional"):
        return _is_plain_any(node.slice)
    return False


def plain_any(path: Path) -> list[str]:
    """The plain-Python annotations of ``path`` that are ``Any`` alone, as ``"file:line: what"``.

    Counted: a function's parameters and return, and annotated assignments (``x: Any = ...``). Not counted:
    everything inside ``@wp.kernel``/``@wp.func`` functions (there ``Any`` is Warp's generic type), and
    ``*args: Any`` / ``**kwargs: Any`` (they annotate each element of a pass-through, as ``dict[str, Any]``
    does a heterogeneous dict).
    """
    rel = path.relative_to(ROOT) if path.is_absolute() and path.is_relative_to(ROOT) else path
    found: list[str] = []

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if is_warp_function(child):
                continue
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                a = child.args
                for arg in a.posonlyargs + a.args + a.kwonlyargs:
                    if _is_plain_any(arg.annotation):
                        found.append(f"{rel}:{arg.lineno}: {child.name}({arg.arg}: Any)")
                if _is_plain_any(child.returns):
                    found.append(f"{rel}:{child.lineno}: {child.name}() -> Any")
            elif isinstance(child, ast.AnnAssign) and _is_plain_any(child.annotation):
                found.append(f"{rel}:{child.lineno}: {ast.unparse(child.target)}: Any")
            visit(child)

    visit(ast.parse(path.read_text(encoding="utf-8")))
    return found


def all_plain_any() -> list[str]:
    """:func:`plain_any` over every module of ``pliant/``."""
    return [hit for path in sorted((ROOT / "pliant").rglob("*.py")) for hit in plain_any(path)]


def main() -> int:
    if "--any" in sys.argv[1:]:
        hits = all_plain_any()
        print("\n".join([*hits, f"{len(hits)} plain-Python Any annotations in pliant/"]))
        return 0
    from mypy import api

    os.chdir(ROOT)  # the configuration's `files` and the reported paths are relative to the repository
    stdout, stderr, status = api.run(["--config-file", str(ROOT / "pyproject.toml"), "--no-error-summary"])
    if status not in (0, 1):  # 2: mypy itself failed (bad configuration, crash)
        sys.stderr.write(stdout + stderr)
        return status
    kept, dropped = host_errors(stdout)
    errors = sum(" error: " in k for k in kept)
    print("\n".join([*kept, f"mypy: {errors} errors in host code ({dropped} inside Warp kernels ignored)"]))
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
