"""Contracts every registered constraint meets (``pl.constraints.registered_constraints``): ∇C, as
``Constraint.evaluate`` returns it from the funcs the projection uses, equals central differences of C in
float64 on a small, randomly perturbed model.

The tests walk the registry, so a new Constraint class is checked without editing a list of names. Each
class needs an entry in :data:`EXAMPLES`: a model to run on, or (only for a set with no scalar C) the
reason it has none; a class with neither fails with "no example for <Name>: add one to EXAMPLES in
tests/test_constraint_contracts.py".
"""

from __future__ import annotations

import gc
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
import warp as wp

import pliant as pl
import pliant.constraints as pc
from pliant.solvers import XPBD

#: Classes without a scalar C(x) to differentiate, each with the reason and where it is tested instead.
NO_SCALAR_C = {
    pc.ShapeMatching: "projects clusters onto a rotated rest shape (no C(x)); see tests/test_xpbd.py",
}


@wp.func
def _user_angle_c(x0: Any, x1: Any, x2: Any, x3: Any, p: Any):
    """A three-point user constraint for GenericConstraint: (x1 − x0)·(x2 − x0) − p [m²]."""
    return wp.dot(x1 - x0, x2 - x0) - p


def _perturbed(model: pl.Model, seed: int, amount: float) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return model.particle_q_np + amount * rng.normal(size=(model.particle_count, 3))


def _cloth(**kw: Any) -> pl.Model:
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_cloth_grid(nx=2, ny=2, size=0.2, mass=0.1, stiffness=50.0, origin=(0, 0, 0), plane="xz", **kw)
    return b.finalize(device="cpu", dtype="float64")


def _bound(model: pl.Model, c: pc.Constraint, steps: int = 0) -> pc.Constraint:
    """``c`` bound to ``model`` by an XPBD solver, after ``steps`` steps (contacts are found in a step)."""
    solver = XPBD(model, iterations=2, constraints=[c], contact=False)
    s0, s1 = model.state(), model.state()
    for _ in range(steps):
        solver.step(s0, s1, None, 1e-3)
        s0, s1 = s1, s0
    return c


def _distance():
    model = _cloth()
    return _bound(model, pc.Distance()), _perturbed(model, 1, 0.02)


def _dihedral():
    model = _cloth()
    return _bound(model, pc.DihedralBending(compliance=1e-3)), _perturbed(model, 2, 0.02)


def _isometric():
    model = _cloth()
    return _bound(model, pc.IsometricBending()), _perturbed(model, 3, 0.02)


def _triangle_area():
    model = _cloth()
    return _bound(model, pc.TriangleArea()), _perturbed(model, 4, 0.02)


def _volume():
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_soft_box(cells=(2, 1, 1), size=(0.2, 0.1, 0.1), origin=(0, 0, 0), E=1e3, nu=0.3)
    model = b.finalize(device="cpu", dtype="float64")
    return _bound(model, pc.Volume()), _perturbed(model, 5, 0.01)


def _attachment():
    model = _cloth()
    c = pc.Attachment([0, 4, 7], [[0.0, 0.1, 0.0], [0.1, 0.05, 0.1], [0.2, 0.0, 0.3]], rest_length=0.02)
    return _bound(model, c), _perturbed(model, 6, 0.02)


def _generic():
    model = _cloth()
    c = pc.GenericConstraint(_user_angle_c, [[0, 1, 3], [4, 5, 7], [8, 5, 6]], params=0.001)
    return _bound(model, c), _perturbed(model, 7, 0.02)


def _ground():
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_particles(np.random.default_rng(8).uniform(-0.05, 0.05, (5, 3)), 0.1, radius=0.01)
    b.add_ground(height=0.0)
    model = b.finalize(device="cpu", dtype="float64")
    return _bound(model, pc.Ground(normal=(0.2, 1.0, -0.1))), _perturbed(model, 8, 0.01)


def _particle_collision():
    # A 2×2×2 lattice (spacing 0.035 m, radius 0.02 m): its 12 edges lie within the query radius 0.04 m,
    # its diagonals (≥ 0.049 m) outside, far enough that no 1 mm perturbation adds or removes a pair.
    g = np.stack(np.meshgrid(*[[0.0, 0.035]] * 3, indexing="ij"), -1).reshape(-1, 3)
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_particles(g, 0.1, radius=0.02)
    model = b.finalize(device="cpu", dtype="float64")
    return _bound(model, pc.ParticleCollision()), _perturbed(model, 9, 0.001)


def _point_triangle():
    # A cloth square in y = 0 and two particles falling onto it: one step finds their contacts.
    b = pl.ModelBuilder(gravity=(0.0, -9.81, 0.0))
    b.add_cloth_grid(
        nx=2, ny=2, size=0.2, mass=0.1, stiffness=50.0, origin=(0, 0, 0), plane="xz", pin=range(9)
    )
    b.add_particles([[0.07, 0.004, 0.03], [0.13, -0.004, 0.16]], 0.1)
    model = b.finalize(device="cpu", dtype="float64")
    c = _bound(model, pc.PointTriangleCollision(thickness=0.01), steps=1)
    assert int(c.contact_count.numpy()[0]) >= 2, "the example needs contacts"
    return c, _perturbed(model, 10, 0.002)


#: A bound constraint and the positions to check at, for every registered constraint class.
EXAMPLES: dict[type[pc.Constraint], Callable[[], tuple[pc.Constraint, np.ndarray]]] = {
    pc.Attachment: _attachment,
    pc.DihedralBending: _dihedral,
    pc.Distance: _distance,
    pc.GenericConstraint: _generic,
    pc.Ground: _ground,
    pc.IsometricBending: _isometric,
    pc.ParticleCollision: _particle_collision,
    pc.PointTriangleCollision: _point_triangle,
    pc.TriangleArea: _triangle_area,
    pc.Volume: _volume,
}


def example_for(cls: type[pc.Constraint]) -> tuple[pc.Constraint, np.ndarray]:
    """The example of ``cls``; a clear failure when it has none."""
    if cls not in EXAMPLES:
        raise LookupError(
            f"no example for {cls.__name__}: add one to EXAMPLES in tests/test_constraint_contracts.py"
        )
    return EXAMPLES[cls]()


def _rows(c: pc.Constraint, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """evaluate() at x with its rows in a canonical order (contact sets come in thread order)."""
    val, idx, grad = c.evaluate(wp.array(x, dtype=wp.vec3d))
    order = np.lexsort(idx.T[::-1])
    return val[order], idx[order], grad[order]


def check_constraint(c: pc.Constraint, x: np.ndarray, name: str, h: float = 1e-6, tol: float = 1e-6) -> None:
    """Assert ∇C of every row of ``c.evaluate`` equals central differences of C (dense Jacobians)."""
    val, idx, grad = _rows(c, x)
    assert val.size > 0, f"{name}: the example has no constraints; the check would be vacuous"
    n = x.shape[0]
    J = np.zeros((val.size, 3 * n))
    for j in range(idx.shape[1]):
        np.add.at(J, (np.arange(val.size)[:, None], 3 * idx[:, j : j + 1] + np.arange(3)), grad[:, j])
    J_fd = np.zeros_like(J)
    for k in range(3 * n):
        xp, xm = x.copy(), x.copy()
        xp[k // 3, k % 3] += h
        xm[k // 3, k % 3] -= h
        (cp, ip, _), (cm, im, _) = _rows(c, xp), _rows(c, xm)
        assert np.array_equal(ip, idx) and np.array_equal(im, idx), f"{name}: the constraint set changed"
        J_fd[:, k] = (cp - cm) / (2 * h)
    scale = np.abs(J_fd).max()
    assert scale > 0, f"{name}: C is flat at the example's x; the check would be vacuous"
    err = np.abs(J - J_fd).max() / scale
    assert err < tol, f"{name}: ∇C differs from central differences of C by {err:.2e} (relative)"


@pytest.mark.parametrize("cls", pc.ALL_CONSTRAINTS, ids=lambda c: c.__name__)
def test_gradient_matches_finite_differences(cls):
    """Every registered constraint with a scalar C: ∇C equals float64 central differences of C."""
    if cls in NO_SCALAR_C:
        with pytest.raises(NotImplementedError, match="no scalar C"):
            cls().evaluate(None)
        return
    c, x = example_for(cls)
    assert type(c) is cls, f"EXAMPLES[{cls.__name__}] makes a {type(c).__name__}"
    check_constraint(c, x, cls.__name__)


def test_registry_lists_every_public_constraint():
    """Every concrete Constraint class pl.constraints exports is registered, and nothing else of pliant's."""
    exported = {
        getattr(pc, n)
        for n in pc.__all__
        if isinstance(getattr(pc, n), type) and issubclass(getattr(pc, n), pc.Constraint)
    }
    assert exported - {pc.Constraint, pc.FixedArityConstraint} == set(pc.ALL_CONSTRAINTS)
    assert set(EXAMPLES) | set(NO_SCALAR_C) == set(pc.ALL_CONSTRAINTS), "stale entries in EXAMPLES"


def test_a_wrong_constraint_gradient_is_caught():
    """A Distance whose ∇C is off by 1 % fails the check that Distance passes."""

    class WrongDistance(pc.Distance):
        def evaluate(self, x):
            val, idx, grad = super().evaluate(x)
            return val, idx, 1.01 * grad

    wrong = None
    try:
        assert WrongDistance in pc.registered_constraints()
        c, x = _distance()
        check_constraint(c, x, "Distance")
        wrong = _bound(c.model, WrongDistance())
        with pytest.raises(AssertionError, match="WrongDistance: ∇C differs"):
            check_constraint(wrong, x, "WrongDistance")
        with pytest.raises(LookupError, match="no example for WrongDistance: add one to EXAMPLES"):
            example_for(WrongDistance)
    finally:
        del WrongDistance, wrong
        gc.collect()  # __subclasses__ holds weak references: the registry forgets it
    assert all(c.__name__ != "WrongDistance" for c in pc.registered_constraints())
