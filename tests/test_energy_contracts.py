"""Contracts every registered energy meets (``pl.energies.registered_energies``): ∇E and ∇²E equal central
differences in float64 on a small, randomly perturbed model, and ∇²E is symmetric.

The tests walk the registry, so a new Energy class is checked without editing a list of names; what it
cannot find alone is a model to run on, so each class has an example in :data:`EXAMPLES` and a class
without one fails with "no example for <Name>: add one to EXAMPLES in tests/test_energy_contracts.py".
"""

from __future__ import annotations

import gc
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest
import warp as wp

import pliant as pl
from tests.helpers import energy_fd_check

E = pl.energies


@dataclass
class Example:
    """An energy on a small float64 model and the positions x [m] where its derivatives are checked.

    Attributes:
        model: the model (float64, CPU).
        energy: the energy instance.
        x: positions [N, 3] to differentiate at (perturbed off any symmetric or rest configuration).
        begin: ``begin_step`` arguments (x, v, dt) of a dissipative term; None for the others.
        eps: finite-difference step [m].
        tol: allowed gradient error relative to the largest entry.
        hess_tol: allowed Hessian error relative to the largest entry.
        linear: E is linear in x, so its Hessian is zero (only then may it be).
    """

    model: pl.Model
    energy: E.Energy
    x: np.ndarray
    begin: tuple | None = None
    eps: float = 1e-6
    tol: float = 1e-6
    hess_tol: float = 1e-5
    linear: bool = False


def _cloth(n: int = 2, *, damping: float = 0.0, seed: int = 1, amount: float = 0.05):
    b = pl.ModelBuilder()
    b.add_cloth_grid(
        nx=n,
        ny=n,
        size=0.2,
        mass=0.1,
        stiffness=50.0,
        shear_stiffness=20.0,
        damping=damping,
        origin=(0, 0, 0),
    )
    model = b.finalize(device="cpu", dtype="float64")
    rng = np.random.default_rng(seed)
    return model, model.particle_q_np + amount * rng.normal(size=(model.particle_count, 3)), rng


def _springs() -> Example:
    model, x, _ = _cloth()
    return Example(model, E.Springs(), x)


def _dashpots() -> Example:
    model, x, rng = _cloth(damping=0.7)
    v = wp.array(rng.normal(size=(model.particle_count, 3)), dtype=wp.vec3d)
    return Example(model, E.Dashpots(), x, begin=(model.particle_q, v, 0.01))


def _air_drag() -> Example:
    model, x, rng = _cloth(seed=3)
    v = wp.array(rng.normal(size=(model.particle_count, 3)), dtype=wp.vec3d)
    return Example(
        model, E.AirDrag(0.3, quadratic=0.2, wind=(0.5, 0, 0)), x, begin=(model.particle_q, v, 0.01)
    )


def _gravity() -> Example:
    model, x, _ = _cloth()
    return Example(model, E.Gravity(), x, linear=True)


def _gravity_from_array() -> Example:
    model, x, _ = _cloth()
    g = wp.array([[0.3, -9.81, 0.2]], dtype=wp.vec3d)
    return Example(model, E.GravityFromArray(g), x, linear=True)


def _control_points() -> Example:
    model, x, _ = _cloth(seed=3)
    handle = E.ControlPoints(model, [[0.0, 0.05, 0.0], [0.2, 0.05, 0.2]], stiffness=40.0, radius=0.15)
    return Example(model, handle, x)


def _ground_penalty() -> Example:
    b = pl.ModelBuilder()
    rng = np.random.default_rng(3)
    b.add_particles(rng.uniform(-0.05, 0.05, size=(12, 3)), rng.uniform(0.1, 1.0, 12), radius=0.01)
    b.add_ground(height=0.0)
    model = b.finalize(device="cpu", dtype="float64")
    return Example(model, E.GroundPenalty(1e4), model.particle_q_np.copy())


def _damped_ground_penalty() -> Example:
    """Compliant contact's clamped spring–damper: particles in contact at the step's start (y⁰ below the
    surface) get the damper, moved by up to 2 cm so that some are pushed, some released."""
    b = pl.ModelBuilder()
    rng = np.random.default_rng(4)
    b.add_particles(rng.uniform(-0.05, 0.05, size=(16, 3)), rng.uniform(0.1, 1.0, 16), radius=0.01)
    b.add_ground(height=0.0, stiffness=1e4, damping_ratio=0.5)
    model = b.finalize(device="cpu", dtype="float64")
    x = model.particle_q_np + rng.uniform(-0.02, 0.02, size=(16, 3))
    v = wp.zeros(16, dtype=wp.vec3d, device="cpu")
    return Example(model, E.DampedGroundPenalty(1e4, 100.0), x, begin=(model.particle_q, v, 0.01))


def _collider_penalty() -> Example:
    cols = pl.collision.Colliders()
    cols.add_sphere((0, 0, 0), 0.4)
    b = pl.ModelBuilder()
    b.add_particles([[0.05, 0.33, 0.1], [0.3, -0.1, 0.15], [0.9, 0.0, 0.0]], 0.1, radius=0.01)
    model = b.finalize(device="cpu", dtype="float64")
    return Example(model, E.ColliderPenalty(cols, stiffness=1e3), model.particle_q_np.copy())


def _barrier_contact() -> Example:
    # Ground and a sphere, each with particles inside d̂ (self-contact pairs couple points, whose blocks the
    # fixed diagonal pattern leaves out: their derivatives are checked per pair in tests/test_barrier.py).
    cols = pl.collision.Colliders()
    cols.add_sphere((0, 0.5, 0), 0.2)
    b = pl.ModelBuilder()
    b.add_particles(
        [[0.0, 0.004, 0.0], [0.3, 0.0021, 0.1], [0.07, 0.7047, 0.03], [0.9, 0.5, 0.0], [0.0, 0.295, 0.01]],
        0.1,
        radius=0.01,
    )
    b.add_ground(height=0.0)
    model = b.finalize(device="cpu", dtype="float64")
    return Example(
        model, E.BarrierContact(dhat=0.01, kappa=50.0, colliders=cols), model.particle_q_np.copy(), eps=1e-7
    )


def _tets(cls: type[E.TetElasticity]) -> Callable[[], Example]:
    def make() -> Example:
        b = pl.ModelBuilder()
        b.add_soft_box(cells=(2, 1, 1), size=(0.2, 0.1, 0.1), origin=(0, 0, 0), density=1000.0, E=1e3, nu=0.3)
        model = b.finalize(device="cpu", dtype="float64")
        rng = np.random.default_rng(2)
        x = model.particle_q_np + 0.02 * rng.standard_normal((model.particle_count, 3))
        return Example(model, cls(), x, hess_tol=1e-6)

    return make


#: A small model for every registered energy class. A new class needs an entry here.
EXAMPLES: dict[type[E.Energy], Callable[[], Example]] = {
    E.AirDrag: _air_drag,
    E.BarrierContact: _barrier_contact,
    E.ColliderPenalty: _collider_penalty,
    E.ControlPoints: _control_points,
    E.Dashpots: _dashpots,
    E.Gravity: _gravity,
    E.GravityFromArray: _gravity_from_array,
    E.GroundPenalty: _ground_penalty,
    E.DampedGroundPenalty: _damped_ground_penalty,
    E.Springs: _springs,
    **{c: _tets(c) for c in (E.TetElasticity, E.LinearElastic, E.StVK, E.Corotated, E.NeoHookean)},
}


def example_for(cls: type[E.Energy]) -> Example:
    """The example of ``cls``; a clear failure when it has none."""
    if cls not in EXAMPLES:
        raise LookupError(
            f"no example for {cls.__name__}: add one to EXAMPLES in tests/test_energy_contracts.py"
        )
    return EXAMPLES[cls]()


def check_energy(ex: Example, name: str) -> None:
    """Assert ∇E = central differences of E and ∇²E (unprojected) = central differences of ∇E."""
    g, g_fd, H, H_fd = energy_fd_check(ex.model, ex.energy, ex.x, eps=ex.eps, begin=ex.begin)
    assert np.abs(g_fd).max() > 0, f"{name}: E is flat at the example's x; the check would be vacuous"
    err = np.abs(g - g_fd).max() / np.abs(g_fd).max()
    assert err < ex.tol, f"{name}: gradient differs from central differences of E by {err:.2e} (relative)"
    h_scale = np.abs(H_fd).max()
    if ex.linear:
        assert np.abs(H).max() == 0.0 and h_scale < 1e-9, f"{name}: a linear energy has a nonzero Hessian"
        return
    assert h_scale > 0, f"{name}: ∇E is constant at the example's x; the Hessian check would be vacuous"
    err = np.abs(H - H_fd).max() / h_scale
    assert err < ex.hess_tol, (
        f"{name}: Hessian differs from central differences of ∇E by {err:.2e} (relative)"
    )
    assert np.abs(H - H.T).max() <= 1e-10 * h_scale, f"{name}: Hessian not symmetric"


@pytest.mark.parametrize("cls", E.ALL_ENERGIES, ids=lambda c: c.__name__)
def test_gradient_and_hessian_match_finite_differences(cls):
    """Every registered energy: ∇E and ∇²E equal float64 central differences on its example."""
    ex = example_for(cls)
    assert type(ex.energy) is cls, f"EXAMPLES[{cls.__name__}] makes a {type(ex.energy).__name__}"
    check_energy(ex, cls.__name__)


def test_registry_lists_every_public_energy():
    """Every concrete Energy class pl.energies exports is registered, and nothing else of pliant's."""
    exported = {
        getattr(E, n)
        for n in E.__all__
        if isinstance(getattr(E, n), type) and issubclass(getattr(E, n), E.Energy)
    }
    assert exported - {E.Energy} == set(E.ALL_ENERGIES)
    names = [c.__name__ for c in E.ALL_ENERGIES]
    assert names == sorted(names) and len(set(names)) == len(names)


class WrongGradientSprings(E.Springs):
    """Springs whose gradient is 1 % too large: the contract must reject it."""

    def gradient(self, model, x, out):
        tmp = wp.zeros_like(out)
        super().gradient(model, x, tmp)
        out.assign(out.numpy() + 1.01 * tmp.numpy())


class WrongHessianSprings(E.Springs):
    """Springs whose Hessian is doubled: the contract must reject it."""

    def hessian(self, model, x, slots, values, *, project_psd=True, scale=1.0):
        super().hessian(model, x, slots, values, project_psd=project_psd, scale=2.0 * scale)


def test_a_wrong_gradient_or_hessian_is_caught():
    """Broken energies are registered like any other and fail the check that the right one passes."""
    assert {WrongGradientSprings, WrongHessianSprings} <= set(E.registered_energies())
    ex = _springs()
    check_energy(ex, "Springs")
    with pytest.raises(AssertionError, match="WrongGradientSprings: gradient differs"):
        check_energy(Example(ex.model, WrongGradientSprings(), ex.x), "WrongGradientSprings")
    with pytest.raises(AssertionError, match="WrongHessianSprings: Hessian differs"):
        check_energy(Example(ex.model, WrongHessianSprings(), ex.x), "WrongHessianSprings")


def test_an_energy_without_an_example_fails_clearly():
    """A new registered energy with no entry in EXAMPLES is an error naming the class and the fix."""

    class NewEnergy(E.Springs):
        pass

    try:
        assert NewEnergy in E.registered_energies()
        with pytest.raises(LookupError, match="no example for NewEnergy: add one to EXAMPLES"):
            example_for(NewEnergy)
    finally:
        del NewEnergy
        gc.collect()  # __subclasses__ holds weak references: the registry forgets it
    assert all(c.__name__ != "NewEnergy" for c in E.registered_energies())
