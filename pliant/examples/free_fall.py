###########################################################################
# Example Free Fall
#
# Particles thrown with different initial velocities fall under gravity alone, advanced by
# symplectic Euler in float64. The discrete solution is known exactly:
#     v_n = v_0 + n Δt g,   x_n = x_0 + v_0 t_n + ½ g t_n² + ½ g Δt t_n,
# the last term being symplectic Euler's O(Δt) drift (it uses the updated velocity).
# test_final() checks every recorded frame against it to 1e-9 relative.
#
# Command: python -m pliant.examples free_fall --frames 60 --output free_fall.mp4
###########################################################################
from __future__ import annotations

import argparse

import numpy as np

import pliant as pl
import pliant.render
from pliant.examples import _common


class Example:
    def __init__(self, args: argparse.Namespace) -> None:
        self.g = np.array([0.0, -9.81, 0.0])
        # A fan of throws from near the origin (positions stay small: float precision, DESIGN.md).
        angles = np.linspace(0.3, 1.3, 5)
        self.x0 = np.stack([0.1 * np.arange(5) - 0.2, np.full(5, 0.5), np.zeros(5)], axis=1)
        self.v0 = np.stack([np.cos(angles), 3.0 * np.sin(angles), 0.2 * np.ones(5)], axis=1)
        b = pl.ModelBuilder(gravity=self.g)
        b.add_particles(self.x0, 0.1, velocities=self.v0, radius=0.02)
        self.model = b.finalize(device=args.device, dtype="float64")
        # Gravity only: no springs, no ground.
        solver = pl.solvers.ForceSolver(self.model, [pl.energies.Gravity()], pl.integrators.SymplecticEuler())
        self.substeps = 4
        self.sim = pl.Simulator(self.model, solver, frame_dt=1 / 60, substeps=self.substeps)
        self.frames = args.frames

    def run(self, progress: bool) -> None:
        self.traj = self.sim.run(self.frames, progress=progress)

    def render(self, path: str) -> None:
        pl.render.render_video(self.traj.x, path, fps=60, progress=False, ground=False)

    def test_final(self) -> None:
        h = self.sim.substep_dt  # the integrator's step Δt
        t = self.traj.t[:, None, None]
        exact = self.x0 + self.v0 * t + 0.5 * self.g * t**2 + 0.5 * self.g * h * t
        rel = np.max(np.abs(self.traj.x - exact) / np.maximum(np.abs(exact), 1.0))
        assert self.traj.frame_count == self.frames + 1
        assert rel < 1e-9, f"free fall deviates from the discrete closed form: {rel:.3g} (expected < 1e-9)"
        print(f"free fall matches the closed form: max relative error {rel:.2e}")


def create_parser() -> argparse.ArgumentParser:
    return _common.create_parser(__doc__, frames=60)


if __name__ == "__main__":
    _common.main(Example, create_parser().parse_args())
