"""XPBD's CUDA schedule: launches per iteration, its colouring, and its trajectory against the CPU path's.

On CUDA a colour sweep launches once per colour, so the colouring there minimises the number of colours
(``color_constraints(..., fewest=True)``); the CPU keeps its Luby colouring and one fused launch per set.
``CUDA_SCHEDULE_ON_CPU`` runs the CUDA schedule on the CPU, which is how these tests count its launches
(the solver's recorded plan: one entry per launch or memset) and compare its motion without a GPU.
"""

from __future__ import annotations

import numpy as np
import pytest

import pliant.constraints._base as base
from pliant.bench._drape_motion import curve_error, solver_curve
from pliant.bench._mass_spring import FRAME_DT, cloth_drape_model
from pliant.constraints import color_constraints, color_incidence_first_fit
from pliant.model import ModelBuilder
from pliant.solvers import XPBD


@pytest.fixture
def cuda_schedule(monkeypatch: pytest.MonkeyPatch) -> None:
    """The CUDA schedule on every device (the CPU included) for the solvers this test builds."""
    monkeypatch.setattr(base, "CUDA_SCHEDULE_ON_CPU", True)


def _max_degree(indices: np.ndarray, inv_mass: np.ndarray) -> int:
    """Most constraints at one movable particle: no colouring can use fewer colours."""
    live = indices[inv_mass[indices] > 0]
    return int(np.bincount(live.ravel()).max())


def _assert_valid(colors: np.ndarray, indices: np.ndarray, inv_mass: np.ndarray) -> None:
    """No two constraints of one colour share a movable particle."""
    for c in range(int(colors.max()) + 1):
        moved = indices[colors == c].ravel()
        moved = moved[inv_mass[moved] > 0]
        assert np.unique(moved).size == moved.size, f"colour {c} moves a particle twice"


def _plan_length(model, solver: XPBD, dt: float) -> int:
    """Launches (and memsets) of one recorded step."""
    solver.step(model.state(), model.state(), None, dt)
    (plan,) = solver._plans.values()
    return len(plan)


@pytest.mark.parametrize("n", [16, 64])
def test_first_fit_colours_a_grid_cloth_in_its_max_degree(n: int) -> None:
    """Structural + shear springs of a grid: 8 springs meet at an inner particle, so 8 colours is the least
    possible; the first-fit colouring reaches it (Luby's random priorities need more) and is valid."""
    model = cloth_drape_model(n, device="cpu", dtype="float32")
    idx = model.spring_indices.numpy().reshape(-1, 2).astype(np.int64)
    w = model.particle_inv_mass.numpy()
    fewest = color_constraints(idx, w, fewest=True)
    _assert_valid(fewest, idx, w)
    assert fewest.max() + 1 == _max_degree(idx, w) == 8
    assert color_constraints(idx, w).max() + 1 > 8


def test_fewest_is_never_more_than_luby_and_valid_on_tets() -> None:
    """On a tetrahedral box (edges and tets, irregular) the launch colouring is valid and has at most as
    many colours as the CPU's."""
    b = ModelBuilder()
    b.add_soft_box(cells=(3, 3, 3), size=(0.2, 0.2, 0.2), origin=(0.0, 0.3, 0.0), stiffness=2e4, E=1e5)
    model = b.finalize(device="cpu")
    w = model.particle_inv_mass.numpy()
    for idx in (model.spring_indices.numpy().reshape(-1, 2), model.tet_indices.numpy().reshape(-1, 4)):
        idx = idx.astype(np.int64)
        fewest = color_constraints(idx, w, fewest=True)
        _assert_valid(fewest, idx, w)
        assert fewest.max() <= color_constraints(idx, w).max()


def test_first_fit_in_id_order_is_sequential_greedy() -> None:
    """A path 0-1-2-3-4 of 4 edges in order: sequential first fit alternates 0, 1, 0, 1; a star's edges all
    meet at the centre and need one colour each; pinned particles (dropped incidences) conflict with none."""
    path = np.array([[0, 1], [1, 2], [2, 3], [3, 4]])
    cid, pid = np.repeat(np.arange(4), 2), path.ravel()
    np.testing.assert_array_equal(color_incidence_first_fit(cid, pid, 4, 5), [0, 1, 0, 1])
    star = np.array([[0, 1], [0, 2], [0, 3]])
    np.testing.assert_array_equal(
        color_incidence_first_fit(np.repeat(np.arange(3), 2), star.ravel(), 3, 4), [0, 1, 2]
    )
    keep = star.ravel() != 0  # the centre pinned
    colors = color_incidence_first_fit(np.repeat(np.arange(3), 2)[keep], star.ravel()[keep], 3, 4)
    np.testing.assert_array_equal(colors, [0, 0, 0])


@pytest.mark.parametrize("iterations", [1, 3])
def test_cuda_schedule_launches_per_iteration(device: str, cuda_schedule: None, iterations: int) -> None:
    """Per step: predict and the velocity update (λ's reset is folded into the first sweep), plus one launch
    per colour per iteration: 8 on the grid cloth (12 with the Luby colouring the CUDA path used before)."""
    model = cloth_drape_model(16, device=device, dtype="float32")
    solver = XPBD(model, iterations=iterations, schedule="coloring")
    (distance,) = solver.constraints
    colours = len(distance.color_offsets) - 1
    assert colours == 8
    assert _plan_length(model, solver, FRAME_DT / 40) == 2 + colours * iterations


def test_cpu_path_is_one_launch_per_set() -> None:
    """Without the switch the CPU sweeps each set in one launch (its colouring, and so its trajectories,
    unchanged)."""
    model = cloth_drape_model(16, device="cpu", dtype="float32")
    solver = XPBD(model, iterations=3, schedule="coloring")
    assert not solver.constraints[0].per_colour
    assert _plan_length(model, solver, FRAME_DT / 40) == 2 + 3


def test_cuda_schedule_follows_the_cpu_trajectory_at_equal_error(device: str, monkeypatch) -> None:
    """The 16² drape's 30-frame fall (40 substeps × 1 iteration, float32): the CUDA schedule sweeps the
    springs in another Gauss–Seidel order, so its sag differs from the CPU path's, but by far less than
    either's error against the converged reference (measured 8e-5 m, bound 5e-4 m, on a sag of ~1 m whose
    error is ~1.2 %), and its trajectory_error is the CPU path's within 2 % of itself (measured 1.231 %
    vs 1.222 %)."""
    substeps = 40

    def fall(dev: str, cuda: bool) -> tuple[float, np.ndarray]:
        monkeypatch.setattr(base, "CUDA_SCHEDULE_ON_CPU", cuda)
        model = cloth_drape_model(16, device=dev, dtype="float32")
        solver = XPBD(model, iterations=1, schedule="coloring")
        curve = solver_curve(model, solver, substeps=substeps, frames=30)
        return curve_error(16, curve)["trajectory_error"], curve

    cpu_error, cpu_curve = fall("cpu", False)
    error, curve = fall(device, True)
    assert cpu_error is not None and error is not None
    assert abs(error - cpu_error) <= 0.02 * cpu_error, (error, cpu_error)
    assert np.abs(curve - cpu_curve).max() < 5e-4
    assert np.abs(curve - cpu_curve).max() > 0.0, "the orders differ: the curves cannot be equal"


def _cloth(device: str, requires_grad: bool = False, ground: bool = True):
    b = ModelBuilder()
    b.add_cloth_grid(nx=8, ny=8, size=0.5, mass=0.1, stiffness=200.0, origin=(-0.25, 0.01, -0.25), plane="xz")
    if ground:
        b.add_ground(0.0, friction=0.4)
    return b.finalize(device=device, dtype="float64", requires_grad=requires_grad)


@pytest.mark.parametrize("iterations", [1, 3])
def test_jacobi_launches_per_step(device: str, iterations: int) -> None:
    """Jacobi: predict, then per iteration a projection and (but for the last) the average of its
    corrections; the last average is fused with the velocity update: 2·iterations + 1 launches per step
    (2·iterations + 3 before: a λ memset, every average, the update)."""
    model = _cloth(device, ground=False)
    solver = XPBD(model, iterations=iterations, schedule="jacobi", relaxation=1.5)
    assert _plan_length(model, solver, 1e-3) == 2 * iterations + 1


def test_jacobi_fused_end_of_step_equals_separate_launches() -> None:
    """The fused last average + velocity update gives the bits of the separate kernels, which the taped
    (requires_grad) step still launches one after the other: 40 steps, falling onto the ground (friction)."""
    out = []
    for grad in (False, True):
        model = _cloth("cpu", requires_grad=grad)
        solver = XPBD(model, iterations=3, schedule="jacobi", relaxation=1.5, contact_iterations=2)
        s0, s1 = model.state(), model.state()
        for _ in range(40):
            solver.step(s0, s1, None, 2e-3)
            s0, s1 = s1, s0
        out.append((s0.particle_q.numpy(), s0.particle_qd.numpy()))
        # Dropped from 1 cm, it lies on the ground (at its particle radius, 5 mm) after 80 ms.
        assert abs(s0.particle_q.numpy()[:, 1].min() - 0.005) < 5e-4, "the cloth is not on the ground"
    np.testing.assert_array_equal(out[0][0], out[1][0])
    np.testing.assert_array_equal(out[0][1], out[1][1])
