"""Colliders, static or moving, as a smooth penalty energy, for implicit solvers."""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from .._warp import launch
from ..collision import Colliders, collider_sdf, rigid_displacement
from ..model import Model
from . import _barrier_friction as F
from ._barrier_math import to_d
from ._base import ModalEnergy


@wp.kernel
def _penalty(
    # Colliders:
    kind: wp.array(dtype=wp.int32),
    pos: wp.array(dtype=Any),
    aux: wp.array(dtype=Any),
    rot: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    mesh: wp.array(dtype=wp.uint64),
    # Model:
    particle_inv_mass: wp.array(dtype=Any),
    particle_radius: wp.array(dtype=Any),
    stiffness: Any,
    # State in:
    x_in: wp.array(dtype=Any),
    mode: int,
    project: int,
    scale: Any,
    slots_in: wp.array(dtype=wp.int32),
    # Out:
    value_out: wp.array(dtype=Any),
    grad_out: wp.array(dtype=Any),
    hess_out: wp.array(dtype=Any),
):
    # E = ½ k Σ_c max(0, r_i − φ_c(x_i))²; ∇E = −k p n; ∇²E = k (n nᵀ − p ∇²φ), p = r_i − φ.
    i = wp.tid()
    zero = stiffness * type(stiffness)(0.0)
    if particle_inv_mass[i] == zero:
        return
    x = x_in[i]
    for c in range(kind.shape[0]):
        phi, n, Hphi = collider_sdf(kind[c], pos[c], aux[c], rot[c], radius[c], mesh[c], x)
        p = particle_radius[i] - phi
        if p > zero:
            if mode == 0:
                wp.atomic_add(value_out, 0, type(stiffness)(0.5) * stiffness * p * p)
            elif mode == 1:
                wp.atomic_sub(grad_out, i, stiffness * p * n)
            else:
                h = wp.outer(n, n)
                if project == 0:
                    h = h - p * Hphi  # curvature term: negative semidefinite for convex colliders
                wp.atomic_add(hess_out, slots_in[i], scale * stiffness * h)


@wp.kernel(enable_backward=False)
def _friction_lag(
    kind: wp.array(dtype=wp.int32),
    pos: wp.array(dtype=Any),
    aux: wp.array(dtype=Any),
    rot: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    mesh: wp.array(dtype=wp.uint64),
    vel: wp.array(dtype=Any),
    omega: wp.array(dtype=Any),
    centre: wp.array(dtype=Any),
    h: Any,
    particle_inv_mass: wp.array(dtype=Any),
    particle_radius: wp.array(dtype=Any),
    stiffness: Any,
    x_in: wp.array(dtype=Any),
    lam_out: wp.array(dtype=wp.float64),
    normal_out: wp.array(dtype=wp.vec3d),
    shift_out: wp.array(dtype=wp.vec3d),
):
    # Per (particle, collider) at the step's start: the penalty's normal force λ = k (r − φ) [N] (0 out of
    # contact), the normal, and a moving collider's surface displacement over the step (0 when static).
    i = wp.tid()
    count = kind.shape[0]
    x = x_in[i]
    zero = stiffness * type(stiffness)(0.0)
    for c in range(count):
        k = i * count + c
        lam_out[k] = wp.float64(0.0)
        shift_out[k] = wp.vec3d()
        if particle_inv_mass[i] != zero:
            phi, n, Hphi = collider_sdf(kind[c], pos[c], aux[c], rot[c], radius[c], mesh[c], x)
            p = particle_radius[i] - phi
            if p > zero:
                lam_out[k] = wp.float64(stiffness * p)
                normal_out[k] = to_d(n)
                if wp.length(vel[c]) > zero or wp.length(omega[c]) > zero:
                    shift_out[k] = to_d(rigid_displacement(vel[c], omega[c], centre[c], h, x))


class ColliderPenalty(ModalEnergy):
    """Penalty E = ½ k Σ_i Σ_c max(0, r_i − φ_c(x_i))² [J] keeping particles outside colliders, with
    optional lagged Coulomb friction.

    φ_c is the collider's signed distance (:class:`pliant.collision.Colliders`) and r_i the particle radius.
    The Hessian is exact (k(n nᵀ − (r − φ)∇²φ)); with ``project_psd`` the curvature term, which is negative
    semidefinite on convex colliders, is dropped. Without ``friction`` there is none in the potential: pair
    the term with ``Colliders.apply`` after the step (whose friction budget, μ times the normal velocity
    change it makes, is small where the penalty already holds the particle: a particle resting on a plate
    moving at 0.5 m/s is dragged at 0.26 g with μ = 1). With ``friction``, the barrier's lagged, smoothed
    Coulomb potential (:mod:`._barrier_friction`) with the penalty's normal force λ = k (r − φ) at the
    step's start: rates μ g and stick inside the cone; then leave the colliders out of ``collisions=``.

    Moving colliders (``velocity=``, ``angular_velocity=``): the implicit step solves for the positions at
    its end, so :meth:`begin_step` (the minimisers call it: the term is then ``dissipative``) puts each
    collider where it will be after the step's h (:meth:`Colliders.pose_ahead`), and the penalty acts
    there; friction acts on the motion relative to the surface (its lagged displacement over the step). The
    colliders themselves move after the step: as a post-step handler, else by the motion handler that
    ``ForceSolver`` adds. Without a :meth:`begin_step` (direct evaluation) the current pose is used.

    Compliant colliders (``stiffness=`` κ) are refused: their normal law is the post-step response's
    (``Colliders.apply``, backward Euler on the step's end state, stable inside implicit steps and resting
    g/κ deep), and this term's own k would add a second normal force to the same contact (a penalty of
    m_i κ would still double it with that response). Use ``collisions=[colliders]`` without this term.

    Args:
        colliders: the colliders (hard ones).
        stiffness: k [N/m]; the penetration at rest is about m g / k.
        friction: lagged Coulomb friction with each collider's μ.
        stick_velocity: ε_v [m/s] of that friction (a creep below it where it should stick); None: the
            colliders' ``stick_velocity`` (at least 1e-12 m per step).
    """

    hessian_changes_each_step = True

    def __init__(
        self,
        colliders: Colliders,
        *,
        stiffness: float = 1.0e4,
        friction: bool = False,
        stick_velocity: float | None = None,
    ) -> None:
        if stiffness <= 0:
            raise ValueError(f"penalty stiffness must be > 0 N/m, got {stiffness}")
        if len(colliders) == 0:
            raise ValueError("ColliderPenalty needs at least one collider")
        if stick_velocity is not None and not stick_velocity > 0:
            raise ValueError(
                f"ColliderPenalty stick_velocity must be > 0 m/s (or None), got {stick_velocity}"
            )
        self.colliders = colliders
        self.stiffness = float(stiffness)
        self.friction = bool(friction)
        self.stick_velocity = stick_velocity
        self._ahead: dict[int, list] = {}
        self._lag: dict[int, tuple] = {}
        self._mus: dict[int, tuple[float, ...]] = {}
        _refuse_compliant(colliders, "ColliderPenalty")

    @property
    def dissipative(self) -> bool:  # type: ignore[override]
        """True with friction or moving colliders: the minimisers then call :meth:`begin_step`."""
        return self.friction or self.colliders.moving

    def begin_step(self, model: Model, x: wp.array, v: wp.array, dt: float) -> None:
        """With moving colliders: their pose after the step's ``dt`` [s], where the penalty then acts. With
        ``friction``: the normal forces, normals and surface displacements at the step's start x [m]."""
        if self.colliders.moving:
            self._ahead[id(model)] = self.colliders.pose_ahead(model, dt)
        if not self.friction:
            return
        d, n, c = model.device, model.particle_count, len(self.colliders)
        lag = self._lag.get(id(model))
        mus = tuple(float(r["friction"]) for r in self.colliders._rows)
        if lag is None or lag[0].shape[0] != c or self._mus.get(id(model)) != mus:
            # Built (and μ written) only when they change: a step replayed as a graph copies nothing.
            lag = (
                wp.array(np.array(mus, np.float64), dtype=wp.float64, device=d),
                wp.zeros(n * c, dtype=wp.float64, device=d),
                wp.zeros(n * c, dtype=wp.vec3d, device=d),
                wp.zeros(n, dtype=model.vec3, device=d),
                wp.zeros(n * c, dtype=wp.vec3d, device=d),
            )
            self._mus[id(model)] = mus
        wp.copy(lag[3], x)
        ev = self.colliders.stick_velocity if self.stick_velocity is None else self.stick_velocity
        self._lag[id(model)] = (*lag[:5], max(float(ev) * float(dt), 1e-12))
        a = self.colliders.arrays(model)
        launch(
            _friction_lag,
            n,
            [*self.colliders.geometry_inputs(model), a["vel"], a["omega"], a["centre"], model.s(dt)]
            + [model.particle_inv_mass, model.particle_radius, model.s(self.stiffness), x]
            + [lag[1], lag[2], lag[4]],
            device=d,
        )

    def _geometry(self, model: Model) -> list:
        """The colliders' kernel inputs: at the step's end pose once :meth:`begin_step` set one."""
        _refuse_compliant(self.colliders, "ColliderPenalty")  # also those added after construction
        if self.colliders.moving:
            ahead = self._ahead.get(id(model))
            if ahead is not None:
                return ahead
        return self.colliders.geometry_inputs(model)

    def _launch_mode(self, model, x, mode, scale, project, outputs) -> None:
        """The penalty energy; ``project`` drops the curvature term of the Hessian."""
        launch(
            _penalty,
            model.particle_count,
            [
                *self._geometry(model),
                model.particle_inv_mass,
                model.particle_radius,
                model.s(self.stiffness),
                x,
                mode,
                int(project),
                model.s(scale),
                *outputs,
            ],
            device=model.device,
        )
        lag = self._lag.get(id(model)) if self.friction else None
        if lag is not None:
            mu, lam, normal, x_start, shift, eps = lag
            launch(
                F.friction_terms,
                model.particle_count,
                [mu.shape[0], mu, lam, normal, x_start, 1, shift, x, wp.float64(eps), mode, wp.float64(scale)]
                + list(outputs),
                device=model.device,
            )

    def hessian_pattern(self, model: Model) -> tuple[np.ndarray, np.ndarray]:
        """One diagonal block per particle (contacts come and go; the pattern stays fixed)."""
        i = np.arange(model.particle_count, dtype=np.int32)
        return i, i.copy()


def _refuse_compliant(colliders: Colliders, who: str) -> None:
    """ValueError naming the compliant colliders (``stiffness=`` κ), whose law is the post-step response's."""
    soft = colliders.compliant()
    if soft:
        raise ValueError(
            f"{who}: colliders {soft} are compliant (stiffness=); their κ is honoured by the post-step "
            "response alone (collisions=[colliders], any solver family): drop stiffness= or this term"
        )
