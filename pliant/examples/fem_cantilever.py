###########################################################################
# Example FEM Cantilever
#
# A cantilever beam of tetrahedral FEM: a 0.6 m x 0.1 m x 0.1 m neo-Hookean beam (12 x 2 x 2 cells,
# 6 tets each, E = 1 MPa, nu = 0.3) clamped at its left end is released under gravity and sags,
# advanced by backward Euler (the incremental potential minimised by L-BFGS with a lagged Hessian).
# Euler-Bernoulli gives the static tip deflection q L^4 / (8 E I) = 0.19 m; linear tets with few
# elements through the thickness are stiffer in bending (locking), so the beam sags less.
# test_final() checks that the clamped particles never move, the tip sags by more than 1 cm but less
# than twice the Euler-Bernoulli value (a suddenly applied load overshoots at most 2x), no tet
# inverts, and the volume changes by less than 2 %.
#
# Command: python -m pliant.examples fem_cantilever --frames 60 --output beam.mp4
###########################################################################
from __future__ import annotations

import argparse

import numpy as np

import pliant as pl
import pliant.geometry
import pliant.render
from pliant.examples import _common


class Example:
    def __init__(self, args: argparse.Namespace) -> None:
        self.L, self.h, self.E, self.rho = 0.6, 0.1, 1.0e6, 1000.0
        mesh = pl.geometry.box_tets(12, 2, 2, size=(self.L, self.h, self.h), origin=(-0.3, 0.55, -0.05))
        self.tets = mesh.tets
        b = pl.ModelBuilder()
        b.add_tet_mesh(mesh.points, mesh.tets, density=self.rho, E=self.E, nu=0.3, name="beam")
        self.clamped = np.flatnonzero(np.isclose(mesh.points[:, 0], -0.3))
        self.tip = np.flatnonzero(np.isclose(mesh.points[:, 0], 0.3))
        b.pin(self.clamped)
        self.model = b.finalize(device=args.device, dtype="float64")
        self.solver = pl.solvers.ForceSolver(
            self.model,
            [pl.energies.NeoHookean(), pl.energies.Gravity()],
            pl.integrators.BackwardEuler(),
            damping_rate=1.0,
            minimizer={"method": "lbfgs"},
        )
        self.sim = pl.Simulator(self.model, self.solver, frame_dt=1 / 30, substeps=1)
        self.frames = args.frames

    def run(self, progress: bool) -> None:
        self.traj = self.sim.run(self.frames, progress=progress)

    def render(self, path: str) -> None:
        pl.render.video(self.traj, path, fps=30, progress=False)

    def test_final(self) -> None:
        x = self.traj.x
        assert np.all(np.isfinite(x)), "non-finite positions"
        np.testing.assert_array_equal(
            x[:, self.clamped], np.broadcast_to(x[0, self.clamped], x[:, self.clamped].shape)
        )
        q = self.rho * 9.81 * self.h**2  # weight per length [N/m]
        eb = q * self.L**4 / (8.0 * self.E * self.h**4 / 12.0)  # Euler-Bernoulli static tip deflection [m]
        sag = x[0, self.tip, 1].mean() - x[:, self.tip, 1].mean(axis=1)
        if self.traj.t[-1] >= 0.3:
            assert sag.max() > 0.01, f"the tip sagged only {sag.max():.4f} m"
        assert sag.max() < 2.0 * eb, (
            f"the tip sagged {sag.max():.3f} m, beyond 2x Euler-Bernoulli ({eb:.3f} m)"
        )
        vol = pl.geometry.signed_tet_volumes(x[-1], self.tets)
        assert vol.min() > 0, "a tet inverted"
        v0 = pl.geometry.signed_tet_volumes(x[0], self.tets).sum()
        assert abs(vol.sum() / v0 - 1.0) < 0.02, f"volume changed by {100 * (vol.sum() / v0 - 1):.2f} %"
        print(f"beam: tip sag {sag[-1]:.4f} m (max {sag.max():.4f} m; Euler-Bernoulli static {eb:.3f} m)")


def create_parser() -> argparse.ArgumentParser:
    return _common.create_parser(__doc__, frames=60)


if __name__ == "__main__":
    _common.main(Example, create_parser().parse_args())
