"""Scenes as worlds: several configurations of one scene that differ only in material parameters, built as
one model of replicated worlds (``ModelBuilder.replicate``) with each world's parameters set
(``Model.set_world_parameter``) before the solver is made. What ``pliant sweep`` batches such runs with.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..model import WORLD_PARAMETERS, ModelBuilder
from ._build import _add_objects, _finalize, _select_handles, build_scene
from ._context import BuildContext
from ._errors import scene_error
from ._knobs import KNOBS
from ._replicate import worlds_unsupported

if TYPE_CHECKING:
    from ..model import Model
    from ._build import Scene
    from ._schema import SceneConfig

#: Model arrays a world may have of its own (set with ``Model.set_world_parameter``).
WORLD_ARRAYS = tuple(WORLD_PARAMETERS)
#: Model arrays every world must share exactly (topology, rest shape, initial state, contact radii).
_SHARED = (
    "particle_q",
    "particle_qd",
    "particle_radius",
    "spring_indices",
    "tri_indices",
    "tet_indices",
    "tet_rest_inv",
    "tet_rest_volume",
    "bending_indices",
    "bending_rest_angle",
)
#: Material fields that change only the model's per-element arrays (others pick laws or solver settings): the
#: material knobs that leave the topology alone (:data:`pliant.scene._knobs.KNOBS`).
MATERIAL_FIELDS = tuple(
    k.attr for k in KNOBS.values() if k.section == "objects[].material" and not k.topology
)


def material_only(run: Sequence[str]) -> bool:
    """True when every ``PATH=V`` override of ``run`` sets one of :data:`MATERIAL_FIELDS` of an object."""
    for o in run:
        path = o.partition("=")[0].strip()
        head, _, field = path.rpartition(".")
        if not (head.startswith("objects[") and head.endswith("].material") and field in MATERIAL_FIELDS):
            return False
    return True


def _model_of(cfg: SceneConfig, device: str | None, dtype: str | None) -> Model:
    ctx = BuildContext(cfg, ModelBuilder(gravity=cfg.scene.gravity))
    _add_objects(ctx)
    _select_handles(ctx)
    _finalize(ctx, device, dtype)
    return ctx.finalized


def build_worlds(cfgs: Sequence[SceneConfig], device: str | None = None, dtype: str | None = None) -> Scene:
    """One :class:`~pliant.scene.Scene` whose model holds ``len(cfgs)`` worlds: world w is ``cfgs[w]``.

    Each configuration's model is built alone first (no solver); they must agree in everything but the
    arrays of :data:`WORLD_ARRAYS` (same objects, topology, rest shape, initial state), and world w then
    gets ``cfgs[w]``'s values of those arrays, set before the solver is made (so solvers that precompute
    from them see each world's own). The solver and the rest of the scene are ``cfgs[0]``'s.

    Args:
        cfgs: validated scenes (:func:`~pliant.scene.load_scene`), differing only in material values.
        device: Warp device; None: the file's.
        dtype: ``"float32"`` or ``"float64"``; None: the file's.

    Raises:
        SceneError: the configurations differ in more than those arrays, or the scene cannot be
            replicated (handles, self-collision, clusters, render meshes, extra constraints or energies).
    """
    base = cfgs[0]
    why = worlds_unsupported(base)
    if why is not None:
        raise scene_error(base, "objects", f"cannot build worlds of this scene: {why}")
    models = [_model_of(c, device, dtype) for c in cfgs]
    m0 = models[0]
    # World 0's arrays once, not once per world.
    shared0 = {name: getattr(m0, name).numpy() for name in _SHARED}
    own0 = {name: getattr(m0, name).numpy() for name in WORLD_ARRAYS}
    pinned0 = m0.particle_inv_mass.numpy() == 0
    params: list[dict[str, np.ndarray]] = []
    for w, m in enumerate(models):
        for name, a in shared0.items():
            b = getattr(m, name).numpy()
            if a.shape != b.shape or not np.array_equal(a, b):
                raise scene_error(base, "objects", f"world {w}: {name} differs from world 0")
        if not np.array_equal(pinned0, m.particle_inv_mass.numpy() == 0):
            raise scene_error(base, "objects", f"world {w}: the pinned particles differ from world 0's")
        own = {}
        for name, a in own0.items():
            b = getattr(m, name).numpy()
            if not np.array_equal(a, b):
                # Masses as the builder had them (float64), so inverse masses round as they do alone.
                own[name] = m.particle_mass_np if name == "particle_mass" else b
        params.append(own)
    return build_scene(base, device, dtype, worlds=len(cfgs), world_parameters=params)
