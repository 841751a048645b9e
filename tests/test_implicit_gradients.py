"""Gradients through implicit steps (IFT adjoint) equal central finite differences (float64, CPU).

Each case runs a rollout of ``STEPS`` steps under a ``wp.Tape`` on the plain path — ``finalize(
requires_grad=True)``, one State per step, ``solver.step`` inside the tape, ``tape.backward`` — and compares
the directional derivative ∇L·d along a random direction d of each parameter array with
(L(θ + εd) − L(θ − εd))/2ε. The minimiser is converged tightly (newton_tol 1e-10) so that the finite
differences see the exact minimiser the adjoint differentiates.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import warp as wp

import pliant as pl
from pliant.diff import GradientError
from pliant.model import State

I = pl.integrators
STEPS = 20
DT = 1.0 / 60.0
TOL = 1e-4
EPS_REST = 1e-6
EPS_TET = 1e-3
#: The initial state's step along d (entries ~0.01 m, m/s): 1e-5 m for the rope and the box. At 1e-7 m the
#: rope's v₀ difference was 1.3e-4 off on one CPU and exact on another (L-BFGS's converged steps differ in
#: the last bits with the BLAS kernels the CPU gets); at 1e-5 m they agree to 1e-6. The cloth, strongly
#: nonlinear (it buckles), keeps 1e-7 m, where the differences' O(ε²) error stays below the tolerance.
EPS_STATE = {"rope": 1e-3, "box": 1e-3, "cloth": 1e-5}


@wp.kernel
def _weighted_sum(x: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d), out: wp.array(dtype=wp.float64)):
    i = wp.tid()
    wp.atomic_add(out, 0, wp.dot(x[i], w[i]))


def _rope(ground: bool):
    b = pl.ModelBuilder(gravity=(0.0, -9.81, 0.0))
    b.add_rope(n_segments=8, length=0.8, mass=0.4, stiffness=400.0, damping=5.0, start=(0.0, 0.12, 0.0))
    if ground:
        b.add_ground(0.0, friction=0.0)
    return b


def _cloth(ground: bool):
    b = pl.ModelBuilder(gravity=(0.0, -9.81, 0.0))
    b.add_cloth_grid(
        nx=6,
        ny=6,
        size=0.5,
        mass=0.2,
        stiffness=300.0,
        bend_stiffness=5.0,
        damping=2.0,
        pin="none",
        origin=(0.0, 0.03, 0.0),
        plane="xz",
    )
    if ground:
        b.add_ground(0.0, friction=0.0)
    return b


def _box(ground: bool):
    b = pl.ModelBuilder(gravity=(0.0, -9.81, 0.0))
    b.add_soft_box(
        cells=(2, 2, 2),
        size=(0.1, 0.1, 0.1),
        origin=(0.0, 0.06, 0.0),
        E=2e4,
        nu=0.3,
        density=500.0,
        velocity=(0.3, -0.5, 0.0),
    )
    if ground:
        b.add_ground(0.0, friction=0.0)
    return b


def _energies(kind: str, ground: bool):
    e = pl.energies
    if kind == "box":
        out = [e.TetElasticity(material="neohookean"), e.Gravity()]
    else:
        out = e.mass_spring()
    if ground:
        out.append(e.GroundPenalty(1e3))
    return out


BUILD = {"rope": _rope, "cloth": _cloth, "box": _box}
PARAMS = {
    "rope": ("spring_stiffness", "spring_rest_length", "spring_damping", "particle_mass"),
    "cloth": ("spring_stiffness", "spring_rest_length", "spring_damping", "particle_mass"),
    "box": ("tet_mu", "tet_lam", "particle_mass"),
}


def _rollout(kind, ground, integ_factory, *, perturb=None, record=False):
    """L = Σ w·x_final (+ Σ w'·v_final); with ``record`` also the tape gradients of every parameter."""
    model = BUILD[kind](ground).finalize(device="cpu", dtype="float64", requires_grad=record)
    rng = np.random.default_rng(7)
    v0 = 0.2 * rng.standard_normal((model.particle_count, 3))
    model.particle_qd.assign(model.particle_qd.numpy() + v0)
    if record:
        model.particle_mass.requires_grad = True  # masses as a parameter (the step reads m, not 1/m)
    if perturb is not None:
        name, d, eps = perturb
        a = getattr(model, name)
        a.assign(a.numpy() + eps * d)
        if name == "particle_mass":
            inv = model.particle_inv_mass.numpy()
            model.particle_inv_mass.assign(np.where(inv > 0, 1.0 / a.numpy(), 0.0))
    # ground=True: contact only through the penalty in Φ (the post-step friction is another module's).
    solver = pl.solvers.ForceSolver(model, energies=_energies(kind, ground), contact=False, **integ_factory())
    states = [model.state() for _ in range(STEPS + 1)]
    wx = wp.array(np.random.default_rng(3).standard_normal((model.particle_count, 3)), dtype=wp.vec3d)
    wv = wp.array(0.1 * np.random.default_rng(4).standard_normal((model.particle_count, 3)), dtype=wp.vec3d)
    loss = wp.zeros(1, dtype=wp.float64, requires_grad=True)
    tape = wp.Tape() if record else None
    if record:
        tape.__enter__()
    try:
        for k in range(STEPS):
            solver.step(states[k], states[k + 1], None, DT)
            st = solver.last_stats
            # Converged, or stalled at the round-off floor far below what the finite differences resolve.
            assert st.converged or st.gradient_norm < 1e-8, st
        wp.launch(_weighted_sum, model.particle_count, [states[-1].particle_q, wx, loss])
        wp.launch(_weighted_sum, model.particle_count, [states[-1].particle_qd, wv, loss])
    finally:
        if record:
            tape.__exit__(None, None, None)
    if not record:
        return float(loss.numpy()[0])
    tape.backward(loss)
    grads = {n: getattr(model, n).grad.numpy().copy() for n in PARAMS[kind]}
    grads["x0"] = states[0].particle_q.grad.numpy().copy()
    grads["v0"] = states[0].particle_qd.grad.numpy().copy()
    return float(loss.numpy()[0]), grads, model


def _check(kind, ground, integ_factory, eps=1e-5):
    wp.config.verify_autograd_array_access = True
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            base, grads, model = _rollout(kind, ground, integ_factory, record=True)
    finally:
        wp.config.verify_autograd_array_access = False
    flagged = [str(w.message) for w in caught if "after it has been read" in str(w.message)]
    assert not flagged, flagged
    rng = np.random.default_rng(11)
    errors = {}
    for name in PARAMS[kind]:
        a = getattr(model, name).numpy()
        d = rng.standard_normal(a.shape) * np.abs(a)  # relative perturbation of each entry
        analytic = float(np.sum(grads[name] * d))
        # The rollout is strongly nonlinear in the rest lengths (in-plane stress buckles the flat cloth):
        # a smaller step keeps the differences' O(ε²) error below the tolerance.
        # The free box barely deforms: its μ, λ derivatives are small, and L-BFGS's converged steps are
        # exact only to ~1e-12 m, so a larger step keeps those differences above the noise.
        e = EPS_REST if name == "spring_rest_length" else EPS_TET if name.startswith("tet_") else eps
        lp = _rollout(kind, ground, integ_factory, perturb=(name, d, e))
        lm = _rollout(kind, ground, integ_factory, perturb=(name, d, -e))
        fd = (lp - lm) / (2 * e)
        errors[name] = (analytic, fd)
    # Initial state: the same through the model's initial arrays.
    for name, attr in (("x0", "particle_q"), ("v0", "particle_qd")):
        d = rng.standard_normal(grads[name].shape) * 0.01
        d[model.particle_inv_mass.numpy() == 0] = 0.0
        analytic = float(np.sum(grads[name] * d))
        lp = _rollout(kind, ground, integ_factory, perturb=(attr, d, EPS_STATE[kind]))
        lm = _rollout(kind, ground, integ_factory, perturb=(attr, d, -EPS_STATE[kind]))
        errors[name] = (analytic, (lp - lm) / (2 * EPS_STATE[kind]))
    for name, (analytic, fd) in errors.items():
        rel = abs(analytic - fd) / max(abs(fd), 1e-12)
        print(f"{kind} ground={ground} {name}: tape {analytic:.9g} fd {fd:.9g} rel {rel:.2e}")
        assert abs(fd) > 1e-8, f"{name}: the loss does not depend on it (a useless check)"
        assert rel <= TOL, f"{kind}, {name}: tape {analytic:.10g} vs central differences {fd:.10g}"


TIGHT = {"newton_tol": 1e-10, "max_newton_iterations": 50}
#: ForceSolver keywords per case: the integrator, and the minimiser where it is not Newton.
INTEGRATORS = {
    "be_newton": lambda: {"integrator": I.BackwardEuler(**TIGHT)},
    # L-BFGS converges linearly: to the round-off floor, so that its finite differences are not noise.
    "be_lbfgs": lambda: {
        "integrator": I.BackwardEuler(newton_tol=1e-12),
        "minimizer": {"method": "lbfgs", "lbfgs_max_iterations": 500},
    },
    "midpoint": lambda: {"integrator": I.ImplicitMidpoint(**TIGHT)},
    "bdf2": lambda: {"integrator": I.BDF2(**TIGHT)},
}


# Default suite: every integrator and each scene at least once, with and without ground; the whole matrix
# (same assertions) under -m slow, to keep the default suite's time down.
FAST = {
    ("rope", "be_newton", False),
    ("rope", "be_lbfgs", True),
    ("rope", "midpoint", False),
    ("rope", "bdf2", True),
    ("cloth", "be_newton", True),
    ("box", "be_newton", True),
    ("box", "be_lbfgs", False),  # box-be_lbfgs-ground (12 s: L-BFGS to the round-off floor) is in -m slow
    ("box", "bdf2", False),
}
# Implicit midpoint with the ground: also test_rollout_through_implicit_integrators_matches_fd (default).
CASES = [
    pytest.param(
        k,
        i,
        g,
        marks=() if (k, i, g) in FAST else pytest.mark.slow,
        id=f"{k}-{i}-{'ground' if g else 'free'}",
    )
    for k in ("rope", "cloth", "box")
    for i in INTEGRATORS
    for g in (False, True)
]


@pytest.mark.parametrize(("kind", "integ", "ground"), CASES)
def test_implicit_step_gradients_match_finite_differences(kind, integ, ground):
    """Tape gradients (x0, v0, each parameter array) of a 20-step rollout equal central differences (1e-4)."""
    _check(kind, ground, INTEGRATORS[integ])


def _driven_rope(targets: np.ndarray, record: bool, integ: str):
    """A rope whose first particle is kinematic, driven along ``targets`` (one per step); L = Σ w·x_final."""
    b = pl.ModelBuilder(gravity=(0.0, -9.81, 0.0))
    b.add_rope(n_segments=8, length=0.8, mass=0.4, stiffness=400.0, damping=5.0, pin="none")
    b.add_kinematic([0])
    model = b.finalize(device="cpu", dtype="float64", requires_grad=record)
    solver = pl.solvers.ForceSolver(
        model, energies=pl.energies.mass_spring(), contact=False, **INTEGRATORS[integ]()
    )
    controls = []
    for k in range(STEPS):
        c = pl.Control(model)
        c.kinematic_targets.assign(targets[k][None, :])
        controls.append(c)
    states = [model.state() for _ in range(STEPS + 1)]
    wx = wp.array(np.random.default_rng(3).standard_normal((model.particle_count, 3)), dtype=wp.vec3d)
    loss = wp.zeros(1, dtype=wp.float64, requires_grad=True)
    tape = wp.Tape()
    with tape:
        for k in range(STEPS):
            solver.step(states[k], states[k + 1], controls[k], DT)
        wp.launch(_weighted_sum, model.particle_count, [states[-1].particle_q, wx, loss])
    if not record:
        return float(loss.numpy()[0])
    tape.backward(loss)
    return float(loss.numpy()[0]), np.stack([c.kinematic_targets.grad.numpy()[0] for c in controls])


@pytest.mark.parametrize("integ", ["be_newton", "bdf2"])
def test_kinematic_target_gradients_match_finite_differences(integ):
    """∂L/∂(kinematic target of every step) of a driven rope equals central differences (1e-4)."""
    t = np.arange(1, STEPS + 1) * DT
    targets = np.stack([0.1 * np.sin(4 * t), 1.0 + 0.05 * t, 0.0 * t], axis=1)
    _, grad = _driven_rope(targets, True, integ)
    d = np.random.default_rng(5).standard_normal(targets.shape)
    eps = 1e-6
    fd = (_driven_rope(targets + eps * d, False, integ) - _driven_rope(targets - eps * d, False, integ)) / (
        2 * eps
    )
    analytic = float(np.sum(grad * d))
    assert abs(fd) > 1e-6
    assert abs(analytic - fd) <= TOL * abs(fd), f"tape {analytic:.10g} vs central differences {fd:.10g}"


@wp.kernel(enable_backward=False)
def _no_adjoint_pull(x: wp.array(dtype=wp.vec3d), out: wp.array(dtype=wp.vec3d)):
    i = wp.tid()
    wp.atomic_add(out, i, wp.float64(10.0) * x[i])


class _OpaqueEnergy(pl.energies.Energy):
    """E = 5|x|² with a gradient kernel Warp cannot differentiate."""

    def value(self, model, x, out):
        pass

    def gradient(self, model, x, out):
        wp.launch(_no_adjoint_pull, model.particle_count, [x, out], device=model.device)


def test_energy_without_adjoint_raises_clear_error():
    """An energy whose gradient kernel has no adjoint makes backward raise (no silent zero gradient)."""
    model = _rope(False).finalize(device="cpu", dtype="float64", requires_grad=True)
    solver = pl.solvers.ForceSolver(
        model,
        energies=[*pl.energies.mass_spring(), _OpaqueEnergy()],
        integrator=I.BackwardEuler(),
        contact=False,
    )
    s0, s1 = model.state(), model.state()
    loss = wp.zeros(1, dtype=wp.float64, requires_grad=True)
    tape = wp.Tape()
    with tape:
        solver.step(s0, s1, None, DT)
        wp.launch(_weighted_sum, model.particle_count, [s1.particle_q, s1.particle_q, loss])
    with pytest.raises(GradientError, match="_OpaqueEnergy.*no adjoint"):
        tape.backward(loss)


@wp.kernel
def _dot_loss(x: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d), out: wp.array(dtype=wp.float64)):
    i = wp.tid()
    wp.atomic_add(out, 0, wp.dot(x[i], w[i]))


def _falling_rope(requires_grad: bool, integ: str = "be_newton", stiffness: float = 400.0):
    """A rope thrown onto the ground (friction 0.5) and its solver with the *default* contact settings
    (contact=True: the solver adds GroundPenalty to Φ and applies penalty friction after the step)."""
    b = pl.ModelBuilder(gravity=(0.0, -9.81, 0.0))
    b.add_rope(n_segments=8, length=0.8, mass=0.4, stiffness=stiffness, damping=5.0, start=(0.0, 0.05, 0.0))
    b.add_ground(0.0, friction=0.5)
    model = b.finalize(device="cpu", dtype="float64", requires_grad=requires_grad)
    n = model.particle_count
    model.particle_qd.assign(np.tile([1.0, -0.5, 0.2], (n, 1)))
    return model, pl.solvers.ForceSolver(model, **INTEGRATORS[integ]())


def _rope_loss(model):
    w = wp.array(np.random.default_rng(3).standard_normal((model.particle_count, 3)), dtype=wp.vec3d)

    def loss(state):
        out = wp.zeros(1, dtype=wp.float64, requires_grad=True)
        wp.launch(_dot_loss, model.particle_count, [state.particle_q, w, out])
        wp.launch(_dot_loss, model.particle_count, [state.particle_qd, w, out])
        return out

    return loss


def _plain_loss(integ: str, dx0: np.ndarray | None = None, stiffness: float = 400.0) -> tuple[float, State]:
    model, solver = _falling_rope(False, integ, stiffness)
    if dx0 is not None:
        model.particle_q.assign(model.particle_q.numpy() + dx0)
    a, b = model.state(), model.state()
    for _ in range(STEPS):
        solver.step(a, b, None, DT)
        a, b = b, a
    return float(_rope_loss(model)(a).numpy()[0]), a


@pytest.mark.parametrize("integ", ["be_newton", pytest.param("be_lbfgs", marks=pytest.mark.slow)])
def test_recorded_implicit_step_with_default_contact_equals_plain_step_and_fd(integ):
    """Default contact on an implicit step: the recorded step applies the same penalty friction as the plain
    one (the same trajectory bit for bit), and pl.diff.rollout's ∂L/∂x0 and ∂L/∂k match central differences
    (1e-4)."""
    model, solver = _falling_rope(True, integ)
    res = pl.diff.rollout(
        model, solver, _rope_loss(model), frames=STEPS, dt=DT, params=["x0", "spring_stiffness"]
    )
    plain, plain_state = _plain_loss(integ)
    # The particles reach the ground and slide (else the friction would not be tested).
    assert np.min(plain_state.particle_q.numpy()[:, 1]) < model.particle_radius.numpy()[0]
    # Same kernels on the same numbers (fresh arrays instead of in-place updates): bit for bit.
    np.testing.assert_array_equal(res.state.particle_q.numpy(), plain_state.particle_q.numpy())
    np.testing.assert_array_equal(res.state.particle_qd.numpy(), plain_state.particle_qd.numpy())
    assert res.loss == plain
    # The differences by Newton: with the default penalty (κ = 1e6 1/s²) L-BFGS stalls at ~5e-6 in one
    # step, which is noise for differences (theirs vary by 40 % with ε) but not for its adjoint.
    ref = "be_newton"
    rng = np.random.default_rng(5)
    d = 0.01 * rng.standard_normal((model.particle_count, 3))
    eps = 1e-5
    fd = (_plain_loss(ref, eps * d)[0] - _plain_loss(ref, -eps * d)[0]) / (2 * eps)
    assert abs(fd) > 1e-6
    assert float(np.sum(res.grads["x0"] * d)) == pytest.approx(fd, rel=TOL)
    dk = 0.04
    fd_k = (_plain_loss(ref, stiffness=400.0 + dk)[0] - _plain_loss(ref, stiffness=400.0 - dk)[0]) / (2 * dk)
    assert abs(fd_k) > 1e-8
    assert float(np.sum(res.grads["spring_stiffness"])) == pytest.approx(fd_k, rel=TOL)


@pytest.mark.parametrize("integ", ["midpoint", "bdf2"])
def test_rollout_through_implicit_integrators_matches_fd(integ):
    """pl.diff.rollout (checkpointed for implicit midpoint; one segment for the multistep BDF2) gives
    ∂L/∂v0 equal to central differences (1e-4) with default ground contact."""
    model, solver = _falling_rope(True, integ)
    every = STEPS if integ == "bdf2" else 5
    res = pl.diff.rollout(
        model, solver, _rope_loss(model), frames=STEPS, dt=DT, params=["v0"], checkpoint_every=every
    )

    def plain(dv):
        m, s = _falling_rope(False, integ)
        m.particle_qd.assign(m.particle_qd.numpy() + dv)
        a, b = m.state(), m.state()
        for _ in range(STEPS):
            s.step(a, b, None, DT)
            a, b = b, a
        return float(_rope_loss(m)(a).numpy()[0])

    d = 0.1 * np.random.default_rng(6).standard_normal((model.particle_count, 3))
    eps = 1e-7  # contact makes the loss strongly curved in v0: a small step keeps the O(ε²) error down
    fd = (plain(eps * d) - plain(-eps * d)) / (2 * eps)
    assert abs(fd) > 1e-6
    assert float(np.sum(res.grads["v0"] * d)) == pytest.approx(fd, rel=TOL)


def test_rollout_refuses_checkpointed_multistep():
    """BDF2's history cannot cross a checkpoint boundary: a clear error, not a wrong gradient."""
    model, solver = _falling_rope(True, "bdf2")
    with pytest.raises(GradientError, match="checkpoint_every"):
        pl.diff.rollout(model, solver, _rope_loss(model), frames=4, dt=DT, params=["v0"], checkpoint_every=1)
