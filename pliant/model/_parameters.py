"""The parameter registry: every physical parameter a rollout can differentiate or a fit can search, declared
by the class whose step reads it.

An energy, constraint, collider, solver (or the Model / State / Control containers) declares its parameters
with a ``parameters()`` class method returning :class:`Parameter` objects and registers itself with
:func:`declares`. Everything that used to keep its own table reads this one:

- :data:`pliant.diff.PARAMETERS` (what :func:`pliant.diff.rollout` differentiates): the differentiable ones;
- :data:`pliant.model._worlds.PARAMETERS` (what ``Model.set_world_parameter`` sets per world): the ones held
  in a per-element model array;
- ``pliant.fit``: the scene-level names (``Et``, ``E``, ``damping_rate``, ``compliance``, ...) name the
  registry parameters they drive; the per-element stage and the image-gradient stage read the arrays and
  default search ranges from here.

A new energy becomes differentiable and fittable by declaring its parameters here: no table to edit.
"""

from __future__ import annotations

import keyword
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any, Union

if TYPE_CHECKING:
    import warp as wp

    from ._model import Control, Model, State

#: Element kinds a parameter may be given per (``global``: one value, or one vector, for the whole model).
PER = ("particle", "spring", "tri", "tet", "bending", "constraint", "collider", "global")

#: Where a parameter's array may live: the prefix of each entry of :attr:`Parameter.arrays`.
HOMES = ("model", "solver", "state", "control", "constraint", "collider")

#: Sign conventions of the values a parameter may take.
SIGNS = ("positive", "nonnegative", "any")

#: Classes that declare parameters (filled by :func:`declares`), in registration order.
OWNERS: list[type] = []

#: The dataclass whose fields a ``model.<attribute>`` array must name: :class:`pliant.model.Model`, which
#: registers itself with :func:`array_home` (this module sits below the Model, which imports it).
HOME_CLASSES: dict[str, type] = {}


class ParameterError(ValueError):
    """A parameter declaration that is inconsistent (unknown array, bad bounds, two owners disagreeing)."""


#: What a getter finds: the Warp array, or (array, component) for one component of a shared array.
Found = Union["wp.array", tuple["wp.array", int]]
#: ``get(model, solver, state0, control)``: the solver is any solver class (read by attribute name: this
#: layer sits below pliant.solvers), the control None when the caller passes none.
Getter = Callable[["Model", object, "State", Union["Control", None]], Found]


@dataclass(frozen=True)
class Parameter:
    """One physical parameter.

    Attributes:
        name: The name :func:`pliant.diff.rollout` takes (``params=[...]``), unique across the registry.
        doc: What it is, one line.
        unit: SI unit (``"1"`` when dimensionless).
        per: What there is one value of (:data:`PER`): per particle, spring, tet, ..., or ``global``.
        arrays: Where the values live, ``"<home>.<attribute>"`` (:data:`HOMES`), e.g.
            ``"model.spring_stiffness"``, ``"solver.damping_rate_array"``,
            ``"solver.ground_coefficients[0]"`` (a component of a shared array).
        bounds: The physically sensible default search range (lo, hi) in ``unit`` (log scale when ``log``),
            or None when the parameter is not a material value to search (positions, forces).
        log: Searched in log scale (a positive magnitude).
        differentiable: Whether a tape-recorded step carries its gradient (False: read once at set-up, e.g.
            a stiffness converted to a compliance when the constraint is bound).
        sign: ``positive``, ``nonnegative`` or ``any``: the values a model may take.
        get: ``get(model, solver, state0, control)`` → the Warp array (or ``(array, component)``) in a
            built set-up; default: ``getattr(model, <attribute>)`` for a ``model.`` array. Raises
            :class:`pliant.diff.GradientError` with the fix when the set-up has none.
    """

    name: str
    doc: str
    unit: str
    per: str
    arrays: tuple[str, ...]
    bounds: tuple[float, float] | None = None
    log: bool = True
    differentiable: bool = True
    sign: str = "nonnegative"
    get: Getter | None = None

    def getter(self) -> Getter:
        """The function that finds this parameter's array in ``(model, solver, state0, control)``."""
        if self.get is not None:
            return self.get
        home, attr = self.arrays[0].split(".", 1)
        if home != "model":
            raise ParameterError(f"parameter {self.name!r}: an array outside the model needs get=")
        return lambda m, s, x, c: getattr(m, attr)

    @property
    def model_array(self) -> str | None:
        """The Model array holding one value per element (``spring_stiffness``, ...), or None."""
        home, attr = self.arrays[0].split(".", 1)
        return attr if home == "model" and "[" not in attr else None


def solver_array(attr: str, what: str, component: int | None = None) -> Getter:
    """A getter for ``solver.<attr>`` (component ``component`` of it when given); GradientError naming
    ``what`` (the set-ups that have it) when the solver has none."""

    def get(model: Model, solver: object, state0: State, control: Control | None) -> Found:
        from .._warp import GradientError

        a = getattr(solver, attr, None)
        if a is None:
            raise GradientError(f"{attr!r} is differentiable only {what}")
        return a if component is None else (a, component)

    return get


def control_array(attr: str) -> Getter:
    """A getter for ``control.<attr>`` (GradientError when no Control is passed)."""

    def get(model: Model, solver: object, state0: State, control: Control | None) -> Found:
        from .._warp import GradientError

        if control is None:
            raise GradientError(f"{attr!r} is a Control array: pass control= to rollout")
        return getattr(control, attr)

    return get


def constraint_array(name: str, attr: str = "compliance_array") -> Getter:
    """A getter for ``<attr>`` of the solver's one constraint set whose class declares parameter ``name``
    (GradientError when there is none or several)."""

    def get(model: Model, solver: object, state0: State, control: Control | None) -> Found:
        from .._warp import GradientError

        sets = [
            c
            for c in getattr(solver, "constraints", ())
            if any(p.name == name for p in getattr(type(c), "parameters", lambda: ())())
        ]
        if not sets or getattr(sets[0], attr, None) is None:
            kinds = " or ".join(o.__name__ for o in registry()[name][1])
            raise GradientError(
                f"{name!r} needs an XPBD solver with a {kinds} constraint set "
                "(PBD sets use a stiffness, not a compliance)"
            )
        if len(sets) > 1:
            raise GradientError(
                f"{name!r}: the solver has {len(sets)} such sets; read constraint.{attr}.grad on the plain "
                "tape path to tell them apart"
            )
        return getattr(sets[0], attr)

    return get


# The Model's per-element arrays, declared once here and returned both by the Model (which holds them) and
# by the energies and constraints that read them.
SPRING_STIFFNESS = Parameter(
    "spring_stiffness",
    "Hooke stiffness per spring",
    "N/m",
    "spring",
    ("model.spring_stiffness",),
    (1e-2, 1e6),
)
SPRING_REST_LENGTH = Parameter(
    "spring_rest_length",
    "rest length per spring",
    "m",
    "spring",
    ("model.spring_rest_length",),
    None,
    log=False,
    sign="positive",
)
SPRING_DAMPING = Parameter(
    "spring_damping",
    "dashpot coefficient along each spring",
    "N s/m",
    "spring",
    ("model.spring_damping",),
    (1e-6, 1.0),
)
TET_MU = Parameter("tet_mu", "Lamé μ per tet", "Pa", "tet", ("model.tet_mu",), (1e1, 1e10), sign="positive")
TET_LAM = Parameter("tet_lam", "Lamé λ per tet", "Pa", "tet", ("model.tet_lam",), (1e1, 1e11), sign="any")
BENDING_STIFFNESS = Parameter(
    "bending_stiffness",
    "bending stiffness per bending element (read once, as alpha = 1/k)",
    "N m/rad",
    "bending",
    ("model.bending_stiffness",),
    (1e-6, 1e2),
    differentiable=False,
)
#: Masses: the step reads both m (gravity) and 1/m (accelerations); a rollout combines
#: ∂L/∂m + ∂L/∂(1/m)·(−1/m²) for free particles (pinned ones keep 1/m = 0).
PARTICLE_MASS = Parameter(
    "particle_mass",
    "mass per particle",
    "kg",
    "particle",
    ("model.particle_mass", "model.particle_inv_mass"),
    (1e-6, 1e3),
    sign="positive",
)
MODEL_ARRAYS = (
    PARTICLE_MASS,
    SPRING_STIFFNESS,
    SPRING_REST_LENGTH,
    SPRING_DAMPING,
    TET_MU,
    TET_LAM,
    BENDING_STIFFNESS,
)


def declares(cls: type) -> type:
    """Class decorator: register ``cls`` (which defines ``parameters()``) as an owner of parameters."""
    if not callable(getattr(cls, "parameters", None)):
        raise ParameterError(f"{cls.__name__}: @declares needs a parameters() class method")
    if cls not in OWNERS:
        OWNERS.append(cls)
    return cls


def array_home(home: str) -> Callable[[type], type]:
    """Class decorator: the dataclass ``cls`` holds the ``<home>.<attribute>`` arrays that :func:`check`
    accepts (only ``"model"`` is checked by attribute; the other homes are objects of many classes)."""

    def register(cls: type) -> type:
        HOME_CLASSES[home] = cls
        return cls

    return register


def check(owner: type, p: Parameter) -> None:
    """Raise :class:`ParameterError` when declaration ``p`` of ``owner`` is inconsistent: an unknown kind,
    home or sign, a ``model.`` array the Model does not have, bounds that are not an increasing pair (> 0
    for log scale)."""
    where = f"{owner.__name__}.parameters(): {p.name!r}"
    if not p.name.isidentifier() or keyword.iskeyword(p.name):
        raise ParameterError(f"{where}: the name must be an identifier")
    if not p.unit or not p.doc:
        raise ParameterError(f"{where}: give a unit ('1' if dimensionless) and a doc line")
    if p.per not in PER:
        raise ParameterError(f"{where}: per={p.per!r}; one of {PER}")
    if p.sign not in SIGNS:
        raise ParameterError(f"{where}: sign={p.sign!r}; one of {SIGNS}")
    if not p.arrays:
        raise ParameterError(f"{where}: name the array(s) it lives in")
    model_fields = {f.name for f in fields(HOME_CLASSES["model"])}
    for a in p.arrays:
        home, _, attr = a.partition(".")
        if home not in HOMES or not attr:
            raise ParameterError(f"{where}: array {a!r} must be '<home>.<attribute>', home one of {HOMES}")
        if home == "model" and attr.split("[")[0] not in model_fields:
            raise ParameterError(f"{where}: the Model has no array {attr!r}")
    if p.get is None and not p.arrays[0].startswith("model."):
        raise ParameterError(f"{where}: an array outside the model needs get=")
    if p.bounds is not None:
        lo, hi = p.bounds
        if not lo < hi or (p.log and lo <= 0):
            raise ParameterError(f"{where}: bounds {p.bounds} must be lo < hi (and lo > 0 in log scale)")


_CACHE: list = []  # [owners, table]: rebuilt when a class registers


def _declared(owner: type) -> tuple[Parameter, ...]:
    """``owner.parameters()``, a class method that :func:`declares` checked the class has."""
    return tuple(owner.parameters())  # type: ignore[attr-defined]  # any class may declare parameters


def registry() -> dict[str, tuple[Parameter, tuple[type, ...]]]:
    """Every declared parameter of the classes imported so far: name → (its declaration, the classes that
    declare it). :func:`pliant.diff.parameters` imports every package that declares some first.

    Raises:
        ParameterError: an inconsistent declaration, or two classes declaring one name differently.
    """
    if _CACHE and _CACHE[0] == tuple(OWNERS):
        return dict(_CACHE[1])
    out: dict[str, tuple[Parameter, tuple[type, ...]]] = {}
    for owner in OWNERS:
        for p in _declared(owner):
            check(owner, p)
            if p.name in out:
                first, owners = out[p.name]
                if first != p:
                    raise ParameterError(
                        f"{owner.__name__} and {owners[0].__name__} declare {p.name!r} differently; "
                        "declare it once (a module constant) and return it from both"
                    )
                out[p.name] = (first, (*owners, owner))
            else:
                out[p.name] = (p, (owner,))
    _CACHE[:] = [tuple(OWNERS), out]
    return dict(out)


def parameter(name: str) -> Parameter:
    """The declaration of parameter ``name``; ParameterError with the known names when there is none."""
    reg = registry()
    if name not in reg:
        raise ParameterError(f"unknown parameter {name!r}; declared: {', '.join(sorted(reg))}")
    return reg[name][0]


class RegistryView(Mapping):
    """A read-only, lazily built view of the registry: ``select(p)`` picks the parameters, ``value(p)`` is
    what the view maps each name to, ``load()`` gives the registry (default :func:`registry`: the classes
    imported so far), each resolved on use."""

    def __init__(
        self,
        select: Callable[[Parameter], bool],
        value: Callable[[Parameter], Any],
        load: Callable[[], dict[str, tuple[Parameter, tuple[type, ...]]]] | None = None,
    ) -> None:
        self._select, self._value, self._load = select, value, load or registry

    def _table(self) -> dict[str, Any]:
        return {n: self._value(p) for n, (p, _) in self._load().items() if self._select(p)}

    def __getitem__(self, key: str) -> Any:
        return self._table()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._table())

    def __len__(self) -> int:
        return len(self._table())

    def __repr__(self) -> str:
        return f"RegistryView({sorted(self._table())})"


__all__ = [
    "OWNERS",
    "PER",
    "Parameter",
    "ParameterError",
    "array_home",
    "RegistryView",
    "check",
    "constraint_array",
    "control_array",
    "declares",
    "parameter",
    "registry",
    "solver_array",
]
