"""What a registered builder receives: the scene, the model builder, then the model and contact handlers."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from ._errors import SceneError, scene_error

if TYPE_CHECKING:
    from ..model import Model, ModelBuilder
    from ._schema import SceneConfig


@dataclass
class BuildContext:
    """State shared by the registered builders of one :func:`~pliant.scene.build_scene` call.

    Attributes:
        cfg: The validated :class:`~pliant.scene.SceneConfig`.
        builder: The ``pl.ModelBuilder`` objects add themselves to.
        ranges: ``(start, stop)`` particle range of each object, filled as objects are built.
        model: The finalized ``pl.Model`` (None while objects are being added).
        handlers: Post-step contact handlers (``Colliders``, ``SelfCollision``) for the solver.
        terms: Extra energies (spring handles, ``[[energies]]``) for force-based solvers.
        constraints: Extra constraints (clusters, self-collision, ``[[constraints]]``) for XPBD / PBD.
    """

    cfg: SceneConfig
    builder: ModelBuilder
    ranges: list[tuple[int, int]] = field(default_factory=list)
    model: Model | None = None
    handlers: list[Any] = field(default_factory=list)
    terms: list[Any] = field(default_factory=list)
    constraints: list[Any] = field(default_factory=list)

    @property
    def finalized(self) -> Model:
        """:attr:`model`, for the steps that run after it is built (a RuntimeError before: a builder bug)."""
        if self.model is None:
            raise RuntimeError("BuildContext.model is read before the model is finalized")
        return self.model

    def fail(self, path: str, msg: str) -> SceneError:
        """A SceneError for the field at dotted ``path`` (with its line in the scene file)."""
        return scene_error(self.cfg, path, msg)
