"""pliant's ``soft_box_drop_10_implicit`` scene as a MuJoCo 3D flex (StVK elasticity), one JSON line.

Needs MuJoCo 4.0 in its own venv (see README.md); not imported by pliant or its tests. MuJoCo is z-up:
pliant's (x, y, z) maps to MuJoCo's (z, x, y), a cyclic permutation that keeps the tets positively oriented.

    taskset -c 0 /work/peers-venv/bin/python benchmarks/peers/soft_box_mujoco.py --timestep 0.004
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402
from _scene import (  # noqa: E402
    FRAME_DT,
    FRAMES,
    FRICTION,
    GRAVITY,
    POISSON,
    RADIUS,
    YOUNG,
    box_tets,
    heights,
    lumped_mass,
    peak_mem_mb,
)


def scene_xml(points: np.ndarray, tets: np.ndarray, args: argparse.Namespace) -> str:
    pts = points[:, [2, 0, 1]]  # pliant (x, y, z) -> MuJoCo (z, x, y): y up becomes z up
    point = " ".join(f"{v:.9g}" for v in pts.ravel())
    element = " ".join(str(int(i)) for i in tets.ravel())
    return f"""
<mujoco model="soft_box_drop">
  <option timestep="{args.timestep}" integrator="{args.integrator}" solver="{args.solver}"
          tolerance="{args.tolerance}" iterations="{args.iterations}" gravity="0 0 -{GRAVITY}"
          cone="{args.cone}"/>
  <worldbody>
    <geom name="ground" type="plane" size="10 10 0.1" friction="{FRICTION} 0.005 0.0001"/>
    <flexcomp name="box" type="direct" dim="3" radius="{RADIUS}" mass="1" point="{point}" element="{element}">
      <contact selfcollide="none" friction="{FRICTION} 0.005 0.0001" condim="3"/>
      <edge equality="false"/>
      <elasticity young="{YOUNG}" poisson="{POISSON}" damping="{args.damping}"/>
    </flexcomp>
  </worldbody>
</mujoco>
"""


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10, help="cells per side (6 tets per cell)")
    ap.add_argument("--timestep", type=float, default=FRAME_DT, help="[s]; 1/60 = one step per frame")
    ap.add_argument("--integrator", default="discrete", help="discrete: the only one implicit in position")
    ap.add_argument("--solver", default="Newton", choices=["Newton", "CG", "PGS"])
    ap.add_argument("--tolerance", type=float, default=1e-6)
    ap.add_argument("--iterations", type=int, default=100)
    ap.add_argument("--cone", default="pyramidal", choices=["pyramidal", "elliptic"])
    ap.add_argument("--damping", type=float, default=0.0, help="Rayleigh damping of the flex [s]")
    ap.add_argument(
        "--uniform-mass", action="store_true", help="flexcomp's equal point masses, not ρV/4 lumping"
    )
    ap.add_argument("--frames", type=int, default=FRAMES)
    ap.add_argument(
        "--trajectory", default=None, help="save the com height per step to this .npy (one read per step)"
    )
    args = ap.parse_args(argv)

    import mujoco

    # MuJoCo appends warnings to MUJOCO_LOG.TXT in the working directory; send them to stderr instead.
    mujoco.set_mju_user_warning(lambda msg: print(f"MuJoCo warning: {msg}", file=sys.stderr))
    t0 = time.perf_counter()
    points, tets = box_tets(args.n)
    mass = lumped_mass(points, tets)
    model = mujoco.MjModel.from_xml_string(scene_xml(points, tets, args))
    # flexcomp gives every point the same mass; set pliant's lumped ρV/4 masses on the point bodies instead.
    vbody = model.flex_vertbodyid[model.flex_vertadr[0] : model.flex_vertadr[0] + model.flex_vertnum[0]]
    if args.uniform_mass:
        model.body_mass[vbody] = mass.sum() / len(mass)
    else:
        model.body_mass[vbody] = mass
    data = mujoco.MjData(model)
    mujoco.mj_setConst(model, data)
    mujoco.mj_step(model, data)  # warm-up
    mujoco.mj_resetData(model, data)
    compile_s = time.perf_counter() - t0

    sim_s = args.frames * FRAME_DT
    steps = int(round(sim_s / model.opt.timestep))
    iters = 0
    vert = slice(model.flex_vertadr[0], model.flex_vertadr[0] + model.flex_vertnum[0])
    body_mass = np.asarray(model.body_mass[vbody])
    com = []
    t0 = time.perf_counter()
    per_frame = max(1, round(steps / args.frames))  # steps per 1/60 s frame
    frame_com = []
    for i in range(steps):
        mujoco.mj_step(model, data)
        iters += int(data.solver_niter[0])
        end_of_frame = (i + 1) % per_frame == 0  # the motion check, every frame as pliant's rows do
        if args.trajectory or end_of_frame:
            c = float(body_mass @ np.asarray(data.flexvert_xpos[vert])[:, 2] / body_mass.sum())
            if args.trajectory:
                com.append(c)
            if end_of_frame:
                frame_com.append(c)
    wall = time.perf_counter() - t0
    if args.trajectory:
        np.save(args.trajectory, np.array(com))

    x = data.flexvert_xpos[model.flex_vertadr[0] : model.flex_vertadr[0] + model.flex_vertnum[0]]
    x = np.asarray(x)[:, [1, 2, 0]]  # back to pliant's (x, y, z)
    dof = model.body_dofadr[vbody]
    v = np.stack([data.qvel[dof + k] for k in range(3)], axis=1)
    row = {
        "benchmark": f"mujoco_soft_box_drop_{args.n}_flex",
        "scene": f"soft_box_drop_{args.n}x{args.n}x{args.n}",
        "peer": f"mujoco {mujoco.__version__}",
        "solver": f"{args.integrator}/{args.solver}",
        "material": "StVK (flex elasticity)",
        "device": "cpu",
        "dtype": "float64",
        "particles": int(model.flex_vertnum[0]),
        "elements": int(model.flex_elemnum[0]),
        "nv": int(model.nv),
        "frames": args.frames,
        "substeps": round(FRAME_DT / model.opt.timestep, 3),
        "dt": float(model.opt.timestep),
        "iterations_per_step": round(iters / steps, 3),
        "tolerance": args.tolerance,
        "damping": args.damping,
        "mass": "uniform" if args.uniform_mass else "lumped rho V/4",
        "total_mass": round(float(body_mass.sum()), 3),
        "wall_s": round(wall, 4),
        "wall_per_sim_s": round(wall / sim_s, 4),
        "compile_s": round(compile_s, 3),
        "time_per_step_s": float(f"{wall / steps:.4g}"),
        "time_per_frame_s": float(f"{wall / args.frames:.4g}"),
        "particle_substeps_per_s": float(f"{model.flex_vertnum[0] * steps / wall:.4g}"),
        "peak_mem_mb": peak_mem_mb(),
        **heights(x, v, body_mass),
        "com_curve": frame_com,
    }
    print(json.dumps(row), flush=True)
    return row


if __name__ == "__main__":
    main()
