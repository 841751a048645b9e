###########################################################################
# Example Cloth Turntable
#
# A cloth dropped on a box spinning about the vertical (a kinematic collider with an angular
# velocity, examples/cloth_turntable.toml) is carried round by friction. test_final() checks
# that no particle enters the turning box, that the cloth turns with it, and that the box is
# drawn where it has turned to at each frame (Scene.render_mesh, pl.render.collider_points).
#
# Command: python examples/cloth_turntable.py --frames 60 --output cloth_turntable.mp4
###########################################################################
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import pliant as pl
import pliant.render
from pliant.examples import _common

SCENE = Path(__file__).with_suffix(".toml")


def _turn(p: np.ndarray, angle: np.ndarray | float) -> np.ndarray:
    """Points ``p`` [..., 3] rotated by ``angle`` [rad] about +y (R_y: x toward -z), broadcast over frames."""
    cos, sin = np.cos(angle), np.sin(angle)
    return np.stack(
        [cos * p[..., 0] + sin * p[..., 2], p[..., 1], cos * p[..., 2] - sin * p[..., 0]], axis=-1
    )


class Example:
    def __init__(self, args: argparse.Namespace) -> None:
        self.scene = pl.scene.build_scene(pl.scene.load_scene(SCENE), device=args.device)
        self.box = self.scene.config.colliders[0]
        self.sim = self.scene.simulator()
        self.frames = args.frames

    def run(self, progress: bool) -> None:
        self.traj = self.sim.run(self.frames, progress=progress)

    def render(self, path: str) -> None:
        x, faces, colors = self.scene.render_mesh(self.traj.x, self.traj.faces, self.traj.t)
        pl.render.render_video(
            x, path, faces=faces, colors=colors, fps=self.scene.fps, camera=self.scene.camera, ground=0.0
        )

    def test_final(self) -> None:
        x, t = self.traj.x.astype(np.float64), self.traj.t
        assert np.all(np.isfinite(x)), "non-finite positions"
        c, he = np.asarray(self.box.center), np.asarray(self.box.half_extents)
        w = float(self.box.angular_velocity[1])  # [rad/s] about +y
        # Each frame in the box's own frame: turned back by -w t about its centre.
        local = _turn(x - c, -w * t[:, None])
        depth = np.min(he - np.abs(local), axis=-1)  # > 0: inside the box, by that much
        assert depth.max() < 2e-3, f"a particle went {depth.max():.4f} m into the turning box"
        # Friction (mu g = 7.8 m/s^2 > w^2 r = 1.7 m/s^2 at the cloth's corners) makes the cloth stick and
        # turn with the box: its angular velocity about the axis, L_y / I_y, within 15 % of w.
        if t[-1] > 0.5:
            r = x[-1] - c
            v = (x[-1] - x[-2]) / self.sim.frame_dt
            spin = np.sum(r[:, 2] * v[:, 0] - r[:, 0] * v[:, 2]) / np.sum(r[:, 0] ** 2 + r[:, 2] ** 2)
            assert abs(spin / w - 1) < 0.15, f"the cloth turns at {spin:.3f} rad/s, the box at {w} rad/s"
        # The video and the viewer draw the box where it has turned to: its corners at the last frame are
        # those it was added with, rotated by w t about the centre.
        drawn, _, _ = self.scene.render_mesh(self.traj.x, self.traj.faces, t)
        corners = drawn[-1, -8:].astype(np.float64) - c
        start = self.scene.static_meshes[0][0] - c
        turned = _turn(start, w * t[-1])
        assert np.abs(corners - turned).max() < 1e-5, "the box is not drawn where it has turned to"
        print(f"deepest {depth.max() * 1e3:.2f} mm into the box; box at {np.degrees(w * t[-1]):.0f} deg")


def create_parser() -> argparse.ArgumentParser:
    return _common.create_parser(__doc__, frames=30)


if __name__ == "__main__":
    _common.main(Example, create_parser().parse_args())
