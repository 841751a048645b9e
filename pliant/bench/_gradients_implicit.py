"""Gradient cost through implicit steps: backward time / forward time and peak memory (not a timed test).

Scene: the soft box of :mod:`pliant.bench._fem` (0.5 m cube, ρ = 1000 kg/m³, neo-Hookean E = 1e5 Pa,
ν = 0.3, 0.1 m above the ground), n³ cells (default 6), float64 on the CPU, backward Euler by L-BFGS (the FEM
rows' tolerance), ground as the penalty inside the potential (no post-step friction), ``frames`` steps of
1/60 s recorded on a ``wp.Tape`` with one State per frame. The loss is the final centre-of-mass height;
``tape.backward`` gives its gradient w.r.t. the per-tet μ, λ and the initial state through one adjoint
solve per step (:mod:`pliant.solvers.minimizers._adjoint`).

Figures: ``forward_s`` (recorded forward, the minimisations with the tape paused), ``plain_forward_s``
(the same rollout without a tape, ``requires_grad=False``), ``backward_s``, ``ratio`` = backward / forward,
``peak_rss_mb`` (the process's peak resident memory after the backward, CPU) and ``tape_mb`` (the bytes of
the arrays the tape keeps: states and per-step work arrays with their gradients).

``python -m pliant.bench._gradients_implicit`` prints the row as JSON.
"""

from __future__ import annotations

import json
import resource
import time
from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

if TYPE_CHECKING:
    from ..model import Model


def _model(n: int, requires_grad: bool) -> Model:
    from ..model import ModelBuilder
    from ._fem import DENSITY, DROP, POISSON, SIDE, YOUNG

    b = ModelBuilder(gravity=(0.0, -9.81, 0.0))
    b.add_soft_box(
        cells=(n, n, n),
        size=(SIDE, SIDE, SIDE),
        origin=(0.0, DROP + 0.5 * SIDE, 0.0),
        density=DENSITY,
        E=YOUNG,
        nu=POISSON,
    )
    b.add_ground(0.0, friction=0.5, restitution=0.0)
    return b.finalize(device="cpu", dtype="float64", requires_grad=requires_grad)


def _rollout(n: int, frames: int, record: bool) -> tuple[float, float, float, int]:
    """(forward s, backward s, loss, tape bytes) of one rollout; backward 0 without ``record``."""
    from ..energies import Gravity, GroundPenalty, NeoHookean
    from ..integrators import BackwardEuler
    from ..solvers import ForceSolver
    from ._fem import FRAME_DT, LBFGS_TOL

    model = _model(n, record)
    solver = ForceSolver(
        model,
        energies=[NeoHookean(), Gravity(), GroundPenalty()],
        integrator=BackwardEuler(newton_tol=LBFGS_TOL["float64"], project_psd=True),
        contact=False,
        minimizer={"method": "lbfgs"},
    )
    states = [model.state() for _ in range(frames + 1)]
    weight: wp.array = wp.array(
        np.tile([0.0, 1.0 / model.particle_count, 0.0], (model.particle_count, 1)),
        dtype=model.vec3,
        device=model.device,
    )
    loss = wp.zeros(1, dtype=model.scalar, device=model.device, requires_grad=True)
    tape = wp.Tape()
    start = time.perf_counter()
    if record:
        with tape:
            for k in range(frames):
                solver.step(states[k], states[k + 1], None, FRAME_DT)
            wp.launch(_dot, model.particle_count, [states[-1].particle_q, weight, loss], device=model.device)
    else:
        for k in range(frames):
            solver.step(states[k], states[k + 1], None, FRAME_DT)
        wp.launch(_dot, model.particle_count, [states[-1].particle_q, weight, loss], device=model.device)
    forward = time.perf_counter() - start
    backward = 0.0
    held = 0
    if record:
        start = time.perf_counter()
        tape.backward(loss)
        backward = time.perf_counter() - start
        held = sum(2 * a.capacity for a in tape.gradients)
        if not np.isfinite(model.tet_mu.grad.numpy()).all():
            raise RuntimeError("non-finite gradient in the benchmark rollout")
    return forward, backward, float(loss.numpy()[0]), held


@wp.kernel
def _dot(x: wp.array(dtype=Any), w: wp.array(dtype=Any), out: wp.array(dtype=Any)):
    i = wp.tid()
    wp.atomic_add(out, 0, wp.dot(x[i], w[i]))


def soft_box_gradient(n: int = 6, frames: int = 60, quick: bool = False) -> dict:
    """Backward / forward time ratio and memory of a recorded L-BFGS rollout of the n³-cell soft box."""
    from .. import _warp

    _warp.init()
    if quick:
        n, frames = 2, 5
    _rollout(2, 2, True)  # compile everything once, outside the timings
    plain, _, plain_loss, _ = _rollout(n, frames, False)
    forward, backward, loss, held = _rollout(n, frames, True)
    wp.synchronize()
    return {
        "scene": f"soft_box {n}^3 cells, {frames} frames",
        "solver": "ForceSolver",
        "integrator": "BackwardEuler (L-BFGS)",
        "device": "cpu",
        "dtype": "float64",
        "particles": (n + 1) ** 3,
        "forward_s": round(forward, 4),
        "plain_forward_s": round(plain, 4),
        "backward_s": round(backward, 4),
        "ratio": round(backward / forward, 3) if forward > 0 else float("nan"),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1),
        "tape_mb": round(held / 2**20, 2),
        "loss_recorded_minus_plain": loss - plain_loss,
    }


BENCHMARKS = {"gradient_implicit_soft_box": soft_box_gradient}


if __name__ == "__main__":
    print(json.dumps(soft_box_gradient()))
