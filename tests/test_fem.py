"""FEM elasticity energies on a mesh: derivatives, invariances, precision, step bound, static solve."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import pliant as pl
from pliant.energies._fem import Corotated, LinearElastic, NeoHookean, StVK, TetElasticity

NAMES = ["linear", "stvk", "corotated", "neohookean"]
E_MOD, NU = 1.0e3, 0.3


def _model(dtype: str = "float64", cells=(2, 1, 1)):
    b = pl.ModelBuilder()
    b.add_soft_box(cells=cells, size=(0.2, 0.1, 0.1), origin=(0.0, 0.0, 0.0), density=1000.0, E=E_MOD, nu=NU)
    return b.finalize(device="cpu", dtype=dtype)


def _deformed(model, rng, amount=0.02) -> np.ndarray:
    x = model.particle_q_np.copy()
    return x + amount * rng.standard_normal(x.shape)


def _arr(model, x):
    return wp.array(
        np.asarray(x, dtype=np.float64 if model.dtype == "float64" else np.float32), dtype=model.vec3
    )


def _value(energy, model, x) -> float:
    out = wp.zeros(1, dtype=model.scalar, device=model.device)
    energy.value(model, _arr(model, x), out)
    return float(out.numpy()[0])


def _gradient(energy, model, x) -> np.ndarray:
    out = wp.zeros(model.particle_count, dtype=model.vec3, device=model.device)
    energy.gradient(model, _arr(model, x), out)
    return out.numpy().astype(np.float64)


def _hessian(energy, model, x, project_psd: bool) -> np.ndarray:
    """Dense 3n×3n Hessian from the energy's blocks, each in its own slot."""
    rows, cols = energy.hessian_pattern(model)
    slots = wp.array(np.arange(rows.size, dtype=np.int32), dtype=wp.int32)
    vals = wp.zeros(rows.size, dtype=model.mat33, device=model.device)
    energy.hessian(model, _arr(model, x), slots, vals, project_psd=project_psd)
    return _blocks_to_dense(rows, cols, vals, model.particle_count)


def _blocks_to_dense(rows, cols, vals, n) -> np.ndarray:
    H = np.zeros((3 * n, 3 * n))
    v = vals.numpy().astype(np.float64)
    for k, (r, c) in enumerate(zip(rows, cols, strict=True)):
        H[3 * r : 3 * r + 3, 3 * c : 3 * c + 3] += v[k]
    return H


def _random_rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


# ∇E and ∇²E of every material against central differences: tests/test_energy_contracts.py (all energies).


@pytest.mark.parametrize("name", NAMES)
def test_tape_gradient_of_value_matches_analytic_gradient(name):
    """wp.Tape through the value kernel gives the analytic gradient (the kernels stay differentiable)."""
    model = _model()
    x_np = _deformed(model, np.random.default_rng(12))
    e = TetElasticity(name)
    x = wp.array(x_np, dtype=wp.vec3d, requires_grad=True)
    out = wp.zeros(1, dtype=wp.float64, requires_grad=True)
    tape = wp.Tape()
    with tape:
        e.value(model, x, out)
    tape.backward(out)
    g = _gradient(e, model, x_np)
    np.testing.assert_allclose(x.grad.numpy(), g, atol=1e-12 * np.abs(g).max())


@pytest.mark.parametrize("name", NAMES)
def test_projected_hessian_is_psd(name):
    """With project_psd the assembled Hessian has no eigenvalue below −1e-10 of its scale."""
    model = _model()
    x = _deformed(model, np.random.default_rng(3), amount=0.04)
    H = _hessian(TetElasticity(name), model, x, project_psd=True)
    lo = np.linalg.eigvalsh(H).min()
    assert lo > -1e-10 * np.abs(H).max(), f"{name}: min eigenvalue {lo:.3e}"


@pytest.mark.parametrize("name", NAMES)
def test_forces_sum_to_zero_and_rest_is_stress_free(name):
    """Σ_i ∇_i E = 0 on a deformed mesh (momentum); E = 0 and ∇E = 0 at rest."""
    model = _model()
    e = TetElasticity(name)
    x = _deformed(model, np.random.default_rng(4))
    g = _gradient(e, model, x)
    assert np.abs(g.sum(axis=0)).max() < 1e-10 * np.abs(g).max()
    rest = model.particle_q_np
    assert abs(_value(e, model, rest)) < 1e-12
    assert np.abs(_gradient(e, model, rest)).max() < 1e-9


@pytest.mark.parametrize("name", ["stvk", "corotated", "neohookean"])
def test_energy_invariant_under_rigid_motion(name):
    """E(Qx + t) = E(x) for a random rotation Q and translation t; a rotated rest shape has E = 0."""
    model = _model()
    rng = np.random.default_rng(5)
    x = _deformed(model, rng)
    Q, t = _random_rotation(rng), rng.standard_normal(3)
    e = TetElasticity(name)
    e0 = _value(e, model, x)
    e1 = _value(e, model, x @ Q.T + t)
    assert abs(e1 - e0) < 1e-9 * abs(e0), f"{name}: E {e0} -> {e1} under a rigid motion"
    assert abs(_value(e, model, model.particle_q_np @ Q.T + t)) < 1e-9 * abs(e0)


def test_linear_elasticity_is_translation_but_not_rotation_invariant():
    """Linear elasticity: invariant under translation, but a 30° rotation of the rest shape costs energy."""
    model = _model()
    e = LinearElastic()
    x = _deformed(model, np.random.default_rng(6))
    assert abs(_value(e, model, x + np.array([0.3, -1.0, 2.0])) - _value(e, model, x)) < 1e-9 * _value(
        e, model, x
    )
    c, s = np.cos(np.pi / 6), np.sin(np.pi / 6)
    Q = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    assert _value(e, model, model.particle_q_np @ Q.T) > 1e-3


def test_small_strain_limit_is_linear_elasticity():
    """For a 1e-5 deformation all four materials give the linear-elastic energy to 1e-3 relative."""
    model = _model()
    rng = np.random.default_rng(7)
    x = model.particle_q_np + 1e-5 * rng.standard_normal(model.particle_q_np.shape)
    ref = _value(LinearElastic(), model, x)
    for cls in (StVK, Corotated, NeoHookean):
        v = _value(cls(), model, x)
        assert abs(v - ref) < 1e-3 * ref, f"{cls.__name__}: {v} vs linear {ref}"


@pytest.mark.parametrize("name", NAMES)
def test_float32_matches_float64(name):
    """The float32 kernels match the float64 ones to 1e-4 relative (value, gradient, Hessian)."""
    m64, m32 = _model("float64"), _model("float32")
    x = _deformed(m64, np.random.default_rng(8)).astype(np.float32).astype(np.float64)
    e = TetElasticity(name)
    v64, v32 = _value(e, m64, x), _value(TetElasticity(name), m32, x)
    assert abs(v32 - v64) < 1e-4 * abs(v64), f"value {v32} vs {v64}"
    g64, g32 = _gradient(e, m64, x), _gradient(TetElasticity(name), m32, x)
    assert np.abs(g32 - g64).max() < 1e-4 * np.abs(g64).max()
    for project in (False, True):
        H64 = _hessian(e, m64, x, project)
        H32 = _hessian(TetElasticity(name), m32, x, project)
        err = np.abs(H32 - H64).max() / np.abs(H64).max()
        assert err < 1e-4, f"project_psd={project}: relative Hessian difference {err:.2e}"


def test_uniform_material_override():
    """NeoHookean(E, nu) overrides the model's per-tet Lamé parameters: E scales the energy linearly."""
    model = _model()
    x = _deformed(model, np.random.default_rng(9))
    base = _value(NeoHookean(), model, x)
    assert abs(_value(NeoHookean(E=2 * E_MOD, nu=NU), model, x) - 2 * base) < 1e-9 * base
    with pytest.raises(ValueError, match="unknown material model"):
        TetElasticity("mooney")


def test_max_step_prevents_inversion():
    """After α = max_step(x, dx) no element keeps less than η of its volume; a harmless step gives α = 1."""
    model = _model()
    rng = np.random.default_rng(10)
    e = NeoHookean()
    x = _deformed(model, rng, amount=0.005)
    X = model.particle_q_np
    tets = model.tet_indices.numpy()

    def dets(y):
        D = np.stack([y[tets[:, k]] - y[tets[:, 0]] for k in (1, 2, 3)], axis=2)
        return np.linalg.det(D)

    d0 = dets(x)
    assert np.all(d0 > 0)
    for _ in range(20):
        dx = 0.2 * rng.standard_normal(x.shape)
        a = e.max_step(model, _arr(model, x), _arr(model, dx))
        assert 0.0 < a <= 1.0
        for frac in np.linspace(0.0, 1.0, 11):
            assert np.all(dets(x + frac * a * dx) > 0.1 * d0 * (1 - 1e-9)), f"alpha {a}"
    assert e.max_step(model, _arr(model, x), _arr(model, 1e-4 * rng.standard_normal(x.shape))) == 1.0
    assert e.max_step(model, _arr(model, X), _arr(model, np.ones_like(X))) == 1.0  # translation
    assert e.min_det(model, _arr(model, X)) == pytest.approx(1.0)


# ------------------------------------------------------------------------------------- dynamics


def _min_det_ok(energy, model, state) -> float:
    return energy.min_det(model, state.particle_q)


def test_stiff_body_backward_euler_is_stable_and_never_inverts():
    """E = 1 GPa at Δt = 1/60 s, spinning at 10 rad/s: backward Euler keeps det F > 0.99 every step,
    dissipates energy monotonically and conserves linear momentum."""
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_soft_box(
        cells=(3, 2, 2), size=(0.3, 0.2, 0.2), origin=(0.0, 0.0, 0.0), density=1000.0, E=1e9, nu=0.3
    )
    model = b.finalize(device="cpu", dtype="float64")
    X, mass = model.particle_q_np, model.particle_mass_np
    rng = np.random.default_rng(11)
    v0 = np.cross(np.array([0.0, 0.0, 10.0]), X) + 0.5 * rng.standard_normal(X.shape)
    p0 = (mass[:, None] * v0).sum(axis=0)
    e = NeoHookean()
    # 1 mm/s: at E = 1 GPa the float64 round-off of Φ stalls the Armijo line search near 1e-4 m/s. Projected
    # Hessians: with exact ones ("auto") Newton wanders for 20 iterations on the first step of this spin.
    integrator = pl.integrators.BackwardEuler(newton_tol=1e-3, project_psd=True)
    solver = pl.solvers.ForceSolver(model, [e], integrator)
    s0, s1 = model.state(), model.state()
    s0.particle_qd.assign(v0)
    totals = []
    for step in range(30):
        solver.step(s0, s1, None, 1.0 / 60.0)
        s0, s1 = s1, s0
        assert solver.last_stats.converged, f"step {step}: {solver.last_stats}"
        d = e.min_det(model, s0.particle_q)
        assert d > 0.99, f"step {step}: min det F = {d}"
        en = solver.energy(s0)
        totals.append(en["NeoHookean"] + en["kinetic"])
    assert np.all(np.diff(totals) <= 1e-9 * totals[0]), f"energy grew: {totals}"
    p = (mass[:, None] * s0.particle_qd.numpy()).sum(axis=0)
    np.testing.assert_allclose(p, p0, atol=1e-6 * np.abs(p0).max() + 1e-9)


def test_soft_box_dropped_on_ground_comes_to_rest():
    """A soft neo-Hookean box dropped on the ground under backward Euler rests on it after 1 s, uninverted."""
    b = pl.ModelBuilder()
    b.add_soft_box(cells=(2, 2, 2), size=(0.2, 0.2, 0.2), origin=(0.0, 0.12, 0.0), E=1e5, nu=0.3)
    b.add_ground()
    model = b.finalize(device="cpu", dtype="float32")
    e = NeoHookean()
    solver = pl.solvers.ForceSolver(model, [e, pl.energies.Gravity()], pl.integrators.BackwardEuler())
    s0, s1 = model.state(), model.state()
    for _ in range(60):
        solver.step(s0, s1, None, 1.0 / 60.0)
        s0, s1 = s1, s0
        assert e.min_det(model, s0.particle_q) > 0.2
    x, v = s0.particle_q.numpy(), s0.particle_qd.numpy()
    radius = float(model.particle_radius.numpy()[0])
    # Implicit steps hold the box with the ground penalty κ m_i d: the bottom particles carry the column above
    # them (about 3× their own weight here), so they rest ~3 g/κ ≈ 0.3-0.8 mm inside the contact radius.
    assert radius - 1e-3 < x[:, 1].min() < radius, "the box does not rest on the ground"
    assert 0.19 < x[:, 1].max() < 0.21, f"top at {x[:, 1].max()} m"
    assert np.abs(v).max() < 0.02, f"still moving: max |v| = {np.abs(v).max()} m/s"


def test_symplectic_euler_soft_box_oscillates_with_bounded_energy():
    """Explicit symplectic Euler at Δt = 1 ms on a stretched soft box: energy stays within 5 %, no inversion,
    zero momentum."""
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_soft_box(cells=(2, 2, 2), size=(0.2, 0.2, 0.2), origin=(0.0, 0.0, 0.0), E=1e4, nu=0.3)
    model = b.finalize(device="cpu", dtype="float32")
    e = NeoHookean()
    solver = pl.solvers.ForceSolver(model, [e], pl.integrators.SymplecticEuler())
    s0, s1 = model.state(), model.state()
    s0.particle_q.assign((model.particle_q_np * np.array([1.1, 0.95, 1.0])).astype(np.float32))
    totals = []
    for step in range(200):
        solver.step(s0, s1, None, 1e-3)
        s0, s1 = s1, s0
        if step % 10 == 9:
            en = solver.energy(s0)
            totals.append(en["NeoHookean"] + en["kinetic"])
            assert e.min_det(model, s0.particle_q) > 0.5
    assert max(totals) < 1.05 * totals[0] and min(totals) > 0.95 * totals[0], totals
    p = (model.particle_mass_np[:, None] * s0.particle_qd.numpy()).sum(axis=0)
    assert np.abs(p).max() < 1e-5


def test_kinematic_squeeze_settles_to_static_equilibrium():
    """Dirichlet conditions in dynamics: a block with a pinned base and a kinematic top pushed down 20 %
    (Control.kinematic_targets) settles under backward Euler where solve_static puts it."""
    h = 0.1
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_soft_box(cells=(2, 2, 2), size=(h, h, h), origin=(0.0, h / 2, 0.0), E=1e5, nu=0.3)
    X = b.positions()
    bottom = np.flatnonzero(np.isclose(X[:, 1], 0.0))
    top = np.flatnonzero(np.isclose(X[:, 1], h))
    b.pin(bottom)
    b.add_kinematic(top)
    model = b.finalize(device="cpu", dtype="float64")
    e = NeoHookean()
    solver = pl.solvers.ForceSolver(model, [e], pl.integrators.BackwardEuler())
    control = model.control()
    s0, s1 = model.state(), model.state()
    steps_down, dt = 20, 1.0 / 60.0
    for step in range(60):
        squeeze = 0.2 * h * min(step + 1, steps_down) / steps_down
        target = X[top] - np.array([0.0, squeeze, 0.0])
        control.set_kinematic_targets(target)
        solver.step(s0, s1, control, dt)
        s0, s1 = s1, s0
        assert e.min_det(model, s0.particle_q) > 0.5
    x_dyn = s0.particle_q.numpy()
    np.testing.assert_allclose(x_dyn[top], target, atol=1e-12)
    x0 = X.copy()
    x0[top] = target
    x_static, stats = pl.solvers.solve_static(model, [e], x0=x0)
    assert stats.converged and stats.fixed_count == bottom.size + top.size
    err = np.abs(x_dyn - x_static.numpy()).max()
    assert err < 1e-3 * h, f"dynamic rest state differs from the static solution by {err:.2e} m"


def test_solve_static_validates_arguments():
    """solve_static rejects dissipative terms, bad fixed indices, wrongly shaped loads, unknown solvers."""
    model = _model()
    with pytest.raises(ValueError, match="dissipative"):
        pl.solvers.solve_static(model, [NeoHookean(), pl.energies.Dashpots()])
    with pytest.raises(ValueError, match="fixed indices"):
        pl.solvers.solve_static(model, [NeoHookean()], fixed=[model.particle_count])
    with pytest.raises(ValueError, match="loads must have shape"):
        pl.solvers.solve_static(model, [NeoHookean()], loads=np.zeros((2, 3)))
    with pytest.raises(ValueError, match="linear_solver"):
        pl.solvers.solve_static(model, [NeoHookean()], linear_solver="lu")
    x, stats = pl.solvers.solve_static(model, [NeoHookean()])
    assert stats.converged and stats.iterations == 0  # the rest shape is already in equilibrium
    np.testing.assert_array_equal(x.numpy(), model.particle_q.numpy())


def test_soft_box_benchmark_quick():
    """The FEM benchmark rows run (quick) and report the figures DESIGN.md asks for."""
    from pliant import bench

    for name in ("soft_box_drop_10_implicit", "soft_box_drop_10_explicit"):
        r = bench.run(name, quick=True)
        for key in ("scene", "solver", "integrator", "device", "particles", "elements", "substeps", "wall_s"):
            assert key in r
        assert r["stable"] and r["final_min_det_F"] > 0 and r["time_per_step_s"] > 0, r
