"""Kinematic control points pulling on an object through springs (PhysTwin-style hand/gripper control)."""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp
from numpy.typing import ArrayLike

from .._warp import launch
from ..model import Model
from ._base import ModalEnergy
from ._spring import dashpot_force, spring_energy, spring_gradient, spring_hessian


@wp.kernel
def _handle_kernel(
    link_particle: wp.array(dtype=wp.int32),
    link_point: wp.array(dtype=wp.int32),
    link_rest: wp.array(dtype=Any),
    stiffness: Any,
    points: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    mode: int,
    project: int,
    scale: Any,
    slots_in: wp.array(dtype=wp.int32),
    value_out: wp.array(dtype=Any),
    grad_out: wp.array(dtype=Any),
    hess_out: wp.array(dtype=Any),
):
    s = wp.tid()
    i = link_particle[s]
    c = points[link_point[s]]
    if mode == 0:
        wp.atomic_add(value_out, 0, spring_energy(x_in[i], c, stiffness, link_rest[s]))
    elif mode == 1:
        wp.atomic_add(grad_out, i, spring_gradient(x_in[i], c, stiffness, link_rest[s]))
    else:
        h = spring_hessian(x_in[i], c, stiffness, link_rest[s], project)
        wp.atomic_add(hess_out, slots_in[s], scale * h)


@wp.kernel
def _handle_force(
    link_particle: wp.array(dtype=wp.int32),
    link_point: wp.array(dtype=wp.int32),
    link_rest: wp.array(dtype=Any),
    stiffness: Any,
    damping: Any,
    points: wp.array(dtype=Any),
    point_velocities: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    f_out: wp.array(dtype=Any),
):
    s = wp.tid()
    i = link_particle[s]
    k = link_point[s]
    f = -spring_gradient(x_in[i], points[k], stiffness, link_rest[s])
    f += dashpot_force(x_in[i], points[k], v_in[i], point_velocities[k], damping)
    wp.atomic_add(f_out, i, f)


class ControlPoints(ModalEnergy):
    """Moving control points, each tied by springs to the particles within ``radius`` (PhysTwin's control).

    At construction every control point is linked to its up to ``max_links`` nearest particles within
    ``radius`` [m], with rest length = their initial distance (or 0 with ``zero_rest=True``). The energy
    is E = Σ_links ½ k (|x_i − c_k| − l)² [J]; moving the points with :meth:`set_positions` drags the object
    along softly (no velocity jumps, unlike kinematic particles). Dashpots γ act along each link on the
    velocity relative to the point (explicit integrators only).

    Args:
        model: the Model (particles to link).
        points: [K, 3] initial control point positions [m].
        stiffness: k [N/m] per link.
        radius: link particles within this distance [m] of a point.
        max_links: at most this many links per point (nearest first).
        damping: γ [N s/m] per link.
        zero_rest: rest length 0 instead of the initial distance.
    """

    def __init__(
        self,
        model: Model,
        points: ArrayLike,
        *,
        stiffness: float,
        radius: float,
        max_links: int = 16,
        damping: float = 0.0,
        zero_rest: bool = False,
    ) -> None:
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if pts.shape[0] == 0:
            raise ValueError("ControlPoints needs at least one point")
        if stiffness < 0 or damping < 0 or radius <= 0 or max_links < 1:
            raise ValueError("stiffness and damping must be >= 0, radius > 0 m and max_links >= 1")
        x0 = model.particle_q_np
        free = model.particle_inv_mass.numpy() > 0
        parts, pids, rests = [], [], []
        for k, c in enumerate(pts):
            d = np.linalg.norm(x0 - c, axis=1)
            cand = np.flatnonzero((d <= radius) & free)
            cand = cand[np.argsort(d[cand], kind="stable")][:max_links]
            parts.append(cand)
            pids.append(np.full(cand.size, k))
            rests.append(np.zeros(cand.size) if zero_rest else d[cand])
        part = np.concatenate(parts)
        if part.size == 0:
            raise ValueError(
                f"no particle lies within radius {radius} m of any control point; increase radius"
            )
        dev = model.device
        self.point_count = pts.shape[0]
        self.link_count = int(part.size)
        self.link_particle: wp.array = wp.array(part.astype(np.int32), dtype=wp.int32, device=dev)
        self.link_point: wp.array = wp.array(
            np.concatenate(pids).astype(np.int32), dtype=wp.int32, device=dev
        )
        self.link_rest: wp.array = wp.array(np.concatenate(rests), dtype=model.scalar, device=dev)
        self.points: wp.array = wp.array(pts, dtype=model.vec3, device=dev)
        self.point_velocities = wp.zeros(pts.shape[0], dtype=model.vec3, device=dev)
        #: The arrays this energy allocated (NumPy input is copied into them, never into a user's array).
        self._owned = {"points": self.points, "velocities": self.point_velocities}
        self._np = np.float64 if model.dtype == "float64" else np.float32
        self.stiffness = float(stiffness)
        self.damping = float(damping)

    def set_positions(self, points: ArrayLike, velocities: ArrayLike | None = None) -> None:
        """Move the control points to ``points`` [K, 3] m (velocities [K, 3] m/s for the dashpots).

        NumPy input is copied into the energy's own arrays. A Warp array (``model.vec3``, shape [K]) is
        used as it is, by reference: give each step its own array (``requires_grad=True``) and a
        ``wp.Tape`` carries ∂loss/∂(control path) into their ``.grad``, explicit and implicit steps alike
        (overwriting one array in place between recorded steps would give the tape only the last values).
        """
        self.points = self._take(points, "points")
        if velocities is not None:
            self.point_velocities = self._take(velocities, "velocities")

    def _take(self, values: ArrayLike, what: str) -> wp.array:
        own = self._owned[what]
        if isinstance(values, wp.array):
            if values.shape != (self.point_count,) or values.dtype != own.dtype:
                raise ValueError(
                    f"control point {what}: expected a wp.array of {self.point_count} {own.dtype.__name__}, "
                    f"got shape {values.shape} of {values.dtype.__name__}"
                )
            return values
        pts = np.asarray(values, dtype=np.float64).reshape(-1, 3)
        if pts.shape[0] != self.point_count:
            raise ValueError(f"expected {self.point_count} control {what}, got {pts.shape[0]}")
        own.assign(pts.astype(self._np))  # never into an array a user handed over
        return own

    def step_inputs(self) -> tuple:
        """The control points' positions and velocities this step reads (see :meth:`set_positions`)."""
        return (self.points, self.point_velocities)

    def set_step_inputs(self, inputs: tuple) -> None:
        """Put back a step's positions and velocities (the implicit adjoint, during ``tape.backward``)."""
        self.points, self.point_velocities = inputs

    def _launch_mode(self, model, x, mode, scale, project, outputs) -> None:
        """The link energy Σ ½ k (|x_i − c_k| − l)²; ``project`` clamps the compressive transverse term."""
        launch(
            _handle_kernel,
            self.link_count,
            [
                self.link_particle,
                self.link_point,
                self.link_rest,
                model.s(self.stiffness),
                self.points,
                x,
                mode,
                int(project),
                model.s(scale),
                *outputs,
            ],
            device=model.device,
        )

    def force(self, model: Model, x: wp.array, v: wp.array, out: wp.array) -> None:
        """Add link spring and dashpot forces [N] into ``out``."""
        launch(
            _handle_force,
            self.link_count,
            [
                self.link_particle,
                self.link_point,
                self.link_rest,
                model.s(self.stiffness),
                model.s(self.damping),
                self.points,
                self.point_velocities,
                x,
                v,
                out,
            ],
            device=model.device,
        )

    def hessian_pattern(self, model: Model) -> tuple[np.ndarray, np.ndarray]:
        """One diagonal block (i, i) per link (the control point is not a degree of freedom)."""
        i = self.link_particle.numpy()
        return i.copy(), i.copy()
