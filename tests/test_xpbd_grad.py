"""Tape gradients through XPBD (Jacobi, fixed iterations) equal central finite differences (float64, CPU).

The plain Warp path: ``finalize(requires_grad=True)``, one State per step, ``solver.step`` inside a
``wp.Tape``, ``tape.backward(loss)``, gradients read from the first state, the model's inverse masses, the
constraint sets' compliances and the solver's gravity. Each check is a directional derivative along a
random direction d: the tape's ⟨∇L, d⟩ against (L(θ + εd) − L(θ − εd))/2ε.
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import pliant.constraints as pc
from pliant.collision import Colliders
from pliant.model import ModelBuilder, State
from pliant.solvers import PBD, XPBD

wp.init()
wp.config.quiet = True

STEPS = 20
DT = 1.0 / 120.0


@wp.kernel
def _weighted_sum(x: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d), out: wp.array(dtype=wp.float64)):
    i = wp.tid()
    wp.atomic_add(out, 0, wp.dot(w[i], x[i]))


def _rope(ground: bool):
    b = ModelBuilder(gravity=(0.0, -9.81, 0.0))
    b.add_rope(
        n_segments=8, length=0.8, mass=0.9, stiffness=200.0, start=(0.0, 0.12, 0.0), direction=(1, -0.1, 0)
    )
    if ground:
        b.add_ground(0.0, friction=0.3)
    return b


def _cloth(ground: bool):
    b = ModelBuilder(gravity=(0.0, -9.81, 0.0))
    b.add_cloth_grid(
        nx=6,
        ny=6,
        size=0.5,
        mass=0.2,
        stiffness=300.0,
        bend_stiffness=1e-2,
        origin=(-0.25, 0.05, -0.25),
        plane="xz",
        pin=[0, 6],
    )
    if ground:
        b.add_ground(0.0, friction=0.3)
    return b


def _box(ground: bool):
    b = ModelBuilder(gravity=(0.0, -9.81, 0.0))
    b.add_soft_box(
        cells=(2, 2, 2),
        size=(0.2, 0.2, 0.2),
        origin=(0.0, 0.11, 0.0),
        E=2e4,
        nu=0.3,
        velocity=(0.3, -0.5, 0.1),
    )
    if ground:
        b.add_ground(0.0, friction=0.3)
    return b


def _cluster(ground: bool):
    # 3×2×2 particles with distinct extents: the moment's singular values stay apart (svd3's adjoint).
    g = np.stack(np.meshgrid([0.0, 0.1, 0.2], [0.0, 0.06], [0.0, 0.03], indexing="ij"), -1).reshape(-1, 3)
    b = ModelBuilder(gravity=(0.0, -9.81, 0.0))
    b.add_particles(g + [0.0, 0.04, 0.0], np.linspace(0.1, 0.2, len(g)))
    if ground:
        b.add_ground(0.0, friction=0.3)
    return b


SCENES = {"rope": _rope, "cloth": _cloth, "box": _box, "cluster": _cluster}


class Rollout:
    """A scene, its XPBD solver and L = Σ w·x_final; ``loss(params)`` evaluates it for perturbed inputs."""

    def __init__(
        self, scene: str, ground: bool, solver_cls: type = XPBD, dt: float = DT, **options: object
    ) -> None:
        """``options``: solver keywords replacing the defaults below (``jacobi="sum"``, ``relaxation``)."""
        self.model = SCENES[scene](ground).finalize(device="cpu", dtype="float64", requires_grad=True)
        if scene in ("box", "cluster"):
            # Expanding and spinning, so that the volume constraints act (a rigid fall never violates them).
            q = self.model.particle_q.numpy()
            r = q - q.mean(axis=0)
            v = self.model.particle_qd.numpy() + 2.0 * r + np.cross([0.0, 3.0, 1.0], r)
            self.model.particle_qd.assign(v)
        kw = {"bending_compliance": 1e-1} if scene == "cloth" else {}
        if scene == "box":
            kw["volume_compliance"] = 1e-6
        if scene == "cluster":
            kw["constraints"] = [pc.ShapeMatching([np.arange(self.model.particle_count)], stiffness=0.5)]
        if solver_cls is PBD:
            kw = {"stiffness": 0.8}
        kw = {"iterations": 5, "schedule": "jacobi", "relaxation": 1.5, **kw, **options}
        self.solver = solver_cls(self.model, **kw)
        self.dt = dt
        rng = np.random.default_rng(3)
        self.w = wp.array(rng.normal(size=(self.model.particle_count, 3)), dtype=wp.vec3d, device="cpu")
        self.ground = ground

    def run(self, q0: wp.array, qd0: wp.array) -> wp.array:
        states = [(q0, qd0)]
        n = self.model.particle_count
        for _ in range(STEPS):
            q = wp.zeros(n, dtype=wp.vec3d, device="cpu", requires_grad=True)
            qd = wp.zeros(n, dtype=wp.vec3d, device="cpu", requires_grad=True)
            self.solver.step(State(*states[-1]), State(q, qd), None, self.dt)
            states.append((q, qd))
        loss = wp.zeros(1, dtype=wp.float64, device="cpu", requires_grad=True)
        wp.launch(_weighted_sum, n, [states[-1][0], self.w, loss], device="cpu")
        return loss


def _fd(rollout: Rollout, array: wp.array, d: np.ndarray, eps: float) -> float:
    """Central difference of L along ``d`` for the contents of ``array`` (restored afterwards)."""
    base = array.numpy().copy()
    vals = []
    for sgn in (1.0, -1.0):
        array.assign(base + sgn * eps * d)
        s = rollout.model.state()
        vals.append(float(rollout.run(s.particle_q, s.particle_qd).numpy()[0]))
    array.assign(base)
    return (vals[0] - vals[1]) / (2.0 * eps)


def _tape_gradients(rollout: Rollout) -> tuple[wp.array, object, set[str]]:
    """Run the rollout under a tape and backpropagate: (loss, first state, names of the taped kernels)."""
    s = rollout.model.state()
    tape = wp.Tape()
    with tape:
        loss = rollout.run(s.particle_q, s.particle_qd)
    tape.backward(loss)
    return loss, s, _taped_kernels(tape)


def _taped_kernels(tape: wp.Tape) -> set[str]:
    """Names (key and function name) of the kernels a tape recorded."""
    names = set()
    for launch in tape.launches:
        k = launch[0] if isinstance(launch, (list, tuple)) else None  # other entries: recorded functions
        if hasattr(k, "key"):
            names |= {k.key, k.func.__name__}
    return names


def _violations(err: str, kernels: set[str]) -> list[str]:
    """Warp's "written to ... after read" reports on stderr that name one of ``kernels``."""
    return [
        line
        for line in err.splitlines()
        if "written to" in line and any(f"in kernel {k} " in line for k in kernels)
    ]


def _params(rollout: Rollout, s) -> dict[str, wp.array]:
    m, solver = rollout.model, rollout.solver
    out = {
        "x0": s.particle_q,
        "v0": s.particle_qd,
        "inv_mass": m.particle_inv_mass,
        "gravity": solver.gravity,
    }
    for c in solver.constraints:
        if isinstance(c, pc.FixedArityConstraint):
            out[f"compliance_{type(c).__name__}"] = c.compliance_array
    return out


@pytest.mark.parametrize("ground", [False, True], ids=["free", "ground"])
@pytest.mark.parametrize("scene", ["rope", "cloth", "box", "cluster"])
def test_tape_gradient_equals_central_differences(scene, ground, capfd):
    """⟨∇L, d⟩ from the tape equals central differences: rel. error ≤ 1e-5 (≤ 1e-4 with ground contact)."""
    prev = wp.config.verify_autograd_array_access
    wp.config.verify_autograd_array_access = True
    try:
        rollout = Rollout(scene, ground)
        capfd.readouterr()
        _, s, tape_kernels = _tape_gradients(rollout)
        # Warp reports in-kernel (at code generation) and across-launch violations on stderr. Only kernels
        # the tape replays matter: the gradient-off kernels (in-place Jacobi averaging) are reported when
        # their module is rebuilt with the check on, but never run under a tape.
        bad = _violations(capfd.readouterr().err, tape_kernels)
        assert not bad, bad[:5]
    finally:
        wp.config.verify_autograd_array_access = prev
    if ground:
        # The rollout must actually touch the ground, or the contact case tests nothing.
        assert rollout.solver.constraints[-1].lam.numpy().max() > 0.0
    tol = 1e-4 if ground else 1e-5
    rng = np.random.default_rng(11)
    params = _params(rollout, s)
    grads = {k: a.grad.numpy().copy() for k, a in params.items()}
    # Fresh (unperturbed) arrays for the finite differences: the tape's inputs are read-only from here on.
    fd_arrays = {
        "x0": rollout.model.particle_q,
        "v0": rollout.model.particle_qd,
        **{k: a for k, a in params.items() if k not in ("x0", "v0")},
    }
    if scene == "cluster":
        # Shape matching moves particles towards goals whatever their masses; the ground ignores them too.
        del fd_arrays["inv_mass"]
    _compare(rollout, scene, grads, fd_arrays, tol, rng)


def _compare(rollout: Rollout, scene: str, grads: dict, fd_arrays: dict, tol: float, rng) -> None:
    """Tape ⟨∇L, d⟩ against central differences for every array of ``fd_arrays``."""
    free = rollout.model.particle_inv_mass.numpy() > 0
    for name, array in fd_arrays.items():
        g = grads[name]
        d = rng.normal(size=g.shape)
        if name == "inv_mass":
            d = d * free * array.numpy()  # relative changes of the free particles' masses
        elif name.startswith("compliance"):
            d = d * np.maximum(array.numpy(), 1e-9)
        eps = 1e-6 * max(float(np.abs(array.numpy()).max()), 1.0) if name in ("x0", "gravity") else 1e-6
        if name.startswith("compliance") or name == "inv_mass":
            eps = 1e-5
        tape_dd = float(np.sum(g * d))
        fd_dd = _fd(rollout, array, d, eps)
        err = abs(tape_dd - fd_dd) / max(abs(fd_dd), 1e-8)
        assert abs(fd_dd) > 1e-8, f"{name}: the loss does not depend on it"
        assert err <= tol, (
            f"{scene}/{name}: tape {tape_dd:.10g}, central differences {fd_dd:.10g}, rel {err:.2e}"
        )


def test_pbd_tape_gradient_equals_central_differences():
    """PBD (stiffness k' per iteration instead of compliance) on the rope with ground: the same check."""
    rollout = Rollout("rope", True, PBD)
    _, s, _ = _tape_gradients(rollout)
    m = rollout.model
    grads = {"x0": s.particle_q.grad.numpy(), "v0": s.particle_qd.grad.numpy()}
    grads["inv_mass"] = m.particle_inv_mass.grad.numpy()
    grads["gravity"] = rollout.solver.gravity.grad.numpy()
    arrays = {"x0": m.particle_q, "v0": m.particle_qd, "inv_mass": m.particle_inv_mass}
    arrays["gravity"] = rollout.solver.gravity
    _compare(rollout, "rope-pbd", grads, arrays, 1e-4, np.random.default_rng(5))


def test_in_place_kernels_are_reported_by_the_access_check(capfd):
    """The check the gradient test relies on is live: an in-place update is reported as written after read."""

    @wp.kernel
    def _in_place(a: wp.array(dtype=wp.float64)):
        i = wp.tid()
        a[i] = wp.float64(2.0) * a[i]

    prev = wp.config.verify_autograd_array_access
    wp.config.verify_autograd_array_access = True
    try:
        capfd.readouterr()
        a = wp.ones(4, dtype=wp.float64, device="cpu", requires_grad=True)
        tape = wp.Tape()
        with tape:
            wp.launch(_in_place, 4, [a], device="cpu")
    finally:
        wp.config.verify_autograd_array_access = prev
    assert _violations(capfd.readouterr().err, _taped_kernels(tape))


def _grad_model():
    return _rope(False).finalize(device="cpu", dtype="float64", requires_grad=True)


def test_what_cannot_be_differentiated_is_refused_clearly():
    """Colouring, shape matching and kinematic targets raise, naming what to change, when gradients are on."""
    model = _grad_model()
    with pytest.raises(NotImplementedError, match='schedule="jacobi"'):
        XPBD(model, schedule="coloring")
    with pytest.raises(NotImplementedError, match="ShapeMatching"):
        XPBD(model, constraints=[pc.ShapeMatching(radii=np.full(model.particle_count, 0.01))])
    solver = XPBD(model)
    solver.constraints.insert(0, pc.Attachment([3]))  # added after construction, as scene files do
    solver.constraints[0].bind(model, False)
    with pytest.raises(NotImplementedError, match="Attachment"):
        solver.step(model.state(), model.state(), None, DT)
    solver = XPBD(model)
    control = model.control()
    control.kinematic_indices = wp.array([3], dtype=wp.int32, device="cpu")
    control.kinematic_targets = wp.array([[0.0, 0.0, 0.0]], dtype=wp.vec3d, device="cpu")
    with pytest.raises(NotImplementedError, match="kinematic"):
        solver.step(model.state(), model.state(), control, DT)
    # Contact handlers correct the step in place: refused under a tape, still run without one.
    colliders = Colliders()
    colliders.add_sphere((0.0, -1.0, 0.0), 0.5)
    solver = XPBD(model, collisions=[colliders])
    solver.step(model.state(), model.state(), None, DT)
    with wp.Tape(), pytest.raises(NotImplementedError, match="collisions="):
        solver.step(model.state(), model.state(), None, DT)


def test_gradient_off_path_records_and_replays_as_before():
    """Without requires_grad the solver keeps replaying recorded launches (the fast path) and no fresh
    arrays are made: λ stays the array bound at set-up."""
    model = _rope(True).finalize(device="cpu", dtype="float64")
    solver = XPBD(model, iterations=3)
    lam = solver.constraints[0].lam
    s0, s1 = model.state(), model.state()
    for _ in range(3):
        solver.step(s0, s1, None, DT)
        s0, s1 = s1, s0
    assert solver.replay and len(solver._plans) == 2
    assert solver.constraints[0].lam is lam


def test_rollout_api_through_xpbd_matches_fd():
    """pl.diff.rollout (checkpointed every 5 steps) through XPBD Jacobi on the rope with ground contact:
    ∂L/∂x0 and ∂L/∂v0 equal central differences (1e-5) and the tape gradients of the plain path."""
    import pliant as pl

    r = Rollout("rope", True)
    n = r.model.particle_count

    def loss(state):
        out = wp.zeros(1, dtype=wp.float64, device="cpu", requires_grad=True)
        wp.launch(_weighted_sum, n, [state.particle_q, r.w, out], device="cpu")
        return out

    res = pl.diff.rollout(
        r.model, r.solver, loss, frames=STEPS, dt=DT, params=["x0", "v0"], checkpoint_every=5
    )
    base, s, _ = _tape_gradients(r)
    assert res.loss == pytest.approx(float(base.numpy()[0]), rel=1e-12)
    np.testing.assert_allclose(res.grads["x0"], s.particle_q.grad.numpy(), rtol=1e-9, atol=1e-12)
    rng = np.random.default_rng(8)
    for name, array in (("x0", r.model.particle_q), ("v0", r.model.particle_qd)):
        d = 0.01 * rng.standard_normal((n, 3))
        d[r.model.particle_inv_mass.numpy() == 0] = 0.0
        fd = _fd(r, array, d, 1e-6)
        assert abs(fd) > 1e-8
        assert float(np.sum(res.grads[name] * d)) == pytest.approx(fd, rel=1e-5)


@pytest.mark.parametrize("scene", ["cloth", "box"])
def test_rollout_compliance_by_name_matches_tape_and_fd(scene):
    """pl.diff.rollout names the XPBD compliances (``compliance_distance``, ``compliance_dihedralbending``,
    ``compliance_volume``): the gradients equal the plain tape's and central differences (1e-5)."""
    import pliant as pl

    r = Rollout(scene, False)
    n = r.model.particle_count
    names = (
        ["compliance_distance", "compliance_dihedralbending"] if scene == "cloth" else ["compliance_volume"]
    )

    def loss(state):
        out = wp.zeros(1, dtype=wp.float64, device="cpu", requires_grad=True)
        wp.launch(_weighted_sum, n, [state.particle_q, r.w, out], device="cpu")
        return out

    res = pl.diff.rollout(r.model, r.solver, loss, frames=STEPS, dt=DT, params=names, checkpoint_every=4)
    _, s, _ = _tape_gradients(r)
    plain = _params(r, s)
    rng = np.random.default_rng(5)
    for name in names:
        kind = {"distance": "Distance", "dihedralbending": "DihedralBending", "volume": "Volume"}[
            name.split("_", 1)[1]
        ]
        array = plain[f"compliance_{kind}"]
        np.testing.assert_allclose(res.grads[name], array.grad.numpy(), rtol=1e-9, atol=1e-14)
        d = rng.normal(size=res.grads[name].shape) * np.maximum(array.numpy(), 1e-9)
        fd = _fd(r, array, d, 1e-5)
        assert abs(fd) > 1e-8
        assert float(np.sum(res.grads[name] * d)) == pytest.approx(fd, rel=1e-5)


def test_rollout_compliance_name_without_such_constraint_is_refused():
    import pliant as pl

    r = Rollout("rope", False)
    with pytest.raises(pl.diff.GradientError, match="Volume"):
        pl.diff.rollout(r.model, r.solver, lambda s: None, frames=1, dt=DT, params=["compliance_volume"])
