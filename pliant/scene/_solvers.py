"""The built-in solver kinds (``force``, ``fast_mass_spring``, ``xpbd``, ``pbd``), integrators by name, and
the checks of ``[solver] options`` / ``integrator_options`` against the constructors they are passed to."""

from __future__ import annotations

import difflib
import inspect
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeVar

from ._errors import SceneError, line_of
from ._registry import CONSTRAINT_KINDS, ENERGY_KINDS, SOLVER_KINDS, register_solver

if TYPE_CHECKING:
    from ..collision import SelfCollision, StepBound
    from ..integrators import Integrator
    from ..solvers import XPBD, FastMassSpring, ForceSolver
    from ._context import BuildContext
    from ._schema import SceneConfig

#: FEM material laws and the ``pliant.energies`` class each needs.
FEM_LAWS = {"neohookean": "NeoHookean", "stvk": "StVK", "corotated": "Corotated", "linear": "LinearElastic"}


# ---------------------------------------------------------------------------------------------- integrators
def integrator_names(*, system_only: bool = False) -> list[str]:
    """Integrators of ``pliant.integrators`` constructible without arguments.

    Args:
        system_only: only those that step a physical model (not ODE-only ones such as DormandPrince).
    """
    from .. import integrators

    names = []
    for n in integrators.__all__:
        obj = getattr(integrators, n, None)
        if isinstance(obj, type) and issubclass(obj, integrators.Integrator) and not inspect.isabstract(obj):
            if system_only and not getattr(obj, "supports_system", True):
                continue
            try:
                inspect.signature(obj).bind()
            except TypeError:
                continue
            names.append(n)
    return sorted(names)


def find_integrator(name: str) -> str | None:
    """The integrator class name matching ``name`` case-insensitively (``-`` and ``_`` ignored), or None."""
    names = integrator_names()
    match = next((n for n in names if n.lower() == name.lower().replace("-", "").replace("_", "")), None)
    return match or next((n for n in names if n.lower() == name.lower()), None)


def make_integrator(
    name: str, options: dict[str, Any] | None = None, *, source: str = "", path: str = "", text: str = ""
):
    """``pliant.integrators.<name>(**options)``, found case-insensitively; errors list what exists."""
    from .. import integrators

    path = path or "solver.integrator"
    match = find_integrator(name)
    if match is None:
        msg = f"unknown integrator {name!r}; available: {', '.join(integrator_names())}"
        raise SceneError(source or "<scene>", [(line_of(text, path), path, msg)])
    try:
        return getattr(integrators, match)(**(options or {}))
    except (TypeError, ValueError) as exc:
        opt = "solver.integrator_options"
        raise SceneError(source or "<scene>", [(line_of(text, opt), opt, f"{match}: {exc}")]) from None


S = TypeVar("S")  # the solver class _construct makes


# ---------------------------------------------------------------------------------------------- options
def accepted_keywords(target: Callable[..., object]) -> dict[str, inspect.Parameter]:
    """Keyword parameters of ``target`` (a class or a function); a class whose ``__init__`` takes
    ``**kwargs`` and passes them on contributes its base classes' parameters too, and where no class
    in the chain names them, the fields of its ``options_type`` dataclass (the implicit integrators)."""
    out: dict[str, inspect.Parameter] = {}
    chain = [c for c in target.__mro__ if "__init__" in vars(c)] if isinstance(target, type) else [target]
    for fn in chain:
        # fn is a class of target's MRO that defines __init__ itself (mypy's "unsound" warns of subclasses)
        params = inspect.signature(fn.__init__ if isinstance(fn, type) else fn).parameters  # type: ignore[misc]
        var_kw = False
        for p in params.values():
            if p.kind is inspect.Parameter.VAR_KEYWORD:
                var_kw = True
            elif p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD) and p.name != "self":
                out.setdefault(p.name, p)
        if not var_kw:
            break
    else:
        # ``**options`` all the way down: a class may name the dataclass those options fill.
        options_type = getattr(target, "options_type", None)
        if options_type is not None:
            for p in inspect.signature(options_type).parameters.values():
                out.setdefault(p.name, p)
    return out


def _type_problem(p: inspect.Parameter, value: object) -> str | None:
    """What is wrong with ``value`` for parameter ``p``, judged from its default (cheap, not exhaustive)."""
    d = p.default
    if d is None:  # judge by the annotation's first type ("float | None" -> float)
        first = str(p.annotation).split("|")[0].strip()
        d = {"float": 0.0, "int": 0, "bool": False, "str": ""}.get(first)
    if d is inspect.Parameter.empty or d is None:
        return None
    if isinstance(d, bool):
        ok = isinstance(value, bool) or (isinstance(value, str) and "str" in str(p.annotation))
        return None if ok else f"expected true or false, got {value!r}"
    if isinstance(d, int):
        return (
            None
            if isinstance(value, int) and not isinstance(value, bool)
            else f"expected an integer, got {value!r}"
        )
    if isinstance(d, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return f"expected a number, got {value!r}"
        return None if abs(value) <= 1e30 else f"expected a finite number of magnitude <= 1e30, got {value!r}"
    if isinstance(d, str):
        return None if isinstance(value, str) else f"expected a string, got {value!r}"
    if isinstance(d, (tuple, list)) and not isinstance(value, list):
        return f"expected a list, got {value!r}"
    return None


def _moved(target: object, key: str) -> str | None:
    """Where option ``key`` of ``target`` went, when its options dataclass says (``options_type.moved``:
    the implicit integrators' former minimiser settings), else None."""
    moved = getattr(getattr(target, "options_type", None), "moved", None)
    return moved([key]) if moved is not None else None


def check_options(
    options: dict[str, Any], target: Any, at: str, what: str, reserved: tuple[str, ...] = ()
) -> list[tuple[str, str]]:
    """Problems ``(path, message)`` of keyword ``options`` passed to ``target`` (named ``what``)."""
    accepted = accepted_keywords(target)
    allowed = sorted(k for k in accepted if k not in reserved and k not in ("model", "self"))
    out = []
    for key, value in options.items():
        if key in reserved or key == "model":
            out.append((f"{at}.{key}", f"{key!r} is set by the scene itself, not through {at}; remove it"))
        elif key not in accepted and _moved(target, key):
            out.append((f"{at}.{key}", str(_moved(target, key))))
        elif key not in accepted:
            near = difflib.get_close_matches(str(key), allowed, n=1)
            hint = f"did you mean {near[0]!r}? " if near else ""
            out.append(
                (
                    f"{at}.{key}",
                    f"{what} has no option {key!r}; {hint}allowed: {', '.join(allowed) or 'none'}",
                )
            )
        else:
            msg = _type_problem(accepted[key], value)
            if msg is not None:
                out.append((f"{at}.{key}", msg))
    return out


def check_solver(cfg: SceneConfig) -> list[tuple[str, str]]:
    """Load-time checks of ``[solver]``: its kind, fields that apply to it, integrator and option names."""
    from .. import integrators

    s = cfg.solver
    out: list[tuple[str, str]] = []
    kind = cfg.solver_kind()
    sk = SOLVER_KINDS.get(kind)
    if sk is None:
        return [("solver.kind", f"got {kind!r}; allowed: {', '.join(SOLVER_KINDS)}")]
    common = {"kind", "options"}
    for f in sorted(s.model_fields_set - common):
        if f not in sk.fields and getattr(s, f) not in (None, {}):
            users = [n for n, k in SOLVER_KINDS.items() if f in k.fields]
            out.append(
                (
                    f"solver.{f}",
                    f"does not apply to solver kind {kind!r} (used by: {', '.join(users) or 'none'}); "
                    "remove it or change [solver] kind",
                )
            )
    if sk.target is not None:
        out += check_options(s.options, sk.target, "solver.options", sk.name, sk.reserved)
    if sk.uses_integrator:
        match = find_integrator(s.integrator)
        if match is not None:
            cls = getattr(integrators, match)
            if not getattr(cls, "supports_system", True):
                out.append(
                    (
                        "solver.integrator",
                        f"{match} integrates ODEs only (adaptive steps), not a physical scene; "
                        "use RK4 or an implicit integrator",
                    )
                )
            out += check_options(s.integrator_options, cls, "solver.integrator_options", match)
    for section, reg in (("energies", ENERGY_KINDS), ("constraints", CONSTRAINT_KINDS)):
        entries = getattr(cfg, section)
        if entries and section == "energies" and kind != "force":
            out.append((f"{section}[0]", 'extra energies need solver kind "force"'))
        if entries and section == "constraints" and kind not in ("xpbd", "pbd"):
            out.append((f"{section}[0]", 'extra constraints need solver kind "xpbd" or "pbd"'))
        for i, e in enumerate(entries):
            k = reg.get(e.kind)
            if k is None:
                out.append((f"{section}[{i}].kind", f"unknown kind {e.kind!r}; allowed: {', '.join(reg)}"))
            else:
                out += check_options(e.options(), k.factory, f"{section}[{i}]", e.kind)
    return out


# ---------------------------------------------------------------------------------------------- factories
def _self_collision(ctx: BuildContext) -> list[SelfCollision]:
    """The force-based solvers' self-collision handler of ``[solver] self_collision``, if any."""
    from ..collision import SelfCollision

    sc = ctx.cfg.solver.self_collision
    if sc is None:
        return []
    try:
        return [
            SelfCollision(
                ctx.finalized,
                thickness=sc.thickness,
                friction=sc.friction,
                iterations=sc.iterations,
                particles=sc.particles,
                triangles=sc.triangles,
                bound=sc.bound,
            )
        ]
    except ValueError as exc:
        raise ctx.fail("solver.self_collision", str(exc)) from None


def _step_bound(ctx: BuildContext) -> list[StepBound]:
    """XPBD / PBD's step bound of ``[solver] self_collision.bound`` (their self-contact is constraints)."""
    from ..collision import StepBound

    sc = ctx.cfg.solver.self_collision
    if sc is None or sc.bound is None:
        return []
    try:
        return [
            StepBound(
                ctx.finalized,
                fraction=sc.bound,
                reach=sc.thickness,
                separation=sc.thickness,
                friction=sc.friction,
            )
        ]
    except ValueError as exc:
        raise ctx.fail("solver.self_collision.bound", str(exc)) from None


def _construct(ctx: BuildContext, cls: type[S], *args: Any, **kwargs: Any) -> S:
    """``cls(*args, **kwargs, **options)``; a refusal of the constructor names ``[solver] options``."""
    try:
        return cls(*args, **kwargs, **ctx.cfg.solver.options)
    except (TypeError, ValueError) as exc:
        raise ctx.fail("solver.options", f"{cls.__name__}: {exc}") from None


def make_force(ctx: BuildContext) -> ForceSolver:
    """``pl.solvers.ForceSolver``: mass-spring (+ FEM) energies, an integrator of ``pl.integrators``."""
    from .. import energies, solvers

    cfg, s = ctx.cfg, ctx.cfg.solver
    terms = list(energies.mass_spring())
    fem = [o for o in cfg.objects if o.model == "fem"]
    if fem:
        terms.append(getattr(energies, FEM_LAWS[fem[0].material.law])())
    terms += ctx.terms
    integrator = make_integrator(s.integrator, s.integrator_options, source=cfg.source, text=cfg.text)
    # A stated [ground] stiffness reaches the model's ground (compliant contact): ForceSolver then adds its
    # GroundPenalty, explicit or implicit (docs/design.md).
    barriers, handlers, self_collision = _barrier_contact(ctx, integrator)
    return _construct(
        ctx,
        solvers.ForceSolver,
        ctx.model,
        terms + barriers,
        integrator,
        velocity_damping=s.velocity_damping,
        damping_rate=s.damping_rate,
        collisions=handlers + self_collision,
    )


def _barrier_contact(ctx: BuildContext, integrator: Integrator) -> tuple[list, list, list]:
    """(barrier energies, post-step handlers, self-collision handlers) of ``contact = "barrier"`` on
    ``[ground]`` (the ground and the colliders) and ``[solver.self_collision]``: barrier contact replaces
    the post-step response of what it covers."""
    from .. import energies
    from ..collision import Colliders

    g, sc = ctx.cfg.ground, ctx.cfg.solver.self_collision
    on_ground = g is not None and g.contact == "barrier"
    on_self = sc is not None and sc.contact == "barrier"
    if not (on_ground or on_self):
        return [], ctx.handlers, _self_collision(ctx)
    where = "ground.contact" if on_ground else "solver.self_collision.contact"
    if integrator.explicit:
        raise ctx.fail(
            where, f'"barrier" needs an implicit integrator (e.g. BackwardEuler), not {integrator.name}'
        )
    out, handlers = [], list(ctx.handlers)
    if on_ground:
        assert g is not None
        cols = [h for h in handlers if isinstance(h, Colliders)]
        handlers = [h for h in handlers if not isinstance(h, Colliders)]
        mus = [g.friction] + [c.friction for c in ctx.cfg.colliders]
        out.append(
            energies.BarrierContact(
                dhat=g.dhat,
                kappa=g.kappa,
                ground=g.enabled,
                colliders=cols[0] if cols else None,
                friction=max(mus) > 0,
                stick_velocity=g.stick_velocity if g.stick_velocity > 0 else None,
            )
        )
    if on_self:
        assert sc is not None
        out.append(
            energies.BarrierContact(
                dhat=sc.thickness, kappa=sc.kappa, ground=False, self_contact=True, self_friction=sc.friction
            )
        )
    return out, handlers, [] if on_self else _self_collision(ctx)


def _refuse_barrier(ctx: BuildContext, solver: str) -> None:
    """A SceneError when ``contact = "barrier"`` is asked of a solver that does not minimise a potential."""
    g, sc = ctx.cfg.ground, ctx.cfg.solver.self_collision
    for on, where in (
        (g is not None and g.contact == "barrier", "ground.contact"),
        (sc is not None and sc.contact == "barrier", "solver.self_collision.contact"),
    ):
        if on:
            raise ctx.fail(
                where, f'"barrier" contact needs the force solver with an implicit integrator, not {solver}'
            )


def make_fast_mass_spring(ctx: BuildContext) -> FastMassSpring:
    """``pl.solvers.FastMassSpring``: the specialised mass-spring path (``options.method``)."""
    from .. import solvers

    _refuse_barrier(ctx, "FastMassSpring")
    s = ctx.cfg.solver
    return _construct(
        ctx,
        solvers.FastMassSpring,
        ctx.model,
        velocity_damping=s.velocity_damping,
        damping_rate=s.damping_rate,
        collisions=ctx.handlers + _self_collision(ctx),
    )


def _xpbd_compliance(cfg: SceneConfig) -> float | None:
    compliance = cfg.solver.compliance
    if compliance is None:
        compliance = next(
            (o.material.compliance for o in cfg.objects if o.material.compliance is not None), None
        )
    if compliance is None and any(o.material.stiffness is None for o in cfg.objects if o.kind != "cluster"):
        compliance = 0.0  # no stiffness given: rigid distance constraints (XPBD would use α = 1/k)
    return compliance


def _position_based(ctx: BuildContext, cls: type[XPBD], **kw: Any) -> XPBD:
    """XPBD / PBD with the scene's iterations, damping, contact handlers and extra constraints."""
    _refuse_barrier(ctx, cls.__name__)
    s = ctx.cfg.solver
    kw = {"iterations": s.iterations, "damping": s.damping_rate, **kw}
    kw = {k: v for k, v in kw.items() if v is not None}
    solver = _construct(ctx, cls, ctx.model, collisions=ctx.handlers + _step_bound(ctx), **kw)
    if ctx.constraints:
        _insert(solver, ctx)
    return solver


def _insert(solver: XPBD, ctx: BuildContext) -> None:
    """Put the scene's extra constraints before the solver's contact constraints (those run last and get
    extra sweeps), found by ``is_contact`` rather than assumed to be the last entry."""
    at = next((k for k, c in enumerate(solver.constraints) if c.is_contact), len(solver.constraints))
    for c in ctx.constraints:
        c.bind(ctx.model, solver.coloring)
    solver.constraints[at:at] = ctx.constraints
    solver.reset_plans()


def make_xpbd(ctx: BuildContext) -> XPBD:
    """``pl.solvers.XPBD`` (compliance α from ``[solver]`` or the objects' materials)."""
    from .. import solvers

    return _position_based(ctx, solvers.XPBD, compliance=_xpbd_compliance(ctx.cfg))


def make_pbd(ctx: BuildContext) -> XPBD:
    """``pl.solvers.PBD`` (dimensionless ``stiffness_factor`` k ∈ [0, 1])."""
    from .. import solvers

    return _position_based(ctx, solvers.PBD, stiffness=ctx.cfg.solver.stiffness_factor)


def _register_builtins() -> None:
    from .. import solvers

    force_fields = ("integrator", "integrator_options", "velocity_damping", "damping_rate", "self_collision")
    register_solver(
        "force",
        make_force,
        target=solvers.ForceSolver,
        models=("mass_spring", "fem"),
        fields=force_fields,
        reserved=("energies", "integrator", "velocity_damping", "damping_rate", "collisions"),
        uses_integrator=True,
    )
    register_solver(
        "fast_mass_spring",
        make_fast_mass_spring,
        target=solvers.FastMassSpring,
        models=("mass_spring",),
        fields=("velocity_damping", "damping_rate", "self_collision"),
        reserved=("velocity_damping", "damping_rate", "collisions"),
    )
    pb_reserved = ("iterations", "damping", "collisions", "constraints")
    register_solver(
        "xpbd",
        make_xpbd,
        target=solvers.XPBD,
        models=("pbd",),
        fields=("iterations", "damping_rate", "compliance", "self_collision"),
        reserved=(*pb_reserved, "compliance"),
    )
    register_solver(
        "pbd",
        make_pbd,
        target=solvers.PBD,
        models=("pbd",),
        fields=("iterations", "damping_rate", "stiffness_factor", "self_collision"),
        reserved=(*pb_reserved, "stiffness"),
    )


_register_builtins()
