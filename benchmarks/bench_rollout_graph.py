"""pl.diff rollouts replayed as captured graphs against launch-by-launch rollouts, side by side.

A pinned cloth (ForceSolver, symplectic Euler, float64) and L = Σ w·x_final; ∂L/∂(spring stiffness) by
``pl.diff.rollout`` with the default (captured on the second call, replayed from the third) and with
``graph=False``, interleaved round by round in one process. Prints the median wall milliseconds per rollout
of both and their ratio; every replayed result is checked equal to a direct one (the loss, bit for bit).

    python benchmarks/bench_rollout_graph.py [--rounds 7]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import warp as wp

import pliant as pl


@wp.kernel
def _weighted_sum(x: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d), out: wp.array(dtype=wp.float64)):
    i = wp.tid()
    wp.atomic_add(out, 0, wp.dot(x[i], w[i]))


def row(n: int, frames: int, substeps: int, rounds: int) -> str:
    """One cloth size: the median milliseconds per rollout, direct and replayed."""
    b = pl.ModelBuilder()
    b.add_cloth_grid(
        nx=n, ny=n, size=0.3, mass=0.05 * (n / 4) ** 2, stiffness=40.0, damping=0.02, origin=(0, 0.5, 0),
        pin="top-corners",
    )  # fmt: skip
    m = b.finalize(device="cpu", dtype="float64", requires_grad=True)
    w = wp.array(np.random.default_rng(0).normal(size=(m.particle_count, 3)), dtype=wp.vec3d)

    def loss(state: pl.State) -> wp.array:
        out = wp.zeros(1, dtype=wp.float64, requires_grad=True)
        wp.launch(_weighted_sum, state.particle_q.shape[0], [state.particle_q, w, out])
        return out

    solver = pl.solvers.ForceSolver(m, pl.energies.mass_spring(), pl.integrators.SymplecticEuler())
    kw = {"frames": frames, "substeps": substeps, "dt": 1e-3, "params": ["spring_stiffness"]}
    for _ in range(3):  # compile, warm up, capture
        pl.diff.rollout(m, solver, loss, **kw)
    times: dict[bool, list[float]] = {True: [], False: []}
    for _ in range(rounds):
        losses = []
        for graph in (None, False):
            t0 = time.perf_counter()
            res = pl.diff.rollout(m, solver, loss, graph=graph, **kw)
            times[graph is None].append(time.perf_counter() - t0)
            assert res.replayed == (graph is None)
            losses.append(res.loss)
        assert losses[0] == losses[1], "a replay differs from the direct run"
    d, r = statistics.median(times[False]), statistics.median(times[True])
    size = f"cloth {n}x{n}, {frames} frames x {substeps} substeps"
    return f"{size}: direct {d * 1e3:.1f} ms, replayed {r * 1e3:.2f} ms ({d / r:.0f}x)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=7, help="interleaved rounds (medians)")
    args = ap.parse_args()
    wp.config.quiet = True
    for n, frames, substeps in ((4, 3, 10), (16, 10, 10)):
        print(row(n, frames, substeps, args.rounds))


if __name__ == "__main__":
    main()
