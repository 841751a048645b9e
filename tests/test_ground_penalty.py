"""The ground penalty that implicit solvers minimise with: derivatives, and no crushed elements on landing."""

from __future__ import annotations

import numpy as np

import pliant as pl
from tests.helpers import energy_fd_check


def _model() -> pl.Model:
    b = pl.ModelBuilder()
    rng = np.random.default_rng(3)
    pts = rng.uniform(-0.05, 0.05, size=(12, 3))
    b.add_particles(pts, rng.uniform(0.1, 1.0, 12), radius=0.01)
    b.add_ground(height=0.0)
    return b.finalize(device="cpu", dtype="float64")


def test_ground_penalty_derivatives_match_finite_differences():
    """∇E and ∇²E of GroundPenalty equal central differences of E (float64, 1e-6 relative)."""
    m = _model()
    x = m.particle_q_np.copy()
    assert np.sum(x[:, 1] < 0.01) >= 3, "the test needs penetrating particles"
    g, g_fd, H, H_fd = energy_fd_check(m, pl.energies.GroundPenalty(1e4), x)
    np.testing.assert_allclose(g, g_fd, rtol=1e-6, atol=1e-6 * np.abs(g).max())
    np.testing.assert_allclose(H, H_fd, rtol=1e-5, atol=1e-5 * np.abs(H).max())
    assert np.abs(g).max() > 0, "no particle penetrates: the check would be vacuous"


def test_force_solver_adds_ground_penalty_for_implicit_integrators_only():
    """BackwardEuler gets a GroundPenalty term automatically; SymplecticEuler does not."""
    m = _model()
    implicit = pl.solvers.ForceSolver(m, pl.energies.mass_spring(), pl.integrators.BackwardEuler())
    explicit = pl.solvers.ForceSolver(m, pl.energies.mass_spring(), pl.integrators.SymplecticEuler())
    assert sum(isinstance(e, pl.energies.GroundPenalty) for e in implicit.energies) == 1
    assert not any(isinstance(e, pl.energies.GroundPenalty) for e in explicit.energies)


def test_implicit_fem_box_lands_without_crushed_elements():
    """A neo-Hookean box landing in one backward-Euler step per frame keeps every det F above 0.3."""
    scene = pl.scene.build_scene(pl.scene.load_scene("soft_box_fem"))
    x = scene.simulator().run(40, progress=False).x
    tets = scene.model.tet_indices_np

    def vol(X):
        e = [X[:, tets[:, k]] - X[:, tets[:, 0]] for k in (1, 2, 3)]
        return np.linalg.det(np.stack(e, axis=-1))

    ratio = vol(x) / vol(x[:1])
    assert ratio.min() > 0.3, f"an element was crushed to det F = {ratio.min():.3g}"
    assert x[-1, :, 1].min() >= 0.0, "the box went through the ground"


def test_explicit_step_with_a_ground_penalty_bounces_elastically_with_coulomb_friction():
    """A GroundPenalty an explicit integrator is given is its contact: no projection after the step (the
    penalty is conservative, so a ball dropped 4 cm bounces back to 4 cm, where the projection with zero
    restitution stops it dead), and friction for the penalty's impulse, which takes μ times the normal
    impulse 2 m v_n off the tangential speed (closed form: Δv_t = 2 μ √(2 g h))."""
    g, h, mu, v0 = 9.81, 0.04, 0.2, 1.0

    def drop(penalty: bool) -> tuple[float, float]:
        b = pl.ModelBuilder(gravity=(0.0, -g, 0.0))
        b.add_particles([[0.0, h + 0.01, 0.0]], [0.5], velocities=[[v0, 0.0, 0.0]], radius=0.01)
        b.add_ground(0.0, friction=mu, restitution=0.0)
        m = b.finalize(device="cpu", dtype="float64")
        energies = [pl.energies.Gravity()] + ([pl.energies.GroundPenalty(1e6)] if penalty else [])
        solver = pl.solvers.ForceSolver(m, energies, pl.integrators.SymplecticEuler())
        s0, s1 = m.state(), m.state()
        top_after_bounce, bounced = 0.0, False
        for _ in range(2000):  # 0.2 s: the fall takes 0.09 s, the rise as long again
            solver.step(s0, s1, None, 1e-4)
            s0, s1 = s1, s0
            y, vy = s0.particle_q.numpy()[0, 1], s0.particle_qd.numpy()[0, 1]
            bounced = bounced or vy > 0
            if bounced:
                top_after_bounce = max(top_after_bounce, y - 0.01)
        return top_after_bounce, float(s0.particle_qd.numpy()[0, 0])

    top, vt = drop(penalty=True)
    assert abs(top - h) < 0.02 * h, top  # elastic: back to its height (no projection, no restitution)
    np.testing.assert_allclose(vt, v0 - 2 * mu * np.sqrt(2 * g * h), rtol=0.02)
    top_projected, _ = drop(penalty=False)
    assert top_projected < 0.1 * h  # restitution 0 with the projection: it stays down
