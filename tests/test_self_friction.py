"""Self-contact Coulomb friction in both regimes, for every solver family with self-contact (issue 39).

A 10 cm soft box rests on a pinned slab (two triangles of the same model, 10 m wide) with gravity tilted so
that the slab is an incline at tan θ = 0.5, as the ground's incline tests (tests/test_friction_incline.py):
the same figures, with the slab's self-contact friction μ instead of the ground's. Coulomb's law: the box
slides at a = g (sin θ − μ cos θ) (the slope of its centre's velocity over 0.3-1.5 s within 2 %) for
μ = 0.3 and 0.45, and travels at most 1 mm over 1.5 s for μ = 0.6. The projection families use
:class:`pliant.collision.SelfCollision` (point–triangle contact, thickness 5 mm); the barrier path is the
implicit ForceSolver with :class:`pliant.energies.BarrierContact` (self_contact, lagged self_friction).
"""

from __future__ import annotations

import numpy as np
import pytest
from test_friction_incline import DURATION, FEM_FAMILIES, SIDE, TILTED, _check

import pliant as pl
from pliant.geometry import surface_from_tets

#: SelfCollision's thickness h [m]; the barrier's d̂ [m].
H, DHAT = 0.005, 1e-3
SLAB = 5.0  # half width [m]: the box slides 2 m in 1.5 s at μ = 0.3


def _model(gap: float, fem: bool) -> pl.Model:
    """The box (FEM or mass-spring, as the ground's incline tests) with its bottom ``gap`` [m] above a
    pinned slab at y = 0 (particles 0-3, triangles 0-1)."""
    b = pl.ModelBuilder(gravity=TILTED)
    s = SLAB
    slab = b.add_particles([[-s, 0, -s], [s, 0, -s], [s, 0, s], [-s, 0, s]], 1.0, radius=0.0, name="slab")
    b.add_triangles(np.array([[0, 2, 1], [0, 3, 2]]) + slab)
    b.pin(np.arange(slab, slab + 4))
    extra = dict(E=1e6, nu=0.3, stiffness=1.0, damping=5.0) if fem else dict(stiffness=2e4, damping=0.5)
    b.add_soft_box(
        cells=(1,) * 3, size=(SIDE,) * 3, origin=(0.0, 0.5 * SIDE + gap, 0.0), radius=0.001, **extra
    )
    return b.finalize(device="cpu", dtype="float64")


def _run(model: pl.Model, solver, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Times [s], the box's centre's travel [m] and velocity [m/s] down the slope (x), 60 samples a second
    (the pinned slab left out)."""
    s0, s1 = model.state(), model.state()
    m = model.particle_mass.numpy() * (model.particle_inv_mass.numpy() > 0)
    n, every = int(round(DURATION / dt)), max(1, int(round(1 / (60 * dt))))
    x0 = (m @ s0.particle_q.numpy())[0] / m.sum()
    ts, xs, vs = [], [], []
    for k in range(n):
        solver.step(s0, s1, None, dt)
        s0, s1 = s1, s0
        if (k + 1) % every == 0:
            ts.append((k + 1) * dt)
            xs.append((m @ s0.particle_q.numpy())[0] / m.sum() - x0)
            vs.append((m @ s0.particle_qd.numpy())[0] / m.sum())
    return np.array(ts), np.array(xs), np.array(vs)


def _solver(family: str, model: pl.Model, mu: float):
    sc = [pl.collision.SelfCollision(model, thickness=H, friction=mu, particles=False)]
    fem = [pl.energies.NeoHookean(), pl.energies.Springs(), pl.energies.Dashpots(), pl.energies.Gravity()]
    if family == "symplectic_euler":
        return pl.solvers.ForceSolver(model, fem, pl.integrators.SymplecticEuler(), collisions=sc), 1 / 2400
    if family == "backward_euler":
        return pl.solvers.ForceSolver(model, fem, pl.integrators.BackwardEuler(), collisions=sc), 1 / 600
    if family == "fast_mass_spring":
        return pl.solvers.FastMassSpring(model, collisions=sc), 1 / 2400
    if family == "xpbd":
        return pl.solvers.XPBD(model, iterations=10, collisions=sc), 1 / 600
    assert family == "barrier"
    # The barrier's points are the surface's vertices: the slab's triangles and the box's boundary.
    tris = np.concatenate([model.tri_indices.numpy().reshape(-1, 3), surface_from_tets(model.tet_indices_np)])
    bar = pl.energies.BarrierContact(
        dhat=DHAT, ground=False, self_contact=True, triangles=tris, self_friction=mu
    )
    return pl.solvers.ForceSolver(model, [*fem, bar], pl.integrators.BackwardEuler()), 1 / 600


FAMILIES = ("symplectic_euler", "backward_euler", "fast_mass_spring", "xpbd", "barrier")
FAST = {"symplectic_euler", "fast_mass_spring", "xpbd"}


@pytest.mark.parametrize("mu", [0.3, 0.45, 0.6])
@pytest.mark.parametrize(
    "family", [f if f in FAST else pytest.param(f, marks=pytest.mark.slow) for f in FAMILIES]
)
def test_a_box_on_a_pinned_slab_slides_at_coulombs_rate_or_rests(family: str, mu: float):
    """Slides at g(sin θ − μ cos θ) (2 %) for μ < tan θ = 0.5, rests (≤ 1 mm over 1.5 s) for μ = 0.6."""
    gap = 0.95 * DHAT if family == "barrier" else H  # the barrier holds the box at 0.95 d̂
    model = _model(gap, fem=family in FEM_FAMILIES or family == "barrier")
    solver, dt = _solver(family, model, mu)
    _check(mu, *_run(model, solver, dt))
