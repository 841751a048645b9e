"""Tape gradients of explicit rollouts equal central finite differences (float64, CPU; issue 12).

Each check compares the directional derivative ∇L·d, d a random direction, with (L(θ+εd) − L(θ−εd))/2ε on
a ≥ 20-step rollout: rope of 8 segments, 6×6 cloth, 2×2×2-cell FEM box, free and on the ground. Warp's
``verify_autograd_array_access`` is on and no "written after read" warning may appear.
"""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest
import warp as wp
from helpers import SYSTEM_INTEGRATORS, integrator_id

import pliant as pl

I = pl.integrators
#: Every registered explicit integrator that steps physical models (a new one is checked too).
EXPLICIT = [i for i in SYSTEM_INTEGRATORS if i.explicit]
STEPS = 20
DT = 1e-3


#: Warp's build-time message for the in-place kernels that never run on a tape (see _verify_access).
_IN_PLACE_NEVER_TAPED = re.compile(
    r"in kernel (apply_deltas(?:_update_velocity)?|apply_average|gauss_seidel\w*) at"
)


@pytest.fixture(autouse=True)
def _verify_access(capfd):
    """Warp checks every recorded launch; its "written after read" warnings (stderr) fail the test."""
    old = wp.config.verify_autograd_array_access
    wp.config.verify_autograd_array_access = True
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield
    wp.config.verify_autograd_array_access = old
    text = capfd.readouterr().err + "".join(str(w.message) for w in caught)
    # Warp checks every kernel of a module when the module is built, taped or not. XPBD's in-place Jacobi
    # kernels (apply_deltas, apply_deltas_update_velocity: read, then reset their delta buffer in their shared
    # apply_average, which Warp names as the kernel) never run on
    # a tape (recorded steps use apply_deltas_to), but they are flagged whenever their module happens to be
    # built inside this fixture — which depends on test order (a pytest-xdist worker). Their lines are
    # dropped; every other kernel's stay.
    # The same for the constraint factory's in-place Gauss-Seidel sweep (gauss_seidel: recorded steps sweep
    # Jacobi), flagged when constraints/_factory.py's generated module is first built in here.
    text = "\n".join(ln for ln in text.splitlines() if not _IN_PLACE_NEVER_TAPED.search(ln))
    # Both of Warp's messages: across launches ("already been read") and within one ("has been read").
    assert "been read" not in text, text[:2000]


def test_access_check_catches_an_in_place_update(capfd):
    """The fixture's check is live: the pre-fix pattern (write into an array a recorded launch read) warns."""
    wp.config.verify_autograd_array_access = True
    a = wp.ones(4, dtype=wp.float64, requires_grad=True)
    b = wp.zeros(4, dtype=wp.float64, requires_grad=True)
    with wp.Tape():
        pl.integrators._ops.lincomb(_Grad(), b, a, [(1.0, a)])
        wp.launch(_scale, 4, [b, a])
    assert "already been read" in capfd.readouterr().err


class _Grad:
    requires_grad = False
    device = "cpu"
    particle_count = 4

    @staticmethod
    def s(x):
        return wp.float64(x)


@wp.kernel
def _scale(x: wp.array(dtype=wp.float64), y: wp.array(dtype=wp.float64)):
    i = wp.tid()
    y[i] = x[i] * wp.float64(2.0)


def build(kind: str, ground: bool, requires_grad: bool = True) -> pl.Model:
    """Small float64 models whose initial velocities deform them (so every parameter matters). A kind
    ending in "~" starts with positions jittered off the rest shape: a projected spring Hessian (the
    Baraff–Witkin step) has a kink at the rest length, where the gradient is one-sided."""
    jitter = kind.endswith("~")
    kind = kind.rstrip("~")
    b = pl.ModelBuilder()
    rng = np.random.default_rng(3)
    if kind == "rope":
        b.add_rope(n_segments=8, length=0.8, mass=0.2, stiffness=200.0, damping=0.3, start=(0, 0.004, 0))
    elif kind == "cloth":
        b.add_cloth_grid(nx=5, ny=5, size=0.5, mass=0.1, stiffness=50.0, damping=0.05, origin=(0, 0.004, 0))
    else:
        box = {"size": (0.2, 0.2, 0.2), "origin": (0, 0.1, 0), "density": 500.0, "E": 2e4, "nu": 0.3}
        b.add_soft_box(cells=(2, 2, 2), **box)
    if ground:
        b.add_ground(friction=0.3, restitution=0.4)
    m = b.finalize(device="cpu", dtype="float64", requires_grad=requires_grad)
    v = rng.normal(size=(m.particle_count, 3)) * 0.5
    m.particle_qd.assign(v)
    if jitter:
        q = m.particle_q.numpy()
        q[m.particle_inv_mass.numpy() > 0] += 0.004 * rng.normal(
            size=q[m.particle_inv_mass.numpy() > 0].shape
        )
        m.particle_q.assign(q)
    return m


def energies(kind: str) -> list:
    E = pl.energies
    return [E.NeoHookean(), E.Gravity()] if kind == "box" else E.mass_spring()


@wp.kernel
def _loss(
    x: wp.array(dtype=wp.vec3d),
    v: wp.array(dtype=wp.vec3d),
    w: wp.array(dtype=wp.vec3d),
    out: wp.array(dtype=wp.float64),
):
    i = wp.tid()
    wp.atomic_add(out, 0, wp.dot(x[i], w[i]) + wp.float64(0.1) * wp.dot(v[i], v[i]))


def loss_of(w: wp.array):
    def loss(state: pl.State) -> wp.array:
        out = wp.zeros(1, dtype=wp.float64, requires_grad=True)
        wp.launch(_loss, state.particle_q.shape[0], [state.particle_q, state.particle_qd, w, out])
        return out

    return loss


def solver_for(m, kind, integ, fast=False):
    if fast == "implicit":
        # CG converged far below the finite differences' resolution: the adjoint is that of the exact solve.
        return pl.solvers.FastMassSpring(
            m, method="implicit", damping_rate=0.5, cg_tol=1e-14, cg_iterations=300
        )
    if fast:
        return pl.solvers.FastMassSpring(m, method="symplectic", damping_rate=0.5)
    minimizer = None
    if isinstance(integ, tuple):  # (integrator or factory, the solver's MinimizerOptions)
        integ, minimizer = integ
    if not isinstance(integ, I.Integrator):
        integ = integ()  # a factory: a fresh integrator per solver (BDF2 keeps a step history)
    return pl.solvers.ForceSolver(m, energies(kind), integ, damping_rate=0.5, minimizer=minimizer)


PARAMS = {
    "rope": ["spring_stiffness", "spring_rest_length", "spring_damping", "particle_mass", "x0", "v0"],
    "cloth": ["spring_stiffness", "spring_damping", "x0", "v0"],
    "box": ["tet_mu", "tet_lam", "particle_mass", "x0", "v0"],
}
GROUND = ["ground_friction", "ground_restitution"]
#: Parameters held in solver arrays (name → attribute).
SOLVER_ARRAYS = {"gravity": "gravity", "damping_rate": "damping_rate_array"}


def perturbed_loss(kind, ground, integ, name, theta, w, fast=False) -> float:
    """L(θ) by a plain forward run (no tape) on a fresh model with parameter ``name`` set to ``theta``."""
    m = build(kind, ground)
    solver = solver_for(m, kind, integ, fast)
    s = m.state()
    target = {"x0": s.particle_q, "v0": s.particle_qd}.get(name)
    if name in GROUND:
        solver.ground_coefficients.assign(
            np.where(np.arange(2) == GROUND.index(name), theta, solver.ground_coefficients.numpy())
        )
    elif target is not None:
        target.assign(theta)
    elif name in SOLVER_ARRAYS:
        getattr(solver, SOLVER_ARRAYS[name]).assign(
            np.reshape(theta, getattr(solver, SOLVER_ARRAYS[name]).numpy().shape)
        )
    elif name == "particle_mass":
        inv = m.particle_inv_mass.numpy()
        m.particle_mass.assign(theta)
        m.particle_inv_mass.assign(np.where(inv > 0, 1.0 / theta, 0.0))
    else:
        getattr(m, name).assign(theta)
    for _ in range(STEPS):
        n = m.state()
        solver.step(s, n, None, DT)
        s = n
    return float(loss_of(w)(s).numpy()[0])


def check(kind, ground, integ, params, tol, fast=False, eps_scale=1e-6, checkpoint_every=1):
    m = build(kind, ground)
    rng = np.random.default_rng(7)
    w = wp.array(rng.normal(size=(m.particle_count, 3)), dtype=wp.vec3d)
    solver = solver_for(m, kind, integ, fast)
    res = pl.diff.rollout(
        m,
        solver,
        loss_of(w),
        frames=5,
        substeps=STEPS // 5,
        dt=DT,
        params=params,
        checkpoint_every=checkpoint_every,
    )
    plain = perturbed_loss(kind, ground, integ, "v0", m.particle_qd.numpy(), w, fast)
    assert res.loss == pytest.approx(plain, rel=1e-12)
    for name in params:
        g = res.grads[name]
        if name in GROUND:
            theta = solver.ground_coefficients.numpy()[GROUND.index(name)]
        elif name in SOLVER_ARRAYS:
            theta = getattr(solver, SOLVER_ARRAYS[name]).numpy().astype(np.float64)
        elif name in ("x0", "v0"):
            theta = (m.particle_q if name == "x0" else m.particle_qd).numpy()
        else:
            theta = getattr(m, name).numpy()
        d = rng.normal(size=np.shape(theta))
        eps = eps_scale * max(float(np.abs(theta).mean()), 1e-2)
        fd = (
            perturbed_loss(kind, ground, integ, name, theta + eps * d, w, fast)
            - perturbed_loss(kind, ground, integ, name, theta - eps * d, w, fast)
        ) / (2 * eps)
        ad = float(np.sum(g * d))
        assert abs(fd) > 1e-9, f"{name}: the loss does not depend on it (test set-up)"
        who = getattr(integ, "name", "FastMassSpring")
        print(f"FD {kind} ground={ground} {who} {name}: rel {abs(ad - fd) / abs(fd):.1e}")
        assert ad == pytest.approx(fd, rel=tol), f"{name}: tape {ad} vs FD {fd}"


@pytest.mark.parametrize("integ", EXPLICIT, ids=integrator_id)
@pytest.mark.parametrize("kind", ["rope", "cloth", "box"])
def test_explicit_gradients_match_finite_differences(kind, integ):
    """∂L/∂(stiffness, rest length, γ, μ, λ, masses, x₀, v₀) of a 20-step rollout, every explicit
    integrator."""
    check(kind, False, integ, PARAMS[kind], 1e-5)


@pytest.mark.parametrize("integ", EXPLICIT, ids=integrator_id)
@pytest.mark.parametrize("kind", ["rope", "box"])
def test_gravity_and_damping_rate_gradients(kind, integ):
    """∂L/∂g (gravity vec3) and ∂L/∂c (damping rate of v ← v·exp(−cΔt)) of a 20-step rollout, every
    explicit integrator, against central finite differences (relative error ≤ 1e-5)."""
    check(kind, False, integ, ["gravity", "damping_rate"], 1e-5)


_TIGHT = {"newton_tol": 1e-12, "max_newton_iterations": 50}
IMPLICIT = {
    "be_newton": lambda: I.BackwardEuler(**_TIGHT),
    "midpoint": lambda: I.ImplicitMidpoint(**_TIGHT),
    "be_lbfgs": (
        lambda: I.BackwardEuler(newton_tol=1e-12),
        pl.solvers.MinimizerOptions(method="lbfgs", lbfgs_max_iterations=500),
    ),
    "bdf2": lambda: I.BDF2(**_TIGHT),
}


@pytest.mark.parametrize("integ", list(IMPLICIT))
@pytest.mark.parametrize("kind", ["rope", "box"])
def test_gravity_and_damping_rate_gradients_implicit(kind, integ):
    """∂L/∂g and ∂L/∂c through implicit steps (g enters the incremental potential through
    GravityFromArray, so the IFT adjoint carries it; δ = exp(−cΔt) scales v₁ on the tape): central finite
    differences within 1e-4."""
    # A larger step than the explicit checks': the minimiser's stopping error (newton_tol) divided by ε
    # would dominate otherwise, and L is nearly linear in g and c (the O(ε²) term stays below 1e-6).
    # BDF2's history cannot cross a checkpoint: one segment for the whole rollout.
    check(kind, False, IMPLICIT[integ], ["gravity", "damping_rate"], 1e-4, eps_scale=1e-4, checkpoint_every=5)


def test_gravity_and_damping_rate_plain_tape():
    """The plain path: solver.step under a wp.Tape; gradients read from the solver's arrays."""
    m = build("rope", False)
    w = wp.array(np.random.default_rng(1).normal(size=(m.particle_count, 3)), dtype=wp.vec3d)
    solver = solver_for(m, "rope", I.SymplecticEuler())
    res = pl.diff.rollout(
        m, solver, loss_of(w), frames=1, substeps=STEPS, dt=DT, params=["gravity", "damping_rate"]
    )
    solver.reset()
    s = m.state()
    tape = wp.Tape()
    with tape:
        for _ in range(STEPS):
            n = pl.State(
                wp.empty_like(s.particle_q, requires_grad=True),
                wp.empty_like(s.particle_qd, requires_grad=True),
            )
            solver.step(s, n, None, DT)
            s = n
        loss = loss_of(w)(s)
    tape.backward(loss=loss)
    np.testing.assert_allclose(solver.gravity.grad.numpy()[0], res.grads["gravity"][0], rtol=1e-12)
    np.testing.assert_allclose(solver.damping_rate_array.grad.numpy(), res.grads["damping_rate"], rtol=1e-12)
    assert abs(solver.damping_rate_array.grad.numpy()[0]) > 0


def test_gravity_and_damping_rate_need_the_arrays():
    """Asking for them where they are not read raises, never a silent zero."""
    m = build("rope", False)
    solver = pl.solvers.ForceSolver(m, energies("rope"), I.SymplecticEuler())  # no damping_rate
    with pytest.raises(pl.diff.GradientError, match="damping_rate"):
        pl.diff.rollout(
            m,
            solver,
            loss_of(wp.zeros(m.particle_count, dtype=wp.vec3d)),
            frames=1,
            dt=DT,
            params=["damping_rate"],
        )
    plain = build("rope", False, requires_grad=False)
    unrecorded = pl.solvers.ForceSolver(plain, energies("rope"), I.BackwardEuler(), damping_rate=0.5)
    assert unrecorded.gravity is None


@pytest.mark.parametrize("integ", [I.SymplecticEuler(), I.RK4(), I.VelocityVerlet()], ids=integrator_id)
@pytest.mark.parametrize("kind", ["rope", "cloth", "box"])
def test_gradients_with_ground_contact(kind, integ):
    """The same with ground contact, plus ∂L/∂(friction, restitution) for the cloth (tolerance 1e-4)."""
    check(kind, True, integ, PARAMS[kind] + (GROUND if kind == "cloth" else []), 1e-4)


@pytest.mark.parametrize("ground", [False, True])
def test_fast_mass_spring_symplectic_gradients(ground):
    """FastMassSpring(method="symplectic") under requires_grad differentiates the same step."""
    check("cloth", ground, None, PARAMS["cloth"] + (GROUND if ground else []), 1e-4 if ground else 1e-5, True)


@pytest.mark.parametrize("kind", ["rope", "cloth"])
@pytest.mark.parametrize("ground", [False, True])
def test_fast_mass_spring_implicit_gradients(kind, ground):
    """FastMassSpring(method="implicit") (Baraff–Witkin): the adjoint of its linear solve gives ∂L/∂(springs,
    masses, x₀, v₀, g, c, ground μ and e) equal to central finite differences (1e-4)."""
    params = PARAMS[kind] + ["gravity", "damping_rate"] + (GROUND if ground else [])
    check(kind + "~", ground, None, params, 1e-4, "implicit", eps_scale=1e-5)


@pytest.mark.parametrize("method", ["symplectic", "implicit"])
def test_fast_mass_spring_recorded_step_equals_fused_step(method):
    """The recorded step is FastMassSpring's own update (equal to round-off, not a different scheme)."""
    out = []
    for rg in (False, True):
        # The gradient-free run is the in-place fast path by design: Warp's tape checks do not apply.
        wp.config.verify_autograd_array_access = rg
        m = build("cloth", True, requires_grad=rg)
        solver = pl.solvers.FastMassSpring(m, method=method, damping_rate=0.5)
        s = m.state()
        for _ in range(STEPS):
            n = m.state()
            solver.step(s, n, None, DT)
            s = n
        out.append(s.particle_q.numpy())
    np.testing.assert_allclose(out[0], out[1], rtol=0, atol=1e-13)


def test_free_particle_initial_velocity_closed_form():
    """x_N = x₀ + NΔt v₀ + ½N(N+1)Δt² g under symplectic Euler: ∂(w·x_N)/∂v₀ = NΔt w, plain tape path."""
    b = pl.ModelBuilder()
    b.add_particles(np.array([[0.0, 1.0, 0.0]]), 1.0)
    m = b.finalize(device="cpu", dtype="float64", requires_grad=True)
    solver = pl.solvers.ForceSolver(m, [pl.energies.Gravity()], I.SymplecticEuler())
    w = wp.array([[0.3, -1.2, 0.7]], dtype=wp.vec3d)
    states = [m.state()]
    tape = wp.Tape()
    with tape:
        for _ in range(STEPS):
            states.append(m.state())
            solver.step(states[-2], states[-1], None, DT)
        out = wp.zeros(1, dtype=wp.float64, requires_grad=True)
        wp.launch(_loss, 1, [states[-1].particle_q, states[-1].particle_qd, w, out])
    tape.backward(out)
    v_n = states[-1].particle_qd.numpy()[0]
    # ∂/∂v₀ of w·x_N + 0.1|v_N|², with v_N = v₀ + NΔt g.
    expect = STEPS * DT * w.numpy()[0] + 0.2 * v_n
    np.testing.assert_allclose(states[0].particle_qd.grad.numpy()[0], expect, rtol=1e-12)
    x_n = states[-1].particle_q.numpy()[0]
    g = np.array(m.gravity)
    np.testing.assert_allclose(x_n, [0, 1, 0] + 0.5 * STEPS * (STEPS + 1) * DT**2 * g, rtol=1e-12)


def test_plain_tape_spring_stiffness_nonzero_and_kinematic_targets():
    """The issue's report: ∂L/∂k is no longer zero on the plain path; kinematic targets get gradients."""
    b = pl.ModelBuilder()
    b.add_rope(n_segments=8, length=0.8, mass=0.2, stiffness=200.0, pin="none")
    b.add_kinematic([0])
    m = b.finalize(device="cpu", dtype="float64", requires_grad=True)
    solver = pl.solvers.ForceSolver(m, integrator=I.SymplecticEuler())
    control = m.control()
    w = wp.array(np.ones((m.particle_count, 3)), dtype=wp.vec3d)

    def run(targets):
        control.kinematic_targets.assign(targets)
        states = [m.state()]
        for _ in range(STEPS):
            states.append(m.state())
            solver.step(states[-2], states[-1], control, DT)
        out = wp.zeros(1, dtype=wp.float64, requires_grad=True)
        wp.launch(_loss, m.particle_count, [states[-1].particle_q, states[-1].particle_qd, w, out])
        return out

    t0 = control.kinematic_targets.numpy() + [[0.0, 0.05, 0.02]]
    tape = wp.Tape()
    with tape:
        out = run(t0)
    tape.backward(out)
    gk = m.spring_stiffness.grad.numpy()
    gt = control.kinematic_targets.grad.numpy().copy()
    assert np.abs(gk).max() > 0
    d = np.array([[0.2, -0.5, 0.9]])
    eps = 1e-6
    fd = (float(run(t0 + eps * d).numpy()[0]) - float(run(t0 - eps * d).numpy()[0])) / (2 * eps)
    assert float(np.sum(gt * d)) == pytest.approx(fd, rel=1e-5)


def test_unsupported_gradients_raise():
    """No silent zeros: the drag handle, implicit steps without an adjoint and unknown names raise."""
    m = build("rope", False)
    fast = pl.solvers.FastMassSpring(m, method="implicit")
    control = pl.Control(m)
    control.drag_index, control.drag_target, control.drag_stiffness = 1, (0.0, 1.0, 0.0), 10.0
    with wp.Tape(), pytest.raises(pl.diff.GradientError, match="drag handle"):
        fast.step(m.state(), m.state(), control, DT)
    s0, s1 = m.state(), m.state()
    solver = pl.solvers.ForceSolver(m, integrator=I.BackwardEuler())
    if not getattr(solver.integrator, "differentiable", False):
        with pytest.raises(pl.diff.GradientError, match="BackwardEuler"):
            solver.step(s0, s1, None, DT)
    with pytest.raises(pl.diff.GradientError, match="unknown"):
        pl.diff.rollout(m, pl.solvers.ForceSolver(m), lambda s: None, frames=1, dt=DT, params=["mass"])
    plain = build("rope", False, requires_grad=False)
    with pytest.raises(pl.diff.GradientError, match="requires_grad"):
        pl.diff.rollout(plain, pl.solvers.ForceSolver(plain), lambda s: None, frames=1, dt=DT)


def test_checkpointing_does_not_change_gradients():
    """One segment per frame and one segment for the whole rollout give the same gradients."""
    m = build("rope", False)
    w = wp.array(np.ones((m.particle_count, 3)), dtype=wp.vec3d)
    solver = solver_for(m, "rope", I.SymplecticEuler())
    kw = {"frames": 4, "substeps": 5, "dt": DT, "params": ["spring_stiffness", "x0"]}
    a = pl.diff.rollout(m, solver, loss_of(w), **kw)
    b = pl.diff.rollout(m, solver, loss_of(w), **kw, checkpoint_every=4)
    assert a.loss == b.loss
    for k in a.grads:
        np.testing.assert_allclose(a.grads[k], b.grads[k], rtol=1e-12, atol=1e-15)


def test_torch_bridge():
    """torch autograd through a rollout: the tensor's gradient equals the rollout's."""
    torch = pytest.importorskip("torch")
    m = build("rope", False)
    w = wp.array(np.ones((m.particle_count, 3)), dtype=wp.vec3d)
    solver = solver_for(m, "rope", I.SymplecticEuler())
    k0 = m.spring_stiffness.numpy().copy()
    ref = pl.diff.rollout(m, solver, loss_of(w), frames=2, substeps=10, dt=DT, params=["spring_stiffness"])
    f = pl.diff.torch_rollout(m, solver, loss_of(w), ["spring_stiffness"], frames=2, substeps=10, dt=DT)
    k = torch.tensor(k0, requires_grad=True)
    loss = 3.0 * f(k)
    loss.backward()
    assert float(loss) == pytest.approx(3.0 * ref.loss, rel=1e-12)
    np.testing.assert_allclose(k.grad.numpy(), 3.0 * ref.grads["spring_stiffness"], rtol=1e-12)


def test_xpbd_gravity_through_rollout():
    """pl.diff's "gravity" resolves to XPBD's solver.gravity: rollout gradient = central differences."""
    w = wp.array(np.random.default_rng(2).normal(size=(9, 3)), dtype=wp.vec3d)

    def run(g, grads):
        m = build("rope", False)
        solver = pl.solvers.XPBD(m, schedule="jacobi")
        solver.gravity.assign(np.reshape(g, (1, 3)))
        res = pl.diff.rollout(m, solver, loss_of(w), frames=2, substeps=10, dt=DT, params=grads)
        return res, solver

    res, solver = run(np.array([0.0, -9.81, 0.0]), ["gravity"])
    d = np.array([0.3, -1.0, 0.2])
    eps = 1e-5
    g0 = np.array([0.0, -9.81, 0.0])
    fd = (run(g0 + eps * d, [])[0].loss - run(g0 - eps * d, [])[0].loss) / (2 * eps)
    ad = float(np.sum(res.grads["gravity"] * d))
    assert abs(fd) > 1e-9
    assert ad == pytest.approx(fd, rel=1e-5)


def test_bdf2_on_a_requires_grad_model_without_tape_matches_plain_model():
    """A requires_grad model stepped without a tape takes the recorded form; BDF2's history must survive it
    (it once read zeroed work buffers as x₋₁ and diverged): same trajectory as a plain model to round-off."""
    finals = []
    for rg in (False, True):
        m = build("rope", False, requires_grad=rg)
        solver = pl.solvers.ForceSolver(m, energies("rope"), I.BDF2(newton_tol=1e-12), damping_rate=0.5)
        s = m.state()
        for _ in range(STEPS):
            n = m.state()
            solver.step(s, n, None, DT)
            s = n
        finals.append(s.particle_q.numpy())
    np.testing.assert_allclose(finals[1], finals[0], rtol=0, atol=1e-10)
