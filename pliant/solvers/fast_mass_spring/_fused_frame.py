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

Before each substep the drag handle's force (``drag_force`` at the substep's start position) goes into a
scratch copy of the external forces, as ``FastMassSpring._external`` sums it. After each substep's update
come the stages ``finish_step`` runs after a step, per particle in its order:
the control's kinematic targets (in the C++ update loop: ``apply_kinematic``'s two lines), then the ground
response. The update loop lists the particles whose penetration r − (y − height) is positive (the plane
kind's own test, so exactly those the response moves); for those, the loop in the kernel language calls
``pliant.collision.ground_particle``, the very function the ground's post-step kernel calls: projection with
restitution, or compliant contact (reading the substep's start, saved for them). Each particle's
response reads only its own state, so the list's order does not matter: bit for bit again.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

from ..._warp import grad_enabled
from ...collision import friction_law_code, ground_particle
from .._post import drag_force, kinematic_slot

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
    const auto* __restrict__ slot = kinematic_slot.data;
    const auto* __restrict__ tg = kinematic_targets.data;
    const auto* __restrict__ rad = particle_radius.data;
    auto* __restrict__ fs = f_springs.data;
    auto* __restrict__ xb = x_b.data;
    auto* __restrict__ vb = v_b.data;
    auto* __restrict__ xs = x_start.data;
    auto* __restrict__ hit = contacts.data;
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
    int count = 0;
    for (int i = 0; i < n; ++i) {
        const auto x0 = xb[i];
        const auto f = wp::add(fs[i], fe[i]);
        fs[i] = wp::mul(f, T(0.0));
        const T w = inv_mass[i];
        auto v1 = wp::mul(delta, wp::add(vb[i], wp::mul(dt, wp::add(gravity, wp::mul(w, f)))));
        if (w == T(0.0))
            v1 = vb[i];
        xb[i] = wp::add(xb[i], wp::mul(dt, v1));
        vb[i] = v1;
        if (kinematic != 0 && slot[i] >= 0) {  // apply_kinematic: on the target, at the speed to it
            xb[i] = tg[slot[i]];
            vb[i] = wp::mul(wp::sub(tg[slot[i]], x0), inv_dt);
        }
        if (ground != 0 && w != T(0.0) && wp::sub(rad[i], wp::sub(xb[i].c[1], height)) > T(0.0)) {
            xs[i] = x0;  // the step's start (compliant contact's damper reads it)
            hit[count++] = i;
        }
    }
    hit[n] = count;  // a generic native function returns no value: the count follows the list
"""

#: Copies the frame's input into the spare buffer (``into_b``) or the end state back (ping-pong's buffer).
_COPY_CPP = """
    const int n = x_a.shape[0];
    auto* __restrict__ xa = x_a.data;
    auto* __restrict__ va = v_a.data;
    auto* __restrict__ xb = x_b.data;
    auto* __restrict__ vb = v_b.data;
    for (int i = 0; i < n; ++i) {
        if (into_b != 0) {
            xb[i] = xa[i];
            vb[i] = va[i];
        } else {
            xa[i] = xb[i];
            va[i] = vb[i];
        }
    }
"""


@wp.func_native(_FRAME_CPP)
def _substep_cpp(
    spring_pairs: wp.array(dtype=wp.vec2i),
    spring_param: wp.array(dtype=Any),
    damped: int,
    particle_inv_mass: wp.array(dtype=Any),
    gravity: Any,
    f_ext: wp.array(dtype=Any),
    dt: Any,
    delta: Any,
    f_springs: wp.array(dtype=Any),
    kinematic: int,
    kinematic_slot: wp.array(dtype=wp.int32),
    kinematic_targets: wp.array(dtype=Any),
    inv_dt: Any,
    ground: int,
    particle_radius: wp.array(dtype=Any),
    height: Any,
    x_start: wp.array(dtype=Any),
    contacts: wp.array(dtype=wp.int32),
    x_b: wp.array(dtype=Any),
    v_b: wp.array(dtype=Any),
) -> None: ...


@wp.func_native(_COPY_CPP)
def _copy_cpp(
    into_b: int, x_a: wp.array(dtype=Any), v_a: wp.array(dtype=Any), x_b: wp.array(dtype=Any),
    v_b: wp.array(dtype=Any),
): ...  # fmt: skip


@wp.kernel(enable_backward=False)
def _symplectic_frame(
    # Model (packed per spring: rest length, stiffness, dashpot γ):
    spring_pairs: wp.array(dtype=wp.vec2i),
    spring_param: wp.array(dtype=Any),
    damped: int,
    particle_inv_mass: wp.array(dtype=Any),
    gravity: Any,
    # Control (kinematic: 1 where its targets apply; slot: particle -> target index, -1 for the others):
    particle_f: wp.array(dtype=Any),
    drag_index: int,
    drag_target: Any,
    drag_stiffness: Any,
    drag_max_force: Any,
    kinematic: int,
    kinematic_slot: wp.array(dtype=wp.int32),
    kinematic_targets: wp.array(dtype=Any),
    # Steps:
    substeps: int,
    dt: Any,
    inv_dt: Any,
    delta: Any,
    # Ground (0: none, 1: projection, 2: compliant), as respond_to_ground passes it:
    ground: int,
    particle_radius: wp.array(dtype=Any),
    height: Any,
    coefficients: wp.array(dtype=Any),
    law: int,
    stick_velocity: Any,
    shift_dt: Any,
    kappa: Any,
    damping: Any,
    # Scratch: the forces the update adds (with a drag handle (drag_index >= 0) an array the frame fills from
    # particle_f, else particle_f itself), the scattered spring forces (zero between steps; the update clears
    # it again), the particles below the ground after a substep's update (their count in the last element)
    # and their start positions:
    f_ext_io: wp.array(dtype=Any),
    f_springs_io: wp.array(dtype=Any),
    contacts_io: wp.array(dtype=wp.int32),
    x_start_io: wp.array(dtype=Any),
    # State: the frame's input (written back for an even substep count) and the spare buffer:
    x_a_io: wp.array(dtype=Any),
    v_a_io: wp.array(dtype=Any),
    x_b_io: wp.array(dtype=Any),
    v_b_io: wp.array(dtype=Any),
):
    # Launched with dim 1: the whole frame on the launching thread. Springs and update in C++ (_FRAME_CPP),
    # which lists the particles below the ground; their response by the ground kernels' own wp.funcs.
    _copy_cpp(1, x_a_io, v_a_io, x_b_io, v_b_io)
    if drag_index >= 0:
        for i in range(particle_f.shape[0]):
            f_ext_io[i] = particle_f[i]
    for _k in range(substeps):
        if drag_index >= 0:  # FastMassSpring._external and add_drag_force: at the substep's start position
            f_ext_io[drag_index] = particle_f[drag_index] + drag_force(
                drag_target, drag_stiffness, drag_max_force, x_b_io[drag_index]
            )
        _substep_cpp(spring_pairs, spring_param, damped, particle_inv_mass, gravity, f_ext_io, dt, delta,
                             f_springs_io, kinematic, kinematic_slot, kinematic_targets, inv_dt, ground,
                             particle_radius, height, x_start_io, contacts_io, x_b_io, v_b_io)  # fmt: skip
        for c in range(contacts_io[x_b_io.shape[0]]):
            i = contacts_io[c]
            xi, vi = ground_particle(x_b_io[i], v_b_io[i], x_start_io[i], particle_inv_mass[i],
                                     particle_radius[i], height, coefficients[0], coefficients[1], law,
                                     stick_velocity, shift_dt, kappa, damping, dt)  # fmt: skip
            x_b_io[i] = xi
            v_b_io[i] = vi
    if substeps % 2 == 0:
        _copy_cpp(0, x_a_io, v_a_io, x_b_io, v_b_io)


def fused_frame_blocker(
    fused_frame: bool | None, model: Model, method: str, scatter: bool, collisions: int
) -> str | None:
    """Why FastMassSpring's frames will not run as one launch on this setup, or None when they will.

    Args:
        fused_frame: the solver's option: None (where it applies), True (required), False (never).
        model: the Model (its device, and whether it records gradients).
        method: the solver's method.
        scatter: whether the symplectic step is the spring scatter (``kernel="scatter"``).
        collisions: how many contact handlers follow each step.

    Raises:
        ValueError: ``fused_frame=True`` on a setup it cannot run.
    """
    if fused_frame is False:
        return "fused_frame=False"
    why = _setup_blocker(model, method, scatter, collisions)
    if fused_frame and why is not None:
        raise ValueError(f"FastMassSpring(fused_frame=True) cannot fuse frames here: {why}")
    return why


def _setup_blocker(model: Model, method: str, scatter: bool, collisions: int) -> str | None:
    """What of this setup a one-launch frame cannot run (:func:`fused_frame_blocker`'s reasons), or None."""
    if not wp.get_device(model.device).is_cpu:
        return "the device is not the CPU (one thread would run the whole frame on a GPU)"
    if method != "symplectic":
        return f"method={method!r} (only the symplectic step is fused)"
    if not scatter:
        return "kernel='gather' (the fused frame is the scatter's arithmetic)"
    if grad_enabled(model):
        return "the model records gradients (each step must write fresh arrays for the tape)"
    if collisions:
        return "contact handlers follow each step"
    return None


class FusedFrame:
    """The fused frame's packed spring parameters, scratch and recorded launches (one per buffer pair, Δt,
    control arrays and ground).

    Args:
        model: the Model.
        spring_pairs: the springs' endpoints [S] (vec2i), as the scatter kernel reads them.
        f_springs: the scatter's force scratch [N] (shared with the per-step path: zero between steps).
        ground: [friction μ, restitution e] of the ground response each substep
            (:func:`pliant.collision.ground_coefficients`); None: no ground contact.
    """

    def __init__(
        self, model: Model, spring_pairs: wp.array, f_springs: wp.array, ground: wp.array | None = None
    ) -> None:
        self.model = model
        self.spring_pairs = spring_pairs
        self.f_springs = f_springs
        self.ground = ground
        #: (rest length [m], stiffness [N/m], γ [N s/m]) per spring, refreshed by :meth:`pack`.
        self.param = wp.zeros(max(model.spring_count, 1), dtype=model.vec3, device=model.device)
        n, d = max(model.particle_count, 1), model.device
        #: Each substep's particles below the ground after the update, and their positions at its start.
        self.contacts = wp.zeros(n + 1, dtype=wp.int32, device=d)  # and how many, last
        self.x_start = wp.zeros(n, dtype=model.vec3, device=d)
        self._no_slot = wp.full(1, -1, dtype=wp.int32, device=d)
        self._no_targets = wp.zeros(1, dtype=model.vec3, device=d)
        self._no_coefficients = wp.zeros(2, dtype=model.scalar, device=d)
        self._cmds: dict[tuple, Any] = {}

    def pack(self, per_spring: np.ndarray) -> None:
        """Write the springs' parameters [S, 3] in place (recorded launches and graphs keep the array)."""
        if per_spring.shape[0]:
            self.param.assign(per_spring)
        self._cmds.clear()

    def _ground_args(self) -> tuple[list, tuple]:
        """The ground's launch arguments (as :func:`pliant.collision.respond_to_ground` passes them to its
        kernels for the explicit step: shift 1) and the host values they were made from (the cache key)."""
        m, g = self.model, self.model.ground
        if self.ground is None or g is None:
            return [0, m.particle_radius, m.s(0.0), self._no_coefficients, 0, m.s(0.0)], ()
        kind = 2 if g.compliant else 1
        key = (kind, g.height, g.stick_velocity, g.friction_law, g.stiffness, g.damping, self.ground.ptr)
        args = [kind, m.particle_radius, m.s(g.height), self.ground, friction_law_code(g.friction_law)]
        return [*args, m.s(g.stick_velocity)], key

    def launch(
        self,
        state: State,
        spare: State,
        control: Control | None,
        f_ext: wp.array,
        f_work: wp.array,
        dt: float,
        delta: float,
        substeps: int,
        damped: int,
    ) -> bool:
        """Run ``substeps`` symplectic steps of ``dt`` [s] (velocity factor ``delta``, external forces
        ``f_ext`` [N] plus the control's drag handle (summed in ``f_work``), dashpots if ``damped``, then the
        control's kinematic targets and the ground response) from ``state``, ending in ``state`` for an even
        count and in ``spare`` for an odd one (where ping-pong stepping ends); False (nothing run) for a
        strided array."""
        arrays = [state.particle_q, state.particle_qd, spare.particle_q, spare.particle_qd, f_ext]
        indices, targets = None, self._no_targets
        if control is not None and control.kinematic_indices.shape[0]:
            indices, targets = control.kinematic_indices, control.kinematic_targets
        arrays.append(targets)
        if not all(a.is_contiguous for a in arrays):
            return False  # the C++ loops index plain pointers
        ground, gkey = self._ground_args()
        drag: tuple[int, tuple[float, ...], float, float] = (-1, (0.0, 0.0, 0.0), 0.0, 0.0)
        if control is not None and control.drag_index >= 0:
            c = control
            drag = (c.drag_index, tuple(map(float, c.drag_target)), c.drag_stiffness, c.drag_max_force)
        # δ and the dashpot switch are baked into the recorded launch: a damping_rate set between frames
        # must record a new one.
        kin_ptr = 0 if indices is None else indices.ptr
        key = (*(a.ptr for a in arrays), dt, delta, damped, substeps, kin_ptr, gkey, drag)
        cmd = self._cmds.get(key)
        if cmd is None:
            if len(self._cmds) > 8:
                self._cmds.clear()
            m, g = self.model, self.model.ground
            kin = indices is not None
            slot = self._no_slot if indices is None else kinematic_slot(m, indices)
            kappa, damping = 0.0, 0.0
            if g is not None and g.stiffness is not None and ground[0] == 2:
                kappa, damping = g.stiffness, g.damping
            args = [self.spring_pairs, self.param, damped, m.particle_inv_mass, m.gravity_vec, f_ext]
            args += [drag[0], m.vec3(*drag[1]), m.s(drag[2]), m.s(drag[3])]
            args += [int(kin), slot, targets, int(substeps), m.s(dt), m.s(1.0 / dt), m.s(delta)]
            args += [*ground, m.s(dt), m.s(kappa), m.s(damping)]
            args += [f_ext if drag[0] < 0 else f_work, self.f_springs, self.contacts, self.x_start]
            args += [state.particle_q, state.particle_qd, spare.particle_q, spare.particle_qd]
            cmd = self._cmds[key] = wp.launch(_symplectic_frame, 1, args, device=m.device, record_cmd=True)
        cmd.launch()
        return True
