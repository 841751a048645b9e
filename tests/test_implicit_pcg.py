"""The device Newton (``MinimizerOptions(linear_solver="pcg")``): its CG against a closed form, its motion
against the direct solver's, graph replay bit for bit, and no host read inside a step."""

from __future__ import annotations

import types

import numpy as np
import pytest
import warp as wp
from warp.sparse import bsr_from_triplets

import pliant as pl
from pliant.solvers.minimizers import DeviceCG, DeviceNewtonStats, _pcg

NEWTON_TOL = 1e-7  # m/s


def _box(device: str, dtype: str = "float64") -> pl.Model:
    b = pl.ModelBuilder()
    b.add_soft_box(
        cells=(2, 2, 2), size=(0.2, 0.2, 0.2), origin=(0.0, 0.15, 0.0), density=500.0, E=2e4, nu=0.3
    )
    b.add_ground(friction=0.5)
    return b.finalize(device=device, dtype=dtype)


def _solver(model: pl.Model, linear_solver: str, integrator: type = pl.integrators.BackwardEuler, **kw):
    return pl.solvers.ForceSolver(
        model,
        [pl.energies.NeoHookean(), pl.energies.Gravity()],
        integrator(newton_tol=NEWTON_TOL),
        minimizer={"linear_solver": linear_solver, **kw},
    )


def _sim(device: str, linear_solver: str, graph: bool | None = None, **kw) -> pl.Simulator:
    m = _box(device)
    sim = pl.Simulator(m, _solver(m, linear_solver, **kw), frame_dt=1 / 60, substeps=2)
    sim.set_graph(graph)
    return sim


@pytest.fixture(params=_pcg.REDUCTIONS)
def reduction(request: pytest.FixtureRequest) -> str:
    """Each way of reducing CG's dot products in turn."""
    return request.param


def _dense_cg(device: str, dense: np.ndarray, reduction: str | None = None) -> DeviceCG:
    """DeviceCG on a dense block matrix (every block stored) of n = len(dense) / 3 particles."""
    n = dense.shape[0] // 3
    rows, cols = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    blocks = dense.reshape(n, 3, n, 3).transpose(0, 2, 1, 3)[rows.ravel(), cols.ravel()]
    A = bsr_from_triplets(
        n,
        n,
        wp.array(rows.ravel().astype(np.int32), dtype=wp.int32, device=device),
        wp.array(cols.ravel().astype(np.int32), dtype=wp.int32, device=device),
        wp.array(blocks, dtype=wp.mat33d, device=device),
    )
    diag = np.flatnonzero(rows.ravel() == cols.ravel()).astype(np.int32)  # dense: sorted (row, col) order
    ws = types.SimpleNamespace(A=A, values=A.values, diag_slots=wp.array(diag, dtype=wp.int32, device=device))
    model = types.SimpleNamespace(
        particle_count=n,
        device=device,
        vec3=wp.vec3d,
        mat33=wp.mat33d,
        scalar=wp.float64,
        particle_inv_mass=wp.ones(n, dtype=wp.float64, device=device),
    )
    return DeviceCG(model, ws, reduction)  # type: ignore[arg-type]


def test_cg_solves_a_spd_system_to_its_tolerance(device: str, reduction: str) -> None:
    """DeviceCG on a random SPD block system: ‖b − Hx‖ ≤ tol‖b‖ (its stopping test), the error within
    cond(H)·tol of numpy's solve, in at most 3n iterations (CG's finite termination) rounded up to a chunk.
    Either reduction (7 rows: on CUDA the tiled launch is one block, mostly rows past the end)."""
    rng = np.random.default_rng(3)
    n = 7
    a = rng.standard_normal((3 * n, 3 * n))
    dense = a @ a.T + 3 * n * np.eye(3 * n)  # SPD, cond ≈ 10
    b = rng.standard_normal((n, 3))
    cg = _dense_cg(device, dense, reduction)
    x = wp.zeros(n, dtype=wp.vec3d, device=device)
    tol = 1e-10
    cg.solve(wp.array(-b, dtype=wp.vec3d, device=device), x, tol, 1000)
    xs = x.numpy().ravel()
    residual = np.linalg.norm(b.ravel() - dense @ xs) / np.linalg.norm(b)
    assert residual <= tol, residual
    exact = np.linalg.solve(dense, b.ravel())
    assert np.abs(xs - exact).max() <= np.linalg.cond(dense) * tol * np.abs(exact).max()
    assert 0 < cg.iterations() <= 3 * n
    assert int(cg.counts.numpy()[3]) == cg.iterations(), "the lifetime total counts the same iterations"
    # A cap stops it early: 3 iterations asked, one chunk of 8 run at most, the residual still large.
    x.zero_()
    cg.counts.zero_()
    cg.solve(wp.array(-b, dtype=wp.vec3d, device=device), x, 1e-14, 3)
    assert cg.iterations() == 3
    assert np.linalg.norm(b.ravel() - dense @ x.numpy().ravel()) > 1e-6 * np.linalg.norm(b)


def test_cg_stops_at_a_breakdown(device: str, reduction: str) -> None:
    """On a negative definite H the first p·Hp is < 0: CG stops there (x stays 0, no iteration counted)
    instead of running to its cap on a meaningless step."""
    n = 4
    cg = _dense_cg(device, -np.eye(3 * n) - 0.1 * np.ones((3 * n, 3 * n)), reduction)
    x = wp.zeros(n, dtype=wp.vec3d, device=device)
    cg.solve(wp.array(np.ones((n, 3)), dtype=wp.vec3d, device=device), x, 1e-10, 100)
    assert cg.iterations() == 0
    assert np.all(x.numpy() == 0.0)
    assert int(cg.counts.numpy()[1]) == 1, "one chunk, then the breakdown flag ended the solve"


def test_unconverged_step_says_so(device: str) -> None:
    """A step capped at one Newton iteration, far from the tolerance, reports it: not converged, one
    iteration, its residuals (start and after the step) and a gradient norm above the tolerance."""
    m = _box(device)
    solver = pl.solvers.ForceSolver(
        m,
        [pl.energies.NeoHookean(), pl.energies.Gravity()],
        pl.integrators.BackwardEuler(newton_tol=1e-12, max_newton_iterations=1),
        minimizer={"linear_solver": "pcg"},
    )
    s0, s1 = m.state(), m.state()
    s0.particle_qd.fill_(wp.vec3d(0.0, -3.0, 0.0))  # lands within the step: contact makes it nonlinear
    solver.step(s0, s1, None, 1 / 30)
    st = solver.last_stats
    assert st.iterations == 1 and not st.converged
    assert len(st.residuals) == 2 and st.residuals[1] < st.residuals[0]
    assert st.gradient_norm == st.residuals[1] > st.tolerance
    assert st.linear_iterations > 0 and st.step_norm > 0


def test_motion_matches_the_direct_solver(
    device: str, reduction: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A neo-Hookean box dropped on the ground (30 frames of 2 backward-Euler steps, float64, with contact):
    the device Newton (replayed as a graph) follows the direct solve's motion to 1e-8 m, both converged to
    ``newton_tol`` = 1e-7 m/s per step (a position error of order tol·h per step), with either reduction."""
    monkeypatch.setattr(_pcg, "REDUCTION", reduction)
    xs, frames = {}, 30
    for lin in ("direct", "pcg"):
        sim = _sim(device if lin == "pcg" else "cpu", lin)
        traj = []
        for _ in range(frames):
            sim.step_frame()
            traj.append(sim.state_0.particle_q.numpy().copy())  # (a CPU array's numpy() is a view)
        xs[lin] = np.array(traj)
        if lin == "pcg":
            assert sim.graph_reason is None
            assert sim._graphs.replays >= frames - 2
            st = sim.solver.last_stats
            assert st.converged and st.iterations >= 1 and st.linear_solver == "pcg"
            assert st.residuals[-1] == st.gradient_norm <= st.tolerance
    err = np.abs(xs["pcg"] - xs["direct"]).max()
    assert err < 1e-8, f"device Newton differs from the direct solve by {err:.3g} m"
    fall = xs["pcg"][0, :, 1].min() - xs["pcg"][-1, :, 1].min()
    assert fall > 0.04, "the box did not reach the ground"


def test_reductions_agree(device: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Block sums and per-thread atomics take the same Newton/CG decisions: bit for bit on the CPU (a CPU
    block is one thread, so the same terms are added in the same order); on CUDA the sums differ only in
    their order."""
    sims = {}
    for reduction in _pcg.REDUCTIONS:
        monkeypatch.setattr(_pcg, "REDUCTION", reduction)
        sims[reduction] = _sim(device, "pcg")
        sims[reduction].step_frame()  # the setting is read when the solver's first step sets up
    for _ in range(7):
        for sim in sims.values():
            sim.step_frame()
    a, b = (sims[r] for r in ("atomic", "tile"))
    assert b.solver.last_stats._dn.cg.reduction == "tile" and a.solver.last_stats._dn.cg.reduction == "atomic"
    (steps, newton, cg), totals_b = a.solver.last_stats.totals(), b.solver.last_stats.totals()
    assert steps == 16 and newton >= steps and cg >= newton
    qa, qb = a.state_0.particle_q.numpy(), b.state_0.particle_q.numpy()
    if device == "cpu":
        assert totals_b == (steps, newton, cg)
        np.testing.assert_array_equal(qa, qb)
    else:
        assert totals_b[:2] == (steps, newton) and abs(totals_b[2] - cg) <= 0.01 * cg
        np.testing.assert_allclose(qa, qb, rtol=0, atol=1e-9)


def test_graph_replay_equals_direct_launches(device: str) -> None:
    """Frames replayed from a captured graph equal the same frames launched directly (bit for bit on the
    CPU; on CUDA atomics may sum in another order)."""
    graphed, direct = _sim(device, "pcg"), _sim(device, "pcg", graph=False)
    for _ in range(8):
        graphed.step_frame()
        direct.step_frame()
    assert graphed.graph_reason is None and graphed._graphs.captures >= 1 and graphed._graphs.replays >= 6
    a, b = graphed.state_0.particle_q.numpy(), direct.state_0.particle_q.numpy()
    if device == "cpu":
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(graphed.state_0.particle_qd.numpy(), direct.state_0.particle_qd.numpy())
    else:
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)


def test_a_step_reads_nothing_back(device: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """No array is copied to the host and no device is synchronised inside a step: launched directly on the
    CPU (its loop flags are read from memory), and while captured on any device; the captured step then
    replays to the direct step's result."""
    m = _box(device)
    solver = _solver(m, "pcg")
    s0, s1 = m.state(), m.state()
    solver.step(s0, s1, None, 1 / 120)  # first step: modules load, buffers are allocated
    reads = {"numpy": 0, "sync": 0}
    numpy = wp.array.numpy

    def counted_numpy(self):  # noqa: ANN001, ANN202
        reads["numpy"] += 1
        return numpy(self)

    monkeypatch.setattr(wp.array, "numpy", counted_numpy)
    for name in ("synchronize", "synchronize_device", "synchronize_stream"):
        real = getattr(wp, name)

        def counted(*a, _real=real, **k):  # noqa: ANN002, ANN003, ANN202
            reads["sync"] += 1
            return _real(*a, **k)

        monkeypatch.setattr(wp, name, counted)
    if device == "cpu":
        solver.step(s1, s0, None, 1 / 120)
        assert reads == {"numpy": 0, "sync": 0}
    x_start = wp.clone(s1.particle_q)
    v_start = wp.clone(s1.particle_qd)
    with wp.ScopedCapture(device=device) as cap:
        solver.step(s1, s0, None, 1 / 120)
    assert reads == {"numpy": 0, "sync": 0}
    monkeypatch.undo()
    wp.copy(s1.particle_q, x_start)
    wp.copy(s1.particle_qd, v_start)
    wp.capture_launch(cap.graph)
    replayed = s0.particle_q.numpy()
    wp.copy(s1.particle_q, x_start)
    wp.copy(s1.particle_qd, v_start)
    solver.step(s1, s0, None, 1 / 120)
    np.testing.assert_allclose(replayed, s0.particle_q.numpy(), rtol=0, atol=0 if device == "cpu" else 1e-9)
    assert solver.last_stats.converged


def test_blockers_say_why() -> None:
    """The solver reports a device-Newton step as replayable, and says why not for a multistep integrator,
    a host Newton, and an energy whose step bound is only known on the host."""

    class HostBound(pl.energies.Gravity):
        def max_step(self, model, x, dx):  # noqa: ANN001, ANN201
            return 1.0

    m = _box("cpu")
    assert _solver(m, "pcg").graph_blocker() is None
    assert "history" in _solver(m, "pcg", pl.integrators.BDF2).graph_blocker()
    assert "host" in _solver(m, "direct").graph_blocker()
    solver = pl.solvers.ForceSolver(
        m,
        [pl.energies.NeoHookean(), HostBound()],
        pl.integrators.BackwardEuler(),
        minimizer={"linear_solver": "pcg"},
    )
    assert "HostBound" in solver.graph_blocker()
    s0, s1 = m.state(), m.state()
    solver.step(s0, s1, None, 1 / 120)  # its bound is read on the host, and the step still converges
    assert solver.last_stats.converged


def test_auto_is_the_device_newton_on_cuda_and_the_direct_solve_on_the_cpu(
    device: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The default ``linear_solver="auto"``: the host's sparse LU on the CPU, the device Newton on CUDA (so a
    Simulator replays implicit FEM frames there by default); L-BFGS is never the device Newton. On a machine
    without a GPU the CUDA branch is checked with a stand-in device."""
    from pliant.solvers.minimizers import _options

    auto, pcg, lbfgs = (
        pl.solvers.MinimizerOptions(**k) for k in ({}, {"linear_solver": "pcg"}, {"method": "lbfgs"})
    )
    assert not _options.device_newton(auto, "cpu") and _options.device_newton(pcg, "cpu")
    m = _box(device)
    solver = pl.solvers.ForceSolver(
        m,
        [pl.energies.NeoHookean(), pl.energies.Gravity()],
        pl.integrators.BackwardEuler(newton_tol=NEWTON_TOL),
    )
    s0, s1 = m.state(), m.state()
    solver.step(s0, s1, None, 1 / 120)
    cuda = wp.get_device(device).is_cuda
    assert isinstance(solver.last_stats, DeviceNewtonStats) == cuda
    assert (solver.graph_blocker() is None) == cuda
    monkeypatch.setattr(_options.wp, "get_device", lambda d=None: types.SimpleNamespace(is_cuda=True))
    assert _options.device_newton(auto, "cuda:0") and not _options.device_newton(lbfgs, "cuda:0")
    # method="auto" (the FEM scenes'): L-BFGS on the CPU, the device Newton on CUDA
    either = pl.solvers.MinimizerOptions(method="auto")
    assert _options.resolve_method(either, "cuda:0") == "newton" and _options.device_newton(either, "cuda:0")
    monkeypatch.undo()
    assert _options.resolve_method(either, "cpu") == "lbfgs" and not _options.device_newton(either, "cpu")


FEM_SCENES = ["cantilever", "fem_drop", "fem_embedded", "fem_squeeze", "soft_box_fem"]


@pytest.mark.parametrize("name", FEM_SCENES)
def test_fem_scenes_take_the_device_newton_a_gpu_gives_them(name: str) -> None:
    """The FEM scenes ask for ``method="auto"``: L-BFGS on the CPU, the device Newton on a GPU. What a GPU
    runs is run here on the CPU (method "newton", linear solver "pcg"): the scene's energies, contacts and
    handles are all device-Newton steps (its frames replay as graphs), and 3 frames land within 1e-4 m of
    L-BFGS's (both stop at the scene's tolerance)."""
    from pliant.solvers.minimizers._options import resolve_method

    runs = {}
    for mz in ({"method": "auto"}, {"method": "newton", "linear_solver": "pcg"}):
        cfg = pl.scene.load_scene(name)
        assert cfg.solver.options["minimizer"] == {"method": "auto"}
        cfg.solver.options = {**cfg.solver.options, "minimizer": mz}
        sim = pl.scene.build_scene(cfg).simulator()
        for _ in range(3):
            sim.step_frame()
        runs[mz["method"]] = sim
    auto, device = runs["auto"], runs["newton"]
    assert resolve_method(auto.solver.minimizer, "cpu") == "lbfgs"
    assert auto.solver.last_stats.linear_solver == "lbfgs"
    assert isinstance(device.solver.last_stats, DeviceNewtonStats) and device.graph_reason is None
    x_auto, x_dev = auto.state_0.particle_q.numpy(), device.state_0.particle_q.numpy()
    assert np.abs(x_dev - x_auto).max() < 1e-4
    assert np.abs(x_auto - pl.scene.build_scene(pl.scene.load_scene(name)).model.particle_q_np).max() > 1e-3
