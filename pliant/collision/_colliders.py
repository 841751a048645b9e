"""Colliders — sphere, box, capsule, triangle mesh, plane — as signed distance fields, static or moving.

Each collider is a signed distance φ(p) [m] (negative inside) with its gradient n = ∇φ (the outward
normal) and Hessian ∇²φ, of a kind registered in :data:`pliant.collision.kinds.CONTACT_KINDS` (one file
per kind). Two responses use them:

* :meth:`Colliders.apply`, a velocity-level response after a step, like the ground plane: particles
  closer than their radius are pushed out along n, the normal velocity (relative to the surface's) is
  reflected with restitution e, and the friction law (:data:`pliant.collision.FRICTION_LAWS`; smoothed
  Coulomb by default) stops the relative tangential velocity if it is at most μ·Δv_n and removes μ·Δv_n of
  it otherwise (so a block sliding on a collider decelerates by μ g, and one resting on a slope inside the
  friction cone stays put: :mod:`pliant.collision._friction`). A collider given a ``stiffness`` κ is
  compliant instead: the ground's spring–damper a = max(κ d − b v_n, 0), b = 2ζ√κ (rests g/κ deep);
* :class:`pliant.energies.ColliderPenalty`, E = ½ k Σ max(0, r − φ)², a smooth term with an exact Hessian
  for implicit solvers.

A collider given a ``velocity`` v [m/s] and/or an ``angular_velocity`` ω [rad/s] (about its centre) is
kinematic: :meth:`Colliders.apply` first moves it rigidly over the step (on the device), then responds
relative to its surface velocity v + ω × (p − c), so a body resting on it is carried along (stick) or
slips at μ g. :meth:`Colliders.reset` puts every collider back where it was added.

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
from ._collider_kernels import _advance, _collider_query, collider_response
from ._friction_laws import friction_law_code
from .kinds import CONTACT_KINDS, vec3

if TYPE_CHECKING:
    from ..model import Control, Model, State

SPHERE, BOX, CAPSULE, MESH, PLANE = (
    CONTACT_KINDS[k].code for k in ("sphere", "box", "capsule", "mesh", "plane")
)
_KIND_NAMES = {k.code: k.name for k in CONTACT_KINDS.values()}


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
    """A set of colliders with Coulomb friction μ and restitution e each; static, or moving rigidly with
    a constant velocity and angular velocity; hard, or compliant (a stiffness κ and damping ratio ζ).

    Example::

        colliders = pl.collision.Colliders()
        colliders.add_sphere((0, 0.3, 0), 0.25, friction=0.3)
        colliders.add_box((0, -0.05, 0), (1, 0.05, 1), velocity=(0.2, 0, 0))  # a conveyor plate
        solver = pl.solvers.FastMassSpring(model, collisions=[colliders])
        # or, after any solver's step: colliders.apply(model, state_0, state_1, dt)

    Args:
        stick_velocity: ε_v [m/s] >= 0 of every collider's smoothed Coulomb friction (a contact loaded
            inside the friction cone creeps below ε_v; 0: exact Coulomb, with a kink at stick/slip;
            :mod:`pliant.collision._friction`).
        friction_law: the name of a law in :data:`pliant.collision.FRICTION_LAWS` ("coulomb": smoothed).
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

    def __init__(self, *, stick_velocity: float = STICK_VELOCITY, friction_law: str = "coulomb") -> None:
        if not (np.isfinite(stick_velocity) and stick_velocity >= 0):
            raise ValueError(f"Colliders: stick_velocity must be >= 0 m/s, got {stick_velocity}")
        self.stick_velocity = float(stick_velocity)
        self.friction_law = friction_law
        self._law = friction_law_code(friction_law)
        self._rows: list[dict[str, Any]] = []
        self._meshes: list[tuple[np.ndarray, np.ndarray]] = []
        self._cache: dict = {}
        self._pending_pose: dict[str, np.ndarray] = {}

    def __len__(self) -> int:
        return len(self._rows)

    def add(
        self,
        kind: str,
        *,
        friction: float = 0.5,
        restitution: float = 0.0,
        velocity: Sequence[float] | None = None,
        angular_velocity: Sequence[float] | None = None,
        stiffness: float | None = None,
        damping_ratio: float = 0.0,
        **params: Any,
    ) -> int:
        """A collider of a registered kind (:data:`pliant.collision.kinds.CONTACT_KINDS`).

        Args:
            kind: the kind's name ("sphere", "box", "capsule", "plane", "mesh" with ``vertices`` and
                ``faces``: :meth:`add_mesh`).
            friction: Coulomb friction coefficient μ [-], >= 0.
            restitution: normal restitution coefficient e [-], in [0, 1] (hard contact only).
            velocity: v [m/s] of a kinematic collider's centre; None: static.
            angular_velocity: ω [rad/s] about its centre (the axis times the rate); None: not spinning.
            stiffness: κ [1/s²] > 0 of compliant contact (rests g/κ deep); None: hard contact.
            damping_ratio: ζ [-] >= 0 of compliant contact's damper b = 2ζ√κ.
            **params: the kind's parameters [m] (its ``params``, e.g. ``center``, ``radius``).

        Returns:
            The collider's index.
        """
        k = CONTACT_KINDS.get(kind)
        if kind == "mesh" and "vertices" in params:
            contact = dict(friction=friction, restitution=restitution, velocity=velocity)
            contact |= dict(
                angular_velocity=angular_velocity, stiffness=stiffness, damping_ratio=damping_ratio
            )
            return self.add_mesh(params.pop("vertices"), params.pop("faces", None), **params, **contact)
        if k is None or (kind == "mesh" and "mesh" not in params):
            raise ValueError(
                f"collider kind must be one of {sorted(CONTACT_KINDS)} (meshes: add_mesh), got {kind!r}"
            )
        mesh = params.pop("mesh", -1)
        centre = params.pop("centre", None)
        packed = k.pack(**params)
        if not (np.isfinite(friction) and friction >= 0):
            raise ValueError(f"collider friction μ must be >= 0, got {friction}")
        if not 0.0 <= restitution <= 1.0:
            raise ValueError(f"collider restitution e must be in [0, 1], got {restitution}")
        if stiffness is not None and not (np.isfinite(stiffness) and stiffness > 0):
            raise ValueError(f"collider stiffness κ must be > 0 1/s^2 (None: hard contact), got {stiffness}")
        if not (np.isfinite(damping_ratio) and damping_ratio >= 0):
            raise ValueError(f"collider damping_ratio ζ must be >= 0, got {damping_ratio}")
        vel = np.zeros(3) if velocity is None else vec3(velocity, "collider velocity")
        omega = (
            np.zeros(3) if angular_velocity is None else vec3(angular_velocity, "collider angular_velocity")
        )
        row = {
            "kind": k.code,
            "name": k.name,
            "pos": packed.pos,
            "aux": packed.aux,
            "rot": packed.rot,
            "radius": packed.radius,
            "centre": packed.centre if centre is None else centre,
            "friction": float(friction),
            "restitution": float(restitution),
            "mesh": mesh,
            "vel": vel,
            "omega": omega,
            "kappa": 0.0 if stiffness is None else float(stiffness),
            "damping": 0.0 if stiffness is None else 2.0 * float(damping_ratio) * float(stiffness) ** 0.5,
            "damping_ratio": float(damping_ratio),
        }
        self._rows.append(row)
        self._cache.clear()
        return len(self._rows) - 1

    @property
    def moving(self) -> bool:
        """Whether any collider has a velocity or an angular velocity."""
        return any(np.any(r["vel"] != 0) or np.any(r["omega"] != 0) for r in self._rows)

    def compliant(self) -> list[int]:
        """The indices of the compliant colliders (given a ``stiffness`` κ)."""
        return [k for k, r in enumerate(self._rows) if r["kappa"] > 0]

    def add_sphere(self, center: Sequence[float], radius: float, **contact: Any) -> int:
        """A sphere of centre ``center`` [m] and ``radius`` [m] > 0.

        Args:
            center: centre [m].
            radius: radius [m], > 0.
            **contact: ``friction``, ``restitution``, ``velocity``, ``angular_velocity``, ``stiffness``,
                ``damping_ratio`` (:meth:`add`).

        Returns:
            The collider's index.
        """
        return self.add("sphere", center=center, radius=radius, **contact)

    def add_box(
        self,
        center: Sequence[float],
        half_extents: Sequence[float],
        *,
        rotation: npt.ArrayLike | None = None,
        rounding: float = 0.0,
        **contact: Any,
    ) -> int:
        """A box, optionally rotated and with rounded edges.

        Args:
            center: centre [m].
            half_extents: half side lengths along the box's own axes [m], each > 0.
            rotation: world-from-box rotation [-], a 3×3 matrix or an (x, y, z, w) quaternion; None: axis
                aligned.
            rounding: radius [m] the surface is offset outwards by (rounded edges and corners), >= 0.
            **contact: ``friction``, ``restitution``, ``velocity``, ``angular_velocity``, ``stiffness``,
                ``damping_ratio`` (:meth:`add`).

        Returns:
            The collider's index.
        """
        return self.add(
            "box", center=center, half_extents=half_extents, rotation=rotation, rounding=rounding, **contact
        )

    def add_capsule(self, a: Sequence[float], b: Sequence[float], radius: float, **contact: Any) -> int:
        """A capsule: the segment a–b thickened by ``radius`` (it spins about the segment's midpoint).

        Args:
            a: first end of the axis segment [m].
            b: second end of the axis segment [m].
            radius: radius [m], > 0.
            **contact: ``friction``, ``restitution``, ``velocity``, ``angular_velocity``, ``stiffness``,
                ``damping_ratio`` (:meth:`add`).

        Returns:
            The collider's index.
        """
        return self.add("capsule", a=a, b=b, radius=radius, **contact)

    def add_plane(
        self, point: Sequence[float], normal: Sequence[float] = (0.0, 1.0, 0.0), **contact: Any
    ) -> int:
        """A plane (the half space below it is solid), e.g. a tilted floor.

        Args:
            point: a point of the plane [m] (it moves and spins about this point).
            normal: the outward normal [-] (non-zero; normalised).
            **contact: ``friction``, ``restitution``, ``velocity``, ``angular_velocity``, ``stiffness``,
                ``damping_ratio`` (:meth:`add`).

        Returns:
            The collider's index.
        """
        return self.add("plane", point=point, normal=normal, **contact)

    def add_mesh(self, vertices: npt.ArrayLike, faces: npt.ArrayLike, **contact: Any) -> int:
        """A closed, outward-wound triangle mesh, queried through a BVH (it spins about its vertices'
        mean).

        Args:
            vertices: [V, 3] vertex positions [m].
            faces: [F, 3] vertex indices per triangle (counter-clockwise seen from outside).
            **contact: ``friction``, ``restitution``, ``velocity``, ``angular_velocity``, ``stiffness``,
                ``damping_ratio`` (:meth:`add`).

        Returns:
            The collider's index.
        """
        v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        if f.size == 0 or f.min() < 0 or f.max() >= v.shape[0]:
            raise ValueError(f"mesh faces must index the {v.shape[0]} vertices and be non-empty")
        if not np.all(np.isfinite(v)):
            raise ValueError("mesh vertices must be finite")
        self._meshes.append((v, f.astype(np.int32)))
        return self.add("mesh", mesh=len(self._meshes) - 1, centre=v.mean(axis=0), **contact)

    # ------------------------------------------------------------------ device data
    def arrays(self, model: Model) -> dict:
        """Device arrays of the colliders in the model's device and dtype (built once, then cached)."""
        key = (str(model.device), model.dtype)
        if key in self._cache:
            return self._cache[key]
        if not self._rows:
            raise ValueError("no colliders: add a sphere, box, capsule, plane or mesh first")
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

        def vecs(name: str, grad: bool = False) -> wp.array:
            return wp.array(np.array([r[name] for r in rows]), dtype=model.vec3, device=d, requires_grad=grad)

        def scalars(name: str, grad: bool = False) -> wp.array:
            return wp.array([r[name] for r in rows], dtype=model.scalar, device=d, requires_grad=grad)

        arr: dict[str, Any] = {
            "kind": wp.array([r["kind"] for r in rows], dtype=wp.int32, device=d),
            "pos": vecs("pos", rg),
            "aux": vecs("aux"),
            "rot": wp.array(np.array([r["rot"] for r in rows]), dtype=model.mat33, device=d),
            "radius": scalars("radius"),
            "mesh": wp.array(
                [meshes[r["mesh"]].id if r["kind"] == MESH else 0 for r in rows], dtype=wp.uint64, device=d
            ),
            "centre": vecs("centre"),
            "vel": vecs("vel"),
            "omega": vecs("omega"),
            "friction": scalars("friction", rg),
            "restitution": scalars("restitution", rg),
            "kappa": scalars("kappa"),
            "damping": scalars("damping"),
            "_meshes": meshes,  # keep the BVHs alive
        }
        # The pose as added, for reset() (moving colliders overwrite pos, aux, rot, centre each step).
        arr["_start"] = {
            name: wp.clone(arr[name], requires_grad=False) for name in ("pos", "aux", "rot", "centre")
        }
        self._write_pose(arr)  # a pose restored from a checkpoint before the arrays existed
        self._cache[key] = arr
        return arr

    def geometry_inputs(self, model: Model) -> list:
        """Kernel inputs (kind, pos, aux, rot, radius, mesh) for :func:`collider_sdf` loops."""
        a = self.arrays(model)
        return [a["kind"], a["pos"], a["aux"], a["rot"], a["radius"], a["mesh"]]

    def advance(self, model: Model, h: float) -> None:
        """Move every collider rigidly over h [s] (centre by v h, rotation exp(ω h) about it), in place on
        the device; static colliders stay bit for bit where they are."""
        a = self.arrays(model)
        args = [a["kind"], a["vel"], a["omega"], model.s(h), a["pos"], a["aux"], a["rot"], a["centre"]]
        launch(_advance, len(self._rows), args, device=model.device)

    def pose_ahead(self, model: Model, h: float) -> list:
        """Kernel inputs as :meth:`geometry_inputs`, with the pose the colliders will have h [s] from now
        (their current pose moved rigidly over h), in arrays of their own (overwritten by the next call;
        the current pose is not touched). Implicit steps evaluate contact here, at the end of the step."""
        a = self.arrays(model)
        ahead = a.get("_ahead")
        if ahead is None:
            ahead = {name: wp.clone(a[name], requires_grad=False) for name in self._POSE}
            a["_ahead"] = ahead
        else:
            for name in self._POSE:
                wp.copy(ahead[name], a[name])
        args = [a["kind"], a["vel"], a["omega"], model.s(h)] + [ahead[name] for name in self._POSE]
        launch(_advance, len(self._rows), args, device=model.device)
        return [a["kind"], ahead["pos"], ahead["aux"], ahead["rot"], a["radius"], a["mesh"]]

    def motion(self) -> ColliderMotion:
        """A contact handler that only moves these colliders each step (no response): for a solver whose
        energies are the contact (``BarrierContact``, ``ColliderPenalty``) without the colliders among its
        post-step handlers; ``ForceSolver`` adds it itself."""
        return ColliderMotion(self)

    def reset(self) -> None:
        """Put moving colliders back where they were added: the pose arrays are overwritten in place (a
        captured frame graph keeps reading them), on every device they were built for."""
        self._pending_pose = {}
        for arr in self._cache.values():
            for name in ("pos", "aux", "rot", "centre"):
                wp.copy(arr[name], arr["_start"][name])

    _POSE = ("pos", "aux", "rot", "centre")

    def checkpoint_state(self) -> dict[str, np.ndarray]:
        """Moving colliders' poses now (``pose_pos``, ``pose_aux``, ``pose_rot``, ``pose_centre``: host
        copies), so that a resumed run continues from where they were; static colliders keep nothing."""
        if not self.moving or not self._cache:
            return {}
        arr = next(iter(self._cache.values()))
        return {f"pose_{name}": arr[name].numpy().copy() for name in self._POSE}

    def restore_checkpoint_state(self, state: dict[str, np.ndarray]) -> None:
        """Take back :meth:`checkpoint_state`'s poses (written into the device arrays in place, now or
        when they are built). Raises ValueError for an unknown key or a wrong shape."""
        n = len(self._rows)
        shapes = {"pos": (n, 3), "aux": (n, 3), "rot": (n, 3, 3), "centre": (n, 3)}
        pose = {}
        for key, a in state.items():
            name = key.removeprefix("pose_")
            if name not in shapes or not key.startswith("pose_"):
                raise ValueError(
                    f"Colliders: unknown checkpoint array {key!r} (pose_pos, pose_aux, pose_rot, pose_centre)"
                )
            a = np.asarray(a, dtype=np.float64)
            if a.shape != shapes[name] or not np.all(np.isfinite(a)):
                raise ValueError(
                    f"Colliders: checkpoint {key} must be finite of shape {shapes[name]}, got {a.shape}"
                )
            pose[name] = a
        self._pending_pose = pose
        for arr in self._cache.values():
            self._write_pose(arr)

    def _write_pose(self, arr: dict[str, Any]) -> None:
        for name, a in self._pending_pose.items():
            arr[name].assign(a)

    def graph_blocker(self) -> str | None:
        """None: the response (and a moving collider's motion) is launches over cached arrays (a frame of
        it can be replayed)."""
        return None

    #: :func:`pliant.solvers._post.finish_step` passes ``x_start`` and ``step_dt`` to :meth:`apply_out`.
    takes_step = True

    def apply(self, model: Model, state_in: State, state_out: State, dt: float) -> None:
        """Velocity-level contact response on ``state_out`` (push out, restitution, Coulomb friction), in
        place: :meth:`apply_out` with ``state_out``'s arrays as input and output."""
        x, v = state_out.particle_q, state_out.particle_qd
        self.apply_out(model, x, v, x, v, dt, x_start=state_in.particle_q, step_dt=dt)

    def apply_out(
        self,
        model: Model,
        x_in: wp.array,
        v_in: wp.array,
        x_out: wp.array,
        v_out: wp.array,
        dt: float,
        *,
        x_start: wp.array | None = None,
        step_dt: float | None = None,
    ) -> None:
        """The response after a step, collider after collider: reads (x_in, v_in), writes (x_out, v_out).

        Friction acts inside the step, so its velocity change Δv_t moves positions by ``dt``·Δv_t: pass
        ∂x₁/∂v₁ [s] of the step, Δt after x₁ = x₀ + Δt v₁ (explicit steps, backward Euler), Δt/2 after the
        implicit midpoint rule (what :func:`~pliant.solvers._post.finish_step` passes). ``step_dt`` [s]
        is the step itself (default ``dt``): moving colliders advance by it first, and compliant contact
        integrates its force over it. ``x_start`` (positions at the step's start; default ``x_in``) tells
        compliant contact's damper which particles were already in contact.

        Outputs that are the inputs are updated in place, in one launch (the gradient-free step). Other
        outputs are a recorded (``wp.Tape``) step's: one launch per collider, each but the last into fresh
        arrays, so that no array is written after a recorded launch read it. The friction μ and
        restitution e arrays (``arrays(model)["friction"]``, ``["restitution"]``, one value per collider)
        and the colliders' positions (``["pos"]``) receive gradients. Piecewise smooth: where a particle
        enters or leaves contact or friction switches stick/slip the gradient is one-sided (a subgradient).
        Mesh and moving colliders raise :class:`~pliant.diff.GradientError` out of place (Warp's BVH query
        has no adjoint here; a moving collider's pose is updated in place).
        """
        in_place = x_out is x_in and v_out is v_in
        if not in_place and any(r["kind"] == MESH for r in self._rows):
            raise GradientError(
                "mesh colliders are not differentiable: use spheres, boxes and capsules, or "
                "finalize(requires_grad=False)"
            )
        moving = self.moving
        if not in_place and moving:
            raise GradientError(
                "moving colliders (velocity=, angular_velocity=) are not differentiable: make them static, "
                "or finalize(requires_grad=False)"
            )
        a = self.arrays(model)
        h = dt if step_dt is None else step_dt
        if moving:
            self.advance(model, h)
        x0 = x_in if x_start is None else x_start
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
                [first, end, *self.geometry_inputs(model), a["centre"], a["vel"], a["omega"]]
                + [a["friction"], a["restitution"], a["kappa"], a["damping"], self._law]
                + [model.s(self.stick_velocity), model.s(dt), model.s(h)]
                + [model.particle_inv_mass, model.particle_radius, x0, x_in, v_in, xo, vo],
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
        """One dict per collider: kind, friction, restitution, radius, and the motion (velocity,
        angular_velocity and the centre [m] it rotates about, where it was added) and compliance set."""
        out = []
        for r in self._rows:
            d = {
                "kind": r["name"],
                "friction": r["friction"],
                "restitution": r["restitution"],
                "radius": r["radius"],
            }
            if np.any(r["vel"] != 0) or np.any(r["omega"] != 0):
                d |= {"velocity": r["vel"].tolist(), "angular_velocity": r["omega"].tolist()}
                d |= {"centre": np.asarray(r["centre"], float).tolist()}  # what it rotates about
            if r["kappa"] > 0:
                d |= {"stiffness": r["kappa"], "damping_ratio": r["damping_ratio"]}
            out.append(d)
        return out


class ColliderMotion:
    """The post-step handler of kinematic colliders whose contact is an energy of the implicit step: it
    moves them over each step (:meth:`Colliders.advance`) and does nothing else; the reset, the checkpointed
    pose and the refusal to be recorded are the colliders' own.

    Args:
        colliders: the moving colliders.
    """

    #: :func:`pliant.solvers._post.finish_step` passes ``x_start`` and ``step_dt`` to :meth:`apply_out`.
    takes_step = True

    def __init__(self, colliders: Colliders) -> None:
        self.colliders = colliders

    def apply(self, model: Model, state_in: State, state_out: State, dt: float) -> None:
        """Move the colliders over ``dt`` [s]; the state is not touched."""
        self.colliders.advance(model, dt)

    def apply_out(self, model: Model, x_in, v_in, x_out, v_out, dt: float, *, x_start=None, step_dt=None):
        """Move the colliders over ``step_dt`` (default ``dt``) [s]; (x_out, v_out) = (x_in, v_in). Raises
        :class:`~pliant.diff.GradientError` out of place (a recorded step: the pose is updated in place)."""
        if x_out is not x_in or v_out is not v_in:
            raise GradientError(
                "moving colliders (velocity=, angular_velocity=) are not differentiable: make them static, "
                "or finalize(requires_grad=False)"
            )
        self.colliders.advance(model, dt if step_dt is None else step_dt)

    def graph_blocker(self) -> str | None:
        """None: one launch over cached arrays."""
        return None

    def reset(self) -> None:
        """The colliders back where they were added."""
        self.colliders.reset()

    def checkpoint_state(self) -> dict[str, np.ndarray]:
        """The colliders' pose (:meth:`Colliders.checkpoint_state`)."""
        return self.colliders.checkpoint_state()

    def restore_checkpoint_state(self, state: dict[str, np.ndarray]) -> None:
        """Take back :meth:`checkpoint_state`'s pose."""
        self.colliders.restore_checkpoint_state(state)
