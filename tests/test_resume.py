"""Resume after interruption equals the uninterrupted run bit for bit on the CPU (issue 11, item 8).

Every built-in scene (explicit, XPBD, FEM with L-BFGS), and BDF2 (with Newton and with L-BFGS) through the
API: run N frames straight; run k frames with a checkpoint; build everything afresh, resume to N; compare.
"""

from __future__ import annotations

import numpy as np
import pytest

import pliant as pl
from tests.golden import _build, scene_names

FRAMES, STOP = 4, 2


def _resume_matches(make_sim, tmp_path, frames: int = FRAMES, stop: int = STOP) -> dict:
    """Run straight and interrupted + resumed; assert bit identity; return the checkpoint's solver keys."""
    reference = make_sim().run(frames, progress=False)
    ckpt = tmp_path / "run.ckpt.npz"
    make_sim().run(stop, progress=False, checkpoint=ckpt)
    with np.load(ckpt) as z:
        solver_keys = sorted(k for k in z.files if k.startswith("solver_"))
    resumed = make_sim().run(frames, progress=False, checkpoint=ckpt, resume=True)
    assert resumed.x.shape == reference.x.shape
    np.testing.assert_array_equal(resumed.t, reference.t)
    differing = [k for k in range(frames + 1) if not np.array_equal(resumed.x[k], reference.x[k])]
    assert not differing, f"frames differing after resume: {differing}"
    return {"solver_keys": solver_keys}


@pytest.mark.parametrize("name", scene_names())
def test_builtin_scene_resumes_bit_for_bit(name, tmp_path):
    """Every built-in scene: the resumed run's frames are the uninterrupted run's, bit for bit."""
    info = _resume_matches(lambda: _build(pl, name).simulator(), tmp_path)
    scene = _build(pl, name)
    integrator = getattr(scene.simulator().solver, "integrator", None)
    if getattr(integrator, "method", None) == "lbfgs":
        # The FEM scenes: the bit identity must come from the stored L-BFGS state, not from luck.
        assert "solver_lbfgs_s" in info["solver_keys"] and "solver_lbfgs_h0_values" in info["solver_keys"]


def _fem_box_sim(integrator, minimizer=None) -> pl.Simulator:
    b = pl.ModelBuilder()
    b.add_soft_box(cells=(2, 2, 2), size=(0.2, 0.2, 0.2), origin=(0.0, 0.12, 0.0), E=2e4, nu=0.3)
    b.add_ground(0.0)
    model = b.finalize(device="cpu", dtype="float64")
    solver = pl.solvers.ForceSolver(
        model,
        energies=[pl.energies.NeoHookean(), pl.energies.Gravity()],
        integrator=integrator,
        minimizer=minimizer,
    )
    return pl.Simulator(model, solver, frame_dt=1 / 30, substeps=2)


@pytest.mark.parametrize("method", ["newton", "lbfgs"])
def test_bdf2_resumes_bit_for_bit(method, tmp_path):
    """BDF2's history (x₋₁, v₋₁) is in the checkpoint; without it the first resumed step is backward Euler."""
    make = lambda: _fem_box_sim(pl.integrators.BDF2(), {"method": method})  # noqa: E731
    info = _resume_matches(make, tmp_path, 6, 3)
    assert {"solver_bdf2_x_prev", "solver_bdf2_v_prev", "solver_bdf2_dt"} <= set(info["solver_keys"])


def test_lbfgs_with_a_multigrid_h0_resumes_bit_for_bit(tmp_path):
    """``lbfgs_h0="amg"``: the restored H₀ values are put into a V-cycle hierarchy again, the same one."""
    mz = {"method": "lbfgs", "lbfgs_h0": "amg"}
    info = _resume_matches(lambda: _fem_box_sim(pl.integrators.BackwardEuler(), mz), tmp_path, 6, 3)
    assert "solver_lbfgs_h0_values" in info["solver_keys"]


def test_lbfgs_resume_needs_the_stored_history(tmp_path):
    """Control: dropping the L-BFGS state from the checkpoint makes the resumed run differ (so the
    bit-identity tests above can fail)."""
    make = lambda: _fem_box_sim(pl.integrators.BackwardEuler(), {"method": "lbfgs"})  # noqa: E731
    reference = make().run(6, progress=False)
    ckpt = tmp_path / "run.ckpt.npz"
    make().run(3, progress=False, checkpoint=ckpt)
    with np.load(ckpt) as z:
        kept = {k: z[k] for k in z.files if not k.startswith("solver_")}
    np.savez(ckpt, **kept)
    resumed = make().run(6, progress=False, checkpoint=ckpt, resume=True)
    np.testing.assert_array_equal(resumed.x[:4], reference.x[:4])
    assert not np.array_equal(resumed.x[4:], reference.x[4:])


def test_bdf2_checkpoint_right_after_a_restore_gives_the_history_back():
    """A checkpoint taken after a restore and before the next step (e.g. a resumed run interrupted at
    once) holds the restored history, not a TypeError on the restored key."""
    sim = _fem_box_sim(pl.integrators.BDF2())
    sim.run(2, progress=False)
    saved = sim.solver.integrator.checkpoint_state()
    assert set(saved) == {"bdf2_x_prev", "bdf2_v_prev", "bdf2_dt"}
    again = _fem_box_sim(pl.integrators.BDF2())
    again.solver.integrator.restore_checkpoint_state(saved, again.solver)
    back = again.solver.integrator.checkpoint_state()
    assert set(back) == set(saved)
    for k in saved:
        np.testing.assert_array_equal(back[k], saved[k])
