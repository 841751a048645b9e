"""BLAS on one thread for pliant's host linear algebra.

The host solves of an implicit step (L-BFGS's two-loop recursion and triangular solves, Newton's sparse LU,
the adjoint's and the static solver's) make many small BLAS calls (dot products and triangular solves of
10⁴-10⁵ entries). A multithreaded OpenBLAS hands each of them to its thread pool, and when the other cores
are busy, waiting for a pool thread costs more than the call. Measured on the 20³ soft box (ImplicitMidpoint,
L-BFGS, 2-core box): with the other core running a busy loop a simulated second took 11.9-14.6 s, 8.8-9.6 s
on one BLAS thread; with the test suite running beside it 4.3 s against 1.8 s for 12 frames (an L-BFGS dot
product took 1 ms instead of 10 µs). On a quiet machine, or pinned to one core, the two are equal.
:func:`single_threaded` limits BLAS to one thread for the ``with`` block only, through ``threadpoolctl``,
so user code keeps its own setting.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

_controller: Any = None


@contextlib.contextmanager
def single_threaded() -> Iterator[None]:
    """Run the block with every loaded BLAS library on one thread (restored afterwards)."""
    global _controller
    if _controller is None:
        import scipy.sparse.linalg  # noqa: F401  (SciPy's BLAS is a library of its own: loaded before the scan)
        from threadpoolctl import ThreadpoolController

        # Scanning the loaded libraries costs milliseconds: once per process, after NumPy's and SciPy's BLAS
        # (the host solves' only users) are loaded.
        _controller = ThreadpoolController()
    with _controller.limit(limits=1, user_api="blas"):
        yield
