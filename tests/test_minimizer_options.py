"""The minimiser's settings belong to the implicit solver (``pl.solvers.MinimizerOptions``,
``ForceSolver(minimizer=...)``, ``[solver] options = { minimizer = {...} }``); the old integrator keywords
(``BackwardEuler(method="lbfgs")``, ``integrator_options = { method = "lbfgs" }``), deprecated since, are
removed: giving one is an error that says where it went."""

from __future__ import annotations

import dataclasses
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
def test_the_old_integrator_keywords_are_an_error_naming_the_new_spelling(integrator):
    """``BackwardEuler(method="lbfgs", lbfgs_history=4)``, and the same in an options dict handed to a
    minimiser, raise a ValueError naming both settings and ``minimizer=pl.solvers.MinimizerOptions``."""
    with pytest.raises(ValueError, match=r"method, lbfgs_history: the implicit solver's settings") as info:
        integrator(method="lbfgs", lbfgs_history=4, newton_tol=1e-6)
    assert "minimizer=pl.solvers.MinimizerOptions(method=..., lbfgs_history=...)" in str(info.value)
    assert integrator.__name__ in str(info.value)
    m = _box()
    x = m.particle_q
    with pytest.raises(ValueError, match="linear_solver: the implicit solver's settings"):
        pl.solvers.minimizers.minimize(
            pl.solvers.ForceSolver(m, [pl.energies.NeoHookean()], integrator()),
            0.0,
            0.01,
            x,
            x,
            m.particle_qd,
            x,
            {"linear_solver": "pcg"},
        )
    assert set(I._implicit.MINIMIZER_SETTINGS) == {
        f.name for f in dataclasses.fields(pl.solvers.MinimizerOptions)
    }, "the error names every minimiser setting"


def _build(solver_line: str):
    return build_scene(parse_scene(HEAD + BOX + SOLVER + solver_line + "\n", "s.toml"), device="cpu")


def test_scene_files_old_and_new_spelling():
    """``[solver] options = { minimizer = {...} }`` builds an L-BFGS solver silently; the old
    ``integrator_options = { method = "lbfgs" }`` is a scene error at ``solver.integrator_options.method``
    that gives the new spelling; a bad minimiser value is a scene error naming ``solver.options`` before any
    step."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        new = _build('options = { minimizer = { method = "lbfgs" } }')
    assert new.solver.minimizer == pl.solvers.MinimizerOptions(method="lbfgs")
    with pytest.raises(SceneError) as info:
        _build('integrator_options = { method = "lbfgs" }')
    text = str(info.value)
    assert "solver.integrator_options.method" in text and "[solver] options = { minimizer = { ... } }" in text
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
