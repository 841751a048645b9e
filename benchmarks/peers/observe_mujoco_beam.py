"""A camera fixture for twins (issue 37): a soft beam clamped at one end and released, simulated AND filmed
by MuJoCo 4.0 (its own physics, its own vertex masses, its own OpenGL renderer), written to
``tests/data/foreign/mujoco_beam_*`` with the truth that ``tests/twin_truth.py`` scores a twin against.

SYNTHETIC DATA from another engine: MuJoCo's StVK flex and renderer stand in for a real beam and real cameras.
Needs MuJoCo in its own venv (README.md); never imported by pliant or its tests. Rendering is headless:
``MUJOCO_GL=egl`` (Mesa's EGL, Debian ``libegl-mesa0``) or ``osmesa`` (``libosmesa6``).

    cd benchmarks/peers
    MUJOCO_GL=egl /work/peers-venv/bin/python observe_mujoco_beam.py

Writes ``mujoco_beam_video.npz`` (4 cameras: ``t``, ``images``, ``masks``, ``depth``, ``K``,
``world_to_camera``), ``mujoco_beam_heldout.npz`` (a 5th camera, the same arrays, never for fitting),
``mujoco_beam_truth.npz`` (``x`` [T, V, 3], ``tets``, ``pinned``, ``mass``, ``t``) and the sidecar
``mujoco_beam_video.json``. Axes as observe_mujoco.py: files in pliant's (y up); MuJoCo runs z up and a point
(x, y, z) of pliant is (z, x, y) in MuJoCo.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402
from _foreign import FIXTURES, FPS, box_tets, floats, intrinsics, look_at  # noqa: E402
from observe_mujoco import (  # noqa: E402
    GRAVITY,
    _flex_vertices,
    _free_vertex_bodies,
    _mujoco,
    _project,
    from_mj,
    to_mj,
)

FRAMES = 90  # frames after frame 0: 3 s at 30 fps
SUBSTEPS = 40  # MuJoCo steps per frame (dt = 1/1200 s; 20 moves the tip by a few mm)
# The beam: 0.4 m along +x from the clamp at x = 0, 0.06 m tall (y) and 0.08 m wide (z), centre line at
# height 0.6 m. Not square on purpose: a square section has equal vertical and sideways bending frequencies,
# and the mesh's asymmetry pumps the vertical swing into a sideways one within a second (1:1 resonance).
# 20 x 3 x 4 cells of 2 cm, Kuhn split (6 tets per cell, pliant's box_tets order); rho = 1000 kg/m3 given to
# flexcomp as the total mass, which it spreads EVENLY over the points (MuJoCo's own masses, kept); the
# 20 points of the x = 0 face pinned. StVK E = 7e5 Pa, nu = 0.3: mean tip sag ~10 cm, first period ~0.53 s.
BEAM = dict(
    cells=(20, 3, 4),
    size=(0.4, 0.06, 0.08),
    height=0.6,
    density=1000.0,
    young=7.0e5,
    poisson=0.3,
    damping=0.001,  # flex Rayleigh damping [s]
    radius=0.0005,  # flex radius [m] (no contacts; MuJoCo needs one)
)
WALL = dict(thickness=0.01, half=(0.09, 0.09), gap=0.002, rgb=(0.35, 0.3, 0.28))  # behind the clamp, x < 0
FLOOR = dict(half=1.5, rgb=(0.55, 0.55, 0.55))
# Cameras: 200 x 150, vertical field of view 40 deg, on the beam's free side (eye x > the beam's centre: the
# wall plate at x < 0 can never come between a camera and the beam), looking at the centre of the motion.
VIDEO = dict(width=200, height=150, fovy=40.0)
CAMERAS = ((15.0, 20.0), (65.0, 40.0), (120.0, 28.0), (170.0, 15.0))  # (azimuth, elevation) [deg]
HELDOUT = (40.0, 62.0)  # the 5th camera: from high above, between the first two
CHECKER = dict(rgb1=(0.1, 0.2, 0.9), rgb2=(0.95, 0.85, 0.1), cell=0.04, background=(0.8, 0.8, 0.8))
DEPTH_RANGE = (0.05, 10.0)  # [m] MuJoCo's near/far planes; beyond 10 m (the sky) the depth reads 0


def beam_mesh() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points [V, 3], tets [E, 4] (pliant's Kuhn split), texture coordinates [V, 2] and pinned indices."""
    b = BEAM
    corner = np.array([0.0, b["height"] - 0.5 * b["size"][1], -0.5 * b["size"][2]])
    pts, tets = box_tets(b["cells"], b["size"], corner)
    rel = pts - corner
    # A checker on every long face: u along the beam, v along (y + z), so the side faces (z fixed) and the
    # top and bottom (y fixed) both get square cells; an eighth of a period offset keeps the end faces off a
    # cell edge (a texture coordinate on an edge samples a blend of both colours).
    period = 2.0 * CHECKER["cell"]  # the builtin checker texture holds 2 x 2 cells
    uv = np.stack([rel[:, 0] / period + 0.125, (rel[:, 1] + rel[:, 2]) / period + 0.125], axis=1)
    pinned = np.flatnonzero(rel[:, 0] < 1e-9)
    return pts, tets, uv, pinned


def _xml(pts, tets, uv, pinned) -> str:
    b, k, w = BEAM, CHECKER, WALL
    mass = b["density"] * float(np.prod(b["size"]))
    wall_centre = np.array([-(w["gap"] + 0.5 * w["thickness"]), b["height"], 0.0])
    wall_half = np.array([0.5 * w["thickness"], *w["half"]])
    cams = "\n    ".join(f'<camera name="c{c}" pos="0 0 3"/>' for c in range(len(CAMERAS) + 1))
    return f"""
<mujoco model="beam">
  <option timestep="{1.0 / FPS / SUBSTEPS!r}" integrator="discrete" solver="Newton" gravity="0 0 -{GRAVITY}"/>
  <visual>
    <headlight ambient="0.35 0.35 0.35" diffuse="0 0 0" specular="0 0 0"/>
    <quality shadowsize="0"/>
  </visual>
  <asset>
    <texture name="sky" type="skybox" builtin="flat" rgb1="{floats(k["background"])}"
             rgb2="{floats(k["background"])}" width="16" height="16"/>
    <texture name="checker" type="2d" builtin="checker" rgb1="{floats(k["rgb1"])}" rgb2="{floats(k["rgb2"])}"
             width="64" height="64"/>
    <material name="checker" texture="checker" specular="0" shininess="0" reflectance="0"/>
  </asset>
  <worldbody>
    <light directional="true" dir="{floats(to_mj(np.array([0.3, -1.0, -0.4])))}" diffuse="0.65 0.65 0.65"
           specular="0 0 0" castshadow="false"/>
    <geom name="floor" type="plane" size="{FLOOR["half"]} {FLOOR["half"]} 0.1" rgba="{floats(FLOOR["rgb"])} 1"
          contype="0" conaffinity="0"/>
    <geom name="wall" type="box" pos="{floats(to_mj(wall_centre))}" size="{floats(to_mj(wall_half))}"
          rgba="{floats(w["rgb"])} 1" group="2" contype="0" conaffinity="0"/>
    {cams}
    <flexcomp name="beam" type="direct" dim="3" radius="{b["radius"]}" mass="{mass!r}" material="checker"
              flatskin="true" point="{floats(to_mj(pts))}" element="{" ".join(map(str, tets.ravel()))}"
              texcoord="{floats(uv)}">
      <pin id="{" ".join(map(str, pinned))}"/>
      <contact selfcollide="none" contype="0" conaffinity="0"/>
      <edge equality="false"/>
      <elasticity young="{b["young"]}" poisson="{b["poisson"]}" damping="{b["damping"]}"/>
    </flexcomp>
  </worldbody>
</mujoco>
"""


def _check_masses(mujoco, model, data, total: float) -> None:
    """Stop unless every free point weighs flexcomp's even share of ``total`` [kg] in the mass matrix and in
    gravity. (observe_mujoco's free-fall check does not apply: the discrete integrator's acceleration already
    includes the implicit stiffness term, so the points next to the clamp start slower than g.)"""
    mujoco.mj_forward(model, data)
    _, body = _free_vertex_bodies(model)
    jnt = np.flatnonzero(np.isin(model.jnt_bodyid, body) & (model.jnt_type == mujoco.mjtJoint.mjJNT_SLIDE))
    dof = model.jnt_dofadr[jnt]
    m = model.body_mass[model.jnt_bodyid[jnt]]
    share = total / model.flex_vertnum[0]
    weight = -np.asarray(model.jnt_axis[jnt]) @ np.asarray(model.opt.gravity) * m  # vertex bodies unrotated
    if (
        np.abs(m / share - 1).max() > 1e-9
        or np.abs(model.dof_M0[dof] / m - 1).max() > 1e-9
        or np.abs(data.qfrc_bias[dof] - weight).max() > 1e-9 * share * GRAVITY
    ):
        raise SystemExit("MuJoCo's point masses, mass matrix and gravity disagree")


def _camera_poses(x: np.ndarray, views, margin: float = 6.0):
    """K [C, 3, 3], world_to_camera [C, 4, 4] (OpenCV) and eyes [C, 3] of cameras at ``views`` ((azimuth,
    elevation) [deg]; azimuth 0 looks from +z, 90 from +x) looking at the centre of the motion ``x``
    [T, V, 3], each as close as it can be while every vertex of every frame stays ``margin`` px inside."""
    v = VIDEO
    pts = x.reshape(-1, 3)
    centre = 0.5 * (pts.min(0) + pts.max(0))
    K = intrinsics(v["fovy"], v["width"], v["height"])
    Ks, Ts, eyes = [], [], []
    for az, el in np.radians(np.asarray(views, float)):
        direction = np.array([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)])

        def fits(dist: float, direction: np.ndarray = direction) -> bool:
            T = look_at(centre + dist * direction, centre)
            if np.min(pts @ T[2, :3] + T[2, 3]) < 0.05:
                return False
            uv = _project(K, T, pts)
            return bool(((uv >= margin) & (uv <= np.array([v["width"], v["height"]]) - 1 - margin)).all())

        near, far = 0.1, 20.0  # bisection on the distance [m]
        for _ in range(40):
            mid = 0.5 * (near + far)
            near, far = (near, mid) if fits(mid) else (mid, far)
        eyes.append(centre + far * direction)
        Ks.append(K)
        Ts.append(look_at(eyes[-1], centre))
    return np.stack(Ks), np.stack(Ts), np.stack(eyes)


def _place_cameras(mujoco, model, Ts: np.ndarray, eyes: np.ndarray) -> None:
    """Set MuJoCo's cameras to the OpenCV poses (MuJoCo's camera frame is x right, y up, looking along −z:
    the columns (x_cv, −y_cv, −z_cv) of the world → camera rotation's transpose, in MuJoCo's axes)."""
    for c, (T, eye) in enumerate(zip(Ts, eyes, strict=True)):
        R = T[:3, :3]
        q = np.zeros(4)
        mujoco.mju_mat2Quat(q, np.stack([to_mj(R[0]), to_mj(-R[1]), to_mj(-R[2])], axis=1).ravel())
        model.cam_pos[c] = to_mj(eye)
        model.cam_quat[c] = q
        model.cam_fovy[c] = VIDEO["fovy"]


def boundary_triangles(tets: np.ndarray) -> np.ndarray:
    """The faces [F, 3] that belong to one tet only (the solid's surface)."""
    faces = np.concatenate([tets[:, [0, 1, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 3]], tets[:, [1, 2, 3]]])
    key = np.sort(faces, axis=1)
    _, inverse, count = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return faces[count[inverse.ravel()] == 1]


def ray_depth(origin: np.ndarray, dirs: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Ray parameter [R] of the first hit of rays ``origin`` + s ``dirs`` [R, 3] on triangles ``tri``
    [F, 3, 3] (Möller–Trumbore, both faces), inf where a ray misses."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    best = np.full(len(dirs), np.inf)
    for s in range(0, len(dirs), 512):  # chunks of rays keep the [R, F] temporaries small
        d = dirs[s : s + 512, None, :]
        p = np.cross(d, e2[None])
        det = np.einsum("rfk,fk->rf", p, e1)
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tv = origin[None, None, :] - tri[None, :, 0]
        u = np.einsum("rfk,rfk->rf", tv, p) * inv
        q = np.cross(tv, e1[None])
        w = np.einsum("rfk,rfk->rf", d, q) * inv
        hit = np.einsum("fk,rfk->rf", e2, q) * inv
        good = ok & (u >= -1e-9) & (w >= -1e-9) & (u + w <= 1 + 1e-9) & (hit > 0)
        best[s : s + 512] = np.where(good, hit, np.inf).min(axis=1)
    return best


def _render(mujoco, model, x: np.ndarray, cams: list[int]) -> dict:
    """Replay the motion ``x`` [T, V, 3] and render ``cams``: images, flex masks, depth [mm], and the masks
    drawn without the wall plate (they must be the same: the plate hides nothing of the beam)."""
    v = VIDEO
    data = mujoco.MjData(model)
    renderer = mujoco.Renderer(model, v["height"], v["width"])
    bare = mujoco.MjvOption()
    bare.geomgroup[2] = 0  # the wall plate's group
    C, T, H, W = len(cams), x.shape[0], v["height"], v["width"]
    out = dict(
        images=np.zeros((C, T, H, W, 3), np.uint8),
        masks=np.zeros((C, T, H, W), bool),
        depth=np.zeros((C, T, H, W), np.uint16),
        hidden=np.zeros(C, np.int64),
    )
    free, body = _free_vertex_bodies(model)
    qadr = model.jnt_qposadr[model.body_jntadr[body]]
    x0 = to_mj(x[0])
    flex = int(mujoco.mjtObj.mjOBJ_FLEX)
    for f in range(T):
        d = to_mj(x[f]) - x0  # the slide joints hold displacements from the initial points
        for k in range(3):
            data.qpos[qadr + k] = d[free, k]
        mujoco.mj_forward(model, data)
        if np.abs(_flex_vertices(model, data) - x[f]).max() > 1e-9:
            raise SystemExit(f"frame {f}: replaying the motion did not reproduce it")
        for i, c in enumerate(cams):
            renderer.update_scene(data, camera=c)
            out["images"][i, f] = renderer.render()
            renderer.enable_segmentation_rendering()
            renderer.update_scene(data, camera=c)
            out["masks"][i, f] = renderer.render()[..., 1] == flex
            renderer.update_scene(data, camera=c, scene_option=bare)
            out["hidden"][i] += int(np.sum(out["masks"][i, f] != (renderer.render()[..., 1] == flex)))
            renderer.disable_segmentation_rendering()
            renderer.enable_depth_rendering()
            renderer.update_scene(data, camera=c)
            z = renderer.render().astype(np.float64)  # metres along the optical axis (checked below)
            renderer.disable_depth_rendering()
            z = np.where(z < 0.999 * DEPTH_RANGE[1], np.round(z * 1000.0), 0.0)
            out["depth"][i, f] = np.clip(z, 0, 65535).astype(np.uint16)
    renderer.close()
    return out


def _check_views(r: dict, K, Ts, x, tris, frames) -> dict:
    """Every true vertex projects onto (or next to) its camera's mask, upside down many do not; depth
    back-projected through K and world_to_camera lands on the true surface (beam pixels) and on the floor."""
    C, T, H, W = r["masks"].shape
    on, flipped, beam_err, floor_err = [], [], [], []
    v, u = np.mgrid[0:H, 0:W]
    for c in range(C):
        Kinv, R, t = np.linalg.inv(K[c]), Ts[c][:3, :3], Ts[c][:3, 3]
        eye = -R.T @ t
        rays_cam = np.stack([u, v, np.ones_like(u)], axis=-1).reshape(-1, 3) @ Kinv.T  # z = 1 in the camera
        for f in frames:
            m = r["masks"][c, f]
            grown = m.copy()
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    grown |= np.roll(np.roll(m, dy, axis=0), dx, axis=1)
            px = np.round(_project(K[c], Ts[c], x[f])).astype(int)
            on.append(grown[px[:, 1], px[:, 0]].mean())
            flipped.append(grown[::-1][px[:, 1], px[:, 0]].mean())
            z = r["depth"][c, f].reshape(-1) / 1000.0
            world = eye + (rays_cam * z[:, None]) @ R  # camera → world: R^T (z K^-1 [u, v, 1])
            sel = m.reshape(-1) & (z > 0)
            # The true depth of each beam pixel: cast its ray at the true surface (along z: the ray's z is 1).
            truth_z = ray_depth(eye, rays_cam[sel] @ R, x[f][tris])
            hit = np.isfinite(truth_z)
            beam_err.append(np.abs(z[sel][hit] - truth_z[hit]))
            floor = ~grown.reshape(-1) & (z > 0) & (np.abs(world[:, 1]) < 0.05)
            floor_err.append(np.abs(world[floor, 1]))
    beam_err, floor_err = np.concatenate(beam_err), np.concatenate(floor_err)
    return {
        "true_vertices_on_mask": float(np.min(on)),
        "true_vertices_on_flipped_mask": float(np.mean(flipped)),
        "beam_depth_error_mm": {
            "median": float(np.median(beam_err) * 1e3),
            "mean": float(beam_err.mean() * 1e3),
            "p95": float(np.percentile(beam_err, 95) * 1e3),
            "pixels": int(beam_err.size),
        },
        "floor_height_from_depth_mm": {
            "mean": float(floor_err.mean() * 1e3),
            "p95": float(np.percentile(floor_err, 95) * 1e3),
        },
    }


def _tip_figures(x: np.ndarray, t: np.ndarray) -> dict:
    """Tip sag [m] (end-face centre's drop), its mean-crossing period [s] and the swing left late on."""
    tip = np.abs(x[0, :, 0] - x[0, :, 0].max()) < 1e-9
    sag = x[0, tip, 1].mean() - x[:, tip, 1].mean(axis=1)
    late = slice(int(0.7 * len(t)), None)
    mid = sag[len(t) // 2 :].mean()
    ups = np.flatnonzero((sag[:-1] < mid) & (sag[1:] >= mid))
    return {
        "tip_sag_max_m": float(sag.max()),
        "tip_sag_mean_last_half_m": float(mid),
        "tip_sag_final_m": float(sag[-1]),
        "period_s": float(np.mean(np.diff(t[ups]))),
        "tip_half_swing_last_30pct_m": float(0.5 * np.ptp(sag[late])),
        "tip_sideways_max_m": float(np.abs(x[:, tip, 2].mean(axis=1)).max()),
    }


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(FIXTURES), help="output folder")
    ap.add_argument("--check-frames", type=int, default=10, help="check the views every N frames")
    args = ap.parse_args(argv)
    mujoco = _mujoco()
    t0 = time.perf_counter()
    pts, tets, uv, pinned = beam_mesh()
    model = mujoco.MjModel.from_xml_string(_xml(pts, tets, uv, pinned))
    data = mujoco.MjData(model)
    _check_masses(mujoco, model, data, BEAM["density"] * float(np.prod(BEAM["size"])))
    xs = [_flex_vertices(model, data)]
    for _ in range(FRAMES):
        for _ in range(SUBSTEPS):
            mujoco.mj_step(model, data)
        xs.append(_flex_vertices(model, data))
    x = np.stack(xs)
    if not np.all(np.isfinite(x)) or np.abs(x[0] - pts).max() > 1e-9:
        raise SystemExit("MuJoCo diverged or reordered the points")
    warnings = {
        str(mujoco.mjtWarning(i)).split(".")[-1]: int(data.warning[i].number)
        for i in range(len(data.warning))
        if data.warning[i].number
    }
    sim_s = time.perf_counter() - t0
    t = np.arange(FRAMES + 1) / FPS
    mass = np.zeros(len(pts))
    free, body = _free_vertex_bodies(model)
    mass[free] = model.body_mass[body]
    mass[pinned] = np.median(mass[free])  # flexcomp's even share; a pinned point has no body of its own
    views = [*CAMERAS, HELDOUT]
    Ks, Ts, eyes = _camera_poses(x, views)
    _place_cameras(mujoco, model, Ts, eyes)
    model.vis.map.znear = DEPTH_RANGE[0] / model.stat.extent
    model.vis.map.zfar = DEPTH_RANGE[1] / model.stat.extent
    check = mujoco.MjData(model)
    mujoco.mj_forward(model, check)
    for c in range(len(views)):  # the poses MuJoCo computed must be the OpenCV ones set
        frame = np.asarray(check.cam_xmat[c]).reshape(3, 3)
        R = np.stack([from_mj(frame[:, 0]), -from_mj(frame[:, 1]), -from_mj(frame[:, 2])])
        if np.abs(R - Ts[c][:3, :3]).max() > 1e-6:
            raise SystemExit(f"camera {c}: MuJoCo's pose differs from the OpenCV one set")
    r = _render(mujoco, model, x, list(range(len(views))))
    if r["hidden"].any():
        raise SystemExit(f"the wall plate hides beam pixels: {r['hidden'].tolist()} per camera")
    tris = boundary_triangles(tets)
    frames = list(range(0, FRAMES + 1, args.check_frames))
    checks = _check_views(r, Ks, Ts, x, tris, frames)
    if checks["true_vertices_on_mask"] < 1.0:
        raise SystemExit(f"true vertices off the masks: {checks}")
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    fit, held = slice(0, len(CAMERAS)), slice(len(CAMERAS), None)
    paths = {}
    for name, sl in (("mujoco_beam_video", fit), ("mujoco_beam_heldout", held)):
        paths[name] = os.path.join(out, f"{name}.npz")
        np.savez_compressed(
            paths[name],
            t=t,
            images=r["images"][sl],
            masks=r["masks"][sl],
            depth=r["depth"][sl],
            K=Ks[sl],
            world_to_camera=Ts[sl],
        )
    paths["mujoco_beam_truth"] = os.path.join(out, "mujoco_beam_truth.npz")
    np.savez_compressed(paths["mujoco_beam_truth"], x=x, tets=tets, pinned=pinned, mass=mass, t=t)
    figures = _tip_figures(x, t)
    meta = _meta(mujoco, model, x, tets, mass, eyes, views, checks, figures, warnings, sim_s)
    paths["mujoco_beam_video.json"] = os.path.join(out, "mujoco_beam_video.json")
    with open(paths["mujoco_beam_video.json"], "w") as fh:
        fh.write(json.dumps(meta, indent=1) + "\n")
    sizes = {os.path.basename(p): os.path.getsize(p) for p in paths.values()}
    row = {"files": sizes, "MB": round(sum(sizes.values()) / 1e6, 2), **figures, **checks}
    row["wall_s"] = round(time.perf_counter() - t0, 1)
    print(json.dumps(row), flush=True)
    return row


def _meta(mujoco, model, x, tets, mass, eyes, views, checks, figures, warnings, sim_s) -> dict:
    b, k = BEAM, CHECKER
    return {
        "fixture": "mujoco_beam_video",
        "data": "SYNTHETIC: MuJoCo's simulation and OpenGL rendering, standing in for a real beam on camera",
        "engine": f"mujoco {mujoco.__version__}",
        "renderer": f"MuJoCo {mujoco.__version__} mujoco.Renderer, OpenGL offscreen, MUJOCO_GL="
        f"{os.environ.get('MUJOCO_GL', '(default)')}",
        "integrator": f"discrete (implicit), Newton solver, timestep 1/{round(FPS * SUBSTEPS)} s, "
        f"{SUBSTEPS} steps per frame",
        "mujoco_warnings": warnings,
        "up_axis": "files in pliant's axes (y up); MuJoCo ran z up: pliant (x, y, z) = MuJoCo (z, x, y)",
        "model": f"flexcomp type='direct' dim=3: {list(b['cells'])} cells x 6 tets (Kuhn split; {x.shape[1]} "
        f"vertices, {len(tets)} tets), {list(b['size'])} m (length x, height y, width z), clamped end face "
        f"x = 0 pinned (<pin>, {int(np.sum(np.abs(x[0, :, 0]) < 1e-9))} points), centre line at height "
        f"{b['height']} m, straight and at rest at t = 0, released under gravity {GRAVITY} m/s2",
        "material_engine": {
            "elasticity": "flex 3D StVK",
            "young_Pa": b["young"],
            "poisson": b["poisson"],
            "density_kg_m3": b["density"],
            "rayleigh_damping_s": b["damping"],
            "flex_radius_m": b["radius"],
        },
        "masses": "MuJoCo's own: flexcomp spreads rho x volume evenly over ALL points (pinned ones "
        "included), so each point weighs the same (pliant's rho V / 4 lumping would not); truth "
        "'mass' gives the pinned points that even share too",
        "total_mass_kg": float(mass.sum()),
        "free_mass_kg": float(np.sum(model.body_mass)),
        "figures": figures,
        "floor": f"plane at height 0 (visible, grey {list(FLOOR['rgb'])}, {2 * FLOOR['half']} m square); the "
        "beam never reaches it",
        "wall_plate": f"a box behind the clamped face (x from {-WALL['gap'] - WALL['thickness']} to "
        f"{-WALL['gap']} m, {2 * WALL['half'][0]} x {2 * WALL['half'][1]} m), visible, NOT in the masks; "
        "checked: it hides no beam pixel in any camera",
        "cameras": len(CAMERAS),
        "heldout_cameras": 1,
        "camera_views_deg": {"fit": [list(v) for v in views[:-1]], "heldout": list(views[-1])},
        "camera_view_convention": "(azimuth, elevation): azimuth 0 looks from +z, 90 from +x (the free end); "
        "each camera as close as it can be with every vertex of every frame 6 px inside its image",
        "camera_eyes_m": {"fit": eyes[:-1].tolist(), "heldout": eyes[-1].tolist()},
        "image_size": [VIDEO["width"], VIDEO["height"]],
        "fovy_deg": VIDEO["fovy"],
        "camera_convention": "OpenCV (x right, y down, z forward), pixel centres at integers, pliant axes "
        "(y up); MuJoCo camera = rows (x, -y, -z) of world_to_camera",
        "arrays": {
            "video/heldout": "t [T] s, images [C, T, H, W, 3] uint8, masks [C, T, H, W] bool, depth "
            "[C, T, H, W] uint16 mm, K [C, 3, 3], world_to_camera [C, 4, 4]",
            "truth": "x [T, V, 3] m (every vertex, pliant axes), tets [E, 4], pinned [P], mass [V] kg, "
            "t [T] s",
        },
        "depth": f"MuJoCo's depth render: distance along the optical axis (camera z) [mm], rounded; 0 = no "
        f"reading (beyond {DEPTH_RANGE[1]} m: the sky); near/far planes {list(DEPTH_RANGE)} m",
        "appearance": {
            "checker_rgb1": k["rgb1"],
            "checker_rgb2": k["rgb2"],
            "checker_cell_m": k["cell"],
            "texture": "u = x / 2c + 1/8 along the beam, v = (y + z - y0 - z0) / 2c + 1/8 (c the cell): "
            "square cells on the four long faces, stripes on the end faces",
            "background_rgb": k["background"],
            "lighting": "one directional light (diffuse 0.65, direction (0.3, -1, -0.4) in pliant axes) + "
            "ambient 0.35 (MuJoCo's headlight), no specular (Lambertian), no shadows, flat-shaded faces",
        },
        "masks": "MuJoCo's segmentation rendering: pixels whose object is the flex (not the floor, the "
        "wall, the sky)",
        "checks": checks,
        "pixel_noise": 0.0,
        "frames": int(x.shape[0]),
        "fps": FPS,
        "simulate_s": round(sim_s, 2),
        "command": "MUJOCO_GL=egl observe_mujoco_beam.py",
    }


if __name__ == "__main__":
    main()
