###########################################################################
# Example Rope Swing
#
# A rope of 30 springs, pinned at one end and released horizontally, swings down like a
# chain pendulum: Hooke springs + dashpots along each spring + gravity, symplectic Euler.
# test_final() checks the physics: the pinned end stays put, the rope keeps its length
# (springs stiff enough), the free end has fallen, and the total energy
# (kinetic + gravity + springs) has not grown, since dashpots only remove energy.
#
# Command: python -m pliant.examples rope_swing --frames 120 --output rope.mp4
###########################################################################
from __future__ import annotations

import argparse

import numpy as np

import pliant as pl
import pliant.render
from pliant.examples import _common


class Example:
    def __init__(self, args: argparse.Namespace) -> None:
        self.n, self.length, self.y0 = 30, 0.8, 1.0
        b = pl.ModelBuilder()
        b.add_rope(
            n_segments=self.n,
            length=self.length,
            mass=0.1,
            stiffness=2000.0,  # [N/m]
            damping=0.002,  # dashpots [N s/m]
            start=(-0.4, self.y0, 0.0),
            direction=(1.0, 0.0, 0.0),
            pin="first",
        )
        b.add_ground()
        self.model = b.finalize(device=args.device)
        self.solver = pl.solvers.ForceSolver(
            self.model, pl.energies.mass_spring(), pl.integrators.SymplecticEuler()
        )
        # Substep 1/1200 s: well inside the explicit limit 2/ω_max for these springs.
        self.sim = pl.Simulator(self.model, self.solver, frame_dt=1 / 30, substeps=40)
        self.frames = args.frames
        self.energy0 = self.total_energy()

    def total_energy(self) -> float:
        return float(sum(self.solver.energy(self.sim.state_0).values()))

    def run(self, progress: bool) -> None:
        self.traj = self.sim.run(self.frames, progress=progress)

    def render(self, path: str) -> None:
        pl.render.video(self.traj, path, fps=30, progress=False)

    def test_final(self) -> None:
        x = self.traj.x
        assert np.all(np.isfinite(x)), "non-finite positions"
        # The pinned end never moves.
        np.testing.assert_array_equal(x[:, 0], np.broadcast_to(x[0, 0], x[:, 0].shape))
        # Stiff springs: the rope's length stays within 3 % of its rest length.
        length = np.sum(np.linalg.norm(np.diff(x[-1], axis=0), axis=1))
        assert abs(length / self.length - 1) < 0.03, f"rope length {length:.4f} m, rest {self.length} m"
        # After t = frames/30 s the free end has fallen (it starts level with the pin).
        t = self.traj.t[-1]
        drop = self.y0 - x[-1, -1, 1]
        if t > 0.3:
            assert drop > 0.2, f"free end fell only {drop:.3f} m in {t:.2f} s"
        energy = self.total_energy()
        assert energy <= self.energy0 + 0.01 * abs(self.energy0), (
            f"energy grew from {self.energy0:.4f} J to {energy:.4f} J"
        )
        print(
            f"rope: length {length:.4f} m, free end fell {drop:.3f} m, "
            f"energy {self.energy0:.4f} -> {energy:.4f} J"
        )


def create_parser() -> argparse.ArgumentParser:
    return _common.create_parser(__doc__, frames=120)


if __name__ == "__main__":
    _common.main(Example, create_parser().parse_args())
