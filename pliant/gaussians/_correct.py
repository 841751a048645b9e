"""Visual correction of a running simulation from calibrated images.

Two methods share one class, :class:`VisualCorrector`:

- ``"state"`` (default): a photometric *estimate* of the particle positions, x̂ = argmin_x Σ_cameras
  MSE(render(binding.deform(x)), image), found by a few bounded L-BFGS-B iterations started at the simulated
  positions (the gradient flows image → Gaussians → binding → particles, so no per-Gaussian displacement has
  to be spread back). The innovation d = x̂ − x then corrects the state at the frame boundary, like a
  position-based (PBD) projection: x ← x + α d, v ← v + β d / T, plus a persistent residual force
  f_i ← f_i + κ m_i 2 d_i / T² (an integral term: it learns the force the model is missing, so the error
  that builds up *inside* the next frame shrinks too). A convex blend of positions cannot go unstable the way
  a force held over a frame does.
- ``"forces"``: Physically Embodied Gaussians' visual forces (Abou-Chakra et al. 2024): Adam steps on the
  means, then f = gain · opacity · Δμ spread onto particles with the binding's weights.

Why the default is not EG's form: on deformables with light particles a force held over a 1/30 s frame is a
sampled P-controller that is unstable at useful gains, and Adam's per-coordinate normalisation adds
full-size steps along directions with negligible gradient (docs/gaussians.md, "Visual correction").
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

from .._warp import np_dtype, vec3_type
from ._bind import Binding
from ._camera import Camera
from ._fit import _accumulate, _views
from ._optim import Adam, photometric_loss
from ._render import render

if TYPE_CHECKING:
    from ..model import Control
    from ..sim import Simulator

_METHODS = ("state", "forces")


@wp.kernel
def _spread_kernel(
    link_gauss: wp.array(dtype=wp.int32),
    link_particle: wp.array(dtype=wp.int32),
    link_weight: wp.array(dtype=Any),
    means: wp.array(dtype=Any),
    means0: wp.array(dtype=Any),
    opacity_logits: wp.array(dtype=Any),
    gain: Any,
    forces_out: wp.array(dtype=Any),
):
    k = wp.tid()
    g = link_gauss[k]
    one = type(gain)(1.0)
    o = one / (one + wp.exp(-opacity_logits[g]))
    wp.atomic_add(forces_out, link_particle[k], (link_weight[k] * gain * o) * (means[g] - means0[g]))


@wp.kernel
def _add_kernel(b: wp.array(dtype=Any), a_io: wp.array(dtype=Any), old_io: wp.array(dtype=Any)):
    # a += b − old; old = b: replace this corrector's previous contribution to the external forces
    i = wp.tid()
    a_io[i] = a_io[i] + (b[i] - old_io[i])
    old_io[i] = b[i]


@wp.kernel
def _state_kernel(
    estimate: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=Any),
    mass: wp.array(dtype=Any),
    alpha: Any,
    beta_over_t: Any,
    kappa_over_t2: Any,
    q_io: wp.array(dtype=Any),
    qd_io: wp.array(dtype=Any),
    residual_io: wp.array(dtype=Any),
    force_io: wp.array(dtype=Any),
    innovation_out: wp.array(dtype=Any),
):
    i = wp.tid()
    if inv_mass[i] == type(alpha)(0.0):  # pinned and kinematic particles keep their prescribed motion
        innovation_out[i] = q_io[i] - q_io[i]
        return
    d = estimate[i] - q_io[i]
    innovation_out[i] = d
    q_io[i] = q_io[i] + alpha * d
    qd_io[i] = qd_io[i] + beta_over_t * d
    f = residual_io[i] + (kappa_over_t2 * mass[i]) * d
    force_io[i] = force_io[i] + (f - residual_io[i])
    residual_io[i] = f


class VisualCorrector:
    """Corrects a running simulation toward what calibrated cameras see (call once per frame).

    Usage::

        vc = pl.gaussians.VisualCorrector(binding, cameras)      # method="state"
        for images in stream:                                    # one RGB image per camera, this frame
            vc.correct(sim, images)                              # before the frame's substeps
            sim.step_frame()

    Args:
        binding: Gaussians bound to the simulated particles (their colours are the object's appearance).
        cameras: The calibrated cameras the images come from.
        method: ``"state"`` (photometric state estimate, position/velocity correction and a residual force;
            see the module doc) or ``"forces"`` (Embodied Gaussians' visual forces).
        iterations: ``"state"``: L-BFGS-B evaluations of the photometric loss per frame (each one render
            and its adjoint per camera); ``"forces"``: Adam steps on the means (EG: 3). Default 10 / 3.
        max_step: ``"state"``: bound on each coordinate of the estimate's change [m] (a trust region;
            photometric gradients carry no information much beyond a splat's size). Default: the median
            of the Gaussians' largest scales.
        position_gain: α in [0, 1]: the fraction of the innovation applied to the positions.
        velocity_gain: β ≥ 0: velocity change β d / T [m/s] for an innovation d over the frame time T.
        force_gain: κ ≥ 0: residual force increment κ m 2 d / T² [N] per frame (0 disables it).
        lr_means: ``"forces"``: Adam learning rate of the means [m] (EG: 1.5e-3).
        gain: ``"forces"``: k_p [N/m] in f = k_p · opacity · Δμ (EG: 4).
        background: RGB behind the Gaussians in the images.

    Raises:
        ValueError: unknown method or gains out of range.
    """

    def __init__(
        self,
        binding: Binding,
        cameras: Sequence[Camera],
        *,
        method: str = "state",
        iterations: int | None = None,
        max_step: float | None = None,
        position_gain: float = 1.0,
        velocity_gain: float = 0.5,
        force_gain: float = 0.2,
        lr_means: float = 1.5e-3,
        gain: float = 4.0,
        background: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        if method not in _METHODS:
            raise ValueError(f"unknown visual correction method {method!r}; use one of {_METHODS}")
        if not 0.0 <= position_gain <= 1.0 or velocity_gain < 0.0 or force_gain < 0.0:
            raise ValueError(
                "VisualCorrector gains: position_gain must lie in [0, 1], velocity_gain and force_gain >= 0"
            )
        self.binding = binding
        self.cameras = list(cameras)
        self.method = method
        self.iterations = int(iterations if iterations is not None else (10 if method == "state" else 3))
        if self.iterations < 1:
            raise ValueError(f"iterations must be >= 1, got {self.iterations}")
        g = binding.gaussians
        self.max_step = float(max_step) if max_step is not None else float(np.median(g.scales.max(axis=1)))
        if not self.max_step > 0.0:
            raise ValueError(f"max_step must be a positive distance [m], got {self.max_step}")
        self.position_gain, self.velocity_gain, self.force_gain = position_gain, velocity_gain, force_gain
        self.lr_means = float(lr_means)
        self.gain = float(gain)
        self.background = background
        gi, pi, w = binding.particle_weights()
        dev = g.device
        self._links: tuple[wp.array, wp.array, wp.array] = (
            wp.array(gi.astype(np.int32), dtype=wp.int32, device=dev),
            wp.array(pi.astype(np.int32), dtype=wp.int32, device=dev),
            wp.array(w, dtype=g.opacity_logits.dtype, device=dev),
        )
        v3 = vec3_type(g.dtype)
        n = binding.particle_count
        self._residual = wp.zeros(n, dtype=v3, device=dev)  # the residual force this corrector applies [N]
        self._applied = wp.zeros(n, dtype=v3, device=dev)  # what "forces" last added to particle_f [N]
        #: The last frame's innovation d = x̂ − x [m] per particle ("state"), for diagnostics.
        self.innovation = wp.zeros(n, dtype=v3, device=dev)

    # ------------------------------------------------------------------ photometric state estimate
    def _loss_and_gradient(self, x: np.ndarray, views) -> tuple[float, np.ndarray]:
        """Mean photometric loss over the views for particle positions x [P, 3] and its gradient w.r.t. x."""
        g = self.binding.gaussians
        q: wp.array = wp.array(
            x.astype(np_dtype(g.dtype)), dtype=vec3_type(g.dtype), device=g.device, requires_grad=True
        )
        tape = wp.Tape()
        with tape:
            placed = self.binding.deform(q)
            outs = [render(placed, cam, self.background) for cam, _, _ in views]
        total, grads = 0.0, {}
        for (c, _a, _d), (_cam, img, _mask) in zip(outs, views, strict=True):
            loss, gc, _ = photometric_loss(c, _a, img, None)
            total += loss
            grads[c] = gc
        tape.backward(grads=grads)
        n = len(views)
        return total / n, q.grad.numpy().astype(np.float64).reshape(-1) / n

    def estimate(self, particle_q: wp.array, images: Sequence[Any], fixed: np.ndarray | None = None):
        """Particle positions [m] that best explain ``images`` near ``particle_q`` (NumPy [P, 3], float64).

        Bounded L-BFGS-B on the mean photometric loss of all cameras, ``iterations`` evaluations at most,
        each coordinate within ``max_step`` of its start; ``fixed`` (bool [P]) particles do not move.
        """
        from scipy.optimize import minimize

        g = self.binding.gaussians
        views = _views(self.cameras, images, None, g.dtype, g.device)
        x0 = particle_q.numpy().astype(np.float64).reshape(-1, 3)
        r = np.full(x0.shape, self.max_step)
        if fixed is not None:
            r[np.asarray(fixed, dtype=bool)] = 0.0
        best = [np.inf, x0]  # the lowest loss evaluated: a budget-limited run may end on a rejected trial

        def fun(z: np.ndarray) -> tuple[float, np.ndarray]:
            x = x0 + r * z.reshape(-1, 3)
            loss, grad = self._loss_and_gradient(x, views)
            if loss < best[0]:
                best[0], best[1] = loss, x
            return loss, grad * r.reshape(-1)

        n = self.iterations
        minimize(
            fun,
            np.zeros(x0.size),
            jac=True,
            method="L-BFGS-B",
            bounds=[(-1.0, 1.0)] * x0.size,  # in units of max_step: the trust region is the unit box
            # run the whole budget: the loss scale depends on the images, so relative tolerances mislead
            options={"maxfun": n, "maxiter": n, "maxcor": 20, "ftol": 0.0, "gtol": 0.0},
        )
        return best[1]

    # ------------------------------------------------------------------ the per-frame entry point
    def correct(self, sim: Simulator, images: Sequence[Any]) -> wp.array:
        """Correct ``sim`` (a :class:`pliant.Simulator`) toward ``images`` (one per camera, taken now).

        ``"state"`` changes ``sim.state_0`` in place and sets its residual force in
        ``sim.control.particle_f``; ``"forces"`` sets the visual forces there. Either way the corrector
        replaces only its own previous contribution to ``particle_f``, so other forces added once stay (do
        not zero ``particle_f`` between frames, or the residual force is lost). Pinned and kinematic
        particles are never moved. Returns the innovation ("state") or the visual forces ("forces").
        """
        model, state, control = sim.model, sim.state_0, sim.control
        f = control.particle_f
        if f.shape != (self.binding.particle_count,) or f.dtype != vec3_type(self.binding.gaussians.dtype):
            raise ValueError(
                f"the simulation has {f.shape[0]} {f.dtype.__name__} particles; the binding expects "
                f"{self.binding.particle_count} {vec3_type(self.binding.gaussians.dtype).__name__}"
            )
        if self.method == "forces":
            out = self.forces(state.particle_q, images)
            wp.launch(_add_kernel, dim=f.shape[0], inputs=[out, f, self._applied], device=f.device)
            return out
        inv_mass = model.particle_inv_mass
        est = self.estimate(state.particle_q, images, fixed=inv_mass.numpy() == 0)
        s = model.scalar
        T = float(sim.frame_dt)
        wp.launch(
            _state_kernel,
            dim=f.shape[0],
            inputs=[
                wp.array(est.astype(np_dtype(model.dtype)), dtype=model.vec3, device=f.device),
                inv_mass,
                model.particle_mass,
                s(self.position_gain),
                s(self.velocity_gain / T),
                s(2.0 * self.force_gain / T**2),
            ],
            outputs=[state.particle_q, state.particle_qd, self._residual, f, self.innovation],
            device=f.device,
        )
        return self.innovation

    def reset(self) -> None:
        """Forget the residual force (call when the simulation is reset; ``particle_f`` is not touched)."""
        self._residual.zero_()
        self._applied.zero_()

    # ------------------------------------------------------------------ Embodied Gaussians' visual forces
    def forces(self, particle_q: wp.array, images: Sequence[Any]) -> wp.array:
        """EG's visual forces [N] per particle (vec3 [particle_count]) for positions ``particle_q`` [m].

        ``iterations`` Adam steps on the placed Gaussians' means, then f_g = gain · opacity_g · Δμ_g spread
        onto the particles with the binding's weights.
        """
        g = self.binding.gaussians
        views = _views(self.cameras, images, None, g.dtype, g.device)
        placed = self.binding.deform(wp.clone(particle_q, requires_grad=False))
        means = wp.clone(placed.means, requires_grad=True)
        moving = placed.with_means(means, transforms=placed.transforms)
        opt = Adam([means], [self.lr_means])
        for _ in range(self.iterations):
            means.grad.zero_()
            _accumulate(moving, views, self.background, 0.0)
            opt.step()
        f = wp.zeros(self.binding.particle_count, dtype=vec3_type(g.dtype), device=g.device)
        s = g.opacity_logits.dtype
        wp.launch(
            _spread_kernel,
            dim=self._links[0].shape[0],
            inputs=[*self._links, means, placed.means, g.opacity_logits, s(self.gain)],
            outputs=[f],
            device=g.device,
        )
        return f

    def apply(self, particle_q: wp.array, control: Control, images: Sequence[Any]) -> wp.array:
        """Add EG's visual forces to ``control.particle_f`` (a :class:`pliant.Control`); returns them."""
        f = self.forces(particle_q, images)
        cur = control.particle_f
        if cur.shape != f.shape or cur.dtype != f.dtype:
            raise ValueError(f"control.particle_f is {cur.shape} {cur.dtype.__name__}, forces are {f.shape}")
        zero = wp.zeros_like(f)
        wp.launch(_add_kernel, dim=f.shape[0], inputs=[f, cur, zero], device=f.device, record_tape=False)
        return f
