"""Barrier contact (pl.energies.BarrierContact, IPC): the barrier and its derivatives per pair type against
float64 central differences and the IPC Toolkit's distances, the PSD projection, the continuous collision
detection's bound on constructed motions (closed forms), and implicit steps at Δt = 0.1 s that never
intersect (checked by ipctk.has_intersections and the colliders' signed distances)."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import pliant as pl
from pliant.energies._barrier import barrier_pair_terms
from tests.helpers import energy_fd_check

ipctk = pytest.importorskip("ipctk")

DHAT = 0.01


def b_closed(d: float, dhat: float = DHAT) -> float:
    """IPC's clamped log barrier, written out."""
    return -((d - dhat) ** 2) * np.log(d / dhat) if d < dhat else 0.0


#: Pairs (name, edge_edge, [4, 3] points) inside d̂, one per closest-point region.
PAIRS = [
    ("pt_face", False, [[0.21, 0.32, 0.004], [0, 0, 0], [1, 0.02, 0], [0.01, 1, 0.03]]),
    ("pt_edge", False, [[0.5, -0.003, 0.004], [0, 0, 0], [1, 0, 0.001], [0, 1, 0]]),
    ("pt_vertex", False, [[-0.003, -0.002, 0.004], [0, 0, 0], [1, 0, 0], [0, 1, 0.002]]),
    ("ee_cross", True, [[0, 0, 0.005], [1, 0.1, 0.004], [0.5, -0.5, 0], [0.4, 0.5, 0.001]]),
    ("ee_end", True, [[0, 0, 0.005], [1, 0.1, 0.004], [1.003, -0.5, 0], [1.004, 0.5, 0.001]]),
]


def _fd(P: np.ndarray, ee: bool, eps: float = 1e-7) -> tuple[np.ndarray, np.ndarray]:
    """Central differences of the pair's value (gradient) and of its gradient (Hessian)."""
    x = P.ravel()
    e = np.eye(12) * eps
    plus = barrier_pair_terms((x + e).reshape(12, 4, 3), edge_edge=ee, dhat=DHAT)
    minus = barrier_pair_terms((x - e).reshape(12, 4, 3), edge_edge=ee, dhat=DHAT)
    return (plus[0] - minus[0]) / (2 * eps), ((plus[1] - minus[1]) / (2 * eps)).T


@pytest.mark.parametrize("name,ee,points", PAIRS, ids=[p[0] for p in PAIRS])
def test_pair_barrier_matches_ipctk_distance_and_finite_differences(name, ee, points):
    """b(d) at the IPC Toolkit's distance; ∇b and ∇²b equal float64 central differences (1e-6 relative)."""
    P = np.asarray(points, np.float64)
    v, g, H = barrier_pair_terms(P[None], edge_edge=ee, dhat=DHAT)
    d2 = (ipctk.edge_edge_distance if ee else ipctk.point_triangle_distance)(*P)
    d = float(np.sqrt(d2))
    assert 0 < d < DHAT
    assert v[0] == pytest.approx(b_closed(d), rel=1e-10)
    g_fd, H_fd = _fd(P, ee)
    assert np.abs(g[0] - g_fd).max() <= 1e-6 * np.abs(g_fd).max()
    assert np.abs(H[0] - H_fd).max() <= 1e-6 * np.abs(H_fd).max()
    assert np.abs(H[0] - H[0].T).max() <= 1e-12 * np.abs(H[0]).max()


def test_barrier_is_zero_beyond_dhat_and_c2_at_it():
    """Exactly 0 beyond d̂; at d = d̂(1 − ε), b ≈ d̂²ε³, b′ ≈ −3d̂ε², b″ ≈ 6ε (C² at d̂, leading terms)."""
    P = np.array([[0.2, 0.2, DHAT * 1.01], [0, 0, 0], [1, 0, 0], [0, 1, 0]])
    v, g, H = barrier_pair_terms(P[None], edge_edge=False, dhat=DHAT)
    assert v[0] == 0 and not g.any() and not H.any()
    for eps in (1e-3, 1e-4):
        P[0, 2] = DHAT * (1 - eps)
        v, g, H = barrier_pair_terms(P[None], edge_edge=False, dhat=DHAT)
        # Face region: ∂d/∂p = n = e_z, so g[2] = b′ and H[2, 2] = b″.
        assert v[0] == pytest.approx(DHAT**2 * eps**3, rel=3 * eps)
        assert g[0, 2] == pytest.approx(-3 * DHAT * eps**2, rel=3 * eps)
        assert H[0, 2, 2] == pytest.approx(6 * eps, rel=3 * eps)


@pytest.mark.parametrize("name,ee,points", PAIRS, ids=[p[0] for p in PAIRS])
def test_psd_projection_clamps_the_negative_eigenvalues(name, ee, points):
    """The projected Hessian is V max(Λ, 0) Vᵀ of the exact one (numpy's eigh as the reference)."""
    P = np.asarray(points, np.float64)
    _, _, H = barrier_pair_terms(P[None], edge_edge=ee, dhat=DHAT)
    _, _, Hp = barrier_pair_terms(P[None], edge_edge=ee, dhat=DHAT, project=True)
    lam, V = np.linalg.eigh(H[0])
    ref = (V * np.maximum(lam, 0)) @ V.T
    scale = np.abs(H[0]).max()
    assert lam.min() < -1e-6 * scale, "the example should have a negative eigenvalue to clamp"
    assert np.abs(Hp[0] - ref).max() <= 1e-9 * scale
    assert np.linalg.eigvalsh(Hp[0]).min() >= -1e-9 * scale


def _particles(points, *, ground: bool = True) -> pl.Model:
    b = pl.ModelBuilder()
    b.add_particles(np.asarray(points, float), 0.1, radius=0.001)
    if ground:
        b.add_ground(height=0.0)
    return b.finalize(device="cpu", dtype="float64")


def test_point_plane_energy_closed_form_and_derivatives():
    """Ground: E = κ Σ b(y_i) and its gradient/Hessian against central differences."""
    ys = [0.004, 0.0021, 0.05]
    model = _particles([[0.0, y, 0.1 * k] for k, y in enumerate(ys)])
    e = pl.energies.BarrierContact(dhat=DHAT, kappa=30.0)
    out = wp.zeros(1, dtype=wp.float64)
    e.value(model, model.particle_q, out)
    assert out.numpy()[0] == pytest.approx(30.0 * sum(b_closed(y) for y in ys), rel=1e-12)
    g, g_fd, H, H_fd = energy_fd_check(model, e, model.particle_q_np.copy(), eps=1e-7)
    assert np.abs(g - g_fd).max() <= 1e-6 * np.abs(g_fd).max()
    assert np.abs(H - H_fd).max() <= 1e-6 * np.abs(H_fd).max()


def test_self_contact_energy_is_the_pairs_sum_and_its_hessian_follows_the_pattern():
    """A point over a triangle through the energy: value and gradient equal the pair's; with the initial
    (diagonal) pattern each point's Hessian block is the pair's diagonal block, and after
    ``refresh_pattern`` the whole Hessian equals central differences of the energy's gradient."""
    pts = [[0.21, 0.004, 0.32], [0, 0, 0], [1, 0.0, 0.02], [0.01, 0.03, 1], [0.2, 0.5, 0.3], [0.3, 0.5, 0.3]]
    model = _particles(pts, ground=False)
    e = pl.energies.BarrierContact(
        dhat=DHAT, kappa=7.0, ground=False, self_contact=True, triangles=[[0, 4, 5], [1, 2, 3]]
    )
    v, gp, Hp = barrier_pair_terms(np.asarray(pts[:4])[None], edge_edge=False, dhat=DHAT)
    out = wp.zeros(1, dtype=wp.float64)
    e.value(model, model.particle_q, out)
    assert out.numpy()[0] == pytest.approx(7.0 * v[0], rel=1e-12)
    g, g_fd, H, H_fd = energy_fd_check(model, e, np.asarray(pts, float), eps=1e-7)
    assert np.abs(g[:12] - 7.0 * gp[0]).max() <= 1e-12 * np.abs(g).max()
    assert np.abs(g - g_fd).max() <= 1e-6 * np.abs(g_fd).max()
    for k in range(4):
        blk = slice(3 * k, 3 * k + 3)
        assert np.abs(H[blk, blk] - H_fd[blk, blk]).max() <= 1e-6 * np.abs(H_fd).max()
    assert np.abs(H[:12, :12] - H_fd[:12, :12]).max() > 1e-3 * np.abs(H_fd).max()  # coupling left out
    # Once the pattern holds the pair's points (as the minimisers refresh it each iterate), it is whole.
    e.refresh_pattern(model, model.particle_q)
    assert e.pattern_version(model) == 1
    g, g_fd, H, H_fd = energy_fd_check(model, e, np.asarray(pts, float), eps=1e-7)
    assert np.abs(H - H_fd).max() <= 1e-6 * np.abs(H_fd).max()


def _max_step(model, energy, dx) -> float:
    return energy.max_step(model, model.particle_q, wp.array(np.asarray(dx, float), dtype=wp.vec3d))


def test_ccd_point_to_plane_is_080_of_the_time_of_impact():
    """A point at height y moving by (0, −3y, 0) hits the plane at t = 1/3: the bound is 0.8/3 exactly."""
    y = 0.02
    model = _particles([[0.0, y, 0.0], [1.0, 0.5, 0.0]])
    e = pl.energies.BarrierContact(dhat=DHAT)
    assert _max_step(model, e, [[0.1, -3 * y, 0.0], [0, -0.1, 0]]) == pytest.approx(0.8 / 3, rel=1e-12)
    assert _max_step(model, e, [[0.1, 0.01, 0.0], [0, -0.1, 0]]) == 1.0  # moving away or short of it


def test_ccd_point_through_triangle_and_edge_through_edge():
    """A point 2 cm over a triangle moved 4 cm through it (toi 0.5), and an edge moved through a crossing
    edge (toi 0.5): the bound keeps 20 % of the gap, 0.8 × toi = 0.4, to additive CCD's tolerance."""
    pts = [[0.2, 0.02, 0.3], [0, 0, 0], [1, 0, 0.0], [0, 0, 1], [0.2, 5, 0.3], [0.3, 5, 0.3]]
    model = _particles(pts, ground=False)
    e = pl.energies.BarrierContact(
        dhat=DHAT, ground=False, self_contact=True, triangles=[[0, 4, 5], [1, 2, 3]]
    )
    dx = np.zeros((6, 3))
    dx[0] = [0.01, -0.04, 0.0]
    t = _max_step(model, e, dx)
    assert 0.4 * (1 - 1e-3) <= t <= 0.4
    edges = [[-0.5, 0.02, 0.5], [0.5, 0.02, 0.5], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0, 5, 0.5], [0, -5, 0.5]]
    model = _particles(edges, ground=False)
    e = pl.energies.BarrierContact(
        dhat=DHAT, ground=False, self_contact=True, triangles=[[0, 1, 4], [2, 3, 5]]
    )
    dx = np.zeros((6, 3))
    dx[:2, 1] = -0.04
    t = _max_step(model, e, dx)
    assert 0.4 * (1 - 1e-3) <= t <= 0.4
    dx[:2, 1] = 0.0
    dx[:, 0] = 0.3  # a translation of everything changes no distance
    assert _max_step(model, e, dx) == 1.0


def test_ccd_point_into_sphere_collider():
    """A point 5 cm from a 0.2 m sphere moving radially 10 cm in: 0.8 × toi = 0.4 (conservative advance)."""
    cols = pl.collision.Colliders()
    cols.add_sphere((0, 0.5, 0), 0.2)
    model = _particles([[0.25, 0.5, 0.0]], ground=False)
    e = pl.energies.BarrierContact(dhat=DHAT, ground=False, colliders=cols)
    t = _max_step(model, e, [[-0.1, 0.0, 0.0]])
    assert 0.4 * (1 - 1e-3) <= t <= 0.4


def _collision_mesh(model: pl.Model):
    F = np.ascontiguousarray(model.tri_indices.numpy().reshape(-1, 3).astype(np.int32))
    E = ipctk.edges(F)
    return ipctk.CollisionMesh(model.particle_q_np.astype(np.float64), E, F)


def test_two_cloths_dropped_at_dt_01_never_intersect():
    """Two cloths (one over the other) dropped on the ground with backward Euler at Δt = 0.1 s: every frame
    stays above the ground and free of intersections (ipctk), and the pile comes to rest within d̂."""
    b = pl.ModelBuilder()
    b.add_cloth_grid(nx=5, ny=5, size=0.3, mass=0.05, stiffness=100.0, origin=(0, 0.0, 0))
    b.add_cloth_grid(nx=5, ny=5, size=0.2, mass=0.05, stiffness=100.0, origin=(0.03, 0.15, 0.02), name="top")
    b.add_ground(height=-0.01)
    model = b.finalize(device="cpu", dtype="float32")
    dhat = 2e-3
    bar = pl.energies.BarrierContact(dhat=dhat, self_contact=True)
    solver = pl.solvers.ForceSolver(model, [*pl.energies.mass_spring(), bar], pl.integrators.BackwardEuler())
    assert not solver.contact  # the barrier is the ground contact: no penalty, no projection
    cm = _collision_mesh(model)
    s0, s1 = model.state(), model.state()
    n_bottom = 36
    for _ in range(8):
        solver.step(s0, s1, None, 0.1)
        s0, s1 = s1, s0
        x = s0.particle_q.numpy().astype(np.float64)
        assert x[:, 1].min() > -0.01
        assert not ipctk.has_intersections(cm, x)
    # At rest: the bottom cloth within d̂ of the ground, the top one within d̂ of the bottom one.
    assert x[:n_bottom, 1].max() < -0.01 + dhat
    assert x[n_bottom:, 1].min() > x[:n_bottom, 1].max()
    assert x[n_bottom:, 1].max() < x[:n_bottom, 1].max() + dhat + 1e-4


def test_soft_box_pushed_into_a_sphere_never_penetrates():
    """A FEM box thrown at 3 m/s against a sphere collider with Δt = 0.1 s (30 cm per step, more than the
    box): every vertex stays outside the sphere at every frame."""
    cols = pl.collision.Colliders()
    center, radius = np.array([0.0, 0.0, 0.0]), 0.3
    cols.add_sphere(tuple(center), radius)
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_soft_box(
        cells=(3, 3, 3), size=(0.2, 0.2, 0.2), origin=(-0.5, 0.0, 0.0), density=500.0, E=2e4, nu=0.3,
        velocity=(3.0, 0.0, 0.0),
    )  # fmt: skip
    model = b.finalize(device="cpu", dtype="float32")
    bar = pl.energies.BarrierContact(dhat=2e-3, ground=False, colliders=cols)
    solver = pl.solvers.ForceSolver(model, [pl.energies.NeoHookean(), bar], pl.integrators.BackwardEuler())
    s0, s1 = model.state(), model.state()
    closest = np.inf
    for _ in range(6):
        solver.step(s0, s1, None, 0.1)
        s0, s1 = s1, s0
        x = s0.particle_q.numpy().astype(np.float64)
        phi = np.linalg.norm(x - center, axis=1) - radius
        assert phi.min() > 0
        closest = min(closest, phi.min())
    assert closest < 2e-3  # it did reach the sphere


BARRIER_SCENE = """
[scene]
name = "barrier_drop"
frame_dt = 0.1
substeps = 1
frames = 3
device = "cpu"
[[objects]]
kind = "cloth"
nx = 4
ny = 4
size = 0.2
origin = [-0.1, 0.05, -0.1]
mass = 0.02
[objects.material]
stiffness = 50.0
[[colliders]]
kind = "sphere"
center = [0.0, -0.25, 0.0]
radius = 0.27
[ground]
contact = "barrier"
dhat = 0.002
[solver]
kind = "force"
integrator = "BackwardEuler"
self_collision = { thickness = 0.002, contact = "barrier" }
"""


def test_scene_barrier_contact_option():
    """``[ground] contact = "barrier"`` (with the colliders) and ``self_collision.contact = "barrier"`` build
    two BarrierContact terms and no post-step handlers; an explicit integrator is refused."""
    cfg = pl.scene.parse_scene(BARRIER_SCENE)
    scene = pl.scene.build_scene(cfg)
    bars = [e for e in scene.solver.energies if isinstance(e, pl.energies.BarrierContact)]
    assert [(b.dhat, b.ground, b.colliders is not None, b.self_contact) for b in bars] == [
        (0.002, True, True, False),
        (0.002, False, False, True),
    ]
    assert scene.solver.collisions == [] and not scene.solver.contact
    s0, s1 = scene.model.state(), scene.model.state()
    for _ in range(3):
        scene.solver.step(s0, s1, None, 0.1)
        s0, s1 = s1, s0
        x = s0.particle_q.numpy()
        assert (np.linalg.norm(x - [0.0, -0.25, 0.0], axis=1) > 0.27).all()
    with pytest.raises(pl.scene.SceneError, match="ground.contact.*implicit integrator"):
        pl.scene.build_scene(pl.scene.parse_scene(BARRIER_SCENE.replace("BackwardEuler", "SymplecticEuler")))


def test_lagged_friction_derivatives():
    """The friction potential's gradient and Hessian (sliding and sticking particles) against central
    differences, with the normal forces lagged at the step's start."""
    cols = pl.collision.Colliders()
    cols.add_sphere((0, 0.5, 0), 0.2, friction=0.3)
    b = pl.ModelBuilder()
    b.add_particles([[0.0, 0.004, 0.0], [0.3, 0.0021, 0.1], [0.0, 0.295, 0.01]], 0.1, radius=0.01)
    b.add_ground(height=0.0, friction=0.6)
    model = b.finalize(device="cpu", dtype="float64")
    e = pl.energies.BarrierContact(dhat=DHAT, kappa=50.0, colliders=cols, friction=True, stick_velocity=0.01)
    x = model.particle_q_np.copy()
    x[0] += [0.003, 0.0, 0.001]  # slides: |u| = 3.2 mm > ε = 1 mm
    x[1] += [0.0002, 0.0, -0.0003]  # sticks: |u| < ε
    x[2] += [0.002, 0.0005, 0.0]
    begin = (model.particle_q, wp.zeros(3, dtype=wp.vec3d), 0.1)
    g, g_fd, H, H_fd = energy_fd_check(model, e, x, eps=1e-7, begin=begin)
    assert np.abs(g - g_fd).max() <= 1e-6 * np.abs(g_fd).max()
    assert np.abs(H - H_fd).max() <= 1e-5 * np.abs(H_fd).max()


def _patch_on_ground(mu: float, gravity) -> tuple:
    b = pl.ModelBuilder(gravity=gravity)
    b.add_cloth_grid(nx=3, ny=3, size=0.1, mass=0.01, stiffness=50.0, origin=(0, 0.0015, 0))
    b.add_ground(height=0.0, friction=mu)
    model = b.finalize(device="cpu", dtype="float64")
    bar = pl.energies.BarrierContact(dhat=2e-3, friction=True)
    solver = pl.solvers.ForceSolver(model, [*pl.energies.mass_spring(), bar], pl.integrators.BackwardEuler())
    s0, s1 = model.state(), model.state()
    for _ in range(10):  # settle onto the barrier before measuring
        solver.step(s0, s1, None, 0.01)
        s0, s1 = s1, s0
    return solver, s0, s1


def _run(solver, s0, s1, steps: int, dt: float = 0.01) -> tuple:
    for _ in range(steps):
        solver.step(s0, s1, None, dt)
        s0, s1 = s1, s0
    return s0, s1


def test_lagged_friction_decelerates_at_mu_g_and_sticks_on_a_slope():
    """Sliding at 1 m/s with μ = 0.5: v drops by μg Δt per step (0.1 %). On a slope tan θ = 0.3: μ = 0.2
    slides at g(sin θ − μ cos θ) (0.1 %); μ = 0.5 creeps less than ε_v = 1e-4 m/s over 1 s."""
    solver, s0, s1 = _patch_on_ground(0.5, (0.0, -9.81, 0.0))
    v = s0.particle_qd.numpy()
    v[:] = (1.0, 0.0, 0.0)
    s0.particle_qd.assign(v)
    s0, s1 = _run(solver, s0, s1, 10)
    assert s0.particle_qd.numpy()[:, 0].mean() == pytest.approx(1.0 - 0.5 * 9.81 * 0.1, rel=1e-3)
    th = np.arctan(0.3)
    g = (9.81 * np.sin(th), -9.81 * np.cos(th), 0.0)
    solver, s0, s1 = _patch_on_ground(0.2, g)
    s0, s1 = _run(solver, s0, s1, 5)
    v0 = s0.particle_qd.numpy()[:, 0].mean()
    s0, s1 = _run(solver, s0, s1, 20)
    accel = (s0.particle_qd.numpy()[:, 0].mean() - v0) / 0.2
    assert accel == pytest.approx(9.81 * (np.sin(th) - 0.2 * np.cos(th)), rel=1e-3)
    solver, s0, s1 = _patch_on_ground(0.5, g)
    x0 = s0.particle_q.numpy().copy()
    s0, s1 = _run(solver, s0, s1, 100)
    assert 0 <= (s0.particle_q.numpy() - x0)[:, 0].max() < 1e-4 * 1.0


def test_explicit_integrator_is_refused():
    """Without Newton's CCD-bounded steps the barrier cannot hold: a one-line error naming the fix."""
    model = _particles([[0.0, 0.1, 0.0]])
    with pytest.raises(ValueError, match="barrier contact needs an implicit integrator.*BackwardEuler"):
        pl.solvers.ForceSolver(model, [pl.energies.BarrierContact()], pl.integrators.SymplecticEuler())


def test_self_contact_friction_derivatives():
    """Lagged friction of a point over a triangle (and the edge pairs it brings): gradient and whole
    Hessian (pattern refreshed) against central differences, sliding and sticking."""
    pts = [[0.21, 0.004, 0.32], [0, 0, 0], [1, 0.0, 0.02], [0.01, 0.003, 1], [0.2, 0.5, 0.3], [0.3, 0.5, 0.3]]
    model = _particles(pts, ground=False)
    e = pl.energies.BarrierContact(
        dhat=DHAT, kappa=7.0, ground=False, self_contact=True, triangles=[[0, 4, 5], [1, 2, 3]],
        self_friction=0.4, stick_velocity=0.01,
    )  # fmt: skip
    begin = (model.particle_q, wp.zeros(6, dtype=wp.vec3d), 0.1)  # ε = 1 mm
    for shift in (0.003, 0.0004):  # sliding, sticking
        x = np.asarray(pts, float)
        x[0] += [shift, 0.0005, -shift / 2]
        e.refresh_pattern(model, wp.array(x, dtype=wp.vec3d))
        g, g_fd, H, H_fd = energy_fd_check(model, e, x, eps=1e-7, begin=begin)
        assert np.abs(g - g_fd).max() <= 1e-6 * np.abs(g_fd).max()
        assert np.abs(H - H_fd).max() <= 1e-5 * np.abs(H_fd).max()
    # The friction part is there: without it the gradient differs.
    g0 = energy_fd_check(model, pl.energies.BarrierContact(
        dhat=DHAT, kappa=7.0, ground=False, self_contact=True, triangles=[[0, 4, 5], [1, 2, 3]]
    ), x, eps=1e-7)[0]  # fmt: skip
    assert np.abs(g - g0).max() > 1e-3 * np.abs(g).max()


def test_self_contact_friction_decelerates_a_cloth_on_a_cloth():
    """A 3×3 patch sliding at 0.5 m/s on a pinned cloth, self-contact μ = 0.4, loses μgΔt per step (1 %)."""
    b = pl.ModelBuilder()
    b.add_cloth_grid(
        nx=8, ny=8, size=0.8, mass=0.1, stiffness=100.0, origin=(-0.4, 0.0, -0.4), pin=list(range(81))
    )
    b.add_cloth_grid(
        nx=3, ny=3, size=0.1, mass=0.01, stiffness=50.0, origin=(-0.2, 0.0015, -0.05), name="patch"
    )
    model = b.finalize(device="cpu", dtype="float64")
    bar = pl.energies.BarrierContact(dhat=2e-3, ground=False, self_contact=True, self_friction=0.4)
    solver = pl.solvers.ForceSolver(model, [*pl.energies.mass_spring(), bar], pl.integrators.BackwardEuler())
    s0, s1 = _run(solver, model.state(), model.state(), 10)
    v = s0.particle_qd.numpy()
    v[81:] = (0.5, 0.0, 0.0)
    s0.particle_qd.assign(v)
    s0, s1 = _run(solver, s0, s1, 5)
    assert s0.particle_qd.numpy()[81:, 0].mean() == pytest.approx(0.5 - 0.4 * 9.81 * 0.05, rel=1e-2)


def test_barrier_problems_take_the_host_newton():
    """Asking for L-BFGS still runs the host Newton (the CCD bound and the feasible start are its), and a
    point released 1 cm over the ground at 3 m/s downwards stops above it in one 0.1 s step."""
    model = _particles([[0.0, 0.01, 0.0]])
    state = model.state()
    state.particle_qd.assign(np.array([[0.0, -3.0, 0.0]]))
    bar = pl.energies.BarrierContact(dhat=2e-3, kappa=10.0)
    solver = pl.solvers.ForceSolver(
        model, [pl.energies.Gravity(), bar], pl.integrators.BackwardEuler(), minimizer={"method": "lbfgs"}
    )
    out = model.state()
    solver.step(state, out, None, 0.1)
    assert solver.last_stats.linear_solver != "lbfgs"
    assert 0.0 < out.particle_q.numpy()[0, 1] < 2e-3
