"""Mass distribution as something the fit can explain (issue 38 item 2): lumped, uniform per particle, their
blend α (``mass_uniformity``) and a smooth density field (``mass_slope_*``) keep the total mass; every
solver falls at g whatever the distribution, pins stay put; the fit searches α when the tracks cover the
object, and recovers even masses from a fixture made with them."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from helpers import FIT_ROPE
from test_fit_slow import FEM_BOX

import pliant as pl
from pliant.fit import Problem, choose_mass_distribution, cmaes, observe
from pliant.fit._params import default_params, lumped_spread, tracks_cover
from pliant.model import distribute_mass, distribute_mass_grad
from pliant.model._mass import normalised_coordinates

#: A 4 × 4 cloth hung by two corners, explicit steps, float64 on the CPU.
CLOTH = (
    FIT_ROPE.replace(
        'kind = "rope"\nn_segments = 6\nlength = 0.3\norigin = [0.0, 0.5, 0.0]\ndirection = [1.0, 0.0, 0.0]',
        'kind = "cloth"\nnx = 4\nny = 4\nsize = 0.3\norigin = [-0.15, 0.5, -0.15]\nplane = "xz"',
    )
    .replace('pin = "first"', 'pin = "top-corners"')
    .replace("frames = 10", "frames = 24")
    .replace("stiffness = 50.0", "stiffness = 20.0")
)

OPTIONS = [
    {},
    {"mass_distribution": "uniform"},
    {"mass_uniformity": 0.3},
    {"mass_slope_x": 1.2, "mass_slope_z": -0.7},
    {"mass_distribution": "uniform", "mass_slope_y": 0.5},
]


def _scene(text: str, **fields: object) -> pl.scene.Scene:
    cfg = pl.scene.parse_scene(text)
    for k, v in fields.items():
        setattr(cfg.objects[0], k, v)
    return pl.scene.build_scene(cfg)


def _masses(text: str, **fields: object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    m = _scene(text, **fields).model
    return m.particle_mass.numpy(), m.particle_inv_mass.numpy(), m.particle_q.numpy()


#: A 2 × 2 × 2-cell FEM box, 0.2 m, 500 kg/m³: 4 kg.
BOX = FEM_BOX.replace("cells = [1, 1, 1]", "cells = [2, 2, 2]")


@pytest.mark.parametrize(
    ("text", "total"), [(FIT_ROPE, 0.05), (CLOTH, 0.05), (BOX, 4.0)], ids=["rope", "cloth", "box"]
)
@pytest.mark.parametrize("fields", OPTIONS, ids=lambda f: "-".join(f) or "lumped")
def test_every_option_keeps_the_total_mass(text, total, fields):
    """Σ m equals the object's mass (0.05 kg; the box's ρV = 4 kg) to float64 rounding for every
    distribution, and the masses are positive."""
    m, _, _ = _masses(text, **fields)
    assert m.sum() == pytest.approx(total, rel=1e-13) and np.all(m > 0)


def test_uniform_gives_equal_masses_and_the_blend_ends_are_exact():
    """uniform: M/N to every particle, bit for bit (M: the lumped masses' sum, which differ by a factor 4);
    α = 0 is the lumped default bit for bit, α = 1 is uniform bit for bit, and α = ½ is the mean of the two
    (linear in α)."""
    lumped, _, _ = _masses(CLOTH)
    uniform, _, _ = _masses(CLOTH, mass_distribution="uniform")
    assert np.all(uniform == lumped.sum() / 25) and lumped.max() > 2.0 * lumped.min()
    assert np.array_equal(_masses(CLOTH, mass_uniformity=0.0)[0], lumped)
    assert np.array_equal(_masses(CLOTH, mass_uniformity=1.0)[0], uniform)
    half, _, _ = _masses(CLOTH, mass_uniformity=0.5)
    np.testing.assert_allclose(half, 0.5 * (lumped + uniform), rtol=1e-14)
    # mass_uniformity overrides the named distribution
    assert np.array_equal(_masses(CLOTH, mass_distribution="uniform", mass_uniformity=0.0)[0], lumped)


def test_density_field_is_exp_of_the_slope_under_the_total_mass_constraint():
    """m_i / m_lumped,i ∝ exp(a · x̂_i) with x̂ ∈ [−1, 1] over the rest box: the ratio's log is linear in x̂
    with slope a (so the density at +x is exp(2 aₓ) times that at −x), and ∫ρ dV = Σ m = M."""
    rng = np.random.default_rng(3)
    pts = rng.uniform(-0.2, 0.4, (50, 3))
    lumped = rng.uniform(0.5, 2.0, 50)
    a = np.array([0.8, -1.5, 0.3])
    m = distribute_mass(lumped, pts, slope=a)
    xh = normalised_coordinates(pts)
    assert xh.min() == -1.0 and xh.max() == 1.0
    assert m.sum() == pytest.approx(lumped.sum(), rel=1e-14)
    log_ratio = np.log(m / lumped)
    coef, *_ = np.linalg.lstsq(np.c_[xh, np.ones(50)], log_ratio, rcond=None)
    np.testing.assert_allclose(coef[:3], a, atol=1e-12)
    # a flat cloth spans no y: its slope along y changes nothing
    flat = pts.copy()
    flat[:, 1] = 0.1
    np.testing.assert_allclose(distribute_mass(lumped, flat, slope=(0.0, 2.0, 0.0)), lumped, rtol=1e-14)
    with pytest.raises(ValueError, match="uniformity must be in"):
        distribute_mass(lumped, pts, uniformity=1.5)


SOLVERS = {
    "symplectic": 'integrator = "SymplecticEuler"',
    "backward_euler": 'integrator = "BackwardEuler"',
    "fast_mass_spring": 'kind = "fast_mass_spring"',
    "fast_mass_spring_implicit": 'kind = "fast_mass_spring"\noptions = { method = "implicit" }',
    "xpbd": 'kind = "xpbd"\niterations = 4',
}


def _solver_text(solver: str) -> str:
    text = CLOTH.replace('integrator = "SymplecticEuler"\ndamping_rate = 0.5', SOLVERS[solver])
    text = text.replace("frames = 24", "frames = 5").replace("substeps = 10", "substeps = 40")
    return text.replace('kind = "cloth"', 'kind = "cloth"\nmodel = "pbd"') if solver == "xpbd" else text


@pytest.mark.parametrize("solver", list(SOLVERS))
def test_masses_written_in_place_reach_every_solver(solver):
    """Uniform masses written into a lumped scene's particle_mass / particle_inv_mass (pins kept at 1/m = 0),
    then ``refresh_parameters()``: the hung cloth swings as the scene built uniform does, to rounding (each
    solver reads the mass arrays in its step; FastMassSpring's implicit system assembles M each step)."""
    built = _scene(_solver_text(solver), mass_distribution="uniform")
    ref = built.simulator().run(frames=5, progress=False).x
    s = _scene(_solver_text(solver))
    m = s.model
    inv = m.particle_inv_mass.numpy()
    new = built.model.particle_mass.numpy()
    m.particle_mass.assign(new)
    m.particle_inv_mass.assign(np.where(inv > 0, 1.0 / new, 0.0))
    assert s.solver.refresh_parameters() is None
    x = s.simulator().run(frames=5, progress=False).x
    assert np.abs(ref[-1] - ref[0]).max() > 0.01  # it moved
    np.testing.assert_allclose(x, ref, rtol=0, atol=1e-12)


@pytest.mark.parametrize("solver", list(SOLVERS))
def test_free_fall_is_g_and_pins_hold_for_every_distribution(solver):
    """Under each solver, whatever its mass distribution: a free cloth at rest falls at g (m g / m: the
    gravity force takes the new masses), on lumped's trajectory to rounding; a cloth hung by two corners
    keeps them where they are."""
    text = _solver_text(solver)
    falls = {}
    for fields in OPTIONS:
        s = _scene(text.replace('pin = "top-corners"', 'pin = "none"'), **fields)
        falls[str(fields)] = s.simulator().run(frames=5, progress=False).x
        hung = _scene(text, **fields)
        x = hung.simulator().run(frames=5, progress=False).x
        pinned = hung.model.particle_inv_mass.numpy() == 0
        assert pinned.sum() == 2 and np.array_equal(x[:, pinned], np.broadcast_to(x[0, pinned], (6, 2, 3)))
    x = falls[str({})]
    t, h = 5 * 0.04, 0.001
    drop = x[0, :, 1] - x[-1, :, 1]
    # Each step v −= g h, then x += h v: after n steps the drop is ½ g h² n (n + 1) = ½ g t (t + h).
    np.testing.assert_allclose(drop, 0.5 * 9.81 * t * (t + h), rtol=1e-9)
    for key, y in falls.items():
        np.testing.assert_allclose(y, x, rtol=0, atol=1e-12, err_msg=key)


def test_the_fit_searches_the_mass_only_when_the_tracks_cover_the_object():
    """All 25 particles of the cloth tracked: mass_uniformity joins the defaults with its reason; 12 of 25
    (a particle a quarter of the cloth's diagonal from the nearest track): it does not; every particle of a
    rope tracked: it does not either (a rope's masses are even already)."""
    cfg = pl.scene.parse_scene(CLOTH)
    scene = pl.scene.build_scene(cfg)
    full, sparse = observe(scene, tracks=25), observe(scene, tracks=12)
    assert tracks_cover(cfg, full) == 0.0 and tracks_cover(cfg, sparse) is None
    assert default_params(cfg, full) == ["stiffness", "damping_rate", "damping", "mass_uniformity"]
    assert "mass_uniformity" not in default_params(cfg, sparse)
    p = Problem(cfg, full, params=None)
    b = next(b for b in p.globals if b.name == "mass_uniformity")
    assert (b.lo, b.hi, b.nominal) == (0.0, 1.0, 0.0) and "cover the object" in b.why and "within 0%" in b.why
    assert "differ up to 4×" in b.why and lumped_spread(cfg) == pytest.approx(4.0, rel=1e-12)
    rope = pl.scene.parse_scene(FIT_ROPE)
    assert (
        lumped_spread(rope) == 1.0
        and tracks_cover(rope, observe(pl.scene.build_scene(rope), tracks=7)) == 0.0
    )
    assert "mass_uniformity" not in default_params(rope, observe(pl.scene.build_scene(rope), tracks=7))


def test_mass_choice_recovers_uniform_masses_of_a_fixture_made_with_them():
    """A cloth recorded with even masses (flexcomp's and PhysTwin's), fitted from the lumped default and a
    k twice the truth: CMA-ES over k and α finds α ≥ 0.8 and k within 5 %, and the choice by validation
    error is "uniform" (10× lower than lumped's); the choice on a lumped recording keeps "lumped"."""
    cfg = pl.scene.parse_scene(CLOTH.replace("stiffness = 20.0", "stiffness = 40.0"))  # 2× too stiff
    truth = pl.scene.parse_scene(CLOTH)
    truth.objects[0].mass_distribution = "uniform"
    obs = observe(pl.scene.build_scene(truth), tracks=25)
    p = Problem(cfg, obs, params=["stiffness", "mass_uniformity"], train_fraction=0.6)
    r = cmaes(p, generations=12)
    assert r.values["mass_uniformity"] >= 0.8, r.values
    assert r.values["stiffness"] == pytest.approx(20.0, rel=0.05)
    choice = choose_mass_distribution(p, r.values)
    assert choice.name == "uniform" and choice.uniformity == 1.0, choice.reason
    assert choice.errors["uniform"] < 0.1 * choice.errors["lumped"]
    lumped_obs = observe(pl.scene.build_scene(pl.scene.parse_scene(CLOTH)), tracks=25)
    q = Problem(cfg, lumped_obs, params=["stiffness", "mass_uniformity"], train_fraction=0.6)
    assert choose_mass_distribution(q, {"stiffness": 20.0, "mass_uniformity": 0.6}).name == "lumped"


def test_the_chain_rule_through_the_distribution_matches_finite_differences():
    """∂L/∂α and ∂L/∂a of L = g · m(α, a) (distribute_mass_grad) against central differences, at an
    interior point of the blend."""
    rng = np.random.default_rng(5)
    pts, lumped, g = rng.uniform(-1.0, 2.0, (40, 3)), rng.uniform(0.2, 3.0, 40), rng.normal(size=40)
    alpha, a = 0.35, np.array([0.4, -0.9, 1.3])
    d_alpha, d_slope = distribute_mass_grad(lumped, pts, g, uniformity=alpha, slope=a)

    def loss(al: float, sl: np.ndarray) -> float:
        return float(g @ distribute_mass(lumped, pts, uniformity=al, slope=sl))

    eps = 1e-6
    assert d_alpha == pytest.approx((loss(alpha + eps, a) - loss(alpha - eps, a)) / (2 * eps), rel=1e-7)
    for k in range(3):
        da = eps * np.eye(3)[k]
        fd = (loss(alpha, a + da) - loss(alpha, a - da)) / (2 * eps)
        assert d_slope[k] == pytest.approx(fd, rel=1e-7, abs=1e-12)


@wp.kernel
def _weighted_positions(
    q: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d), out: wp.array(dtype=wp.float64)
):
    i = wp.tid()
    wp.atomic_add(out, 0, wp.dot(q[i], w[i]))


def test_a_rollout_gradient_reaches_the_uniformity_through_the_masses():
    """dL/dα of a swinging cloth's final positions (L = Σ w · x): the rollout's particle_mass gradient
    chained through distribute_mass_grad agrees with central differences of rebuilt scenes to 1e-5."""
    text = CLOTH.replace("frames = 24", "frames = 6")
    rng = np.random.default_rng(2)
    w_np = rng.normal(size=(25, 3))

    def scene(alpha: float, grad: bool = False) -> pl.scene.Scene:
        cfg = pl.scene.parse_scene(text)
        cfg.objects[0].mass_uniformity = alpha
        return pl.scene.build_scene(cfg, requires_grad=grad)

    def plain_loss(alpha: float) -> float:
        return float(np.sum(w_np * scene(alpha).simulator().run(frames=6, progress=False).x[-1]))

    alpha = 0.4
    s = scene(alpha, grad=True)
    w = wp.array(w_np, dtype=wp.vec3d)

    def loss_fn(state: pl.State) -> wp.array:
        out = wp.zeros(1, dtype=wp.float64, requires_grad=True)
        wp.launch(_weighted_positions, state.particle_q.shape[0], [state.particle_q, w, out])
        return out

    res = pl.diff.rollout(
        s.model, s.solver, loss_fn, frames=6, dt=s.substep_dt, substeps=s.substeps, params=["particle_mass"]
    )
    assert res.loss == pytest.approx(plain_loss(alpha), rel=1e-12)
    lumped, _, q0 = _masses(text)
    d_alpha, _ = distribute_mass_grad(lumped, q0, res.grads["particle_mass"], uniformity=alpha)
    eps = 1e-5
    fd = (plain_loss(alpha + eps) - plain_loss(alpha - eps)) / (2 * eps)
    assert abs(fd) > 1e-2 and d_alpha == pytest.approx(fd, rel=1e-5)  # measured: -0.0755 both
