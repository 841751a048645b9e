###########################################################################
# Example Rope Worlds
#
# Four ropes of different stiffness, pinned at one end, swing down together as four worlds of one
# model (ModelBuilder.replicate): one launch per kernel steps them all. test_final() checks that the
# worlds are independent (world 1 equals a run of that rope alone, bit for bit), that the stiffer rope
# stretches less, and that resetting one world puts it back at its start while the others go on.
#
# Command: python -m pliant.examples rope_worlds --frames 60 --output worlds.mp4
###########################################################################
from __future__ import annotations

import argparse

import numpy as np

import pliant as pl
import pliant.render
from pliant.examples import _common

STIFFNESS = [50.0, 100.0, 200.0, 400.0]  # [N/m], one per world


SPACING = 0.3  # [m] between the worlds along z, so that the video shows them side by side


def _rope(worlds: int | None, device: str | None, z: float = 0.0) -> pl.Model:
    b = pl.ModelBuilder()
    b.add_rope(n_segments=10, length=0.5, mass=0.05, stiffness=100.0, start=(0.0, 1.0, z), pin="first")
    if worlds is not None:
        b.replicate(worlds, spacing=(0.0, 0.0, SPACING))
    return b.finalize(device=device, dtype="float64")


def _solver(model: pl.Model) -> pl.solvers.ForceSolver:
    return pl.solvers.ForceSolver(model, pl.energies.mass_spring(), pl.integrators.SymplecticEuler())


class Example:
    def __init__(self, args: argparse.Namespace) -> None:
        self.device = args.device
        self.model = _rope(len(STIFFNESS), args.device)
        for w, k in enumerate(STIFFNESS):
            self.model.set_world_parameter("spring_stiffness", w, k)
        self.sim = pl.Simulator(self.model, _solver(self.model), frame_dt=1 / 30, substeps=40)
        self.frames = args.frames

    def run(self, progress: bool) -> None:
        self.traj = self.sim.run(self.frames, progress=progress)

    def render(self, path: str) -> None:
        pl.render.video(self.traj, path, fps=30, progress=False)

    def test_final(self) -> None:
        assert self.traj.world_count == len(STIFFNESS)
        # World 1 moves exactly as its rope alone.
        alone = _rope(None, self.device, z=SPACING)  # where world 1 starts
        alone.set_world_parameter("spring_stiffness", 0, STIFFNESS[1])
        sim = pl.Simulator(alone, _solver(alone), frame_dt=1 / 30, substeps=40)
        np.testing.assert_array_equal(self.traj.world(1).x, sim.run(self.frames, progress=False).x)
        # The stiffer the rope, the less it stretches.
        lengths = []
        for w in range(len(STIFFNESS)):
            x = self.traj.world(w).x[-1]
            lengths.append(float(np.sum(np.linalg.norm(np.diff(x, axis=0), axis=1))))
        assert all(a > b for a, b in zip(lengths, lengths[1:], strict=False)), lengths
        # Reset world 2 only.
        before = self.sim.state_0.particle_q.numpy().copy()
        self.model.reset_world(self.sim.state_0, 2)
        after = self.sim.state_0.particle_q.numpy()
        w2, w3 = self.model.world_slice("particle", 2), self.model.world_slice("particle", 3)
        np.testing.assert_array_equal(after[w2], self.model.particle_q.numpy()[w2])
        np.testing.assert_array_equal(after[w3], before[w3])
        print("rope lengths [m] by stiffness:", dict(zip(STIFFNESS, np.round(lengths, 4), strict=True)))


def create_parser() -> argparse.ArgumentParser:
    return _common.create_parser(__doc__, frames=60)


if __name__ == "__main__":
    _common.main(Example, create_parser().parse_args())
