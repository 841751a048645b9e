"""Gravity as a potential, so implicit solvers see it in the incremental potential."""

from __future__ import annotations

from typing import Any

import warp as wp

from .._warp import launch
from ..model import Model, Parameter, declares, solver_array
from ._base import Energy


@wp.kernel
def _gravity_value(mass: wp.array(dtype=Any), g: Any, x_in: wp.array(dtype=Any), out: wp.array(dtype=Any)):
    i = wp.tid()
    wp.atomic_add(out, 0, -mass[i] * wp.dot(g, x_in[i]))


@wp.kernel
def _gravity_value_array(
    mass: wp.array(dtype=Any), g: wp.array(dtype=Any), x_in: wp.array(dtype=Any), out: wp.array(dtype=Any)
):
    i = wp.tid()
    wp.atomic_add(out, 0, -mass[i] * wp.dot(g[0], x_in[i]))


@wp.kernel
def _gravity_gradient(mass: wp.array(dtype=Any), g: Any, grad_out: wp.array(dtype=Any)):
    i = wp.tid()
    # An atomic add rather than a read-then-write, so that wp.Tape can replay it (same arithmetic).
    wp.atomic_sub(grad_out, i, mass[i] * g)


@wp.kernel
def _gravity_gradient_array(mass: wp.array(dtype=Any), g: wp.array(dtype=Any), grad_out: wp.array(dtype=Any)):
    # Recorded steps: g read from a 1-element array so that the tape carries ∂/∂g.
    i = wp.tid()
    wp.atomic_sub(grad_out, i, mass[i] * g[0])


@declares
class Gravity(Energy):
    """E = −Σ_i m_i g·x_i [J], with g = ``model.gravity`` [m/s²]; its Hessian is zero."""

    @classmethod
    def parameters(cls) -> tuple[Parameter, ...]:
        """Gravity g, a vec3 held by the solver (ForceSolver, FastMassSpring's recorded step, XPBD/PBD)."""
        return (
            Parameter(
                "gravity",
                "gravitational acceleration",
                "m/s^2",
                "global",
                ("solver.gravity",),
                None,
                log=False,
                sign="any",
                get=solver_array("gravity", "with ForceSolver or XPBD/PBD on a requires_grad model"),
            ),
        )

    def value(self, model: Model, x: wp.array, out: wp.array) -> None:
        """Add the gravitational potential energy [J] into ``out[0]``."""
        launch(
            _gravity_value,
            model.particle_count,
            [model.particle_mass, model.gravity_vec, x, out],
            device=model.device,
        )

    def gradient(self, model: Model, x: wp.array, out: wp.array) -> None:
        """Add −m_i g [N] into ``out``."""
        launch(
            _gravity_gradient,
            model.particle_count,
            [model.particle_mass, model.gravity_vec, out],
            device=model.device,
        )

    def gradient_from(self, model: Model, g: wp.array, out: wp.array) -> None:
        """Add −m_i g [N] into ``out`` with g [m/s²] read from the 1-element vec3 array ``g`` (recorded
        steps that differentiate gravity: ``g.grad`` then receives ∂loss/∂g)."""
        launch(
            _gravity_gradient_array, model.particle_count, [model.particle_mass, g, out], device=model.device
        )


class GravityFromArray(Gravity):
    """Gravity with g [m/s²] read from a 1-element vec3 array (``ForceSolver.gravity`` on a
    ``requires_grad`` model), so that a recorded step, explicit or implicit, carries ∂loss/∂g into
    ``g.grad``; the same energy as :class:`Gravity` otherwise (zero Hessian).

    Args:
        g: the 1-element vec3 array holding g [m/s²].
    """

    def __init__(self, g: wp.array) -> None:
        super().__init__()
        self.g = g

    def value(self, model: Model, x: wp.array, out: wp.array) -> None:
        """Add −Σ m_i g·x_i [J] into ``out[0]``."""
        launch(
            _gravity_value_array,
            model.particle_count,
            [model.particle_mass, self.g, x, out],
            device=model.device,
        )

    def gradient(self, model: Model, x: wp.array, out: wp.array) -> None:
        """Add −m_i g [N] into ``out``."""
        self.gradient_from(model, self.g, out)
