"""FastMassSpring uses the spring energy's own force, dashpot and Hessian (issue 10): its steps equal the
generic path's to round-off (float64), not within a percent."""

from __future__ import annotations

import numpy as np
import warp as wp

import pliant as pl


def _rope() -> pl.Model:
    b = pl.ModelBuilder()
    b.add_rope(
        n_segments=6, length=0.6, mass=0.06, stiffness=300.0, damping=0.2, bend_stiffness=20.0, pin="none"
    )
    m = b.finalize(device="cpu", dtype="float64")
    rng = np.random.default_rng(5)
    m.particle_q.assign(m.particle_q.numpy() + 0.02 * rng.normal(size=(m.particle_count, 3)))
    m.particle_qd.assign(rng.normal(size=(m.particle_count, 3)))
    return m


def test_symplectic_step_equals_force_solver_to_round_off():
    """One fused FastMassSpring step = ForceSolver(Springs, Dashpots, Gravity; SymplecticEuler), 1e-13."""
    m = _rope()
    out = []
    for solver in (
        pl.solvers.FastMassSpring(m, method="symplectic", contact=False),
        pl.solvers.ForceSolver(m, pl.energies.mass_spring(), pl.integrators.SymplecticEuler(), contact=False),
    ):
        s0, s1 = m.state(), m.state()
        solver.step(s0, s1, None, 1e-3)
        out.append(np.concatenate([s1.particle_q.numpy(), s1.particle_qd.numpy()]))
    np.testing.assert_allclose(out[0], out[1], rtol=1e-13, atol=1e-13)


def test_implicit_step_solves_the_energies_linear_system():
    """Baraff–Witkin with converged CG solves (M + hD + h²K)Δv = h(f − hKv) built from the energies'
    Hessian blocks (Springs, PSD-projected; Dashpots' D) and forces, to 1e-10."""
    m = _rope()
    h = 5e-3
    solver = pl.solvers.FastMassSpring(m, method="implicit", cg_iterations=300, cg_tol=1e-15, contact=False)
    s0, s1 = m.state(), m.state()
    solver.step(s0, s1, None, h)
    n = m.particle_count
    x, v = s0.particle_q, s0.particle_qd

    def dense(energy, scale):
        rows, cols = energy.hessian_pattern(m)
        vals = wp.zeros(rows.shape[0], dtype=wp.mat33d)
        energy.hessian(m, x, wp.array(np.arange(rows.shape[0], dtype=np.int32)), vals, project_psd=True)
        A = np.zeros((3 * n, 3 * n))
        for r, c, blk in zip(rows, cols, vals.numpy(), strict=True):
            A[3 * r : 3 * r + 3, 3 * c : 3 * c + 3] += scale * blk
        return A

    K = dense(pl.energies.Springs(), 1.0)
    dash = pl.energies.Dashpots()
    dash.begin_step(m, x, v, h)
    hD = dense(dash, h * h)  # the Rayleigh potential's Hessian is D/h
    f = wp.zeros(n, dtype=wp.vec3d)
    force_solver = pl.solvers.ForceSolver(m, pl.energies.mass_spring(), contact=False)
    force_solver.forces(0.0, x, v, f)
    M = np.diag(np.repeat(m.particle_mass.numpy(), 3))
    vv = v.numpy().ravel()
    dv = np.linalg.solve(M + hD + h * h * K, h * (f.numpy().ravel() - h * K @ vv))
    np.testing.assert_allclose(s1.particle_qd.numpy().ravel(), vv + dv, rtol=1e-10, atol=1e-10)
