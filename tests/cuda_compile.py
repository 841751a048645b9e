"""Compile pliant's kernels for CUDA without a GPU: Warp's NVRTC generates PTX for a given architecture
ahead of time (``wp.compile_aot_module``), so the CUDA side of every kernel — forward and adjoint, the
``__CUDA_ARCH__`` branches of atomics and intrinsics — is compiled even on a CPU-only machine.

Generic kernels compile only for registered overloads. This script registers those of every built-in
scene (the prebuild manifests) and runs small CPU workloads for the paths no scene takes (FastMassSpring's
steps and gather variants, XPBD's Jacobi and colouring schedules and tolerance loop, every FEM law explicit
and under Newton, the Gaussian rasteriser; the taped rollouts, fit losses and visual corrector of
tests/test_devices_grad.py), then compiles every pliant module with at least one compilable kernel. It prints
one JSON line: modules compiled, kernels skipped for lack of an overload, and the errors (module → message).
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
        gathers = ({"kernel": "gather", "gather": g} for g in ("loop", "unrolled", "ell", "tiled", "tiled16"))
        for kw in ({"kernel": "scatter"}, *gathers, {"method": "implicit"}):
            s0, s1 = m.state(), m.state()
            FastMassSpring(m, **kw).step(s0, s1, None, 1e-4)
        FastMassSpring(m, fused_frame=True).step_frame(s0, s1, None, 1e-4, 2)  # the C++ frame (CPU only)
        s0, s1 = m.state(), m.state()
        XPBD(m, schedule="jacobi").step(s0, s1, None, 1e-4)
        # the Gauss–Seidel sweep, which CUDA launches per colour
        XPBD(m, schedule="coloring").step(s0, s1, None, 1e-4)
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
    for dtype in ("float32", "float64"):  # the device Newton's kernels (linear_solver "pcg" and "band")
        for linear in ("pcg", "band"):
            box = soft_box_model(1, dtype=dtype)
            s0, s1 = box.state(), box.state()
            pcg = ForceSolver(
                box,
                [energies.NeoHookean(), energies.Gravity()],
                integrators.BackwardEuler(),
                minimizer={"linear_solver": linear},
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


def _gradient_workloads() -> None:
    """The adjoint paths: a taped rollout per solver family (each family's custom adjoint modules), the fit's
    losses under a tape, the Gaussian binding's backward pass and the visual corrector."""
    from pliant import ModelBuilder, diff, energies, integrators
    from pliant.fit._losses import acceleration_loss, chamfer_loss, track_loss
    from pliant.gaussians import Camera, Gaussians, VisualCorrector, bind, render
    from pliant.solvers import XPBD, FastMassSpring, ForceSolver

    for dtype in ("float32", "float64"):
        cloth = ModelBuilder()
        cloth.add_cloth_grid(nx=3, ny=3, size=0.3, mass=0.05, stiffness=40.0, pin="top-corners")
        m = cloth.finalize(device="cpu", dtype=dtype, requires_grad=True)
        v3, s = m.vec3, m.scalar

        def loss(state, m=m, s=s):
            out = wp.zeros(1, dtype=s, requires_grad=True)
            x = state.particle_q
            idx = wp.array(np.arange(m.particle_count, dtype=np.int32))
            track_loss(x, idx, wp.zeros_like(x), wp.ones(m.particle_count, dtype=wp.int32), out)
            chamfer_loss(x, wp.zeros(4, dtype=v3), wp.array([4], dtype=wp.int32), out)
            acceleration_loss(x, x, x, x, out)
            return out

        for solver in (
            ForceSolver(m, energies.mass_spring(), integrators.SymplecticEuler()),
            ForceSolver(m, energies.mass_spring(), integrators.BackwardEuler()),
            FastMassSpring(m, method="symplectic"),
            FastMassSpring(m, method="implicit"),  # its adjoint linear solve (fast_mass_spring._adjoint)
            XPBD(m, iterations=2, schedule="jacobi"),
        ):
            diff.rollout(m, solver, loss, frames=1, substeps=1, dt=1e-4, params=["v0"])
    rng = np.random.default_rng(1)
    x = rng.uniform(-0.3, 0.3, (8, 3))
    g = Gaussians.from_values(x, scales=0.1, opacities=0.8, colors=rng.uniform(0, 1, (8, 3)))
    b = bind(g, x, method="lbs", k=4, neighbours=4)
    q = wp.array(x, dtype=wp.vec3, requires_grad=True)
    cam = Camera.look_at([0.0, 0.5, 3.0], [0.0, 0.0, 0.0], width=16, height=16)
    with wp.Tape() as tape:
        c = render(b.deform(q), cam).colour
    tape.backward(grads={c: wp.ones(c.shape, dtype=wp.vec3)})
    image = [c.numpy()]
    VisualCorrector(b, [cam], iterations=2).estimate(q, image)
    VisualCorrector(b, [cam], method="forces", iterations=2).forces(q, image)


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
    _gradient_workloads()
    compiled, errors, skipped = [], {}, 0
    for name, module in sorted(context.user_modules.items()):
        # module="unique" kernels built by a factory (the "ell" gather) get a module of their own, named
        # after the factory: pliant's by their function's module.
        homes = (getattr(k.func, "__module__", None) or "" for k in module.kernels.values())
        own = any(home.startswith("pliant.") for home in homes)
        if not (name.startswith("pliant.") or own):
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
