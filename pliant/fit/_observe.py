"""Synthetic observations from a simulation (``pliant observe``): tracks of chosen particles with noise and
dropped-out frames, for tutorials, tests and known-truth studies. This is synthetic data, never a
substitute for real measurements."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ..io import Observations

if TYPE_CHECKING:
    from ..scene import Scene


def observe(
    scene: Scene,
    *,
    frames: int | None = None,
    tracks: int = 60,
    noise: float = 0.0,
    dropout: float = 0.0,
    seed: int = 0,
    cloud: bool = False,
    progress: bool = False,
) -> Observations:
    """Simulate ``scene`` and track ``tracks`` of its particles.

    Args:
        scene: A built scene (``pl.scene.build_scene``).
        frames: Observed frames including frame 0 (default: the scene's ``frames`` + 1).
        tracks: Tracked particles K (chosen at random without repetition, at most all particles; pinned and
            kinematic particles are included only when there are not enough free ones).
        noise: Standard deviation of Gaussian noise on each coordinate [m].
        dropout: Probability that a track is hidden at a frame (independent per frame and track).
        seed: Random seed of the choice of particles, the noise and the dropout.
        cloud: Also record every particle's (noisy) position as a depth "cloud" (``cloud``/``cloud_count``).
        progress: Show the simulation's progress bar.

    Returns:
        Observations with ``particle`` set to the tracked particles (frame 0 always fully visible), and
        ``controls`` when the scene has spring handles (their control points at each frame).
    """
    if tracks < 1:
        raise ValueError(f"--tracks: expected at least 1 track, got {tracks}")
    if not 0.0 <= dropout < 1.0:
        raise ValueError(f"--dropout: expected a probability in [0, 1), got {dropout}")
    if not noise >= 0.0 or not np.isfinite(noise):
        raise ValueError(f"--noise: expected a standard deviation >= 0 in metres, got {noise}")
    frames = scene.frames + 1 if frames is None else frames
    if frames < 2:
        raise ValueError(f"--frames: observations need at least 2 frames, got {frames}")
    traj = scene.simulator().run(frames - 1, progress=progress)
    x = traj.x
    rng = np.random.default_rng(seed)
    n = x.shape[1]
    free = np.flatnonzero(scene.model.particle_inv_mass.numpy() > 0)
    fixed = np.setdiff1d(np.arange(n), free)
    k = min(tracks, n)
    pick = rng.permutation(free)[:k]
    if pick.size < k:
        pick = np.concatenate([pick, rng.permutation(fixed)[: k - pick.size]])
    pts = x[:, pick] + rng.normal(scale=noise, size=(frames, k, 3)) if noise > 0 else x[:, pick].copy()
    visible = rng.random((frames, k)) >= dropout
    visible[0] = True
    extra: dict[str, Any] = {}
    if scene.control_points:
        extra["controls"] = _controls(scene, frames)
    if cloud:
        c = x + rng.normal(scale=noise, size=x.shape) if noise > 0 else x.copy()
        extra = {"cloud": c, "cloud_count": np.full(frames, n, dtype=np.int64)}
    return Observations.from_arrays(
        t=np.arange(frames) * scene.frame_dt,
        points=np.where(visible[..., None], pts, np.nan),
        visible=visible,
        particle=pick.astype(np.int64),
        source="<observe>",
        **extra,
    )


def _controls(scene: Scene, frames: int) -> np.ndarray:
    """[frames, C, 3] positions [m] of the spring handles' control points at each frame time."""
    control = scene.model.control()
    move = scene.control_fn
    if move is None:  # spring handles always come with one (scene._build._make_control_fn)
        raise ValueError("the scene has control points but no control_fn to move them")
    out = []
    for f in range(frames):
        # control_fn(t, control) places the points at the end of the frame that starts at t; (0, None): start.
        move((f - 1) * scene.frame_dt if f else 0.0, control if f else None)
        out.append(np.concatenate([cp.points.numpy() for cp in scene.control_points]))
    move(0.0, None)
    return np.stack(out).astype(float)


__all__ = ["observe"]
