"""PBD/XPBD constraint maths: gradients, momentum, exact projection, colouring, shape matching."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import warp as wp

import pliant.constraints as pc
from pliant.model import ModelBuilder
from pliant.solvers import XPBD
from tests.reference import pbd as ref

wp.init()
wp.config.quiet = True

DIST, BEND, VOL, GROUND, PT, COLL = range(6)
NAMES = {
    DIST: "distance",
    BEND: "dihedral",
    VOL: "volume",
    GROUND: "ground",
    PT: "point_triangle",
    COLL: "collision",
}


@wp.kernel
def _eval(
    kind: int,
    x: wp.array2d(dtype=wp.vec3d),
    rest: wp.array(dtype=wp.float64),
    c_out: wp.array(dtype=wp.float64),
    g_out: wp.array2d(dtype=wp.vec3d),
):
    k = wp.tid()
    x0 = x[k, 0]
    x1 = x[k, 1]
    x2 = x[k, 2]
    x3 = x[k, 3]
    r = rest[k]
    z = wp.vec3d()
    if kind == 0:
        c_out[k] = pc.distance_c(x0, x1, r)
        g0, g1 = pc.distance_grad(x0, x1)
        g_out[k, 0] = g0
        g_out[k, 1] = g1
        g_out[k, 2] = z
        g_out[k, 3] = z
    elif kind == 1:
        c_out[k] = pc.dihedral_c(x0, x1, x2, x3, r)
        g0, g1, g2, g3 = pc.dihedral_grad(x0, x1, x2, x3)
        g_out[k, 0] = g0
        g_out[k, 1] = g1
        g_out[k, 2] = g2
        g_out[k, 3] = g3
    elif kind == 2:
        c_out[k] = pc.volume_c(x0, x1, x2, x3, r)
        g0, g1, g2, g3 = pc.volume_grad(x0, x1, x2, x3)
        g_out[k, 0] = g0
        g_out[k, 1] = g1
        g_out[k, 2] = g2
        g_out[k, 3] = g3
    elif kind == 3:
        n = wp.vec3d(wp.float64(0.0), wp.float64(1.0), wp.float64(0.0))
        c_out[k] = pc.ground_c(x0, n, r, wp.float64(0.01))
        g_out[k, 0] = pc.ground_grad(x0, n)
        g_out[k, 1] = z
        g_out[k, 2] = z
        g_out[k, 3] = z
    elif kind == 4:
        c_out[k] = pc.point_triangle_c(x0, x1, x2, x3, r, wp.float64(0.01))
        g0, g1, g2, g3 = pc.point_triangle_grad(x0, x1, x2, x3, r)
        g_out[k, 0] = g0
        g_out[k, 1] = g1
        g_out[k, 2] = g2
        g_out[k, 3] = g3
    else:
        c_out[k] = pc.particle_collision_c(x0, x1, wp.float64(0.1), r)
        g0, g1 = pc.distance_grad(x0, x1)
        g_out[k, 0] = g0
        g_out[k, 1] = g1
        g_out[k, 2] = z
        g_out[k, 3] = z


def warp_c_grad(kind: int, X: np.ndarray, rest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """C [n] and ∇C [n, 4, 3] of the Warp float64 maths at configurations X [n, 4, 3]."""
    n = X.shape[0]
    x = wp.array(X, dtype=wp.vec3d, device="cpu")
    r = wp.array(rest, dtype=wp.float64, device="cpu")
    c = wp.zeros(n, dtype=wp.float64, device="cpu")
    g = wp.zeros((n, 4), dtype=wp.vec3d, device="cpu")
    wp.launch(_eval, n, [kind, x, r, c, g], device="cpu")
    return c.numpy(), g.numpy()


def warp_fd(kind: int, X: np.ndarray, rest: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """Central differences [n, 4, 3] of the Warp C, all perturbations in one launch."""
    n = X.shape[0]
    P = np.repeat(X[:, None, None], 12, axis=1).repeat(2, axis=2)  # [n, 12, 2, 4, 3]
    for a in range(12):
        P[:, a, 0, a // 3, a % 3] += h
        P[:, a, 1, a // 3, a % 3] -= h
    c, _ = warp_c_grad(kind, P.reshape(-1, 4, 3), np.repeat(rest, 24))
    c = c.reshape(n, 12, 2)
    return ((c[:, :, 0] - c[:, :, 1]) / (2 * h)).reshape(n, 4, 3)


def random_configs(kind: int, rng: np.random.Generator, n: int = 20) -> tuple[np.ndarray, np.ndarray]:
    X = rng.normal(size=(n, 4, 3))
    rest = rng.uniform(0.1, 1.0, n)
    if kind == BEND:
        rest = rng.uniform(-np.pi, np.pi, n)
    if kind == PT:
        rest = rng.choice([-1.0, 1.0], n)
    return X, rest


def hinge(theta: float) -> np.ndarray:
    """Two unit triangles on the x-axis hinge with dihedral angle θ (0 flat, π folded)."""
    x0, x1 = np.zeros(3), np.array([1.0, 0.0, 0.0])
    x2 = np.array([0.4, 0.0, -1.0])  # wing 1 in the xz plane, normal e × (x2 − x0) = +y
    x3 = np.array([0.6, -np.sin(theta), np.cos(theta)])  # sign: θ > 0 turns n̂2 about +ê
    return np.stack([x0, x1, x2, x3])


@pytest.mark.parametrize("kind", [DIST, BEND, VOL, GROUND, PT, COLL], ids=lambda k: NAMES[k])
def test_gradient_matches_finite_differences(kind):
    """∇C of every constraint's Warp float64 maths equals central differences of C (1e-6 relative)."""
    rng = np.random.default_rng(kind)
    X, rest = random_configs(kind, rng)
    _, g = warp_c_grad(kind, X, rest)
    fd = warp_fd(kind, X, rest)
    np.testing.assert_allclose(g, fd, rtol=1e-6, atol=1e-6 * np.abs(fd).max())


@pytest.mark.parametrize("theta", [0.0, 1e-7, -1e-7, np.pi - 1e-7, -(np.pi - 1e-7), np.pi, 2.0, -2.5])
def test_dihedral_well_defined_at_flat_and_folded(theta):
    """The dihedral angle is exact and its gradient finite and equal to finite differences at 0 and ±π."""
    X = hinge(theta)[None]
    rest = np.array([0.3])
    c, g = warp_c_grad(BEND, X, rest)
    expected = (theta - 0.3 + np.pi) % (2 * np.pi) - np.pi
    assert abs(c[0] - expected) < 1e-12 or abs(abs(c[0] - expected) - 2 * np.pi) < 1e-12, (c[0], expected)
    assert np.all(np.isfinite(g))
    np.testing.assert_allclose(g, warp_fd(BEND, X, rest, h=1e-7), atol=1e-6)


@pytest.mark.parametrize("kind", [DIST, BEND, VOL, PT], ids=lambda k: NAMES[k])
def test_warp_maths_match_float64_reference(kind):
    """The Warp C and ∇C equal the independently derived NumPy twins (1e-10)."""
    rng = np.random.default_rng(10 + kind)
    X, rest = random_configs(kind, rng)
    c, g = warp_c_grad(kind, X, rest)
    for k in range(X.shape[0]):
        if kind == DIST:
            rc, rg = ref.distance_c(X[k, :2], rest[k]), ref.distance_grad(X[k, :2])
            rg = np.concatenate([rg, np.zeros((2, 3))])
        elif kind == BEND:
            rc, rg = ref.dihedral_c(X[k], rest[k]), ref.dihedral_grad(X[k])
        elif kind == VOL:
            rc, rg = ref.volume_c(X[k], rest[k]), ref.volume_grad(X[k])
        else:
            rc, rg = ref.point_triangle_c(X[k], rest[k], 0.01), ref.point_triangle_grad(X[k], rest[k])
        assert abs(c[k] - rc) < 1e-10, (NAMES[kind], k, c[k], rc)
        np.testing.assert_allclose(g[k], rg, rtol=1e-8, atol=1e-10)


def test_reference_gradients_match_finite_differences():
    """The NumPy twins' gradients equal their own central differences (first hop of the oracle)."""
    rng = np.random.default_rng(3)
    for _ in range(5):
        X = rng.normal(size=(4, 3))
        np.testing.assert_allclose(
            ref.dihedral_grad(X), ref.central_diff(lambda y: ref.dihedral_c(y, 0.1), X), atol=1e-6
        )
        np.testing.assert_allclose(
            ref.volume_grad(X), ref.central_diff(lambda y: ref.volume_c(y, 0.0), X), atol=1e-6
        )
        np.testing.assert_allclose(
            ref.point_triangle_grad(X, -1.0),
            ref.central_diff(lambda y: ref.point_triangle_c(y, -1.0, 0.0), X),
            atol=1e-6,
        )


# ---------------------------------------------------------------------- projections on a model
def _model(points: np.ndarray, masses: np.ndarray, *, pin=()):
    b = ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_particles(points, masses)
    if len(pin):
        b.pin(list(pin))
    return b.finalize(device="cpu", dtype="float64")


def _project_once(model, constraint, dt: float = 1e-2, schedule: str = "coloring") -> np.ndarray:
    """Positions after one sweep of ``constraint`` starting from the model's positions."""
    solver = XPBD(model, iterations=1, schedule=schedule, constraints=[constraint], contact=False)
    p = wp.clone(model.particle_q)
    ctx = solver.context()
    constraint.begin_step(ctx, model.particle_q, p, dt)
    constraint.project(ctx, p, dt)
    if constraint.writes_deltas(solver.coloring):
        from pliant.solvers.xpbd import _kernels as K

        wp.launch(
            K.apply_deltas, model.particle_count, [model.s(1.0), 1, p, solver.delta, solver.delta_count]
        )
    return p.numpy()


def _constraint_for(kind: str, rng: np.random.Generator, n: int):
    if kind == "distance":
        return pc.Distance([[0, 1]], rest_length=rng.uniform(0.2, 2.0), compliance=rng.uniform(0, 1e-3))
    if kind == "volume":
        return pc.Volume([[0, 1, 2, 3]], rest_volume=rng.uniform(-0.2, 0.2), compliance=rng.uniform(0, 1e-3))
    if kind == "bending":
        return pc.DihedralBending(
            [[0, 1, 2, 3]], rest_angle=rng.uniform(-3, 3), compliance=rng.uniform(0, 1e-3)
        )
    return pc.ShapeMatching([np.arange(n)], stiffness=rng.uniform(0.2, 1.0))


@pytest.mark.parametrize("kind", ["distance", "volume", "bending", "shape_matching"])
def test_projection_conserves_momentum(kind):
    """One projection with random masses changes neither Σ m Δx nor Σ m x × Δx (1e-6, float64)."""
    rng = np.random.default_rng(7)
    for trial in range(10):
        n = 6 if kind == "shape_matching" else 4
        x = rng.normal(size=(n, 3))
        m = rng.uniform(0.1, 5.0, n)
        model = _model(x, m)
        if kind == "shape_matching":
            # A rest shape different from the current one, so that the projection moves particles.
            c = pc.ShapeMatching([np.arange(n)], stiffness=rng.uniform(0.2, 1.0))
            solver = XPBD(model, iterations=1, schedule="coloring", constraints=[c], contact=False)
            c.rest.assign(rng.normal(size=(n, 3)))
            c.rest_center.assign((m @ c.rest.numpy() / m.sum())[None])
            p = wp.clone(model.particle_q)
            c.project(solver.context(), p, 1e-2)
            dx = p.numpy() - x
        else:
            dx = _project_once(model, _constraint_for(kind, rng, n)) - x
        scale = np.abs(m[:, None] * dx).sum()
        assert scale > 1e-6, f"{kind}: trial {trial} did not move"
        lin = np.abs((m[:, None] * dx).sum(axis=0)).max()
        ang = np.abs((m[:, None] * np.cross(x, dx)).sum(axis=0)).max()
        assert lin < 1e-6 * max(scale, 1.0), f"{kind}: linear momentum change {lin:.3g}"
        assert ang < 1e-6 * max(scale, 1.0), f"{kind}: angular momentum change {ang:.3g}"


def test_zero_compliance_one_iteration_satisfies_distance_exactly():
    """With α = 0 one projection satisfies an isolated distance constraint to 1e-12 (float64)."""
    rng = np.random.default_rng(1)
    for _ in range(10):
        x = rng.normal(size=(2, 3))
        m = rng.uniform(0.1, 5.0, 2)
        rest = rng.uniform(0.1, 3.0)
        p = _project_once(_model(x, m), pc.Distance([[0, 1]], rest_length=rest, compliance=0.0))
        err = abs(np.linalg.norm(p[0] - p[1]) - rest)
        assert err < 1e-12, f"|C| after one projection {err:.3g}"


def test_projection_matches_reference_twin():
    """A compliant distance projection equals the NumPy XPBD update (1e-12)."""
    rng = np.random.default_rng(2)
    x = rng.normal(size=(2, 3))
    m = np.array([0.5, 2.0])
    alpha, dt = 1e-3, 1e-2
    p = _project_once(_model(x, m), pc.Distance([[0, 1]], rest_length=0.3, compliance=alpha), dt=dt)
    expected, _ = ref.xpbd_project(x, 1 / m, ref.distance_c(x, 0.3), ref.distance_grad(x), alpha / dt**2, 0.0)
    np.testing.assert_allclose(p, expected, atol=1e-12)


def test_pinned_particle_is_not_moved_by_projection():
    """A particle with inverse mass 0 keeps its position; the other takes the whole correction."""
    x = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    p = _project_once(_model(x, np.ones(2), pin=[0]), pc.Distance([[0, 1]], rest_length=1.0, compliance=0.0))
    np.testing.assert_allclose(p, [[0, 0, 0], [1, 0, 0]], atol=1e-14)


def test_shape_matching_matches_reference_twin():
    """The shape-matching update equals the NumPy polar-decomposition twin, reflections included (1e-10)."""
    rng = np.random.default_rng(5)
    n = 8
    rest = rng.normal(size=(n, 3))
    m = rng.uniform(0.5, 2.0, n)
    for mirror in (1.0, -1.0):
        cur = rest @ np.diag([1.0, 1.0, mirror]) + rng.normal(scale=0.2, size=(n, 3))
        model = _model(rest, m)
        c = pc.ShapeMatching([np.arange(n)], stiffness=0.7)
        solver = XPBD(model, iterations=1, schedule="coloring", constraints=[c], contact=False)
        p = wp.array(cur, dtype=wp.vec3d, device="cpu")
        c.project(solver.context(), p, 1e-2)
        np.testing.assert_allclose(p.numpy() - cur, ref.shape_match(cur, rest, m, 0.7), atol=1e-10)


@pytest.mark.parametrize("radii", [(0.3, 0.3, 0.3), (0.5, 0.2, 0.1)])
def test_oriented_moment_matches_solid_ellipsoid_inertia(radii):
    """A_i = (1/5) m R diag(r²) equals ∫ρ (R y) yᵀ dV of a solid sphere/ellipsoid (quadrature, 1%)."""

    @wp.kernel
    def k(R: wp.array(dtype=wp.mat33d), r: wp.vec3d, out: wp.array(dtype=wp.mat33d)):
        out[0] = pc.oriented_moment(wp.float64(2.0), R[0], r)

    rng = np.random.default_rng(0)
    R = ref.polar_rotation(rng.normal(size=(3, 3)))
    out = wp.zeros(1, dtype=wp.mat33d, device="cpu")
    wp.launch(k, 1, [wp.array([R], dtype=wp.mat33d, device="cpu"), wp.vec3d(*radii), out], device="cpu")
    expected = ref.ellipsoid_moment(2.0, np.asarray(radii), R)
    np.testing.assert_allclose(out.numpy()[0], expected, atol=0.01 * np.abs(expected).max())
    if radii[0] == radii[1] == radii[2]:
        # The sphere: (1/5) m r² R, i.e. the inertia-like second moment (1/5) m r² per axis.
        np.testing.assert_allclose(out.numpy()[0], 0.2 * 2.0 * radii[0] ** 2 * R, atol=1e-12)


def test_coloring_separates_shared_particles():
    """No two constraints of one colour share a moving particle; pinned particles may be shared."""
    from pliant.geometry import cloth_grid

    g = cloth_grid(12, 9)
    springs = g.springs
    inv_mass = np.ones(len(g.points))
    inv_mass[[0, 5]] = 0.0
    colors = pc.color_constraints(springs, inv_mass)
    assert colors.min() == 0
    for c in range(colors.max() + 1):
        members = springs[colors == c].ravel()
        members = members[inv_mass[members] > 0]
        assert np.unique(members).size == members.size, f"colour {c} has a conflict"
    assert colors.max() + 1 <= 24, f"{colors.max() + 1} colours for max degree 12"


def test_pbd_iteration_stiffness():
    """k' = 1 − (1 − k)^(1/n): n sweeps of k' shrink an error by exactly (1 − k)."""
    for k, n in ((0.5, 4), (0.9, 10), (1.0, 3), (0.0, 5)):
        kp = pc.pbd_iteration_stiffness(k, n)
        assert abs((1 - kp) ** n - (1 - k)) < 1e-12


@wp.func
def _user_distance(x0: Any, x1: Any, x2: Any, x3: Any, rest: Any):
    return wp.length(x0 - x1) - rest


def test_generic_constraint_autodiff_gradient_and_projection():
    """Given only C, Warp's autodiff ∇C equals the analytic one and one projection equals Distance's."""
    rng = np.random.default_rng(9)
    x = rng.normal(size=(2, 3))
    m = np.array([0.7, 1.9])
    model = _model(x, m)
    gen = pc.GenericConstraint(_user_distance, [[0, 1]], params=0.5, compliance=1e-3)
    XPBD(model, iterations=1, constraints=[gen], contact=False)
    c, idx, g = gen.evaluate(model.particle_q)
    assert idx.tolist() == [[0, 1]]
    np.testing.assert_allclose(g[0], ref.distance_grad(x), atol=1e-14)
    np.testing.assert_allclose(c[0], ref.distance_c(x, 0.5), atol=1e-14)
    p_gen = _project_once(model, pc.GenericConstraint(_user_distance, [[0, 1]], params=0.5, compliance=1e-3))
    p_ref = _project_once(model, pc.Distance([[0, 1]], rest_length=0.5, compliance=1e-3))
    np.testing.assert_allclose(p_gen, p_ref, atol=1e-12)


def test_isometric_bending_vanishes_on_planar_stencils_and_projects_exactly():
    """Bergou's K: C = ΣK_i x_i is 0 on planar stencils, ΣK_i = 0, and one α = 0 sweep flattens exactly."""
    rng = np.random.default_rng(11)
    idx = np.array([[0, 1, 2, 3]])
    for _ in range(5):
        flat = np.c_[rng.normal(size=(4, 2)), np.zeros(4)]
        flat[2, 1], flat[3, 1] = abs(flat[2, 1]) + 0.3, -abs(flat[3, 1]) - 0.3  # opposite sides of the edge
        flat[0], flat[1] = [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]
        R = ref.polar_rotation(rng.normal(size=(3, 3)))
        q = flat @ R.T + rng.normal(size=3)
        K = pc.isometric_bending_weights(q, idx)[0]
        assert abs(K.sum()) < 1e-12
        # Any planar configuration (here an in-plane affine map of the rest one) has C = 0.
        A = np.eye(3) + 0.3 * np.outer(R[:, 0], R[:, 1])
        assert np.abs(K @ (q @ A.T)).max() < 1e-12
        bent = q.copy()
        bent[3] += 0.2 * R[:, 2]
        m = rng.uniform(0.5, 2.0, 4)
        model = _model(q, m)
        p = _project_once_from(model, pc.IsometricBending(idx, compliance=0.0), bent)
        assert np.abs(K @ p).max() < 1e-12
        assert np.abs((m[:, None] * (p - bent)).sum(axis=0)).max() < 1e-12


def _project_once_from(model, constraint, start: np.ndarray, dt: float = 1e-2) -> np.ndarray:
    """Positions after one Gauss–Seidel sweep of ``constraint`` from positions ``start``."""
    solver = XPBD(model, iterations=1, schedule="coloring", constraints=[constraint], contact=False)
    p = wp.array(start, dtype=model.vec3, device="cpu")
    ctx = solver.context()
    constraint.begin_step(ctx, model.particle_q, p, dt)
    constraint.project(ctx, p, dt)
    return p.numpy()
