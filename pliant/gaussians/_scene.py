"""Gaussians for a scene's ``[gaussians]`` section: load or generate the splats, bind them to the object,
and make the cameras that render or watch it (the scene layer only validates the section)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from ._bind import Binding, bind
from ._camera import Camera
from ._gaussians import Gaussians, _matrix_quats
from ._ply import PlyError, load_ply
from ._render import render


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
    """

    binding: Binding
    lo: int
    hi: int
    background: tuple[float, float, float]

    def place(self, x: Any) -> Gaussians:
        """The splats for model positions ``x`` [m] (NumPy [N, 3] of the whole model, or a Warp array)."""
        b = self.binding
        if isinstance(x, wp.array):
            q = x[self.lo : self.hi]
        else:
            from .._warp import np_dtype, vec3_type

            dt = b.gaussians.dtype
            q = wp.array(
                np.asarray(x)[self.lo : self.hi].astype(np_dtype(dt)),
                dtype=vec3_type(dt),
                device=b.gaussians.device,
            )
        return b.deform(q)

    def image(self, x: Any, camera: Camera) -> np.ndarray:
        """RGB image [H, W, 3] in [0, 1] of the object at model positions ``x`` seen by ``camera``."""
        return render(self.place(x), camera, self.background).colour.numpy()


def _fail(cfg: Any, field: str, msg: str) -> SplatSceneError:
    return SplatSceneError(f"{cfg.source}: {field}: {msg}")


def _object_range(cfg: Any, model: Any, index: int) -> tuple[int, int]:
    name = cfg.object_names()[index]
    rec = next((o for o in model.objects if o["name"] == name), None)
    if rec is None:  # objects registered in file order
        rec = model.objects[index]
    return int(rec["start"]), int(rec["start"] + rec["count"])


def _generate(spec: Any, X: np.ndarray, faces: np.ndarray, dtype: str, device: str) -> Gaussians:
    """One flat splat per surface triangle (or one round splat per particle when there is no surface)."""
    if len(faces):
        P = X[faces]  # [F, 3, 3]
        centre = P.mean(axis=1)
        e1 = P[:, 1] - P[:, 0]
        n = np.cross(e1, P[:, 2] - P[:, 0])
        area = 0.5 * np.linalg.norm(n, axis=1)
        n /= np.maximum(2.0 * area, 1e-300)[:, None]
        e1 /= np.maximum(np.linalg.norm(e1, axis=1), 1e-300)[:, None]
        R = np.stack([e1, np.cross(n, e1), n], axis=2)  # columns: in-plane, in-plane, normal
        s = 0.5 * spec.scale * np.sqrt(2.0 * area)  # about half a triangle leg
        scales = np.stack([s, s, np.maximum(0.05 * s, 1e-5)], axis=1)
        quats = _matrix_quats(R)
    else:
        from scipy.spatial import cKDTree

        centre = X
        d = cKDTree(X).query(X, k=2)[0][:, 1] if len(X) > 1 else np.array([0.01])
        scales = np.repeat((0.5 * spec.scale * np.maximum(np.median(d), 1e-4)) * np.ones((len(X), 1)), 3, 1)
        quats = np.tile([1.0, 0.0, 0.0, 0.0], (len(X), 1))
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


def scene_splats(cfg: Any, scene: Any) -> SceneSplats:
    """Build the ``[gaussians]`` splats of a built ``scene`` (its config ``cfg``) and bind them.

    Raises:
        SplatSceneError: the PLY cannot be read or lacks properties, or the binding does not fit the
            object (no triangles, no tets); the message names the scene file and the field.
    """
    from ..scene._gaussians import object_index

    spec = cfg.gaussians
    model = scene.model
    index = object_index(cfg, spec)
    lo, hi = _object_range(cfg, model, index)
    X = model.particle_q_np[lo:hi].astype(np.float64)
    faces = np.asarray(model.render_faces, dtype=np.int64).reshape(-1, 3)
    faces = faces[np.all((faces >= lo) & (faces < hi), axis=1)] - lo
    tets = np.asarray(model.tet_indices_np, dtype=np.int64).reshape(-1, 4)
    tets = tets[np.all((tets >= lo) & (tets < hi), axis=1)] - lo
    dtype, device = model.dtype, model.device
    if spec.ply is not None:
        from ..scene._files import scene_path

        path = scene_path(cfg, spec.ply, "gaussians.ply")
        try:
            g = load_ply(path).copy(dtype=dtype, device=device)
        except (PlyError, OSError) as exc:
            raise _fail(cfg, "gaussians.ply", str(exc)) from None
    else:
        g = _generate(spec, X, faces, dtype, device)
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
    return SceneSplats(b, lo, hi, tuple(float(c) for c in spec.background))
