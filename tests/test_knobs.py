"""Contract tests over the two registries a parameter change crosses: the knobs (pliant/scene/_knobs.py:
every knob resolves to a schema field and to registry parameters that exist, and the fit's, worlds' and live
view's tables are views of it) and the solvers (every registered solver kind says how it takes new
parameter values in place, and a value taken that way steps as a rebuilt scene does)."""

from __future__ import annotations

import typing

import numpy as np
import pytest
from helpers import FIT_ROPE
from pydantic import BaseModel

import pliant as pl
from pliant.scene import KNOBS, Knob
from pliant.scene._registry import OBJECT_KINDS, SOLVER_KINDS
from pliant.scene._schema import Material, ObjectBase, SceneConfig
from pliant.solvers import Solver


def _model_class(annotation: object) -> type[BaseModel]:
    """The pydantic class of a section field's annotation (``GroundSection | None`` → GroundSection)."""
    for t in (annotation, *typing.get_args(annotation)):
        if isinstance(t, type) and issubclass(t, BaseModel):
            return t
    raise AssertionError(f"{annotation!r} is not a section")


def _field_class(k: Knob) -> type[BaseModel]:
    """The schema class that holds knob ``k``'s field, from its path."""
    path = k.section
    if not path.startswith("objects["):
        return _model_class(SceneConfig.model_fields[path].annotation)
    kind, _, rest = path[len("objects[") :].partition("]")
    if rest == ".material":
        return Material
    assert rest == "", f"{k.name}: {k.field!r} is not objects[<kind>].<field> or objects[].material.<field>"
    return OBJECT_KINDS[kind].schema if kind else ObjectBase


@pytest.mark.parametrize("name", list(KNOBS))
def test_every_knob_resolves_to_a_schema_field_and_registry_parameters(name):
    """Each knob's field exists in the class its path names, each driven parameter in the registry (with a
    unit and, where the knob has no bounds of its own, the bounds it inherits), the bounds are an increasing
    pair (positive in log scale), and the fit's box around a value inside them is increasing too."""
    k = KNOBS[name]
    assert k.attr in _field_class(k).model_fields, f"{name}: no field {k.field!r} in the schema"
    registry = pl.diff.parameters()
    for d in k.drives:
        assert d in registry, f"{name} drives {d!r}, which no class declares"
    lo, hi = k.physical_bounds()
    assert lo < hi and (lo > 0 or not k.log), (name, lo, hi)
    v = (lo * hi) ** 0.5 if k.log else 0.5 * (lo + hi)
    blo, bhi = k.box(v)
    assert blo < bhi and (blo > 0 or not k.log)
    assert k.doc and (not k.default_for or k.why), name
    if k.per_element is not None:  # per-element factors scale arrays held per element
        assert all(registry[d][0].per != "global" for d in k.drives), name


def test_the_tables_are_views_of_the_knobs():
    """The fit's global, per-element, default, contact and object-level tables, the worlds' material fields
    and the live sliders name only knobs, and derive what they say from them."""
    from pliant.fit._cmaes import OBJECT_PARAMS
    from pliant.fit._params import CONTACT, DEFAULTS, GLOBAL, PER_ELEMENT, PER_ELEMENT_OF, WHY
    from pliant.scene._worlds import MATERIAL_FIELDS

    assert set(GLOBAL) == {n for n, k in KNOBS.items() if k.fit}
    assert all(GLOBAL[n] is KNOBS[n] for n in GLOBAL)
    assert OBJECT_PARAMS == {n for n in GLOBAL if KNOBS[n].on_object}
    assert set(PER_ELEMENT) == {n for n in GLOBAL if KNOBS[n].per_element}
    for model, rows in WHY.items():
        assert (
            [n for n, _ in rows]
            == [n for n in GLOBAL if model in KNOBS[n].default_for]
            == list(DEFAULTS[model])
        )
        assert all(why == KNOBS[n].why for n, why in rows)
        assert PER_ELEMENT_OF[model] in PER_ELEMENT
    assert CONTACT and all(KNOBS[n].field.startswith("ground.") for n in CONTACT)
    assert {KNOBS[n].field for n in ("stiffness", "Et")} <= {
        f"objects[].material.{f}" for f in MATERIAL_FIELDS
    }
    assert all(not k.topology for k in KNOBS.values() if k.attr in MATERIAL_FIELDS)


def test_a_knob_sets_the_scene_values_it_names():
    """``where`` finds the fields the knob sets and ``apply_globals`` writes them: a rope's k and damping rate
    land in the built model's springs and in the solver."""
    from pliant.fit._params import apply_globals

    cfg = pl.scene.parse_scene(FIT_ROPE)
    assert [(type(s).__name__, f) for s, f in KNOBS["stiffness"].where(cfg)] == [("Material", "stiffness")]
    assert KNOBS["Et"].where(cfg) == []  # the rope gives its k, not E·t
    scene = pl.scene.build_scene(apply_globals(cfg, {"stiffness": 73.0, "damping_rate": 0.25}))
    assert np.all(scene.model.spring_stiffness.numpy() == 73.0)
    assert scene.solver.damping_rate == 0.25


#: A rope under each registered solver kind (and each ForceSolver minimiser), written as a [solver] table.
SOLVERS = {
    "force": 'integrator = "SymplecticEuler"\ndamping_rate = 0.5',
    "force_newton": 'integrator = "BackwardEuler"',
    "force_lbfgs": 'integrator = "BackwardEuler"\noptions = { minimizer = { method = "lbfgs" } }',
    "fast_mass_spring": 'kind = "fast_mass_spring"',
    "xpbd": 'kind = "xpbd"\niterations = 4',
    "pbd": 'kind = "pbd"\niterations = 4',
}


def _rope(case: str, k: float) -> pl.scene.Scene:
    text = FIT_ROPE.replace('integrator = "SymplecticEuler"\ndamping_rate = 0.5', SOLVERS[case])
    if case in ("xpbd", "pbd"):
        text = text.replace('kind = "rope"', 'kind = "rope"\nmodel = "pbd"')
    return pl.scene.build_scene(pl.scene.parse_scene(text.replace("stiffness = 50.0", f"stiffness = {k}")))


def test_every_registered_solver_says_how_it_takes_new_values():
    """Every solver class the scene registry builds overrides ``Solver.refresh_parameters`` (the default only
    says it does not know), and every registered kind has a case in :data:`SOLVERS`."""
    for name, kind in SOLVER_KINDS.items():
        cls = kind.target
        assert isinstance(cls, type) and issubclass(cls, Solver), name
        assert cls.refresh_parameters is not Solver.refresh_parameters, (
            f"{cls.__name__}: no refresh_parameters"
        )
        assert name in SOLVERS, f"solver kind {name!r}: add a case to SOLVERS"


@pytest.mark.parametrize("case", list(SOLVERS))
def test_a_value_taken_in_place_steps_as_a_rebuilt_scene(case):
    """Spring k written into a built model and taken by ``refresh_parameters`` gives the trajectory of a
    scene built with that k, bit for bit (and not the old one, where the solver reads k); a solver that
    cannot take it says why in one line naming itself."""
    held = _rope(case, 50.0)
    before = pl.Simulator(held.model, held.solver, graph=False, **held.sim_kwargs).run(4, progress=False).x
    k = held.model.spring_stiffness.numpy()
    held.model.spring_stiffness.assign(np.full_like(k, 7.0))
    why = held.solver.refresh_parameters()
    if why is not None:
        assert case == "force_lbfgs" and "\n" not in why and type(held.solver).__name__ in why
        return
    after = pl.Simulator(held.model, held.solver, graph=False, **held.sim_kwargs).run(4, progress=False).x
    fresh = _rope(case, 7.0)
    rebuilt = (
        pl.Simulator(fresh.model, fresh.solver, graph=False, **fresh.sim_kwargs).run(4, progress=False).x
    )
    assert after.tobytes() == rebuilt.tobytes()
    if case != "pbd":  # PBD's constraints use the dimensionless [solver] stiffness_factor, not k
        assert not np.array_equal(after, before)
