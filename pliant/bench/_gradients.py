"""Gradient-cost benchmarks: a differentiable rollout's time and memory against the forward run.

Scene: the cloth drape of :mod:`pliant.bench._mass_spring` (n × n cells, pinned at two corners) for 60
frames of 1/60 s with symplectic Euler substeps, loss = Σ y of the final positions. Figures:

* ``forward_s``: the plain forward run (model without gradients: the fast, replayed path);
* ``forward_recorded_s``: the same run on a ``requires_grad`` model, without a tape (fresh arrays per step);
* ``gradient_s``: :func:`pliant.diff.rollout` with one checkpoint per frame — forward, recomputation of each
  frame under a tape and backward — and ``backward_over_forward`` = (gradient_s − forward_recorded_s) /
  forward_s, the cost of the gradient in units of a plain forward run (goal ≤ 3 on one CPU core);
* ``peak_rss_mb``: the process's peak resident memory after the rollout.
"""

from __future__ import annotations

import resource
import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from .._time import substep_dt
from ._common import print_rows

if TYPE_CHECKING:
    import warp as wp

    from ..model import Model, State
    from ..solvers import Solver

FRAMES = 60
FRAME_DT = 1.0 / 60.0


def _loss_kernel() -> wp.Kernel:
    import warp as wp

    @wp.kernel
    def height_sum(x: wp.array(dtype=Any), out: wp.array(dtype=Any)):
        i = wp.tid()
        wp.atomic_add(out, 0, x[i][1])

    return height_sum


def _bench(n: int, substeps: int, implicit: bool = False) -> Callable[..., dict]:
    """The row for an n × n cloth: ForceSolver + symplectic Euler with ``substeps`` per frame, or
    (``implicit``) FastMassSpring's Baraff–Witkin step, whose gradient is the adjoint of its linear solve."""

    def bench(device: str | None = "cpu", quick: bool = False) -> dict:
        import warp as wp

        from .. import diff
        from ..integrators import SymplecticEuler
        from ..solvers import FastMassSpring, ForceSolver
        from ._mass_spring import cloth_drape_model

        def make_solver(model: Model) -> Solver:
            if implicit:
                return FastMassSpring(model, method="implicit", cg_iterations=40, damping_rate=1.0)
            return ForceSolver(model, integrator=SymplecticEuler(), damping_rate=1.0)

        cells, frames = (8, 3) if quick else (n, FRAMES)
        dt = substep_dt(FRAME_DT, substeps)
        kernel = _loss_kernel()

        def loss(state: State) -> wp.array:
            scalar = wp.float64 if state.particle_q.dtype == wp.vec3d else wp.float32
            out = wp.zeros(1, dtype=scalar, device=state.particle_q.device)
            out.requires_grad = True
            wp.launch(kernel, state.particle_q.shape[0], [state.particle_q, out], device=out.device)
            return out

        def forward(model: Model) -> float:
            solver = make_solver(model)
            s0, s1 = model.state(), model.state()
            solver.step(s0, s1, None, dt)  # warm-up (compilation)
            wp.synchronize_device(model.device)
            t0 = time.perf_counter()
            for _ in range(frames * substeps):
                solver.step(s0, s1, None, dt)
                s0, s1 = s1, s0
            wp.synchronize_device(model.device)
            return time.perf_counter() - t0

        def timed_recorded(model: Model) -> float:
            solver = make_solver(model)
            s = model.state()
            t0 = time.perf_counter()
            for _ in range(frames * substeps):
                nxt = model.state()
                solver.step(s, nxt, None, dt)
                s = nxt
            wp.synchronize_device(model.device)
            return time.perf_counter() - t0

        plain = cloth_drape_model(cells, device=device, dtype="float64", damping=0.01)
        t_fwd = forward(plain)
        model = cloth_drape_model(cells, device=device, dtype="float64", damping=0.01)
        model = _with_grad(model)
        t_rec = timed_recorded(model)
        solver = make_solver(model)
        # Warm-up: compiles the adjoint kernels (not part of the gradient's cost).
        diff.rollout(model, solver, loss, frames=1, substeps=1, dt=dt, params=["spring_stiffness"])
        t0 = time.perf_counter()
        res = diff.rollout(
            model, solver, loss, frames=frames, substeps=substeps, dt=dt, params=["spring_stiffness", "x0"]
        )
        wp.synchronize_device(model.device)
        t_grad = time.perf_counter() - t0
        return {
            "scene": f"cloth_drape_{cells}",
            "solver": "FastMassSpring" if implicit else "ForceSolver",
            "integrator": "BaraffWitkin" if implicit else "SymplecticEuler",
            "device": str(model.device),
            "dtype": "float64",
            "particles": model.particle_count,
            "frames": frames,
            "substeps": substeps,
            "forward_s": round(t_fwd, 3),
            "forward_recorded_s": round(t_rec, 3),
            "gradient_s": round(t_grad, 3),
            "backward_over_forward": round((t_grad - t_rec) / t_fwd, 2),
            "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1),
            "loss": res.loss,
            "grad_finite": bool(all(abs(g).max() < float("inf") for g in res.grads.values())),
        }

    return bench


def _with_grad(model: Model) -> Model:
    """``model`` rebuilt with ``requires_grad=True`` (the drape builder finalises without gradients)."""
    import dataclasses

    import warp as wp

    grads = (
        "particle_q",
        "particle_qd",
        "spring_rest_length",
        "spring_stiffness",
        "spring_damping",
        "tet_mu",
        "tet_lam",
    )
    changes: dict[str, Any] = {k: wp.clone(getattr(model, k), requires_grad=True) for k in grads}
    return dataclasses.replace(model, requires_grad=True, **changes)


BENCHMARKS: dict[str, Callable[..., dict]] = {
    "gradient_cloth_32_symplectic": _bench(32, 40),
    "gradient_cloth_32_implicit": _bench(32, 1, implicit=True),
}


if __name__ == "__main__":
    print_rows(BENCHMARKS, sys.argv[1:])
