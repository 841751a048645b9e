"""tests/typecheck.py keeps mypy's errors in host code and drops only those inside Warp kernels/functions."""

from __future__ import annotations

import typecheck

SOURCE = """import warp as wp

@wp.kernel(enable_backward=False)
def k(x: wp.array(dtype=float)):
    i, j = wp.tid()

@wp.func
def f(a: float):
    return a

def host(x: int) -> str:
    return x
"""


def test_errors_inside_kernels_are_dropped_and_host_errors_kept(tmp_path):
    """Errors on a kernel's decorator, signature or body and a @wp.func's are dropped; a host one is kept."""
    path = tmp_path / "mod.py"
    path.write_text(SOURCE)
    report = "\n".join(
        [
            f"{path}:3: error: decorator  [misc]",
            f"{path}:4: error: Invalid type comment or annotation  [valid-type]",
            f"{path}:4: note: Cannot use a function call in a type annotation",
            f'{path}:5: error: "int" object is not iterable  [misc]',
            f"{path}:9: error: in a func  [misc]",
            f'{path}:12: error: Incompatible return value type (got "int", expected "str")  [return-value]',
            f"{path}:12: note: a note of the kept error",
        ]
    )
    kept, dropped = typecheck.host_errors(report)
    assert dropped == 4, kept
    assert kept == [
        f'{path}:12: error: Incompatible return value type (got "int", expected "str")  [return-value]',
        f"{path}:12: note: a note of the kept error",
    ]
