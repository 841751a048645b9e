"""FastMassSpring's symplectic frame in one CPU launch: every substep's spring scatter and update in loops
inside one kernel of one thread (``FastMassSpring(fused_frame=...)``).

A Warp CPU launch runs its threads one after another on the calling core, so a kernel of dim 1 that loops
over the frame's substeps, and within each over the springs and then the particles, does the work of the
scatter path's two launches per substep (:mod:`._explicit`) in the same order: the same arithmetic, each
particle's spring forces summed in spring order, hence the same frame bit for bit. It saves the cost around
the arithmetic: the Python of ``step`` and its post-step stages, two launches per substep, a kernel body
entered once per spring or particle, and the strided indexing of Warp's generated loops (the loops are C++,
:data:`_FRAME_CPP`). Measured on the drape, one core: 1.78× the step-by-step frames per second at 64² and
128² (CPU time; 3.24× / 2.79× Newton's SemiImplicit; ``benchmarks/peers/results_2026-11-28_cloth_fused.txt``).

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

if TYPE_CHECKING:
    from ...model import Control, Model, State


#: The frame in C++ (a Warp native function) with Warp's own operations (``wp::add``, ``wp::length``, ...) in
#: the order of the scatter and update kernels: the force of ``pliant.energies.spring_gradient_axis``
#: negated, plus ``dashpot_force_axis`` where damped, added to one end and subtracted from the other, then
#: ``pliant.integrators.symplectic_particle`` on g + w f. C++ rather than Warp's kernel language because a
#: generated loop indexes every array through its byte strides; plain pointers into contiguous arrays
#: (``FusedFrame.launch`` checks) run the same arithmetic faster: a 64² drape spring pass in 38 µs, not 61.
#: Undamped springs go four at a time through vector sqrt and division (the divider is the bottleneck;
#: IEEE per lane, so the same bits): another 1.13× / 1.12× the frames per second at 64² / 128².
_FRAME_CPP = """
    typedef decltype(dt) T;
    const int n = x_b.shape[0];
    const int springs = spring_pairs.shape[0];
    const auto* __restrict__ pairs = spring_pairs.data;
    const auto* __restrict__ prm = spring_param.data;
    const auto* __restrict__ inv_mass = particle_inv_mass.data;
    const auto* __restrict__ fe = f_ext.data;
    auto* __restrict__ fs = f_springs.data;
    auto* __restrict__ xa = x_a.data;
    auto* __restrict__ va = v_a.data;
    auto* __restrict__ xb = x_b.data;
    auto* __restrict__ vb = v_b.data;
    for (int i = 0; i < n; ++i) {
        xb[i] = xa[i];
        vb[i] = va[i];
    }
    for (int k = 0; k < substeps; ++k) {
        int first = 0;  // springs before it ran four at a time
#ifndef __CUDA_ARCH__
        if (damped == 0) {
            // Four springs' lengths and force factors as vectors (IEEE sqrt and division per lane: the
            // scalar results), then their forces added in spring order.
            typedef T v4 __attribute__((ext_vector_type(4)));
            for (; first + 4 <= springs; first += 4) {
                v4 dx, dy, dz, rest, stiff;
                for (int q = 0; q < 4; ++q) {
                    const auto d = wp::sub(xb[pairs[first + q].c[0]], xb[pairs[first + q].c[1]]);
                    dx[q] = d.c[0];
                    dy[q] = d.c[1];
                    dz[q] = d.c[2];
                    rest[q] = prm[first + q].c[0];
                    stiff[q] = prm[first + q].c[1];
                }
                const v4 l = __builtin_elementwise_sqrt(dx * dx + dy * dy + dz * dz);  // as wp::length
                const v4 c = (stiff * (l - rest)) / l;
                for (int q = 0; q < 4; ++q) {
                    const int i = pairs[first + q].c[0];
                    const int j = pairs[first + q].c[1];
                    wp::vec_t<3, T> g(dx[q] * T(0.0), dy[q] * T(0.0), dz[q] * T(0.0));
                    if (l[q] > T(0.0))
                        g = wp::vec_t<3, T>(dx[q] * c[q], dy[q] * c[q], dz[q] * c[q]);
                    const auto fi = wp::neg(g);
                    fs[i] = wp::add(fs[i], fi);
                    fs[j] = wp::sub(fs[j], fi);
                }
            }
        }
#endif
        for (int s = first; s < springs; ++s) {
            const int i = pairs[s].c[0];
            const int j = pairs[s].c[1];
            const auto d = wp::sub(xb[i], xb[j]);
            const T l = wp::length(d);
            auto g = wp::mul(d, T(0.0));
            if (l > T(0.0))
                g = wp::mul(d, wp::div(wp::mul(prm[s].c[1], wp::sub(l, prm[s].c[0])), l));
            auto fi = wp::neg(g);
            if (damped != 0) {
                auto fd = wp::mul(d, T(0.0));
                if (l > T(0.0)) {
                    const auto nrm = wp::div(d, l);
                    fd = wp::mul(wp::mul(wp::neg(prm[s].c[2]), wp::dot(wp::sub(vb[i], vb[j]), nrm)), nrm);
                }
                fi = wp::add(fi, fd);
            }
            fs[i] = wp::add(fs[i], fi);
            fs[j] = wp::sub(fs[j], fi);
        }
        for (int i = 0; i < n; ++i) {
            const auto f = wp::add(fs[i], fe[i]);
            fs[i] = wp::mul(f, T(0.0));
            const T w = inv_mass[i];
            auto v1 = wp::mul(delta, wp::add(vb[i], wp::mul(dt, wp::add(gravity, wp::mul(w, f)))));
            if (w == T(0.0))
                v1 = vb[i];
            xb[i] = wp::add(xb[i], wp::mul(dt, v1));
            vb[i] = v1;
        }
    }
    if (substeps % 2 == 0) {
        for (int i = 0; i < n; ++i) {
            xa[i] = xb[i];
            va[i] = vb[i];
        }
    }
"""


@wp.func_native(_FRAME_CPP)
def _frame_cpp(
    spring_pairs: wp.array(dtype=wp.vec2i),
    spring_param: wp.array(dtype=Any),
    damped: int,
    particle_inv_mass: wp.array(dtype=Any),
    gravity: Any,
    f_ext: wp.array(dtype=Any),
    substeps: int,
    dt: Any,
    delta: Any,
    f_springs: wp.array(dtype=Any),
    x_a: wp.array(dtype=Any),
    v_a: wp.array(dtype=Any),
    x_b: wp.array(dtype=Any),
    v_b: wp.array(dtype=Any),
): ...


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
    # Launched with dim 1: the whole frame on the launching thread (_FRAME_CPP).
    _frame_cpp(spring_pairs, spring_param, damped, particle_inv_mass, gravity, f_ext, substeps, dt, delta,
               f_springs, x_a, v_a, x_b, v_b)  # fmt: skip


def fused_frame_blocker(
    fused_frame: bool | None, model: Model, method: str, scatter: bool, contact: bool, collisions: int
) -> str | None:
    """Why FastMassSpring's frames will not run as one launch on this setup, or None when they will.

    Args:
        fused_frame: the solver's option: None (where it applies), True (required), False (never).
        model: the Model (its device, and whether it records gradients).
        method: the solver's method.
        scatter: whether the symplectic step is the spring scatter (``kernel="scatter"``).
        contact: whether ground contact follows each step.
        collisions: how many contact handlers follow each step.

    Raises:
        ValueError: ``fused_frame=True`` on a setup it cannot run.
    """
    if fused_frame is False:
        return "fused_frame=False"
    why = _setup_blocker(model, method, scatter, contact, collisions)
    if fused_frame and why is not None:
        raise ValueError(f"FastMassSpring(fused_frame=True) cannot fuse frames here: {why}")
    return why


def _setup_blocker(model: Model, method: str, scatter: bool, contact: bool, collisions: int) -> str | None:
    """What of this setup a one-launch frame cannot run (:func:`fused_frame_blocker`'s reasons), or None."""
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
    ) -> bool:
        """Run ``substeps`` symplectic steps of ``dt`` [s] (velocity factor ``delta``, external forces
        ``f_ext`` [N], dashpots if ``damped``) from ``state``, ending in ``state`` for an even count and in
        ``spare`` for an odd one (where ping-pong stepping ends); False (nothing run) for a strided array."""
        arrays = (state.particle_q, state.particle_qd, spare.particle_q, spare.particle_qd, f_ext)
        if not all(a.is_contiguous for a in arrays):
            return False  # the C++ loops index plain pointers
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
        return True
