"""The parameter registry (issue 25 item 3): every differentiable parameter that an energy, constraint,
collider, solver or the Model / State / Control declares gets a float64 central finite-difference check of
its gradient through ``pl.diff.rollout`` — walked from the registry, not listed here — and inconsistent or
wrong declarations are caught.

Finite differences perturb the declared array and, for a model array, build the solver again afterwards,
so a parameter that a solver reads once at construction (and whose tape gradient is therefore zero) fails
the check if it is declared differentiable.
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from test_gradients import loss_of

import pliant as pl
from pliant.model import _parameters as reg
from pliant.model._parameters import Parameter, ParameterError

STEPS, FRAMES, DT = 20, 5, 1e-3


def _mass_spring_model() -> pl.Model:
    # A 4×4 cloth with dashpots falling onto a sphere collider and the ground, one kinematic corner.
    b = pl.ModelBuilder()
    b.add_cloth_grid(
        nx=4, ny=4, size=0.3, mass=0.05, stiffness=80.0, damping=0.02, origin=(-0.15, 0.205, -0.15)
    )
    b.add_kinematic([0])
    b.add_ground(0.18, friction=0.3, restitution=0.4)
    m = b.finalize(device="cpu", dtype="float64", requires_grad=True)
    rng = np.random.default_rng(0)
    # Sliding fast enough that friction slows rather than sticks (a stuck contact has no μ-gradient).
    m.particle_qd.assign(np.array([2.0, -1.5, 0.5]) + 0.1 * rng.normal(size=(m.particle_count, 3)))
    return m


def _mass_spring_solver(m: pl.Model):
    col = pl.collision.Colliders()
    col.add_sphere((0.02, 0.0, 0.01), 0.2, friction=0.4, restitution=0.3)
    return pl.solvers.ForceSolver(
        m, pl.energies.mass_spring(), pl.integrators.SymplecticEuler(), damping_rate=0.5, collisions=[col]
    )


def _mass_spring_control(m: pl.Model):
    c = m.control()
    c.particle_f.assign(np.random.default_rng(1).normal(size=(m.particle_count, 3)) * 0.01)
    c.kinematic_targets.assign(c.kinematic_targets.numpy() + [[0.0, 0.02, 0.01]])
    return c


def _box_model() -> pl.Model:
    b = pl.ModelBuilder()
    b.add_soft_box(cells=(2, 2, 2), size=(0.2, 0.2, 0.2), origin=(0.0, 0.3, 0.0), E=2e4, nu=0.3)
    m = b.finalize(device="cpu", dtype="float64", requires_grad=True)
    q = m.particle_q.numpy()
    r = q - q.mean(axis=0)
    m.particle_qd.assign(2.0 * r + np.cross([0.0, 3.0, 1.0], r))  # expanding and spinning: stresses act
    return m


def _xpbd_cloth_model() -> pl.Model:
    b = pl.ModelBuilder()
    b.add_cloth_grid(
        nx=5, ny=5, size=0.5, mass=0.2, stiffness=300.0, origin=(-0.25, 0.05, -0.25), plane="xz", pin=[0, 5]
    )
    m = b.finalize(device="cpu", dtype="float64", requires_grad=True)
    m.bending_stiffness.fill_(0.05)  # XPBD's default bending set reads α = 1/k from it when it is built
    return m


def _xpbd(**kw):
    return lambda m: pl.solvers.XPBD(m, iterations=5, schedule="jacobi", relaxation=1.5, **kw)


#: Set-ups the walk tries, in order, for each parameter: (model, solver, control) factories. A parameter
#: is checked in the first set-up whose solver holds it; one that none holds fails the test (add a set-up).
SETUPS = {
    "mass_spring": (_mass_spring_model, _mass_spring_solver, _mass_spring_control),
    "fem": (
        _box_model,
        lambda m: pl.solvers.ForceSolver(m, [pl.energies.NeoHookean(), pl.energies.Gravity()]),
        None,
    ),
    "xpbd_cloth": (_xpbd_cloth_model, _xpbd(), None),
    "xpbd_box": (_box_model, _xpbd(volume_compliance=1e-6), None),
}


def _locate(p: Parameter):
    """The first set-up holding ``p`` (name, (model, solver, control, array-or-(array, component))), or
    None."""
    from pliant.diff import GradientError

    for name, (mk_model, mk_solver, mk_control) in SETUPS.items():
        m = mk_model()
        s = mk_solver(m)
        c = mk_control(m) if mk_control else None
        try:
            a = p.getter()(m, s, m.state(), c)
        except (GradientError, ValueError):
            continue
        arr = a[0] if isinstance(a, tuple) else a
        if arr.shape[0] == 0:
            continue
        return name
    return None


def _loss_with(setup: str, p: Parameter, delta: np.ndarray | float | None, w: wp.array) -> float:
    """The rollout loss with ``p``'s array moved by ``delta`` (the solver built again after a model array
    changed, so values read at construction see it)."""
    mk_model, mk_solver, mk_control = SETUPS[setup]
    m = mk_model()
    s = mk_solver(m)
    c = mk_control(m) if mk_control else None
    state0 = m.state()
    if delta is not None:
        a = p.getter()(m, s, state0, c)
        arr, comp = a if isinstance(a, tuple) else (a, None)
        v = arr.numpy().astype(np.float64)
        if comp is None:
            v = v + delta
        else:
            v[comp] += delta
        arr.assign(v)
        if "model.particle_inv_mass" in p.arrays:  # the mass's second array, as the builder keeps it
            inv = m.particle_inv_mass.numpy()
            m.particle_inv_mass.assign(np.where(inv > 0, 1.0 / v, 0.0))
        if p.arrays[0].startswith("model."):
            s = mk_solver(m)
    return pl.diff.rollout(
        m, s, loss_of(w), frames=FRAMES, substeps=STEPS // FRAMES, dt=DT, state0=state0, control=c
    ).loss


def fd_check(p: Parameter, setup: str, tol: float = 1e-5) -> tuple[float, float]:
    """(tape, central difference) of the directional derivative of the rollout loss along a random
    direction of ``p``'s values in ``setup``; asserts that they agree within ``tol`` (relative)."""
    mk_model, mk_solver, mk_control = SETUPS[setup]
    m = mk_model()
    s = mk_solver(m)
    c = mk_control(m) if mk_control else None
    rng = np.random.default_rng(7)
    w = wp.array(rng.normal(size=(m.particle_count, 3)), dtype=wp.vec3d)
    res = pl.diff.rollout(
        m, s, loss_of(w), frames=FRAMES, substeps=STEPS // FRAMES, dt=DT, params=[p.name], control=c
    )
    g = np.asarray(res.grads[p.name], dtype=np.float64)
    a = p.getter()(m, s, m.state(), c)
    arr, comp = a if isinstance(a, tuple) else (a, None)
    theta = arr.numpy().astype(np.float64)
    if comp is not None:
        theta = theta[comp]
    d = rng.normal(size=np.shape(theta))
    eps = 1e-6 * max(float(np.abs(theta).mean()), 1e-2)
    if p.log and p.bounds is not None:  # a positive magnitude: relative changes, as its fits make
        d, eps = d * np.abs(theta), 1e-4
    fd = (_loss_with(setup, p, eps * d, w) - _loss_with(setup, p, -eps * d, w)) / (2 * eps)
    ad = float(np.sum(g * d))
    assert abs(fd) > 1e-9, f"{p.name}: the loss of set-up {setup!r} does not depend on it (test set-up)"
    assert ad == pytest.approx(fd, rel=tol), f"{p.name} in {setup}: tape {ad} vs finite differences {fd}"
    return ad, fd


DIFFERENTIABLE = sorted(n for n, (p, _) in pl.diff.parameters().items() if p.differentiable)


@pytest.mark.parametrize("name", DIFFERENTIABLE)
def test_every_declared_parameter_matches_finite_differences(name):
    """Each differentiable parameter in the registry: tape gradient through pl.diff.rollout = central
    differences (float64, relative 1e-5; contact switches make ground and collider ones piecewise smooth,
    1e-4)."""
    p = reg.parameter(name)
    setup = _locate(p)
    assert setup is not None, f"{name}: no set-up in SETUPS holds it; add one that does"
    fd_check(p, setup, tol=1e-4 if p.per == "collider" or name.startswith("ground_") else 1e-5)


def test_the_tables_are_views_of_the_registry():
    """pl.diff.PARAMETERS is every differentiable declaration; the per-world table every per-element model
    array (the non-differentiable bending stiffness included); every declaration names a unit."""
    from pliant.model._worlds import PARAMETERS as WORLD

    table = pl.diff.parameters()
    assert sorted(pl.diff.PARAMETERS) == DIFFERENTIABLE
    assert "bending_stiffness" not in pl.diff.PARAMETERS and WORLD["bending_stiffness"] == (
        "bending",
        "N m/rad",
    )
    assert sorted(WORLD) == sorted(
        [
            "spring_stiffness",
            "spring_damping",
            "spring_rest_length",
            "bending_stiffness",
            "tet_mu",
            "tet_lam",
            "particle_mass",
        ]
    )
    assert all(p.unit for p, _ in table.values())
    # Solvers that hold the damping rate share one declaration.
    owners = {o.__name__ for o in table["damping_rate"][1]}
    assert {"ForceSolver", "FastMassSpring"} <= owners


def test_a_wrong_declaration_is_caught(monkeypatch):
    """A parameter declared differentiable that a solver only reads at construction (the bending stiffness,
    turned into XPBD compliances once) has a zero tape gradient: the finite-difference check fails. A
    declaration naming an array the Model lacks, or two owners disagreeing, is refused at once."""

    class Claims:
        @classmethod
        def parameters(cls):
            return (
                Parameter(
                    "bending_claimed",
                    "bending stiffness, wrongly claimed differentiable",
                    "N m/rad",
                    "bending",
                    ("model.bending_stiffness",),
                    (1e-6, 1e2),
                ),
            )

    monkeypatch.setattr(reg, "OWNERS", [*reg.OWNERS, Claims])
    p = reg.parameter("bending_claimed")
    assert _locate(p) is not None
    with pytest.raises(AssertionError, match="tape .* vs finite differences"):
        fd_check(p, "xpbd_cloth")

    class Typo:
        @classmethod
        def parameters(cls):
            return (
                Parameter("spring_stifness", "typo", "N/m", "spring", ("model.spring_stifness",), (1.0, 2.0)),
            )

    monkeypatch.setattr(reg, "OWNERS", [*reg.OWNERS, Typo])
    with pytest.raises(ParameterError, match="the Model has no array 'spring_stifness'"):
        reg.registry()

    class Disagrees:
        @classmethod
        def parameters(cls):
            return (Parameter("tet_mu", "Lamé μ", "kPa", "tet", ("model.tet_mu",), (1.0, 2.0)),)

    monkeypatch.setattr(reg, "OWNERS", [o for o in reg.OWNERS if o is not Typo] + [Disagrees])
    with pytest.raises(ParameterError, match="declare 'tet_mu' differently"):
        reg.registry()
    with pytest.raises(ParameterError, match="bounds"):
        reg.check(Claims, Parameter("k", "k", "N/m", "spring", ("model.spring_stiffness",), (0.0, 1.0)))


def test_a_new_energy_becomes_differentiable_by_declaring(monkeypatch):
    """Declaring a parameter is all it takes: rollout then returns its gradient (here a second name for
    the dashpots' array, checked against finite differences)."""

    class Viscous:
        @classmethod
        def parameters(cls):
            return (
                Parameter(
                    "viscosity", "dashpot γ, again", "N s/m", "spring", ("model.spring_damping",), (1e-6, 1.0)
                ),
            )

    monkeypatch.setattr(reg, "OWNERS", [*reg.OWNERS, Viscous])
    assert "viscosity" in pl.diff.PARAMETERS
    fd_check(reg.parameter("viscosity"), "mass_spring")
    from pliant.fit._params import per_element_arrays

    class _Scene:
        model = _mass_spring_model()
        solver = None

    assert list(per_element_arrays(_Scene, "viscosity")) == ["model.spring_damping"]
