"""The minimiser registry's contract (``pliant.solvers.minimizers.MINIMIZERS``), walked entry by entry: a
minimiser added to the registry is checked here without a line of its own.

* every entry reaches the same minimum of the incremental potential on the same problems (a pinned spring
  cloth pushed by a Control force, a free neo-Hookean box shaken out of rest), and says it converged;
* an entry that keeps its decisions on the device reads nothing back from it in a step
  (tests/host_reads.py counts the calls that would be reads on a GPU, on any device);
* for any settings exactly one entry is chosen, and a problem with barrier contact goes to the entry that
  takes it.
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from host_reads import HostReads

import pliant as pl
from pliant.solvers.minimizers import MINIMIZERS, MinimizerOptions, choose
from pliant.solvers.minimizers._options import LINEAR_SOLVERS

NEWTON_TOL = 1e-9  # m/s: tight, so that the minima agree far below the motion of the step
H = 1.0 / 120.0  # s


class Problem:
    """A PotentialProblem and nothing more: what a minimiser may read (model, energies, control) and write
    (last_stats, its cache)."""

    def __init__(self, model: pl.Model, energies: list, control: pl.Control | None = None) -> None:
        self.model = model
        self.energies = energies
        self.control = control
        self.last_stats = None
        self.minimizer_cache = pl.solvers.minimizers.MinimizerCache()


def _cloth() -> Problem:
    b = pl.ModelBuilder(gravity=(0.0, -9.81, 0.0))
    b.add_cloth_grid(
        nx=5, ny=5, size=1.0, mass=0.2, stiffness=500.0, damping=0.0, pin="top-corners", plane="xy"
    )
    model = b.finalize(device="cpu", dtype="float64")
    control = pl.Control(model)
    control.particle_f.assign(np.tile([0.5, 0.0, 0.2], (model.particle_count, 1)))
    return Problem(model, pl.energies.mass_spring(dashpots=False), control)


def _box() -> Problem:
    b = pl.ModelBuilder()
    b.add_soft_box(
        cells=(2, 2, 2), size=(0.2, 0.2, 0.2), origin=(0.0, 0.15, 0.0), density=500.0, E=2e4, nu=0.3
    )
    model = b.finalize(device="cpu", dtype="float64")
    return Problem(model, [pl.energies.NeoHookean(), pl.energies.Gravity()])


PROBLEMS = {"cloth": _cloth, "box": _box}


def _start(model: pl.Model, seed: int = 3) -> tuple[wp.array, wp.array, wp.array]:
    """x_ref, v_ref (free particles shaken out of rest) and the inertial prediction x̃ = x + h v."""
    rng = np.random.default_rng(seed)
    free = (model.particle_inv_mass.numpy() > 0)[:, None]
    x = model.particle_q.numpy() + 0.002 * rng.standard_normal((model.particle_count, 3)) * free
    v = 0.3 * rng.standard_normal((model.particle_count, 3)) * free
    arr = lambda a: wp.array(a, dtype=model.vec3, device=model.device)  # noqa: E731
    return arr(x), arr(v), arr(x + H * v)


def _minimum(name: str, problem: Problem, steps: int = 1) -> tuple[np.ndarray, object]:
    x_ref, v_ref, x_tilde = _start(problem.model)
    x_out = wp.clone(x_ref)
    stats = None
    for _ in range(steps):
        stats = MINIMIZERS[name].minimize(
            problem,
            0.0,
            H,
            x_tilde,
            x_ref,
            v_ref,
            x_out,
            {"newton_tol": NEWTON_TOL},
            minimizer=MinimizerOptions(),
        )
    return x_out.numpy(), stats


@pytest.mark.parametrize("kind", list(PROBLEMS))
def test_every_minimizer_reaches_the_same_minimum(kind: str) -> None:
    """Each entry's x_out agrees with the host Newton's to 1e-9 m (the step moves the particles by ~1e-3 m),
    and each says it converged."""
    reference, _ = _minimum("newton", PROBLEMS[kind]())
    x_ref, _, _ = _start(PROBLEMS[kind]().model)
    moved = np.abs(reference - x_ref.numpy()).max()
    assert moved > 1e-4, f"{kind}: the step barely moves ({moved:.3g} m); the check would be vacuous"
    for name in MINIMIZERS:
        x, stats = _minimum(name, PROBLEMS[kind]())
        assert stats.converged, f"{name} on {kind}: {stats}"
        err = np.abs(x - reference).max()
        assert err < 1e-9, f"{name} on {kind}: {err:.3g} m from the host Newton's minimum"


@pytest.mark.parametrize("name", [n for n, m in MINIMIZERS.items() if m.device_decisions])
def test_device_minimizers_read_nothing_back(name: str) -> None:
    """A minimiser that keeps its decisions on the device: after a first step (modules load, buffers are
    allocated) a step makes no host read (no array.numpy, no copy to the host, no synchronisation)."""
    problem = _box()
    x_ref, v_ref, x_tilde = _start(problem.model)
    x_out = wp.clone(x_ref)
    run = MINIMIZERS[name].minimize
    args = (problem, 0.0, H, x_tilde, x_ref, v_ref, x_out, {"newton_tol": NEWTON_TOL})
    run(*args, minimizer=MinimizerOptions())
    with HostReads() as reads:
        stats = run(*args, minimizer=MinimizerOptions())
    assert reads.counts["read"] == 0, f"{name}: host reads in a step: {reads.report()}"
    assert stats.converged  # read after the count


def test_exactly_one_minimizer_is_chosen() -> None:
    """For every method and linear solver on both problems one entry's ``chosen`` holds, and ``choose``
    names it; with a barrier energy the step goes to the entry that takes barrier contact."""
    problems = [f() for f in PROBLEMS.values()]
    for method in ("newton", "lbfgs", "auto"):
        for lin in LINEAR_SOLVERS:
            mz = MinimizerOptions(method=method, linear_solver=lin)
            for p in problems:
                takers = [n for n, m in MINIMIZERS.items() if m.chosen(p, mz)]
                assert len(takers) == 1, f"method={method!r} linear_solver={lin!r}: {takers}"
                assert choose(p, mz) == takers[0]

    class Barrier:
        feasible_start = True

    barrier = Problem(problems[0].model, [*problems[0].energies, Barrier()])
    taker = choose(barrier, MinimizerOptions(method="lbfgs"))
    assert MINIMIZERS[taker].barrier and taker == "newton"
