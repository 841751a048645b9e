###########################################################################
# Example Cloth Drop
#
# A 24 x 24 mass-spring cloth (structural, shear and bend springs, dashpots) falls flat from
# 0.3 m onto the ground and settles; ground contact with Coulomb friction, symplectic Euler.
# test_final() checks that the cloth reached the ground without passing through it, that
# its springs stay close to rest length, and that it has (nearly) stopped bouncing.
#
# Command: python -m pliant.examples cloth_drop --frames 60 --output cloth_drop.mp4
###########################################################################
from __future__ import annotations

import argparse

import numpy as np

import pliant as pl
import pliant.render
from pliant.examples import _common


class Example:
    def __init__(self, args: argparse.Namespace) -> None:
        self.height, self.radius = 0.3, 0.005
        b = pl.ModelBuilder()
        b.add_cloth_grid(
            nx=24,
            ny=24,
            size=1.0,
            mass=0.2,  # [kg]
            stiffness=300.0,  # structural and shear springs [N/m]
            bend_stiffness=6.0,  # springs across two cells [N/m]
            damping=0.005,  # dashpots [N s/m]
            origin=(-0.5, self.height, -0.5),  # near the origin: float32 keeps its precision
            plane="xz",
            radius=self.radius,
        )
        b.add_ground(0.0, friction=0.6)
        self.model = b.finalize(device=args.device)
        solver = pl.solvers.ForceSolver(
            self.model, pl.energies.mass_spring(), pl.integrators.SymplecticEuler(), damping_rate=1.0
        )
        self.sim = pl.Simulator(self.model, solver, frame_dt=1 / 30, substeps=60)
        self.frames = args.frames
        self.rest = self.model.spring_rest_length.numpy()
        self.springs = self.model.spring_indices.numpy()

    def run(self, progress: bool) -> None:
        self.traj = self.sim.run(self.frames, progress=progress)

    def render(self, path: str) -> None:
        pl.render.video(self.traj, path, fps=30, progress=False, ground=0.0)

    def test_final(self) -> None:
        x = self.traj.x
        assert np.all(np.isfinite(x)), "non-finite positions"
        # Free fall from 0.3 m takes √(2h/g) = 0.25 s; by then the cloth must be on the ground.
        t_land = np.sqrt(2 * self.height / 9.81)
        y_min = x[-1, :, 1].min()
        if self.traj.t[-1] > t_land + 0.1:
            assert y_min < self.radius + 1e-3, f"cloth did not reach the ground: min y {y_min:.4f} m"
        # Contact keeps every particle at least its radius above the ground (float32 rounding aside).
        assert x[:, :, 1].min() > self.radius - 1e-5, f"cloth passed the ground: {x[:, :, 1].min():.5f} m"
        # The springs stay near rest length: no over-stretch from the impact.
        length = np.linalg.norm(x[-1, self.springs[:, 0]] - x[-1, self.springs[:, 1]], axis=1)
        strain = np.max(np.abs(length / self.rest - 1))
        assert strain < 0.1, f"max spring strain {strain:.3f} (expected < 0.1)"
        speed = np.max(np.linalg.norm(x[-1] - x[-2], axis=1)) / self.sim.frame_dt
        if self.traj.t[-1] > 1.0:
            assert speed < 0.5, f"cloth still moving at {speed:.3f} m/s after {self.traj.t[-1]:.2f} s"
        print(f"cloth: min y {y_min:.4f} m, max strain {strain:.3f}, max speed {speed:.3f} m/s")


def create_parser() -> argparse.ArgumentParser:
    return _common.create_parser(__doc__, frames=60)


if __name__ == "__main__":
    _common.main(Example, create_parser().parse_args())
