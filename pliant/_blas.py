"""BLAS on one thread for pliant's host linear algebra.

The host solves of an implicit step (L-BFGS's two-loop recursion and triangular solves, Newton's sparse LU,
the adjoint's and the static solver's) make many small BLAS calls (dot products and triangular solves of
10⁴-10⁵ entries). A multithreaded OpenBLAS hands each of them to its thread pool, and waking the pool costs
more than the call: on the 20³ soft box an L-BFGS dot product took 1 ms, not 10 µs, and a step ran 2.4×
slower with the second core busy (docs/design.md, "BLAS threads"). :func:`single_threaded` limits BLAS to
one thread for the ``with`` block only, through ``threadpoolctl``, so user code keeps its own setting.
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
