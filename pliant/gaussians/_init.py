"""Physical particles and visual splats from calibrated pictures of an object's first frame: steps 3–6 of
Physically Embodied Gaussians' builder (Abou-Chakra et al. 2024, Fig. 2; their public
``scene_builders/simple_body_builder.py``), written for pliant's own rasteriser and Adam.

Given points that fill the object's volume (carved from the masks, at a spacing the cameras resolve):

3. an isotropic Gaussian at every point (opacity ½, colour the mean observed colour where the point projects
   inside the masks, σ = r/2: with Embodied Gaussians' σ = r, a splat one radius inside the silhouette
   spills a whole σ over it, and the outer layer of true particles is pruned as often as the false one
   outside; degree-1 spherical harmonics, so that a particle on a colour edge may show each camera its own
   side instead of fading as inconsistent);
4. Adam on their means, opacities and colours. The loss is the RGB squared error where, every iteration,
   the render's background *and* the observed background pixels (outside the masks) take one random colour:
   a splat that covers background cannot match a colour it does not know, so it turns transparent instead
   of painting the background; plus ``mask_weight`` · (alpha − mask)². After each step a few Jacobi
   projections push apart particles closer than 2r (:func:`separate_particles`), so that they stay a valid
   physical sampling (spheres of radius r that do not overlap);
5. particles whose Gaussian ends with opacity ≤ ½ are dropped, unless every camera sees them only through
   the kept ones (:func:`hidden_points`): the loss has no evidence about buried splats and would rather
   hollow the object out, as a buried splat only blurs the colours in front of it. The rest, separated to
   2r, are the physical particles;
6. a second, visual set, started from the trained first set, is trained further with means, rotations and
   scales free (scales clamped to [r/2, 2r]); splats farther than 2.3r from every particle are dropped. The
   survivors move with the particles through :func:`pliant.gaussians.bind` (``"lbs"``, the nearest
   particles) and are written as a 3DGS PLY that a scene's ``[gaussians]`` section loads
   (:meth:`SplatInit.save`).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import warp as wp

from .._warp import np_dtype, resolve_device, scalar_type
from ._appearance import sample_colours
from ._bind import Binding, bind
from ._camera import Camera
from ._gaussians import SH_C0, Gaussians
from ._optim import _flat
from ._ply import save_ply
from ._render import render
from ._splat_training import _check_inputs, _clamp_kernel, _scores, _train, _View

#: Adam's learning rates of both stages. ``means`` is per unit of the points' bounding-box diagonal [m/step
#: per m] (Embodied Gaussians' 1e-4 for a scene of about 1 m, ×3 as this stage takes fewer steps);
#: ``colours`` is in RGB units per step (the SH coefficient's rate is this / SH_C0); ``opacity_logits`` is
#: 10× theirs so that a splat's fate (kept or pruned at logit 0) is decided within the few hundred steps
#: that fit one CPU core's budget; ``quats`` and ``log_scales`` (visual stage only) are 3DGS's.
INIT_LRS = {
    "means": 3e-4,
    "opacity_logits": 1e-2,
    "colours": 1e-2,
    "quats": 1e-3,
    "log_scales": 5e-3,
}


@dataclass
class SplatInit:
    """What :func:`splats_from_particles` built.

    Attributes:
        particles: Physical particle positions [m], shape [P, 3] (the points whose splat stayed opaque,
            after training and collision projection).
        particle_colours: Their trained RGB in [0, 1], shape [P, 3].
        kept: Which input points became particles, bool [N].
        gaussians: The visual splats (the second set, attached: none farther than ``attach`` · r from a
            particle).
        radius: Particle radius r [m].
        separation: The least distance between two particles, in units of 2r (≥ 1 − 10⁻³ unless the final
            projections ran out of iterations on a very crowded input).
        pruned: Input points dropped by opacity (step 5).
        buried: Input points whose splat faded but that every camera sees only through kept particles,
            kept as particles (step 5).
        visual_dropped: Visual splats dropped as farther than ``attach`` · r from every particle, or as
            fainter than ``min_opacity``.
        psnr_before: PSNR [dB] of the starting splats (step 3) over the training views, object pixels only
            (observed image × mask against the render over black).
        psnr_particles: The same for the kept particles' splats after step 5.
        psnr_after: The same for the visual splats.
        iou_before: Mean IoU of rendered alpha > ½ with the masks, starting splats.
        iou_particles: The same after step 5.
        iou_after: The same for the visual splats.
        history: Mean loss before each Adam step of step 4.
        visual_history: The same for step 6.
        wall_time: Seconds, whole stage.
        cpu_time: CPU seconds of this process over the stage (the cost on one core, whatever else runs).
        timings: Seconds per step (``"particles"``, ``"visual"``, ``"metrics"``).
    """

    particles: np.ndarray
    particle_colours: np.ndarray
    kept: np.ndarray
    gaussians: Gaussians
    radius: float
    separation: float
    pruned: int
    buried: int
    visual_dropped: int
    psnr_before: float
    psnr_particles: float
    psnr_after: float
    iou_before: float
    iou_particles: float
    iou_after: float
    history: list[float] = field(default_factory=list)
    visual_history: list[float] = field(default_factory=list)
    wall_time: float = 0.0
    cpu_time: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)

    def bind(self, *, method: str = "lbs", k: int = 16, neighbours: int = 16) -> Binding:
        """The visual splats bound to the particles (:func:`pliant.gaussians.bind` at the particles' rest
        positions), as a scene's ``[gaussians]`` section with ``bind = "lbs"`` binds them.

        Args:
            method: ``"lbs"`` (the ``k`` nearest particles) or ``"rigid"`` (one body).
            k: Particles each splat follows.
            neighbours: Particles in each particle's Procrustes neighbourhood.
        """
        clusters = [np.arange(len(self.particles))] if method == "rigid" else None
        return bind(
            self.gaussians, self.particles, method=method, k=k, neighbours=neighbours, clusters=clusters
        )

    def save(
        self, directory: str | os.PathLike, *, ply: str = "splats.ply", points: str = "particles.npy"
    ) -> dict[str, dict[str, Any]]:
        """Write the visual splats as a 3DGS PLY and the particles as .npy [P, 3] float64 into ``directory``.

        Args:
            directory: Folder (created when missing).
            ply: File name of the splats.
            points: File name of the particles.

        Returns:
            Scene-file entries that load them, paths relative to ``directory``: ``"gaussians"`` for the
            ``[gaussians]`` section (``ply``, ``bind = "lbs"``) and ``"object"`` for a ``points`` object
            (``path``, and ``origin`` = the particles' mean, since a ``points`` object centres its file's
            points on ``origin``).
        """
        d = os.fspath(directory)
        os.makedirs(d, exist_ok=True)
        save_ply(self.gaussians, os.path.join(d, ply))
        np.save(os.path.join(d, points), np.asarray(self.particles, dtype=np.float64))
        centre = [float(v) for v in np.asarray(self.particles).mean(axis=0)]
        return {
            "gaussians": {"ply": ply, "bind": "lbs"},
            "object": {"kind": "points", "path": points, "origin": centre},
        }


def separate_particles(
    points: np.ndarray,
    radius: float,
    *,
    iterations: int = 8,
    relaxation: float = 0.2,
    tolerance: float | None = None,
) -> np.ndarray:
    """Push apart particles closer than 2r: Jacobi projections of the non-penetration constraint
    |x_i − x_j| ≥ 2r (Embodied Gaussians' ``_solve_collisions_jacobi``, without cohesion).

    Every overlapping pair moves each of its particles by half the overlap along the pair's axis; the moves
    of all pairs are summed and applied times ``relaxation``. Neighbours come from a k-d tree with a skin of
    r/2, rebuilt when a particle has moved a quarter of r since (so that no pair is missed).

    Args:
        points: Particle positions [m], shape [N, 3].
        radius: Particle radius r [m], > 0.
        iterations: Projections; with ``tolerance``, the most projections.
        relaxation: Fraction of the summed correction applied per projection, in (0, 1].
        tolerance: None: exactly ``iterations`` projections. Else stop once every pair is at least
            2r · (1 − ``tolerance``) apart.

    Returns:
        New positions [m], float64 [N, 3].
    """
    from scipy.spatial import cKDTree

    x = np.array(points, dtype=np.float64).reshape(-1, 3)
    if not radius > 0.0 or not math.isfinite(radius):
        raise ValueError(f"separate_particles: radius must be a positive length [m], got {radius}")
    if not 0.0 < relaxation <= 1.0:
        raise ValueError(f"separate_particles: relaxation must lie in (0, 1], got {relaxation}")
    n, d0, skin = len(x), 2.0 * radius, 0.5 * radius
    if n < 2:
        return x
    pairs, anchor = np.zeros((0, 2), dtype=np.int64), x.copy()
    built = False
    for _ in range(int(iterations)):
        if not built or np.max(np.sum((x - anchor) ** 2, axis=1)) > (0.5 * skin) ** 2:
            pairs, anchor, built = cKDTree(x).query_pairs(d0 + skin, output_type="ndarray"), x.copy(), True
        if not len(pairs):
            break
        i, j = pairs[:, 0], pairs[:, 1]
        dv = x[i] - x[j]
        dist = np.sqrt(np.sum(dv * dv, axis=1))
        close = dist < d0
        if tolerance is not None and not np.any(dist < d0 * (1.0 - tolerance)):
            break
        if not np.any(close):
            break
        i, j, dv, dist = i[close], j[close], dv[close], dist[close]
        # coincident particles have no axis: split them along x (the next projection fixes the rest)
        same = dist < 1e-12 * radius
        axis = np.where(same[:, None], np.array([1.0, 0.0, 0.0]), dv / np.where(same, 1.0, dist)[:, None])
        push = 0.5 * (d0 - dist)[:, None] * axis
        delta = np.stack(
            [np.bincount(i, push[:, k], n) - np.bincount(j, push[:, k], n) for k in range(3)], axis=1
        )
        x += relaxation * delta
    return x


def _separation(x: np.ndarray, radius: float) -> float:
    """Least distance between two of the points ``x`` [m], in units of 2 · ``radius`` (inf for one point)."""
    from scipy.spatial import cKDTree

    if len(x) < 2:
        return math.inf
    return float(np.min(cKDTree(x).query(x, k=2)[0][:, 1]) / (2.0 * radius))


def hidden_points(
    points: np.ndarray,
    occluders: np.ndarray,
    radius: float,
    cameras: Sequence[Camera],
    *,
    device: str | None = None,
    dtype: str = "float32",
) -> np.ndarray:
    """Which ``points`` [m] lie behind the opaque spheres of ``occluders`` [m] (radius r) in every camera:
    those no picture can show, bool [N].

    Each camera renders the occluders as near-opaque splats (σ = r, opacity 0.95); a point is hidden from it
    when it projects inside the image onto a pixel whose alpha exceeds ½ and lies more than 2r behind that
    pixel's rendered depth (a whole particle layer, so that the blending of the front splats' depths cannot
    hide a point of the front layer itself).

    Args:
        points: Query points [m], shape [N, 3].
        occluders: Occluding particle centres [m], shape [P, 3].
        radius: Particle radius r [m].
        cameras: The cameras.
        device: Warp device.
        dtype: ``"float32"`` or ``"float64"``.
    """
    q = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    hidden = np.ones(len(q), dtype=bool)
    if not len(q) or not len(occluders):
        return np.zeros(len(q), dtype=bool)
    wall = Gaussians.from_values(
        np.asarray(occluders, dtype=np.float64), scales=radius, opacities=0.95, dtype=dtype, device=device
    )
    for cam in cameras:
        _, alpha, depth = render(wall, cam)
        a, d = alpha.numpy(), depth.numpy()
        p = q @ cam.rotation.T + cam.translation
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.round(cam.fx * p[:, 0] / z + cam.cx)
            v = np.round(cam.fy * p[:, 1] / z + cam.cy)
        ok = (z > 1e-6) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        behind = np.zeros(len(q), dtype=bool)
        vi, ui = v[ok].astype(int), u[ok].astype(int)
        behind[ok] = (a[vi, ui] > 0.5) & (z[ok] > d[vi, ui] + 2.0 * radius)
        hidden &= behind
    return hidden


def splats_from_particles(
    points: np.ndarray,
    cameras: Sequence[Camera],
    images: Sequence[np.ndarray],
    masks: Sequence[np.ndarray],
    *,
    radius: float,
    iterations: int = 200,
    visual_iterations: int = 100,
    lrs: dict[str, float] | None = None,
    mask_weight: float = 1.0,
    projections: int = 4,
    relaxation: float = 0.2,
    opacity_threshold: float = 0.5,
    attach: float = 2.3,
    min_opacity: float = 0.02,
    sigma: float = 0.5,
    sh_degree: int = 1,
    seed: int = 0,
    device: str | None = None,
    dtype: str = "float32",
) -> SplatInit:
    """Physical particles and visual splats of an object from its first frame (module doc, steps 3–6).

    Args:
        points: Points filling the object's volume [m], shape [N, 3] (e.g. carved voxel centres at a
            spacing of about 2 · ``radius``).
        cameras: The C calibrated cameras.
        images: One RGB image [H, W, 3] per camera, floats in [0, 1] (uint8 is scaled by 1/255).
        masks: One object mask [H, W] per camera, bool or floats in [0, 1] (1: the object's pixel).
        radius: Particle radius r [m]: half the particles' least distance, and the unit of the splats'
            starting σ, of the visual splats' scale bounds [r/2, 2r] and of ``attach``.
        iterations: Adam steps of the particle stage (step 4).
        visual_iterations: Adam steps of the visual stage (step 6); 0: the first set, filtered as below.
        lrs: Learning rates by name, overriding :data:`INIT_LRS` (0 freezes a parameter).
        mask_weight: Weight of the mean squared (alpha − mask) term beside the RGB term (mean over pixels and
            channels).
        projections: Jacobi collision projections after each Adam step of step 4.
        relaxation: Their relaxation, in (0, 1].
        opacity_threshold: Particles whose splat ends with opacity at or below this are pruned.
        attach: Visual splats farther than ``attach`` · r from every particle are dropped.
        min_opacity: Visual splats at or below this opacity (they draw nothing) are dropped too.
        sigma: The starting splats' σ, in units of r (Embodied Gaussians: 1; see the module doc).
        sh_degree: Spherical-harmonic degree of the splats' colours (0: one RGB each; 0–3).
        seed: Seed of the random background colours.
        device: Warp device (default: CUDA when present).
        dtype: ``"float32"`` or ``"float64"``.

    Returns:
        :class:`SplatInit`.

    Raises:
        ValueError: points not [N, 3] or not finite, a non-positive radius or sigma, an SH degree outside
            0–3, negative iterations, unknown ``lrs``, counts of cameras, images and masks that differ, an
            image or mask of the wrong size, an empty mask (the message names the array), or no particle
            left after pruning (the points and the masks disagree).
    """
    t0, c0 = time.perf_counter(), time.process_time()
    pts, imgs, mks = _check_inputs(points, cameras, images, masks, radius)
    _check_options(sigma, sh_degree, iterations, visual_iterations, projections, lrs)
    rates = dict(INIT_LRS, **(lrs or {}))
    dev = resolve_device(device)
    r = float(radius)
    views = [_View(cam, im, m, dtype, dev) for cam, im, m in zip(cameras, imgs, mks, strict=True)]
    rng = np.random.default_rng(seed)
    extent = max(float(np.linalg.norm(np.ptp(pts, axis=0))), 2.0 * r)
    lr_sh = rates["colours"] / SH_C0

    # Step 3: isotropic splats at the points, coloured by what the cameras see there.
    rgb = sample_colours(pts, cameras, imgs, mks)
    g, quats = _starting_splats(pts, rgb, sh_degree, sigma * r, dtype, dev)
    psnr_before, iou_before = _scores(g, views)

    # Step 4: Adam on means, opacities and colours; the particles kept apart after every step.
    t1 = time.perf_counter()
    lr = [rates["means"] * extent, rates["opacity_logits"], lr_sh]
    project = _separation_hook(g, r, projections, relaxation, dtype)
    history = _train(
        g, [g.means, g.opacity_logits, g.sh], lr, views, int(iterations), rng, mask_weight, project
    )
    # Step 5: prune by opacity; the survivors, separated to 2r within a tolerance, are the particles.
    p = g.numpy()
    opaque, kept, particles = _prune(p, opacity_threshold, r, cameras, relaxation, dev, dtype)
    colours = np.clip(p["sh"][kept, 0] * SH_C0 + 0.5, 0.0, 1.0)
    p["means"][kept] = particles
    solid = _splat_set(p, quats, dtype, dev, kept)  # the particles' own splats (their means: particles)
    t2 = time.perf_counter()

    # Step 6: the visual set, from the trained first set, with means, rotations and scales free.
    v = _splat_set(p, quats, dtype, dev, requires_grad=True)
    lr = [rates["means"] * extent, rates["quats"], rates["log_scales"], rates["opacity_logits"], lr_sh]
    hook = _scale_clamp(v, r, dtype, dev)
    visual_history = _train(v, v.parameters(), lr, views, int(visual_iterations), rng, mask_weight, hook)
    visual, keep_v = _attached(v, particles, attach * r, min_opacity, dtype, dev)
    t3 = time.perf_counter()
    psnr_particles, iou_particles = _scores(solid, views)
    psnr_after, iou_after = _scores(visual, views)
    t4 = time.perf_counter()
    return SplatInit(
        particles=particles,
        particle_colours=colours,
        kept=kept,
        gaussians=visual,
        radius=r,
        separation=_separation(particles, r),
        pruned=int(len(pts) - kept.sum()),
        buried=int(np.sum(kept & ~opaque)),
        visual_dropped=int(len(pts) - keep_v.sum()),
        psnr_before=psnr_before,
        psnr_particles=psnr_particles,
        psnr_after=psnr_after,
        iou_before=iou_before,
        iou_particles=iou_particles,
        iou_after=iou_after,
        history=history,
        visual_history=visual_history,
        wall_time=t4 - t0,
        cpu_time=time.process_time() - c0,
        timings={"particles": t2 - t1, "visual": t3 - t2, "metrics": (t1 - t0) + (t4 - t3)},
    )


def _check_options(
    sigma: float,
    sh_degree: int,
    iterations: int,
    visual_iterations: int,
    projections: int,
    lrs: dict[str, float] | None,
) -> None:
    """``splats_from_particles``' numeric options: σ > 0, an SH degree 0–3, counts >= 0, known rates."""
    unknown = set(lrs or {}) - set(INIT_LRS)
    if not (sigma > 0.0 and math.isfinite(sigma)) or sh_degree not in (0, 1, 2, 3):
        raise ValueError(
            f"splats_from_particles: sigma must be > 0 (got {sigma}) and sh_degree 0-3 (got {sh_degree})"
        )
    if iterations < 0 or visual_iterations < 0 or projections < 0:
        raise ValueError("splats_from_particles: iterations, visual_iterations and projections must be >= 0")
    if unknown:
        raise ValueError(f"splats_from_particles: unknown lrs {sorted(unknown)}; known: {sorted(INIT_LRS)}")


def _starting_splats(
    pts: np.ndarray, rgb: np.ndarray, sh_degree: int, sigma: float, dtype: str, dev: str
) -> tuple[Gaussians, np.ndarray]:
    """Step 3: isotropic splats of σ ``sigma`` [m] at ``pts`` [N, 3] [m], opacity ½, SH colours of
    ``sh_degree`` whose constant term is ``rgb`` [N, 3]; with their (identity) quaternions [N, 4]."""
    n = len(pts)
    sh = np.zeros((n, (sh_degree + 1) ** 2, 3))
    sh[:, 0] = (np.clip(rgb, 0.02, 0.98) - 0.5) / SH_C0
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    g = Gaussians(
        pts,
        quats,
        np.full((n, 3), math.log(sigma)),
        np.zeros(n),
        sh,
        dtype=dtype,
        device=dev,
        requires_grad=True,
    )
    return g, quats


def _prune(
    p: dict[str, np.ndarray],
    opacity_threshold: float,
    r: float,
    cameras: Sequence[Camera],
    relaxation: float,
    dev: str,
    dtype: str,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 5: (opaque [N], kept [N], the kept particles separated to 2 ``r`` [K, 3] [m]) of the trained
    splats' values ``p``; a buried splat (every camera sees it only through opaque ones) is kept too."""
    opaque = 1.0 / (1.0 + np.exp(-p["opacity_logits"])) > opacity_threshold
    # The photometric loss cannot judge a particle that every camera sees only through the kept ones (it
    # would rather hollow the object out: a buried splat only blurs the colours of the surface in front);
    # such a particle keeps its place in the carved volume.
    kept = opaque.copy()
    kept[~opaque] = hidden_points(
        p["means"][~opaque], p["means"][opaque], r, cameras, device=dev, dtype=dtype
    )
    if not np.any(kept):
        raise ValueError(
            f"splats_from_particles: every splat's opacity ended at or below {opacity_threshold}; the points "
            "do not lie where the masks show the object (check the cameras' poses and the masks)"
        )
    particles = separate_particles(
        p["means"][kept], r, iterations=2000, relaxation=relaxation, tolerance=1e-3
    )
    return opaque, kept, particles


def _splat_set(
    p: dict[str, np.ndarray],
    quats: np.ndarray,
    dtype: str,
    dev: str,
    keep: np.ndarray | None = None,
    requires_grad: bool = False,
) -> Gaussians:
    """The Gaussians of the values ``p`` (``Gaussians.numpy()``) with rotations ``quats`` [N, 4], those of
    ``keep`` [N] (bool) only when given."""
    sel = slice(None) if keep is None else keep
    return Gaussians(
        p["means"][sel],
        quats[sel],
        p["log_scales"][sel],
        p["opacity_logits"][sel],
        p["sh"][sel],
        dtype=dtype,
        device=dev,
        requires_grad=requires_grad,
    )


def _separation_hook(
    g: Gaussians, r: float, projections: int, relaxation: float, dtype: str
) -> Callable[[], None]:
    """Step 4's step hook: ``projections`` Jacobi projections (``relaxation``) push apart the splats'
    means closer than 2 ``r`` [m]."""
    nd = np_dtype(dtype)

    def project() -> None:
        x = separate_particles(g.means.numpy(), r, iterations=projections, relaxation=relaxation)
        g.means.assign(x.astype(nd))

    return project


def _scale_clamp(v: Gaussians, r: float, dtype: str, dev: str) -> Callable[[], None]:
    """Step 6's step hook: clamp the visual splats' scales to [r/2, 2r] [m]."""
    s = scalar_type(dtype)
    lo, hi = s(math.log(0.5 * r)), s(math.log(2.0 * r))
    flat_scales = _flat(v.log_scales)

    def clamp() -> None:
        wp.launch(_clamp_kernel, dim=flat_scales.shape[0], inputs=[flat_scales, lo, hi], device=dev)

    return clamp


def _attached(
    v: Gaussians, particles: np.ndarray, reach: float, min_opacity: float, dtype: str, dev: str
) -> tuple[Gaussians, np.ndarray]:
    """Step 6's survivors: the visual splats within ``reach`` [m] of a particle and above ``min_opacity``,
    with unit quaternions; and the mask [N] of those kept."""
    from scipy.spatial import cKDTree

    q = v.numpy()
    near = np.asarray(cKDTree(particles).query(q["means"], k=1)[0]) <= reach
    keep_v = near & (1.0 / (1.0 + np.exp(-q["opacity_logits"])) > min_opacity)
    q["quats"] /= np.linalg.norm(q["quats"], axis=1, keepdims=True)
    visual = Gaussians(
        q["means"][keep_v],
        q["quats"][keep_v],
        q["log_scales"][keep_v],
        q["opacity_logits"][keep_v],
        q["sh"][keep_v],
        dtype=dtype,
        device=dev,
    )
    return visual, keep_v


__all__ = ["INIT_LRS", "SplatInit", "hidden_points", "separate_particles", "splats_from_particles"]
