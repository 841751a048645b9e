"""Stage 2: gradient descent on per-element parameters (Adam by default, or L-BFGS-B from SciPy), with
gradients from ``wp.Tape`` over short horizons, as PhysTwin's ``trainer_warp.py`` does.

The horizon is one frame by default: :func:`pliant.diff.rollout` (the one stepping loop) records one frame of
substeps from the state carried forward, the loss compares that frame with the observations, the rollout's
backward pass gives the gradient, the optimiser steps, and the next frame starts from the simulated end state
(without gradient) — or, with multiple shooting (``problem.shooting``), from the observed state at each
window start (teacher forcing, as the CMA-ES stage's training runs). ``horizon=None`` records
the whole training rollout on one tape. Each per-element value is ``a = a₀ · exp(θ)``; θ is what is fitted,
bounded to ``|θ| ≤ log(max_factor)``.

A solver whose step is not tape-correct gives zero gradients; this stage refuses to go on when the
gradient of a non-zero loss is exactly zero (a clear error, never a silent no-op).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from ..model import State
from ._cmaes import StageResult
from ._losses import acceleration_loss, chamfer_loss, track_loss
from ._params import FitError, per_element_arrays, per_element_incidence, scene_constraints
from ._problem import Problem

if TYPE_CHECKING:
    from ..scene import Scene


class Smoothness:
    """Total-variation prior on θ over neighbouring elements (elements that share a particle):
    ``R(θ) = weight / n · Σ_(a,b) (√((θ_a − θ_b)² + ε²) − ε)``, n the number of elements.

    Why total variation: per-element stiffnesses are poorly conditioned one by one (springs in parallel
    trade load, and a stiff spring barely stretches, so its own data gradient is weak and noisy), while real
    objects are made of few materials. An L1 penalty on differences pulls an element towards its
    neighbours' consensus but, unlike a quadratic (Laplacian) penalty, costs a sharp material boundary only
    its length, so the boundary stays sharp. ε [log units] rounds the kink at 0 so Adam sees a smooth
    function. θ are log-factors, so the penalty is scale-free (a jump 100 → 1000 N/m costs as much as
    1 → 10).

    Args:
        incidence: [n, k] particles of each element.
        weight: λ, in units of the training loss.
        eps: smoothing of |·| [log units].
    """

    def __init__(self, incidence: np.ndarray, weight: float, eps: float = 0.01) -> None:
        from scipy import sparse

        inc = np.asarray(incidence, np.int64)
        n, k = inc.shape
        a = sparse.csr_matrix((np.ones(n * k), (np.repeat(np.arange(n), k), inc.ravel())))
        pairs = sparse.triu(a @ a.T, k=1).tocoo()
        self.a, self.b = pairs.row, pairs.col
        self.n, self.weight, self.eps = max(n, 1), float(weight), float(eps)

    def value_grad(self, theta: np.ndarray) -> tuple[float, np.ndarray]:
        """R(θ) and dR/dθ."""
        d = theta[self.a] - theta[self.b]
        r = np.sqrt(d * d + self.eps**2)
        c = self.weight / self.n
        g = np.zeros_like(theta)
        np.add.at(g, self.a, c * d / r)
        np.add.at(g, self.b, -c * d / r)
        return float(c * np.sum(r - self.eps)), g


class Convergence:
    """Stopping rule of the gradient stages: ``stop(loss)`` after each iteration is True once the best loss
    has improved by less than ``tol`` (relative) over each of the last ``patience`` iterations (the cap
    on iterations is the caller's).

    Args:
        tol: Relative improvement below which an iteration counts as stalled (0: never stop early).
        patience: Stalled iterations in a row that stop the stage.
    """

    def __init__(self, tol: float, patience: int = 5) -> None:
        if not (math.isfinite(tol) and tol >= 0):
            raise FitError(f"tol: expected a relative improvement >= 0, got {tol}")
        self.tol, self.patience = float(tol), int(patience)
        self.best, self.stalled = math.inf, 0

    def __call__(self, loss: float) -> bool:
        gain = (
            (self.best - loss) / abs(self.best) if math.isfinite(self.best) and self.best != 0 else math.inf
        )
        self.best = min(self.best, loss)
        self.stalled = self.stalled + 1 if gain < self.tol else 0
        return self.tol > 0 and self.stalled >= self.patience


class _Rollout:
    """A scene built with gradients, its per-element arrays and the observation arrays on the device; its
    rollouts are :func:`pliant.diff.rollout`'s (the one stepping loop), with the fit's per-frame loss."""

    def __init__(self, problem: Problem, values: dict[str, float], shared: bool, n_train: int) -> None:
        self.problem, self.n_train = problem, n_train
        self.scene = problem.build(values, requires_grad=True)
        m = self.scene.model
        assert problem.per_element is not None  # the gradient stage fits per-element arrays
        self.arrays = per_element_arrays(self.scene, problem.per_element)
        self.names = {k: _registry_name(self.scene, k) for k in self.arrays}
        self.base = {k: a.numpy().astype(np.float64) for k, a in self.arrays.items()}
        self.shared = shared
        self.size = 1 if shared else next(iter(self.arrays.values())).shape[0]
        o, d = problem.obs, m.device
        assert o.particle is not None  # Problem binds the tracks to particles (Observations.bind)
        self.particle: wp.array = wp.array(o.particle.astype(np.int32), dtype=wp.int32, device=d)
        self.points: list[wp.array] = [wp.array(np.nan_to_num(p), dtype=m.vec3, device=d) for p in o.points]
        self.visible: list[wp.array] = [
            wp.array(v.astype(np.int32), dtype=wp.int32, device=d) for v in o.visible
        ]
        n_vis = o.visible[1:n_train].sum()
        self.track_norm = 3.0 * max(int(n_vis), 1)
        self.cloud: list[wp.array] | None = None
        if o.cloud is not None and o.cloud_count is not None:  # the file checks they come together
            self.cloud = [wp.array(c, dtype=m.vec3, device=d) for c in o.cloud]
            self.count: list[wp.array] = [wp.array([int(c)], dtype=wp.int32, device=d) for c in o.cloud_count]
            self.cloud_norm = max(int(o.cloud_count[1:n_train].sum()), 1)
        self.control_fn = problem.control_fn(self.scene)
        self.grads: dict[str, np.ndarray] = {}

    def set_theta(self, theta: np.ndarray) -> None:
        for k, a in self.arrays.items():
            a.assign(self.base[k] * np.exp(theta))

    def values(self, theta: np.ndarray) -> dict[str, np.ndarray]:
        return {k: self.base[k] * np.exp(theta) for k in self.arrays}

    def grad_theta(self) -> np.ndarray:
        """dL/dθ = Σ_arrays dL/da · a (chain rule through a = a₀ exp θ), from the last :meth:`run`."""
        g: np.ndarray | float = 0.0
        for k, a in self.arrays.items():
            g = g + self.grads[self.names[k]] * a.numpy().astype(np.float64)
        return np.atleast_1d(np.sum(g)) if self.shared else np.asarray(g)

    def frame_loss(self, hist: list) -> Callable[[int, State, wp.array], None]:
        """The fit's loss of observed frame ``g`` (tracks, Chamfer, acceleration over ``hist``, the
        positions of the frames before), added into ``out``."""
        p, m = self.problem, self.scene.model

        def add(g: int, s: State, loss: wp.array) -> None:
            if p.weights["track"]:
                track_loss(
                    s.particle_q,
                    self.particle,
                    self.points[g],
                    self.visible[g],
                    loss,
                    beta=p.beta,
                    weight=p.weights["track"],
                    normaliser=self.track_norm,
                )
            if self.cloud is not None and p.weights["chamfer"]:
                chamfer_loss(
                    s.particle_q,
                    self.cloud[g],
                    self.count[g],
                    loss,
                    weight=p.weights["chamfer"],
                    normaliser=self.cloud_norm,
                )
            hist.append(s.particle_q)
            if p.weights["acceleration"] and len(hist) >= 4:
                x0, x1, x2, x3 = hist[-4:]
                acceleration_loss(
                    x0,
                    x1,
                    x2,
                    x3,
                    loss,
                    beta=p.beta,
                    weight=p.weights["acceleration"],
                    normaliser=3.0 * m.particle_count * max(self.n_train - 3, 1),
                )

        return add

    def run(
        self, q: wp.array, qd: wp.array, f0: int, frames: int, hist: list, reset: bool = False
    ) -> tuple[float, State]:
        """Simulate frames f0+1 … f0+frames from (q, qd) through :func:`pliant.diff.rollout` (one tape);
        returns (loss, end state) and keeps ∂loss/∂(per-element arrays) for :meth:`grad_theta`. ``reset``:
        the solver forgets what it carries from the frame before (frame 0, or a teacher-forced start)."""
        from ..diff import rollout

        scene, m = self.scene, self.scene.model
        fn = self.control_fn
        res = rollout(
            m,
            scene.solver,
            None,
            frames=frames,
            dt=scene.substep_dt,
            substeps=scene.substeps,
            params=sorted(set(self.names.values())),
            state0=State(q, qd),
            control=m.control(),
            # One segment: the acceleration term reads the frames before, in order.
            checkpoint_every=frames,
            frame_loss=self.frame_loss(hist),
            control_fn=None if fn is None else (lambda f, c: fn(f * scene.frame_dt, c)),
            first_frame=f0,
            reset=reset or f0 == 0,  # a horizon continuing the previous one keeps what the solver carries
            # Never replayed: each horizon starts from new arrays and its frame loss is a new closure that
            # keeps host history (the acceleration term), so every call is a new key (pliant.diff._graph).
            graph=False,
        )
        self.grads = res.grads
        assert res.state is not None  # rollout always returns its end state
        return res.loss, res.state


def _registry_name(scene: Scene, key: str) -> str:
    """The registry parameter (:data:`pliant.diff.PARAMETERS`) of per-element array ``key``
    (``model.<array>`` or ``constraints.<i>.<array>``)."""
    parts = key.split(".")
    if parts[0] == "model":
        return parts[1]
    c = scene_constraints(scene)[int(parts[1])]
    return next(
        p.name for p in type(c).parameters() if p.differentiable and p.arrays[0] == f"constraint.{parts[2]}"
    )


def _detach(a: wp.array) -> wp.array:
    return wp.clone(a, requires_grad=True)


def gradient_stage(
    problem: Problem,
    values: dict[str, float],
    *,
    iterations: int = 20,
    lr: float = 0.01,
    horizon: int | None = 1,
    optimizer: str = "adam",
    max_factor: float = 100.0,
    shared: bool = False,
    smoothness: float = 0.0,
    frames: int | None = None,
    tol: float = 1e-4,
    callback: Callable[[int, float], None] | None = None,
) -> StageResult:
    """Fit ``problem.per_element`` (log-scale factors θ per element) with gradients from the tape.

    Args:
        problem: The fitting problem (``per_element`` set).
        values: Global parameter values to build the scene with (stage 1's result).
        iterations: Epochs: passes over the training frames (Adam), or L-BFGS-B iterations.
        lr: Adam's initial step size in θ (log-scale units; 0.01 ≈ 1 % per step), decaying to lr / 10.
        horizon: Frames per tape (1: PhysTwin's one-frame horizon, the state carried forward); None: the
            whole training rollout on one tape (needed by L-BFGS).
        optimizer: ``"adam"`` or ``"lbfgs"`` (SciPy L-BFGS-B on θ, whole-rollout horizon).
        max_factor: Bound of each factor: a₀ / max_factor ≤ a ≤ a₀ · max_factor.
        shared: One factor for all elements (a global scale fitted with gradients) instead of one each.
        smoothness: Weight λ of the total-variation prior over neighbouring elements (:class:`Smoothness`;
            0: none). With Adam it is added once per epoch, spread over the epoch's horizons.
        frames: Train on frames 1 … frames − 1 only (default: all of ``problem``'s training frames); the
            rest can validate the result (:func:`pliant.fit.fit` does).
        tol: Stop when the epoch loss improves by less than this fraction five epochs in a row (Adam;
            L-BFGS-B: its ``ftol``); ``iterations`` is the cap. 0: run every iteration.
        callback: ``callback(iteration, loss)`` after each iteration.

    Raises:
        FitError: no per-element parameter, an unknown optimiser, or a solver that gives no gradient.
    """
    if problem.per_element is None:
        raise FitError(
            "the gradient stage needs a per-element parameter (--per-element stiffness, E, compliance)"
        )
    if not (math.isfinite(smoothness) and smoothness >= 0):
        raise FitError(f"smoothness: expected a weight >= 0, got {smoothness}")
    if optimizer not in ("adam", "lbfgs"):
        raise FitError(f"optimizer: expected 'adam' or 'lbfgs', got {optimizer!r}")
    t0 = time.perf_counter()
    n_train = problem.n_train if frames is None else min(max(2, int(frames)), problem.n_train)
    r = _Rollout(problem, values, shared, n_train)
    m = r.scene.model
    n_frames = n_train - 1
    bound = math.log(max_factor)
    theta = np.zeros(r.size)
    result = StageResult(values=dict(values), loss=float("inf"), per_element=r.values(theta))
    checked = [False]
    prior = None
    if smoothness > 0 and not shared:
        prior = Smoothness(per_element_incidence(r.scene, problem.per_element), smoothness)

    def regularise(th: np.ndarray, value: float, g: np.ndarray, share: float) -> tuple[float, np.ndarray]:
        if prior is None:
            return value, g
        rv, rg = prior.value_grad(th)
        return value + share * rv, g + share * rg

    def rollout_grad(
        th: np.ndarray, f0: int, frames: int, q: wp.array, qd: wp.array, hist: list, reset: bool = False
    ):
        from ..diff import check_rollout
        from ..sim import DivergenceError

        r.set_theta(th)
        try:  # pl.diff's check: non-finite, or a particle faster than 1000 m/s (a finite blow-up)
            value, s = r.run(q, qd, f0, frames, hist, reset)  # the rollout checks its own states
            g = r.grad_theta()
            sc = r.scene
            h = sc.substep_dt
            check_rollout(  # and the gradient with respect to θ, which it does not see
                value, {"theta": g}, s, solver=sc.solver, dt=h, substeps=sc.substeps, frames=f0 + frames
            )
        except (DivergenceError, ValueError) as exc:
            raise FitError(
                f"the gradient stage's rollout over frames {f0}-{f0 + frames} blew up ({exc}); lower --lr too"
            ) from None
        if value > 0 and not checked[0]:
            if not np.any(g != 0.0):
                raise FitError(
                    f"the {type(r.scene.solver).__name__} step of this scene gives exactly zero gradient for "
                    f"{problem.per_element!r}: its step is not tape-differentiable in this version, or the "
                    "parameter does not move the tracked points; fit global parameters only (no "
                    "--per-element), or use a differentiable solver (XPBD)"
                )
            checked[0] = True
        end = (_detach(s.particle_q), _detach(s.particle_qd))
        return value, g, end

    def start_state():
        s = m.state()
        return _detach(s.particle_q), _detach(s.particle_qd)

    def forced(f: int, q: wp.array, qd: wp.array) -> tuple[wp.array, wp.array]:
        """Teacher forcing at a window start of multiple shooting (``problem.shooting``), as the CMA-ES
        stage's training runs do: the tracked particles restart from their observed state."""
        qn, qdn = q.numpy(), qd.numpy()
        problem.force_state(m, f, qn, qdn)
        return (
            wp.array(qn, dtype=q.dtype, device=q.device, requires_grad=True),
            wp.array(qdn, dtype=qd.dtype, device=qd.device, requires_grad=True),
        )

    try:
        if optimizer == "lbfgs":
            from scipy.optimize import minimize

            def fun(th: np.ndarray) -> tuple[float, np.ndarray]:
                q, qd = start_state()
                value, g, _ = rollout_grad(th, 0, n_frames, q, qd, [q])
                value, g = regularise(th, value, g, 1.0)
                if value < result.loss:
                    result.loss, result.per_element = value, r.values(th)
                result.evaluations += 1
                return value, g

            def cb(th: np.ndarray) -> None:
                result.history.append(result.loss)
                if callback is not None:
                    callback(len(result.history), result.loss)

            minimize(
                fun,
                theta,
                jac=True,
                method="L-BFGS-B",
                bounds=[(-bound, bound)] * r.size,
                options={"maxiter": iterations},
                callback=cb,
            )
        else:
            h = n_frames if horizon is None else max(1, int(horizon))
            mom, var = np.zeros(r.size), np.zeros(r.size)
            b1, b2, step = 0.9, 0.99, 0
            stop = Convergence(tol)
            for it in range(iterations):
                # Step size decays geometrically from lr to lr / 10 over the run, so that Adam settles.
                lr_it = lr * 0.1 ** (it / max(iterations - 1, 1))
                q, qd = start_state()
                hist: list = [q]
                epoch = 0.0
                f0 = 0
                while f0 < n_frames:
                    frames = min(h, n_frames - f0)
                    if problem.shooting > 0:  # a tape never spans a window start
                        frames = min(frames, problem.shooting - f0 % problem.shooting)
                    restart = problem.forces(f0)
                    if restart:
                        q, qd = forced(f0, q, qd)
                        hist[-1] = q
                    value, g, (q, qd) = rollout_grad(theta, f0, frames, q, qd, hist, restart)
                    value, g = regularise(theta, value, g, frames / n_frames)
                    hist[-1] = q
                    hist[:] = hist[-3:]
                    epoch += value
                    result.evaluations += 1
                    step += 1
                    mom = b1 * mom + (1 - b1) * g
                    var = b2 * var + (1 - b2) * g * g
                    mhat, vhat = mom / (1 - b1**step), var / (1 - b2**step)
                    theta = np.clip(theta - lr_it * mhat / (np.sqrt(vhat) + 1e-12), -bound, bound)
                    f0 += frames
                # θ moved during the epoch (one step per horizon): its loss is the sum over the frames as
                # they were simulated; the result is the θ after the epoch.
                result.loss, result.per_element = epoch, r.values(theta)
                result.history.append(epoch)
                if callback is not None:
                    callback(it + 1, epoch)
                if stop(epoch):
                    break
    except KeyboardInterrupt:
        result.interrupted = True
    result.wall_time = time.perf_counter() - t0
    return result


__all__ = ["gradient_stage"]
