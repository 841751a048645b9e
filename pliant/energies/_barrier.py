"""Barrier contact (IPC): a smoothly clamped log barrier for self-contact, the ground and colliders, with a
continuous-collision-detection bound on every Newton step, so that implicit steps never intersect.

Li, Ferguson, Schneider, Langlois, Zorin, Panozzo, Jiang, Kaufman, "Incremental Potential Contact:
Intersection- and Inversion-free, Large-Deformation Dynamics", ACM TOG 39(4), 2020; the CCD is the additive
CCD of Li, Kaufman, Jiang, "Codimensional Incremental Potential Contact", ACM TOG 40(4), 2021.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .._warp import launch
from ..collision import Colliders
from ..model import STICK_VELOCITY, Model
from . import _barrier_ccd as C
from . import _barrier_friction as F
from . import _barrier_kernels as K
from ._base import ModalEnergy


def surface_edges(tris: np.ndarray) -> np.ndarray:
    """The unique edges (int32 [E, 2], low index first) of triangles ``tris`` (int [T, 3])."""
    t = np.asarray(tris, np.int64).reshape(-1, 3)
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    e.sort(axis=1)
    return np.unique(e, axis=0).astype(np.int32)


class _Surface:
    """Triangles, edges, points and the two BVHs (refit per query) of one model's contact surface."""

    def __init__(self, model: Model, tris: np.ndarray) -> None:
        d = model.device
        tris = np.asarray(tris, np.int32).reshape(-1, 3)
        edges = surface_edges(tris)
        self.tri_count, self.edge_count = len(tris), len(edges)
        self.tris: wp.array = wp.array(tris.ravel(), dtype=wp.int32, device=d)
        self.edges: wp.array = wp.array(edges.ravel(), dtype=wp.int32, device=d)
        self.points: wp.array = wp.array(np.unique(tris).astype(np.int32), dtype=wp.int32, device=d)
        self.tri_lo = wp.zeros(len(tris), dtype=wp.vec3f, device=d)
        self.tri_hi = wp.zeros(len(tris), dtype=wp.vec3f, device=d)
        self.edge_lo = wp.zeros(len(edges), dtype=wp.vec3f, device=d)
        self.edge_hi = wp.zeros(len(edges), dtype=wp.vec3f, device=d)
        self.tri_bvh: wp.Bvh | None = None
        self.edge_bvh: wp.Bvh | None = None

    def refit(self, model: Model, x: wp.array, dx: wp.array | None, pad: float) -> None:
        """Boxes of the primitives at x (``dx`` None) or swept to x + dx, padded by ``pad`` [m]."""
        swept = dx is not None
        for prims, arity, lo, hi in (
            (self.tris, 3, self.tri_lo, self.tri_hi),
            (self.edges, 2, self.edge_lo, self.edge_hi),
        ):
            launch(
                K.prim_bounds,
                lo.shape[0],
                [prims, arity, x, dx if swept else x, int(swept), float(pad), lo, hi],
                device=model.device,
            )
        if self.tri_bvh is None:
            self.tri_bvh = wp.Bvh(self.tri_lo, self.tri_hi)
            self.edge_bvh = wp.Bvh(self.edge_lo, self.edge_hi)
        else:
            self.tri_bvh.refit()
            assert self.edge_bvh is not None
            self.edge_bvh.refit()


class BarrierContact(ModalEnergy):
    """IPC's barrier E = κ Σ_k b(d_k) [J] over contact pairs k at distance d_k [m], with the clamped log
    barrier

        b(d) = −(d − d̂)² ln(d/d̂) for 0 < d < d̂, 0 for d ≥ d̂

    (C² at d̂, +∞ at contact): point–triangle and edge–edge pairs of the contact surface (self-contact),
    every particle against the ground plane (d = y − h) and against each collider (d = φ_c(x), the signed
    distance, so spheres, boxes, capsules and mesh SDFs). Pairs are found by box queries of ``wp.Bvh``\\ s
    over the surface's triangles and edges.

    The implicit step's Newton search is kept intersection-free by :meth:`max_step`: continuous collision
    detection along the step x + α Δx lets no pair come closer than 20 % of its distance at the start of
    the step — for the plane exactly 0.8 × the time of impact, for the other pairs additive CCD's
    conservative bound. The minimiser also starts from the step's start positions moved towards x̃ as far
    as that bound allows (``feasible_start``), instead of from x̃ itself, which may intersect. Start from an
    intersection-free configuration with every pair farther apart than 0; then no iterate ever intersects.

    Moving colliders (``velocity=``, ``angular_velocity=``): the step solves for the positions at its end,
    so :meth:`begin_step` (the minimisers call it; the term is then ``dissipative``) puts each collider at
    its pose after the step's h (:meth:`Colliders.pose_ahead`); the barrier, its derivatives and the line
    search's CCD all see that pose, and friction acts on the motion relative to the surface (the lagged
    surface displacement, :mod:`._barrier_friction`). The start x_ref, clear of the colliders where they
    were, may be inside one where it will be, so the minimiser starts from :meth:`carried_start`: each
    particle within reach of a moving collider moved by that collider's rigid motion (its distance to it
    is then unchanged), checked clear of the ground and every collider at the end pose (else left where it
    was; RuntimeError when neither is clear: a kinematic collider squeezes it into an obstacle). What is
    guaranteed: every iterate (the start and each line-search point) is clear of the ground and of every
    collider at the end pose, so the step's result never intersects a collider at the end of the step.
    What is not: the motion in between (a collider thinner than its travel in a step could have passed a
    particle outside its reach, which is then simply on its other side), and self-contact of a surface only
    partly carried. ``ForceSolver`` moves the colliders after the step (a motion handler when they are
    not among its ``collisions``). Compliant colliders (``stiffness=``) are refused: a barrier is hard.

    Hessian: per pair, exact (closest-point envelope formula, :mod:`._barrier_math`) and projected to the
    nearest PSD matrix when ``project_psd`` (self-contact pairs: Jacobi rotations in the ≤ 5-dimensional
    subspace that holds the 12×12 Hessian's range; obstacles: 3×3). The pattern follows the pairs:
    :meth:`refresh_pattern` (called by the Newton minimiser at the start of a step and after each
    iterate) adds the point pairs of every self-contact pair closer than 2 d̂, and
    :meth:`pattern_version` tells the minimiser to rebuild its matrix. A pair whose points are not all in
    the pattern yet adds only its 3×3 diagonal blocks (principal blocks of a PSD matrix are PSD, so the
    direction still descends).

    The barrier acts on the mesh surface itself (particle radii are not used): d̂ must be below the
    smallest distance between non-adjacent primitives at rest (about half an edge on a regular grid).

    Args:
        dhat: d̂ [m], the distance below which contact acts.
        kappa: κ [N/m] (J/m²); None: 100 × (mean particle mass) × |g| / d̂, about a weight per point held at
            0.94 d̂.
        ground: barrier against ``model.ground`` (when the model has one).
        colliders: static :class:`pliant.collision.Colliders` to keep particles outside, or None.
        self_contact: point–triangle and edge–edge barrier on the surface (``triangles``, default the
            model's triangles ``model.tri_indices``, else its ``render_faces``).
        triangles: int [T, 3] particle indices of the contact surface, or None.
        friction: lagged, smoothed Coulomb friction against the ground (μ of ``model.ground``) and the
            colliders (their μ), :mod:`._barrier_friction`: the normal force and normal are frozen at the
            step's start (IPC's lagging).
        self_friction: μ [-] of the same lagged friction between self-contact pairs (0: none; with
            ``self_contact``).
        stick_velocity: ε_v [m/s] of the friction: below it friction is a viscous ramp (a creep of at most
            ε_v where it should stick); None: the ground's ``stick_velocity`` (else 1e-4 m/s).
    """

    hessian_changes_each_step = True
    #: The minimiser starts from the CCD-filtered advance from x_ref towards x̃ (see the class docstring).
    feasible_start = True

    def __init__(
        self,
        *,
        dhat: float = 1.0e-3,
        kappa: float | None = None,
        ground: bool = True,
        colliders: Colliders | None = None,
        self_contact: bool = False,
        triangles: np.ndarray | None = None,
        friction: bool = False,
        stick_velocity: float | None = None,
        self_friction: float = 0.0,
    ) -> None:
        if not dhat > 0:
            raise ValueError(f"BarrierContact dhat must be > 0 m, got {dhat}")
        if kappa is not None and not kappa > 0:
            raise ValueError(f"BarrierContact kappa must be > 0 N/m (or None for the default), got {kappa}")
        if stick_velocity is not None and not stick_velocity > 0:
            raise ValueError(f"BarrierContact stick_velocity must be > 0 m/s (or None), got {stick_velocity}")
        if not self_friction >= 0:
            raise ValueError(f"BarrierContact self_friction must be >= 0 (a Coulomb μ), got {self_friction}")
        self.self_friction = float(self_friction) if self_contact else 0.0
        self.friction = bool(friction) or self.self_friction > 0
        self.stick_velocity = None if stick_velocity is None else float(stick_velocity)
        self._ahead: dict[int, list] = {}
        self._carry: dict[int, tuple[wp.array, wp.array]] = {}
        self._ahead_dt: dict[int, float] = {}
        self._lag: dict[int, tuple] = {}
        self._self_lag: dict[int, tuple] = {}
        self.dhat = float(dhat)
        self.kappa = None if kappa is None else float(kappa)
        self.ground = bool(ground)
        self.colliders = colliders if colliders is not None and len(colliders) > 0 else None
        if self.colliders is not None:
            _refuse_compliant(self.colliders, "BarrierContact")
        self.self_contact = bool(self_contact)
        self.triangles = None if triangles is None else np.asarray(triangles, np.int32).reshape(-1, 3)
        self._surfaces: dict[int, _Surface] = {}
        self._alpha: dict[int, wp.array] = {}
        # Per model: the sorted keys i·n + j (i < j) of the point pairs in the Hessian pattern, on the host
        # and the device, and the pattern's version (bumped when it changes).
        self._keys: dict[int, tuple[np.ndarray, wp.array, int]] = {}

    @property
    def dissipative(self) -> bool:  # type: ignore[override]
        """With friction or moving colliders: the minimisers call :meth:`begin_step` (the lagged normal
        forces, the colliders' pose at the step's end)."""
        return self.friction or self._moving()

    def _moving(self) -> bool:
        return self.colliders is not None and self.colliders.moving

    @property
    def owns_ground(self) -> bool:
        """True with ``ground``: ``ForceSolver`` then adds no ground penalty and no post-step ground
        projection (this energy is the ground contact)."""
        return self.ground

    # ------------------------------------------------------------------------------------- set-up
    def stiffness(self, model: Model) -> float:
        """κ [N/m] on ``model`` (the given one, or the default from its mean mass and gravity)."""
        if self.kappa is not None:
            return self.kappa
        mean_mass = float(np.mean(model.particle_mass_np)) if model.particle_count else 0.0
        g = float(np.linalg.norm(model.gravity)) or 9.81
        return 100.0 * mean_mass * g / self.dhat

    def _surface(self, model: Model) -> _Surface | None:
        if not self.self_contact:
            return None
        s = self._surfaces.get(id(model))
        if s is None:
            tris = self.triangles
            if tris is None:
                tris = model.tri_indices.numpy() if model.tri_count else np.asarray(model.render_faces)
            tris = np.asarray(tris).reshape(-1, 3)
            if len(tris) == 0:
                raise ValueError(
                    "BarrierContact(self_contact=True): the model has no triangles; pass triangles= "
                    "(int [T, 3] particle indices of the contact surface)"
                )
            if tris.min() < 0 or tris.max() >= model.particle_count:
                raise ValueError(
                    f"BarrierContact triangles: indices must be in [0, {model.particle_count}), got "
                    f"[{tris.min()}, {tris.max()}]; pass the surface of this model"
                )
            s = _Surface(model, tris)
            self._surfaces[id(model)] = s
        return s

    def _obstacles(self, model: Model, start: bool = False) -> list:
        """(collider inputs..., count, ground flag, ground height) for the obstacle kernels: moving colliders
        at the step's end pose once :meth:`begin_step` set one (``start``: where they are now)."""
        if self.colliders is not None:
            _refuse_compliant(self.colliders, "BarrierContact")  # also those added after construction
            ahead = None if start or not self._moving() else self._ahead.get(id(model))
            geo: list = self.colliders.geometry_inputs(model) if ahead is None else ahead
            count = len(self.colliders)
        else:
            key = ("_dummy_colliders", model.dtype, str(model.device))
            cached = getattr(self, "_dummy", {}).get(key)
            if cached is not None:
                geo = cached
            else:
                d = model.device
                geo = [
                    wp.zeros(1, dtype=wp.int32, device=d),
                    wp.zeros(1, dtype=model.vec3, device=d),
                    wp.zeros(1, dtype=model.vec3, device=d),
                    wp.zeros(1, dtype=model.mat33, device=d),
                    wp.zeros(1, dtype=model.scalar, device=d),
                    wp.zeros(1, dtype=wp.uint64, device=d),
                ]
                self._dummy = {**getattr(self, "_dummy", {}), key: geo}
            count = 0
        ground = model.ground if self.ground else None
        on = ground is not None
        height = float(ground.height) if ground is not None else 0.0
        return [*geo, count, int(on), wp.float64(height)]

    # -------------------------------------------------------------------------------------- energy
    def _launch_mode(self, model, x, mode, scale, project, outputs) -> None:
        """Barrier value, gradient or (PSD-projected if ``project``) Hessian diagonal blocks."""
        d = model.device
        common = [
            wp.float64(self.dhat),
            wp.float64(self.stiffness(model)),
            mode,
            int(project),
            wp.float64(scale),
        ]
        launch(
            K.obstacle_barrier,
            model.particle_count,
            [*self._obstacles(model), model.particle_inv_mass, x, *common, *outputs],
            device=d,
        )
        lag = self._lag.get(id(model))
        if lag is not None:
            mu, lam, normal, x_start, eps, moving, shift = lag
            launch(
                F.friction_terms,
                model.particle_count,
                [
                    mu.shape[0],
                    mu,
                    lam,
                    normal,
                    x_start,
                    moving,
                    shift,
                    x,
                    wp.float64(eps),
                    mode,
                    wp.float64(scale),
                    *outputs,
                ],
                device=d,
            )
        s = self._surface(model)
        if s is None:
            return
        s.refit(model, x, None, self.dhat)
        assert s.tri_bvh is not None and s.edge_bvh is not None
        keys = [self._pattern(model)[1], model.particle_count]
        launch(
            K.point_triangle_barrier,
            s.points.shape[0],
            [s.points, s.tris, wp.uint64(s.tri_bvh.id), model.particle_inv_mass, *keys, x, *common, *outputs],
            device=d,
        )
        launch(
            K.edge_edge_barrier,
            s.edge_count,
            [s.edges, wp.uint64(s.edge_bvh.id), model.particle_inv_mass, *keys, x, *common, *outputs],
            device=d,
        )
        sl = self._self_lag.get(id(model))
        if sl is not None and sl[0].shape[0] > 0:
            quads, coef, lam, normal, x_start, eps = sl
            launch(
                F.self_friction_terms,
                quads.shape[0],
                [quads, coef, lam, normal, *keys, x_start, x, wp.float64(self.self_friction), wp.float64(eps)]
                + [mode, wp.float64(scale), *outputs],
                device=d,
            )

    def begin_step(self, model: Model, x: wp.array, v: wp.array, dt: float) -> None:
        """With moving colliders: their pose after the step Δt [s], where the barrier then acts. With
        ``friction``: freeze the normal forces λ = κ|b′(d)| [N], normals and the moving colliders' surface
        displacements at the step's start x [m] (ε = ε_v Δt)."""
        moving = self._moving()
        if moving:
            assert self.colliders is not None
            self._ahead[id(model)] = self.colliders.pose_ahead(model, dt)
            self._ahead_dt[id(model)] = float(dt)
        if not self.friction:
            return
        d = model.device
        n, c = model.particle_count, (len(self.colliders) if self.colliders is not None else 0)
        mus = [model.ground.friction if (self.ground and model.ground is not None) else 0.0]
        if self.colliders is not None:
            mus += [float(r["friction"]) for r in self.colliders._rows]
        lag = self._lag.get(id(model))
        if lag is None or lag[0].shape[0] != c + 1:
            lag = (
                wp.zeros(c + 1, dtype=wp.float64, device=d),
                wp.zeros(n * (c + 1), dtype=wp.float64, device=d),
                wp.zeros(n * (c + 1), dtype=wp.vec3d, device=d),
                wp.zeros(n, dtype=model.vec3, device=d),
                0.0,
                0,
                wp.zeros(n * (c + 1), dtype=wp.vec3d, device=d),
            )
        lag[0].assign(np.asarray(mus, np.float64))
        wp.copy(lag[3], x)
        ev = self.stick_velocity
        if ev is None:
            ev = model.ground.stick_velocity if model.ground is not None else STICK_VELOCITY
        self._lag[id(model)] = (*lag[:4], max(float(ev) * float(dt), 1e-12), int(moving), lag[6])
        motion = self._motion(model)
        launch(
            F.friction_lag,
            n,
            [
                *self._obstacles(model, start=True),
                model.particle_inv_mass,
                wp.float64(self.dhat),
                wp.float64(self.stiffness(model)),
                int(moving),
                *motion,
                model.s(dt),
                x,
                lag[1],
                lag[2],
                lag[6],
            ],
            device=d,
        )
        s = self._surface(model)
        if s is None or self.self_friction == 0:
            return
        pt, ee = self._candidates(model, s, x, self.dhat)
        quads = np.concatenate([pt, ee]).astype(np.int32).reshape(-1, 4)
        m = len(quads)
        flags = np.r_[np.zeros(len(pt), np.int32), np.ones(len(ee), np.int32)]
        sl: tuple = (
            wp.array(quads, dtype=wp.vec4i, device=d),
            wp.zeros(m, dtype=wp.vec4d, device=d),
            wp.zeros(m, dtype=wp.float64, device=d),
            wp.zeros(m, dtype=wp.vec3d, device=d),
            lag[3],
            self._lag[id(model)][4],
        )
        if m:
            launch(
                F.self_friction_lag,
                m,
                [sl[0], wp.array(flags, dtype=wp.int32, device=d), x, wp.float64(self.dhat)]
                + [wp.float64(self.stiffness(model)), sl[1], sl[2], sl[3]],
                device=d,
            )
        self._self_lag[id(model)] = sl

    def _motion(self, model: Model) -> list:
        """(vel, omega, centre) of the colliders now (the dummies' zeros without colliders)."""
        if self.colliders is not None:
            a = self.colliders.arrays(model)
            return [a["vel"], a["omega"], a["centre"]]
        dummy = self._obstacles(model)[1]  # a 1-element vec3 array of zeros
        return [dummy, dummy, dummy]

    def carried_start(self, model: Model, x_ref: wp.array) -> wp.array | None:
        """Where the minimiser starts from instead of ``x_ref`` [m] with moving colliders (None without):
        particles within reach of one carried by its rigid motion over the step (class docstring). Raises
        RuntimeError when a particle is clear of the colliders' end pose neither carried nor left."""
        ahead = self._ahead.get(id(model))
        if not self._moving() or ahead is None:
            return None
        assert self.colliders is not None
        d = model.device
        buf = self._carry.get(id(model))
        if buf is None:
            buf = (wp.zeros_like(x_ref), wp.zeros(1, dtype=wp.int32, device=d))
            self._carry[id(model)] = buf
        out, blocked = buf
        blocked.zero_()
        start = self._obstacles(model, start=True)
        a = self.colliders.arrays(model)
        h = float(self._ahead_dt[id(model)])
        launch(
            C.carry_start,
            model.particle_count,
            [*start[:6], a["vel"], a["omega"], a["centre"], *ahead[1:4], *start[6:]]
            + [model.s(h), model.s(self.dhat), model.particle_inv_mass, x_ref, out, blocked],
            device=d,
        )
        k = int(blocked.numpy()[0])
        if k:
            raise RuntimeError(
                f"BarrierContact: {k} particles would be inside a collider or the ground at the step's end "
                "whether carried by a moving collider or not (a kinematic collider squeezes them into an "
                "obstacle); move the collider clear, or lower dt"
            )
        return out

    # ----------------------------------------------------------------------------------- Hessian pattern
    def _pattern(self, model: Model) -> tuple[np.ndarray, wp.array, int]:
        p = self._keys.get(id(model))
        if p is None:
            p = (np.zeros(0, np.int64), wp.zeros(0, dtype=wp.int64, device=model.device), 0)
            self._keys[id(model)] = p
        return p

    def hessian_pattern(self, model: Model) -> tuple[np.ndarray, np.ndarray]:
        """One diagonal block per particle, then (i, j) and (j, i) for each point pair (i < j) of the
        self-contact pairs found by the last :meth:`refresh_pattern`."""
        n = model.particle_count
        keys = self._pattern(model)[0]
        i, j = (keys // n).astype(np.int32), (keys % n).astype(np.int32)
        d = np.arange(n, dtype=np.int32)
        rows = np.concatenate([d, np.stack([i, j], 1).ravel()])
        cols = np.concatenate([d, np.stack([j, i], 1).ravel()])
        return rows, cols

    def pattern_version(self, model: Model) -> int:
        """Changes whenever :meth:`hessian_pattern` does (the minimisers then rebuild their matrix)."""
        return self._pattern(model)[2]

    def _candidates(
        self, model: Model, s: _Surface, x: wp.array, radius: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """(point–triangle, edge–edge) pairs closer than ``radius`` [m] at x: int [K, 4] particle indices."""
        s.refit(model, x, None, radius)
        assert s.tri_bvh is not None and s.edge_bvh is not None
        d = model.device
        count = wp.zeros(1, dtype=wp.int32, device=d)
        out = []
        for kernel, dim, head in (
            (K.point_triangle_candidates, s.points.shape[0], [s.points, s.tris, wp.uint64(s.tri_bvh.id)]),
            (K.edge_edge_candidates, s.edge_count, [s.edges, wp.uint64(s.edge_bvh.id)]),
        ):
            cap = max(64, 4 * dim)
            while True:
                buf = wp.zeros(cap, dtype=wp.vec4i, device=d)
                count.zero_()
                launch(
                    kernel, dim, [*head, model.particle_inv_mass, x, wp.float64(radius), count, buf], device=d
                )
                k = int(count.numpy()[0])
                if k <= cap:
                    break
                cap = 2 * k
            out.append(buf.numpy()[:k].reshape(-1, 4))
        return out[0], out[1]

    def refresh_pattern(self, model: Model, x: wp.array) -> None:
        """Put into the pattern every point pair of the self-contact pairs closer than 2 d̂ at x [m] (the
        minimisers call it at the start of each step). Pairs that come closer only later in the step add
        their diagonal blocks alone until the next step; the pattern keeps its pairs while it is less than
        4 times the size that the current ones need."""
        s = self._surface(model)
        if s is None:
            return
        radius = 2.0 * self.dhat
        pt, ee = self._candidates(model, s, x, radius)
        quads = np.concatenate([pt, ee]).astype(np.int64)
        a, b = np.triu_indices(4, 1)
        lo = np.minimum(quads[:, a], quads[:, b]).ravel()
        hi = np.maximum(quads[:, a], quads[:, b]).ravel()
        need = np.unique(lo * model.particle_count + hi)
        keys, _, version = self._pattern(model)
        if np.isin(need, keys, assume_unique=True).all():
            return
        if keys.size < 4 * max(need.size, 1):
            need = np.union1d(keys, need)
        self._keys[id(model)] = (need, wp.array(need, dtype=wp.int64, device=model.device), version + 1)

    # ----------------------------------------------------------------------------------- step bound
    def max_step(self, model: Model, x: wp.array, dx: wp.array) -> float:
        """Largest α ≤ 1 found such that along x + t·dx, t ∈ [0, α], no contact pair comes closer than
        20 % of its distance at x (continuous collision detection; one host read)."""
        d = model.device
        a = self._alpha.get(id(model))
        if a is None:
            a = wp.zeros(1, dtype=model.scalar, device=d)
            self._alpha[id(model)] = a
        a.fill_(model.s(1.0))
        keep = wp.float64(C.KEEP_FRACTION)
        launch(
            C.obstacle_toi,
            model.particle_count,
            [*self._obstacles(model), model.particle_inv_mass, x, dx, keep, a],
            device=d,
        )
        s = self._surface(model)
        if s is not None:
            s.refit(model, x, dx, 1.0e-6)
            assert s.tri_bvh is not None and s.edge_bvh is not None
            launch(
                C.point_triangle_toi,
                s.points.shape[0],
                [s.points, s.tris, wp.uint64(s.tri_bvh.id), model.particle_inv_mass, x, dx, keep, a],
                device=d,
            )
            launch(
                C.edge_edge_toi,
                s.edge_count,
                [s.edges, wp.uint64(s.edge_bvh.id), model.particle_inv_mass, x, dx, keep, a],
                device=d,
            )
        return float(a.numpy()[0])

    def max_step_radius(self, model: Model, x: wp.array) -> float:
        """0: every step is checked by :meth:`max_step` (L-BFGS skips it for steps inside the radius)."""
        return 0.0


def barrier_pair_terms(
    points: np.ndarray, *, edge_edge: bool, dhat: float, project: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """b(d) [m²], its gradient [m] (K, 12) and Hessian (K, 12, 12) of K pairs, float64 on the CPU.

    Args:
        points: [K, 4, 3] positions [m]: a point and a triangle (``edge_edge`` False) or two edges.
        edge_edge: the pairs are edge–edge pairs.
        dhat: d̂ [m].
        project: project each Hessian to PSD.
    """
    p = np.asarray(points, np.float64).reshape(-1, 4, 3)
    k = len(p)
    x: wp.array = wp.array(p.reshape(-1, 3), dtype=wp.vec3d, device="cpu")
    v = wp.zeros(k, dtype=wp.float64, device="cpu")
    g = wp.zeros(k, dtype=K.vec12d, device="cpu")
    H = wp.zeros(k, dtype=K.mat12d, device="cpu")
    wp.launch(K.pair_terms, k, [x, int(edge_edge), wp.float64(dhat), int(project), v, g, H], device="cpu")
    return v.numpy(), g.numpy(), H.numpy()


def _refuse_compliant(colliders: Colliders, who: str) -> None:
    """ValueError naming the compliant colliders (``stiffness=`` κ): a barrier is hard contact."""
    soft = colliders.compliant()
    if soft:
        raise ValueError(
            f"{who}: colliders {soft} are compliant (stiffness=); a barrier keeps every particle outside, so "
            "drop stiffness= (or use the post-step response collisions=[colliders], which honours it)"
        )
