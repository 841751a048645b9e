###########################################################################
# Example Gradients
#
# A hanging rope (8 springs, float64) swings for a few frames; the loss is the squared distance of its
# free end to a target point. pl.diff.rollout returns the loss and its gradient with respect to every
# spring's stiffness and the initial velocities, recomputing one frame at a time in the backward pass
# (checkpointing). Then a few steps of gradient descent on the stiffness bring the end toward the target.
# test_final() checks the gradient against central finite differences along a random direction
# (relative error < 1e-5) and that the descent lowered the loss.
#
# Command: python examples/gradients.py --frames 20
###########################################################################
from __future__ import annotations

import argparse
import time

import numpy as np
import warp as wp

import pliant as pl


@wp.kernel
def end_distance(x: wp.array(dtype=wp.vec3d), index: int, target: wp.vec3d, out: wp.array(dtype=wp.float64)):
    d = x[index] - target
    out[0] = wp.dot(d, d)


class Example:
    def __init__(self, args: argparse.Namespace) -> None:
        b = pl.ModelBuilder()
        b.add_rope(n_segments=8, length=0.8, mass=0.2, stiffness=100.0, damping=0.1, start=(0.0, 1.0, 0.0))
        # Gradients need float64 for a finite-difference check and requires_grad for the tape.
        self.model = b.finalize(device=args.device, dtype="float64", requires_grad=True)
        self.solver = pl.solvers.ForceSolver(self.model, integrator=pl.integrators.SymplecticEuler())
        self.frames, self.substeps, self.dt = max(args.frames, 1), 5, 2e-3
        self.end = self.model.particle_count - 1
        self.target = wp.vec3d(0.7, 0.8, 0.0)
        self.history: list[float] = []

    def loss(self, state: pl.State) -> wp.array:
        out = wp.zeros(1, dtype=wp.float64, device=self.model.device, requires_grad=True)
        wp.launch(end_distance, 1, [state.particle_q, self.end, self.target, out], device=self.model.device)
        return out

    def gradient(self) -> pl.diff.RolloutResult:
        return pl.diff.rollout(
            self.model,
            self.solver,
            self.loss,
            frames=self.frames,
            substeps=self.substeps,
            dt=self.dt,
            params=["spring_stiffness", "v0"],
        )

    def run(self, progress: bool) -> None:
        k = self.model.spring_stiffness
        for it in range(5):
            res = self.gradient()
            self.history.append(res.loss)
            g = res.grads["spring_stiffness"]
            # A step of at most 10 % per spring, down the gradient.
            step = 0.1 * k.numpy() * g / max(np.abs(g).max(), 1e-30)
            k.assign(k.numpy() - step)
            if progress:
                print(f"iteration {it}: loss {res.loss:.6g}")
        self.history.append(self.gradient().loss)

    def test_final(self) -> None:
        k = self.model.spring_stiffness
        res = self.gradient()
        k0 = k.numpy().copy()
        d = np.random.default_rng(0).normal(size=k0.shape)
        eps = 1e-6 * np.abs(k0).mean()
        k.assign(k0 + eps * d)
        plus = self.gradient().loss
        k.assign(k0 - eps * d)
        minus = self.gradient().loss
        k.assign(k0)
        fd = (plus - minus) / (2 * eps)
        ad = float(res.grads["spring_stiffness"] @ d)
        rel = abs(ad - fd) / abs(fd)
        assert rel < 1e-5, f"tape gradient {ad:.6g} vs finite differences {fd:.6g}: relative error {rel:.2e}"
        assert self.history[-1] < self.history[0], f"descent did not lower the loss: {self.history}"
        print(f"gradient matches finite differences: relative error {rel:.2e}")
        print(f"loss {self.history[0]:.4g} -> {self.history[-1]:.4g} after {len(self.history) - 1} steps")


def create_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--device", default=None, help="cpu or cuda:N (default: CUDA when present)")
    p.add_argument("--frames", "--num-frames", dest="frames", type=int, default=20)
    p.add_argument("--test", action="store_true", help="run the gradient checks of test_final()")
    return p


if __name__ == "__main__":
    args = create_parser().parse_args()
    example = Example(args)
    t0 = time.perf_counter()
    example.run(progress=not args.test)
    print(f"5 gradient steps over {example.frames} frames in {time.perf_counter() - t0:.2f} s")
    if args.test:
        example.test_final()
