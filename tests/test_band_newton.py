"""The small-problem path: the device Newton with the banded LDLᵀ solve (``linear_solver="band"``, what
``method="auto"`` takes on the CPU for small bodies), against the host Newton and numpy."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import pliant as pl
import pliant.scene
from pliant.solvers.minimizers import DeviceNewtonStats, _band, _band_order, _options
from pliant.solvers.minimizers._problem import cache_of


def _beam(cells=(12, 2, 2), dtype="float64", minimizer=None, newton_tol=None, substeps=4):
    """The cantilever scene with ``cells`` (12 x 2 x 2: 117 particles, 288 tets), ``substeps`` per frame."""
    cfg = pl.scene.load_scene("cantilever")
    cfg.scene.substeps = substeps
    cfg.objects[0].cells = list(cells)
    if minimizer is not None:
        cfg.solver.options = {**cfg.solver.options, "minimizer": minimizer}
    if newton_tol is not None:
        cfg.solver.integrator_options = {**cfg.solver.integrator_options, "newton_tol": newton_tol}
    return pl.scene.build_scene(cfg, device="cpu", dtype=dtype)


def test_auto_takes_the_band_newton_for_a_small_body_and_lbfgs_for_a_larger_one():
    small = _beam()
    assert small.model.particle_count == 117 and small.model.tet_count == 288
    large = _beam(cells=(16, 3, 3))
    works = []
    for scene in (small, large):
        ws = cache_of(scene.solver).workspace(scene.model, scene.solver.energies)
        works.append(_band_order.band_work(scene.model.particle_count, ws.band_order()[1]))
    assert works[0] <= _options.SMALL_BAND_WORK < works[1]
    mz = small.solver.minimizer
    assert mz.method == "auto" and large.solver.minimizer.method == "auto"
    assert _options.resolve_method(mz, "cpu", small.solver) == "newton"
    assert _options.device_newton(mz, "cpu", small.solver)
    assert _options.resolve_method(mz, "cpu", large.solver) == "lbfgs"
    assert not _options.device_newton(mz, "cpu", large.solver)
    assert _options.resolve_method(mz, "cpu") == "lbfgs"  # no problem given: the size is unknown
    sims = [small.simulator(), large.simulator()]
    for sim in sims:
        sim.step_frame()
        sim.step_frame()
    assert sims[0].solver.last_stats.linear_solver == "band" and sims[0].graph_reason is None
    assert sims[1].solver.last_stats.linear_solver == "lbfgs" and sims[1].graph_reason is not None


@pytest.mark.parametrize("shift", [0.0, 0.3, "singular"])
def test_band_ldlt_solves_the_assembled_system(shift):
    """LDLᵀ in RCM order equals a dense solve, for the SPD Hessian and for an indefinite one (shifted down
    by a fraction of its largest diagonal entry, as an exact Hessian may be); a singular one gives Δx = 0."""
    scene = _beam(minimizer={"method": "newton", "linear_solver": "band"})
    sim = scene.simulator(graph=False)
    sim.step_frame()
    dn = scene.solver.minimizer_cache.pcg
    ws, band = dn.ws, dn.cg
    assert isinstance(band, _band.BandLDL) and band.b == 32  # RCM: 10 particles either side
    n = scene.model.particle_count
    vals = ws.values.numpy()[: ws.nnz].copy()
    diag = ws.diag_slots.numpy()
    free = scene.model.particle_inv_mass.numpy() > 0
    if shift == "singular":
        vals[diag[np.flatnonzero(free)[0]]] = 0.0  # an empty row and column
        vals[np.isin(ws.block_rows.numpy(), np.flatnonzero(free)[:1])] = 0.0
        vals[np.isin(ws.block_cols.numpy(), np.flatnonzero(free)[:1])] = 0.0
    elif shift:
        top = np.abs(vals[diag]).max()
        vals[diag[free]] -= shift * top * np.eye(3)
    ws.values.assign(vals)
    failures = band.failures
    band.factor(1.0 / 120.0)
    band.solve(ws.grad, ws.dx)
    dx = ws.dx.numpy().reshape(-1)
    if shift == "singular":
        assert band.failures == failures + 1 and not dx.any()
        return
    import scipy.sparse as sp

    H = sp.bsr_matrix((vals, ws.indices, ws.indptr), shape=(3 * n, 3 * n)).toarray()
    eig = np.linalg.eigvalsh(0.5 * (H + H.T))
    assert (eig.min() < 0.0) == bool(shift)  # the shifted system is indefinite indeed
    ref = np.linalg.solve(H, -ws.grad.numpy().reshape(-1))
    assert np.abs(dx - ref).max() <= 1e-9 * np.abs(ref).max()
    assert band.failures == failures


def test_band_newton_follows_the_existing_solvers_to_1e_9_m():
    """float64, tolerances tight: 10 frames of the beam (40 steps, the lagged factor, the warm start and the
    line search at work) by the device Newton with the band solve, replayed as CPU graphs, land within
    1e-9 m of the host Newton's (SciPy's sparse LU every iteration), L-BFGS's and the device Newton's with
    CG, frame by frame; and the factorisation is lagged over most iterations."""
    tight = 1e-8
    runs = {}
    for name, mz in (
        ("band", {"method": "auto"}),
        ("host", {"method": "newton", "linear_solver": "direct"}),
        ("lbfgs", {"method": "lbfgs", "lbfgs_max_iterations": 500}),
        ("pcg", {"method": "newton", "linear_solver": "pcg", "cg_tol": 1e-10}),
    ):
        sim = _beam(minimizer=mz, newton_tol=tight).simulator()
        runs[name] = sim.run(10, progress=False).x
        stats = sim.solver.last_stats
        if name == "band":
            assert sim.graph_reason is None and stats.linear_solver == "band"
            steps, iterations, factorisations = stats.totals()
            assert steps == 40 and factorisations < 0.5 * iterations
    assert np.abs(runs["band"][-1] - runs["band"][0]).max() > 1e-3  # the beam moved
    for name in ("host", "lbfgs", "pcg"):
        assert np.abs(runs["band"] - runs[name]).max() <= 1e-9, name


def test_band_newton_without_lagging_takes_newtons_iterates(monkeypatch):
    """With a factorisation every iteration and no warm start the band Newton's steps are the host
    Newton's, iterate for iterate (same count, positions to round-off) at the default tolerance."""
    monkeypatch.setattr(_band, "LAG_RATE", 0.0)
    monkeypatch.setattr(_band, "LAG_MAX_ITERATIONS", -1)
    monkeypatch.setattr(_band, "WARM_START", False)
    out = {}
    for name, mz in (("band", {"method": "newton", "linear_solver": "band"}), ("host", {"method": "newton"})):
        sim = _beam(minimizer=mz).simulator(graph=False)
        its = []
        for _ in range(3):
            sim.step_frame()
            its.append(sim.solver.last_stats.iterations)
        out[name] = (sim.state_0.particle_q.numpy(), its)
    assert out["band"][1] == out["host"][1]
    assert np.abs(out["band"][0] - out["host"][0]).max() <= 1e-11


def test_band_newton_steps_are_differentiable():
    """Tape gradients through band-Newton steps (the IFT adjoint of the converged step) equal central
    differences: the box of tests/test_implicit_gradients.py, with the ground."""
    from pliant import integrators as I
    from tests.test_implicit_gradients import TIGHT, _check

    _check(
        "box",
        True,
        lambda: {"integrator": I.BackwardEuler(**TIGHT), "minimizer": {"linear_solver": "band"}},
    )


def test_band_solver_name_is_validated():
    assert pl.solvers.MinimizerOptions(linear_solver="band").linear_solver == "band"
    with pytest.raises(ValueError, match="'band'"):
        pl.solvers.MinimizerOptions(linear_solver="bands")
    assert _options.band_solve(pl.solvers.MinimizerOptions(linear_solver="band"), "cpu")
    assert not _options.band_solve(pl.solvers.MinimizerOptions(linear_solver="pcg"), "cpu")
    assert wp.get_device("cpu").is_cpu and DeviceNewtonStats is not None


def test_restart_runs_as_a_new_simulator_bit_for_bit():
    """``Simulator.restart`` forgets the lagged band factor: the replayed rerun equals a new simulator's."""
    scene = _beam()
    sim = scene.simulator()
    first = sim.run(3, progress=False).x
    sim.restart()
    again = sim.run(3, progress=False).x
    assert sim.graph_reason is None and scene.solver.last_stats.linear_solver == "band"
    np.testing.assert_array_equal(again, first)


def test_band_newton_resumes_bit_for_bit(tmp_path):
    """The lagged factor, its stiffness ratio and the warm start's corrections are in the checkpoint: a
    resumed run's frames are the uninterrupted run's, bit for bit."""
    from tests.test_resume import _resume_matches

    info = _resume_matches(lambda: _beam(dtype="float32").simulator(), tmp_path, 6, 3)
    assert {"solver_band_factor", "solver_band_correction"} <= set(info["solver_keys"])


def test_band_newton_resume_needs_its_state(tmp_path):
    """Control: without the band state the resumed run differs (so the test above can fail); a wrong
    array is refused with its name."""
    make = lambda: _beam(dtype="float32").simulator()  # noqa: E731
    reference = make().run(6, progress=False)
    ckpt = tmp_path / "run.ckpt.npz"
    make().run(3, progress=False, checkpoint=ckpt)
    with np.load(ckpt) as z:
        kept = {k: z[k] for k in z.files if not k.startswith("solver_band_")}
        factor = z["solver_band_factor"]
    np.savez(ckpt, **kept)
    resumed = make().run(6, progress=False, checkpoint=ckpt, resume=True)
    np.testing.assert_array_equal(resumed.x[:4], reference.x[:4])
    assert not np.array_equal(resumed.x[4:], reference.x[4:])
    sim = make()
    state = sim.solver.checkpoint_state()
    assert state == {} or not any(k.startswith("band_") for k in state)  # no step yet: nothing kept
    sim.run(1, progress=False)
    state = sim.solver.checkpoint_state()
    state["band_factor"] = factor[:-1]
    with pytest.raises(ValueError, match="band_factor"):
        make().solver.restore_checkpoint_state(state)
