###########################################################################
# Example XPBD Chain
#
# A chain pendulum of position-based dynamics: eight beads joined by inextensible XPBD distance
# constraints (compliance 0), hung from a pinned bead and released horizontally. It swings and whips
# while every link keeps its length, the constraint projection doing what stiff springs cannot at a
# large step (Macklin et al., XPBD, 2016; the lecture's Algorithm 1).
# test_final() checks that the pinned bead never moves, every link stays within 1 % of its rest
# length, the free end has fallen, and the energy (kinetic + gravity) has not grown: XPBD only removes it.
#
# Command: python -m pliant.examples xpbd_chain --frames 150 --output chain.mp4
###########################################################################
from __future__ import annotations

import argparse

import numpy as np

import pliant as pl
import pliant.render
from pliant.examples import _common


class Example:
    def __init__(self, args: argparse.Namespace) -> None:
        self.n, self.length, self.y0 = 8, 0.6, 1.2
        self.g = 9.81
        b = pl.ModelBuilder()
        b.add_rope(
            n_segments=self.n,
            length=self.length,
            mass=0.08,
            stiffness=1.0e4,  # unused by XPBD here: compliance = 0 below makes the links inextensible
            start=(0.0, self.y0, 0.0),
            direction=(1.0, 0.0, 0.0),
            pin="first",
        )
        self.model = b.finalize(device=args.device, dtype="float64")
        self.solver = pl.solvers.XPBD(self.model, iterations=10, compliance=0.0, schedule="coloring")
        self.sim = pl.Simulator(self.model, self.solver, frame_dt=1 / 30, substeps=20)
        self.frames = args.frames
        self.mass = self.model.particle_mass_np

    def energy(self, x: np.ndarray, v: np.ndarray) -> float:
        """Kinetic + gravitational energy [J] of the free beads."""
        free = self.mass > 0
        m = self.mass[free]
        return float(np.sum(0.5 * m * np.sum(v[free] ** 2, axis=1) + m * self.g * x[free, 1]))

    def run(self, progress: bool) -> None:
        self.traj = self.sim.run(self.frames, progress=progress, record_velocity=True)

    def render(self, path: str) -> None:
        pl.render.video(self.traj, path, fps=30, progress=False)

    def test_final(self) -> None:
        x, v = self.traj.x, self.traj.v
        assert np.all(np.isfinite(x)), "non-finite positions"
        np.testing.assert_array_equal(x[:, 0], np.broadcast_to(x[0, 0], x[:, 0].shape))
        rest = self.length / self.n
        links = np.linalg.norm(np.diff(x, axis=1), axis=2)
        worst = float(np.max(np.abs(links / rest - 1.0)))
        assert worst < 0.01, f"a link stretched by {100 * worst:.2f} % (rest {rest} m)"
        # Within 0.3 s the free end has fallen most of the way a free bead would (0.44 m), the chain swinging
        # down from horizontal.
        drop = float(np.max(self.y0 - x[:, -1, 1]))
        if self.traj.t[-1] >= 0.3:
            assert drop > 0.3, f"the free end fell only {drop:.3f} m"
        e0, e1 = self.energy(x[0], v[0]), self.energy(x[-1], v[-1])
        assert e1 <= e0 + 1e-3 * abs(e0), f"energy grew from {e0:.5f} J to {e1:.5f} J"
        print(
            f"chain: worst link strain {worst:.2e}, free end fell {drop:.3f} m, energy {e0:.4f} -> {e1:.4f} J"
        )


def create_parser() -> argparse.ArgumentParser:
    return _common.create_parser(__doc__, frames=150)


if __name__ == "__main__":
    _common.main(Example, create_parser().parse_args())
