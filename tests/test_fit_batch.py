"""CMA-ES generations as one batched simulation (one copy of the object per candidate): each copy's loss
equals the candidate's own run, for explicit and implicit steps; what cannot be batched is not."""

from __future__ import annotations

import numpy as np
import pytest

import pliant as pl
from pliant.fit._cmaes import batchable, evaluate, evaluate_batch


def _problem(integrator: str, params: list[str]):
    truth = pl.scene.load_scene("fit_rope", ["objects[0].material.stiffness=480"])
    obs = pl.fit.observe(pl.scene.build_scene(truth), frames=12, tracks=6, seed=3)
    cfg = pl.scene.load_scene("fit_rope", [f'solver.integrator="{integrator}"', 'scene.dtype="float64"'])
    return pl.fit.Problem(cfg, obs, params=params)


@pytest.mark.parametrize("integrator", ["SymplecticEuler", "BackwardEuler"])
def test_batched_generation_equals_candidates_run_alone(integrator):
    p = _problem(integrator, ["stiffness", "damping"])
    assert batchable(p)
    cands = [{"stiffness": k, "damping": g} for k, g in ((200.0, 0.01), (480.0, 0.02), (900.0, 0.005))]
    batched = evaluate_batch(p, cands)
    alone = [evaluate(p, v) for v in cands]
    # explicit: the same arithmetic per copy; implicit: one Newton solve for all copies, converged for each
    rtol = 1e-12 if integrator == "SymplecticEuler" else 1e-6
    np.testing.assert_allclose(batched, alone, rtol=rtol)
    assert np.argmin(batched) == 1  # the truth's candidate fits best


def test_solver_level_parameters_are_not_batched():
    assert not batchable(_problem("SymplecticEuler", ["stiffness", "damping_rate"]))
