"""The banded solve's particle order and its cost: plain NumPy/SciPy on the Hessian's pattern, below the
workspace (which caches the order) and the minimiser options (which choose the band solve by its cost), so
neither imports the solve itself (:mod:`pliant.solvers.minimizers._band`)."""

from __future__ import annotations

import numpy as np


def band_order(n: int, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, int]:
    """Reverse Cuthill–McKee order of the n-node graph (``rows``, ``cols``: its edges, both directions) and
    the half-bandwidth in nodes of the matrix in that order.

    Returns:
        (perm, width): node ``perm[k]`` goes to position k; max |position(i) − position(j)| over the edges.
    """
    import scipy.sparse as sp
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    if n == 0:
        return np.zeros(0, dtype=np.int64), 0
    adj = sp.csr_matrix((np.ones(rows.size, dtype=np.int8), (rows, cols)), shape=(n, n))
    perm = np.asarray(reverse_cuthill_mckee(adj, symmetric_mode=True), dtype=np.int64)
    inv = np.empty_like(perm)
    inv[perm] = np.arange(n)
    width = int(np.abs(inv[rows] - inv[cols]).max()) if rows.size else 0
    return perm, width


def band_work(n: int, width: int) -> int:
    """Multiply-adds of one banded LDLᵀ factorisation: N (b + 1)² / 2 with N = 3n unknowns and scalar
    half-bandwidth b = 3·width + 2."""
    b = 3 * width + 2
    return 3 * n * (b + 1) * (b + 1) // 2


__all__ = ["band_order", "band_work"]
