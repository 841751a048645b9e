"""Compile pliant's kernels for CUDA without a GPU: Warp's NVRTC generates PTX for a given architecture
ahead of time (``wp.compile_aot_module``), so the CUDA side of every kernel — forward and adjoint, the
``__CUDA_ARCH__`` branches of atomics and intrinsics — is compiled even on a CPU-only machine.

Generic kernels compile only for registered overloads. This script registers those of every built-in
scene (the prebuild manifests) and runs small CPU workloads for the paths no scene takes (FastMassSpring's
three steps, XPBD's Jacobi schedule and tolerance loop, every FEM law explicit and under Newton, the
Gaussian rasteriser), then compiles every pliant module with at least one compilable kernel. It prints one
JSON line: modules compiled, kernels skipped for lack of an overload, and the errors (module → message).
Run by tests/test_cuda_compile.py in a fresh process.

    python tests/cuda_compile.py [--arch 90] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import warnings

import numpy as np
import warp as wp

NO_KERNELS = "No compilable kernels found"


def _workloads() -> None:
    """Small CPU runs whose launches register the overloads no built-in scene needs."""
    from pliant.bench._mass_spring import cloth_drape_model
    from pliant.gaussians import Camera, Gaussians, render
    from pliant.solvers import XPBD, FastMassSpring

    for dtype in ("float32", "float64"):
        m = cloth_drape_model(4, dtype=dtype)
        for kw in ({"kernel": "scatter"}, {"kernel": "gather"}, {"method": "implicit"}):
            s0, s1 = m.state(), m.state()
            FastMassSpring(m, **kw).step(s0, s1, None, 1e-4)
        s0, s1 = m.state(), m.state()
        XPBD(m, schedule="jacobi").step(s0, s1, None, 1e-4)
        # the device-side tolerance loop's kernels (only a solver with a tolerance launches them)
        XPBD(m, iterations=3, tolerance=1e-12, check_every=1).step(s0, s1, None, 1e-4)
    from pliant import energies, integrators
    from pliant.bench._fem import soft_box_model
    from pliant.scene._solvers import FEM_LAWS
    from pliant.solvers import ForceSolver

    box = soft_box_model(1, dtype="float64")
    for law in FEM_LAWS.values():  # each law's energy, gradient and Hessian modules
        for integ in (integrators.SymplecticEuler(), integrators.BackwardEuler()):
            s0, s1 = box.state(), box.state()
            ForceSolver(box, [getattr(energies, law)(), energies.Gravity()], integ).step(s0, s1, None, 1e-4)
    for dtype in ("float32", "float64"):  # the device Newton's kernels (linear_solver="pcg")
        box = soft_box_model(1, dtype=dtype)
        s0, s1 = box.state(), box.state()
        pcg = ForceSolver(
            box,
            [energies.NeoHookean(), energies.Gravity()],
            integrators.BackwardEuler(),
            minimizer={"linear_solver": "pcg"},
        )
        pcg.step(s0, s1, None, 1e-3)
    rng = np.random.default_rng(0)
    g = Gaussians.from_values(rng.uniform(-0.5, 0.5, (8, 3)), scales=np.full((8, 3), 0.1), sh_degree=1)
    cam = Camera.look_at([0.0, 0.0, 3.0], [0.0, 0.0, 0.0], width=16, height=16)
    render(g, cam)
    # the backward pass with a differentiable background and a light (the appearance stage's kernels)
    gg = Gaussians(**g.numpy(), requires_grad=True)
    bg = wp.zeros(1, dtype=wp.vec3, requires_grad=True)
    light = wp.array([[1.0, 0.1, 0.2, 0.3], [0.1, 0.0, 0.0, 0.0]], dtype=wp.vec4, requires_grad=True)
    with wp.Tape() as tape:
        c, _, _ = render(gg, cam, bg, light=light)
    tape.backward(grads={c: wp.ones(c.shape, dtype=wp.vec3)})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arch", type=int, default=90, help="CUDA architecture (90: H100/H200)")
    ap.add_argument("--out", default=None, help="where the PTX goes (default: a temporary folder)")
    args = ap.parse_args()
    wp.config.quiet = True
    wp.init()
    from warp._src import context

    from pliant import _prebuild

    out = args.out or tempfile.mkdtemp(prefix="pliant-ptx-")
    try:  # a Warp build without NVRTC (CPU-only wheels) cannot compile for CUDA at all
        wp.compile_aot_module(_prebuild, arch=args.arch, module_dir=out, use_ptx=True)
    except Exception as exc:  # noqa: BLE001
        print(json.dumps({"unavailable": str(exc)[-500:]}))
        return
    for manifest in json.loads(_prebuild.MANIFEST.read_text()).values():
        _prebuild.register_overloads(manifest)
    _workloads()
    compiled, errors, skipped = [], {}, 0
    for name, module in sorted(context.user_modules.items()):
        if not name.startswith("pliant."):
            continue
        skipped += sum(1 for k in module.kernels.values() if k.is_generic and not k.overloads)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # "generic kernels without overloads will be skipped"
                wp.compile_aot_module(module, arch=args.arch, module_dir=out, use_ptx=True)
            compiled.append(name)
        except Exception as exc:  # noqa: BLE001 - every failure is reported, by module
            if NO_KERNELS not in str(exc):
                errors[name] = str(exc)[-2000:]
    print(json.dumps({"arch": args.arch, "compiled": compiled, "skipped_kernels": skipped, "errors": errors}))


if __name__ == "__main__":
    main()
