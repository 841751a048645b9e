"""Knobs: the scene-file values that a fit searches, a sweep varies per world and the live view turns, each
declared once here, beside the schema (:mod:`pliant.scene._schema`) that holds its field.

A knob names its scene field (``objects[].material.Et``), the registry parameters
(:mod:`pliant.model._parameters`) whose arrays the scene builds from it (``Et`` → ``spring_stiffness``), its
physical bounds (by default the first driven parameter's), whether it is searched in log scale, whether it
lives in an object's own section or is global to the scene, whether it changes topology, and one line of
what it is, with its unit. Every other table is a view of :data:`KNOBS`:

- ``pliant.fit``'s global parameters (``GLOBAL``), CMA-ES's object-level ones, the per-element ones and the
  default parameters per object model (with why each is searched);
- :data:`pliant.scene._worlds.MATERIAL_FIELDS` (what worlds of one scene may differ in);
- the live view's sliders (:func:`pliant.live.live_parameters`).

The fit searches a box around the scene's own value rather than the knob's physical bounds: a knob's
``search`` is that policy (:class:`Around`: ×/÷ a factor around the value; None: the physical bounds),
documented where the knob is declared, not a second set of bounds. The box may leave the physical bounds,
as the scene's value (and data recorded elsewhere) is trusted over the registry's sensible range.

Adding a knob is one :class:`Knob` in :data:`KNOBS`; ``tests/test_knobs.py`` walks the table (every field
resolves in the schema, every driven parameter exists in the registry).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from ..model import GROUND_DAMPING_RATIO, GROUND_STIFFNESS, SPRING_STIFFNESS

if TYPE_CHECKING:
    from ..model import Parameter
    from ._build import Scene
    from ._schema import SceneConfig

#: ``when(cfg, section)``: whether a section that has the knob's field takes part (e.g. ``Et`` only where no
#: ``stiffness`` is given); ``default(cfg, section)``: the value an unset optional field starts from.
Condition = Callable[[Any, Any], bool]
Default = Callable[[Any, Any], float]


@dataclass(frozen=True)
class Around:
    """The fit's search box around the scene's value v: [c / factor, c · up] with c = max(v, floor)
    (``floor`` None: c = v, and a v ≤ 0 searches the knob's physical bounds instead).

    Attributes:
        factor: How far the box reaches each way (×/÷), > 1.
        floor: The smallest value the box is centred on (a scene value of 0 or below it starts there), in
            the knob's unit; None: no floor.
        up: How far it reaches up (×), when not ``factor``: for a start known to be a lower bound.
    """

    factor: float
    floor: float | None = None
    up: float | None = None

    def __call__(self, v: float, bounds: tuple[float, float]) -> tuple[float, float]:
        """(lo, hi) around ``v`` (``bounds``: the knob's physical ones, used when v ≤ 0 without a floor)."""
        c = v if self.floor is None else max(v, self.floor)
        if c <= 0:
            return bounds
        return (c / self.factor, c * (self.factor if self.up is None else self.up))


@dataclass(frozen=True)
class UpTo:
    """The fit's search box from the knob's physical lower bound lo to max(factor · v, factor · lo): a count
    (springs per point) searched from its least up to a multiple of the scene's value."""

    factor: float

    def __call__(self, v: float, bounds: tuple[float, float]) -> tuple[float, float]:
        """(lo, hi) for scene value ``v`` and physical ``bounds``."""
        return (bounds[0], max(self.factor * v, self.factor * bounds[0]))


@dataclass(frozen=True)
class Knob:
    """One scene value that the fit, worlds and the live view may change.

    Attributes:
        field: Its scene field: ``objects[].material.<f>`` (every object's material), ``objects[<kind>].<f>``
            (objects of that kind), or ``<section>.<f>`` (``solver``, ``ground``: skipped when disabled).
        doc: What it is, with its unit in brackets.
        drives: The registry parameters whose arrays the scene builds proportional to this value
            (``Et`` → ``spring_stiffness``; ``E`` → ``tet_mu``, ``tet_lam``): the gradient stages
            differentiate through them. Empty: derivative-free only (ν, topology).
        models: Object models whose objects have it (material and object fields); empty: every model.
        when: Which sections of those take part (see :data:`Condition`); None: every one whose field is set.
        default: The value an unset optional field starts from; None: an unset field does not take part.
        bounds: Physical (lo, hi) in its unit; None: the first driven parameter's registry bounds.
        log: Searched in log scale (a positive magnitude).
        search: The fit's box around the scene's value (:class:`Around`, :class:`UpTo`); None: ``bounds``.
        topology: Changes the springs (a derivative-free search only; no world may differ in it).
        integer: Rounded to a whole number.
        object_level: Lives in an object's own section, so candidates differing only in it can run as copies
            of one object (CMA-ES's batched generations); None: whether ``field`` is an object's.
        fit: The fit may search it (``GLOBAL``).
        per_element: (the elements, what one factor scales) when the fit's per-element stage and the live
            view may scale its arrays element by element, else None.
        default_for: Object models whose fit searches it by default, in :data:`KNOBS` order.
        why: Why it is searched by default (``pliant fit`` prints it).
        live: The live view's factor range (lo, hi) on its arrays, or for a solver value (``damping_rate``)
            its floor and the least ceiling; None: no slider.
        name: The ``--params`` name (unique); default: the field's own name.
    """

    field: str
    doc: str
    drives: tuple[str, ...] = ()
    models: tuple[str, ...] = ()
    when: Condition | None = None
    default: Default | None = None
    bounds: tuple[float, float] | None = None
    log: bool = True
    search: Callable[[float, tuple[float, float]], tuple[float, float]] | None = None
    topology: bool = False
    integer: bool = False
    object_level: bool | None = None
    fit: bool = True
    per_element: tuple[str, str] | None = None
    default_for: tuple[str, ...] = ()
    why: str = ""
    live: tuple[float, float] | None = None
    name: str = ""

    def __post_init__(self) -> None:
        if not self.name:  # named after its field unless the name says more (ground_friction)
            object.__setattr__(self, "name", self.attr)

    @property
    def attr(self) -> str:
        """The field's own name (the last part of :attr:`field`)."""
        return self.field.rpartition(".")[2]

    @property
    def section(self) -> str:
        """The path of the section holding the field (``objects[].material``, ``solver``, ...)."""
        return self.field.rpartition(".")[0]

    @property
    def on_object(self) -> bool:
        """Whether it lives in an object's own section (see :attr:`object_level`)."""
        if self.object_level is not None:
            return self.object_level
        return self.field.startswith("objects[")

    def parameters(self) -> list[Parameter]:
        """The registry declarations of :attr:`drives` (every package that declares some imported first).

        Raises:
            ParameterError: a driven name the registry does not declare.
        """
        from ..model import parameter

        _load_registry()
        return [parameter(n) for n in self.drives]

    def physical_bounds(self) -> tuple[float, float]:
        """:attr:`bounds`, or the first driven parameter's registry bounds.

        Raises:
            ValueError: neither is declared (the knob must then give ``bounds``).
        """
        if self.bounds is not None:
            return self.bounds
        for p in self.parameters():
            if p.bounds is not None:
                return p.bounds
        raise ValueError(f"pliant/scene/_knobs.py: knob {self.name!r} has no bounds; declare bounds=(lo, hi)")

    def box(self, value: float) -> tuple[float, float]:
        """The fit's search box (lo, hi) for the scene's ``value`` (:attr:`search`, else the bounds)."""
        physical = self.physical_bounds()
        return physical if self.search is None else self.search(value, physical)

    def sections(self, cfg: SceneConfig) -> list[Any]:
        """The sections of ``cfg`` that have this knob's field (before :attr:`when` and unset fields)."""
        path = self.section
        if not path.startswith("objects["):
            sec = getattr(cfg, path)
            return [] if sec is None or getattr(sec, "enabled", True) is False else [sec]
        kind, _, rest = path[len("objects[") :].partition("]")
        objs = [
            o
            for o in cfg.objects
            if (not kind or o.kind == kind) and (not self.models or o.model in self.models)
        ]
        return [o.material for o in objs] if rest == ".material" else objs

    def where(self, cfg: SceneConfig) -> list[tuple[Any, str]]:
        """``[(section, field)]``: the scene values this knob sets in ``cfg`` (all to one value). An unset
        optional field with a :attr:`default` is filled in (the search starts from it)."""
        out = []
        for sec in self.sections(cfg):
            if self.when is not None and not self.when(cfg, sec):
                continue
            if getattr(sec, self.attr) is None:
                if self.default is None:
                    continue
                setattr(sec, self.attr, self.default(cfg, sec))
            out.append((sec, self.attr))
        return out

    def to_unit(self, value: float, lo: float, hi: float) -> float:
        """Value → [0, 1] in the box [lo, hi] (log scale for :attr:`log`)."""
        import math

        if self.log:
            return (math.log(value) - math.log(lo)) / (math.log(hi) - math.log(lo))
        return (value - lo) / (hi - lo)

    def from_unit(self, u: float, lo: float, hi: float) -> float:
        """[0, 1] → value in the box [lo, hi] (rounded for :attr:`integer`)."""
        import math

        u = min(max(float(u), 0.0), 1.0)
        v = math.exp(math.log(lo) + u * (math.log(hi) - math.log(lo))) if self.log else lo + u * (hi - lo)
        return float(round(v)) if self.integer else v


#: κ [1/s²] a compliant ground's search starts from when neither the scene nor the tracks give one: the
#: stiffness that rests 2 mm deep under 9.81 m/s².
GROUND_STIFFNESS_START = 9.81 / 2.0e-3


def _load_registry() -> None:
    from .. import collision, constraints, energies, solvers  # noqa: F401  (their classes register)


def _xpbd_compliance(cfg: SceneConfig, sec: object) -> float:
    """XPBD's scene-wide compliance when unset: the first object's own, else 1e-6 m/N."""
    return next((o.material.compliance for o in cfg.objects if o.material.compliance is not None), 1e-6)


_DISSIPATION = (
    "velocity damping: the dissipation of the observed motion (air, material loss) is unknown to the scene"
)
_MS = ("mass_spring",)


#: Every knob, in the order the fit lists its default parameters (per object model: :attr:`Knob.default_for`).
def _table(knobs: list[Knob]) -> dict[str, Knob]:
    """name → knob; ValueError on a name declared twice (a dict would silently keep the last)."""
    out: dict[str, Knob] = {}
    for k in knobs:
        if k.name in out:
            raise ValueError(f"pliant/scene/_knobs.py: knob {k.name!r} is declared twice; give it one name")
        out[k.name] = k
    return out


KNOBS: dict[str, Knob] = _table(
    [
        Knob(
            "objects[].material.stiffness",
            "spring constant k of every mass-spring object [N/m]",
            ("spring_stiffness",),
            _MS,
            search=Around(10.0, 1e-6),
            per_element=("springs", "log-scale factor of each spring's k"),
            default_for=_MS,
            why="default for mass-spring: the spring stiffness",
            live=(0.1, 10.0),
        ),
        Knob(
            "objects[].material.Et",
            "membrane stiffness E·t of every mass-spring cloth given by it [N/m] (sets its structural and "
            "shear springs)",
            ("spring_stiffness",),
            _MS,
            when=lambda cfg, m: m.stiffness is None,
            search=Around(10.0, 1e-6),
            default_for=_MS,
            why="default for mass-spring cloth: the membrane stiffness",
        ),
        Knob(
            "objects[].material.bend_stiffness",
            "k of the bend springs (across two segments or cells) of every mass-spring object that has them "
            "[N/m]",
            # No `drives`: the bend springs share spring_stiffness with the others, so a gradient through
            # that array is not this knob's; CMA-ES fits it. Its bounds are spring_stiffness's, by reference.
            models=_MS,
            when=lambda cfg, m: m.bend_stiffness > 0,
            bounds=SPRING_STIFFNESS.bounds,
            # ×100: a bend spring is a crude stand-in for another engine's rod or shell bending (MuJoCo's rope
            # fits at a tenth of its converted value), so the data may put it far from the conversion.
            search=Around(100.0, 1e-6),
            # Not batched: CMA-ES's batched generations predate it and were never checked with it; batching
            # it would change the fits that search it (fit_rope).
            object_level=False,
            default_for=_MS,
            why="default for mass-spring with bend springs: the bending stiffness",
        ),
        Knob(
            "objects[].material.E",
            "Young's modulus of every FEM object [Pa]",
            ("tet_mu", "tet_lam"),
            ("fem",),
            search=Around(10.0, 1.0),
            per_element=("tetrahedra", "log-scale factor of each tet's E (μ and λ together: ν unchanged)"),
            default_for=("fem",),
            why="default for FEM: Young's modulus",
            live=(0.1, 10.0),
        ),
        Knob(
            "objects[].material.nu",
            "Poisson ratio of every FEM object",
            models=("fem",),
            bounds=(0.0, 0.49),
            log=False,
            default_for=("fem",),
            why="default for FEM: Poisson's ratio",
        ),
        Knob(
            "solver.compliance",
            "XPBD compliance α [m/N]",
            ("compliance_distance", "compliance_dihedralbending", "compliance_volume"),
            when=lambda cfg, s: cfg.solver_kind() == "xpbd",
            default=_xpbd_compliance,
            search=Around(100.0, 1e-10),
            per_element=(
                "XPBD constraints with a compliance",
                "log-scale factor of each XPBD constraint's compliance α",
            ),
            default_for=("pbd",),
            why="default for XPBD: the constraints' compliance",
            live=(0.1, 10.0),
        ),
        Knob(
            "solver.damping_rate",
            "velocity damping rate of the solver [1/s]",
            ("damping_rate",),
            default=lambda cfg, s: 0.0,
            search=Around(10.0),
            default_for=("mass_spring", "fem", "pbd"),
            why=_DISSIPATION,
            live=(0.0, 10.0),
        ),
        Knob(
            "objects[].material.damping",
            "dashpot γ along each spring of every mass-spring object [N s/m]",
            ("spring_damping",),
            _MS,
            search=Around(10.0, 1e-5),
            default_for=_MS,
            why="default for mass-spring: the dashpot along each spring (internal dissipation)",
            live=(0.0, 10.0),
        ),
        Knob(
            "ground.friction",
            "Coulomb friction μ of the ground",
            ("ground_friction",),
            log=False,
            name="ground_friction",
        ),
        Knob(
            "ground.restitution",
            "restitution e of the ground",
            ("ground_restitution",),
            log=False,
            name="ground_restitution",
        ),
        # Compliant contact (model.Ground.stiffness, damping_ratio): read when the scene is built, so
        # CMA-ES searches them (no `drives`); the fit adds them when the tracks sink into the ground
        # (pliant/fit/_params.py: COMPLIANT). κ and ζ rather than MuJoCo's (τ, ζ): the resting depth g/κ
        # depends on κ alone and the rebound on ζ alone, so the two are not traded against each other.
        Knob(
            "ground.stiffness",
            "normal stiffness κ per unit mass of compliant ground contact, resting g/κ deep [1/s²]",
            default=lambda cfg, g: GROUND_STIFFNESS_START,
            bounds=GROUND_STIFFNESS.bounds,
            # The start (g over the deepest track, :func:`pliant.fit._params.contact_start`) is a lower
            # bound: an impact sinks deeper than the body rests, so the box reaches far up (a 10 cm drop
            # sinking 1 cm is 20 × g/d) and a little down (the tracks' noise).
            search=Around(3.0, up=300.0),
            name="ground_stiffness",
        ),
        Knob(
            "ground.damping_ratio",
            "damping ratio ζ of compliant ground contact's damper b = 2ζ√κ (MuJoCo's dampratio)",
            when=lambda cfg, g: g.stiffness is not None,
            default=lambda cfg, g: 1.0,
            bounds=GROUND_DAMPING_RATIO.bounds,
            search=Around(10.0, 1e-2),
            name="ground_damping_ratio",
        ),
        Knob(
            "objects[points].radius",
            "spring radius of point-cloud objects [m] (topology)",
            default=lambda cfg, o: 1.8 * o.spacing,
            bounds=(1e-6, 1e6),
            log=False,
            search=Around(2.0),
            topology=True,
        ),
        Knob(
            "objects[points].max_neighbors",
            "most springs per point of point-cloud objects (topology)",
            default=lambda cfg, o: o.max_neighbors,
            bounds=(1.0, 1024.0),
            log=False,
            search=UpTo(2.0),
            topology=True,
            integer=True,
            name="neighbours",
        ),
        Knob(
            "objects[].mass_uniformity",
            "blend α of every object's particle masses from lumped by length, area or volume (0) to even per "
            "particle (1), the total kept",
            default=lambda cfg, o: o.mass_blend(),
            bounds=(0.0, 1.0),
            log=False,
            # Searched when the tracks cover the object (pliant/fit/_params.py: default_reasons), not by
            # model: a mass distribution shows only in motion recorded across the whole object.
            why="the tracks cover the object: how its mass is spread (lumped or even per particle)",
        ),
        *(
            Knob(
                f"objects[].mass_slope_{ax}",
                f"log-gradient a_{ax} of every object's mass density along its normalised {ax} (density "
                f"exp(a · x̂) over the rest box, x̂ ∈ [−1, 1], the total kept)",
                bounds=(-2.0, 2.0),
                log=False,
            )
            for ax in "xyz"
        ),
        Knob(
            "objects[].material.shear_stiffness",
            "k of a mass-spring cloth's shear springs [N/m] (default: stiffness)",
            models=_MS,
            bounds=SPRING_STIFFNESS.bounds,
            fit=False,
        ),
    ]
)


def knob(name: str) -> Knob:
    """The knob called ``name``; KeyError listing the knobs when there is none."""
    if name not in KNOBS:
        raise KeyError(f"unknown knob {name!r}; the knobs are {', '.join(KNOBS)}")
    return KNOBS[name]


def _declares(c: object, name: str) -> bool:
    return any(p.name == name for p in getattr(type(c), "parameters", lambda: ())())


def registry_arrays(scene: Scene, names: tuple[str, ...]) -> dict[str, Any]:
    """The arrays of registry parameters ``names`` in a built scene that hold one value per element:
    ``model.<array>`` for model arrays (when the model has such elements) and
    ``constraints.<i>.<array>`` for every constraint set of the solver (XPBD / PBD) whose class declares
    the name."""
    from ..model import registry

    _load_registry()
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
            for i, c in enumerate(getattr(scene.solver, "constraints", [])):
                a = getattr(c, attr, None)
                if a is not None and a.shape[0] and _declares(c, n):
                    out[f"constraints.{i}.{attr}"] = a
    return out


def knob_arrays(scene: Scene, k: Knob) -> dict[str, Any]:
    """The per-element arrays a built scene holds for knob ``k`` (:func:`registry_arrays` of its drives)."""
    return registry_arrays(scene, k.drives)


__all__ = ["KNOBS", "Around", "Knob", "UpTo", "knob", "knob_arrays", "registry_arrays"]
