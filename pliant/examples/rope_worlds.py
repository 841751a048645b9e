###########################################################################
# Example Rope Worlds
#
# Four ropes of different stiffness, pinned at one end, swing down together as four worlds of one
# model (ModelBuilder.replicate): one launch per kernel steps them all. test_final() checks that the
# worlds are independent (world 1 equals a run of that rope alone, bit for bit), that the stiffer rope
# stretches less (at rest, by the closed form g/k Σ i m_i), and that resetting one world puts it back
# at its start while the others go on.
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


LENGTH = 0.5  # [m] unstretched
SPACING = 0.3  # [m] between the worlds along z, so that the video shows them side by side


def _rope(worlds: int | None, device: str | None, z: float = 0.0) -> pl.Model:
    b = pl.ModelBuilder()
    b.add_rope(n_segments=10, length=LENGTH, mass=0.05, stiffness=100.0, start=(0.0, 1.0, z), pin="first")
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
        # The stiffer the rope, the less it stretches: compared at rest, where the stretch has a closed form.
        # (While they swing, a softer rope can be shorter than a stiffer one at some instant: their
        # stretch oscillates at different frequencies.)
        lengths = self.rest_lengths()
        assert all(a > b for a, b in zip(lengths, lengths[1:], strict=False)), lengths
        # A rope hanging at rest: the link above particle i carries the weight of the particles below it,
        # so the stretch is g/k Σ_i i m_i (i links above particle i, the pinned one first).
        m = self.model.particle_mass.numpy()[self.model.world_slice("particle", 0)]
        expected = 9.81 * float(np.sum(np.arange(len(m)) * m)) / np.asarray(STIFFNESS)
        np.testing.assert_allclose(np.asarray(lengths) - LENGTH, expected, rtol=1e-3)
        # Reset world 2 only.
        before = self.sim.state_0.particle_q.numpy().copy()
        self.model.reset_world(self.sim.state_0, 2)
        after = self.sim.state_0.particle_q.numpy()
        w2, w3 = self.model.world_slice("particle", 2), self.model.world_slice("particle", 3)
        np.testing.assert_array_equal(after[w2], self.model.particle_q.numpy()[w2])
        np.testing.assert_array_equal(after[w3], before[w3])
        print(
            "rope lengths at rest [m] by stiffness:",
            {k: round(v, 4) for k, v in zip(STIFFNESS, lengths, strict=True)},
        )

    def rest_lengths(self, seconds: float = 2.0) -> list[float]:
        """Each world's rope length [m] after it has come to rest: the same worlds from the same start,
        stepped with a strong velocity damping (v ← v·exp(−10 Δt / s)) for ``seconds``."""
        model = _rope(len(STIFFNESS), self.device)
        for w, k in enumerate(STIFFNESS):
            model.set_world_parameter("spring_stiffness", w, k)
        solver = pl.solvers.ForceSolver(
            model, pl.energies.mass_spring(), pl.integrators.SymplecticEuler(), damping_rate=10.0
        )
        traj = pl.Simulator(model, solver, frame_dt=1 / 30, substeps=40).run(
            round(30 * seconds), progress=False
        )
        out = []
        for w in range(len(STIFFNESS)):
            x = traj.world(w).x
            assert np.abs(x[-1] - x[-2]).max() * 30 < 0.02, "the damped ropes have not come to rest"
            out.append(float(np.sum(np.linalg.norm(np.diff(x[-1], axis=0), axis=1))))
        return out


def create_parser() -> argparse.ArgumentParser:
    return _common.create_parser(__doc__, frames=60)


if __name__ == "__main__":
    _common.main(Example, create_parser().parse_args())
