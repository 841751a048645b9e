"""ModelBuilder: collects particles and elements on the host, validates them, and finalizes a Model."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
import warp as wp

from .._warp import init, mat33_type, np_dtype, resolve_device, scalar_type, vec3_type
from ._checks import _as_index_array, _per_item
from ._model import STICK_VELOCITY, Ground, Model
from ._shapes import ShapesMixin


class ModelBuilder(ShapesMixin):
    """Collects particles, springs, triangles, tetrahedra and bending elements, then builds a Model.

    Every ``add_*`` validates its input and raises ``ValueError`` naming the element and the fix; nothing
    is silently dropped. Example::

        b = pl.ModelBuilder()
        b.add_cloth_grid(nx=32, ny=32, size=1.0, mass=0.2, stiffness=1e3, pin="top-corners")
        b.add_ground()
        model = b.finalize(device="cpu")

    Args:
        gravity: gravitational acceleration [m/s²] (x, y, z); y is up.
    """

    def __init__(self, *, gravity: Sequence[float] = (0.0, -9.81, 0.0)) -> None:
        g = tuple(float(v) for v in gravity)
        if len(g) != 3:
            raise ValueError(f"ModelBuilder: gravity must be 3 numbers (x, y, z) [m/s²], got {gravity!r}")
        self.gravity: tuple[float, float, float] = (g[0], g[1], g[2])
        self._q: list[np.ndarray] = []
        self._qd: list[np.ndarray] = []
        self._mass: list[np.ndarray] = []
        self._radius: list[np.ndarray] = []
        self._count = 0
        self._pinned: set[int] = set()
        self._kinematic: list[int] = []
        self._springs: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        self._tris: list[np.ndarray] = []
        self._tets: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._tets10: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._bending: list[tuple[np.ndarray, np.ndarray]] = []
        self._render_faces: list[np.ndarray] = []
        self._tet_host: list[np.ndarray] = []  # tets of every volume, FEM or not, for export
        self.ground: Ground | None = None
        self.objects: list[dict] = []
        self._worlds: dict | None = None  # set by replicate()

    # ------------------------------------------------------------------ particles
    @property
    def particle_count(self) -> int:
        """Number of particles added so far."""
        return self._count

    def positions(self) -> np.ndarray:
        """All particle positions added so far [m], shape [particle_count, 3]."""
        return np.concatenate(self._q) if self._q else np.zeros((0, 3))

    def add_particles(
        self,
        positions: npt.ArrayLike,
        mass: npt.ArrayLike,
        *,
        velocities: npt.ArrayLike | None = None,
        radius: npt.ArrayLike = 0.01,
        name: str = "particles",
    ) -> int:
        """Add particles; returns the index of the first one.

        Args:
            positions: [n, 3] positions [m].
            mass: [n] or scalar mass per particle [kg]; must be > 0 (pin particles to fix them).
            velocities: [n, 3] initial velocities [m/s] (zeros by default).
            radius: [n] or scalar contact radius [m].
            name: label used in error messages.
        """
        q = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        n = q.shape[0]
        if not np.all(np.isfinite(q)):
            bad = np.flatnonzero(~np.all(np.isfinite(q), axis=1))
            raise ValueError(
                f"{name}: {bad.size} particle positions are NaN/inf (first: {bad[:5].tolist()}); "
                "fix the mesh or the generator that produced them"
            )
        m = _per_item(mass, n, f"{name}: mass", "kg")
        if np.any(m <= 0):
            bad = np.flatnonzero(m <= 0)
            raise ValueError(
                f"{name}: {bad.size} particles have zero or negative mass (first: {bad[:5].tolist()}, "
                f"value {m[bad[0]]:g} kg); give a positive mass and pin particles that must not move"
            )
        qd = np.zeros_like(q) if velocities is None else np.asarray(velocities, np.float64).reshape(-1, 3)
        if qd.shape != q.shape:
            raise ValueError(f"{name}: velocities have shape {qd.shape}, expected {q.shape}")
        if not np.all(np.isfinite(qd)):
            raise ValueError(f"{name}: velocities contain NaN/inf; give finite values [m/s]")
        r = _per_item(radius, n, f"{name}: radius", "m")
        if np.any(r < 0):
            raise ValueError(f"{name}: radius must be >= 0 m")
        start = self._count
        self._q.append(q)
        self._qd.append(qd)
        self._mass.append(m)
        self._radius.append(r)
        self._count += n
        return start

    def particle_masses(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """A copy of the masses [kg] of particles ``start`` .. ``stop`` − 1 (None: to the last one added)."""
        if not self._mass:
            return np.zeros(0)
        return np.concatenate(self._mass)[start:stop].copy()

    def set_particle_masses(self, start: int, masses: npt.ArrayLike) -> None:
        """Replace the masses of particles ``start`` .. ``start + len(masses)`` − 1 (e.g. an object's, spread
        otherwise than its builder lumped them: :func:`pliant.model.distribute_mass`); pins are kept (a pinned
        particle's inverse mass stays 0 whatever its mass).

        Args:
            start: Index of the first particle to set.
            masses: [n] masses [kg], each finite and > 0.
        """
        m = np.asarray(masses, dtype=np.float64).reshape(-1)
        if start < 0 or start + m.size > self._count:
            raise ValueError(
                f"set_particle_masses: particles [{start}, {start + m.size}) are not all added "
                f"(there are {self._count}); add the particles first"
            )
        if not np.all(np.isfinite(m) & (m > 0)):
            raise ValueError("set_particle_masses: masses must be finite and > 0 kg; pin particles instead")
        whole = np.concatenate(self._mass)
        whole[start : start + m.size] = m
        self._mass = [whole]

    def _check_range(self, idx: np.ndarray, what: str) -> None:
        if idx.size and (idx.min() < 0 or idx.max() >= self._count):
            bad = np.flatnonzero(np.any((idx < 0) | (idx >= self._count), axis=1))
            raise ValueError(
                f"{what} {bad[0]} refers to particle {idx[bad[0]].tolist()}, out of range "
                f"[0, {self._count}); add the particles first or fix the indices ({bad.size} bad {what}s)"
            )

    def pin(self, indices: npt.ArrayLike) -> None:
        """Fix particles in place (infinite mass: inverse mass 0).

        Args:
            indices: global particle indices (int or sequence of ints) to fix.
        """
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        self._check_range(idx.reshape(-1, 1), "pin")
        self._pinned.update(int(i) for i in idx)

    def add_kinematic(self, indices: npt.ArrayLike) -> None:
        """Mark particles as kinematic: their positions follow ``Control.kinematic_targets``.

        Args:
            indices: global particle indices (int or sequence of ints) driven by the targets [m].
        """
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        self._check_range(idx.reshape(-1, 1), "kinematic particle")
        self._kinematic.extend(int(i) for i in idx)

    # ------------------------------------------------------------------ elements
    def add_springs(
        self,
        indices: npt.ArrayLike,
        *,
        stiffness: npt.ArrayLike,
        damping: npt.ArrayLike = 0.0,
        rest_length: npt.ArrayLike | None = None,
    ) -> None:
        """Add springs between particle pairs.

        Args:
            indices: [S, 2] particle indices.
            stiffness: [S] or scalar spring constant k [N/m], >= 0.
            damping: [S] or scalar dashpot coefficient γ [N s/m] acting along the spring axis.
            rest_length: [S] rest lengths [m]; default the current distance.
        """
        idx = _as_index_array(indices, 2, "spring")
        self._check_range(idx, "spring")
        s = idx.shape[0]
        if s == 0:
            return
        if np.any(idx[:, 0] == idx[:, 1]):
            bad = np.flatnonzero(idx[:, 0] == idx[:, 1])
            raise ValueError(f"spring {bad[0]} connects particle {idx[bad[0], 0]} to itself; remove it")
        q = self.positions()
        if rest_length is None:
            rest = np.linalg.norm(q[idx[:, 0]] - q[idx[:, 1]], axis=1)
        else:
            rest = _per_item(rest_length, s, "spring rest_length", "m")
        if np.any(rest <= 0):
            bad = np.flatnonzero(rest <= 0)
            raise ValueError(
                f"spring {bad[0]} between particles {idx[bad[0]].tolist()} has zero rest length; "
                "its endpoints coincide: merge the duplicate particles or give rest_length > 0"
            )
        k = _per_item(stiffness, s, "spring stiffness", "N/m")
        g = _per_item(damping, s, "spring damping", "N s/m")
        if np.any(k < 0) or np.any(g < 0):
            raise ValueError("spring stiffness [N/m] and damping [N s/m] must be >= 0")
        self._springs.append((idx, rest, k, g))

    def add_triangles(self, indices: npt.ArrayLike, *, render: bool = True) -> None:
        """Add surface triangles (used for rendering, bending, collisions); rejects degenerate ones.

        Args:
            indices: [F, 3] particle indices per triangle.
            render: also draw these triangles (renderer and mesh export).
        """
        idx = _as_index_array(indices, 3, "triangle")
        self._check_range(idx, "triangle")
        q = self.positions()
        a, b, c = q[idx[:, 0]], q[idx[:, 1]], q[idx[:, 2]]
        area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)
        scale = np.maximum.reduce([np.sum((b - a) ** 2, 1), np.sum((c - a) ** 2, 1), np.sum((c - b) ** 2, 1)])
        bad = np.flatnonzero(area2 <= 1e-12 * np.maximum(scale, 1e-300))
        if bad.size:
            raise ValueError(
                f"{bad.size} triangles are degenerate (zero area; first: {bad[:5].tolist()}, vertices "
                f"{idx[bad[0]].tolist()}); remove them or merge their collinear/duplicate vertices"
            )
        self._tris.append(idx)
        if render:
            self._render_faces.append(idx)

    def add_tetrahedra(
        self,
        indices: npt.ArrayLike,
        *,
        E: npt.ArrayLike,
        nu: npt.ArrayLike,
        fix_orientation: bool = False,
    ) -> None:
        """Add linear tetrahedral elements with Young's modulus ``E`` [Pa] and Poisson ratio ``nu``.

        Inverted (negative-volume) tets raise unless ``fix_orientation``; degenerate ones always raise.

        Args:
            indices: [E, 4] particle indices per tetrahedron.
            E: [E] or scalar Young's modulus [Pa], > 0.
            nu: [E] or scalar Poisson ratio [-], in (-1, 0.5).
            fix_orientation: swap two vertices of inverted tets instead of raising.
        """
        from ._materials import lame_parameters

        idx = _as_index_array(indices, 4, "tetrahedron")
        self._check_range(idx, "tetrahedron")
        n = idx.shape[0]
        idx = self._oriented_tets(idx, fix_orientation, "tetrahedra")
        E_arr = _per_item(E, n, "Young's modulus E", "Pa")
        nu_arr = _per_item(nu, n, "Poisson ratio nu", "-")
        mu, lam = lame_parameters(E_arr, nu_arr)
        self._tets.append((idx, np.broadcast_to(mu, (n,)).copy(), np.broadcast_to(lam, (n,)).copy()))

    def _oriented_tets(self, idx: np.ndarray, fix_orientation: bool, what: str) -> np.ndarray:
        """``idx`` with its corners (columns 0–3) checked: degenerate tets raise, inverted ones raise
        unless ``fix_orientation`` (then corners 2 and 3 are swapped; a copy is returned)."""
        q = self.positions()
        x0 = q[idx[:, 0]]
        dm = np.stack([q[idx[:, 1]] - x0, q[idx[:, 2]] - x0, q[idx[:, 3]] - x0], axis=2)
        det = np.linalg.det(dm)
        edge = np.max(np.linalg.norm(dm, axis=1), axis=1)
        degenerate = np.abs(det) <= 1e-9 * np.maximum(edge, 1e-300) ** 3
        if np.any(degenerate):
            bad = np.flatnonzero(degenerate)
            raise ValueError(
                f"{bad.size} {what} are degenerate (zero volume; first: {bad[:5].tolist()}, vertices "
                f"{idx[bad[0]].tolist()}); remesh with quality settings (pliant.geometry.tetrahedralize)"
            )
        inverted = det < 0
        if np.any(inverted):
            if not fix_orientation:
                bad = np.flatnonzero(inverted)
                raise ValueError(
                    f"{bad.size} {what} are inverted (negative volume; first: {bad[:5].tolist()}); "
                    "reorder their vertices or pass fix_orientation=True"
                )
            idx = idx.copy()
            idx[inverted, 2], idx[inverted, 3] = idx[inverted, 3], idx[inverted, 2].copy()
        return idx

    def add_quadratic_tetrahedra(
        self,
        indices: npt.ArrayLike,
        *,
        E: npt.ArrayLike,
        nu: npt.ArrayLike,
    ) -> None:
        """Add quadratic (10-node, P2) tetrahedra with Young's modulus ``E`` [Pa] and Poisson ratio ``nu``.

        Node order: corners 0–3, then the mid-edge nodes of (0,1), (1,2), (0,2), (0,3), (1,3), (2,3) (VTK
        and TetGen ``-o2``; :func:`pliant.geometry.promote_tets_p2` makes them from a linear mesh). Elements
        are straight-sided: each mid-edge node must sit at its edge's midpoint. The node masses are the
        caller's (``add_tet_mesh(..., order=2)`` lumps ρV with :func:`pliant.geometry.p2_lumped_masses`).

        Args:
            indices: [E, 10] particle indices per element.
            E: [E] or scalar Young's modulus [Pa], > 0.
            nu: [E] or scalar Poisson ratio [-], in (-1, 0.5).
        """
        from ..geometry import P2_EDGES
        from ._materials import lame_parameters

        idx = _as_index_array(indices, 10, "quadratic tetrahedron")
        self._check_range(idx, "quadratic tetrahedron")
        n = idx.shape[0]
        idx = self._oriented_tets(idx, False, "quadratic tetrahedra")
        q = self.positions()
        mid = 0.5 * (q[idx[:, P2_EDGES[:, 0]]] + q[idx[:, P2_EDGES[:, 1]]])  # [E, 6, 3]
        edge = np.linalg.norm(q[idx[:, P2_EDGES[:, 0]]] - q[idx[:, P2_EDGES[:, 1]]], axis=2)
        off = np.linalg.norm(q[idx[:, 4:]] - mid, axis=2) > 1e-6 * np.maximum(edge, 1e-300)
        if np.any(off):
            bad = np.flatnonzero(off.any(axis=1))
            raise ValueError(
                f"{bad.size} quadratic tetrahedra have mid-edge nodes off their edge midpoints (first: "
                f"{bad[:5].tolist()}); only straight-sided elements are supported: place nodes 4-9 at the "
                "midpoints of edges (0,1), (1,2), (0,2), (0,3), (1,3), (2,3)"
            )
        E_arr = _per_item(E, n, "Young's modulus E", "Pa")
        nu_arr = _per_item(nu, n, "Poisson ratio nu", "-")
        mu, lam = lame_parameters(E_arr, nu_arr)
        self._tets10.append((idx, np.broadcast_to(mu, (n,)).copy(), np.broadcast_to(lam, (n,)).copy()))

    def add_bending(self, indices: npt.ArrayLike, *, stiffness: npt.ArrayLike) -> None:
        """Add dihedral bending elements: shared edge (0, 1), opposite vertices (2, 3).

        Args:
            indices: [B, 4] particle indices per element.
            stiffness: [B] or scalar bending stiffness [N m/rad].
        """
        idx = _as_index_array(indices, 4, "bending element")
        self._check_range(idx, "bending element")
        if idx.shape[0]:
            self._bending.append((idx, _per_item(stiffness, idx.shape[0], "bending stiffness", "N m/rad")))

    def add_ground(
        self,
        height: float = 0.0,
        *,
        friction: float = 0.5,
        restitution: float = 0.0,
        stick_velocity: float = STICK_VELOCITY,
        stiffness: float | None = None,
        damping_ratio: float = 0.0,
        friction_law: str = "coulomb",
    ) -> None:
        """Add the ground plane y = ``height``.

        Args:
            height: height of the plane [m].
            friction: Coulomb friction coefficient μ [-], >= 0.
            restitution: normal restitution coefficient [-], in [0, 1].
            stick_velocity: ε_v [m/s], >= 0: the smoothed Coulomb law's static-friction ramp (a contact
                loaded inside the friction cone creeps below ε_v; 0: exact Coulomb, with a kink).
            stiffness: κ [1/s²] > 0 of compliant contact (a normal spring κ d per unit mass; rests g/κ
                deep); None: hard contact (projection and restitution).
            damping_ratio: ζ [-] >= 0 of compliant contact's damper b = 2ζ√κ (MuJoCo's dampratio).
            friction_law: the name of a law in :data:`pliant.collision.FRICTION_LAWS` ("coulomb": smoothed
                Coulomb, "coulomb_exact": unsmoothed); checked when a solver is set up.
        """
        if friction < 0:
            raise ValueError(f"ground friction must be >= 0, got {friction}")
        if not 0 <= restitution <= 1:
            raise ValueError(f"ground restitution must be in [0, 1], got {restitution}")
        if not (math.isfinite(stick_velocity) and stick_velocity >= 0):
            raise ValueError(f"ground stick_velocity must be >= 0 m/s, got {stick_velocity}")
        if stiffness is not None and not (math.isfinite(stiffness) and stiffness > 0):
            raise ValueError(f"ground stiffness must be > 0 1/s² (or None: hard contact), got {stiffness}")
        if not (math.isfinite(damping_ratio) and damping_ratio >= 0):
            raise ValueError(f"ground damping_ratio must be >= 0, got {damping_ratio}")
        if not (isinstance(friction_law, str) and friction_law):
            raise ValueError(
                f"ground friction_law must be a law's name (e.g. 'coulomb'), got {friction_law!r}"
            )
        if damping_ratio > 0 and stiffness is None:
            raise ValueError(
                "ground damping_ratio needs a stiffness (compliant contact): give stiffness= too"
            )
        kappa = None if stiffness is None else float(stiffness)
        self.ground = Ground(
            float(height),
            float(friction),
            float(restitution),
            float(stick_velocity),
            kappa,
            float(damping_ratio),
            friction_law,
        )

    # ------------------------------------------------------------------ shapes
    def register_object(self, name: str, kind: str, start: int, **extra: Any) -> None:
        """Record particles ``start`` .. ``particle_count`` (added last) as one named object of ``kind``.

        ``add_*`` shape methods call it; call it after :meth:`add_particles` for a body made by hand, so that
        ``model.objects`` (ranges used by renderers, handles and scene files) lists it. ``extra`` items are
        stored with it (e.g. ``nx``, ``ny`` of a cloth grid).

        Args:
            name: the object's name.
            kind: its kind label (``"cloth"``, ``"rope"``, ...).
            start: index of its first particle.
            **extra: more items stored with the record.
        """
        self.objects.append(
            {"name": name, "kind": kind, "start": start, "count": self._count - start, **extra}
        )

    def replicate(self, n: int, *, spacing: Sequence[float] = (0.0, 0.0, 0.0)) -> None:
        """Turn everything added so far into world 0 and append ``n`` − 1 independent copies (worlds).

        Each world's particles and elements are one contiguous block (``model.world_slice``); no element
        couples two worlds, so all are stepped by the same launches and every solver treats them as one
        block-diagonal model. Per-world parameters: ``model.set_world_parameter`` /
        ``set_world_material`` / ``set_world_state``; per-world reset: ``model.reset_world``; per-world
        output: ``Trajectory.world(w)``. Call it last: nothing may be added afterwards.

        Args:
            n: number of worlds, >= 1.
            spacing: offset [m] between consecutive worlds' positions (for viewing; the ground is shared).

        Raises:
            ValueError: n < 1, nothing added yet, or called twice.
        """
        from ._worlds import replicate

        replicate(self, n, spacing)

    def _host_springs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Springs as host arrays (indices [S, 2], rest length m, stiffness N/m, damping N s/m); a particle
        pair with two springs is an error."""
        if self._springs:
            s_idx = np.concatenate([s[0] for s in self._springs])
            s_rest, s_k, s_g = (np.concatenate([s[i] for s in self._springs]) for i in (1, 2, 3))
            key = np.sort(s_idx, axis=1)
            _, first_seen, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
            if np.any(counts > 1):
                dup = key[first_seen[np.flatnonzero(counts > 1)[0]]]
                raise ValueError(
                    f"{int(np.sum(counts > 1))} duplicate springs (first between particles {dup.tolist()}); "
                    "each particle pair may have one spring: merge their stiffnesses into one spring"
                )
        else:
            s_idx, s_rest, s_k, s_g = np.zeros((0, 2), np.int32), np.zeros(0), np.zeros(0), np.zeros(0)
        return s_idx, s_rest, s_k, s_g

    def _host_tets(self, q: np.ndarray) -> tuple[np.ndarray, ...]:
        """Linear tets as host arrays: indices [T, 4], Lamé μ and λ (Pa), rest volume (m³) and inverse rest
        edge matrix [T, 3, 3] (1/m) at positions ``q`` [N, 3]."""
        if self._tets:
            t_idx = np.concatenate([t[0] for t in self._tets])
            t_mu = np.concatenate([t[1] for t in self._tets])
            t_lam = np.concatenate([t[2] for t in self._tets])
            x0 = q[t_idx[:, 0]]
            dm = np.stack([q[t_idx[:, 1]] - x0, q[t_idx[:, 2]] - x0, q[t_idx[:, 3]] - x0], axis=2)
            t_vol = np.linalg.det(dm) / 6.0
            t_inv = np.linalg.inv(dm)
        else:
            t_idx, t_mu, t_lam = np.zeros((0, 4), np.int32), np.zeros(0), np.zeros(0)
            t_vol, t_inv = np.zeros(0), np.zeros((0, 3, 3))
        return t_idx, t_mu, t_lam, t_vol, t_inv

    def _host_bending(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Bending elements as host arrays: indices [B, 4], stiffness and rest dihedral angle (rad) at
        positions ``q`` [N, 3]."""
        if self._bending:
            b_idx = np.concatenate([b[0] for b in self._bending])
            b_k = np.concatenate([b[1] for b in self._bending])
            b_rest = _dihedral_angles(q, b_idx)
        else:
            b_idx, b_k, b_rest = np.zeros((0, 4), np.int32), np.zeros(0), np.zeros(0)
        return b_idx, b_k, b_rest

    # ------------------------------------------------------------------ finalize
    def finalize(
        self, device: str | None = None, dtype: str = "float32", requires_grad: bool = False
    ) -> Model:
        """Validate everything and copy it to ``device`` as a :class:`Model` in ``dtype``.

        Args:
            device: Warp device (``"cpu"``, ``"cuda"``, ``"cuda:0"``); None: CUDA when present, else CPU.
            dtype: ``"float32"`` or ``"float64"``.
            requires_grad: allocate arrays that record gradients (differentiable runs).
        """
        from ._worlds import offsets

        world_offsets = offsets(self)  # checks that nothing was added after replicate()
        init()
        device = resolve_device(device)
        f = np_dtype(dtype)
        vec3, mat33, scalar = vec3_type(dtype), mat33_type(dtype), scalar_type(dtype)
        if self._count == 0:
            raise ValueError("the model has no particles; add a rope, cloth, volume or particles first")
        q = np.concatenate(self._q)
        qd = np.concatenate(self._qd)
        mass = np.concatenate(self._mass)
        radius = np.concatenate(self._radius)
        inv_mass = 1.0 / mass
        fixed = sorted(self._pinned | set(self._kinematic))
        inv_mass[fixed] = 0.0
        qd[fixed] = 0.0

        s_idx, s_rest, s_k, s_g = self._host_springs()
        tris = np.concatenate(self._tris) if self._tris else np.zeros((0, 3), np.int32)
        t_idx, t_mu, t_lam, t_vol, t_inv = self._host_tets(q)
        b_idx, b_k, b_rest = self._host_bending(q)

        def arr(a: np.ndarray, wp_type: type, rg: bool = False) -> wp.array:
            return wp.array(a, dtype=wp_type, device=device, requires_grad=rg)

        def ints(a: np.ndarray, width: int) -> wp.array:
            return wp.array(a.reshape(-1, width).astype(np.int32), dtype=wp.int32, device=device)

        p2 = {}
        if self._tets10:
            from ..geometry import p2_subtets

            t10 = np.concatenate([t[0] for t in self._tets10])
            x0 = q[t10[:, 0]]
            dm = np.stack([q[t10[:, 1]] - x0, q[t10[:, 2]] - x0, q[t10[:, 3]] - x0], axis=2)
            p2 = dict(
                tet10_count=t10.shape[0],
                tet10_indices=ints(t10, 10),
                tet10_rest_inv=arr(np.linalg.inv(dm).astype(f), mat33),
                tet10_rest_volume=arr((np.linalg.det(dm) / 6.0).astype(f), scalar),
                tet10_mu=arr(np.concatenate([t[1] for t in self._tets10]).astype(f), scalar, requires_grad),
                tet10_lam=arr(np.concatenate([t[2] for t in self._tets10]).astype(f), scalar, requires_grad),
                tet10_subtets=ints(p2_subtets(q, t10), 4),
            )
        faces = np.concatenate(self._render_faces) if self._render_faces else np.zeros((0, 3), np.int32)
        tet_host = np.concatenate(self._tet_host) if self._tet_host else t_idx
        return Model(
            device=device,
            dtype=dtype,
            requires_grad=requires_grad,
            particle_count=self._count,
            particle_q=arr(q.astype(f), vec3, requires_grad),
            particle_qd=arr(qd.astype(f), vec3, requires_grad),
            particle_mass=arr(mass.astype(f), scalar),
            particle_inv_mass=arr(inv_mass.astype(f), scalar),
            particle_radius=arr(radius.astype(f), scalar),
            spring_count=s_idx.shape[0],
            spring_indices=ints(s_idx, 2),
            spring_rest_length=arr(s_rest.astype(f), scalar, requires_grad),
            spring_stiffness=arr(s_k.astype(f), scalar, requires_grad),
            spring_damping=arr(s_g.astype(f), scalar, requires_grad),
            tri_count=tris.shape[0],
            tri_indices=ints(tris, 3),
            tet_count=t_idx.shape[0],
            tet_indices=ints(t_idx, 4),
            tet_rest_inv=arr(t_inv.astype(f), mat33),
            tet_rest_volume=arr(t_vol.astype(f), scalar),
            tet_mu=arr(t_mu.astype(f), scalar, requires_grad),
            tet_lam=arr(t_lam.astype(f), scalar, requires_grad),
            bending_count=b_idx.shape[0],
            bending_indices=ints(b_idx, 4),
            bending_rest_angle=arr(b_rest.astype(f), scalar),
            bending_stiffness=arr(b_k.astype(f), scalar, requires_grad),
            gravity=self.gravity,
            ground=self.ground,
            particle_q_np=q,
            particle_mass_np=mass,
            kinematic_indices_np=np.asarray(self._kinematic, np.int32),
            render_faces=faces.astype(np.int32),
            tet_indices_np=tet_host.astype(np.int32),
            objects=list(self.objects),
            world_count=1 if self._worlds is None else self._worlds["count"],
            world_offsets=world_offsets,
            **p2,
        )


def _dihedral_angles(q: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Signed dihedral angle [rad] of each bending element (0 when flat)."""
    x0, x1, x2, x3 = (q[b[:, i]] for i in range(4))
    e = x1 - x0
    n1 = np.cross(e, x2 - x0)
    n2 = np.cross(x3 - x0, e)
    n1 /= np.maximum(np.linalg.norm(n1, axis=1, keepdims=True), 1e-300)
    n2 /= np.maximum(np.linalg.norm(n2, axis=1, keepdims=True), 1e-300)
    e_hat = e / np.maximum(np.linalg.norm(e, axis=1, keepdims=True), 1e-300)
    cos = np.clip(np.sum(n1 * n2, axis=1), -1.0, 1.0)
    sin = np.sum(np.cross(n1, n2) * e_hat, axis=1)
    return np.arctan2(sin, cos)
