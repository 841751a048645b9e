"""Newton on the incremental potential: assembly, linear solvers, convergence, fixed particles, controls."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import pliant as pl
from pliant.solvers.minimizers import minimize_incremental_potential
from pliant.solvers.minimizers._assembly import assemble, gradient
from pliant.solvers.minimizers._problem import workspace_of
from tests.helpers import run_steps

I = pl.integrators


def _cloth(n=6, *, gravity=(0.0, -9.81, 0.0), pin="top-corners", damping=0.2, stiffness=500.0):
    b = pl.ModelBuilder(gravity=gravity)
    b.add_cloth_grid(
        nx=n, ny=n, size=1.0, mass=0.2, stiffness=stiffness, damping=damping, pin=pin, plane="xy"
    )
    return b.finalize(device="cpu", dtype="float64")


def _moving_state(model, seed=1):
    rng = np.random.default_rng(seed)
    s = model.state()
    free = model.particle_inv_mass.numpy() > 0
    x = model.particle_q.numpy() + 0.001 * rng.standard_normal((model.particle_count, 3)) * free[:, None]
    v = 0.5 * rng.standard_normal((model.particle_count, 3)) * free[:, None]
    s.particle_q.assign(x)
    s.particle_qd.assign(v)
    return s


def _one_step(model, state, integ, energies=None, control=None, minimizer=None):
    solver = pl.solvers.ForceSolver(
        model,
        energies=pl.energies.mass_spring() if energies is None else energies,
        integrator=integ,
        minimizer=minimizer,
    )
    out = model.state()
    solver.step(state, out, control, 1.0 / 60.0)
    return out, solver


def test_cg_and_direct_agree():
    """CG (tol 1e-12) and the sparse direct solve give the same Newton step and the same result (1e-8)."""
    model = _cloth(4)
    state = _moving_state(model)
    res = {}
    for lin in ("cg", "direct"):
        for iters in (1, 20):
            integ = I.BackwardEuler(newton_tol=1e-10, max_newton_iterations=iters)
            out, solver = _one_step(model, state, integ, minimizer={"linear_solver": lin, "cg_tol": 1e-12})
            res[lin, iters] = out.particle_q.numpy()
            assert solver.last_stats.linear_solver == lin
    x0 = state.particle_q.numpy()
    scale = np.abs(res["direct", 1] - x0).max()
    assert scale > 1e-3
    for iters in (1, 20):
        diff = np.abs(res["cg", iters] - res["direct", iters]).max()
        assert diff <= 1e-8 * scale, f"{iters} iterations: CG and direct differ by {diff:.3g} m"


def test_newton_reports_statistics():
    """last_stats reports iterations, per-iteration residuals and a final gradient norm below tolerance."""
    model = _cloth()
    out, solver = _one_step(model, model.state(), I.BackwardEuler(newton_tol=1e-8))
    st = solver.last_stats
    assert st.converged and 1 <= st.iterations <= 6
    assert len(st.residuals) == st.iterations + 1
    assert st.residuals[-1] == st.gradient_norm <= st.tolerance
    assert st.residuals[0] > 1e3 * st.residuals[-1]
    assert st.linear_solver == "direct" and st.linear_iterations == 0


def test_hanging_cloth_converges_quickly():
    """Backward Euler on a 16×16 cloth pinned at two corners converges (gradient < tol) in ≤ 5 iterations."""
    model = _cloth(16, stiffness=1e3, damping=0.1)
    integ = I.BackwardEuler(newton_tol=1e-6)
    solver = pl.solvers.ForceSolver(model, energies=pl.energies.mass_spring(), integrator=integ)
    stats = []
    s = run_steps(solver, model, 1.0 / 60.0, 15, callback=lambda n, s: stats.append(solver.last_stats))
    assert all(st.converged and st.iterations <= 5 for st in stats), [
        (st.iterations, st.gradient_norm) for st in stats
    ]
    assert all(st.gradient_norm <= st.tolerance for st in stats)
    sag = model.particle_q.numpy()[:, 1].min() - s.particle_q.numpy()[:, 1].min()
    assert sag > 0.0


def test_pinned_particles_stay():
    """Pinned particles (inverse mass 0) keep their positions exactly through implicit steps."""
    model = _cloth()
    pinned = model.particle_inv_mass.numpy() == 0
    assert pinned.sum() == 2
    for integ in (I.BackwardEuler(), I.ImplicitMidpoint(), I.BDF2()):
        solver = pl.solvers.ForceSolver(model, energies=pl.energies.mass_spring(), integrator=integ)
        s = run_steps(solver, model, 1.0 / 60.0, 5)
        assert np.array_equal(s.particle_q.numpy()[pinned], model.particle_q.numpy()[pinned])
        assert np.all(s.particle_qd.numpy()[pinned] == 0)


def test_assembled_hessian_matches_finite_differences():
    """H = M + h²ΣH_e assembled on the fixed BSR pattern equals the central difference of ∇Φ (1e-6)."""
    import scipy.sparse as sp

    model = _cloth(3, pin="none", gravity=(0.0, 0.0, 0.0))
    solver = pl.solvers.ForceSolver(model, energies=pl.energies.mass_spring(), integrator=I.BackwardEuler())
    h = 0.01
    n = model.particle_count
    x_ref = model.particle_q
    x = wp.array(1.2 * model.particle_q.numpy(), dtype=model.vec3, device="cpu")  # all springs stretched
    for e in solver.energies:
        e.begin_step(model, x_ref, model.particle_qd, h)
    ws = workspace_of(solver)
    assemble(solver, ws, x, h, True)
    vals = ws.values.numpy()[: ws.nnz]
    H = sp.bsr_matrix((vals, ws.indices, ws.indptr), shape=(3 * n, 3 * n)).toarray()
    x_tilde = wp.clone(x_ref)
    x0 = x.numpy().reshape(-1)
    fd = np.zeros((3 * n, 3 * n))
    eps = 1e-6
    for c in range(3 * n):
        gs = []
        for sgn in (1, -1):
            xp = x0.copy()
            xp[c] += sgn * eps
            gradient(solver, ws, wp.array(xp.reshape(n, 3), dtype=model.vec3, device="cpu"), x_tilde, h)
            gs.append(ws.grad.numpy().reshape(-1).copy())
        fd[:, c] = (gs[0] - gs[1]) / (2 * eps)
    np.testing.assert_allclose(H, fd, rtol=1e-6, atol=1e-6 * np.abs(H).max())
    assert np.allclose(H, H.T)


def test_control_force_equals_gravity():
    """A Control force m·g on a gravity-free model gives the same implicit step as the Gravity energy."""
    g = (0.0, -9.81, 0.0)
    with_g = _cloth(gravity=g)
    no_g = _cloth(gravity=(0.0, 0.0, 0.0))
    state = _moving_state(with_g)
    a, _ = _one_step(with_g, state, I.BackwardEuler(newton_tol=1e-10))
    control = no_g.control()
    control.particle_f.assign(no_g.particle_mass_np[:, None] * np.asarray(g)[None, :])
    state2 = no_g.state()
    state2.assign(state)
    b, _ = _one_step(no_g, state2, I.BackwardEuler(newton_tol=1e-10), control=control)
    free = with_g.particle_inv_mass.numpy() > 0
    np.testing.assert_allclose(b.particle_q.numpy()[free], a.particle_q.numpy()[free], rtol=0, atol=1e-10)


def test_implicit_step_balances_forces_with_dashpots():
    """The converged step satisfies m(v₁ − v₀)/h = F_spring(x₁) + F_dashpot(v₁) (axis frozen at x₀) to 1e-8.

    Exact Hessians (no PSD projection) here: with compressed springs the projected Newton converges only
    linearly, which is the price of its robustness, not an error.
    """
    model = _cloth(pin="none", gravity=(0.0, 0.0, 0.0), damping=2.0)
    state = _moving_state(model)
    h = 1.0 / 60.0
    out, solver = _one_step(
        model,
        state,
        I.BackwardEuler(newton_tol=1e-10, project_psd=False),
        energies=pl.energies.mass_spring(gravity=False),
    )
    assert solver.last_stats.converged
    x0, v0 = state.particle_q.numpy(), state.particle_qd.numpy()
    x1, v1 = out.particle_q.numpy(), out.particle_qd.numpy()
    idx = model.spring_indices.numpy()
    i, j = idx[:, 0], idx[:, 1]
    k, rest, gamma = (
        a.numpy() for a in (model.spring_stiffness, model.spring_rest_length, model.spring_damping)
    )
    d1 = x1[i] - x1[j]
    l1 = np.linalg.norm(d1, axis=1)
    f_s = -(k * (l1 - rest) / l1)[:, None] * d1  # on i
    n0 = (x0[i] - x0[j]) / np.linalg.norm(x0[i] - x0[j], axis=1)[:, None]
    f_d = -(gamma * np.einsum("sk,sk->s", v1[i] - v1[j], n0))[:, None] * n0
    f = np.zeros_like(x1)
    np.add.at(f, i, f_s + f_d)
    np.add.at(f, j, -(f_s + f_d))
    residual = model.particle_mass_np[:, None] * (v1 - v0) / h - f
    assert np.abs(residual).max() <= 1e-8 * np.abs(f).max(), np.abs(residual).max()
    assert np.abs(f_d).max() > 1e-3 * np.abs(f_s).max()  # the dashpots did take part


def test_options_validated():
    """Unknown linear solvers and non-positive tolerances are rejected with the accepted values named."""
    with pytest.raises(ValueError, match="'cg', 'scipy-cg', 'direct' or 'auto'"):
        pl.solvers.MinimizerOptions(linear_solver="lu")
    with pytest.raises(ValueError, match="newton_tol"):
        I.BDF2(newton_tol=0.0)
    with pytest.raises(ValueError, match="project_psd"):
        I.ImplicitMidpoint(project_psd="always")
    # Defined once (ImplicitOptions): every integrator and the minimisers reject the same mistakes (the
    # minimiser's own settings: tests/test_minimizer_options.py).
    bad = {
        "newton_tol": [float("nan"), -1e-5, 0],
        "max_newton_iterations": [0, 2.5],
        "max_line_search": [-1],
    }
    for name, values in bad.items():
        for value in values:
            for cls in (I.BackwardEuler, I.ImplicitMidpoint, I.BDF2):
                with pytest.raises(ValueError, match=name):
                    cls(**{name: value})
            with pytest.raises(ValueError, match=name):
                I.ImplicitOptions(**{name: value})
    for cls in (I.BackwardEuler, I.BDF2):
        with pytest.raises(
            ValueError, match=r"unknown option\(s\) \['newton_tolerance'\] for .*known options"
        ):
            cls(newton_tolerance=1e-6)
    integ = I.BDF2(newton_tol=1e-7)
    assert integ.newton_tol == integ.options.newton_tol == 1e-7 and not hasattr(integ, "lbfgs_history")
    model = _cloth(3)
    solver = pl.solvers.ForceSolver(model, integrator=I.BackwardEuler())
    x = model.particle_q
    with pytest.raises(ValueError, match="linear_solver must be"):
        minimize_incremental_potential(
            solver, 0.0, 0.01, x, x, model.particle_qd, wp.clone(x), None, minimizer={"linear_solver": "qr"}
        )


def test_auto_projection_converges_faster():
    """On a falling cloth (compressed springs) exact Hessians ("auto") need fewer Newton iterations than
    always-projected ones and reach the same state (1e-7 m)."""
    b = pl.ModelBuilder()
    b.add_cloth_grid(nx=8, ny=8, size=1.0, mass=0.2, stiffness=1e3, pin="top-corners")
    model = b.finalize(device="cpu", dtype="float64")
    res = {}
    for psd in (True, "auto"):
        integ = I.BackwardEuler(project_psd=psd, newton_tol=1e-8)
        solver = pl.solvers.ForceSolver(
            model, energies=[pl.energies.Springs(), pl.energies.Gravity()], integrator=integ
        )
        its = []
        s = run_steps(
            solver, model, 1.0 / 60.0, 10, callback=lambda n, s: its.append(solver.last_stats.iterations)
        )
        assert solver.last_stats.converged
        res[psd] = (sum(its), s.particle_q.numpy())
    assert res["auto"][0] < res[True][0], (res["auto"][0], res[True][0])
    assert np.abs(res["auto"][1] - res[True][1]).max() < 1e-7


def test_scipy_cg_matches_direct_on_a_soft_step():
    """linear_solver="scipy-cg" gives the direct solver's backward-Euler step to 1e-6 m (float64)."""
    model = _cloth()
    outs = {}
    for lin in ("direct", "scipy-cg"):
        integ = I.BackwardEuler(newton_tol=1e-8)
        out, solver = _one_step(model, model.state(), integ, minimizer={"linear_solver": lin})
        outs[lin] = out.particle_q.numpy()
        assert solver.last_stats.converged, solver.last_stats
    err = np.abs(outs["direct"] - outs["scipy-cg"]).max()
    assert err < 1e-6, f"scipy-cg differs from direct by {err:.3g} m"


@pytest.mark.parametrize("method", ["newton", "lbfgs"])
def test_minimizers_read_only_the_declared_problem(method):
    """Newton and L-BFGS need only PotentialProblem's model, energies and control (no ForceSolver fields):
    a plain object gives bit-for-bit the ForceSolver's minimiser, the Control's force included."""
    from pliant.solvers.minimizers import minimize_quasi_newton

    fn = minimize_quasi_newton if method == "lbfgs" else minimize_incremental_potential
    model = _cloth(3)
    control = pl.Control(model)
    control.particle_f.assign(np.tile([0.5, 0.0, 0.0], (model.particle_count, 1)))

    class Problem:
        def __init__(self) -> None:
            self.model = model
            self.energies = pl.energies.mass_spring(dashpots=False)
            self.control = control
            self.last_stats = None

    solver = pl.solvers.ForceSolver(model, energies=pl.energies.mass_spring(dashpots=False), contact=False)
    solver._control = control  # what ForceSolver.step sets for its step
    x, v = model.particle_q, model.particle_qd
    x_tilde = wp.clone(x)
    outs = []
    for problem in (Problem(), solver):
        out = wp.clone(x)
        stats = fn(problem, 0.0, 0.01, x_tilde, x, v, out, {"newton_tol": 1e-9})
        assert stats.converged and problem.last_stats is stats
        outs.append(out.numpy())
    assert np.array_equal(outs[0], outs[1])
    assert np.abs(outs[0] - x.numpy()).max() > 1e-6  # the force moved the cloth
