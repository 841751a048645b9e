"""Photometric system identification: physical parameters fitted to calibrated camera videos alone.

The observation file carries ``images`` [C, T, H, W, 3] with ``K`` and ``world_to_camera`` (no tracks, no
point clouds needed). The simulated object is drawn as 3D Gaussians bound to its particles
(:func:`pliant.gaussians._scene.scene_gaussians`: the scene's ``[gaussians]`` section when it has one, else
Gaussians generated deterministically from the object's surface; ``pliant observe --cameras`` made the
images the same way), rendered by pliant's Warp rasteriser from every camera at every training frame, and
compared with the images:

    L = 1/(C·F) Σ_c Σ_f [ mean_pixels,channels |I_cf − Î_cf|² + w_m · mean_pixels (α_cf − M_cf)² ]

(the mask term only when the file has ``masks``). Frames f = 1 … n_train − 1 train, as in every fit.

- Stage 1 (CMA-ES, forward runs only) is the ordinary one: :class:`PhotometricProblem` only replaces the loss.
- Stage 2 (:func:`refine_globals`) follows the gradient of the same loss through the whole training rollout:
  image → Gaussians (hand-written compositing adjoint) → binding → particle positions → every substep of the
  solver (``wp.Tape``) → per-spring (per-tet) arrays → the global parameter. A global value enters the model
  as arrays proportional to it (found once by building the scene at twice the value), so
  ∂L/∂log p = Σ_i ∂L/∂a_i · a_i over the proportional entries; L-BFGS-B (or Adam) on log p within its bounds.

This is pliant → pliant data: the same Gaussians and the same renderer made the images (an "inverse crime");
it measures the gradient path and the identifiability of a parameter from images, not robustness to real
footage.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

from ..gaussians import GENERATED_BACKGROUND
from ..io import Observations
from ._gradient import Convergence
from ._params import GLOBAL, FitError, GlobalParam
from ._problem import Problem
from ._resume import Journal, StageHook
from ._stage import StageResult

if TYPE_CHECKING:
    from ..diff import RolloutResult
    from ..gaussians import RenderOutput
    from ..scene import GaussiansSection, Scene, SceneConfig

#: Background colour behind generated Gaussians in observed and rendered images (RGB in [0, 1]); a scene's
#: ``[gaussians]`` section sets its own.
BACKGROUND = GENERATED_BACKGROUND


@wp.kernel
def _image_loss_kernel(
    colour: wp.array2d(dtype=Any),
    alpha: wp.array2d(dtype=Any),
    target: wp.array2d(dtype=Any),
    mask: wp.array2d(dtype=Any),
    has_mask: int,
    colour_weight: Any,
    mask_weight: Any,
    out: wp.array(dtype=Any),
):
    # Straight-line per pixel: Warp's automatic adjoint gives ∂L/∂colour and ∂L/∂alpha on the tape, which
    # the rasteriser's hand-written compositing adjoint then reads.
    y, x = wp.tid()
    d = colour[y, x] - target[y, x]
    loss = colour_weight * wp.dot(d, d)
    if has_mask != 0:
        e = alpha[y, x] - mask[y, x]
        loss = loss + mask_weight * e * e
    wp.atomic_add(out, 0, loss)


class PhotometricProblem(Problem):
    """A fitting problem whose loss compares rendered images with observed camera videos.

    Args:
        cfg: The scene (``pl.scene.load_scene``); not modified.
        obs: Observations with ``images``, ``K`` and ``world_to_camera`` (tracks optional and unused by the
            loss; they are still reported as track errors when present).
        mask_weight: Weight w_m of the mask term (used when the observations have ``masks``).
        per_triangle: Gaussians per surface triangle (1 or 3) of the generated splats the fit renders
            (``pliant fit`` uses 1, as ``pliant observe --cameras`` does); a scene with a ``[gaussians]``
            section renders the section's splats instead (and refuses ``per_triangle`` != 1).
        **kwargs: As :class:`pliant.fit.Problem` (``params``, ``train_fraction``, ``device``, ``dtype``);
            ``per_element`` is refused (per-element fits from images are not supported).

    Raises:
        FitError: no images, a per-element parameter, or a ``[gaussians]`` section that cannot be built.
        ObservationError: as :class:`Problem` (times that do not match the scene's frames).
    """

    photometric = True
    #: The ``[gaussians]`` section of the appearance stage's splats, once it ran (pliant/fit/_explain.py).
    appearance_section: GaussiansSection | None = None

    def __init__(
        self,
        cfg: SceneConfig,
        obs: Observations,
        *,
        mask_weight: float = 1.0,
        per_triangle: int = 1,
        **kwargs: Any,
    ) -> None:
        from ..gaussians import Camera, SplatSceneError, scene_gaussians

        if obs.images is None:
            raise FitError(f"{obs.source}: images: a photometric fit needs camera images in the observations")
        if kwargs.get("per_element") is not None:
            raise FitError(
                "--per-element: per-element parameters cannot be fitted from images yet; fit global ones "
                "(--params stiffness, ...): stage 2 refines them with image gradients"
            )
        super().__init__(cfg, obs, **kwargs)
        scene = self.build(self.nominal)
        m = scene.model
        self.scalar, self.vec3, self.model_device = m.scalar, m.vec3, str(m.device)
        self.dtype_name = "float64" if m.scalar == wp.float64 else "float32"
        H, W = obs.images.shape[2:4]  # checked above: not None
        K, w2c = obs.K, obs.world_to_camera
        assert K is not None and w2c is not None  # Observations requires them beside images
        self.cameras = [Camera(K[c], w2c[c], W, H) for c in range(obs.cameras)]
        try:
            self.splats = scene_gaussians(scene, per_triangle=per_triangle)
        except SplatSceneError as exc:
            raise FitError(str(exc)) from None
        self.binding = self.splats.binding
        self.gaussians = self.binding.gaussians
        self.mask_weight = float(mask_weight)
        self._targets: dict[tuple[int, int], tuple[wp.array, wp.array | None]] = {}

    # ------------------------------------------------------------------ images
    def target(self, camera: int, frame: int) -> tuple[wp.array, wp.array | None]:
        """Observed image (vec3 [H, W]) and mask ([H, W] or None) of ``camera`` at ``frame`` (device)."""
        key = (camera, frame)
        if key not in self._targets:
            img: wp.array = wp.array(self.obs.image(camera, frame), dtype=self.vec3, device=self.model_device)
            raw = self.obs.mask(camera, frame)
            mk: wp.array | None = (
                None if raw is None else wp.array(raw, dtype=self.scalar, device=self.model_device)
            )
            self._targets[key] = (img, mk)
        return self._targets[key]

    def render(self, q: wp.array, camera: int) -> RenderOutput:
        """Colour, alpha and depth of the Gaussians bound to particle positions ``q`` seen by ``camera``."""
        return self.splats.render(q, self.cameras[camera])

    def add_frame_loss(self, q: wp.array, frame: int, out: wp.array, views: int) -> None:
        """Add frame ``frame``'s photometric loss of positions ``q`` (vec3 [N]), over all cameras, divided by
        ``views`` (the number of camera × frame terms averaged), into ``out`` [1] (recorded by an active
        tape).
        """
        H, W = self.cameras[0].height, self.cameras[0].width
        s = self.scalar
        for c in range(len(self.cameras)):
            colour, alpha, _ = self.render(q, c)
            img, mk = self.target(c, frame)
            wp.launch(
                _image_loss_kernel,
                dim=(H, W),
                inputs=[
                    colour,
                    alpha,
                    img,
                    alpha if mk is None else mk,
                    int(mk is not None),
                    s(1.0 / (3.0 * H * W * views)),
                    s(self.mask_weight / (H * W * views)),
                ],
                outputs=[out],
                device=self.model_device,
            )

    def frame_losses(self, x: np.ndarray, lo: int = 1, hi: int | None = None) -> np.ndarray:
        """Photometric loss of each frame ``lo … hi − 1`` of positions ``x`` [T, N, 3] (mean over cameras)."""
        hi = min(self.frames, x.shape[0]) if hi is None else hi
        out = np.full(max(hi - lo, 0), np.nan)
        for i, f in enumerate(range(lo, hi)):
            acc = wp.zeros(1, dtype=self.scalar, device=self.model_device)
            q: wp.array = wp.array(np.ascontiguousarray(x[f]), dtype=self.vec3, device=self.model_device)
            self.add_frame_loss(q, f, acc, len(self.cameras))
            out[i] = float(acc.numpy()[0])
        return out

    def loss(self, x: np.ndarray, lo: int = 1, hi: int | None = None) -> float:
        """Photometric loss (mean over cameras and frames ``lo … hi − 1``; default: the training frames) of
        simulated positions ``x`` [T, N, 3]."""
        hi = self.n_train if hi is None else hi
        if hi <= lo:
            return 0.0
        return float(np.mean(self.frame_losses(x, lo, hi)))

    def image_report(self, x: np.ndarray, x_nominal: np.ndarray) -> dict[str, Any]:
        """Per-frame photometric loss of the fitted and nominal motions, train / test means and, without
        masks, PSNR [dB] (for ``fit.json``)."""
        n = self.n_train
        out: dict[str, Any] = {
            "cameras": len(self.cameras),
            "image_size": [self.cameras[0].width, self.cameras[0].height],
            "gaussians": self.gaussians.count,
        }
        for key, pos in (("fitted", x), ("nominal", x_nominal)):
            per_frame = self.frame_losses(pos, 0)
            split = {"train": per_frame[1:n], "test": per_frame[n:]}
            out[key] = {"loss_per_frame": per_frame.tolist()}
            for part, v in split.items():
                mean = float(np.mean(v)) if len(v) else None
                out[key][f"loss_{part}"] = mean
                if self.obs.masks is None and mean is not None:  # the loss is then the colour MSE
                    out[key][f"psnr_{part}_db"] = -10.0 * math.log10(mean) if mean > 0 else None
        return out

    def comparison_frames(
        self, x: np.ndarray, camera: int = 0, min_height: int = 240
    ) -> Iterator[np.ndarray]:
        """Video frames for ``fit.mp4``: the observed image of ``camera`` (left) beside the simulated
        positions ``x`` drawn as the fit's splats from the same camera (right), for every observed frame.

        Args:
            x: Simulated positions [m], shape [T, N, 3] (the fitted motion).
            camera: Index of the observation camera.
            min_height: Both images are enlarged by the smallest integer factor (nearest pixel) that makes
                them at least this tall [px], so that small observation videos stay visible.

        Yields:
            uint8 RGB frames [LABEL_BAR + s·H, 2·s·W + 2·s, 3]: a dark bar on top naming the two halves
            (above the images, so small ones are not covered), then the images with a grey bar between.
        """
        H, W = self.cameras[camera].height, self.cameras[camera].width
        s = max(1, -(-int(min_height) // H))
        bar = np.full((H, 2, 3), 0.5)
        for f in range(min(x.shape[0], self.obs.frames)):
            q: wp.array = wp.array(np.ascontiguousarray(x[f]), dtype=self.vec3, device=self.model_device)
            observed = np.asarray(self.obs.image(camera, f), dtype=np.float64)
            fitted = self.render(q, camera).colour.numpy().astype(np.float64)
            row = np.concatenate([observed, bar, fitted], axis=1)
            row = np.repeat(np.repeat(row, s, axis=0), s, axis=1)
            frame = np.round(np.clip(row, 0.0, 1.0) * 255.0).astype(np.uint8)
            top = np.full((LABEL_BAR, frame.shape[1], 3), 30, dtype=np.uint8)
            labels = [(0, f"observed, camera {camera}"), (s * (W + 2), "fitted (splats)")]
            yield np.concatenate([_label(top, labels), frame], axis=0)

    # ------------------------------------------------------------------ differentiable rollout
    def rollout(self, scene: Scene, params: list[str] | tuple[str, ...] = ()) -> RolloutResult:
        """The training loss of ``scene`` (built with ``requires_grad``) simulated from its initial state by
        :func:`pliant.diff.rollout` (the one stepping loop), every substep and render on its tape; returns
        its :class:`pliant.diff.RolloutResult` (``loss`` equals :meth:`loss` of :meth:`simulate`'s
        positions; ``grads`` of the registry parameters ``params``)."""
        from ..diff import rollout

        m = scene.model
        fn = self.control_fn(scene)
        if fn is not None:
            fn(0.0, None)
        views = len(self.cameras) * (self.n_train - 1)
        frames = self.n_train - 1
        return rollout(
            m,
            scene.solver,
            None,
            frames=frames,
            dt=scene.substep_dt,
            substeps=scene.substeps,
            params=list(params),
            control=m.control(),
            checkpoint_every=frames,
            frame_loss=lambda f, s, out: self.add_frame_loss(s.particle_q, f, out, views),
            control_fn=None if fn is None else (lambda f, c: fn(f * scene.frame_dt, c)),
        )


def _values_of(scene: Scene, name: str) -> tuple[Any, np.ndarray, int | None]:
    """(array, its values in float64, component or None) of registry parameter ``name`` in a built
    scene (GradientError when the scene has none)."""
    from ..diff import PARAMETERS

    m = scene.model
    a = PARAMETERS[name](m, scene.solver, m.state(), m.control())
    arr, comp = a if isinstance(a, tuple) else (a, None)
    return arr, arr.numpy().astype(np.float64), comp


class _GlobalGradient:
    """Loss and ∂loss/∂log p of global parameters ``names`` through one requires_grad scene whose arrays
    proportional to them are rescaled in place (no rebuild per evaluation). The arrays are those of the
    registry parameters each global parameter drives (``GLOBAL[name].drives``: model arrays, solver
    arrays such as the damping rate, constraint compliances), found proportional by building the scene at
    twice the value."""

    def __init__(self, problem: PhotometricProblem, values: dict[str, float], names: list[str]) -> None:
        from .._warp import GradientError

        self.problem, self.names = problem, names
        self.v0 = {n: float(values[n]) for n in names}
        self.scene = problem.build(values, requires_grad=True)
        plain = problem.build(values, requires_grad=True)
        self.arrays: dict[str, tuple[Any, int | None]] = {}  # registry name → (array in self.scene, comp)
        self.base: dict[str, np.ndarray] = {}
        self.masks: dict[str, dict[str, np.ndarray]] = {}
        for name in names:
            twice = problem.build({**values, name: 2.0 * values[name]}, requires_grad=True)
            self.masks[name] = {}
            for reg in GLOBAL[name].drives:
                try:
                    _, a0, comp = _values_of(plain, reg)
                    _, a1, _ = _values_of(twice, reg)
                except GradientError:
                    continue  # this scene has no such array (no dihedral set, no damping rate array)
                if comp is not None:  # one component of a shared array
                    keep = np.zeros(a0.shape, bool)
                    keep[comp] = True
                    a1 = np.where(keep, a1, a0)
                prop = (a0 != 0) & np.isclose(a1, 2.0 * a0, rtol=1e-6, atol=0.0)
                same = np.isclose(a1, a0, rtol=1e-12, atol=0.0)
                if not np.all(prop | same):
                    raise FitError(
                        f"--params {name}: the model's {reg} is not proportional to {name} in this scene, "
                        "so its image gradient is not defined here; fit it with CMA-ES only (--iterations "
                        "for the generations, and no gradient stage)"
                    )
                if prop.any():
                    self.masks[name][reg] = prop
                    arr, base, comp = _values_of(self.scene, reg)
                    self.arrays[reg] = (arr, comp)
                    self.base[reg] = base
            if not self.masks[name]:
                raise FitError(f"--params {name}: no array of this scene depends on it")

    def evaluate(self, theta: np.ndarray, grad: bool = True) -> tuple[float, np.ndarray]:
        """(loss, ∂loss/∂θ) at log factors θ (p = p₀ · exp θ for each name)."""
        for reg, (a, _) in self.arrays.items():
            log_f = sum(t * self.masks[n].get(reg, 0.0) for t, n in zip(theta, self.names, strict=True))
            a.assign(self.base[reg] * np.exp(log_f))
        res = self.problem.rollout(self.scene, list(self.arrays) if grad else [])
        g = np.zeros(len(self.names))
        if grad:
            for i, n in enumerate(self.names):
                for reg, mask in self.masks[n].items():
                    a = self.arrays[reg][0].numpy().astype(np.float64)
                    ga = np.zeros_like(a)
                    comp = self.arrays[reg][1]
                    if comp is None:
                        ga = np.asarray(res.grads[reg], dtype=np.float64).reshape(a.shape)
                    else:
                        ga[comp] = float(res.grads[reg])
                    g[i] += float(np.sum(mask * ga * a))
        return res.loss, g

    def values(self, theta: np.ndarray) -> dict[str, float]:
        return {n: self.v0[n] * math.exp(float(t)) for n, t in zip(self.names, theta, strict=True)}


def gradient_capable(param: GlobalParam) -> bool:
    """Whether the image-gradient stage can refine global parameter ``param`` (a ``GlobalParam``): a
    positive magnitude (log scale) that drives registry parameters (``drives``: stiffness, Et, damping,
    damping_rate, E, compliance); ν, the ground coefficients and the topology are CMA-ES's alone."""
    return bool(param.drives) and param.log and not param.topology


def refinable(problem: Problem) -> list[str]:
    """The problem's global parameters that :func:`refine_globals` can differentiate."""
    return [b.name for b in problem.globals if gradient_capable(b.param)]


def _check_refinable(problem: Problem, optimizer: str) -> list[str]:
    """The names :func:`refine_globals` refines; FitError when there is none or ``optimizer`` is unknown."""
    names = refinable(problem)
    if not names:
        capable = [n for n, p in GLOBAL.items() if gradient_capable(p)]
        raise FitError(
            f"the image-gradient stage refines {', '.join(capable)}; none of them is fitted here (the others "
            "are fitted by CMA-ES alone)"
        )
    if optimizer not in ("adam", "lbfgs"):
        raise FitError(f"optimizer: expected 'adam' or 'lbfgs', got {optimizer!r}")
    return names


def _evaluate_or_inf(gg: _GlobalGradient, theta: np.ndarray) -> tuple[float, np.ndarray]:
    """The loss and gradient at ``theta``; (inf, zeros) for a rollout that diverged."""
    from ..sim import DivergenceError

    try:
        return gg.evaluate(theta)
    except DivergenceError:  # pl.diff refuses a rollout that blew up: a failed trial, not an error
        return math.inf, np.zeros_like(theta)


def refine_globals(
    problem: PhotometricProblem,
    values: dict[str, float],
    *,
    iterations: int = 20,
    optimizer: str = "lbfgs",
    lr: float = 0.01,
    tol: float = 1e-4,
    callback: Callable[[int, float], None] | None = None,
    checkpoint: StageHook | None = None,
) -> StageResult:
    """Stage 2 of a photometric fit: gradient descent on the log of the global parameters that enter the
    model or the solver as proportional arrays (:func:`gradient_capable`: every log-scale parameter that
    drives registry parameters: stiffness, Et, damping, damping_rate, E, compliance), from ``values``. It
    stops when an iteration improves the loss by less than ``tol`` (relative), or after ``iterations``.

    Args:
        problem: The photometric problem.
        values: Starting global values (stage 1's); the others are held.
        iterations: L-BFGS-B iterations, or Adam steps (each one whole training rollout plus its backward).
        optimizer: ``"lbfgs"`` (SciPy L-BFGS-B within the parameters' bounds) or ``"adam"``.
        lr: Adam's step in log units (decaying to lr / 10).
        tol: Stop when an iteration lowers the best loss by less than this fraction (L-BFGS-B: its
            ``ftol`` on the loss relative to the start; Adam: five such iterations in a row); the cap is
            ``iterations``.
        callback: ``callback(iteration, best_loss)`` after each iteration.
        checkpoint: Saves every evaluation after each iteration (:mod:`pliant.fit._resume`); a saved
            stage is continued by returning its evaluations to the optimiser in order.

    Returns:
        A StageResult whose ``values`` are the best found (never worse than ``values``: ``kept`` says
        whether they improved on them).

    Raises:
        FitError: no differentiable global parameter, an unknown optimiser, or a gradient that is exactly
            zero or not finite.
    """
    names = _check_refinable(problem, optimizer)
    t0 = time.perf_counter()
    gg = _GlobalGradient(problem, values, names)
    bounds = {b.name: b for b in problem.globals}
    box = [(math.log(bounds[n].lo / gg.v0[n]), math.log(bounds[n].hi / gg.v0[n])) for n in names]
    theta0 = np.zeros(len(names))
    start, _ = gg.evaluate(theta0, grad=False)
    result = StageResult(values=dict(values), loss=start, evaluations=1, kept=False)

    scale = 1.0 / start if start > 0 else 1.0  # the optimisers see L / L(start): tolerances are relative

    first = [True]
    journal = Journal(None if checkpoint is None or checkpoint.state is None else checkpoint.state["journal"])

    def evaluate(theta: np.ndarray) -> tuple[float, np.ndarray]:
        return _evaluate_or_inf(gg, theta)

    def save() -> None:
        if checkpoint is not None and not journal.replaying:
            checkpoint.save({"journal": journal.entries}, len(result.history))

    def fun(theta: np.ndarray) -> tuple[float, np.ndarray]:
        value, g = journal(evaluate, theta)
        result.evaluations += 1
        if not (np.isfinite(value) and np.all(np.isfinite(g))):
            # A step too stiff for the substep diverged: a high loss without slope sends the line search back.
            return 10.0, np.zeros_like(theta)
        if first[0] and value > 0 and not np.any(g != 0.0):
            # Checked at the start only: a trial step that throws the object out of every view (a too-stiff
            # explicit step blowing up) also has zero slope, and the line search must just step back.
            raise FitError(
                f"the {type(gg.scene.solver).__name__} step of this scene gives exactly zero image gradient "
                f"for {', '.join(names)}: its step is not tape-differentiable, or the object is not seen"
            )
        first[0] = False
        if value < result.loss:
            result.loss, result.values, result.kept = value, {**values, **gg.values(theta)}, True
        return value * scale, g * scale

    try:
        if optimizer == "lbfgs":
            from scipy.optimize import minimize

            def cb(theta: np.ndarray) -> None:
                result.history.append(result.loss)
                save()
                if callback is not None:
                    callback(len(result.history), result.loss)

            minimize(
                fun,
                theta0,
                jac=True,
                method="L-BFGS-B",
                bounds=box,
                options={"maxiter": iterations, "ftol": tol, "gtol": 1e-10},
                callback=cb,
            )
        else:
            theta, mom, var = theta0.copy(), np.zeros(len(names)), np.zeros(len(names))
            lo, hi = np.array([b[0] for b in box]), np.array([b[1] for b in box])
            stop = Convergence(tol)
            for it in range(iterations):
                _, g = fun(theta)
                mom = 0.9 * mom + 0.1 * g
                var = 0.99 * var + 0.01 * g * g
                step = lr * 0.1 ** (it / max(iterations - 1, 1))
                mhat, vhat = mom / (1 - 0.9 ** (it + 1)), var / (1 - 0.99 ** (it + 1))
                theta = np.clip(theta - step * mhat / (np.sqrt(vhat) + 1e-12), lo, hi)
                result.history.append(result.loss)
                save()
                if callback is not None:
                    callback(it + 1, result.loss)
                if stop(result.loss):
                    break
    except KeyboardInterrupt:
        result.interrupted = True
    result.wall_time = time.perf_counter() - t0
    return result


def problem_for(obs: Observations) -> type[Problem]:
    """The problem class of an observation file: photometric when it carries images, else tracks."""
    return PhotometricProblem if obs.images is not None else Problem


__all__ = [
    "BACKGROUND",
    "gradient_capable",
    "PhotometricProblem",
    "problem_for",
    "refinable",
    "refine_globals",
]


#: Height [px] of the bar above ``fit.mp4``'s images that names them.
LABEL_BAR = 14


def _label(frame: np.ndarray, labels: list[tuple[int, str]]) -> np.ndarray:
    """``frame`` with each text drawn at (x, 2) in white on a dark box (Pillow's built-in bitmap font)."""
    from PIL import Image, ImageDraw

    img = Image.fromarray(frame)
    draw = ImageDraw.Draw(img)
    for x, text in labels:
        left, top, right, bottom = draw.textbbox((x + 4, 3), text)
        draw.rectangle((left - 2, top - 2, right + 2, bottom + 2), fill=(30, 30, 30))
        draw.text((x + 4, 3), text, fill=(255, 255, 255))
    return np.asarray(img)
