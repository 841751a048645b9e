"""Mass-spring physics: statics of chains, ropes and stretched cloth, dissipation, derivatives, the drape."""

from __future__ import annotations

import numpy as np
import pytest

import pliant as pl
from pliant.bench._mass_spring import REFERENCE_SAG, cloth_drape, cloth_drape_model, sag

G = 9.81


def _relax(model, *, frames=400, h=0.01, damping_rate=5.0, iterations=200, control=None):
    """Run Baraff–Witkin steps with strong damping until (near) rest; returns the final state."""
    solver = pl.solvers.FastMassSpring(
        model, method="implicit", cg_iterations=iterations, cg_tol=1e-12, damping_rate=damping_rate
    )
    s0, s1 = model.state(), model.state()
    c = control if control is not None else model.control()
    for _ in range(frames):
        solver.step(s0, s1, c, h)
        s0, s1 = s1, s0
    return s0


def test_hanging_chain_stretch_per_link_is_weight_below_over_k():
    """A chain hanging from its top: the stretch of each link equals the weight below it over k (0.5%)."""
    n, k, mass = 10, 200.0, 0.5
    b = pl.ModelBuilder()
    b.add_rope(
        n_segments=n, length=1.0, mass=mass, stiffness=k, start=(0, 0, 0), direction=(0, -1, 0), pin="first"
    )
    model = b.finalize(device="cpu", dtype="float64")
    x = _relax(model, frames=300).particle_q.numpy()
    stretch = np.linalg.norm(np.diff(x, axis=0), axis=1) - 1.0 / n
    m = model.particle_mass_np
    weight_below = np.array([m[j + 1 :].sum() * G for j in range(n)])
    np.testing.assert_allclose(stretch, weight_below / k, rtol=5e-3)


def test_stiff_rope_pinned_at_both_ends_lies_on_the_catenary():
    """A long, stiff rope pinned at both ends, damped to rest, lies within 1% of its span of the catenary."""
    n, span, length, mass = 40, 1.0, 1.3, 0.2
    xs = np.linspace(0.0, span, n + 1)
    pts = np.stack([xs, np.zeros_like(xs), np.zeros_like(xs)], axis=1)
    b = pl.ModelBuilder()
    b.add_particles(pts, mass / (n + 1))
    edges = np.stack([np.arange(n), np.arange(1, n + 1)], axis=1)
    b.add_springs(edges, stiffness=2e4, rest_length=length / n)
    b.pin([0, n])
    model = b.finalize(device="cpu", dtype="float64")
    # Start from a shallow parabola of the right length scale so the rope does not have to buckle first.
    x0 = pts.copy()
    x0[:, 1] = -1.6 * xs * (span - xs)
    model.particle_q.assign(x0)
    x = _relax(model, frames=600).particle_q.numpy()
    # Catenary y = a cosh((x − span/2)/a) + c through both ends, arc length L: 2a sinh(span/2a) = L.
    from scipy.optimize import brentq

    a = brentq(lambda a: 2 * a * np.sinh(span / (2 * a)) - length, 0.05, 100.0)
    y_cat = a * np.cosh((x[:, 0] - span / 2) / a) - a * np.cosh(span / (2 * a))
    assert np.max(np.abs(x[:, 1] - y_cat)) < 0.01 * span


def _spinning_rope(dtype="float64"):
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_rope(n_segments=12, length=1.0, mass=0.3, stiffness=300.0, damping=0.5, pin="none")
    model = b.finalize(device="cpu", dtype=dtype)
    rng = np.random.default_rng(0)
    model.particle_qd.assign(rng.normal(size=(model.particle_count, 3)))
    return model


def _kinetic_potential_momentum(model, state):
    x, v = state.particle_q.numpy(), state.particle_qd.numpy()
    m = model.particle_mass_np
    idx = model.spring_indices.numpy()
    k, rest = model.spring_stiffness.numpy(), model.spring_rest_length.numpy()
    stretch = np.linalg.norm(x[idx[:, 0]] - x[idx[:, 1]], axis=1) - rest
    energy = 0.5 * np.sum(m * np.sum(v * v, axis=1)) + 0.5 * np.sum(k * stretch**2)
    return energy, (m[:, None] * v).sum(axis=0)


@pytest.mark.parametrize("which", ["force_dashpots", "fast_dashpots", "velocity_damping"])
def test_dashpots_and_damping_dissipate_monotonically(which):
    """Dashpots and δ damping lower the energy monotonically; dashpots conserve momentum, δ scales it."""
    model = _spinning_rope()
    dt, delta = 2e-4, 0.999
    if which == "force_dashpots":
        solver = pl.solvers.ForceSolver(
            model,
            energies=[pl.energies.Springs(), pl.energies.Dashpots()],
            integrator=pl.integrators.SymplecticEuler(),
        )
    elif which == "fast_dashpots":
        solver = pl.solvers.FastMassSpring(model, method="symplectic")
    else:
        model.spring_damping.zero_()
        solver = pl.solvers.ForceSolver(
            model,
            energies=[pl.energies.Springs()],
            integrator=pl.integrators.SymplecticEuler(),
            velocity_damping=delta,
        )
    s0, s1 = model.state(), model.state()
    e0, p0 = _kinetic_potential_momentum(model, s0)
    energies, steps = [e0], 0
    for _ in range(40):
        for _ in range(25):
            solver.step(s0, s1, None, dt)
            s0, s1 = s1, s0
            steps += 1
        e, p = _kinetic_potential_momentum(model, s0)
        energies.append(e)
        expected_p = p0 * (delta**steps if which == "velocity_damping" else 1.0)
        np.testing.assert_allclose(p, expected_p, atol=1e-10)
    assert np.all(np.diff(energies) < 0)
    assert energies[-1] < 0.8 * energies[0]


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_fast_symplectic_scatter_equals_gather_and_force_solver(dtype):
    """The CPU's symplectic step (each spring once, scattered) equals the per-particle gather that CUDA
    runs and ForceSolver's Springs + Dashpots + Gravity + SymplecticEuler, to round-off: dashpots, pinned
    corners that move with their velocity (infinite mass), external forces and δ damping included."""
    b = pl.ModelBuilder(gravity=(0.0, -9.81, 0.0))
    b.add_cloth_grid(nx=6, ny=5, size=0.5, mass=0.2, youngs_modulus_thickness=400.0, damping=0.02,
                     origin=(-0.25, 0.0, -0.25), plane="xz", pin="top-corners")  # fmt: skip
    model = b.finalize(device="cpu", dtype=dtype)
    rng = np.random.default_rng(3)
    model.particle_qd.assign(rng.normal(scale=0.3, size=(model.particle_count, 3)))
    control = model.control()
    control.particle_f.assign(rng.normal(scale=0.01, size=(model.particle_count, 3)))
    dt, steps = 1e-3, 200

    def run(solver):
        s0, s1 = model.state(), model.state()
        for _ in range(steps):
            solver.step(s0, s1, control, dt)
            s0, s1 = s1, s0
        return s0.particle_q.numpy(), s0.particle_qd.numpy()

    scatter = pl.solvers.FastMassSpring(model, method="symplectic", velocity_damping=0.9995)
    assert scatter.kernel == "scatter"  # the CPU's default
    gather = pl.solvers.FastMassSpring(model, method="symplectic", velocity_damping=0.9995, kernel="gather")
    force = pl.solvers.ForceSolver(
        model,
        energies=[pl.energies.Springs(), pl.energies.Dashpots(), pl.energies.Gravity()],
        integrator=pl.integrators.SymplecticEuler(),
        velocity_damping=0.9995,
    )
    xs, vs = run(scatter)
    tol = 1e-5 if dtype == "float32" else 1e-12
    moved = np.abs(xs - model.particle_q.numpy()).max()
    assert moved > 0.05  # the cloth fell and swung: a comparison of motion, not of rest
    for other in (gather, force):
        xo, vo = run(other)
        np.testing.assert_allclose(xs, xo, rtol=0, atol=tol)
        np.testing.assert_allclose(vs, vo, rtol=0, atol=50 * tol)


def test_fast_mass_spring_rejects_an_unknown_kernel():
    model = _spinning_rope()
    with pytest.raises(ValueError, match="kernel must be 'scatter', 'gather'"):
        pl.solvers.FastMassSpring(model, kernel="simd")


def test_block_sliding_on_ground_stops_after_v2_over_2_mu_g():
    """A particle sliding on the ground with friction μ stops after v²/(2μg) (2%)."""
    v0, mu, dt = 2.0, 0.4, 1e-3
    b = pl.ModelBuilder()
    b.add_particles([[0.0, 0.01, 0.0]], 1.0, velocities=[[v0, 0.0, 0.0]], radius=0.01)
    b.add_ground(friction=mu)
    model = b.finalize(device="cpu", dtype="float64")
    solver = pl.solvers.ForceSolver(
        model, energies=[pl.energies.Gravity()], integrator=pl.integrators.SymplecticEuler()
    )
    s0, s1 = model.state(), model.state()
    for _ in range(int(1.2 * v0 / (mu * G) / dt)):
        solver.step(s0, s1, None, dt)
        s0, s1 = s1, s0
    x, v = s0.particle_q.numpy()[0], s0.particle_qd.numpy()[0]
    assert abs(v[0]) < 1e-9
    assert x[0] == pytest.approx(v0**2 / (2 * mu * G), rel=0.02)


def test_uniaxial_stretch_strains_by_stress_over_youngs_modulus():
    """A cloth patch (ν = 1/3) under uniaxial tension σ strains by σ/(E·t) (2%) and contracts by ν·ε (5%).

    The interior of the square lattice is exact for ν = 1/3; the free edges add an O(1/n) boundary layer
    (their axis springs are not halved), which is what the tolerances leave room for at n = 40 (measured
    ε/(σ/Et) = 1.005, ν = 0.344).
    """
    n, et, nu, size = 40, 1000.0, 1.0 / 3.0, 1.0
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_cloth_grid(
        nx=n, ny=n, size=size, mass=0.1, youngs_modulus_thickness=et, poisson=nu, origin=(0, 0, 0)
    )
    model = b.finalize(device="cpu", dtype="float64")
    x0 = model.particle_q_np
    sigma = 0.002 * et  # membrane stress [N/m]: 0.2% strain, in the linear range
    col = np.rint(x0[:, 0] * n).astype(int)
    row = np.rint(x0[:, 2] * n).astype(int)
    share = np.where((row == 0) | (row == n), 0.5, 1.0) * size / n  # edge length carried by each node
    f = np.zeros_like(x0)
    f[col == n, 0] = sigma * share[col == n]
    f[col == 0, 0] = -sigma * share[col == 0]
    control = model.control()
    control.particle_f.assign(f)
    x = _relax(model, frames=150, h=0.02, control=control).particle_q.numpy()
    inner = (col >= n // 4) & (col <= 3 * n // 4) & (row >= n // 4) & (row <= 3 * n // 4)
    # Affine fit of the interior displacement: ∂u_x/∂x and ∂u_z/∂z.
    A = np.stack([x0[inner, 0], x0[inner, 2], np.ones(inner.sum())], axis=1)
    exx = np.linalg.lstsq(A, x[inner, 0] - x0[inner, 0], rcond=None)[0][0]
    ezz = np.linalg.lstsq(A, x[inner, 2] - x0[inner, 2], rcond=None)[0][1]
    assert exx == pytest.approx(sigma / et, rel=0.02)
    assert -ezz / exx == pytest.approx(nu, rel=0.05)


def test_cloth_spring_stiffness_rejects_bad_poisson():
    """cloth_spring_stiffness validates ν and E·t, and maps ν = 1/3 to k_s = 3/4 E·t, k_d = 3/8 E·t."""
    ks, kd = pl.energies.cloth_spring_stiffness(800.0, 1.0 / 3.0)
    assert (ks, kd) == pytest.approx((600.0, 300.0))
    with pytest.raises(ValueError):
        pl.energies.cloth_spring_stiffness(800.0, 0.5)


def test_drape_implicit_and_symplectic_agree_on_sag():
    """The 16×16 drape (float64) sags the same with Baraff–Witkin and converged symplectic Euler (1%)."""
    sags = []
    for method, sub in (("implicit", 1), ("symplectic", 40)):
        model = cloth_drape_model(16, dtype="float64")
        solver = pl.solvers.FastMassSpring(model, method=method, cg_iterations=60, damping_rate=3.0)
        s0, s1 = model.state(), model.state()
        for _ in range(300 * sub):
            solver.step(s0, s1, None, 1 / 60 / sub)
            s0, s1 = s1, s0
        sags.append(sag(model, s0.particle_q.numpy()))
    assert 0.95 < sags[0] < 1.1
    assert sags[1] == pytest.approx(sags[0], rel=0.01)


def test_drape_benchmark_row_has_the_documented_fields():
    """A quick drape benchmark row is stable and carries speed and sag figures."""
    row = cloth_drape(16, "implicit", quick=True)
    for key in (
        "scene",
        "solver",
        "integrator",
        "device",
        "particles",
        "elements",
        "substeps",
        "iterations",
        "wall_s",
        "compile_s",
        "fps",
        "particle_substeps_per_s",
        "peak_mem_mb",
        "sag",
    ):
        assert key in row
    assert row["stable"] and row["particles"] == 17 * 17


@pytest.mark.bench
@pytest.mark.parametrize("n", [64, 128])
def test_drape_implicit_sag_within_5_percent_of_reference(n):
    """The n×n drape with Baraff–Witkin (20 CG iterations, float32) ends within 5% of the reference sag."""
    row = cloth_drape(n, "implicit")
    assert row["stable"]
    assert row["sag"] == pytest.approx(REFERENCE_SAG[n], rel=0.05)


@pytest.mark.parametrize("solver_kind", ["force", "fast_symplectic", "fast_implicit"])
def test_drag_handle_pulls_to_the_cursor_and_pins_hold(solver_kind):
    """The drag handle pulls a rope's free end to the cursor (1 cm) while the pinned end stays put."""
    b = pl.ModelBuilder()
    b.add_rope(
        n_segments=8, length=0.4, mass=0.04, stiffness=500.0, damping=0.05, start=(0, 0, 0), pin="first"
    )
    model = b.finalize(device="cpu", dtype="float64")
    if solver_kind == "force":
        solver = pl.solvers.ForceSolver(
            model,
            energies=pl.energies.mass_spring(),
            integrator=pl.integrators.SymplecticEuler(),
            damping_rate=4.0,
        )
    else:
        method = "symplectic" if solver_kind == "fast_symplectic" else "implicit"
        solver = pl.solvers.FastMassSpring(model, method=method, cg_iterations=60, damping_rate=4.0)
    control = model.control()
    target = np.array([0.3, 0.2, 0.0])
    control.set_drag(8, target, 200.0)
    s0, s1 = model.state(), model.state()
    dt = 1e-3 if solver_kind != "fast_implicit" else 1e-2
    for _ in range(int(3.0 / dt)):
        solver.step(s0, s1, control, dt)
        s0, s1 = s1, s0
    x = s0.particle_q.numpy()
    assert np.array_equal(x[0], model.particle_q_np[0])
    # At rest the handle spring holds the end: k·|target − x_end| balances gravity and the rope's pull.
    assert np.linalg.norm(x[8] - target) < 0.01


def test_a_cloth_run_does_not_load_scipy():
    """Building and stepping a cloth never imports SciPy (27 MB of resident memory, the margin by which
    pliant's drape stays under Newton's peak memory; docs/design.md): SciPy is imported where a consistent
    mass matrix, an embedding or a sparse solve needs it."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from pliant.bench._mass_spring import cloth_drape_model, make_solver\n"
        "m = cloth_drape_model(8)\n"
        "s = make_solver(m, 'symplectic')\n"
        "s0, s1 = m.state(), m.state()\n"
        "s.step(s0, s1, None, 1e-4)\n"
        "loaded = sorted(k for k in sys.modules if k.split('.')[0] == 'scipy')\n"
        "assert not loaded, loaded[:5]\n"
        "print('OK')\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip().endswith("OK")
