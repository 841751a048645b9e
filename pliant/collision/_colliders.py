"""Static colliders — sphere, box, capsule, triangle mesh — as signed distance fields.

Each collider is a signed distance φ(p) [m] (negative inside) with its gradient n = ∇φ (the outward
normal) and Hessian ∇²φ. Two responses use them:

* :meth:`Colliders.apply`, a velocity-level response after an (explicit) step, like the ground plane:
  particles closer than their radius are pushed out along n, the normal velocity is reflected with
  restitution e, and Coulomb friction stops the tangential velocity if it is at most μ·Δv_n and removes
  μ·Δv_n of it otherwise (so a block sliding on a collider decelerates by μ g, and one resting on a slope
  inside the friction cone stays put: :mod:`pliant.collision._friction`);
* :class:`pliant.energies.ColliderPenalty`, E = ½ k Σ max(0, r − φ)², a smooth term with an exact Hessian
  for implicit solvers.

Meshes use ``wp.Mesh`` (a BVH) and ``wp.mesh_query_point``: they must be closed and consistently wound for
the inside/outside sign; their Hessian omits the curvature term (exact on faces, Gauss–Newton elsewhere).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt
import warp as wp

from .._warp import GradientError, fresh, launch
from ..model import STICK_VELOCITY, Found, Getter, Parameter, declares
from ._collider_sdf import collider_contact, collider_sdf

if TYPE_CHECKING:
    from ..model import Control, Model, State

SPHERE, BOX, CAPSULE, MESH = 0, 1, 2, 3
_KIND_NAMES = {SPHERE: "sphere", BOX: "box", CAPSULE: "capsule", MESH: "mesh"}


@wp.kernel
def collider_response(
    first: int,
    end: int,
    # Colliders:
    kind: wp.array(dtype=wp.int32),
    pos: wp.array(dtype=Any),
    aux: wp.array(dtype=Any),
    rot: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    mesh: wp.array(dtype=wp.uint64),
    friction: wp.array(dtype=Any),
    restitution: wp.array(dtype=Any),
    stick_velocity: Any,
    dt: Any,
    # Model:
    particle_inv_mass: wp.array(dtype=Any),
    particle_radius: wp.array(dtype=Any),
    # State in:
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    # Out:
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    """Colliders ``first`` to ``end`` − 1 in turn (:func:`collider_contact`): reads (x_in, v_in), writes
    every particle's (x_out, v_out), which may be the inputs (an in-place update).

    Recorded steps launch one collider at a time (``end`` = ``first`` + 1), which runs no loop: Warp's
    adjoint re-runs a dynamic loop's body with the values its variables hold after the loop, so x and v
    carried through the colliders in a loop would get a wrong gradient. The gradient-free step launches all
    colliders at once and carries x and v through them in registers.
    """
    i = wp.tid()
    x = x_in[i]
    v = v_in[i]
    r = particle_radius[i]
    eps = stick_velocity
    if particle_inv_mass[i] != r * type(r)(0.0):
        if end == first + 1:
            k = first
            x, v = collider_contact(
                kind[k],
                pos[k],
                aux[k],
                rot[k],
                radius[k],
                mesh[k],
                friction[k],
                restitution[k],
                eps,
                dt,
                r,
                x,
                v,
            )
        else:
            for c in range(first, end):
                x, v = collider_contact(
                    kind[c],
                    pos[c],
                    aux[c],
                    rot[c],
                    radius[c],
                    mesh[c],
                    friction[c],
                    restitution[c],
                    eps,
                    dt,
                    r,
                    x,
                    v,
                )
    x_out[i] = x
    v_out[i] = v


@wp.kernel
def _collider_query(
    kind: wp.array(dtype=wp.int32),
    pos: wp.array(dtype=Any),
    aux: wp.array(dtype=Any),
    rot: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    mesh: wp.array(dtype=wp.uint64),
    x_in: wp.array(dtype=Any),
    phi_out: wp.array(dtype=Any),
    n_out: wp.array(dtype=Any),
):
    i = wp.tid()
    best = radius[0] * type(radius[0])(0.0) + type(radius[0])(1.0e30)
    for c in range(kind.shape[0]):
        phi, n, H = collider_sdf(kind[c], pos[c], aux[c], rot[c], radius[c], mesh[c], x_in[i])
        if phi < best:
            best = phi
            n_out[i] = n
    phi_out[i] = best


def _rotation_matrix(rotation: npt.ArrayLike | None) -> np.ndarray:
    if rotation is None:
        return np.eye(3)
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape == (3, 3):
        if not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
            raise ValueError("box rotation must be a proper rotation matrix (orthonormal, det +1)")
        return r
    if r.shape == (4,):  # quaternion (x, y, z, w)
        x, y, z, w = r / np.linalg.norm(r)
        return np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )
    raise ValueError(f"box rotation must be a 3x3 matrix or an (x, y, z, w) quaternion, got shape {r.shape}")


def _vec(v: npt.ArrayLike, what: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{what} must be 3 finite numbers [m], got {v!r}")
    return a


def _collider_array(key: str) -> Getter:
    def get(model: Model, solver: object, state0: State, control: Control | None) -> Found:
        from .._warp import GradientError

        found = [c for c in getattr(solver, "collisions", ()) if callable(getattr(c, "apply_out", None))]
        if len(found) != 1:
            raise GradientError(
                f"'collider_{key}' needs exactly one pl.collision.Colliders in the solver's collisions= "
                f"(found {len(found)})"
            )
        return found[0].arrays(model)[key]

    return get


@declares
class Colliders:
    """A set of static colliders with Coulomb friction μ and restitution e each.

    Example::

        colliders = pl.collision.Colliders()
        colliders.add_sphere((0, 0.3, 0), 0.25, friction=0.3)
        colliders.add_box((0, -0.05, 0), (1, 0.05, 1))
        solver = pl.solvers.FastMassSpring(model, collisions=[colliders])
        # or, after any solver's step: colliders.apply(model, state_0, state_1, dt)

    Args:
        stick_velocity: ε_v [m/s] >= 0 of every collider's smoothed Coulomb friction (a contact loaded
            inside the friction cone creeps below ε_v; 0: exact Coulomb, with a kink at stick/slip;
            :mod:`pliant.collision._friction`).
    """

    @classmethod
    def parameters(cls) -> tuple[Parameter, ...]:
        """Per collider: Coulomb μ, restitution e and centre (ForceSolver's recorded contact)."""
        return (
            Parameter(
                "collider_friction",
                "Coulomb friction coefficient per collider",
                "1",
                "collider",
                ("collider.friction",),
                (0.0, 2.0),
                log=False,
                get=_collider_array("friction"),
            ),
            Parameter(
                "collider_restitution",
                "restitution coefficient per collider",
                "1",
                "collider",
                ("collider.restitution",),
                (0.0, 1.0),
                log=False,
                get=_collider_array("restitution"),
            ),
            Parameter(
                "collider_pos",
                "centre of each collider",
                "m",
                "collider",
                ("collider.pos",),
                None,
                log=False,
                sign="any",
                get=_collider_array("pos"),
            ),
        )

    def __init__(self, *, stick_velocity: float = STICK_VELOCITY) -> None:
        if not (np.isfinite(stick_velocity) and stick_velocity >= 0):
            raise ValueError(f"Colliders: stick_velocity must be >= 0 m/s, got {stick_velocity}")
        self.stick_velocity = float(stick_velocity)
        self._rows: list[tuple] = []
        self._meshes: list[tuple[np.ndarray, np.ndarray]] = []
        self._cache: dict = {}

    def __len__(self) -> int:
        return len(self._rows)

    def _add(self, kind, pos, aux, rot, radius, friction, restitution, mesh=-1) -> int:
        if friction < 0:
            raise ValueError(f"collider friction μ must be >= 0, got {friction}")
        if not 0.0 <= restitution <= 1.0:
            raise ValueError(f"collider restitution e must be in [0, 1], got {restitution}")
        self._rows.append((kind, pos, aux, rot, float(radius), float(friction), float(restitution), mesh))
        self._cache.clear()
        return len(self._rows) - 1

    def add_sphere(
        self, center: Sequence[float], radius: float, *, friction: float = 0.5, restitution: float = 0.0
    ) -> int:
        """A sphere.

        Args:
            center: centre [m].
            radius: radius [m], > 0.
            friction: Coulomb friction coefficient μ [-], >= 0.
            restitution: normal restitution coefficient e [-], in [0, 1].

        Returns:
            The collider's index.
        """
        if radius <= 0:
            raise ValueError(f"sphere radius must be > 0 m, got {radius}")
        c = _vec(center, "sphere center")
        return self._add(SPHERE, c, np.zeros(3), np.eye(3), radius, friction, restitution)

    def add_box(
        self,
        center: Sequence[float],
        half_extents: Sequence[float],
        *,
        rotation: npt.ArrayLike | None = None,
        rounding: float = 0.0,
        friction: float = 0.5,
        restitution: float = 0.0,
    ) -> int:
        """A box, optionally rotated and with rounded edges.

        Args:
            center: centre [m].
            half_extents: half side lengths along the box's own axes [m], each > 0.
            rotation: world-from-box rotation [-], a 3×3 matrix or an (x, y, z, w) quaternion; None: axis
                aligned.
            rounding: radius [m] the surface is offset outwards by (rounded edges and corners), >= 0.
            friction: Coulomb friction coefficient μ [-], >= 0.
            restitution: normal restitution coefficient e [-], in [0, 1].

        Returns:
            The collider's index.
        """
        he = _vec(half_extents, "box half_extents")
        if np.any(he <= 0):
            raise ValueError(f"box half_extents must be > 0 m, got {half_extents}")
        if rounding < 0:
            raise ValueError(f"box rounding must be >= 0 m, got {rounding}")
        c = _vec(center, "box center")
        return self._add(BOX, c, he, _rotation_matrix(rotation), rounding, friction, restitution)

    def add_capsule(
        self,
        a: Sequence[float],
        b: Sequence[float],
        radius: float,
        *,
        friction: float = 0.5,
        restitution: float = 0.0,
    ) -> int:
        """A capsule: the segment a–b thickened by ``radius``.

        Args:
            a: first end of the axis segment [m].
            b: second end of the axis segment [m].
            radius: radius [m], > 0.
            friction: Coulomb friction coefficient μ [-], >= 0.
            restitution: normal restitution coefficient e [-], in [0, 1].

        Returns:
            The collider's index.
        """
        pa, pb = _vec(a, "capsule a"), _vec(b, "capsule b")
        if radius <= 0:
            raise ValueError(f"capsule radius must be > 0 m, got {radius}")
        if np.linalg.norm(pb - pa) == 0:
            raise ValueError("capsule endpoints coincide; use add_sphere")
        return self._add(CAPSULE, pa, pb, np.eye(3), radius, friction, restitution)

    def add_mesh(
        self,
        vertices: npt.ArrayLike,
        faces: npt.ArrayLike,
        *,
        friction: float = 0.5,
        restitution: float = 0.0,
    ) -> int:
        """A closed, outward-wound triangle mesh, queried through a BVH.

        Args:
            vertices: [V, 3] vertex positions [m].
            faces: [F, 3] vertex indices per triangle (counter-clockwise seen from outside).
            friction: Coulomb friction coefficient μ [-], >= 0.
            restitution: normal restitution coefficient e [-], in [0, 1].

        Returns:
            The collider's index.
        """
        v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        if f.size == 0 or f.min() < 0 or f.max() >= v.shape[0]:
            raise ValueError(f"mesh faces must index the {v.shape[0]} vertices and be non-empty")
        self._meshes.append((v, f.astype(np.int32)))
        return self._add(
            MESH, np.zeros(3), np.zeros(3), np.eye(3), 0.0, friction, restitution, len(self._meshes) - 1
        )

    # ------------------------------------------------------------------ device data
    def arrays(self, model: Model) -> dict:
        """Device arrays of the colliders in the model's device and dtype (built once, then cached)."""
        key = (str(model.device), model.dtype)
        if key in self._cache:
            return self._cache[key]
        if not self._rows:
            raise ValueError("no colliders: add a sphere, box, capsule or mesh first")
        d = model.device
        meshes = [
            wp.Mesh(
                points=wp.array(v, dtype=wp.vec3f, device=d),
                indices=wp.array(f.ravel(), dtype=wp.int32, device=d),
            )
            for v, f in self._meshes
        ]
        rows = self._rows
        rg = bool(getattr(model, "requires_grad", False))  # μ, e and positions carry gradients then
        arr = {
            "kind": wp.array([r[0] for r in rows], dtype=wp.int32, device=d),
            "pos": wp.array(np.array([r[1] for r in rows]), dtype=model.vec3, device=d, requires_grad=rg),
            "aux": wp.array(np.array([r[2] for r in rows]), dtype=model.vec3, device=d),
            "rot": wp.array(np.array([r[3] for r in rows]), dtype=model.mat33, device=d),
            "radius": wp.array([r[4] for r in rows], dtype=model.scalar, device=d),
            "mesh": wp.array(
                [meshes[r[7]].id if r[0] == MESH else 0 for r in rows], dtype=wp.uint64, device=d
            ),
            "friction": wp.array([r[5] for r in rows], dtype=model.scalar, device=d, requires_grad=rg),
            "restitution": wp.array([r[6] for r in rows], dtype=model.scalar, device=d, requires_grad=rg),
            "_meshes": meshes,  # keep the BVHs alive
        }
        self._cache[key] = arr
        return arr

    def geometry_inputs(self, model: Model) -> list:
        """Kernel inputs (kind, pos, aux, rot, radius, mesh) for :func:`collider_sdf` loops."""
        a = self.arrays(model)
        return [a["kind"], a["pos"], a["aux"], a["rot"], a["radius"], a["mesh"]]

    def graph_blocker(self) -> str | None:
        """None: the response is one launch over cached arrays (a frame of it can be replayed)."""
        return None

    def apply(self, model: Model, state_in: State, state_out: State, dt: float) -> None:
        """Velocity-level contact response on ``state_out`` (push out, restitution, Coulomb friction), in
        place: :meth:`apply_out` with ``state_out``'s arrays as input and output."""
        x, v = state_out.particle_q, state_out.particle_qd
        self.apply_out(model, x, v, x, v, dt)

    def apply_out(
        self, model: Model, x_in: wp.array, v_in: wp.array, x_out: wp.array, v_out: wp.array, dt: float
    ) -> None:
        """The response after a step, collider after collider: reads (x_in, v_in), writes (x_out, v_out).

        Friction acts inside the step, so its velocity change Δv_t moves positions by ``dt``·Δv_t: pass
        ∂x₁/∂v₁ [s] of the step, Δt after x₁ = x₀ + Δt v₁ (explicit steps, backward Euler), Δt/2 after the
        implicit midpoint rule (what :func:`~pliant.solvers._post.finish_step` passes).

        Outputs that are the inputs are updated in place, in one launch (the gradient-free step). Other
        outputs are a recorded (``wp.Tape``) step's: one launch per collider, each but the last into fresh
        arrays, so that no array is written after a recorded launch read it. The friction μ and
        restitution e arrays (``arrays(model)["friction"]``, ``["restitution"]``, one value per collider)
        and the colliders' positions (``["pos"]``) receive gradients. Piecewise smooth: where a particle
        enters or leaves contact or friction switches stick/slip the gradient is one-sided (a subgradient).
        Mesh colliders raise :class:`~pliant.diff.GradientError` out of place (Warp's BVH query has no
        adjoint here).
        """
        in_place = x_out is x_in and v_out is v_in
        if not in_place and any(r[0] == MESH for r in self._rows):
            raise GradientError(
                "mesh colliders are not differentiable: use spheres, boxes and capsules, or "
                "finalize(requires_grad=False)"
            )
        a = self.arrays(model)
        count = len(self._rows)
        # In place: one launch over every collider. Out of place: one launch per collider, each but the
        # last into fresh arrays.
        ranges = [(0, count)] if in_place else [(c, c + 1) for c in range(count)]
        for first, end in ranges:
            last = end == count
            xo, vo = (x_out, v_out) if last else (fresh(model), fresh(model))
            launch(
                collider_response,
                model.particle_count,
                [first, end, *self.geometry_inputs(model), a["friction"], a["restitution"]]
                + [model.s(self.stick_velocity), model.s(dt)]
                + [model.particle_inv_mass, model.particle_radius, x_in, v_in, xo, vo],
                device=model.device,
            )
            x_in, v_in = xo, vo

    def query(self, model: Model, x: wp.array) -> tuple[np.ndarray, np.ndarray]:
        """Smallest signed distance φ [m] over the colliders and its normal, per point (host arrays)."""
        phi = wp.zeros(x.shape[0], dtype=model.scalar, device=model.device)
        n = wp.zeros(x.shape[0], dtype=model.vec3, device=model.device)
        launch(_collider_query, x.shape[0], [*self.geometry_inputs(model), x, phi, n], device=model.device)
        return phi.numpy(), n.numpy()

    def describe(self) -> list[dict]:
        """One dict per collider: kind, parameters, friction, restitution."""
        return [
            {"kind": _KIND_NAMES[r[0]], "friction": r[5], "restitution": r[6], "radius": r[4]}
            for r in self._rows
        ]
