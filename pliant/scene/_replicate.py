"""Whether a scene can be replicated into worlds, and the replication: what ``build_scene(worlds=)`` does
and what sweeps, CMA-ES generations and :func:`~pliant.scene.build_worlds` check before running together.

Below :mod:`._build` (which replicates) and :mod:`._worlds` (which builds worlds of different materials
with ``build_scene``), so that neither of those imports the other.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ._context import BuildContext
    from ._schema import SceneConfig


def coupled(cfg: SceneConfig) -> str | None:
    """Why copies of ``cfg``'s objects in one model would not move as the scene alone does (None when they
    would): handles drive particles of one copy, and self-collision would couple the copies. What sweeps,
    CMA-ES generations and worlds all require before running runs together."""
    if cfg.handles:
        return "handles drive particles of one world"
    if getattr(cfg.solver, "self_collision", None) is not None:
        return "self-collision would couple the worlds"
    return None


def worlds_unsupported(cfg: SceneConfig) -> str | None:
    """Why ``cfg`` cannot be replicated into worlds (None when it can): what would couple the worlds or
    apply to world 0 only."""
    why = coupled(cfg)
    if why is not None:
        return why
    if cfg.constraints or cfg.energies:
        return "[[constraints]] / [[energies]] entries are built for one world"
    for i, o in enumerate(cfg.objects):
        if o.kind == "cluster" or getattr(o, "render_mesh", None) is not None:
            return f"objects[{i}] ({o.kind}) keeps per-object data of world 0 only"
    return None


def replicate_scene(ctx: BuildContext, worlds: int) -> None:
    """Replicate what ``ctx.builder`` holds into ``worlds`` worlds, or raise SceneError saying why not."""
    why = worlds_unsupported(ctx.cfg)
    if why is not None:
        raise ctx.fail("objects", f"cannot build {worlds} worlds of this scene: {why}")
    ctx.builder.replicate(worlds)
