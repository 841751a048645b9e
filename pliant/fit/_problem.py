"""A fitting problem: a scene, its observations, the parameters to fit and the train / test split."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from ..io import ObservationError, Observations
from ._losses import chamfer_loss, track_errors, track_loss
from ._params import (
    COMPLIANT,
    Bound,
    FitError,
    apply_globals,
    default_reasons,
    per_element_arrays,
    resolve_globals,
    seed_contact,
    widen_bounds,
)

if TYPE_CHECKING:
    from collections.abc import Callable

    from ..model import Control, Model
    from ..scene import Scene, SceneConfig
    from ..sim import Simulator

#: Multiple shooting by default (:class:`Problem` ``shooting=None``): its window [frames], the share of the
#: free particles the tracks must cover, and the fewest training frames.
SHOOTING_WINDOW = 10
SHOOTING_COVERAGE = 0.9
SHOOTING_MIN_FRAMES = 30


def observed_velocity(
    points: np.ndarray, visible: np.ndarray, f: int, frame_dt: float
) -> tuple[np.ndarray, np.ndarray]:
    """Velocities [m/s] of the tracks at frame ``f`` from their observed positions, and where they exist.

    The five-point stencil (x₋₂ − 8x₋₁ + 8x₊₁ − x₊₂)/(12 Δt), error O(Δt⁴), where frames f − 2 … f + 2 are
    seen; else the central difference (O(Δt²)); at the last observed frame the backward one. The central
    difference alone under-reads an oscillation's speed by (ωΔt)²/6, so windows of multiple shooting started
    with too little energy and the fit lowered the damping to make up for it (8 % on the fit_rope scene).

    Args:
        points: observed positions [T, K, 3] [m] (NaN where unseen).
        visible: [T, K] bool.
        f: the frame, 1 ≤ f < T.
        frame_dt: the time between frames [s].

    Returns:
        (velocities [K, 3] [m/s], [K] bool: the tracks that have one).
    """
    T = points.shape[0]
    nxt = min(f + 1, T - 1)
    vis = visible[f] & visible[f - 1] & visible[nxt]
    vel = (points[nxt] - points[f - 1]) / ((nxt - f + 1) * frame_dt)
    if 2 <= f <= T - 3:
        five = vis & visible[f - 2] & visible[f + 2]
        v5 = (points[f - 2] - 8.0 * points[f - 1] + 8.0 * points[f + 1] - points[f + 2]) / (12.0 * frame_dt)
        vel = np.where(five[:, None], v5, vel)
    return vel, vis


class Problem:
    """Observations of a scene, the parameters to fit and the loss.

    Frame ``f`` of the observations is compared with the scene's frame ``f`` (t = f · frame_dt); frames
    ``1 … n_train − 1`` train (the first ``train_fraction`` of them), the rest are the held-out test.

    Args:
        cfg: The scene (``pl.scene.load_scene``); not modified.
        obs: The observations (``pl.io.Observations.load``).
        params: Global parameter names (``pl.fit.GLOBAL``); None: the defaults of the scene's models
            (:func:`pliant.fit.default_params`: stiffness, dissipation, and the ground's coefficients when the
            observations reach it).
        per_element: A per-element parameter name (``pl.fit.PER_ELEMENT``) for the gradient stage, or None.
        train_fraction: Fraction of the frames used for training (PhysTwin: 0.7).
        device: Warp device (None: the scene's).
        dtype: ``"float32"`` / ``"float64"`` (None: the scene's).
        track_weight: Weight of the smooth-L1 tracking term.
        chamfer_weight: Weight of the one-sided Chamfer term (used when the observations have clouds).
        acceleration_weight: Weight of the acceleration regulariser (gradient stage; PhysTwin uses 0.01 on
            real data; it is not zero at the truth, so it biases a fit of clean data: default 0).
        beta: smooth-L1 threshold [m].
        shooting: Multiple shooting with teacher forcing for the training runs: every ``shooting`` frames the
            tracked particles are put back on their observed positions (and velocities from the observed
            displacement), so that each window of the training loss starts from the observed state, as
            PhysTwin's gradient stage does; a chaotic motion (an undamped cloth folding) then cannot drift
            away for good, which leaves the loss smooth in the parameters. 0: open loop (every training run
            from frame 0 alone). None: :data:`SHOOTING_WINDOW` frames where the tracks cover at least
            :data:`SHOOTING_COVERAGE` of the free particles (the forced state is then the observed one) and
            the training window has at least :data:`SHOOTING_MIN_FRAMES` frames; otherwise open loop.
            Reports, the test frames and the gradient stage's validation are always open loop.

    Raises:
        FitError: unknown parameters, nothing to fit, too few frames.
        ObservationError: times that do not match the scene's frames, tracks bound beyond the particles.
    """

    def __init__(
        self,
        cfg: SceneConfig,
        obs: Observations,
        *,
        params: list[str] | None = None,
        per_element: str | None = None,
        train_fraction: float = 0.7,
        device: str | None = None,
        dtype: str | None = None,
        track_weight: float = 1.0,
        chamfer_weight: float = 1.0,
        acceleration_weight: float = 0.0,
        beta: float = 0.01,
        shooting: int | None = None,
    ) -> None:
        self.cfg = cfg.model_copy(deep=True)
        #: The constructor's arguments: a worker process rebuilds this problem from them (fit/_workers.py).
        self.recipe = (
            self.cfg,
            obs,
            {
                "params": params,
                "per_element": per_element,
                "train_fraction": train_fraction,
                "device": device,
                "dtype": dtype,
                "track_weight": track_weight,
                "chamfer_weight": chamfer_weight,
                "acceleration_weight": acceleration_weight,
                "beta": beta,
                "shooting": shooting,
            },
        )
        reasons = default_reasons(self.cfg, obs) if params is None else {}
        names = list(reasons) if params is None else list(params)
        #: The scene as the user gave it: what ``error_nominal`` and the validation gate compare with (the
        #: searched scene may differ: a hard ground made compliant where the tracks sink into it).
        self.given = self.cfg.model_copy(deep=True)
        # compliant contact starts at the depth the tracks sink to
        self.seeded = seed_contact(self.cfg, obs, names)
        self.globals: list[Bound] = resolve_globals(self.cfg, names)
        for b in self.globals:
            b.why = reasons.get(b.name, b.why)
        self.per_element = per_element
        if not self.globals and per_element is None:
            raise FitError(
                "nothing to fit: the scene has none of the default material parameters; name some with "
                "--params (e.g. stiffness, damping_rate) or --per-element"
            )
        if not 0.0 < train_fraction <= 1.0:
            raise FitError(f"--train-fraction: expected a number in (0, 1], got {train_fraction}")
        self.device, self.dtype = device, dtype
        self.weights = {"track": track_weight, "chamfer": chamfer_weight, "acceleration": acceleration_weight}
        self.beta = beta
        if any(b.name in ("damping", "damping_rate") for b in self.globals):
            widen_bounds(self.globals, self.build(self.nominal))  # scaled to this scene's springs and masses
        scene = self.build(self.nominal)
        obs.check_times(scene.frame_dt, f"the scene {cfg.source}")
        self.frame_dt, self.frames = scene.frame_dt, obs.frames
        self.n_train = min(max(2, int(round(train_fraction * obs.frames))), obs.frames)
        self._check_controls(scene, obs)
        self.obs = obs
        x = self.simulate(scene, min(obs.frames, 8), forced=False)  # bind at each track's first visible frame
        self.obs = obs.bind(x)
        self.x0 = x[0]
        self.shooting = self._shooting(scene, shooting)
        if per_element is not None:
            per_element_arrays(scene, per_element)  # fail early on a name the scene does not have

    # ------------------------------------------------------------------ scenes
    @property
    def nominal(self) -> dict[str, float]:
        """The scene's own values of the global parameters."""
        return {b.name: b.nominal for b in self.globals}

    def config(self, values: dict[str, float]) -> SceneConfig:
        """The scene config with global parameter ``values`` (name → value) set."""
        return apply_globals(self.cfg, values)

    def build_given(self) -> Scene:
        """The scene as the user gave it (:attr:`given`), none of the search's values or seeds applied."""
        from ..scene import build_scene

        return build_scene(self.given, device=self.device, dtype=self.dtype)

    def unseed(self) -> None:
        """Go back to the scene as given where the fit had seeded compliant contact (:attr:`seeded`): its
        ground is hard again and the compliant-contact parameters leave the search."""
        if not self.seeded:
            return
        self.cfg = self.given.model_copy(deep=True)
        self.globals = [b for b in self.globals if b.name not in COMPLIANT]
        self.seeded = False

    def build(self, values: dict[str, float], requires_grad: bool = False) -> Scene:
        """Build the scene with global parameter ``values``."""
        from ..scene import build_scene

        return build_scene(
            self.config(values), device=self.device, dtype=self.dtype, requires_grad=requires_grad
        )

    def _check_controls(self, scene: Scene, obs: Observations) -> None:
        if obs.controls is None:
            return
        n = sum(cp.point_count for cp in scene.control_points)
        if n != obs.controls.shape[1]:
            raise ObservationError(
                f"{obs.source}: controls: {obs.controls.shape[1]} control points but the scene's spring "
                f'handles have {n}; give the scene one [[handles]] kind = "points" with as many points'
            )

    def control_fn(self, scene: Scene) -> Callable[[float, Control | None], None] | None:
        """f(t, control) for the Simulator: the observed control points when there are any, else the
        scene's."""
        if self.obs.controls is None:
            return scene.control_fn
        ctrl, frame_dt = self.obs.controls, self.frame_dt

        def control_fn(t: float, control: Control | None) -> None:
            f = min(int(round(t / frame_dt)) + (1 if control is not None else 0), ctrl.shape[0] - 1)
            vel = (ctrl[f] - ctrl[max(f - 1, 0)]) / frame_dt
            lo = 0
            for cp in scene.control_points:
                cp.set_positions(ctrl[f, lo : lo + cp.point_count], vel[lo : lo + cp.point_count])
                lo += cp.point_count

        return control_fn

    @property
    def particle(self) -> np.ndarray:
        """[K] int: the particle each observed track follows (``Observations.bind`` in the constructor)."""
        if self.obs.particle is None:
            raise FitError("the observations are not bound to the scene's particles yet (Observations.bind)")
        return self.obs.particle

    def _shooting(self, scene: Scene, shooting: int | None) -> int:
        if shooting is not None:
            if isinstance(shooting, bool) or int(shooting) != shooting or shooting < 0:
                raise FitError(
                    f"--shooting: expected a window of >= 0 frames (0: open loop), got {shooting!r}"
                )
            return int(shooting)
        free = int(np.count_nonzero(scene.model.particle_inv_mass.numpy() > 0))
        covered = len(np.unique(self.particle)) if self.obs.tracks else 0
        dense = free > 0 and covered >= SHOOTING_COVERAGE * free
        return SHOOTING_WINDOW if dense and self.n_train - 1 >= SHOOTING_MIN_FRAMES else 0

    def forces(self, f: int) -> bool:
        """Whether teacher forcing restarts frame ``f`` from the observations (a window start of multiple
        shooting: every :attr:`shooting` frames after frame 0, while there are observations)."""
        return getattr(self, "shooting", 0) > 0 and 0 < f < self.obs.frames and f % self.shooting == 0

    def force_state(self, model: Model, f: int, q: np.ndarray, qd: np.ndarray) -> None:
        """Teacher forcing at frame ``f``, in place on positions ``q`` and velocities ``qd`` [N, 3] of
        ``model``: the tracked free particles take their observed positions and velocities (every copy of a
        batched object); :func:`observed_velocity` gives the velocities."""
        o, m = self.obs, model
        n = self.x0.shape[0]
        starts = [0] if m.particle_count == n else [ob["start"] for ob in m.objects]
        vel, vis = observed_velocity(o.points, o.visible, f, self.frame_dt)
        free = m.particle_inv_mass.numpy() > 0
        for s in starts:
            idx = self.particle[vis] + s
            keep = free[idx]
            q[idx[keep]] = o.points[f][vis][keep]
            qd[idx[keep]] = vel[vis][keep]

    def _force(self, sim: Simulator) -> None:
        """The Simulator's ``on_frame`` hook of a forced run (:meth:`forces`, :meth:`force_state`)."""
        if not self.forces(sim.frame):
            return
        q, qd = sim.state_0.particle_q.numpy(), sim.state_0.particle_qd.numpy()
        self.force_state(sim.model, sim.frame, q, qd)
        sim.state_0.particle_q.assign(q)
        sim.state_0.particle_qd.assign(qd)

    def simulator(self, scene: Scene) -> Simulator:
        """A Simulator of ``scene`` under this problem's control function (:meth:`control_fn`)."""
        from ..sim import Simulator

        fn = self.control_fn(scene)
        kw = {**scene.sim_kwargs, "control_fn": fn} if fn is not None else scene.sim_kwargs
        return Simulator(scene.model, scene.solver, **kw)

    def simulate(
        self, scene: Scene, frames: int, forced: bool | None = None, sim: Simulator | None = None
    ) -> np.ndarray:
        """Positions [m], shape [frames, N, 3], of frames 0 … frames − 1 (DivergenceError on a blow-up).

        ``forced``: teacher forcing every :attr:`shooting` frames (see the class); None: for a training run
        (``frames == n_train``, what the CMA-ES stage simulates) when :attr:`shooting` is on.
        ``sim``: a Simulator of ``scene`` (:meth:`simulator`) to run again from frame 0
        (``Simulator.restart``: its captured frame graphs are kept); None: a new one.
        """
        fn = self.control_fn(scene)
        if fn is not None:
            fn(0.0, None)  # the handles' positions at t = 0 (the same function the Simulator calls)
        if sim is None:
            sim = self.simulator(scene)
        else:
            sim.restart()
        if forced is None:
            forced = getattr(self, "shooting", 0) > 0 and frames == self.n_train
        return sim.run(frames - 1, progress=False, on_frame=self._force if forced else None).x

    # ------------------------------------------------------------------ losses and metrics
    def loss(self, x: np.ndarray, lo: int = 1, hi: int | None = None) -> float:
        """Tracking (+ Chamfer) loss of simulated positions ``x`` [T, N, 3] on frames ``lo … hi − 1``."""
        hi = self.n_train if hi is None else hi
        if hi <= lo:
            return 0.0
        o, dev = self.obs, self.device or "cpu"
        dtype, vec = wp.float64, wp.vec3d
        xs: wp.array = wp.array(np.ascontiguousarray(x[lo:hi]).reshape(-1, 3), dtype=vec, device=dev)
        out = wp.zeros(1, dtype=dtype, device=dev)
        if self.weights["track"]:
            pts = np.nan_to_num(o.points[lo:hi]).reshape(-1, 3)
            track_loss(
                xs,
                wp.array(self.particle.astype(np.int32), dtype=wp.int32, device=dev),
                wp.array(pts, dtype=vec, device=dev),
                wp.array(o.visible[lo:hi].reshape(-1).astype(np.int32), dtype=wp.int32, device=dev),
                out,
                frames=hi - lo,
                beta=self.beta,
                weight=self.weights["track"],
            )
        if o.cloud is not None and o.cloud_count is not None and self.weights["chamfer"]:  # both or neither
            chamfer_loss(
                xs,
                wp.array(o.cloud[lo:hi].reshape(-1, 3), dtype=vec, device=dev),
                wp.array(o.cloud_count[lo:hi].astype(np.int32), dtype=wp.int32, device=dev),
                out,
                frames=hi - lo,
                weight=self.weights["chamfer"],
            )
        return float(out.numpy()[0])

    def errors(self, x: np.ndarray) -> np.ndarray:
        """Per-frame mean track error [m] of positions ``x`` [T, N, 3] (NaN where no track is visible)."""
        o = self.obs
        t = min(x.shape[0], o.frames)
        return track_errors(x[:t], self.particle, o.points[:t], o.visible[:t])

    def split_errors(self, x: np.ndarray) -> dict[str, float]:
        """Mean track error [m] over the train frames (1 … n_train − 1) and the test frames (the rest)."""
        e = self.errors(x)
        train, test = e[1 : self.n_train], e[self.n_train :]
        return {
            "train": float(np.nanmean(train)) if np.isfinite(train).any() else float("nan"),
            "test": float(np.nanmean(test)) if np.isfinite(test).any() else float("nan"),
        }


__all__ = ["Problem"]
