"""Fitted parameters: global ones (scene-file values, changed by rebuilding the scene) and per-element ones
(model arrays changed in place, with gradients from the tape). Both name the registry parameters
(:mod:`pliant.model._parameters`) they drive; the arrays and the classes that read them come from there.

Global parameters (``GLOBAL``) live in the scene file; the CMA-ES stage searches them in a box normalised to
[0, 1]ᵈ, log-scaled for positive magnitudes. Topology parameters (spring radius and neighbour count of
point-cloud objects) rebuild the springs, so only the derivative-free stage may change them.
Per-element parameters (``PER_ELEMENT``) are log-scale factors θ on model arrays, ``a = a₀ · exp(θ)``:
``stiffness`` (per spring k) and ``E`` (per tet, μ and λ together: ν unchanged).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from ..io import Observations
    from ..model._parameters import Parameter
    from ..scene import Scene, SceneConfig


class FitError(ValueError):
    """A fitting set-up that cannot work (unknown parameter, nothing to fit, no gradient); one line, with the
    fix."""


def _materials(cfg: SceneConfig, models: tuple[str, ...]) -> list[Any]:
    return [o.material for o in cfg.objects if o.model in models]


def _mat_field(field: str, models: tuple[str, ...]) -> Callable[[Any], list[tuple[Any, str]]]:
    def where(cfg: SceneConfig) -> list[tuple[Any, str]]:
        return [(m, field) for m in _materials(cfg, models) if getattr(m, field) is not None]

    return where


def _section_field(section: str, field: str, default: float | None = None) -> Callable[[Any], list]:
    def where(cfg: SceneConfig) -> list[tuple[Any, str]]:
        sec = getattr(cfg, section)
        if sec is None or (getattr(sec, "enabled", True) is False):
            return []
        if getattr(sec, field) is None:
            if default is None:
                return []
            setattr(sec, field, default)  # an unset optional value: start the search from its default
        return [(sec, field)]

    return where


def _compliance(cfg: SceneConfig) -> list[tuple[Any, str]]:
    if cfg.solver_kind() != "xpbd":
        return []
    if cfg.solver.compliance is None:
        cfg.solver.compliance = next(
            (o.material.compliance for o in cfg.objects if o.material.compliance is not None), 1e-6
        )
    return [(cfg.solver, "compliance")]


def _points_field(field: str, default: Callable[[Any], float]) -> Callable[[Any], list]:
    def where(cfg: SceneConfig) -> list[tuple[Any, str]]:
        out = []
        for o in cfg.objects:
            if o.kind == "points":
                if getattr(o, field) is None:
                    setattr(o, field, default(o))
                out.append((o, field))
        return out

    return where


@dataclass(frozen=True)
class GlobalParam:
    """A global parameter: where it lives in a scene, its scale and bounds.

    Attributes:
        name: The ``--params`` name.
        doc: What it is, with units.
        where: ``where(cfg) -> [(section, field)]`` the scene values it sets (all set to one value); may fill
            in an unset optional field with its default.
        log: Searched in log scale (positive magnitudes).
        bounds: ``bounds(nominal) -> (lo, hi)``.
        topology: Changes the springs (derivative-free stage only).
        integer: Rounded to a whole number.
        drives: The registry parameters (:mod:`pliant.model._parameters`) whose arrays the scene builds
            proportional to this value (``Et`` → ``spring_stiffness``; ``E`` → ``tet_mu``, ``tet_lam``;
            ``compliance`` → every XPBD compliance): the gradient stages differentiate through them. Empty:
            derivative-free only (ν, topology).
    """

    name: str
    doc: str
    where: Callable[[Any], list[tuple[Any, str]]]
    log: bool
    bounds: Callable[[float], tuple[float, float]]
    topology: bool = False
    integer: bool = False
    drives: tuple[str, ...] = ()

    def to_unit(self, value: float, lo: float, hi: float) -> float:
        """Value → [0, 1] (log scale for ``log``)."""
        if self.log:
            return (math.log(value) - math.log(lo)) / (math.log(hi) - math.log(lo))
        return (value - lo) / (hi - lo)

    def from_unit(self, u: float, lo: float, hi: float) -> float:
        """[0, 1] → value."""
        u = min(max(float(u), 0.0), 1.0)
        v = math.exp(math.log(lo) + u * (math.log(hi) - math.log(lo))) if self.log else lo + u * (hi - lo)
        return float(round(v)) if self.integer else v


def _around(factor: float, floor: float) -> Callable[[float], tuple[float, float]]:
    return lambda v: (max(v, floor) / factor, max(v, floor) * factor)


GLOBAL: dict[str, GlobalParam] = {
    p.name: p
    for p in [
        GlobalParam(
            "stiffness",
            "spring constant k of every mass-spring object [N/m]",
            _mat_field("stiffness", ("mass_spring",)),
            True,
            _around(10.0, 1e-6),
            drives=("spring_stiffness",),
        ),
        GlobalParam(
            "Et",
            "membrane stiffness E·t of every mass-spring cloth given by it [N/m] (sets its structural and "
            "shear springs)",
            lambda cfg: [(m, f) for m, f in _mat_field("Et", ("mass_spring",))(cfg) if m.stiffness is None],
            True,
            _around(10.0, 1e-6),
            drives=("spring_stiffness",),
        ),
        GlobalParam(
            "bend_stiffness",
            "k of the bend springs (across two segments or cells) of every mass-spring object that has them "
            "[N/m]",
            lambda cfg: [
                (m, f) for m, f in _mat_field("bend_stiffness", ("mass_spring",))(cfg) if m.bend_stiffness > 0
            ],
            True,
            # ×100: a bend spring is a crude stand-in for another engine's rod or shell bending (MuJoCo's rope
            # fits at a tenth of its converted value), so the data may put it far from the conversion.
            _around(100.0, 1e-6),
            # No `drives`: the bend springs share spring_stiffness with the others, so a gradient through
            # that array is not this parameter's; CMA-ES fits it.
        ),
        GlobalParam(
            "damping",
            "dashpot γ along each spring of every mass-spring object [N s/m]",
            _mat_field("damping", ("mass_spring",)),
            True,
            _around(10.0, 1e-5),
            drives=("spring_damping",),
        ),
        GlobalParam(
            "damping_rate",
            "velocity damping rate of the solver [1/s]",
            _section_field("solver", "damping_rate", 0.0),
            True,
            lambda v: (v / 10.0, v * 10.0) if v > 0 else (1e-3, 20.0),
            drives=("damping_rate",),
        ),
        GlobalParam(
            "ground_friction",
            "Coulomb friction μ of the ground",
            _section_field("ground", "friction"),
            False,
            lambda v: (0.0, 2.0),
            drives=("ground_friction",),
        ),
        GlobalParam(
            "ground_restitution",
            "restitution e of the ground",
            _section_field("ground", "restitution"),
            False,
            lambda v: (0.0, 1.0),
            drives=("ground_restitution",),
        ),
        GlobalParam(
            "E",
            "Young's modulus of every FEM object [Pa]",
            _mat_field("E", ("fem",)),
            True,
            _around(10.0, 1.0),
            drives=("tet_mu", "tet_lam"),
        ),
        GlobalParam(
            "nu",
            "Poisson ratio of every FEM object",
            _mat_field("nu", ("fem",)),
            False,
            lambda v: (0.0, 0.49),
        ),
        GlobalParam(
            "compliance",
            "XPBD compliance α [m/N]",
            _compliance,
            True,
            _around(100.0, 1e-10),
            drives=("compliance_distance", "compliance_dihedralbending", "compliance_volume"),
        ),
        GlobalParam(
            "radius",
            "spring radius of point-cloud objects [m] (topology)",
            _points_field("radius", lambda o: 1.8 * o.spacing),
            False,
            lambda v: (0.5 * v, 2.0 * v),
            topology=True,
        ),
        GlobalParam(
            "neighbours",
            "most springs per point of point-cloud objects (topology)",
            _points_field("max_neighbors", lambda o: o.max_neighbors),
            False,
            lambda v: (1.0, max(2.0 * v, 2.0)),
            topology=True,
            integer=True,
        ),
    ]
}


def scene_constraints(scene: Scene) -> list[Any]:
    """The constraint sets of the scene's solver (XPBD / PBD), indexed as in ``constraints.<i>.<array>``
    keys; empty for the other solvers. Each is a :class:`~pliant.constraints.Constraint` of some kind;
    callers read what their kind has (``indices``, the ``parameters()`` that ``@declares`` checked)."""
    return list(getattr(scene.solver, "constraints", []))


def _declares(c: object, name: str) -> bool:
    return any(p.name == name for p in getattr(type(c), "parameters", lambda: ())())


def registry_arrays(scene: Scene, names: tuple[str, ...]) -> dict[str, Any]:
    """The arrays of registry parameters ``names`` in a built scene that hold one value per element:
    ``model.<array>`` for model arrays (when the model has such elements) and
    ``constraints.<i>.<array>`` for every constraint set of the solver whose class declares the name."""
    from ..diff import parameters as registry

    reg = registry()
    out: dict[str, Any] = {}
    for n in names:
        p = reg[n][0]
        if p.model_array is not None:
            a = getattr(scene.model, p.model_array)
            if a.shape[0]:
                out[f"model.{p.model_array}"] = a
        elif p.per == "constraint":
            attr = p.arrays[0].split(".", 1)[1]
            for i, c in enumerate(scene_constraints(scene)):
                a = getattr(c, attr, None)
                if a is not None and a.shape[0] and _declares(c, n):
                    out[f"constraints.{i}.{attr}"] = a
    return out


def _per_element(name: str, what: str) -> Callable[[Any], dict[str, Any]]:
    def arrays(scene: Scene) -> dict[str, Any]:
        out = registry_arrays(scene, GLOBAL[name].drives)
        if not out:
            raise FitError(f"--per-element: this scene's model has no {what}")
        for key, a in out.items():
            if key.startswith("constraints.") and not np.all(a.numpy() > 0):
                c = scene_constraints(scene)[int(key.split(".")[1])]
                raise FitError(
                    f"--per-element {name}: {type(c).__name__} constraints are rigid (α = 0), which a "
                    "log-scale factor cannot change; give the scene a compliance > 0"
                )
        return out

    return arrays


#: Per-element parameters: name → (the arrays scaled together by exp(θ) per element, what it is): the
#: model arrays and constraint arrays of the registry parameters the global parameter of that name drives.
PER_ELEMENT: dict[str, tuple[Callable[[Any], dict[str, Any]], str]] = {
    "stiffness": (_per_element("stiffness", "springs"), "log-scale factor of each spring's k"),
    "E": (
        _per_element("E", "tetrahedra"),
        "log-scale factor of each tet's E (μ and λ together: ν unchanged)",
    ),
    "compliance": (
        _per_element("compliance", "XPBD constraints with a compliance"),
        "log-scale factor of each XPBD constraint's compliance α",
    ),
}

_DISSIPATION = (
    "velocity damping: the dissipation of the observed motion (air, material loss) is unknown to the scene"
)

#: Default parameters per object model, each with why it is searched (issue 25): the ones that matter for
#: motion recorded elsewhere — the stiffness, and the two dissipations (velocity damping rate and, for
#: mass-spring, the dashpot along the springs), which another engine's or a real object's motion always has.
WHY: dict[str, tuple[tuple[str, str], ...]] = {
    "mass_spring": (
        ("stiffness", "default for mass-spring: the spring stiffness"),
        ("Et", "default for mass-spring cloth: the membrane stiffness"),
        ("bend_stiffness", "default for mass-spring with bend springs: the bending stiffness"),
        ("damping_rate", _DISSIPATION),
        ("damping", "default for mass-spring: the dashpot along each spring (internal dissipation)"),
    ),
    "fem": (
        ("E", "default for FEM: Young's modulus"),
        ("nu", "default for FEM: Poisson's ratio"),
        ("damping_rate", _DISSIPATION),
    ),
    "pbd": (("compliance", "default for XPBD: the constraints' compliance"), ("damping_rate", _DISSIPATION)),
}
#: Default parameter names per object model (the names of :data:`WHY`).
DEFAULTS = {model: tuple(n for n, _ in rows) for model, rows in WHY.items()}
#: The per-element parameter of each model (``per_element="auto"``).
PER_ELEMENT_OF = {"mass_spring": "stiffness", "fem": "E", "pbd": "compliance"}

#: Ground coefficients, searched by default when the observations reach the ground.
CONTACT = ("ground_friction", "ground_restitution")


def ground_contact(cfg: SceneConfig, obs: Observations) -> float | None:
    """The lowest visible track height above the scene's ground [m] when the observations come within 5 % of
    their extent of it (they show contact), else None (no ground, no tracks, or motion well above it)."""
    g = getattr(cfg, "ground", None)
    if g is None or not g.enabled or obs is None or obs.tracks == 0:
        return None
    pts = obs.points[obs.visible]
    if pts.size == 0:
        return None
    gap = float(pts[:, 1].min()) - float(g.height)
    extent = float(np.ptp(pts, axis=0).max())
    return gap if gap <= 0.05 * max(extent, 1e-9) else None


def default_params(cfg: SceneConfig, obs: Observations | None = None) -> list[str]:
    """The default parameters of the scene's models (:data:`WHY`: mass-spring k or E·t, damping rate,
    dashpot γ; FEM: E, ν, damping rate; XPBD: compliance, damping rate), plus the ground's friction and
    restitution when ``obs`` (Observations) reach the ground (:func:`ground_contact`)."""
    return list(default_reasons(cfg, obs))


def default_reasons(cfg: SceneConfig, obs: Any = None) -> dict[str, str]:
    """:func:`default_params` with why each is searched (name → reason)."""
    out: dict[str, str] = {}
    for o in cfg.objects:
        for name, why in WHY.get(o.model, ()):
            if name not in out and GLOBAL[name].where(cfg.model_copy(deep=True)):
                out[name] = why
    gap = ground_contact(cfg, obs)
    if gap is not None:
        for name in CONTACT:
            out[name] = f"the observations reach the ground (lowest track {gap * 1e3:.3g} mm above it)"
    return out


def auto_per_element(cfg: SceneConfig, obs: Observations) -> str | None:
    """``per_element="auto"``: the per-element parameter of the scene's first object's model
    (:data:`PER_ELEMENT_OF`), or None for image observations (per-element fits need tracks)."""
    if obs is not None and getattr(obs, "images", None) is not None:
        return None
    return PER_ELEMENT_OF.get(cfg.objects[0].model) if cfg.objects else None


def _critical_damping(scene: Scene) -> float | None:
    """2·√(k·m) [N s/m] of a typical spring (median k, median free particle mass), or None."""
    m = scene.model
    if m.spring_count == 0:
        return None
    k = float(np.median(m.spring_stiffness.numpy()))
    mass = m.particle_mass.numpy()[m.particle_inv_mass.numpy() > 0]
    if mass.size == 0 or k <= 0:
        return None
    return 2.0 * math.sqrt(k * float(np.median(mass)))


def widen_bounds(bounds: list[Any], scene: Scene) -> None:
    """Physically scaled bounds, set in place: a dashpot γ spans 10⁻⁴ … 1 × the critical damping
    2√(k m) of a typical spring of ``scene`` (built at the nominal values; a placeholder γ of 0 would
    otherwise leave a box around 10⁻⁵ N s/m), and a damping rate of 0 the registry's range."""
    from ..diff import parameters as registry

    for b in bounds:
        if b.name == "damping":
            gc = _critical_damping(scene)
            if gc is None:
                continue
            if (b.scene_value or 0.0) > 0:  # a value of the scene's own: widen the box around it
                b.lo, b.hi = min(b.lo, 1e-4 * gc), max(b.hi, gc)
            else:  # a placeholder 0: the physical range alone
                b.lo, b.hi = 1e-4 * gc, gc
        elif b.name == "damping_rate" and not (b.scene_value or 0.0) > 0:
            physical = registry()["damping_rate"][0].bounds
            assert physical is not None  # damping_rate declares its range (pliant/model/_parameters.py)
            b.lo, b.hi = physical
        else:
            continue
        if not (b.scene_value or 0.0) > 0:
            b.nominal = math.sqrt(b.lo * b.hi)
        b.nominal = min(max(b.nominal, b.lo), b.hi)


@dataclass
class Bound:
    """A global parameter resolved for one scene: where the search starts (``nominal``), its bounds, the
    scene's own value (which may lie outside them: a damping rate of 0 starts the log-scale search at
    √(lo·hi)) and why it is searched."""

    param: GlobalParam
    nominal: float
    lo: float
    hi: float
    scene_value: float | None = None
    why: str = "named by --params"

    @property
    def name(self) -> str:
        return self.param.name


def resolve_globals(cfg: SceneConfig, names: list[str]) -> list[Bound]:
    """Check ``names`` against the scene and return their nominal values and bounds.

    Raises:
        FitError: an unknown name, or one the scene has no value for (with the names that exist).
    """
    out = []
    for name in names:
        p = GLOBAL.get(name)
        if p is None:
            raise FitError(
                f"--params: unknown parameter {name!r}; the global parameters are {', '.join(GLOBAL)}"
            )
        where = p.where(cfg)
        if not where:
            usable = [n for n, q in GLOBAL.items() if q.where(cfg.model_copy(deep=True))]
            raise FitError(
                f"--params: {name!r} ({p.doc}) does not exist in this scene; it has "
                f"{', '.join(usable) or 'none'}"
            )
        nominal = scene_value = float(getattr(*where[0]))
        lo, hi = p.bounds(nominal)
        if p.log and nominal <= 0:
            nominal = math.sqrt(lo * hi)
        out.append(Bound(p, min(max(nominal, lo), hi), lo, hi, scene_value))
    return out


def apply_globals(cfg: SceneConfig, values: dict[str, float]) -> SceneConfig:
    """A deep copy of the scene config with the global parameters set (``values``: name → value)."""
    cfg = cfg.model_copy(deep=True)
    for name, v in values.items():
        p = GLOBAL[name]
        for section, field in p.where(cfg):
            setattr(section, field, int(v) if p.integer else float(v))
    return cfg


def per_element_incidence(scene: Scene, name: str) -> np.ndarray:
    """The particles of each element of per-element parameter ``name``, int [n_elements, k] (springs: 2,
    tets: 4, constraints: their arity): which elements are neighbours for the smoothness term."""
    key = next(iter(per_element_arrays(scene, name)))
    parts = key.split(".")
    if parts[0] == "constraints":
        c = scene_constraints(scene)[int(parts[1])]
        return c.indices.numpy().reshape(c.count, -1)
    if parts[1].startswith("spring_"):
        return scene.model.spring_indices.numpy().reshape(-1, 2)
    if parts[1].startswith("bending_"):
        return scene.model.bending_indices.numpy().reshape(-1, 4)
    return scene.model.tet_indices.numpy().reshape(-1, 4)


def per_element_arrays(scene: Scene, name: str) -> dict[str, Any]:
    """The arrays of per-element parameter ``name`` in a built scene (``model.<array>`` /
    ``constraints.<i>.<array>`` → Warp array); raises FitError when unknown or absent."""
    if name in PER_ELEMENT:
        return PER_ELEMENT[name][0](scene)
    p = _element_parameter(name)
    if p is None:
        raise FitError(
            f"--per-element: unknown parameter {name!r}; choose one of {', '.join(PER_ELEMENT)} or a "
            f"per-element parameter of the registry ({', '.join(_element_parameters())})"
        )
    out = registry_arrays(scene, (name,))
    if not out:
        raise FitError(f"--per-element: this scene has no {p.per} holding {name!r} ({p.doc})")
    return out


def _element_parameters() -> list[str]:
    from ..diff import parameters as registry

    return [n for n, (p, _) in registry().items() if _element_parameter(n) is not None]


def _element_parameter(name: str) -> Parameter | None:
    """The registry declaration of ``name`` when it can be a per-element fit parameter: differentiable, a
    positive magnitude (log-scale factors) held per spring, tet, bending element or constraint."""
    from ..diff import parameters as registry

    entry = registry().get(name)
    if entry is None:
        return None
    p = entry[0]
    ok = (
        p.differentiable
        and p.log
        and p.bounds is not None
        and p.per in ("spring", "tet", "bending", "constraint")
    )
    return p if ok else None


__all__ = [
    "DEFAULTS",
    "GLOBAL",
    "PER_ELEMENT",
    "Bound",
    "FitError",
    "GlobalParam",
    "apply_globals",
    "default_params",
    "auto_per_element",
    "default_reasons",
    "ground_contact",
    "widen_bounds",
    "per_element_arrays",
    "per_element_incidence",
    "registry_arrays",
    "resolve_globals",
]
