"""Stage 2: gradient descent on per-element parameters (Adam by default, or L-BFGS-B from SciPy), with
gradients from ``wp.Tape`` over short horizons, as PhysTwin's ``trainer_warp.py`` does.

The horizon is one frame by default: :func:`pliant.diff.rollout` (the one stepping loop) records one frame of
substeps from the state carried forward, the loss compares that frame with the observations, the rollout's
backward pass gives the gradient, the optimiser steps, and the next frame starts from the simulated end state
(without gradient) — or, with multiple shooting (``problem.shooting``), from the observed state at each
window start (teacher forcing, as the CMA-ES stage's training runs). ``horizon=None`` records
the whole training rollout on one tape. Each per-element value is ``a = a₀ · exp(θ)``; θ is what is fitted,
bounded to ``|θ| ≤ log(max_factor)``.

Repeated horizons of one shape (frames, history depth, reset) replay one captured graph (:class:`_Rollout`,
:mod:`pliant.diff._graph`), with the numbers of ``PLIANT_GRAPH=0`` bit for bit.

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

from ..diff import rollout_graphs
from ..model import State
from ._losses import acceleration_loss, chamfer_loss, track_loss
from ._params import FitError, per_element_arrays, per_element_incidence, scene_constraints
from ._problem import Problem
from ._resume import Journal, StageHook
from ._stage import StageResult

if TYPE_CHECKING:
    from ..scene import Scene

#: Most horizon shapes whose rollout graphs the stage keeps (each holds one horizon's intermediate arrays).
_MAX_SHAPES = 8


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
    rollouts are :func:`pliant.diff.rollout`'s (the one stepping loop), with the fit's per-frame loss.

    Repeated horizons replay one captured graph (:mod:`pliant.diff._graph`), which needs every call of a
    horizon shape to launch the same kernels on the same arrays: the rollout starts from fixed state buffers
    (:meth:`start`, :meth:`force`, and the end state copied back after each horizon), each horizon shape
    (frames, history depth) has one loss closure, made once, that reads its frames' observations from
    fixed buffers filled before the call, and the acceleration term's history (the positions of the up to
    three frames before the horizon) lives in fixed device buffers that the loss refills inside the pass.
    """

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
        self.control = m.control()  # one Control: a new one each call would be a new graph key
        self.grads: dict[str, np.ndarray] = {}
        # Fixed buffers (no gradient: the rollout differentiates its own copy of the start state).
        n = m.particle_count
        self.state0 = State(*(wp.empty(n, dtype=m.vec3, device=d) for _ in range(2)))
        self.accel = bool(problem.weights["acceleration"])
        self.hist = [wp.empty(n, dtype=m.vec3, device=d) for _ in range(3)]  # the frames before a horizon
        self.hist_out = [wp.empty(n, dtype=m.vec3, device=d) for _ in range(3)]  # … after it
        self.depth = 0  # how many of hist are frames (the last is the start state)
        self._losses: dict[tuple[int, int], tuple[Callable[[int, State, wp.array], None], list]] = {}

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

    def start(self) -> None:
        """Start from the model's initial state (frame 0), with only it in the history."""
        s = self.scene.model.state()
        self._restart(s.particle_q, s.particle_qd)
        self.depth = 1

    def force(self, f: int) -> None:
        """Teacher forcing at a window start of multiple shooting (``problem.shooting``), as the CMA-ES
        stage's training runs do: the tracked particles restart from their observed state (which then ends
        the history, as the frame it replaces did)."""
        q, qd = self.state0.particle_q, self.state0.particle_qd
        qn, qdn = q.numpy(), qd.numpy()
        self.problem.force_state(self.scene.model, f, qn, qdn)
        self._restart(
            wp.array(qn, dtype=q.dtype, device=q.device), wp.array(qdn, dtype=q.dtype, device=q.device)
        )

    def _restart(self, q: wp.array, qd: wp.array) -> None:
        wp.copy(self.state0.particle_q, q)
        wp.copy(self.state0.particle_qd, qd)
        wp.copy(self.hist[2], q)

    def shape(self, frames: int) -> tuple[int, int]:
        """The loss's shape key of a horizon of ``frames`` frames starting now: (frames, history depth)."""
        return frames, self.depth if self.accel else 0

    def frame_loss(self, frames: int, depth: int) -> tuple[Callable[[int, State, wp.array], None], list]:
        """The fit's loss of a horizon of ``frames`` frames with ``depth`` frames of history (tracks,
        Chamfer, acceleration), and its observation buffers; made once per shape, so that a repeated horizon
        is the same callback on the same arrays (a replayable graph)."""
        key = (frames, depth)
        if key in self._losses:
            return self._losses[key]
        p, m = self.problem, self.scene.model
        track, chamfer, accel = p.weights["track"], p.weights["chamfer"], p.weights["acceleration"]
        beta, track_norm, particle = p.beta, self.track_norm, self.particle
        pts = [wp.empty_like(self.points[0]) for _ in range(frames)]
        vis = [wp.empty_like(self.visible[0]) for _ in range(frames)]
        buffers: list = [(pts, self.points), (vis, self.visible)]
        cloud = count = None
        cloud_norm = 0
        if self.cloud is not None and chamfer:
            cloud = [wp.empty_like(self.cloud[0]) for _ in range(frames)]
            count = [wp.empty_like(self.count[0]) for _ in range(frames)]
            buffers += [(cloud, self.cloud), (count, self.count)]
            cloud_norm = self.cloud_norm
        accel_norm = 3.0 * m.particle_count * max(self.n_train - 3, 1)
        hist, hist_out = self.hist[3 - depth :], self.hist_out
        keep = min(depth + frames, 3)  # history after the horizon
        window: list[wp.array] = []  # filled during a pass only (a callback's closure is part of its key)

        def add(g: int, s: State, loss: wp.array) -> None:
            k = g - 1  # the horizon's frame (the rollout's first_frame is 0)
            if track:
                track_loss(
                    s.particle_q,
                    particle,
                    pts[k],
                    vis[k],
                    loss,
                    beta=beta,
                    weight=track,
                    normaliser=track_norm,
                )
            if cloud is not None and count is not None:
                chamfer_loss(s.particle_q, cloud[k], count[k], loss, weight=chamfer, normaliser=cloud_norm)
            if not depth:
                return
            if k == 0:
                window[:] = hist
            window.append(s.particle_q)
            if len(window) >= 4:
                x0, x1, x2, x3 = window[-4:]
                acceleration_loss(x0, x1, x2, x3, loss, beta=beta, weight=accel, normaliser=accel_norm)
            if k == frames - 1:  # the history the next horizon starts from, copied on the device
                for j, x in enumerate(window[-keep:]):
                    wp.copy(hist_out[3 - keep + j], x)
                window.clear()

        self._losses[key] = (add, buffers)
        return add, buffers

    def run(self, f0: int, frames: int, reset: bool = False) -> tuple[float, State]:
        """Simulate frames f0+1 … f0+frames from the start buffers through :func:`pliant.diff.rollout` (one
        tape); returns (loss, end state), keeps ∂loss/∂(per-element arrays) for :meth:`grad_theta` and
        carries the end state and history into the buffers for the next horizon. ``reset``: the solver
        forgets what it carries from the frame before (frame 0, or a teacher-forced start)."""
        from ..diff import rollout

        scene, m = self.scene, self.scene.model
        depth = self.shape(frames)[1]
        loss, buffers = self.frame_loss(frames, depth)
        for dst, src in buffers:
            for k in range(frames):
                wp.copy(dst[k], src[f0 + 1 + k])
        fn = self.control_fn
        res = rollout(
            m,
            scene.solver,
            None,
            frames=frames,
            dt=scene.substep_dt,
            substeps=scene.substeps,
            params=sorted(set(self.names.values())),
            state0=self.state0,
            control=self.control,
            # One segment: the acceleration term reads the frames before, in order.
            checkpoint_every=frames,
            frame_loss=loss,
            control_fn=None if fn is None else (lambda f, c: fn((f0 + f) * scene.frame_dt, c)),
            # Frames are counted from the horizon's start, so that every horizon of a shape is one key.
            first_frame=0,
            reset=reset or f0 == 0,  # a horizon continuing the previous one keeps what the solver carries
            # A control function sets the control points from the host each frame: not replayable.
            graph=None if fn is None else False,
        )
        self.grads = res.grads
        assert res.state is not None  # rollout always returns its end state
        wp.copy(self.state0.particle_q, res.state.particle_q)
        wp.copy(self.state0.particle_qd, res.state.particle_qd)
        if depth:
            self.depth = min(depth + frames, 3)
            for i in range(3 - self.depth, 3):
                wp.copy(self.hist[i], self.hist_out[i])
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


def _schedule(problem: Problem, n_frames: int, h: int) -> list[tuple[int, int, bool]]:
    """(first frame, frames, teacher-forced start) of each horizon of an Adam epoch of ``h``-frame
    horizons over frames 1 … n_frames; a horizon never spans a window start of multiple shooting."""
    out, f0 = [], 0
    while f0 < n_frames:
        frames = min(h, n_frames - f0)
        if problem.shooting > 0:
            frames = min(frames, problem.shooting - f0 % problem.shooting)
        out.append((f0, frames, problem.forces(f0)))
        f0 += frames
    return out


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
    checkpoint: StageHook | None = None,
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
        checkpoint: Saves the stage after each iteration (:mod:`pliant.fit._resume`: Adam's θ and moments
            after each epoch; L-BFGS-B's evaluations) and continues a saved one.

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

    def rollout_grad(th: np.ndarray, f0: int, frames: int, reset: bool = False) -> tuple[float, np.ndarray]:
        from ..diff import check_rollout
        from ..sim import DivergenceError

        r.set_theta(th)
        try:  # pl.diff's check: non-finite, or a particle faster than 1000 m/s (a finite blow-up)
            value, s = r.run(f0, frames, reset)  # the rollout checks its own states
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
        return value, g

    h = n_frames if horizon is None or optimizer == "lbfgs" else max(1, int(horizon))
    schedule = _schedule(problem, n_frames, h) if optimizer == "adam" else [(0, n_frames, False)]
    # Each horizon shape (frames, history depth, reset) is one captured rollout graph, replayed every epoch
    # (pliant.diff._graph): keep them all, or each would evict the next one before its turn.
    shapes, depth = set(), 1
    for f0, frames, restart in schedule:
        shapes.add((frames, depth if r.accel else 0, restart or f0 == 0))
        depth = min(depth + frames, 3)
    graphs = rollout_graphs(r.scene.solver)
    graphs.max_graphs = max(graphs.max_graphs, min(len(shapes), _MAX_SHAPES))

    saved = None if checkpoint is None else checkpoint.state
    try:
        if optimizer == "lbfgs":
            from scipy.optimize import minimize

            journal = Journal(None if saved is None else saved["journal"])

            def evaluate(th: np.ndarray) -> tuple[float, np.ndarray]:
                r.start()
                value, g = rollout_grad(th, 0, n_frames)
                return regularise(th, value, g, 1.0)

            def fun(th: np.ndarray) -> tuple[float, np.ndarray]:
                value, g = journal(evaluate, th)
                if value < result.loss:
                    result.loss, result.per_element = value, r.values(th)
                result.evaluations += 1
                return value, g

            def cb(th: np.ndarray) -> None:
                result.history.append(result.loss)
                if checkpoint is not None and not journal.replaying:
                    checkpoint.save({"journal": journal.entries}, len(result.history))
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
            mom, var = np.zeros(r.size), np.zeros(r.size)
            b1, b2, step, first = 0.9, 0.99, 0, 0
            stop = Convergence(tol)
            if saved is not None:  # the state after the saved epoch
                theta, mom, var = (np.asarray(saved[k], np.float64) for k in ("theta", "mom", "var"))
                step, first, stop.best, stop.stalled = (
                    saved["step"],
                    saved["epochs"],
                    saved["best"],
                    saved["stalled"],
                )
                result.loss, result.per_element = saved["loss"], r.values(theta)
                result.history, result.evaluations = list(saved["history"]), saved["evaluations"]
                checked[0] = True
            for it in range(first, iterations):
                if saved is not None and saved["stopped"]:
                    break
                # Step size decays geometrically from lr to lr / 10 over the run, so that Adam settles.
                lr_it = lr * 0.1 ** (it / max(iterations - 1, 1))
                r.start()
                epoch = 0.0
                for f0, frames, restart in schedule:
                    if restart:
                        r.force(f0)
                    value, g = rollout_grad(theta, f0, frames, restart)
                    value, g = regularise(theta, value, g, frames / n_frames)
                    epoch += value
                    result.evaluations += 1
                    step += 1
                    mom = b1 * mom + (1 - b1) * g
                    var = b2 * var + (1 - b2) * g * g
                    mhat, vhat = mom / (1 - b1**step), var / (1 - b2**step)
                    theta = np.clip(theta - lr_it * mhat / (np.sqrt(vhat) + 1e-12), -bound, bound)
                # θ moved during the epoch (one step per horizon): its loss is the sum over the frames as
                # they were simulated; the result is the θ after the epoch.
                result.loss, result.per_element = epoch, r.values(theta)
                result.history.append(epoch)
                stopped = stop(epoch)
                if checkpoint is not None:
                    state = {k: v.tolist() for k, v in (("theta", theta), ("mom", mom), ("var", var))}
                    state.update(step=step, epochs=it + 1, best=stop.best, stalled=stop.stalled, loss=epoch)
                    state.update(history=result.history, evaluations=result.evaluations, stopped=stopped)
                    checkpoint.save(state, it + 1)
                if callback is not None:
                    callback(it + 1, epoch)
                if stopped:
                    break
    except KeyboardInterrupt:
        result.interrupted = True
    result.wall_time = time.perf_counter() - t0
    return result


__all__ = ["gradient_stage"]
