"""Host solves run BLAS on one thread (pliant._blas): small calls that a thread pool only slows down."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.sparse.linalg  # noqa: F401  (both BLAS libraries loaded before the counts)
from threadpoolctl import threadpool_info, threadpool_limits

import pliant as pl
from pliant._blas import single_threaded


def _blas_threads() -> list[int]:
    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


def test_single_threaded_limits_blas_inside_and_restores_it_after():
    if not _blas_threads():
        pytest.skip("no BLAS library reports its threads here")
    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        with single_threaded():
            assert _blas_threads() == [1] * len(before)
        assert _blas_threads() == before


def test_implicit_step_minimises_with_one_blas_thread(monkeypatch):
    """ForceSolver's implicit step calls its minimiser inside the limit (L-BFGS here)."""
    import pliant.solvers.minimizers._minimize as mz

    if not _blas_threads():
        pytest.skip("no BLAS library reports its threads here")
    seen = []
    original = mz.MINIMIZERS["lbfgs"].minimize

    def spy(*args, **kwargs):
        seen.append(_blas_threads())
        return original(*args, **kwargs)

    monkeypatch.setitem(mz.MINIMIZERS, "lbfgs", dataclasses.replace(mz.MINIMIZERS["lbfgs"], minimize=spy))
    b = pl.ModelBuilder()
    b.add_soft_box(cells=(2, 2, 2), size=(0.2, 0.2, 0.2), origin=(0.0, 0.5, 0.0), density=500.0, E=1e4)
    m = b.finalize(device="cpu", dtype="float64")
    solver = pl.solvers.ForceSolver(
        m,
        [pl.energies.NeoHookean(), pl.energies.Gravity()],
        pl.integrators.BackwardEuler(),
        minimizer={"method": "lbfgs"},
    )
    with threadpool_limits(limits=2, user_api="blas"):
        s0, s1 = m.state(), m.state()
        solver.step(s0, s1, None, 1 / 60)
    assert seen and all(t == [1] * len(t) for t in seen), seen
    assert np.all(np.isfinite(s1.particle_q.numpy()))
