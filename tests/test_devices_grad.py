"""Gradients, fitting and the Gaussian rasteriser on every available device (CUDA when a GPU is present):
a representative row of the gradient matrix per solver family, a fit stage and the rasteriser's forward,
backward and visual corrector each give the CPU's numbers on the device within a stated bound (float64),
and each gradient equals central differences taken on the device itself. tests/test_devices.py covers the
forward physics."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
import warp as wp
from helpers import FIT_ROPE

import pliant as pl
from pliant.fit import Problem, cmaes, gradient_stage, observe
from pliant.fit._params import apply_globals
from pliant.gaussians import Camera, Gaussians, VisualCorrector, bind, render
from tests.test_gaussians import _camera, _scene, _weights


@wp.kernel
def _weighted_sum(x: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d), out: wp.array(dtype=wp.float64)):
    i = wp.tid()
    wp.atomic_add(out, 0, wp.dot(x[i], w[i]))


def weighted_loss(m: pl.Model, device: str) -> Callable[[pl.State], wp.array]:
    """L = Σ w·x of a State, w fixed random weights per particle (a loss that every particle moves)."""
    w = wp.array(np.random.default_rng(0).normal(size=(m.particle_count, 3)), dtype=wp.vec3d, device=device)

    def loss(state: pl.State) -> wp.array:
        out = wp.zeros(1, dtype=wp.float64, device=device, requires_grad=True)
        wp.launch(_weighted_sum, state.particle_q.shape[0], [state.particle_q, w, out], device=device)
        return out

    return loss


# ----------------------------------------------------------------------------------------- gradient matrix
def _cloth(device: str) -> pl.Model:
    b = pl.ModelBuilder()
    b.add_cloth_grid(
        nx=4, ny=4, size=0.3, mass=0.05, stiffness=40.0, damping=0.02, origin=(0, 0.5, 0), pin="top-corners"
    )
    return b.finalize(device=device, dtype="float64", requires_grad=True)


def _box(device: str) -> pl.Model:
    b = pl.ModelBuilder()
    b.add_soft_box(cells=(1, 1, 2), size=(0.1, 0.1, 0.2), origin=(0, 0.3, 0), density=500.0, E=2e4, nu=0.3)
    m = b.finalize(device=device, dtype="float64", requires_grad=True)
    # Expanding, so that the elastic forces act (a rigid fall does not depend on μ).
    q = m.particle_q.numpy()
    m.particle_qd.assign(2.0 * (q - q.mean(axis=0)))
    return m


def _springs(m: pl.Model) -> pl.solvers.Solver:
    return pl.solvers.ForceSolver(m, pl.energies.mass_spring(), pl.integrators.SymplecticEuler())


def _implicit(m: pl.Model) -> pl.solvers.Solver:
    integ = pl.integrators.BackwardEuler(newton_tol=1e-12)
    return pl.solvers.ForceSolver(m, pl.energies.mass_spring(), integ)


def _fem(m: pl.Model) -> pl.solvers.Solver:
    energies = [pl.energies.NeoHookean(), pl.energies.Gravity()]
    return pl.solvers.ForceSolver(m, energies, pl.integrators.SymplecticEuler())


#: One row per solver family: (model, solver, parameter, frames, substeps, dt, checkpoint_every, bound on
#: the relative CPU/device difference). Implicit steps stop Newton at a tolerance, so the device's
#: differently ordered sums may take a different last iterate: a looser bound there.
ROWS: dict[str, tuple[Callable, Callable, str, int, int, float, int, float]] = {
    "springs-symplectic": (_cloth, _springs, "spring_damping", 3, 10, 1e-3, 1, 1e-9),
    "fem-explicit": (_box, _fem, "tet_mu", 3, 10, 1e-4, 2, 1e-9),
    "implicit-backward-euler": (_cloth, _implicit, "spring_stiffness", 2, 2, 5e-3, 1, 1e-7),
    "xpbd-jacobi": (
        _cloth,
        lambda m: pl.solvers.XPBD(m, iterations=4, schedule="jacobi"),
        "compliance_distance",
        3,
        2,
        5e-3,
        3,
        1e-9,
    ),
    "fast-mass-spring": (
        _cloth,
        lambda m: pl.solvers.FastMassSpring(m, method="symplectic"),
        "spring_stiffness",
        3,
        10,
        1e-3,
        1,
        1e-9,
    ),
    "fast-mass-spring-implicit": (
        _cloth,
        lambda m: pl.solvers.FastMassSpring(m, method="implicit", cg_tol=1e-12, cg_iterations=300),
        "spring_stiffness",
        2,
        2,
        5e-3,
        1,
        1e-7,
    ),
}


def _gradient_row(device: str, row: str) -> tuple[float, np.ndarray, float, float]:
    """(loss, ∂loss/∂parameter, the gradient along a random direction d, the central difference along d)
    of ``row``'s rollout on ``device``."""
    make_model, make_solver, name, frames, substeps, dt, every, _ = ROWS[row]
    m = make_model(device)
    solver = make_solver(m)
    loss = weighted_loss(m, device)

    def run(params: list[str]) -> pl.diff.RolloutResult:
        return pl.diff.rollout(
            m, solver, loss, frames=frames, substeps=substeps, dt=dt, params=params, checkpoint_every=every
        )

    res = run([name])
    entry = pl.diff.PARAMETERS[name](m, solver, m.state(), None)
    array, comp = entry if isinstance(entry, tuple) else (entry, None)
    assert comp is None, f"{name}: the rows use per-element parameters"
    base = array.numpy().copy()
    d = np.random.default_rng(1).normal(size=base.shape) * np.abs(base)
    h = 1e-3  # relative: the loss is O(1) and the effect small, so a smaller step drowns in round-off

    def at(eps: float) -> float:
        array.assign(base + eps * d)
        return run([]).loss

    fd = (at(h) - at(-h)) / (2 * h)
    array.assign(base)
    g = res.grads[name]
    return res.loss, g, float(np.sum(g * d)), fd


@pytest.mark.parametrize("row", list(ROWS))
def test_gradient_row_matches_cpu_and_finite_differences(device: str, row: str) -> None:
    """Each solver family's rollout gradient on this device equals the CPU's (float64, the row's bound) and
    the device's own central differences (relative 1e-4)."""
    results = {dev: _gradient_row(dev, row) for dev in {"cpu", device}}
    loss, g, along, fd = results[device]
    ref_loss, ref = results["cpu"][:2]
    bound = ROWS[row][-1]
    assert np.abs(ref).max() > 0, "the CPU gradient is zero: the row tests nothing"
    assert loss == pytest.approx(ref_loss, rel=bound)
    np.testing.assert_allclose(g, ref, rtol=bound, atol=bound * np.abs(ref).max())
    assert abs(fd) > 1e-10
    assert along == pytest.approx(fd, rel=1e-4)


def test_replayed_rollout_matches_direct_on_device(device: str) -> None:
    """A repeated rollout (mass-spring cloth) is replayed as a graph from its third call on this device, and
    its loss and gradient equal a direct run's: bit for bit on the CPU, within 1e-9 relative on CUDA (the
    atomics sum in any order)."""
    make_model, make_solver, name, frames, substeps, dt, every, _ = ROWS["springs-symplectic"]
    m = make_model(device)
    solver = make_solver(m)
    loss = weighted_loss(m, device)
    kw = {"frames": frames, "substeps": substeps, "dt": dt, "params": [name], "checkpoint_every": every}
    for _ in range(3):
        res = pl.diff.rollout(m, solver, loss, **kw)
    assert res.replayed, res.graph_reason
    ref = pl.diff.rollout(m, solver, loss, graph=False, **kw)
    rtol = 0.0 if device == "cpu" else 1e-9
    assert res.loss == pytest.approx(ref.loss, rel=rtol, abs=0.0)
    np.testing.assert_allclose(
        res.grads[name], ref.grads[name], rtol=rtol, atol=rtol * np.abs(ref.grads[name]).max()
    )


# ------------------------------------------------------------------------------------------------- fitting
def _rope_problem(device: str, obs) -> Problem:
    cfg = pl.scene.parse_scene(FIT_ROPE.replace('device = "cpu"', f'device = "{device}"'))
    return Problem(
        apply_globals(cfg, {"stiffness": 80.0}), obs, params=["stiffness"], per_element="stiffness"
    )


@pytest.fixture(scope="module")
def rope_obs():
    return observe(pl.scene.build_scene(pl.scene.parse_scene(FIT_ROPE)), tracks=7)


def test_gradient_stage_matches_cpu(device: str, rope_obs) -> None:
    """Four Adam epochs of per-spring stiffness factors (one-frame horizons, tape gradients) on this device
    give the CPU's stiffnesses and loss history (relative 1e-9, float64), and the loss falls."""
    out = {}
    for dev in {"cpu", device}:
        p = _rope_problem(dev, rope_obs)
        out[dev] = gradient_stage(p, p.nominal, iterations=4, lr=0.1, tol=0.0)
    k, ref = (
        out[device].per_element["model.spring_stiffness"],
        out["cpu"].per_element["model.spring_stiffness"],
    )
    np.testing.assert_allclose(k, ref, rtol=1e-9)
    np.testing.assert_allclose(out[device].history, out["cpu"].history, rtol=1e-9)
    assert out[device].history[-1] < out[device].history[0]


def test_cmaes_stage_matches_cpu(device: str, rope_obs) -> None:
    """Three CMA-ES generations (same seed) on this device sample and rank as on the CPU: the same
    stiffness and loss (relative 1e-9), and the loss does not rise."""
    out = {}
    for dev in {"cpu", device}:
        p = _rope_problem(dev, rope_obs)
        out[dev] = cmaes(p, generations=3, seed=1)
    assert out[device].values["stiffness"] == pytest.approx(out["cpu"].values["stiffness"], rel=1e-9)
    assert out[device].loss == pytest.approx(out["cpu"].loss, rel=1e-9)
    assert out[device].history[-1] <= out[device].history[0]


# ------------------------------------------------------------------------------------ Gaussian rasteriser
def _render_grads(device: str) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(colour, alpha, depth images) and the gradients of Σ w·images w.r.t. every Gaussian parameter."""
    g = _scene(requires_grad=True, device=device)
    cam = _camera()
    w = _weights((48, 64))
    tape = wp.Tape()
    with tape:
        c, a, d = render(g, cam, (0.1, 0.2, 0.3))
    seeds = {
        c: wp.array(w[0], dtype=wp.vec3d, device=device),
        a: wp.array(w[1], dtype=wp.float64, device=device),
        d: wp.array(w[2], dtype=wp.float64, device=device),
    }
    tape.backward(grads=seeds)
    return [x.numpy() for x in (c, a, d)], [p.grad.numpy() for p in g.parameters()]


def test_rasteriser_forward_and_backward_match_cpu(device: str) -> None:
    """The float64 images and every parameter gradient (means, rotations, scales, opacities, SH) on this
    device equal the CPU's (relative 1e-9 of each array's largest entry; the atomics sum in another order)."""
    out = {dev: _render_grads(dev) for dev in {"cpu", device}}
    images, grads = out[device]
    for x, ref in zip(images + grads, out["cpu"][0] + out["cpu"][1], strict=True):
        assert np.abs(ref).max() > 0
        np.testing.assert_allclose(x, ref, rtol=0, atol=1e-9 * np.abs(ref).max())


def _blob(device: str):
    g1 = np.linspace(-0.3, 0.3, 3)
    rng = np.random.default_rng(2)
    X = np.stack(np.meshgrid(g1, g1, g1, indexing="ij"), -1).reshape(-1, 3) + rng.normal(0, 0.01, (27, 3))
    g = Gaussians.from_values(
        X, scales=0.09, opacities=0.8, colors=rng.uniform(0, 1, X.shape), dtype="float64", device=device
    )
    cams = [
        Camera.look_at([2.5 * np.sin(a), 0.8, 2.5 * np.cos(a)], [0, 0, 0], width=48, height=36)
        for a in (0.3, 2.4, 4.5)
    ]
    return X, bind(g, X, method="lbs", k=4, neighbours=8), cams


def test_visual_corrector_matches_cpu(device: str) -> None:
    """The photometric state estimate (L-BFGS-B over renders and their gradients) on this device recovers a
    known shift as on the CPU: the same estimate within 1e-7 m, and the shift to a tenth of its length."""
    shift = np.array([0.03, -0.02, 0.01])
    est = {}
    for dev in {"cpu", device}:
        X, b, cams = _blob(dev)
        moved = wp.array(X + shift, dtype=wp.vec3d, device=dev)
        observed = [render(b.deform(moved), c).colour.numpy() for c in cams]
        vc = VisualCorrector(b, cams, iterations=10)
        est[dev] = vc.estimate(wp.array(X, dtype=wp.vec3d, device=dev), observed)
    X = _blob("cpu")[0]
    np.testing.assert_allclose(est[device], est["cpu"], rtol=0, atol=1e-7)
    assert np.linalg.norm((est[device] - X).mean(axis=0) - shift) < 0.1 * np.linalg.norm(shift)
