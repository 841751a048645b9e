###########################################################################
# Example Fit Rope
#
# Real-to-sim in miniature (PhysTwin's recipe): observe a swinging rope (synthetic tracks of 10 particles
# with 1 mm noise and 30 % of them hidden at each frame), start from a scene whose stiffness and damping
# rate are wrong by 1.6x and 0.5x, and recover both with CMA-ES, then refine the stiffness of every
# spring with tape gradients over one-frame horizons (Adam). Trained on the first 70 % of the frames; the
# rest is held out. test_final() checks the recovered values (within 5 %) and that the held-out error
# dropped below 2 mm.
#
# Command: python examples/fit_rope.py --frames 45 --output fit_rope.mp4
###########################################################################
from __future__ import annotations

import argparse
import time

import numpy as np

import pliant as pl
import pliant.fit
import pliant.scene

TRUTH = {"stiffness": 300.0, "damping_rate": 0.5}


class Example:
    def __init__(self, args: argparse.Namespace) -> None:
        cfg = pl.scene.load_scene("fit_rope")
        cfg.scene.frames = args.frames
        cfg.scene.dtype = "float64"
        truth = pl.scene.build_scene(cfg, device=args.device)
        self.obs = pl.fit.observe(truth, tracks=10, noise=0.001, dropout=0.3, seed=1)
        # The scene to fit: the same rope with the wrong material.
        wrong = pl.fit.apply_globals(cfg, {"stiffness": 480.0, "damping_rate": 0.25})
        self.problem = pl.fit.Problem(
            wrong, self.obs, params=["stiffness", "damping_rate"], per_element="stiffness", device=args.device
        )
        self.generations = 12 if args.test else 25
        self.result = None

    def run(self) -> None:
        p = self.problem
        self.stage1 = pl.fit.cmaes(p, generations=self.generations)
        self.stage2 = pl.fit.gradient_stage(p, self.stage1.values, iterations=2, lr=0.02)
        scene = pl.fit.fitted_scene(p, self.stage1.values, self.stage2.per_element)
        self.x = p.simulate(scene, p.frames)
        self.x_nominal = p.simulate(p.build(p.nominal), p.frames)

    def render(self, path: str) -> None:
        pl.render.render_video(self.x, path, fps=30, progress=False)

    def test_final(self) -> None:
        v = self.stage1.values
        for name, truth in TRUTH.items():
            rel = abs(v[name] - truth) / truth
            print(f"{name}: fitted {v[name]:.4g}, truth {truth:.4g} ({100 * rel:.2f} % off)")
            assert rel < 0.05, f"{name} {v[name]:.4g} is more than 5 % from the truth {truth}"
        e, e0 = self.problem.split_errors(self.x), self.problem.split_errors(self.x_nominal)
        print(f"held-out track error: fitted {1e3 * e['test']:.2f} mm, start {1e3 * e0['test']:.2f} mm")
        k = self.stage2.per_element["model.spring_stiffness"]
        print(f"per-spring stiffness after the gradient stage: median {np.median(k):.4g} N/m")
        assert e["test"] < 2e-3 and e["test"] < 0.5 * e0["test"]


def create_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--device", default="cpu", help="cpu or cuda:N (default: cpu)")
    p.add_argument("--frames", "--num-frames", dest="frames", type=int, default=45)
    p.add_argument("--output", default=None, help="write a video of the fitted rope (.mp4 or .gif)")
    p.add_argument("--test", action="store_true", help="run the checks of test_final()")
    return p


if __name__ == "__main__":
    args = create_parser().parse_args()
    example = Example(args)
    t0 = time.perf_counter()
    example.run()
    print(f"fitted in {time.perf_counter() - t0:.2f} s")
    if args.output:
        example.render(args.output)
        print(f"wrote {args.output}")
    if args.test:
        example.test_final()
