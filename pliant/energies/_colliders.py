"""Static colliders as a smooth penalty energy, for implicit solvers."""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from .._warp import launch
from ..collision import Colliders, collider_sdf
from ..model import Model
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


class ColliderPenalty(ModalEnergy):
    """Penalty E = ½ k Σ_i Σ_c max(0, r_i − φ_c(x_i))² [J] keeping particles outside static colliders.

    φ_c is the collider's signed distance (:class:`pliant.collision.Colliders`) and r_i the particle radius.
    The Hessian is exact (k(n nᵀ − (r − φ)∇²φ)); with ``project_psd`` the curvature term, which is negative
    semidefinite on convex colliders, is dropped. Friction is not part of the potential: pair it with
    ``Colliders.apply`` after the step for Coulomb friction and restitution.

    Args:
        colliders: the colliders.
        stiffness: k [N/m]; the penetration at rest is about m g / k.
    """

    hessian_changes_each_step = True

    def __init__(self, colliders: Colliders, *, stiffness: float = 1.0e4) -> None:
        if stiffness <= 0:
            raise ValueError(f"penalty stiffness must be > 0 N/m, got {stiffness}")
        if len(colliders) == 0:
            raise ValueError("ColliderPenalty needs at least one collider")
        self.colliders = colliders
        self.stiffness = float(stiffness)

    def _launch_mode(self, model, x, mode, scale, project, outputs) -> None:
        """The penalty energy; ``project`` drops the curvature term of the Hessian."""
        launch(
            _penalty,
            model.particle_count,
            [
                *self.colliders.geometry_inputs(model),
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

    def hessian_pattern(self, model: Model) -> tuple[np.ndarray, np.ndarray]:
        """One diagonal block per particle (contacts come and go; the pattern stays fixed)."""
        i = np.arange(model.particle_count, dtype=np.int32)
        return i, i.copy()
