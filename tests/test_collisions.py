"""Colliders, penalty energies, air drag, control points, particle and cloth self-collision."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import pliant as pl
from tests.helpers import energy_fd_check

G = 9.81
DEVICES = ["cpu"] + (["cuda:0"] if wp.is_cuda_available() else [])


def _box_mesh(center, half):
    c, h = np.asarray(center, float), np.asarray(half, float)
    v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * h + c
    faces = np.array(
        [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
         [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    )  # fmt: skip
    # Orient every face outward (away from the centre).
    a, b, cc = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    flip = np.einsum("ij,ij->i", np.cross(b - a, cc - a), (a + b + cc) / 3 - c) < 0
    faces[flip] = faces[flip][:, [0, 2, 1]]
    return v, faces


def _particles(points, radius, dtype="float64", gravity=(0.0, -G, 0.0), velocities=None, device="cpu"):
    b = pl.ModelBuilder(gravity=gravity)
    b.add_particles(points, 1.0, radius=radius, velocities=velocities)
    return b.finalize(device=device, dtype=dtype)


@pytest.mark.parametrize(
    "shape, points",
    [
        ("sphere", [[0.1, 0.45, 0.05], [0.0, -0.2, 0.3]]),
        ("box_face", [[0.05, 0.33, 0.1], [0.45, 0.0, -0.1]]),
        ("box_edge_corner", [[0.45, 0.35, 0.0], [0.44, 0.34, 0.23]]),
        ("capsule", [[0.1, 0.32, 0.0], [0.62, 0.1, 0.05]]),
        ("mesh", [[0.05, 0.33, 0.1], [0.1, -0.05, 0.42]]),
    ],
)
def test_collider_penalty_gradient_and_hessian_match_finite_differences(shape, points):
    """ColliderPenalty: gradient and unprojected Hessian equal central differences (float64)."""
    cols = pl.collision.Colliders()
    if shape == "sphere":
        cols.add_sphere((0, 0, 0), 0.4)
    elif shape == "capsule":
        cols.add_capsule((-0.5, 0, 0), (0.5, 0, 0), 0.25)
    elif shape == "mesh":
        cols.add_mesh(*_box_mesh((0, 0, 0), (0.4, 0.3, 0.35)))
    else:
        rot = [0.0, 0.0, np.sin(0.1), np.cos(0.1)] if shape == "box_face" else None
        cols.add_box((0, 0, 0), (0.4, 0.3, 0.2), rotation=rot)
    model = _particles(points, 0.1)
    energy = pl.energies.ColliderPenalty(cols, stiffness=1e3)
    x = np.asarray(points, float)
    # The mesh BVH is float32: difference over 1 mm (exact for the quadratic penalty on a face).
    g, g_fd, H, H_fd = energy_fd_check(model, energy, x, eps=1e-3 if shape == "mesh" else 1e-6)
    assert np.abs(g).max() > 1.0  # every point is in contact
    np.testing.assert_allclose(g, g_fd, atol=2e-5 * np.abs(g).max())
    np.testing.assert_allclose(H, H_fd, atol=2e-4 * np.abs(H).max())


def test_air_drag_and_control_point_derivatives_match_finite_differences():
    """AirDrag's implicit potential and ControlPoints' springs: gradient and Hessian equal FD (float64)."""
    b = pl.ModelBuilder()
    b.add_cloth_grid(nx=2, ny=2, size=0.2, mass=0.1, stiffness=10.0, origin=(0, 0, 0))
    model = b.finalize(device="cpu", dtype="float64")
    rng = np.random.default_rng(3)
    x = model.particle_q_np + 0.02 * rng.normal(size=(model.particle_count, 3))
    v = wp.array(rng.normal(size=(model.particle_count, 3)), dtype=wp.vec3d)
    drag = pl.energies.AirDrag(0.3, quadratic=0.2, wind=(0.5, 0, 0))
    g, g_fd, H, H_fd = energy_fd_check(model, drag, x, begin=(model.particle_q, v, 0.01))
    np.testing.assert_allclose(g, g_fd, atol=1e-6 * np.abs(g).max())
    np.testing.assert_allclose(H, H_fd, atol=1e-5 * np.abs(H).max())
    handle = pl.energies.ControlPoints(
        model, [[0.0, 0.05, 0.0], [0.2, 0.05, 0.2]], stiffness=40.0, radius=0.15
    )
    g, g_fd, H, H_fd = energy_fd_check(model, handle, x)
    np.testing.assert_allclose(g, g_fd, atol=1e-6 * np.abs(g).max())
    np.testing.assert_allclose(H, H_fd, atol=1e-5 * np.abs(H).max())


def _run_force(model, energies, steps, dt, colliders=None, state=None):
    solver = pl.solvers.ForceSolver(model, energies=energies, integrator=pl.integrators.SymplecticEuler())
    s0 = state if state is not None else model.state()
    s1 = model.state()
    for _ in range(steps):
        solver.step(s0, s1, None, dt)
        if colliders is not None:
            colliders.apply(model, s0, s1, dt)
        s0, s1 = s1, s0
    return s0


def test_block_sliding_on_a_box_collider_stops_after_v2_over_2_mu_g():
    """A particle sliding on a (rotated-frame) box collider with friction μ stops after v²/(2μg) (2%)."""
    v0, mu, dt, r = 1.5, 0.3, 1e-3, 0.01
    cols = pl.collision.Colliders()
    cols.add_box((0, -0.5, 0), (5.0, 0.5, 5.0), rotation=[0, np.sin(0.3), 0, np.cos(0.3)], friction=mu)
    model = _particles([[0.0, r, 0.0]], r, velocities=[[v0, 0.0, 0.0]])
    s = _run_force(model, [pl.energies.Gravity()], int(1.2 * v0 / (mu * G) / dt), dt, cols)
    x, v = s.particle_q.numpy()[0], s.particle_qd.numpy()[0]
    assert np.abs(v).max() < 1e-9
    assert x[1] == pytest.approx(r, abs=1e-4)
    assert x[0] == pytest.approx(v0**2 / (2 * mu * G), rel=0.02)


@pytest.mark.parametrize("kind", ["sphere", "capsule", "mesh"])
def test_restitution_bounce_height_is_e_squared_h(kind):
    """A particle dropped from height h onto a collider bounces back to e²·h (3%)."""
    e, h, dt, r = 0.6, 0.3, 2e-4, 0.01
    cols = pl.collision.Colliders()
    if kind == "sphere":
        cols.add_sphere((0, -0.5, 0), 0.5, restitution=e)
    elif kind == "capsule":
        cols.add_capsule((-1, -0.5, 0), (1, -0.5, 0), 0.5, restitution=e)
    else:
        v, f = _box_mesh((0, -0.5, 0), (1, 0.5, 1))
        cols.add_mesh(v, f, restitution=e)
    model = _particles([[0.0, r + h, 0.0]], r)
    solver = pl.solvers.ForceSolver(
        model, energies=[pl.energies.Gravity()], integrator=pl.integrators.SymplecticEuler()
    )
    s0, s1 = model.state(), model.state()
    peak, bounced = 0.0, False
    for _ in range(int(2.2 * np.sqrt(2 * h / G) / dt)):
        solver.step(s0, s1, None, dt)
        cols.apply(model, s0, s1, dt)
        s0, s1 = s1, s0
        y, vy = s0.particle_q.numpy()[0, 1], s0.particle_qd.numpy()[0, 1]
        bounced = bounced or vy > 0
        if bounced:
            peak = max(peak, y - r)
    assert peak == pytest.approx(e * e * h, rel=0.03)


@pytest.mark.parametrize("device", DEVICES)
def test_cloth_draped_on_sphere_stays_outside(device):
    """A cloth dropped on a sphere ends draped over it with no particle inside radius − 1 mm."""
    radius = 0.3
    b = pl.ModelBuilder()
    b.add_cloth_grid(
        nx=20, ny=20, size=1.0, mass=0.2, youngs_modulus_thickness=200.0, origin=(-0.5, 0.35, -0.5)
    )
    model = b.finalize(device=device, dtype="float32")
    cols = pl.collision.Colliders()
    cols.add_sphere((0, 0, 0), radius, friction=0.4)
    solver = pl.solvers.FastMassSpring(
        model, method="implicit", cg_iterations=40, damping_rate=1.0, collisions=[cols]
    )
    s0, s1 = model.state(), model.state()
    inside_min = np.inf
    for frame in range(90):
        for _ in range(2):
            solver.step(s0, s1, None, 1 / 120)
            s0, s1 = s1, s0
        d = np.linalg.norm(s0.particle_q.numpy(), axis=1)
        inside_min = min(inside_min, d.min())
    x = s0.particle_q.numpy()
    assert np.all(np.isfinite(x))
    assert inside_min > radius - 1e-3
    assert np.linalg.norm(x, axis=1).min() < radius + 0.02  # it really rests on the sphere
    assert x[:, 1].min() < 0.0  # and drapes below the equator


def test_particle_resting_on_mesh_collider_stays_on_top():
    """A particle dropped on a closed mesh box comes to rest on its top face (within 0.5 mm)."""
    r = 0.01
    cols = pl.collision.Colliders()
    cols.add_mesh(*_box_mesh((0, -0.5, 0), (0.5, 0.5, 0.5)))
    model = _particles([[0.1, 0.2, -0.1]], r)
    s = _run_force(model, [pl.energies.Gravity()], 1000, 1e-3, cols)
    assert s.particle_q.numpy()[0, 1] == pytest.approx(r, abs=5e-4)


def test_air_drag_terminal_velocity():
    """A particle falling with linear drag c reaches m g / c; with quadratic drag c₂, sqrt(m g / c₂) (1%)."""
    for lin, quad, expected in ((2.0, 0.0, G / 2.0), (0.0, 0.5, np.sqrt(G / 0.5))):
        model = _particles([[0.0, 0.0, 0.0]], 0.01)
        s = _run_force(model, [pl.energies.Gravity(), pl.energies.AirDrag(lin, quadratic=quad)], 1500, 2e-3)
        assert -s.particle_qd.numpy()[0, 1] == pytest.approx(expected, rel=0.01)


def test_control_points_drag_the_cloth_along():
    """A control point moved 0.1 m up carries its linked particles along (links within 2 mm of rest)."""
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_cloth_grid(nx=8, ny=8, size=0.4, mass=0.05, stiffness=50.0, origin=(0, 0, 0))
    model = b.finalize(device="cpu", dtype="float64")
    handle = pl.energies.ControlPoints(model, [[0.0, 0.0, 0.0]], stiffness=200.0, radius=0.06, damping=0.05)
    solver = pl.solvers.ForceSolver(
        model,
        energies=[pl.energies.Springs(), handle],
        integrator=pl.integrators.SymplecticEuler(),
        damping_rate=2.0,
    )
    s0, s1 = model.state(), model.state()
    dt = 1e-3
    for k in range(3000):
        lift = min(1.0, k * dt / 1.0) * 0.1
        handle.set_positions([[0.0, lift, 0.0]], [[0.0, 0.1 if k * dt < 1.0 else 0.0, 0.0]])
        solver.step(s0, s1, None, dt)
        s0, s1 = s1, s0
    x = s0.particle_q.numpy()
    linked = handle.link_particle.numpy()
    length = np.linalg.norm(x[linked] - np.array([0.0, 0.1, 0.0]), axis=1)
    np.testing.assert_allclose(length, handle.link_rest.numpy(), atol=2e-3)
    assert x[linked, 1].min() > 0.05 and x[-1, 1] < 0.05  # linked particles rose, the far corner did not


@pytest.mark.parametrize("device", DEVICES)
def test_particles_of_different_objects_collide_with_thickness(device):
    """Two particles thrown at each other stop at the thickness apart, conserving momentum."""
    h = 0.05
    model = _particles(
        [[-0.2, 0, 0], [0.2, 0, 0]],
        0.01,
        gravity=(0, 0, 0),
        velocities=[[1, 0, 0], [-1, 0, 0]],
        device=device,
    )
    sc = pl.collision.SelfCollision(model, thickness=h, triangles=False, iterations=1)
    solver = pl.solvers.FastMassSpring(model, collisions=[sc])
    s0, s1 = model.state(), model.state()
    dmin = np.inf
    for _ in range(400):
        solver.step(s0, s1, None, 1e-3)
        s0, s1 = s1, s0
        x = s0.particle_q.numpy()
        dmin = min(dmin, np.linalg.norm(x[0] - x[1]))
    v = s0.particle_qd.numpy()
    assert dmin > h - 1e-6
    assert np.abs(v.sum(axis=0)).max() < 1e-9
    assert np.abs(v).max() < 1e-9  # inelastic: the approaching velocity is removed


def _crossings(x0, x1, tris):
    """Count (particle, triangle) pairs, the particle not a vertex of it, whose signed distance to the
    triangle's plane changes sign between two frames while its projection lies inside the triangle at both."""

    def signed(x):
        a, b, c = x[tris[:, 0]], x[tris[:, 1]], x[tris[:, 2]]
        n = np.cross(b - a, c - a)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        return x @ n.T - np.einsum("tk,tk->t", a, n)[None], n  # [P, T]

    s0, _ = signed(x0)
    s1, _ = signed(x1)
    p_idx, t_idx = np.nonzero(np.sign(s0) != np.sign(s1))
    own = (tris[t_idx] == p_idx[:, None]).any(axis=1)
    p_idx, t_idx = p_idx[~own], t_idx[~own]
    inside = np.ones(p_idx.size, bool)
    for x in (x0, x1):
        a, b, c = x[tris[t_idx, 0]], x[tris[t_idx, 1]], x[tris[t_idx, 2]]
        e0, e1, d = b - a, c - a, x[p_idx] - a
        d00, d01, d11 = (e0 * e0).sum(1), (e0 * e1).sum(1), (e1 * e1).sum(1)
        d20, d21 = (d * e0).sum(1), (d * e1).sum(1)
        den = d00 * d11 - d01 * d01
        v = (d11 * d20 - d01 * d21) / den
        w = (d00 * d21 - d01 * d20) / den
        inside &= (v > 0) & (w > 0) & (v + w < 1)
    return int(inside.sum())


def _fold_setup(self_collision: bool, device: str):
    """The folding cloth: (model, FastMassSpring with or without self-collision, the carried edge's rest
    positions, a function writing the edge's targets at time t [s] into a Control)."""
    n = 14
    b = pl.ModelBuilder()
    b.add_cloth_grid(
        nx=n,
        ny=n,
        size=0.4,
        mass=0.05,
        youngs_modulus_thickness=100.0,
        damping=0.01,
        origin=(-0.2, 0.005, 0.0),
    )
    b.add_ground(friction=0.5)
    edge = np.arange(n + 1)  # the row at z = 0 is carried over the cloth to the far side
    b.add_kinematic(edge)
    model = b.finalize(device=device, dtype="float32")
    handlers = [pl.collision.SelfCollision(model, thickness=0.008, friction=0.2)] if self_collision else []
    solver = pl.solvers.FastMassSpring(
        model, method="implicit", cg_iterations=30, damping_rate=2.0, collisions=handlers
    )
    x_edge = model.particle_q_np[edge]

    def carry(t: float, control: pl.Control) -> None:
        t = min(t, 1.0)  # a half turn in 1 s: z from 0 to 0.35, up to 0.15 and down to 0.025
        angle = np.pi * t
        target = x_edge.copy()
        target[:, 2] = 0.175 - 0.175 * np.cos(angle)
        target[:, 1] = 0.005 + 0.15 * np.sin(angle) + 0.02 * t
        control.set_kinematic_targets(target)

    return model, solver, carry


def _fold(self_collision: bool, device: str = "cpu") -> tuple[int, float]:
    model, solver, carry = _fold_setup(self_collision, device)
    control = model.control()
    tris = model.tri_indices.numpy()
    s0, s1 = model.state(), model.state()
    crossings, dt = 0, 1 / 240
    prev = s0.particle_q.numpy()
    for k in range(300):
        carry(k * dt, control)
        solver.step(s0, s1, control, dt)
        s0, s1 = s1, s0
        cur = s0.particle_q.numpy()
        crossings += _crossings(prev, cur, tris)
        prev = cur
    layers = np.ptp(prev[:, 1])
    return crossings, layers


@pytest.mark.parametrize("device", DEVICES)
def test_cloth_folding_onto_itself_never_passes_through_its_triangles(device):
    """A cloth folded onto itself with self-collision has no particle crossing a triangle in any frame
    (checked geometrically); without it the fold does pass through."""
    crossings, layers = _fold(True, device)
    assert crossings == 0
    assert layers > 0.008  # the folded layer lies on top, at least one thickness up
    crossings_without, _ = _fold(False, device)
    assert crossings_without > 0


def test_force_solver_runs_collision_handlers():
    """ForceSolver(collisions=[...]) keeps a cloth on a sphere outside R + particle radius (1e-6 m)."""
    b = pl.ModelBuilder()
    b.add_cloth_grid(
        nx=12, ny=12, size=1.0, mass=0.2, stiffness=300.0, damping=0.01, origin=(-0.5, 0.6, -0.5)
    )
    m = b.finalize(device="cpu")
    colliders = pl.collision.Colliders()
    colliders.add_sphere((0.0, 0.3, 0.0), 0.25)
    solver = pl.solvers.ForceSolver(
        m,
        pl.energies.mass_spring(),
        pl.integrators.SymplecticEuler(),
        collisions=[colliders],
        damping_rate=2.0,
    )
    x = pl.Simulator(m, solver, frame_dt=1 / 60, substeps=40).run(60, progress=False).x
    d = np.linalg.norm(x[-1] - np.array([0.0, 0.3, 0.0]), axis=1)
    assert d.min() >= 0.25 + 0.005 - 1e-6, f"a particle is {0.255 - d.min():.3g} m inside the sphere"
    assert x[-1, :, 1].min() < 0.3, "the cloth should drape below the sphere's centre"


def test_ground_response_without_a_ground_plane_names_the_fix():
    """respond_to_ground on a model with no ground: a ValueError naming add_ground, before any launch."""
    b = pl.ModelBuilder()
    b.add_particles(np.zeros((2, 3)), mass=1.0)
    model = b.finalize(device="cpu")
    s = model.state()
    coefficients = wp.zeros(2, dtype=model.scalar, device="cpu")
    with pytest.raises(ValueError, match="add_ground"):
        pl.collision.respond_to_ground(model, coefficients, 1e-3, s.x, s.v, s.x, s.v)


@pytest.mark.parametrize("device", DEVICES)
def test_self_collision_frames_replay_as_graphs(device):
    """The fold above stepped by a Simulator: with self-collision (hash-grid build and BVH refit every
    substep) its frames replay as graphs, bit for bit with launch-by-launch frames on the CPU (on CUDA to
    round-off of the order of atomics), and the folded layer still never passes through a triangle."""
    runs = {}
    for graph in (None, False):
        model, solver, carry = _fold_setup(True, device)
        assert solver.collisions[0].graph_blocker() is None
        sim = pl.Simulator(model, solver, frame_dt=1 / 60, substeps=4, control_fn=carry, graph=graph)
        tris = model.tri_indices.numpy()
        crossings, prev = 0, sim.state_0.particle_q.numpy().copy()
        for _ in range(75):
            sim.step_frame()
            cur = sim.state_0.particle_q.numpy().copy()
            crossings += _crossings(prev, cur, tris)
            prev = cur
        runs[graph] = (sim, prev, crossings)
    (graphed, x_g, cross_g), (_, x_d, _) = runs[None], runs[False]
    assert graphed.graph_reason is None and graphed._graphs.replays >= 70
    assert cross_g == 0
    assert np.ptp(x_g[:, 1]) > 0.008  # folded: the carried layer lies on top
    if device == "cpu":
        np.testing.assert_array_equal(x_g, x_d)
    else:
        np.testing.assert_allclose(x_g, x_d, atol=1e-4)
