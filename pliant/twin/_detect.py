"""What holds the object, and what it rests on, found from the observed motion alone.

Both detectors read the per-frame point clouds that the pictures give (:func:`pliant.geometry.frame_clouds`:
back-projected masked depth, or the surface of each frame's carved hull), so they work the same with and
without depth:

- **Fixed regions** (:func:`detect_fixed`): a frame-0 surface point is *static* when, in every later frame,
  an observed point lies within ``tol`` of it. A clamp leaves such a patch; a free fall leaves none. A
  particle is fixed when its nearest frame-0 surface point is static and most of the surface points around
  it are, and the fixed particles are
  split into connected groups, each becoming a kinematic box handle. Static points explained by the ground
  (within a margin of a detected ground plane) are not a clamp: an object at rest on the floor is held by
  contact, not pinned.
- **The ground** (:func:`detect_ground`): with depth, a RANSAC plane through the background (valid depth
  outside the masks) whose normal is within a few degrees of up; without depth, the lowest level the
  object's points reach, where a flat patch as wide as a quarter of the object rests. It is used only when
  the object comes within ``margin`` of it: a floor far below a hanging object takes no part in the motion.

Decisions come with a reason in words, written into ``twin.json``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

if TYPE_CHECKING:
    from ..geometry import Plane

#: Nearest frame-0 surface points looked at for each particle: the nearest must be static, and at least
#: :data:`STATIC_SHARE` of them.
FIXED_NEIGHBOURS = 8
STATIC_SHARE = 0.5
#: Depth of a clamp [particle spacings] kept at the end of a still region (:func:`_clamps`).
CLAMP_DEPTH = 2.0
#: Most frame-0 surface points whose motion is measured (every k-th of a denser cloud: a pixel's spacing on
#: a 200 × 150 camera is far below a particle's).
MAX_QUERY = 5000
#: Fewest fixed particles that make a clamp (fewer are noise: a stray static pixel).
MIN_FIXED = 3


@dataclass
class FixedRegions:
    """Fixed particles found from the motion (:func:`detect_fixed`).

    Attributes:
        fixed: [N] bool, the particles held kinematic.
        boxes: One (centre [3], half extents [3]) [m] per connected group of fixed particles.
        static_fraction: Fraction of frame-0 surface points that never moved.
        max_motion: [M] largest distance [m] from each frame-0 surface point to the nearest observed point
            of any later frame.
        reason: Why, in words.
    """

    fixed: np.ndarray
    boxes: list[tuple[np.ndarray, np.ndarray]]
    static_fraction: float
    max_motion: np.ndarray
    reason: str

    def summary(self) -> dict[str, Any]:
        """JSON-ready description for ``twin.json``."""
        return {
            "fixed_particles": int(self.fixed.sum()),
            "boxes": [{"center": c.tolist(), "half_extents": h.tolist()} for c, h in self.boxes],
            "static_surface_fraction": self.static_fraction,
            "reason": self.reason,
        }


@dataclass
class Ground:
    """The ground plane found from the pictures (:func:`detect_ground`).

    Attributes:
        height: Height [m] of the plane along +y, or None when no ground takes part.
        seen_height: Height [m] of a floor seen in the background even when unused, or None.
        clearance: Smallest height [m] of the object's observed points above the plane over the recording.
        reason: Why, in words.
    """

    height: float | None
    seen_height: float | None = None
    clearance: float | None = None
    reason: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        """JSON-ready description for ``twin.json``."""
        return {
            "height": self.height,
            "seen_height": self.seen_height,
            "clearance": self.clearance,
            "reason": self.reason,
            **self.extra,
        }


def surface_motion(clouds: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Frame-0 surface points (at most :data:`MAX_QUERY`, every k-th) and, for each, the largest distance [m]
    to the nearest observed point of any later frame.

    Args:
        clouds: [T, P, 3] padded per-frame point clouds [m].
        counts: [T] valid points of each frame.

    Returns:
        (points [M, 3] of frame 0, max_motion [M] in metres).
    """
    p0 = np.asarray(clouds[0, : int(counts[0])], dtype=np.float64)
    p0 = (
        p0[:: -(-len(p0) // MAX_QUERY)] if len(p0) > MAX_QUERY else p0
    )  # every k-th: the same points each frame
    worst = np.zeros(len(p0))
    for t in range(1, clouds.shape[0]):  # one KD-tree per frame; every point is queried at once
        n = int(counts[t])
        if n == 0:
            continue  # a frame with nothing seen says nothing about motion
        d, _ = cKDTree(np.asarray(clouds[t, :n], dtype=np.float64)).query(p0)
        np.maximum(worst, d, out=worst)
    return p0, worst


def _groups(points: np.ndarray, link: float) -> list[np.ndarray]:
    """Connected groups (index arrays) of ``points`` whose neighbours lie within ``link`` [m]."""
    pairs = cKDTree(points).query_pairs(link, output_type="ndarray")
    n = len(points)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    k, label = connected_components(graph, directed=False)
    return [np.flatnonzero(label == i) for i in range(k)]


def _clamps(particles: np.ndarray, still: np.ndarray, spacing: float) -> np.ndarray:
    """The clamps among the particles that stay still: each connected still group that touches a moving
    particle, cut down to the object's end slab there (:data:`CLAMP_DEPTH` spacings deep, on the side away
    from the moving part, every particle within two spacings of the group).

    Why cut: motion grows smoothly from a clamp (a cantilever's as the square of the distance), so every
    particle closer than the observations resolve looks still; holding them all would shorten the free
    part. The holder grips the end. Why touching: a still group with nothing moving beside it is no clamp
    (the visual hull's excess behind a still part, seen by no camera's silhouette, is such a group); nor is
    a group of fewer than :data:`MIN_FIXED` particles (a stray still pixel).
    """
    out = np.zeros(len(particles), dtype=bool)
    moving = np.flatnonzero(~still)
    if len(moving) == 0:
        return still  # nothing moves: the whole object is held
    tree = cKDTree(particles[moving])
    idx = np.flatnonzero(still)
    for g in _groups(particles[idx], 1.5 * spacing):
        pts = particles[idx[g]]
        d, _ = tree.query(pts, distance_upper_bound=1.5 * spacing)
        if len(g) < MIN_FIXED or not np.isfinite(d).any():
            continue
        away = pts.mean(axis=0) - particles[moving].mean(axis=0)
        axis = away / max(np.linalg.norm(away), 1e-12)
        # The end slab of the object there, across the whole section: parts of a clamped end face look
        # still while its edges, nearer to moving surfaces, do not.
        s = particles @ axis
        near = cKDTree(pts).query(particles, distance_upper_bound=2.0 * spacing)[0] < np.inf
        out |= near & (s >= (pts @ axis).max() - CLAMP_DEPTH * spacing)
    return out


def detect_fixed(
    particles: np.ndarray,
    clouds: np.ndarray,
    counts: np.ndarray,
    *,
    tol: float,
    spacing: float,
    ground: float | None = None,
    surface: tuple[np.ndarray, np.ndarray] | None = None,
) -> FixedRegions:
    """Particles held still by something the cameras may not see (a clamp), from the observed motion.

    Args:
        particles: [N, 3] the twin's particles at frame 0 [m].
        clouds: [T, P, 3] padded per-frame observed point clouds [m] (frame 0 first).
        counts: [T] valid points per frame.
        tol: Largest motion [m] of a static surface point (the observations' resolution: about a quarter of
            a particle spacing with depth, half a voxel for carved hulls).
        spacing: Particle spacing [m]: groups of fixed particles are linked within 1.5 spacings, and each
            group's box is padded by half a spacing so the handle grabs its particles.
        ground: Height [m] of a ground plane, or None: static points within two spacings of it rest on the
            ground and do not make a clamp.
        surface: :func:`surface_motion` of ``clouds`` when already computed (it depends on the clouds
            only, so models of one object share it), or None to compute it here.

    Returns:
        The fixed particles, their boxes and the reason.
    """
    particles = np.asarray(particles, dtype=np.float64)
    n = len(particles)
    none = np.zeros(n, dtype=bool)
    if clouds.shape[0] < 2 or int(counts[0]) == 0:
        return FixedRegions(none, [], 0.0, np.zeros(0), "too few observed frames to see what stays still")
    p0, motion = surface_motion(clouds, counts) if surface is None else surface
    static = motion <= tol
    if ground is not None:
        static &= p0[:, 1] > ground + 2.0 * spacing
    frac = float(static.mean()) if len(static) else 0.0
    k = min(FIXED_NEIGHBOURS, len(p0))
    _, near = cKDTree(p0).query(particles, k=k)
    near = near.reshape(n, k)
    # Held: the nearest surface point never moves, nor do most of the surface points around it (a single
    # static pixel next to moving ones is noise, not a clamp).
    fixed = static[near[:, 0]] & (static[near].mean(axis=1) >= STATIC_SHARE)
    if fixed.sum() < MIN_FIXED:
        moved = float(np.median(motion)) if len(motion) else 0.0
        return FixedRegions(
            none,
            [],
            frac,
            motion,
            f"no region stays still: {frac:.1%} of the frame-0 surface moves less than {tol * 1e3:.1f} mm "
            f"(median largest motion {moved * 1e3:.1f} mm), too little to hold any particle; the object is "
            "free",
        )
    fixed = _clamps(particles, fixed, spacing)
    if fixed.sum() < MIN_FIXED:
        return FixedRegions(
            none,
            [],
            frac,
            motion,
            "the parts that stay still touch nothing that moves: no clamp holds the object",
        )
    boxes = []
    idx = np.flatnonzero(fixed)
    for g in _groups(particles[idx], 1.5 * spacing):
        if len(g) < MIN_FIXED:
            fixed[idx[g]] = False  # a stray corner of a slab: no handle of its own
            continue
        pts = particles[idx[g]]
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        boxes.append(((lo + hi) / 2.0, (hi - lo) / 2.0 + 0.5 * spacing))
    return FixedRegions(
        fixed,
        boxes,
        frac,
        motion,
        f"{int(fixed.sum())} particles in {len(boxes)} region(s) whose surface neighbourhood moves "
        f"less than {tol * 1e3:.1f} mm in every frame ({frac:.1%} of the frame-0 surface is static): held "
        "kinematic, like a clamp",
    )


def detect_ground(
    clouds: np.ndarray,
    counts: np.ndarray,
    *,
    spacing: float,
    background: np.ndarray | None = None,
    margin: float | None = None,
    plane: Plane | None = None,
) -> Ground:
    """The ground plane, when the object rests on or hits it.

    Args:
        clouds: [T, P, 3] padded per-frame observed point clouds of the object [m].
        counts: [T] valid points per frame.
        spacing: Particle spacing [m] (tolerances scale with it).
        background: [B, 3] points of the background (valid depth outside the masks) [m], or None without
            depth.
        margin: Closest approach [m] of the object to a seen floor for it to count as touching (default
            two spacings).
        plane: A plane already fitted to ``background`` (:func:`pliant.geometry.fit_plane`'s result), or
            None to fit one here.

    Returns:
        The ground (``height`` None when no ground takes part) and the reason.
    """
    margin = 2.0 * spacing if margin is None else margin
    lows = np.array([np.min(clouds[t, : int(c), 1]) if c else np.inf for t, c in enumerate(counts)])
    lowest = float(lows.min())
    if background is not None and len(background) >= 100:
        from ..geometry import fit_plane

        pl = plane if plane is not None else fit_plane(background, tol=0.25 * spacing)
        if pl is not None:
            h = float(pl.height)
            clear = lowest - h
            if clear <= margin:
                return Ground(
                    h,
                    h,
                    clear,
                    f"a floor is seen in the background depth at y = {h:.4f} m and the object comes within "
                    f"{clear * 1e3:.1f} mm of it (<= {margin * 1e3:.1f} mm): ground contact",
                )
            return Ground(
                None,
                h,
                clear,
                f"a floor is seen at y = {h:.4f} m, but the object stays {clear * 1e3:.1f} mm above it "
                f"(> {margin * 1e3:.1f} mm): it takes no part in the motion",
            )
    # Without depth: a flat, wide patch at the lowest level the object reaches.
    tol = 0.5 * spacing
    best, at = 0.0, -1
    for t in np.flatnonzero(lows <= lowest + tol):
        pts = clouds[t, : int(counts[t])]
        span = np.ptp(pts[:, [0, 2]], axis=0)
        patch = pts[pts[:, 1] <= lowest + tol][:, [0, 2]]
        if len(patch) < 3 or np.any(span <= 0):
            continue
        cover = float(np.prod(np.ptp(patch, axis=0) / span))
        if cover > best:
            best, at = cover, int(t)
    if best >= 0.25:
        return Ground(
            lowest,
            None,
            0.0,
            f"at frame {at} the object's lowest points form a flat patch covering {best:.0%} of its "
            f"horizontal extent at y = {lowest:.4f} m: it rests on, or hits, a ground there",
        )
    return Ground(
        None,
        None,
        None,
        f"no floor in the pictures (no depth, or no horizontal plane in it) and the object's lowest points "
        f"never flatten into a wide patch (at most {best:.0%} of its extent): no ground",
    )


__all__ = ["FixedRegions", "Ground", "detect_fixed", "detect_ground", "surface_motion"]
