"""The contact registries' contract (issue 39 item 4): every kind in ``pl.collision.CONTACT_KINDS`` and every
law in ``pl.collision.FRICTION_LAWS`` is one file and one registry line, and this test walks them.

Interfaces: each kind packs and validates its parameters, its signed distance's gradient is the finite
difference of φ, the projection after a step puts a penetrating particle on its surface, the penalty and
barrier energies' gradients match finite differences on it, and a scene file can name it. Physics: a
particle on each kind's ``floor()`` (the plane y = 0 near the origin) under gravity tilted to a 1:2 incline
(tan θ = 0.5) slides at Coulomb's g(sin θ − μ cos θ) (2 %) for μ = 0.3 and moves at most 1 mm over 1.5 s
for μ = 0.6, in every solver family: ForceSolver with symplectic and backward Euler, FastMassSpring, XPBD
(the model's ground plane, with its own kernels, is walked beside them).
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import pliant as pl
from tests.helpers import energy_fd_check

G = 9.81
THETA = float(np.arctan(0.5))
TILTED = (G * np.sin(THETA), -G * np.cos(THETA), 0.0)
KINDS = tuple(pl.collision.CONTACT_KINDS)
FAMILIES = ("symplectic_euler", "backward_euler", "fast_mass_spring", "xpbd")
R, DURATION, DT = 0.001, 1.5, 1 / 600


def coulomb(mu: float) -> float:
    """Coulomb's acceleration [m/s²] down the slope (0 inside the cone)."""
    return max(G * (np.sin(THETA) - mu * np.cos(THETA)), 0.0)


def _floor(kind: str, **contact) -> pl.collision.Colliders:
    colliders = pl.collision.Colliders(friction_law=contact.pop("law", "coulomb"))
    colliders.add(kind, **pl.collision.CONTACT_KINDS[kind].floor(), **contact)
    return colliders


def _particle(gravity=TILTED, at=(0.0, R, 0.0), ground: dict | None = None, radius: float = R) -> pl.Model:
    b = pl.ModelBuilder(gravity=gravity)
    b.add_particles([at], [0.01], radius=radius)
    if ground is not None:
        b.add_ground(0.0, **ground)
    return b.finalize(device="cpu", dtype="float64")


def _solver(family: str, model: pl.Model, collisions: list):
    gravity = [pl.energies.Gravity()]
    if family == "symplectic_euler":
        integ = pl.integrators.SymplecticEuler()
        return pl.solvers.ForceSolver(model, gravity, integ, collisions=collisions)
    if family == "backward_euler":
        integ = pl.integrators.BackwardEuler(newton_tol=1e-12)
        return pl.solvers.ForceSolver(model, gravity, integ, collisions=collisions)
    if family == "fast_mass_spring":
        return pl.solvers.FastMassSpring(model, collisions=collisions)
    assert family == "xpbd"
    return pl.solvers.XPBD(model, iterations=2, collisions=collisions)


def _slide(model: pl.Model, solver, steps: int, dt: float = DT) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Times [s], the particle's positions [m] and velocities [m/s], every step."""
    s0, s1 = model.state(), model.state()
    xs, vs = np.empty((steps, 3)), np.empty((steps, 3))
    for k in range(steps):
        solver.step(s0, s1, None, dt)
        s0, s1 = s1, s0
        xs[k], vs[k] = s0.particle_q.numpy()[0], s0.particle_qd.numpy()[0]
    return dt * np.arange(1, steps + 1), xs, vs


def _check_incline(mu: float, ts: np.ndarray, xs: np.ndarray, vs: np.ndarray) -> None:
    if mu > np.tan(THETA):
        travel = np.linalg.norm(xs - xs[0], axis=1).max()
        assert travel <= 1e-3, f"μ = {mu}: it should rest, but it travelled {travel * 1e3:.3f} mm"
        return
    window = ts >= 0.3
    accel = np.polyfit(ts[window], vs[window, 0], 1)[0]
    assert accel == pytest.approx(coulomb(mu), rel=0.02), f"μ = {mu}: {accel:.4f} m/s² vs {coulomb(mu):.4f}"
    assert np.abs(xs[:, 1] - R).max() < 1e-3  # on the surface throughout (the 10 km sphere drops 0.2 mm)


@pytest.mark.parametrize("mu", [0.3, 0.6])
@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("kind", (*KINDS, "ground"))
def test_every_kind_rests_or_slides_on_an_incline_in_every_family(kind: str, family: str, mu: float):
    """Coulomb's two regimes on a 1:2 incline, per kind × solver family (the module docstring)."""
    if kind == "ground":
        model, collisions = _particle(ground=dict(friction=mu, restitution=0.0)), []
    else:
        model, collisions = _particle(), [_floor(kind, friction=mu)]
    solver = _solver(family, model, collisions)
    _check_incline(mu, *_slide(model, solver, int(DURATION / DT)))


@pytest.mark.parametrize("mu", [0.3, 0.6])
@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("law", tuple(pl.collision.FRICTION_LAWS))
def test_every_friction_law_rests_or_slides_on_an_incline(law: str, family: str, mu: float):
    """Each registered law keeps Coulomb's two regimes (it may smooth the switch, not move it), on a box
    collider and on the model's ground (whose kernels dispatch on the law too) in every family."""
    for ground in (False, True):
        if ground:
            model, collisions = _particle(ground=dict(friction=mu, restitution=0.0, friction_law=law)), []
        else:
            model, collisions = _particle(), [_floor("box", friction=mu, law=law)]
        _check_incline(mu, *_slide(model, _solver(family, model, collisions), int(DURATION / DT)))


def test_the_registries_are_consistent():
    """Unique codes, names that match their keys, a floor for every kind, a scene kind built from every
    kind's declared keys, and a drawing."""
    from pliant.scene._registry import COLLIDER_KINDS

    kinds = pl.collision.CONTACT_KINDS.values()
    assert len({k.code for k in kinds}) == len(kinds)
    assert all(name == k.name for name, k in pl.collision.CONTACT_KINDS.items())
    func = type(pl.collision.friction_velocity)  # what @wp.func makes
    assert all(isinstance(k.sdf, func) for k in kinds)
    assert set(pl.collision.CONTACT_KINDS) <= set(COLLIDER_KINDS), "a kind without a [[colliders]] schema"
    for k in kinds:  # its scene keys are its schema's, and its drawing of its floor is a triangle mesh
        assert {p.name for p in k.scene} <= set(COLLIDER_KINDS[k.name].schema.model_fields), k.name
        if k.draw is not None:
            v, f = k.draw(**k.floor())
            assert np.all(np.isfinite(v)) and v.shape[1] == 3 and f.min() >= 0 and f.max() < len(v), k.name
    laws = pl.collision.FRICTION_LAWS.values()
    assert len({law.code for law in laws}) == len(laws)
    assert all(isinstance(law.scale, func) for law in laws)
    with pytest.raises(ValueError, match="friction_law must be one of"):
        pl.collision.Colliders(friction_law="viscous")
    with pytest.raises(ValueError, match="collider kind must be one of"):
        pl.collision.Colliders().add("torus")
    model = _particle(ground=dict(friction_law="viscous"))
    with pytest.raises(ValueError, match="friction_law must be one of"):
        _solver("symplectic_euler", model, [])


@pytest.mark.parametrize("kind", KINDS)
def test_every_kind_implements_every_interface(kind: str):
    """φ's gradient is its finite difference; the projection puts a particle 1 cm deep on the surface;
    the penalty's and the barrier's gradients match finite differences."""
    colliders = _floor(kind, friction=0.5)
    assert colliders.describe()[0]["kind"] == kind
    model = _particle(gravity=(0.0, -G, 0.0), at=(0.3, -0.01, 0.2), radius=0.0)
    tol = 1e-5 if kind == "mesh" else 1e-8  # the BVH is float32
    # The signed distance and its gradient.
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-3, 3, 8), rng.uniform(0.05, 0.2, 8), rng.uniform(-3, 3, 8)])
    phi, n = colliders.query(model, wp.array(pts, dtype=wp.vec3d))
    h = 1e-3
    for a in range(3):
        e = np.zeros(3)
        e[a] = h
        hi = colliders.query(model, wp.array(pts + e, dtype=wp.vec3d))[0]
        lo = colliders.query(model, wp.array(pts - e, dtype=wp.vec3d))[0]
        np.testing.assert_allclose((hi - lo) / (2 * h), n[:, a], atol=1e-3 if kind == "mesh" else 1e-6)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-9)
    np.testing.assert_allclose(
        phi, pts[:, 1], atol=1e-3 if kind in ("sphere", "capsule") else tol
    )  # 10 km radius: sags
    # The projection after a step.
    s0, s1 = model.state(), model.state()
    colliders.apply(model, s0, s1, DT)
    x = s1.particle_q.numpy()
    assert colliders.query(model, s1.particle_q)[0][0] == pytest.approx(0.0, abs=tol)
    np.testing.assert_allclose(x[0, [0, 2]], (0.3, 0.2), atol=1e-6)  # pushed out along the normal
    # The penalty energy 5 mm deep, and the barrier 0.5 mm above the surface (within its 1 mm reach).
    for energy, y in ((pl.energies.ColliderPenalty(colliders, stiffness=1e3), -0.005), (None, 5e-4)):
        if energy is None:
            energy = pl.energies.BarrierContact(ground=False, colliders=colliders, kappa=1.0)
        xs = np.array([[0.3, y, 0.2]])
        g, g_fd, _, _ = energy_fd_check(model, energy, xs, eps=1e-7)
        assert np.abs(g).max() > 0
        # Relative to |∇E|: φ's round-off on a 10 km radius is 1e-12 m, 1e-5 of ∇E through a 1e-7 m step.
        atol = (1e-3 if kind == "mesh" else 1e-4) * np.abs(g).max()
        np.testing.assert_allclose(g, g_fd, rtol=1e-4, atol=atol)


def test_a_scene_file_names_a_plane_with_motion_and_compliance():
    """``[[colliders]] kind = "plane"`` with ``velocity``, ``angular_velocity``, ``stiffness`` and
    ``damping_ratio`` reaches the Colliders."""
    cfg = pl.scene.load_scene("points_push")
    cfg = cfg.model_copy(update={"colliders": []})
    raw = cfg.model_dump()
    raw["colliders"] = [
        dict(kind="plane", point=[0, -1, 0], normal=[0, 1, 0], velocity=[0.1, 0, 0], stiffness=2500.0),
        dict(kind="sphere", center=[5, 5, 5], radius=0.1, angular_velocity=[0, 1, 0], damping_ratio=1.0),
    ]
    scene = pl.scene.build_scene(pl.scene.SceneConfig.model_validate(raw), device="cpu")
    d = scene.colliders.describe()
    assert d[0]["kind"] == "plane" and d[0]["velocity"] == [0.1, 0.0, 0.0] and d[0]["stiffness"] == 2500.0
    assert d[1]["angular_velocity"] == [0.0, 1.0, 0.0] and "stiffness" not in d[1]


def test_a_scene_ground_names_its_friction_law():
    """``[ground] friction_law`` reaches the model; an unknown law is a SceneError at that field."""
    raw = pl.scene.load_scene("points_push").model_dump()
    raw["ground"]["friction_law"] = "coulomb_exact"
    scene = pl.scene.build_scene(pl.scene.SceneConfig.model_validate(raw), device="cpu")
    assert scene.model.ground.friction_law == "coulomb_exact"
    raw["ground"]["friction_law"] = "viscous"
    with pytest.raises(pl.scene.SceneError, match="ground.friction_law: unknown law 'viscous'"):
        pl.scene.build_scene(pl.scene.SceneConfig.model_validate(raw), device="cpu")
