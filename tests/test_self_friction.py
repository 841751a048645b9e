"""Self-contact Coulomb friction in both regimes, for every solver family with self-contact (issue 39).

A 10 cm soft box rests on a pinned slab (two triangles of the same model, 10 m wide) with gravity tilted so
that the slab is an incline at tan θ = 0.5, as the ground's incline tests (tests/test_friction_incline.py):
the same figures, with the slab's self-contact friction μ instead of the ground's. Coulomb's law: the box
slides at a = g (sin θ − μ cos θ) (the slope of its centre's velocity over 0.3-1.5 s within 2 %) for
μ = 0.3 and 0.45, and travels at most 1 mm over 1.5 s for μ = 0.6. The projection families use
:class:`pliant.collision.SelfCollision` (point–triangle contact, thickness 5 mm); the barrier path is the
implicit ForceSolver with :class:`pliant.energies.BarrierContact` (self_contact, lagged self_friction);
"xpbd_constraints" is XPBD's own point–triangle contact constraint
(:class:`pliant.constraints.PointTriangleCollision`, friction inside the projection) without any handler.
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
    if family == "xpbd_constraints":
        contact = pl.constraints.PointTriangleCollision(thickness=H, friction=mu)
        return pl.solvers.XPBD(
            model, iterations=10, constraints=[pl.constraints.Distance(), contact]
        ), 1 / 600
    assert family == "barrier"
    # The barrier's points are the surface's vertices: the slab's triangles and the box's boundary.
    tris = np.concatenate([model.tri_indices.numpy().reshape(-1, 3), surface_from_tets(model.tet_indices_np)])
    bar = pl.energies.BarrierContact(
        dhat=DHAT, ground=False, self_contact=True, triangles=tris, self_friction=mu
    )
    return pl.solvers.ForceSolver(model, [*fem, bar], pl.integrators.BackwardEuler()), 1 / 600


FAMILIES = ("symplectic_euler", "backward_euler", "fast_mass_spring", "xpbd", "xpbd_constraints", "barrier")
FAST = {"symplectic_euler", "fast_mass_spring", "xpbd", "xpbd_constraints"}


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


def _apply_once(model: pl.Model, x_pred: np.ndarray, v_pred: np.ndarray, **kw) -> tuple[np.ndarray, ...]:
    """One SelfCollision pass (μ = 0.3, h = 1 cm, no stick smoothing in play) from the model's positions to
    the predicted state; returns (x, v) after it."""
    sc = pl.collision.SelfCollision(model, thickness=0.01, friction=0.3, iterations=1, **kw)
    s_in, s_out = model.state(), model.state()
    s_out.particle_q.assign(x_pred)
    s_out.particle_qd.assign(v_pred)
    sc.apply(model, s_in, s_out, 1e-3)
    return s_out.particle_q.numpy(), s_out.particle_qd.numpy()


def test_a_self_contact_pair_conserves_momentum():
    """Two particles (10 g and 30 g) overlapping in a step, approaching and sliding past each other: the
    pass conserves momentum and the centre of mass (1e-12), stops the approach, and slows the relative
    sliding by exactly μ |Δv_n| (Coulomb's slip). A particle sliding into a free triangle (vertices of
    20-40 g): tangential momentum and the centre's tangential position are conserved the same way (the
    normal push moves the point only), with the same slip law."""
    m = np.array([0.01, 0.03])
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_particles([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]], m, radius=0.001)
    model = b.finalize(device="cpu", dtype="float64")
    x = np.array([[0.0, 0.0, 0.0], [0.006, 0.002, 0.0]])
    v = np.array([[0.3, 0.5, 2.0], [-0.1, 0.3, -1.0]])
    x1, v1 = _apply_once(model, x, v, triangles=False)
    np.testing.assert_allclose(m @ v1, m @ v, rtol=0, atol=1e-12)
    np.testing.assert_allclose(m @ x1, m @ x, rtol=0, atol=1e-12)
    n = (x[0] - x[1]) / np.linalg.norm(x[0] - x[1])
    vn, vn1 = (v[0] - v[1]) @ n, (v1[0] - v1[1]) @ n
    assert vn < 0 and abs(vn1) < 1e-12
    st, st1 = (np.linalg.norm(w - (w @ n) * n) for w in (v[0] - v[1], v1[0] - v1[1]))
    assert st1 == pytest.approx(st - 0.3 * abs(vn), rel=1e-12)

    # A point 4 mm above a free triangle in y = 0 (thickness 1 cm), moving down and sideways.
    m = np.array([0.01, 0.02, 0.03, 0.04])
    start = np.array([[0.1, 0.02, 0.1], [0.0, 0.0, 0.0], [0.0, 0.0, 0.4], [0.4, 0.0, 0.0]])
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_particles(start, m, radius=0.001)
    b.add_triangles([[1, 2, 3]])
    model = b.finalize(device="cpu", dtype="float64")
    x = start + [[0.0, -0.016, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
    v = np.array([[2.0, -1.0, 0.5], [0.1, 0.0, 0.0], [0.0, 0.0, -0.2], [0.0, 0.0, 0.1]])
    x1, v1 = _apply_once(model, x, v, particles=False)
    tangential = [0, 2]
    np.testing.assert_allclose((m @ v1)[tangential], (m @ v)[tangential], rtol=0, atol=1e-12)
    np.testing.assert_allclose((m @ x1)[tangential], (m @ x)[tangential], rtol=0, atol=1e-12)
    assert x1[0, 1] == pytest.approx(0.01, rel=1e-12) and abs(v1[0, 1]) < 1e-12
    w = np.array([1.0, 1.0 - 0.25 - 0.25, 0.25, 0.25])  # point, then the barycentric weights at (0.1, 0.1)
    rel, rel1 = (u[0] - w[1:] @ u[1:] for u in (v, v1))
    assert np.linalg.norm(rel1[tangential]) == pytest.approx(np.linalg.norm(rel[tangential]) - 0.3, rel=1e-12)


def test_vertices_moving_under_a_triangle_carry_it_by_coulomb():
    """A free triangle (springs, 10 g a vertex) resting on three kinematic points 4 mm under it, which move
    sideways at V = 0.2 m/s: only the step bound's separation push touches this contact (the points are
    not free, the triangle is not under a point of its own), and its friction (μ = 0.4) speeds the
    triangle up at μg until it moves with them: v(25 ms) = μg·25 ms (3 %), v(0.3 s) = V (1 %), and
    then it keeps its place on them (≤ 1 mm over 0.2 s). Before the push had friction it stayed put."""
    mu, speed, h, dt = 0.4, 0.2, 0.005, 1 / 2400
    b = pl.ModelBuilder(gravity=(0.0, -9.81, 0.0))
    tri = np.array([[-0.1, h * 0.8, -0.1], [0.1, h * 0.8, -0.1], [0.0, h * 0.8, 0.1]])
    b.add_particles(tri, 0.01, radius=0.001)
    b.add_springs([[0, 1], [1, 2], [2, 0]], stiffness=1e3, damping=1.0)
    b.add_triangles([[0, 2, 1]])
    support = np.array([[-0.03, 0.0, -0.05], [0.03, 0.0, -0.05], [0.0, 0.0, 0.04]])
    first = b.add_particles(support, 1.0, radius=0.0)
    b.add_kinematic(np.arange(first, first + 3))
    model = b.finalize(device="cpu", dtype="float64")
    bound = pl.collision.StepBound(model, fraction=0.4, reach=h, separation=h, friction=mu)
    solver = pl.solvers.ForceSolver(model, pl.energies.mass_spring(), collisions=[bound])
    s0, s1, control = model.state(), model.state(), model.control()
    vx, offset = {}, {}
    for k in range(1, int(0.5 / dt) + 1):
        control.kinematic_targets.assign(support + [speed * k * dt, 0.0, 0.0])
        solver.step(s0, s1, control, dt)
        s0, s1 = s1, s0
        x, v = s0.particle_q.numpy(), s0.particle_qd.numpy()
        vx[k] = v[:3, 0].mean()
        offset[k] = x[:3, 0].mean() - speed * k * dt
    k25, k300, k500 = round(0.025 / dt), round(0.3 / dt), round(0.5 / dt)
    assert vx[k25] == pytest.approx(mu * 9.81 * 0.025, rel=0.03)
    assert vx[k300] == pytest.approx(speed, rel=0.01)
    assert abs(offset[k500] - offset[k300]) <= 1e-3


def _xpbd_step(model: pl.Model, v: np.ndarray, contact, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """One XPBD step (4 sweeps) with only ``contact`` from the model's positions at velocities ``v``;
    returns the start positions and the velocities after it."""
    s0, s1 = model.state(), model.state()
    s0.particle_qd.assign(v)
    pl.solvers.XPBD(model, iterations=4, constraints=[contact]).step(s0, s1, None, dt)
    return s0.particle_q.numpy(), s1.particle_qd.numpy()


def test_xpbd_contact_constraints_conserve_momentum_and_slip_by_coulomb():
    """XPBD's own contact constraints with μ = 0.3, no gravity. Two particles (10 g and 30 g, radius 5 mm)
    whose step overlaps by 0.84 mm while sliding past each other: momentum is conserved (1e-12), the pair
    ends touching and its relative tangential velocity is cut by exactly μ depth/Δt (Coulomb's slip, 1e-12
    relative). A point (10 g) landing 6 mm deep in a free triangle (20-40 g) moving in its plane: momentum
    is conserved in all three axes (1e-12; the normal push moves the triangle too), and the tangential
    velocity of the point against the triangle's point under it is cut by μ depth/Δt to 0.3 % (the
    triangle tilts a little under the push, so the barycentric point is not quite the start's)."""
    mu, dt = 0.3, 2e-3
    m = np.array([0.01, 0.03])
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_particles([[0.0, 0.0, 0.0], [0.012, 0.0, 0.0]], m, radius=0.005)
    model = b.finalize(device="cpu", dtype="float64")
    v = np.array([[1.0, 0.2, 0.5], [-0.5, -0.1, -0.3]])
    x, v1 = _xpbd_step(model, v, pl.constraints.ParticleCollision(friction=mu), dt)
    np.testing.assert_allclose(m @ v1, m @ v, rtol=0, atol=1e-12)
    d = (x[0] + dt * v[0]) - (x[1] + dt * v[1])  # the predicted positions' separation
    n, depth = d / np.linalg.norm(d), 0.01 - np.linalg.norm(d)
    assert depth > 5e-4
    rel, rel1 = dt * (v[0] - v[1]), v1[0] - v1[1]
    assert rel1 @ n == pytest.approx((rel @ n + depth) / dt, rel=1e-12)
    slip = np.linalg.norm(rel - (rel @ n) * n)
    assert slip > mu * depth  # it slides: the budget does not stop it
    assert np.linalg.norm(rel1 - (rel1 @ n) * n) == pytest.approx((slip - mu * depth) / dt, rel=1e-12)

    m = np.array([0.01, 0.02, 0.03, 0.04])
    start = np.array([[0.1, 0.02, 0.1], [0.0, 0.0, 0.0], [0.0, 0.0, 0.4], [0.4, 0.0, 0.0]])
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_particles(start, m, radius=0.001)
    b.add_triangles([[1, 2, 3]])
    model = b.finalize(device="cpu", dtype="float64")
    v = np.array([[2.0, -8.0, 0.5], [0.1, 0.0, 0.0], [0.0, 0.0, -0.2], [0.0, 0.0, 0.1]])
    contact = pl.constraints.PointTriangleCollision(thickness=0.01, friction=mu)
    _, v1 = _xpbd_step(model, v, contact, dt)
    assert int(contact.contact_count.numpy()[0]) == 1
    np.testing.assert_allclose(m @ v1, m @ v, rtol=0, atol=1e-12)
    depth = 0.01 - (0.02 + dt * v[0, 1])  # 6 mm below the thickness
    w = np.array([0.5, 0.25, 0.25])  # the barycentric weights at (0.1, 0.1)
    rel, rel1 = (u[0] - w @ u[1:] for u in (v, v1))
    slip = np.linalg.norm(rel[[0, 2]])
    assert slip > mu * depth / dt
    assert np.linalg.norm(rel1[[0, 2]]) == pytest.approx(slip - mu * depth / dt, rel=3e-3)


@pytest.mark.slow
def test_xpbd_contact_constraints_hold_a_stack_of_boxes():
    """Issue 39's stack of three soft boxes (pliant/examples/_contact_scenes.py) in XPBD with only its own
    contact constraints (no SelfCollision handler, no step bound), μ = 0.6 between the boxes: every box's
    centre stays within 5 mm of where it started, horizontally, over 1.5 s (measured 0.5, 0.7, 1.3 mm; with
    μ = 0 the upper boxes slide 30-39 mm), and they end stacked (2 cm of 0.055, 0.165, 0.275 m)."""
    from pliant.examples import _contact_scenes as cs

    scene = cs.boxes(family="xpbd")
    model = scene.model
    contact = [
        pl.constraints.PointTriangleCollision(thickness=0.005, friction=0.6),
        pl.constraints.ParticleCollision(friction=0.6),
    ]
    scene.solver = pl.solvers.XPBD(
        model, iterations=10, damping=2.0, constraints=[pl.constraints.Distance(compliance=0.0), *contact]
    )
    x = scene.run()
    m = model.particle_mass.numpy()
    n = len(m) // 3
    for k in range(3):
        part = slice(k * n, (k + 1) * n)
        c = (m[part] @ x[:, part]) / m[part].sum()  # [F, 3] the box's centre
        drift = np.linalg.norm(c[:, [0, 2]] - c[0, [0, 2]], axis=1).max()
        assert drift < 0.005, f"box {k} drifted {drift * 1e3:.1f} mm"
        assert abs(c[-1, 1] - (0.055 + k * 0.11)) < 0.02, f"box {k} ends at {c[-1, 1]:.3f} m"


def test_a_scene_gives_its_self_collision_friction_to_xpbds_contact_constraints():
    """``[solver] self_collision.friction`` reaches XPBD's ParticleCollision and PointTriangleCollision (it
    used to reach only the step bound's push), as does a ``[[constraints]] particle_collision``'s friction;
    a negative μ is refused before any work."""
    from pathlib import Path

    from pliant.scene import SceneError, build_scene, parse_scene

    text = (Path(pl.__file__).parent / "scenes" / "xpbd_cloth_sphere.toml").read_text(encoding="utf-8")
    on = text.replace("self_collision = { thickness", "self_collision = { friction = 0.4, thickness")
    solver = build_scene(parse_scene(on, overrides=["scene.frames=1"])).solver
    kinds = (pl.constraints.ParticleCollision, pl.constraints.PointTriangleCollision)
    contact = [c for c in solver.constraints if isinstance(c, kinds)]
    assert len(contact) == 2 and all(c.friction_settings.friction == 0.4 for c in contact)
    extra = on + '\n[[constraints]]\nkind = "particle_collision"\nfriction = 0.25\n'
    solver = build_scene(parse_scene(extra, overrides=["scene.frames=1"])).solver
    mus = sorted(c.friction_settings.friction for c in solver.constraints if isinstance(c, kinds))
    assert mus == [0.25, 0.4, 0.4]
    with pytest.raises(SceneError, match="friction"):
        bad = on.replace("friction = 0.4", "friction = -0.1")
        build_scene(parse_scene(bad, overrides=["scene.frames=1"]))
    with pytest.raises(ValueError, match="PointTriangleCollision: friction must be a finite μ >= 0"):
        pl.constraints.PointTriangleCollision(friction=float("nan"))
