"""Coulomb friction in both regimes on an incline, for every solver family (issue 39).

A small stiff body rests on the ground with gravity tilted so that the plane is effectively inclined at
tan θ = 0.5 (or, for the colliders, gravity straight down on a box collider rotated by θ). Coulomb's law:
below the cone (μ ≥ tan θ) the body stays put, above it it slides with a = g (sin θ − μ cos θ). Figures:
the centre of mass's acceleration along the slope (the slope of its velocity over 0.3-1.5 s, after the
start transient) within 2 % of Coulomb's for μ = 0.3 and 0.45, and at most 1 mm of travel over 1.5 s for
μ = 0.6 (before the static regime held, such a body crept 0.06-0.26 m/s).
"""

from __future__ import annotations

import numpy as np
import pytest

import pliant as pl

G = 9.81
THETA = float(np.arctan(0.5))
#: Gravity tilted by θ about z: the ground y = 0 is the incline, x is down the slope.
TILTED = (G * np.sin(THETA), -G * np.cos(THETA), 0.0)
SIDE, RADIUS, DURATION = 0.1, 0.001, 1.5


def coulomb(mu: float) -> float:
    """Coulomb's acceleration [m/s²] down the slope (0 inside the cone)."""
    return max(G * (np.sin(THETA) - mu * np.cos(THETA)), 0.0)


def _box(mu: float, *, fem: bool, cells: int = 1, gravity=TILTED, ground: bool = True, origin=None, **kw):
    """A 10 cm box resting on the plane: FEM (E = 1 MPa, with weak damped springs so that an explicit step
    does not ring for ever) or a mass-spring box (k = 2·10⁴ N/m)."""
    b = pl.ModelBuilder(gravity=gravity)
    o = (0.0, 0.5 * SIDE + RADIUS, 0.0) if origin is None else origin
    extra = dict(E=1e6, nu=0.3, stiffness=1.0, damping=5.0) if fem else dict(stiffness=2e4, damping=0.5)
    b.add_soft_box(cells=(cells,) * 3, size=(SIDE,) * 3, origin=o, radius=RADIUS, **extra, **kw)
    if ground:
        b.add_ground(0.0, friction=mu, restitution=0.0)
    return b.finalize(device="cpu", dtype="float64")


def _run(
    model: pl.Model, solver, dt: float, axis=(1.0, 0.0, 0.0)
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Times [s], the centre of mass's travel [m] and velocity [m/s] along ``axis``, 60 samples a second."""
    s0, s1 = model.state(), model.state()
    m = model.particle_mass.numpy()
    a = np.asarray(axis, float)
    n, every = int(round(DURATION / dt)), max(1, int(round(1 / (60 * dt))))
    x0 = (m @ s0.particle_q.numpy()) / m.sum() @ a
    ts, xs, vs = [], [], []
    for k in range(n):
        solver.step(s0, s1, None, dt)
        s0, s1 = s1, s0
        if (k + 1) % every == 0:
            ts.append((k + 1) * dt)
            xs.append((m @ s0.particle_q.numpy()) / m.sum() @ a - x0)
            vs.append((m @ s0.particle_qd.numpy()) / m.sum() @ a)
    return np.array(ts), np.array(xs), np.array(vs)


def _check(mu: float, ts: np.ndarray, xs: np.ndarray, vs: np.ndarray) -> None:
    if mu > np.tan(THETA):
        travel = np.abs(xs).max()
        assert travel <= 1e-3, f"μ = {mu} > tan θ: it should rest, but it travelled {travel * 1e3:.3f} mm"
        return
    window = ts >= 0.3
    accel = np.polyfit(ts[window], vs[window], 1)[0]
    assert accel == pytest.approx(coulomb(mu), rel=0.02), f"μ = {mu}: {accel:.4f} m/s² vs {coulomb(mu):.4f}"


def _solver(family: str, model: pl.Model):
    fem = [pl.energies.NeoHookean(), pl.energies.Springs(), pl.energies.Dashpots(), pl.energies.Gravity()]
    if family == "symplectic_euler":
        return pl.solvers.ForceSolver(model, fem, pl.integrators.SymplecticEuler()), 1 / 2400
    if family == "backward_euler":
        return pl.solvers.ForceSolver(model, fem, pl.integrators.BackwardEuler()), 1 / 600
    if family == "implicit_midpoint":
        return pl.solvers.ForceSolver(model, fem, pl.integrators.ImplicitMidpoint()), 1 / 600
    if family == "fast_mass_spring":
        return pl.solvers.FastMassSpring(model), 1 / 2400
    if family == "fast_mass_spring_implicit":
        return pl.solvers.FastMassSpring(model, method="implicit"), 1 / 600
    assert family == "xpbd"
    return pl.solvers.XPBD(model, iterations=10), 1 / 600


FEM_FAMILIES = ("symplectic_euler", "backward_euler", "implicit_midpoint")
FAMILIES = (*FEM_FAMILIES, "fast_mass_spring", "fast_mass_spring_implicit", "xpbd")
FAST = {"symplectic_euler", "fast_mass_spring", "xpbd"}


@pytest.mark.parametrize("mu", [0.3, 0.45, 0.6])
@pytest.mark.parametrize(
    "family", [f if f in FAST else pytest.param(f, marks=pytest.mark.slow) for f in FAMILIES]
)
def test_a_box_on_an_incline_slides_at_coulombs_rate_or_rests(family: str, mu: float):
    """Slides at g(sin θ − μ cos θ) (2 %) for μ < tan θ = 0.5, rests (≤ 1 mm over 1.5 s) for μ = 0.6."""
    model = _box(mu, fem=family in FEM_FAMILIES)
    solver, dt = _solver(family, model)
    _check(mu, *_run(model, solver, dt))


@pytest.mark.parametrize("mu", [0.3, 0.6])
def test_implicit_box_on_an_incline_rests_or_slides(mu: float):
    """The implicit (penalty) ground in the default suite: backward Euler, both regimes."""
    model = _box(mu, fem=True)
    solver, dt = _solver("backward_euler", model)
    _check(mu, *_run(model, solver, dt))


@pytest.mark.parametrize("mu", [0.3, 0.6])
def test_a_box_on_a_tilted_box_collider_slides_or_rests(mu: float):
    """Gravity straight down, a box collider rotated by θ about z: the same two regimes, measured along the
    collider's slope."""
    c, s = np.cos(THETA), np.sin(THETA)
    down, normal = np.array([c, -s, 0.0]), np.array([s, c, 0.0])
    centre = 0.5 * (SIDE + 2 * RADIUS) * normal + 0.02 * down  # resting on the collider's top face at 0
    model = _box(mu, fem=False, gravity=(0.0, -G, 0.0), ground=False, origin=tuple(centre))
    # The box's own axes along the slope: rotate its particles by θ about its centre.
    x = model.particle_q.numpy()
    rot = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    model.particle_q.assign((x - centre) @ rot.T + centre)
    colliders = pl.collision.Colliders()
    quat = (0.0, 0.0, -np.sin(THETA / 2), np.cos(THETA / 2))  # −θ about z: the top face faces `normal`
    colliders.add_box(-1.0 * normal, (3.0, 1.0, 1.0), rotation=quat, friction=mu, restitution=0.0)
    solver = pl.solvers.FastMassSpring(model, collisions=[colliders])
    _check(mu, *_run(model, solver, 1 / 2400, axis=down))


@pytest.mark.parametrize("mu", [0.3, 0.6])
def test_a_particle_on_a_sphere_collider_rests_inside_the_cone(mu: float):
    """A particle on a sphere collider where the surface is inclined at tan θ = 0.5 (polar angle θ): it
    stays within 1 mm over 1.5 s for μ = 0.6 (it crept 11 mm before the static regime held), and slides
    off (more than 5 cm) for μ = 0.3. Symplectic Euler, Δt = 1/600 s."""
    R, r = 0.5, 0.01
    n = np.array([np.sin(THETA), np.cos(THETA), 0.0])
    b = pl.ModelBuilder(gravity=(0.0, -G, 0.0))
    b.add_particles([(R + r) * n], [0.01], radius=r)
    model = b.finalize(device="cpu", dtype="float64")
    colliders = pl.collision.Colliders()
    colliders.add_sphere((0.0, 0.0, 0.0), R, friction=mu, restitution=0.0)
    solver = pl.solvers.ForceSolver(model, [pl.energies.Gravity()], collisions=[colliders])
    s0, s1 = model.state(), model.state()
    x0 = s0.particle_q.numpy()[0].copy()
    travel = 0.0
    for _ in range(int(DURATION * 600)):
        solver.step(s0, s1, None, 1 / 600)
        s0, s1 = s1, s0
        travel = max(travel, float(np.linalg.norm(s0.particle_q.numpy()[0] - x0)))
    if mu > np.tan(THETA):
        assert travel <= 1e-3, f"μ = {mu}: it should rest on the sphere, travelled {travel * 1e3:.3f} mm"
    else:
        assert travel > 0.05, f"μ = {mu}: it should slide off, travelled {travel * 1e3:.1f} mm"


@pytest.mark.parametrize("family", ["symplectic_euler", "xpbd"])
def test_an_oblique_bounce_on_the_ground_has_restitution_and_coulombs_impulse(family: str):
    """A particle dropped from h = 0.1 m with v_x = 2 m/s onto the ground (e = 0.5, μ = 0.2) rises to e²h
    (2 %). Symplectic Euler's projection removes μ(1 + e)√(2gh) of v_x in the impact step (1 %): the
    friction budget is the whole normal velocity change, restitution included. XPBD's velocity pass bounds
    friction by the projection's μ|Δx_n|/Δt alone (Müller et al. 2020): v_x drops by at most μ√(2gh)."""
    h, e, mu, vx0, r, dt = 0.1, 0.5, 0.2, 2.0, 0.01, 1e-4
    b = pl.ModelBuilder(gravity=(0.0, -G, 0.0))
    b.add_particles([[0.0, r + h, 0.0]], [0.01], velocities=[[vx0, 0.0, 0.0]], radius=r)
    b.add_ground(0.0, friction=mu, restitution=e)
    model = b.finalize(device="cpu", dtype="float64")
    if family == "xpbd":
        solver = pl.solvers.XPBD(model, iterations=4)
    else:
        solver = pl.solvers.ForceSolver(model, [pl.energies.Gravity()], pl.integrators.SymplecticEuler())
    s0, s1 = model.state(), model.state()
    peak, vx_after, bounced = 0.0, None, False
    for _ in range(int(2.2 * np.sqrt(2 * h / G) / dt)):
        solver.step(s0, s1, None, dt)
        s0, s1 = s1, s0
        x, v = s0.particle_q.numpy()[0], s0.particle_qd.numpy()[0]
        if v[1] > 0 and not bounced:
            bounced, vx_after = True, float(v[0])
        if bounced:
            peak = max(peak, float(x[1]) - r)
    assert bounced and peak == pytest.approx(e * e * h, rel=0.02)
    vn = np.sqrt(2 * G * h)
    if family == "xpbd":
        assert vx0 - mu * vn * 1.01 <= vx_after < vx0
    else:
        assert vx_after == pytest.approx(vx0 - mu * (1 + e) * vn, rel=0.01)


def test_friction_law_is_c1_through_stick_and_slip():
    """The smoothed law's outgoing speed s'(s) for a budget b: 0 at s = 0, s − b from s = b + ε_v on (the
    unsmoothed slip, exactly), monotonic with a continuous slope through the switch, and below ε_v inside
    the cone (the creep bound)."""
    import warp as wp

    from pliant.collision._friction import friction_scale

    @wp.kernel
    def speeds(
        s_in: wp.array(dtype=wp.float64), b: wp.float64, eps: wp.float64, out: wp.array(dtype=wp.float64)
    ):
        i = wp.tid()
        out[i] = s_in[i] * friction_scale(s_in[i], b, eps)

    b, eps = 2e-3, 1e-4
    s = np.linspace(0.0, 3 * b, 300001)
    out = wp.zeros(s.size, dtype=wp.float64, device="cpu")
    wp.launch(speeds, s.size, [wp.array(s, dtype=wp.float64, device="cpu"), b, eps, out], device="cpu")
    sp = out.numpy()
    slip = s >= b + eps
    np.testing.assert_array_equal(sp[slip], (s[slip] - b) / s[slip] * s[slip])
    assert sp[0] == 0.0 and np.all(np.diff(sp) >= 0)
    assert np.all(sp[s <= b] < eps)
    slope = np.diff(sp) / np.diff(s)
    # No kink (the unsmoothed law's slope jumps from 0 to 1 at s = b): ≤ 2b/ε² ds = 0.008 per sample here.
    assert np.abs(np.diff(slope)).max() < 0.02


def test_scene_ground_defaults_to_the_models_stick_velocity():
    """A scene's ``[ground] stick_velocity`` defaults to :data:`pl.model.STICK_VELOCITY` and reaches the
    model."""
    from pliant.scene._schema import GroundSection

    assert GroundSection().stick_velocity == pl.model.STICK_VELOCITY
    scene = pl.scene.build_scene(pl.scene.load_scene("points_push"), device="cpu")
    assert scene.model.ground.stick_velocity == pl.model.STICK_VELOCITY
