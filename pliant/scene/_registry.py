"""Registries of what a scene file can name: object, collider and handle kinds, solver kinds, and the
energies and constraints of ``[[energies]]`` / ``[[constraints]]``.

A new kind is one registered function (plus its schema when it has fields of its own)::

    class Blob(pl.scene.ObjectBase):
        kind: Literal["blob"]
        radius: float = 0.1

    def build_blob(ctx, obj, index):
        ctx.builder.add_particles(...)

    pl.scene.register_object_kind("blob", Blob, build_blob)

Registering rebuilds :class:`~pliant.scene.SceneConfig`'s tagged unions, so the new kind is validated with
the same ``file:line: field: ...`` messages as the built-in ones.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Annotated, Any, Union

from pydantic import BaseModel, Field

from ._schema import ColliderBase, ObjectBase, SceneConfig

if TYPE_CHECKING:
    from ._schema import HandleConfig


@dataclass(frozen=True)
class ObjectKind:
    """An ``[[objects]]`` kind.

    Attributes:
        name: The ``kind = "..."`` tag.
        schema: Its pydantic model (a subclass of :class:`ObjectBase` with ``kind: Literal[name]``).
        build: ``build(ctx, obj, index)`` adds the object to ``ctx.builder`` (a ``pl.ModelBuilder``) and
            registers it there (``add_*`` methods do, or ``builder.register_object``); raises ``ValueError``
            with the reason (reported with the object's field path).
        check: ``check(cfg, obj, at) -> [(path, message)]``: cross-field rules at load time (optional).
        particles: ``particles(cfg, obj) -> float``: an upper estimate of the particles it creates, computed
            from the schema before anything is allocated (for the memory budget; optional).
        volumetric: It is a tet mesh (may use ``model = "fem"``).
    """

    name: str
    schema: type[BaseModel]
    build: Callable[..., None]
    check: Callable[..., list[tuple[str, str]]] | None = None
    particles: Callable[..., float] | None = None
    volumetric: bool = False


@dataclass(frozen=True)
class ColliderKind:
    """A ``[[colliders]]`` kind: ``add(colliders, cfg, c) -> (vertices, faces) | None`` adds it to a
    ``pl.collision.Colliders`` and returns the triangle mesh to draw (or None when it has none)."""

    name: str
    schema: type[BaseModel]
    add: Callable[..., Any]


@dataclass(frozen=True)
class HandleKind:
    """A ``[[handles]]`` kind: ``select(ctx, handle, lo, hi, index) -> (indices | None, points)`` picks the
    particles it grabs (global indices, for kinematic handles) or the control points [m] (spring handles);
    ``check(cfg, handle, at) -> [(path, message)]`` are its load-time rules."""

    name: str
    select: Callable[..., Any]
    check: Callable[..., list[tuple[str, str]]] | None = None
    default_mode: str = "kinematic"


@dataclass(frozen=True)
class SolverKind:
    """A ``[solver] kind``.

    Attributes:
        name: The ``kind = "..."`` tag.
        factory: ``factory(ctx) -> Solver`` builds the solver from a :class:`~pliant.scene.BuildContext`
            (model, handlers, the validated ``[solver]`` section).
        target: The constructor ``[solver] options`` are passed to (its signature checks their names).
        models: The object ``model``s it can simulate.
        fields: ``[solver]`` fields it reads (others that are set are rejected as not applying to it).
        reserved: Constructor arguments the factory sets itself (rejected in ``options``).
        uses_integrator: Whether ``[solver] integrator`` applies.
    """

    name: str
    factory: Callable[..., Any]
    target: Callable[..., Any] | None = None
    models: tuple[str, ...] = ("mass_spring",)
    fields: tuple[str, ...] = ()
    reserved: tuple[str, ...] = ()
    uses_integrator: bool = False


@dataclass(frozen=True)
class TermKind:
    """An ``[[energies]]`` / ``[[constraints]]`` kind: ``factory(model, **options)`` returns the
    ``pl.energies.Energy`` / ``pl.constraints.Constraint``; options are checked against its signature."""

    name: str
    factory: Callable[..., Any]
    solvers: tuple[str, ...] = field(default=())


@dataclass(frozen=True)
class SectionKind:
    """An optional top-level section (``[name]``) added to :class:`SceneConfig` by a module above the core
    schema: ``schema`` validates it (``cfg.<name>`` is None when absent) and ``check(cfg, section) ->
    [(path, message)]`` holds its cross-field rules (run at load time, like the built-in ones)."""

    name: str
    schema: type[BaseModel]
    check: Callable[..., list[tuple[str, str]]] | None = None


OBJECT_KINDS: dict[str, ObjectKind] = {}
SECTIONS: dict[str, SectionKind] = {}
COLLIDER_KINDS: dict[str, ColliderKind] = {}
HANDLE_KINDS: dict[str, HandleKind] = {}
SOLVER_KINDS: dict[str, SolverKind] = {}
ENERGY_KINDS: dict[str, TermKind] = {}
CONSTRAINT_KINDS: dict[str, TermKind] = {}


def _check_schema(name: str, schema: type[BaseModel], base: type[BaseModel]) -> None:
    if not (isinstance(schema, type) and issubclass(schema, base)):
        raise TypeError(f"the schema of kind {name!r} must subclass pliant.scene.{base.__name__}")
    tag = schema.model_fields.get("kind")
    if tag is None or getattr(tag.annotation, "__args__", None) != (name,):
        raise TypeError(f'the schema of kind {name!r} must declare kind: Literal["{name}"]')


def _rebuild() -> None:
    """Put the registered object and collider schemas into SceneConfig's tagged unions."""
    for section, kinds in (("objects", OBJECT_KINDS), ("colliders", COLLIDER_KINDS)):
        schemas = tuple(k.schema for k in kinds.values())
        if not schemas:
            continue
        # A Union of a run-time tuple: pydantic reads it, mypy cannot (it wants a static type).
        union = Annotated[Union[schemas], Field(discriminator="kind")]  # type: ignore[valid-type]  # noqa: UP007
        SceneConfig.model_fields[section].annotation = list[union]
    SceneConfig.model_rebuild(force=True)


def register_object_kind(
    name: str,
    schema: type[BaseModel],
    build: Callable[..., None],
    *,
    check: Callable[..., list[tuple[str, str]]] | None = None,
    particles: Callable[..., float] | None = None,
    volumetric: bool = False,
) -> None:
    """Make ``kind = name`` an ``[[objects]]`` kind (see :class:`ObjectKind` for the arguments)."""
    _check_schema(name, schema, ObjectBase)
    OBJECT_KINDS[name] = ObjectKind(name, schema, build, check, particles, volumetric)
    _rebuild()


def register_collider_kind(name: str, schema: type[BaseModel], add: Callable[..., Any]) -> None:
    """Make ``kind = name`` a ``[[colliders]]`` kind (see :class:`ColliderKind`)."""
    _check_schema(name, schema, ColliderBase)
    COLLIDER_KINDS[name] = ColliderKind(name, schema, add)
    _rebuild()


def register_section(
    name: str, schema: type[BaseModel], *, check: Callable[..., list[tuple[str, str]]] | None = None
) -> None:
    """Make ``[name]`` an optional scene-file section validated by ``schema`` (see :class:`SectionKind`)."""
    from pydantic.fields import FieldInfo

    if name in SceneConfig.model_fields and name not in SECTIONS:
        raise ValueError(f"[{name}] is a built-in scene section")
    SECTIONS[name] = SectionKind(name, schema, check)
    # A Union of a run-time class: pydantic reads it; mypy wants a static type (a special form is no type[]).
    optional = Union[schema, None]  # type: ignore[valid-type]  # noqa: UP007
    SceneConfig.model_fields[name] = FieldInfo.from_annotated_attribute(optional, None)  # type: ignore[arg-type]
    SceneConfig.model_rebuild(force=True)


def register_handle_kind(
    name: str,
    select: Callable[..., Any],
    *,
    check: Callable[..., list[tuple[str, str]]] | None = None,
    default_mode: str = "kinematic",
) -> None:
    """Make ``kind = name`` a ``[[handles]]`` kind (see :class:`HandleKind`)."""
    HANDLE_KINDS[name] = HandleKind(name, select, check, default_mode)


def handle_mode(handle: HandleConfig) -> str:
    """A ``[[handles]]`` entry's ``mode``, or its kind's default (``"kinematic"`` for an unknown kind).

    A function of the registry rather than a method of the schema: the schema sits below the registry.
    """
    kind = HANDLE_KINDS.get(handle.kind)
    return handle.mode or (kind.default_mode if kind is not None else "kinematic")


def register_solver(
    name: str,
    factory: Callable[..., Any],
    *,
    target: Callable[..., Any] | None = None,
    models: tuple[str, ...] = ("mass_spring",),
    fields: tuple[str, ...] = (),
    reserved: tuple[str, ...] = (),
    uses_integrator: bool = False,
) -> None:
    """Make ``[solver] kind = name`` build ``factory(ctx)`` (see :class:`SolverKind`)."""
    SOLVER_KINDS[name] = SolverKind(
        name, factory, target, tuple(models), tuple(fields), tuple(reserved), uses_integrator
    )


def register_energy(name: str, factory: Callable[..., Any]) -> None:
    """Make ``[[energies]] kind = name`` add ``factory(model, **options)`` to a force-based solver."""
    ENERGY_KINDS[name] = TermKind(name, factory)


def register_constraint(name: str, factory: Callable[..., Any]) -> None:
    """Make ``[[constraints]] kind = name`` add ``factory(model, **options)`` to an XPBD / PBD solver."""
    CONSTRAINT_KINDS[name] = TermKind(name, factory)


def kind_names(section: str) -> tuple[str, ...]:
    """The registered kinds of ``section`` (objects, colliders, handles, solver, energies, constraints)."""
    registries: dict[str, Mapping[str, object]] = {
        "objects": OBJECT_KINDS,
        "colliders": COLLIDER_KINDS,
        "handles": HANDLE_KINDS,
        "solver": SOLVER_KINDS,
        "energies": ENERGY_KINDS,
        "constraints": CONSTRAINT_KINDS,
    }
    return tuple(registries[section])
