"""The minimiser's settings belong to the implicit solver (``pl.solvers.MinimizerOptions``,
``ForceSolver(minimizer=...)``, ``[solver] options = { minimizer = {...} }``); the old integrator keywords
(``BackwardEuler(method="lbfgs")``, ``integrator_options = { method = "lbfgs" }``) still work, with a
DeprecationWarning, and reach the minimiser unchanged."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import pliant as pl
from pliant.scene import SceneError, build_scene, parse_scene

I = pl.integrators
HEAD = '[scene]\nname = "t"\nframes = 1\nsubsteps = 2\n'
BOX = (
    '[[objects]]\nkind = "soft_box"\nmodel = "fem"\ncells = [2, 2, 2]\nsize = [0.2, 0.2, 0.2]\n'
    "material = { E = 1e5 }\n"
)
SOLVER = '[solver]\nkind = "force"\nintegrator = "BackwardEuler"\n'


def _box() -> pl.Model:
    b = pl.ModelBuilder()
    b.add_soft_box(cells=(2, 2, 2), size=(0.2, 0.2, 0.2), origin=(0.0, 0.3, 0.0), density=1000.0, E=1e5)
    return b.finalize(device="cpu", dtype="float64")


def _steps(solver: pl.solvers.ForceSolver, model: pl.Model, n: int = 3) -> np.ndarray:
    s0, s1 = model.state(), model.state()
    for _ in range(n):
        solver.step(s0, s1, None, 1 / 60)
        s0, s1 = s1, s0
    return s0.particle_q.numpy().copy()


def test_minimizer_options_are_validated_with_the_allowed_values_named():
    """Every setting is checked once, in MinimizerOptions (and so in ForceSolver(minimizer=...))."""
    bad = {
        "method": ["bogus", "LBFGS"],
        "linear_solver": ["lu"],
        "cg_tol": [1.0, 0.0, float("nan")],
        "cg_max_iterations": [0, 2.5],
        "lbfgs_history": [-1, 1.5],
        "lbfgs_max_iterations": [0],
        "lbfgs_refresh": [0],
        "lbfgs_warm_start": [1],
        "lbfgs_h0": ["cholesky"],
    }
    m = _box()
    for name, values in bad.items():
        for value in values:
            with pytest.raises(ValueError, match=name):
                pl.solvers.MinimizerOptions(**{name: value})
            with pytest.raises(ValueError, match=name):
                pl.solvers.ForceSolver(
                    m, [pl.energies.NeoHookean()], I.BackwardEuler(), minimizer={name: value}
                )
    with pytest.raises(ValueError, match=r"unknown minimizer option\(s\) \['newton_tol'\]"):
        pl.solvers.ForceSolver(m, [pl.energies.NeoHookean()], I.BackwardEuler(), minimizer={"newton_tol": 1})
    assert pl.solvers.MinimizerOptions(lbfgs_history=0).lbfgs_history == 0


@pytest.mark.parametrize("integrator", [I.BackwardEuler, I.ImplicitMidpoint, I.BDF2])
def test_the_old_integrator_keywords_warn_validate_and_give_the_same_steps(integrator):
    """``BackwardEuler(method="lbfgs", lbfgs_history=4)`` warns, names the new spelling, is validated when
    the solver is built, and steps bit for bit like ``minimizer=MinimizerOptions(...)``."""
    with pytest.warns(DeprecationWarning, match=r"minimizer=pl.solvers.MinimizerOptions\(method='lbfgs'"):
        old = integrator(method="lbfgs", lbfgs_history=4, newton_tol=1e-6)
    assert old.options.minimizer_settings() == {"method": "lbfgs", "lbfgs_history": 4}
    m = _box()
    energies = [pl.energies.NeoHookean(), pl.energies.Gravity()]
    s_old = pl.solvers.ForceSolver(m, energies, old)
    assert s_old.minimizer == pl.solvers.MinimizerOptions(method="lbfgs", lbfgs_history=4)
    x_old = _steps(s_old, m)
    assert s_old.last_stats.linear_solver == "lbfgs"
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        new = pl.solvers.ForceSolver(
            m, energies, integrator(newton_tol=1e-6), minimizer={"method": "lbfgs", "lbfgs_history": 4}
        )
        x_new = _steps(new, m)
    np.testing.assert_array_equal(x_old, x_new)
    # Old keywords with bad values fail when the solver is built, before any step.
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match="lbfgs_h0 must be 'lu' or 'amg'"):
        pl.solvers.ForceSolver(m, energies, integrator(lbfgs_h0="cholesky"))


def test_both_spellings_must_agree():
    """The same setting given as an integrator keyword and in minimizer=: equal is fine, different refused."""
    m = _box()
    with pytest.warns(DeprecationWarning):
        integ = I.BackwardEuler(method="lbfgs")
    s = pl.solvers.ForceSolver(m, [pl.energies.NeoHookean()], integ, minimizer={"method": "lbfgs"})
    assert s.minimizer.method == "lbfgs"
    with pytest.raises(ValueError, match=r"\['method'\] given twice, differently"):
        pl.solvers.ForceSolver(m, [pl.energies.NeoHookean()], integ, minimizer={"method": "newton"})


def _build(solver_line: str):
    return build_scene(parse_scene(HEAD + BOX + SOLVER + solver_line + "\n", "s.toml"), device="cpu")


def test_scene_files_old_and_new_spelling():
    """``[solver] options = { minimizer = {...} }`` builds an L-BFGS solver silently; the old
    ``integrator_options = { method = "lbfgs" }`` still loads (DeprecationWarning) to the same settings; a bad
    minimiser value is a scene error naming ``solver.options`` before any step."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        new = _build('options = { minimizer = { method = "lbfgs" } }')
    assert new.solver.minimizer == pl.solvers.MinimizerOptions(method="lbfgs")
    with pytest.warns(DeprecationWarning, match="integrator_options"):
        old = _build('integrator_options = { method = "lbfgs" }')
    assert old.solver.minimizer == new.solver.minimizer
    with pytest.raises(SceneError) as info:
        _build('options = { minimizer = { method = "lbgfs" } }')
    assert "solver.options" in str(info.value) and "method must be 'newton', 'lbfgs' or 'auto'" in str(
        info.value
    )


@pytest.mark.parametrize("name", ["soft_box_fem", "fem_drop", "fem_embedded", "fem_squeeze", "cantilever"])
def test_builtin_fem_scenes_use_lbfgs_through_the_solver(name):
    """The built-in FEM scenes ask the solver for ``method="auto"`` (L-BFGS on the CPU, the device Newton
    on a GPU) in the new spelling (no deprecated keyword), and get L-BFGS on the CPU."""
    cfg = pl.scene.load_scene(name)
    assert cfg.solver.options.get("minimizer") == {"method": "auto"}
    assert pl.scene.build_scene(cfg).solver.minimizer.method == "auto"
    assert not set(cfg.solver.integrator_options) & set(I._implicit.MINIMIZER_SETTINGS)
