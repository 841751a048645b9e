"""FastMassSpring's symplectic frame in one CPU launch: every substep's spring scatter and update in a loop
inside one kernel of one thread (``FastMassSpring(fused_frame=...)``).

A Warp CPU launch runs its threads one after another on the calling core, so a kernel of dim 1 that loops
over the frame's substeps, and within each over the springs and then the particles, is the same work as the
two launches per substep of the scatter path (:mod:`._explicit`) in the same order: the same arithmetic,
each particle's spring forces summed in spring order, hence the same frame bit for bit. What it saves is
the per-substep cost around the arithmetic: the Python of ``step`` and its post-step stages, two launches,
and a kernel body entered once per spring or particle (measured on the 64² drape, one core: 1.2× the frames
per second, 1.15× at 128²; ``benchmarks/peers/results_2026-11-28_cloth_fused.txt``). The springs' rest
length, stiffness and γ are read as one packed vec3 per spring, and the damped and undamped spring loops
are separate loops, so that no branch is taken per spring.

The substeps run in place in one buffer: the scatter reads all positions before the update writes any, and
a particle's update reads only its own position, velocity and force, so writing x¹, v¹ over x⁰, v⁰ gives
what the ping-pong pair gives. The frame copies its input into the spare buffer first, and copies the result
back when ping-pong stepping would have ended in the input buffer (an even substep count).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

from ..._warp import grad_enabled
from ...energies import dashpot_force_axis, spring_gradient_axis
from ...integrators import symplectic_particle

if TYPE_CHECKING:
    from ...model import Control, Model, State


@wp.kernel
def _symplectic_frame(
    # Model (packed per spring: rest length, stiffness, dashpot γ):
    spring_pairs: wp.array(dtype=wp.vec2i),
    spring_param: wp.array(dtype=Any),
    damped: int,
    particle_inv_mass: wp.array(dtype=Any),
    gravity: Any,
    # Control:
    f_ext: wp.array(dtype=Any),
    # Steps:
    substeps: int,
    dt: Any,
    delta: Any,
    # Scratch: the scattered spring forces (zero between steps; the update clears it again):
    f_springs: wp.array(dtype=Any),
    # State: the frame's input (written back for an even substep count) and the spare buffer:
    x_a: wp.array(dtype=Any),
    v_a: wp.array(dtype=Any),
    x_b: wp.array(dtype=Any),
    v_b: wp.array(dtype=Any),
):
    n = x_b.shape[0]
    for i in range(n):
        x_b[i] = x_a[i]
        v_b[i] = v_a[i]
    for _k in range(substeps):
        # The scatter kernel's arithmetic, in its order (an atomic add on the CPU is this plain add).
        if damped != 0:
            for s in range(spring_pairs.shape[0]):
                ij = spring_pairs[s]
                p = spring_param[s]
                d = x_b[ij[0]] - x_b[ij[1]]
                l = wp.length(d)
                fi = -spring_gradient_axis(d, l, p[1], p[0])
                fi += dashpot_force_axis(d, l, v_b[ij[0]], v_b[ij[1]], p[2])
                f_springs[ij[0]] = f_springs[ij[0]] + fi
                f_springs[ij[1]] = f_springs[ij[1]] - fi
        else:
            for s in range(spring_pairs.shape[0]):
                ij = spring_pairs[s]
                p = spring_param[s]
                d = x_b[ij[0]] - x_b[ij[1]]
                fi = -spring_gradient_axis(d, wp.length(d), p[1], p[0])
                f_springs[ij[0]] = f_springs[ij[0]] + fi
                f_springs[ij[1]] = f_springs[ij[1]] - fi
        # The update kernel's, in place.
        for i in range(n):
            f = f_springs[i] + f_ext[i]
            f_springs[i] = f * type(dt)(0.0)
            w = particle_inv_mass[i]
            x, v = symplectic_particle(w, x_b[i], v_b[i], gravity + w * f, dt, delta)
            x_b[i] = x
            v_b[i] = v
    if substeps % 2 == 0:
        for i in range(n):
            x_a[i] = x_b[i]
            v_a[i] = v_b[i]


def fused_frame_blocker(
    model: Model, method: str, scatter: bool, contact: bool, collisions: int
) -> str | None:
    """Why FastMassSpring's frames cannot run as one launch on this setup, or None when they can.

    Args:
        model: the Model (its device, and whether it records gradients).
        method: the solver's method.
        scatter: whether the symplectic step is the spring scatter (``kernel="scatter"``).
        contact: whether ground contact follows each step.
        collisions: how many contact handlers follow each step.
    """
    if not wp.get_device(model.device).is_cpu:
        return "the device is not the CPU (one thread would run the whole frame on a GPU)"
    if method != "symplectic":
        return f"method={method!r} (only the symplectic step is fused)"
    if not scatter:
        return "kernel='gather' (the fused frame is the scatter's arithmetic)"
    if grad_enabled(model):
        return "the model records gradients (each step must write fresh arrays for the tape)"
    if contact:
        return "ground contact follows each step"
    if collisions:
        return "contact handlers follow each step"
    return None


def control_blocker(control: Control | None) -> str | None:
    """Why a frame with ``control`` cannot be fused (a per-step stage it needs), or None."""
    if control is None:
        return None
    if control.drag_index >= 0:
        return "the control's drag handle (its force follows the particle every step)"
    if control.kinematic_indices.shape[0]:
        return "the control's kinematic targets (applied after every step)"
    return None


class FusedFrame:
    """The fused frame's packed spring parameters and its recorded launches (one per buffer pair and Δt).

    Args:
        model: the Model.
        spring_pairs: the springs' endpoints [S] (vec2i), as the scatter kernel reads them.
        f_springs: the scatter's force scratch [N] (shared with the per-step path: zero between steps).
    """

    def __init__(self, model: Model, spring_pairs: wp.array, f_springs: wp.array) -> None:
        self.model = model
        self.spring_pairs = spring_pairs
        self.f_springs = f_springs
        #: (rest length [m], stiffness [N/m], γ [N s/m]) per spring, refreshed by :meth:`pack`.
        self.param = wp.zeros(max(model.spring_count, 1), dtype=model.vec3, device=model.device)
        self._cmds: dict[tuple, Any] = {}

    def pack(self, per_spring: np.ndarray) -> None:
        """Write the springs' parameters [S, 3] in place (recorded launches and graphs keep the array)."""
        if per_spring.shape[0]:
            self.param.assign(per_spring)
        self._cmds.clear()

    def launch(
        self, state: State, spare: State, f_ext: wp.array, dt: float, delta: float, substeps: int, damped: int
    ) -> None:
        """Run ``substeps`` symplectic steps of ``dt`` [s] (velocity factor ``delta``) from ``state``, ending
        in ``state`` for an even count and in ``spare`` for an odd one (where ping-pong stepping ends)."""
        key = (state.particle_q.ptr, state.particle_qd.ptr, spare.particle_q.ptr, f_ext.ptr, dt, substeps)
        cmd = self._cmds.get(key)
        if cmd is None:
            if len(self._cmds) > 8:
                self._cmds.clear()
            m = self.model
            args = [self.spring_pairs, self.param, damped, m.particle_inv_mass, m.gravity_vec, f_ext]
            args += [int(substeps), m.s(dt), m.s(delta), self.f_springs]
            args += [state.particle_q, state.particle_qd, spare.particle_q, spare.particle_qd]
            cmd = self._cmds[key] = wp.launch(_symplectic_frame, 1, args, device=m.device, record_cmd=True)
        cmd.launch()
