"""The Gaussians of a scene: its ``[gaussians]`` section's (load or generate the splats, bind them to the
object; the scene layer only validates the section), or, without one, Gaussians generated from the model's
surface (:func:`scene_gaussians` decides; ``pliant run``, ``pliant observe --cameras`` and the photometric
fit all call it or :func:`scene_splats`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from ._bind import Binding, bind
from ._camera import Camera
from ._gaussians import Gaussians
from ._ply import PlyError, load_ply
from ._render import RenderOutput, render
from ._surface import (
    GENERATED_BACKGROUND,
    object_surface,
    particle_splats,
    surface_gaussians,
    triangle_splats,
)

if TYPE_CHECKING:
    from ..model import Model
    from ..scene import GaussiansSection, Scene, SceneConfig


class SplatSceneError(ValueError):
    """A ``[gaussians]`` section that cannot be built; the message names the scene file and the field."""


@dataclass
class SceneSplats:
    """Splats bound to one object of a built scene.

    Attributes:
        binding: The binding (its particles are the object's, in local indices ``0 .. hi - lo``).
        lo: The object's first particle in the model.
        hi: One past its last particle.
        background: RGB behind the splats.
        light: Shading (ambient, Lx, Ly, Lz, headlight) of :func:`pliant.gaussians.render`, or None (unlit).
    """

    binding: Binding
    lo: int
    hi: int
    background: tuple[float, float, float]
    light: tuple[float, ...] | None = None

    def place(self, x: wp.array | np.ndarray) -> Gaussians:
        """The splats for model positions ``x`` [m] (NumPy [N, 3] of the whole model, or a Warp array)."""
        b = self.binding
        if isinstance(x, wp.array):
            # a view (its gradient is the same view of x.grad), or x itself when the object is the model
            q = x if (self.lo, self.hi) == (0, x.shape[0]) else x[self.lo : self.hi]
        else:
            from .._warp import np_dtype, vec3_type

            dtype = b.gaussians.dtype
            q = wp.array(
                np.asarray(x)[self.lo : self.hi].astype(np_dtype(dtype)),
                dtype=vec3_type(dtype),
                device=b.gaussians.device,
            )
        return b.deform(q)

    def render(self, x: wp.array | np.ndarray, camera: Camera) -> RenderOutput:
        """Colour, alpha and depth of the splats at model positions ``x`` seen by ``camera`` (differentiable
        w.r.t. a Warp ``x`` under ``wp.Tape``)."""
        return render(self.place(x), camera, self.background, light=self.light)

    def image(self, x: wp.array | np.ndarray, camera: Camera) -> np.ndarray:
        """RGB image [H, W, 3] in [0, 1] of the object at model positions ``x`` seen by ``camera``."""
        return self.render(x, camera).colour.numpy()


def _fail(cfg: SceneConfig, field: str, msg: str) -> SplatSceneError:
    return SplatSceneError(f"{cfg.source}: {field}: {msg}")


def _object_range(cfg: SceneConfig, model: Model, index: int) -> tuple[int, int]:
    name = cfg.object_names()[index]
    rec = next((o for o in model.objects if o["name"] == name), None)
    if rec is None:  # objects registered in file order
        rec = model.objects[index]
    return int(rec["start"]), int(rec["start"] + rec["count"])


def _generate(spec: GaussiansSection, X: np.ndarray, faces: np.ndarray, dtype: str, device: str) -> Gaussians:
    """One flat splat per surface triangle (or one round splat per particle when there is no surface),
    coloured ``color`` or in a checker of ``color`` / ``color2``."""
    if len(faces):
        # σ = scale · half a triangle leg
        centre, scales, quats = triangle_splats(X, faces, size=0.5 * spec.scale)
    else:
        centre, scales, quats = X, particle_splats(X, size=0.5 * spec.scale), None
    colours = np.tile(np.asarray(spec.color, dtype=np.float64), (len(centre), 1))
    if spec.checker > 0:
        odd = np.floor(centre / spec.checker).astype(np.int64).sum(axis=1) % 2 == 1
        colours[odd] = spec.color2
    return Gaussians.from_values(
        centre,
        scales=scales,
        rotations=quats,
        opacities=spec.opacity,
        colors=colours,
        dtype=dtype,
        device=device,
    )


def gaussians_section(cfg: SceneConfig) -> GaussiansSection | None:
    """The scene's ``[gaussians]`` section, or None: a section that pliant/scene/_gaussians.py registers, so
    not a field that SceneConfig declares (a type checker cannot see it as an attribute)."""
    return getattr(cfg, "gaussians", None)


def scene_splats(cfg: SceneConfig, scene: Scene) -> SceneSplats:
    """Build the ``[gaussians]`` splats of a built ``scene`` (its config ``cfg``) and bind them.

    Raises:
        SplatSceneError: the PLY cannot be read or lacks properties, or the binding does not fit the
            object (no triangles, no tets); the message names the scene file and the field.
    """
    from ..scene import object_index

    spec = gaussians_section(cfg)
    if spec is None:
        raise _fail(cfg, "gaussians", "the scene has no [gaussians] section")
    model = scene.model
    index = object_index(cfg, spec)
    if index is None:  # the scene's own checks reject this first; a hand-made config may skip them
        raise _fail(cfg, "gaussians.object", f"no object {spec.object!r} in this scene")
    lo, hi = _object_range(cfg, model, index)
    X = model.particle_q_np[lo:hi].astype(np.float64)
    surface = object_surface(model)
    faces = np.zeros((0, 3), dtype=np.int64) if surface is None else surface.astype(np.int64)
    faces = faces[np.all((faces >= lo) & (faces < hi), axis=1)] - lo
    tets = np.asarray(model.tet_indices_np, dtype=np.int64).reshape(-1, 4)
    tets = tets[np.all((tets >= lo) & (tets < hi), axis=1)] - lo
    dtype, device = model.dtype, model.device
    if spec.ply is not None:
        from ..scene import scene_path

        path = scene_path(cfg, spec.ply, "gaussians.ply")
        try:
            g = load_ply(path).copy(dtype=dtype, device=device)
        except (PlyError, OSError) as exc:
            raise _fail(cfg, "gaussians.ply", str(exc)) from None
    else:
        try:
            g = _generate(spec, X, faces, dtype, device)
        except ValueError as exc:
            raise _fail(cfg, "gaussians.generate", str(exc)) from None
    method = spec.bind
    if method is None:
        method = "barycentric" if len(tets) else ("triangles" if len(faces) and spec.ply is None else "lbs")
    if method == "triangles" and not len(faces):
        raise _fail(
            cfg, "gaussians.bind", f"'triangles' needs a surface, but objects[{index}] has no triangles"
        )
    if method == "barycentric" and not len(tets):
        raise _fail(cfg, "gaussians.bind", f"'barycentric' needs tets, but objects[{index}] has none")
    try:
        b = bind(
            g,
            X,
            method=method,
            k=spec.k,
            neighbours=spec.neighbours,
            tets=tets if method == "barycentric" else None,
            triangles=faces if method == "triangles" else None,
            clusters=[np.arange(hi - lo)] if method == "rigid" else None,
        )
    except ValueError as exc:
        raise _fail(cfg, "gaussians.bind", str(exc)) from None
    light = None if spec.light is None else tuple(float(v) for v in spec.light)
    bg = spec.background
    return SceneSplats(b, lo, hi, (float(bg[0]), float(bg[1]), float(bg[2])), light)


def scene_gaussians(scene: Scene, *, per_triangle: int = 1) -> SceneSplats:
    """The Gaussians that draw a built ``scene`` (the one place that decides which): its ``[gaussians]``
    section's (:func:`scene_splats`) when it has one, else Gaussians generated deterministically from the
    whole model's surface on a black background (:func:`pliant.gaussians._surface.surface_gaussians`).

    Used by ``pliant observe --cameras`` and the photometric fit, so that both draw the same splats.

    Args:
        scene: A built scene (``pl.scene.build_scene``); its ``config`` carries the section.
        per_triangle: Generated Gaussians per surface triangle (1 or 3) of a scene *without* a section.

    Raises:
        SplatSceneError: the section cannot be built (see :func:`scene_splats`), or ``per_triangle`` != 1
            with a section (its splats are the section's).
    """
    cfg = scene.config
    if gaussians_section(cfg) is not None:
        if per_triangle != 1:
            raise SplatSceneError(
                f"{cfg.source}: gaussians: per_triangle = {per_triangle} applies to generated surface "
                "splats; this scene's [gaussians] section defines its own (remove the section or the option)"
            )
        return scene_splats(cfg, scene)
    m = scene.model
    _, binding = surface_gaussians(
        m.particle_q_np, object_surface(m), per_triangle=per_triangle, dtype=m.dtype, device=str(m.device)
    )
    return SceneSplats(binding, 0, m.particle_count, GENERATED_BACKGROUND)
