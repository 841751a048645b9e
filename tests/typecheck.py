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
KERNEL_DECORATORS = ("wp.kernel", "wp.func", "warp.kernel", "warp.func")


def is_warp_function(node: ast.AST) -> bool:
    """Whether ``node`` is a function decorated with ``@wp.kernel`` or ``@wp.func`` (with or without
    arguments, e.g. ``@wp.kernel(enable_backward=False)``)."""
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


def main() -> int:
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
