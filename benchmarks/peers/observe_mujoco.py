"""Cross-engine fixtures from MuJoCo 4.0: a flex cloth (tracks, and camera footage rendered by MuJoCo's own
OpenGL renderer), a flex soft cube thrown onto the ground, and a flex rope (a discrete elastic rod),
written as pliant observation files with a JSON sidecar, the noise-free truth and the matching pliant scene
(``tests/data/foreign/``).

SYNTHETIC DATA from another engine: it stands in for real measurements through a genuine model mismatch
(MuJoCo's StVK flex elasticity, soft contacts and elastic rods against pliant's springs and tets), not by
being real. Needs MuJoCo in its own venv (README.md); never imported by pliant or its tests. Rendering is
headless: ``MUJOCO_GL=egl`` (Mesa's EGL, Debian ``libegl-mesa0``) or ``osmesa`` (``libosmesa6``).

    cd benchmarks/peers
    MUJOCO_GL=egl /work/peers-venv/bin/python observe_mujoco.py cloth   # mujoco_cloth + mujoco_cloth_video
    /work/peers-venv/bin/python observe_mujoco.py cube
    /work/peers-venv/bin/python observe_mujoco.py rope

These fixtures give MuJoCo pliant's lumped masses; ``observe_own.py`` makes ``mujoco_cloth_own`` and
``mujoco_cube_own`` MuJoCo's own way (flexcomp's even masses, its default soft contact) from the helpers here.

Axes: MuJoCo runs z-up here (its ground plane and gravity); pliant is y-up. A point (x, y, z) of pliant is
(z, x, y) in MuJoCo, a cyclic permutation (a rotation, so element orientations are kept); every file is
written in pliant's axes.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402
from _foreign import (  # noqa: E402
    FPS,
    THROWN_BOX,
    box_tets,
    cloth_mesh,
    cloth_toml,
    fixture_meta,
    floats,
    intrinsics,
    look_at,
    lumped_by_area,
    noisy_tracks,
    scene_toml,
    soft_box_toml,
    write_fixture,
)
from _scene import lumped_mass  # noqa: E402

GRAVITY = 9.81
FRAMES = 60  # track fixtures: frames after frame 0 (61 frames, 2 s at 30 fps)
VIDEO_FRAMES = 40  # footage: frames after frame 0 (41 frames)
SUBSTEPS = 20  # MuJoCo steps per frame (dt = 1/600 s)
SOLVER = "Newton"  # MuJoCo's constraint solver (flex elasticity needs the discrete integrator)


def to_mj(p: np.ndarray) -> np.ndarray:
    """pliant (x, y, z) → MuJoCo (z, x, y)."""
    return np.asarray(p)[..., [2, 0, 1]]


def from_mj(p: np.ndarray) -> np.ndarray:
    """MuJoCo (x, y, z) → pliant (y, z, x)."""
    return np.asarray(p)[..., [1, 2, 0]]


# Cloth: the same object as observe_newton.py's (12 × 12 cells, 0.6 m, xz plane at height 1, held at the two
# corners of largest z, 0.1 kg lumped by area), as a MuJoCo 2D flex: StVK membrane (plane stress) and hinge
# bending from <elasticity elastic2d="both"> with E = 1e5 Pa, ν = 0.3, thickness 1 mm (E·t = 100 N/m),
# Rayleigh damping 1 ms; no contacts (nothing to hit).
CLOTH = dict(n=12, size=0.6, origin=(-0.3, 1.0, -0.3), mass=0.1, young=1.0e5, poisson=0.3, thickness=0.001)
CLOTH_DAMPING = 0.001  # flex Rayleigh damping [s]
# Footage: 3 cameras, 128 × 96, vertical field of view 40°, a blue/yellow checker of 0.1 m cells.
VIDEO = dict(width=128, height=96, fovy=40.0, azimuths=(30.0, 150.0, 270.0), elevation=25.0)
CHECKER = dict(rgb1=(0.1, 0.2, 0.9), rgb2=(0.95, 0.85, 0.1), cell=0.1, background=(0.8, 0.8, 0.8))

# Soft cube: pliant's soft_box of 4 × 4 × 4 cells (Kuhn split, 6 tets per cell), side 0.2 m, centre at
# (0, 0.45, 0) so that its bottom is 0.35 m above the ground, thrown at (1.2, -1, 0) m/s; ρ = 500 kg/m³
# lumped ρV/4; a MuJoCo 3D flex with StVK elasticity E = 4e4 Pa, ν = 0.3, Rayleigh damping 2 ms; vertex
# spheres of radius 5 mm against the ground plane, friction 0.5 (MuJoCo's soft contact, solref 5 ms).
CUBE = dict(
    **THROWN_BOX,
    young=4.0e4,
    poisson=0.3,
    damping=0.002,
    friction=0.5,
    radius=0.005,
    solref=(0.005, 1.0),
)

# Rope: a MuJoCo 1D flex (a discrete elastic rod: bending and twist) of 20 segments, 0.6 m from (0, 1, 0)
# along +x, its first vertex pinned (free to turn), released straight and horizontal; 0.06 kg, equal vertex
# masses as pliant's; circular section of radius 5 mm, E = 2e6 Pa (EI = E π r⁴ / 4 = 9.8e-4 N m²), ν = 0.3,
# Rayleigh damping 1 ms; inextensible through edge equality constraints (solref 4 ms: the segments stretch
# by at most a few per cent at the bottom of the swing).
ROPE = dict(
    segments=20, length=0.6, origin=(0.0, 1.0, 0.0), mass=0.06, radius=0.005, young=2.0e6, poisson=0.3
)
ROPE_DAMPING = 0.001  # flex Rayleigh damping [s]
ROPE_EDGE_SOLREF = (0.004, 1.0)  # edge equality constraint: time constant [s], damping ratio


def _mujoco():
    import mujoco

    # MuJoCo appends warnings to MUJOCO_LOG.TXT in the working directory; send them to stderr instead.
    mujoco.set_mju_user_warning(lambda msg: print(f"MuJoCo warning: {msg}", file=sys.stderr))
    return mujoco


def _ints(a: np.ndarray) -> str:
    return " ".join(str(int(v)) for v in np.asarray(a).ravel())


def _option() -> str:
    return (
        f'<option timestep="{1.0 / FPS / SUBSTEPS!r}" integrator="discrete" solver="{SOLVER}" '
        f'gravity="0 0 -{GRAVITY}"/>'
    )


def _cloth_xml(pts, tris, uv, pin) -> str:
    c, k = CLOTH, CHECKER
    repeat = c["size"] / (2 * k["cell"])  # the builtin checker texture holds 2 × 2 cells
    return f"""
<mujoco model="cloth">
  {_option()}
  <visual>
    <headlight ambient="0.35 0.35 0.35" diffuse="0 0 0" specular="0 0 0"/>
    <quality shadowsize="0"/>
  </visual>
  <asset>
    <texture name="sky" type="skybox" builtin="flat" rgb1="{floats(k["background"])}"
             rgb2="{floats(k["background"])}" width="16" height="16"/>
    <texture name="checker" type="2d" builtin="checker" rgb1="{floats(k["rgb1"])}"
             rgb2="{floats(k["rgb2"])}" width="64" height="64"/>
    <material name="checker" texture="checker" texrepeat="{repeat:g} {repeat:g}" specular="0" shininess="0"
              reflectance="0"/>
  </asset>
  <worldbody>
    <light directional="true" dir="{floats(to_mj(np.array([-0.3, -1.0, -0.5])))}" diffuse="0.65 0.65 0.65"
           specular="0 0 0" castshadow="false"/>
    <camera name="c0" pos="0 0 3"/> <camera name="c1" pos="0 0 3"/> <camera name="c2" pos="0 0 3"/>
    <flexcomp name="cloth" type="direct" dim="2" radius="0.001" mass="{c["mass"]}" material="checker"
              point="{floats(to_mj(pts))}" element="{_ints(tris)}" texcoord="{floats(uv)}">
      <pin id="{_ints(pin)}"/>
      <contact selfcollide="none" contype="0" conaffinity="0"/>
      <edge equality="false"/>
      <elasticity young="{c["young"]}" poisson="{c["poisson"]}" thickness="{c["thickness"]}"
                  damping="{CLOTH_DAMPING}" elastic2d="both"/>
    </flexcomp>
  </worldbody>
</mujoco>
"""


def _flex_vertices(model, data) -> np.ndarray:
    a, n = model.flex_vertadr[0], model.flex_vertnum[0]
    return from_mj(np.array(data.flexvert_xpos[a : a + n], np.float64))


def _free_vertex_bodies(model) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the flex's free vertices and their bodies (pinned vertices belong to the world body)."""
    a, n = model.flex_vertadr[0], model.flex_vertnum[0]
    body = np.asarray(model.flex_vertbodyid[a : a + n])
    free = np.flatnonzero(body > 0)
    return free, body[free]


def _set_flex_masses(model, mass: np.ndarray) -> None:
    """Point-body masses [kg] (flexcomp spreads its mass evenly; pliant lumps by area or volume).

    ``mj_setConst`` must follow: without it MuJoCo keeps the gravity of the even masses while the inertia
    uses the new ones, so each vertex falls at g × (even mass / its mass) — a checkerboard of 0.4 g to 1.6 g
    on the lumped cloth, which no physical model reproduces. :func:`_check_free_fall` guards against it.
    """
    mujoco = _mujoco()
    free, body = _free_vertex_bodies(model)
    model.body_mass[body] = mass[free]
    mujoco.mj_setConst(model, mujoco.MjData(model))


def _check_free_fall(model, data, tol: float = 1e-3) -> None:
    """Stop unless every free vertex's slide joints accelerate at g (to ``tol`` × g) at the unstrained start:
    no internal force yet, only gravity, so the masses, gravity and inertia agree."""
    mujoco = _mujoco()
    mujoco.mj_forward(model, data)
    _, body = _free_vertex_bodies(model)
    jnt = np.flatnonzero(np.isin(model.jnt_bodyid, body) & (model.jnt_type == mujoco.mjtJoint.mjJNT_SLIDE))
    want = np.asarray(model.jnt_axis[jnt]) @ np.asarray(model.opt.gravity)  # vertex bodies are unrotated
    err = float(np.abs(np.asarray(data.qacc)[model.jnt_dofadr[jnt]] - want).max())
    if err > tol * GRAVITY:
        raise SystemExit(
            f"MuJoCo's start is not a free fall (|a - g| up to {err:.3g} m/s²); check the masses"
        )


def _simulate(mujoco, model, data, frames: int) -> np.ndarray:
    xs = [_flex_vertices(model, data)]
    for _ in range(frames):
        for _ in range(SUBSTEPS):
            mujoco.mj_step(model, data)
        xs.append(_flex_vertices(model, data))
    x = np.stack(xs)
    if not np.all(np.isfinite(x)):
        raise SystemExit("MuJoCo's simulation diverged")
    return x


def _cameras(x: np.ndarray, margin: float = 4.0) -> tuple[np.ndarray, np.ndarray, list]:
    """K [C, 3, 3], world_to_camera [C, 4, 4] (OpenCV) and eyes of cameras looking at the centre of the
    motion ``x`` [T, N, 3] from VIDEO's azimuths and elevation, each as close as it can be while every vertex
    of every frame stays ``margin`` pixels inside its image."""
    v = VIDEO
    pts = x.reshape(-1, 3)
    lo, hi = pts.min(0), pts.max(0)
    centre = 0.5 * (lo + hi)
    K = intrinsics(v["fovy"], v["width"], v["height"])
    el = np.radians(v["elevation"])
    Ks, Ts, eyes = [], [], []
    for az in np.radians(v["azimuths"]):
        direction = np.array([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)])

        def fits(dist: float, direction: np.ndarray = direction) -> bool:
            T = look_at(centre + dist * direction, centre)
            if np.min(pts @ T[2, :3] + T[2, 3]) < 0.05:
                return False
            uv = _project(K, T, pts)
            inside = (uv >= margin) & (uv <= np.array([v["width"], v["height"]]) - 1 - margin)
            return bool(inside.all())

        near, far = 0.1, 20.0  # bisection on the distance [m]
        for _ in range(40):
            mid = 0.5 * (near + far)
            near, far = (near, mid) if fits(mid) else (mid, far)
        eye = centre + far * direction
        Ks.append(K)
        Ts.append(look_at(eye, centre))
        eyes.append(eye)
    return np.stack(Ks), np.stack(Ts), eyes


def _place_cameras(mujoco, model, Ts: np.ndarray, eyes: list) -> None:
    """Set MuJoCo's cameras to the OpenCV poses: MuJoCo's camera frame is x right, y up, looking along −z,
    i.e. the columns (x_cv, −y_cv, −z_cv) of the world → camera rotation's transpose, in MuJoCo's axes."""
    for c, (T, eye) in enumerate(zip(Ts, eyes, strict=True)):
        R = T[:3, :3]
        frame = np.stack([to_mj(R[0]), to_mj(-R[1]), to_mj(-R[2])], axis=1)  # columns: camera axes
        q = np.zeros(4)
        mujoco.mju_mat2Quat(q, frame.ravel())
        model.cam_pos[c] = to_mj(eye)
        model.cam_quat[c] = q
        model.cam_fovy[c] = VIDEO["fovy"]


def _project(K: np.ndarray, T: np.ndarray, p: np.ndarray) -> np.ndarray:
    q = p @ T[:3, :3].T + T[:3, 3]
    uvw = q @ K.T
    return uvw[:, :2] / uvw[:, 2:3]


def _cloth_video(mujoco, model, x: np.ndarray, args: argparse.Namespace) -> dict:
    """Render the first VIDEO_FRAMES + 1 frames of the cloth's motion ``x`` from 3 cameras."""
    t0 = time.perf_counter()
    v = VIDEO
    Ks, Ts, eyes = _cameras(x)
    _place_cameras(mujoco, model, Ts, eyes)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    # The poses MuJoCo computed must be those we set (OpenCV rows = MuJoCo camera axes (x, −y, −z)).
    for c in range(len(Ts)):
        frame = np.asarray(data.cam_xmat[c]).reshape(3, 3)
        R = np.stack([from_mj(frame[:, 0]), -from_mj(frame[:, 1]), -from_mj(frame[:, 2])])
        if np.abs(R - Ts[c][:3, :3]).max() > 1e-6:
            raise SystemExit(f"camera {c}: MuJoCo's pose differs from the OpenCV one set")
    renderer = mujoco.Renderer(model, v["height"], v["width"])
    C, T = len(Ts), x.shape[0]
    images = np.zeros((C, T, v["height"], v["width"], 3), np.uint8)
    masks = np.zeros((C, T, v["height"], v["width"]), bool)
    # Replay the stored motion: set the free vertices' slide joints from the recorded positions.
    a, n = model.flex_vertadr[0], model.flex_vertnum[0]
    body = model.flex_vertbodyid[a : a + n]
    free = np.flatnonzero(body > 0)
    qadr = model.jnt_qposadr[model.body_jntadr[body[free]]]
    x0 = to_mj(x[0])
    for f in range(T):
        d = to_mj(x[f]) - x0  # slide joints hold displacements from the initial points
        for k in range(3):
            data.qpos[qadr + k] = d[free, k]
        mujoco.mj_forward(model, data)
        if np.abs(_flex_vertices(model, data) - x[f]).max() > 1e-9:
            raise SystemExit(f"frame {f}: replaying the motion did not reproduce it")
        for c in range(C):
            renderer.update_scene(data, camera=c)
            images[c, f] = renderer.render()
            renderer.enable_segmentation_rendering()
            renderer.update_scene(data, camera=c)
            seg = renderer.render()
            renderer.disable_segmentation_rendering()
            masks[c, f] = seg[..., 1] == int(mujoco.mjtObj.mjOBJ_FLEX)
    # Which colour is the checker cell at the cloth's origin corner: read at its centre in camera 0, frame 0.
    k = CHECKER
    cell_centre = np.asarray(CLOTH["origin"]) + np.array([0.5, 0.0, 0.5]) * k["cell"]
    u, w = np.round(_project(Ks[0], Ts[0], cell_centre[None])[0]).astype(int)
    seen = images[0, 0, w, u] / 255.0
    first = "rgb1" if np.abs(seen - k["rgb1"]).sum() < np.abs(seen - k["rgb2"]).sum() else "rgb2"
    t = np.arange(T) / FPS
    meta = {
        "fixture": "mujoco_cloth_video",
        "data": "SYNTHETIC: MuJoCo's simulation and OpenGL rendering, standing in for real footage",
        "engine": f"mujoco {mujoco.__version__}",
        "renderer": f"MuJoCo {mujoco.__version__} mujoco.Renderer, OpenGL offscreen, MUJOCO_GL="
        f"{os.environ.get('MUJOCO_GL', '(default)')}",
        "motion": "frames 0-40 of mujoco_cloth (the same simulation); its truth file holds every vertex",
        "truth": "mujoco_cloth_truth.npz",
        "scene": "mujoco_cloth.toml",
        "cameras": len(Ts),
        "image_size": [v["width"], v["height"]],
        "fovy_deg": v["fovy"],
        "camera_convention": "OpenCV (x right, y down, z forward), pixel centres at integers, pliant axes "
        "(y up); MuJoCo camera = rows (x, -y, -z) of world_to_camera",
        "camera_eyes_m": [list(map(float, e)) for e in eyes],
        "appearance": {
            "checker_rgb1": k["rgb1"],
            "checker_rgb2": k["rgb2"],
            "checker_cell_m": k["cell"],
            "cell_at_origin_corner": first,
            "cells_along_each_side": round(CLOTH["size"] / k["cell"]),
            "background_rgb": k["background"],
            "lighting": "one directional light (diffuse 0.65, direction (-0.3, -1, -0.5) in pliant axes) + "
            "ambient 0.35 (MuJoCo's headlight), no specular (Lambertian), no shadows",
        },
        "masks": "MuJoCo's segmentation rendering: pixels whose object is the flex",
        "pixel_noise": 0.0,
        "frames": T,
        "fps": FPS,
    }
    written = write_fixture(
        "mujoco_cloth_video",
        dict(t=t, images=images, K=Ks, world_to_camera=Ts, masks=masks),
        meta,
    )
    return _row("mujoco_cloth_video", written, x, t0)


def _track_fixture(name, x, candidates, args, meta_args, scene, wall_start) -> dict:
    """Noisy, occluded tracks of the motion ``x`` [T, N, 3] and the fixture's files."""
    rng = np.random.default_rng(args.seed)
    points, visible, pick, gaps = noisy_tracks(x, candidates, args.tracks, rng)
    t = np.arange(x.shape[0]) / FPS
    meta = _meta(name, t=t, pick=pick, gaps=gaps, args=args, **meta_args)
    written = write_fixture(name, dict(t=t, points=points, visible=visible), meta, truth=x, scene=scene)
    return _row(name, written, x, wall_start)


def _meta(name, *, mujoco, mjmodel, model, material, converted, nominal, args, t, pick, gaps, extra=None):
    _, body = _free_vertex_bodies(mjmodel)
    command = f"observe_mujoco.py {name.removeprefix('mujoco_')} --tracks {args.tracks} --seed {args.seed}"
    return {
        **fixture_meta(name, f"mujoco {mujoco.__version__}", t, pick, gaps, args.seed, command),
        "integrator": f"discrete (implicit), {SOLVER} solver, timestep 1/{round(FPS * SUBSTEPS)} s, "
        f"{SUBSTEPS} steps per frame",
        "up_axis": "files in pliant's axes (y up); MuJoCo ran z up: pliant (x, y, z) = MuJoCo (z, x, y)",
        "model": model,
        "material_engine": material,
        "free_mass_kg": float(np.sum(mjmodel.body_mass[body])),  # the vertices that are not pinned
        "material_pliant_converted": converted,
        "material_pliant_nominal": {
            **nominal,
            "note": "deliberately about 5x too soft: a fit's starting point",
        },
        **(extra or {}),
    }


def _row(name, written, x, t0: float) -> dict:
    return {
        "fixture": name,
        "files": {p.name: p.stat().st_size for p in written},
        "frames": int(x.shape[0]),
        "vertices": int(x.shape[1]),
        "drop_m": float(x[0, :, 1].mean() - x[-1, :, 1].mean()),
        "wall_s": round(time.perf_counter() - t0, 2),
    }


def _comments(mujoco, what: str, lines: list[str]) -> list[str]:
    """The comment lines of a fixture's scene: where it comes from, the axes, the conversion."""
    return [
        f"MuJoCo {mujoco.__version__} {what},",
        "described in pliant's terms (SYNTHETIC cross-engine data).",
        "Generated by benchmarks/peers/observe_mujoco.py; the sidecar JSON says how.",
        "Axes: y up, as pliant (MuJoCo ran z up; pliant (x, y, z) = MuJoCo (z, x, y)).",
        *lines,
    ]


# ---------------------------------------------------------------------------------------------- cloth
def cloth(args: argparse.Namespace) -> list[dict]:
    mujoco = _mujoco()
    t0 = time.perf_counter()
    c = CLOTH
    pts, tris, uv, pin = cloth_mesh(CLOTH)
    model = mujoco.MjModel.from_xml_string(_cloth_xml(pts, tris, uv, pin))
    _set_flex_masses(model, lumped_by_area(pts, tris, c["mass"]))
    data = mujoco.MjData(model)
    _check_free_fall(model, data)
    x = _simulate(mujoco, model, data, FRAMES)
    if np.abs(x[0] - pts).max() > 1e-9:
        raise SystemExit("MuJoCo's vertex order differs from the points given")
    Et = c["young"] * c["thickness"]
    D = c["young"] * c["thickness"] ** 3 / (12 * (1 - c["poisson"] ** 2))
    comments = _comments(
        mujoco,
        "flex cloth (2D, StVK membrane + hinge bending)",
        [
            f"Converted: Et = E t = {c['young']:g} Pa * {c['thickness']:g} m = {Et:g} N/m, "
            f"nu = {c['poisson']}.",
            f"No pliant equivalent: MuJoCo's bending D = E t^3 / (12 (1 - nu^2)) = {D:.3g} N m (negligible)",
            f"and its Rayleigh damping of {CLOTH_DAMPING * 1e3:g} ms.",
            f"NOMINAL material below: Et = {Et / 5:g} N/m, deliberately 5x too soft (where a fit starts).",
        ],
    )
    body = cloth_toml(c, Et / 5, c["poisson"], Et, "pinned in MuJoCo too")
    scene = scene_toml(comments, "mujoco_cloth", 40, FRAMES, body)
    material = {
        "elasticity": "flex 2D, elastic2d='both': StVK membrane (plane stress) + hinge bending",
        "young_Pa": c["young"],
        "poisson": c["poisson"],
        "thickness_m": c["thickness"],
        "rayleigh_damping_s": CLOTH_DAMPING,
        "bending_D_Nm": D,
    }
    meta = dict(
        mujoco=mujoco,
        mjmodel=model,
        model=f"flexcomp type='direct' dim=2, {c['n']} x {c['n']} cells ({len(pts)} vertices, {len(tris)} "
        f"triangles), {c['size']} m square in the xz plane at height {c['origin'][1]} m, two corners pinned "
        f"(<pin>), {c['mass']} kg lumped by area, no contacts",
        material=material,
        converted={"Et": Et, "nu": c["poisson"]},
        nominal={"Et": Et / 5, "nu": c["poisson"]},
    )
    free = np.setdiff1d(np.arange(len(pts)), pin)
    rows = [_track_fixture("mujoco_cloth", x, free, args, meta, scene, t0)]
    rows.append(_cloth_video(mujoco, model, x[: VIDEO_FRAMES + 1], args))
    return rows


# ---------------------------------------------------------------------------------------------- cube
def cube(args: argparse.Namespace) -> list[dict]:
    mujoco = _mujoco()
    t0 = time.perf_counter()
    c = k = CUBE
    corner = np.asarray(c["centre"]) - 0.5 * np.asarray(c["size"])
    pts, tets = box_tets(c["cells"], c["size"], corner)
    xml = f"""
<mujoco model="cube">
  {_option()}
  <worldbody>
    <geom name="ground" type="plane" size="5 5 0.1" friction="{k["friction"]} 0.005 0.0001"
          solref="{floats(k["solref"])}"/>
    <flexcomp name="cube" type="direct" dim="3" radius="{k["radius"]}" mass="1" point="{floats(to_mj(pts))}"
              element="{_ints(tets)}">
      <contact selfcollide="none" friction="{k["friction"]} 0.005 0.0001" condim="3"
               solref="{floats(k["solref"])}"/>
      <edge equality="false"/>
      <elasticity young="{k["young"]}" poisson="{k["poisson"]}" damping="{k["damping"]}"/>
    </flexcomp>
  </worldbody>
</mujoco>
"""
    model = mujoco.MjModel.from_xml_string(xml)
    mass = lumped_mass(pts, tets, c["density"])
    _set_flex_masses(model, mass)
    data = mujoco.MjData(model)
    free, body = _free_vertex_bodies(model)
    dof = model.jnt_dofadr[model.body_jntadr[body]]
    for a in range(3):  # each vertex body has three slide joints along MuJoCo's x, y, z
        data.qvel[dof + a] = to_mj(np.asarray(c["velocity"]))[a]
    _check_free_fall(model, data)
    x = _simulate(mujoco, model, data, FRAMES)
    if np.abs(x[0] - pts).max() > 1e-9:
        raise SystemExit("MuJoCo's vertex order differs from the points given")
    E = k["young"]
    comments = _comments(
        mujoco,
        "flex soft cube (3D, StVK) thrown onto the ground",
        [
            f"Converted: E = {E:g} Pa, nu = {k['poisson']}, law stvk (MuJoCo's 3D flex elasticity is StVK);",
            f"ground friction {k['friction']}; contact radius {k['radius']} m as MuJoCo's flex radius.",
            f"No pliant equivalent: MuJoCo's Rayleigh damping of {k['damping'] * 1e3:g} ms and soft contact",
            f"(solref {k['solref'][0]:g} s: the vertices sink up to a few mm into the ground).",
            f"NOMINAL material below: E = {E / 5:g} Pa, deliberately 5x too soft (where a fit starts).",
        ],
    )
    body = soft_box_toml(c, E / 5, E, k["poisson"], "stvk")
    scene = scene_toml(comments, "mujoco_cube", 40, FRAMES, body)
    meta = dict(
        mujoco=mujoco,
        mjmodel=model,
        model=f"flexcomp type='direct' dim=3: pliant's soft_box mesh, {list(c['cells'])} cells x 6 tets "
        f"(Kuhn split; {len(pts)} vertices, {len(tets)} tets), side {c['size'][0]} m, centre "
        f"{list(c['centre'])} m, "
        f"initial velocity {list(c['velocity'])} m/s, rho {c['density']:g} kg/m3 lumped rho V/4 "
        f"({mass.sum():.4g} kg); "
        f"ground plane at height 0 (MuJoCo soft contact, pyramidal friction cone, condim 3)",
        material={
            "elasticity": "flex 3D StVK",
            "young_Pa": E,
            "poisson": k["poisson"],
            "rayleigh_damping_s": k["damping"],
            "friction": k["friction"],
            "contact_radius_m": k["radius"],
            "contact_solref": list(k["solref"]),
        },
        converted={"E": E, "nu": k["poisson"], "law": "stvk", "ground_friction": k["friction"]},
        nominal={"E": E / 5, "nu": k["poisson"], "law": "stvk", "ground_friction": k["friction"]},
        extra={
            "lowest_vertex_m": float(x[:, :, 1].min()),
            "ground_height_m": 0.0,
            "contact": "the cube lands at about frame 5 and slides, tips and settles on the ground",
        },
    )
    return [_track_fixture("mujoco_cube", x, np.arange(len(pts)), args, meta, scene, t0)]


# ---------------------------------------------------------------------------------------------- rope
def rope(args: argparse.Namespace) -> list[dict]:
    mujoco = _mujoco()
    t0 = time.perf_counter()
    r = ROPE
    n = r["segments"]
    pts = np.asarray(r["origin"]) + np.outer(np.linspace(0.0, r["length"], n + 1), [1.0, 0.0, 0.0])
    edges = np.stack([np.arange(n), np.arange(1, n + 1)], axis=1)
    xml = f"""
<mujoco model="rope">
  {_option()}
  <worldbody>
    <flexcomp name="rope" type="direct" dim="1" radius="{r["radius"]}" mass="{r["mass"]}"
              point="{floats(to_mj(pts))}" element="{_ints(edges)}">
      <pin id="0"/>
      <contact selfcollide="none" contype="0" conaffinity="0"/>
      <edge equality="true" solref="{floats(ROPE_EDGE_SOLREF)}"/>
      <elasticity young="{r["young"]}" poisson="{r["poisson"]}" damping="{ROPE_DAMPING}"/>
    </flexcomp>
  </worldbody>
</mujoco>
"""
    model = mujoco.MjModel.from_xml_string(xml)
    _set_flex_masses(model, np.full(n + 1, r["mass"] / (n + 1)))  # pliant: evenly over the particles
    data = mujoco.MjData(model)
    # No _check_free_fall: the edge equality constraints next to the pin act from the first step (the
    # masses are flexcomp's own even ones, so the rope never had the cloth's and cube's mismatch).
    mujoco.mj_forward(model, data)
    x = _simulate(mujoco, model, data, FRAMES)
    if np.abs(x[0] - pts).max() > 1e-9:
        raise SystemExit("MuJoCo's vertex order differs from the points given")
    seg = np.linalg.norm(np.diff(x, axis=1), axis=2) / (r["length"] / n)
    EI = r["young"] * np.pi * r["radius"] ** 4 / 4
    # Bending has no exact pliant equivalent: pliant's bend springs (over two segments) resist a bend angle
    # θ with energy k_b (l θ² / 4)² / 2, quartic, where the rod stores EI θ² / (2 l) per vertex. They are
    # matched at θ = 0.3 rad; the stretch springs stand in for MuJoCo's inextensible edges.
    h = r["length"] / n
    theta = 0.3
    k_bend = EI / h * theta**2 / (h * theta**2 / 4) ** 2
    k_stretch = 1.0e4
    comments = _comments(
        mujoco,
        "flex rope (1D: a discrete elastic rod, inextensible edges)",
        [
            "Converted (no exact equivalent): MuJoCo's edges are inextensible (edge equality constraints);",
            f"stiffness {k_stretch:g} N/m keeps pliant's segments within 1 % under the swing. Its bending",
            f"EI = E pi r^4 / 4 = {EI:.3g} N m^2 is linear in the bend angle; pliant's bend springs over two",
            f"segments are quartic, matched in energy at 0.3 rad: bend_stiffness = {k_bend:.4g} N/m.",
            f"Also no pliant equivalent: the rod's twist, its Rayleigh damping of {ROPE_DAMPING * 1e3:g} ms.",
            f"NOMINAL material below: both stiffnesses 5x too soft ({k_stretch / 5:g}, {k_bend / 5:.4g}).",
        ],
    )
    body = f"""[[objects]]
kind = "rope"
n_segments = {n}
length = {r["length"]}
origin = [{", ".join(f"{v:g}" for v in r["origin"])}]   # the pinned end [m]
direction = [1.0, 0.0, 0.0]
mass = {r["mass"]}        # [kg], evenly over the {n + 1} particles in both engines
pin = "first"

[objects.material]
stiffness = {k_stretch / 5:g}       # [N/m]; converted: {k_stretch:g}
bend_stiffness = {k_bend / 5:.4g}  # [N/m]; converted: {k_bend:.4g}
"""
    scene = scene_toml(comments, "mujoco_rope", 160, FRAMES, body)
    meta = dict(
        mujoco=mujoco,
        mjmodel=model,
        model=f"flexcomp type='direct' dim=1 (discrete elastic rod, circular section), {n} segments, "
        f"{r['length']} m from {list(r['origin'])} along +x, first vertex pinned (<pin id='0'>: free to "
        f"turn), {r['mass']} kg in equal vertex masses; edge equality constraints (solref "
        f"{list(ROPE_EDGE_SOLREF)}), no contacts",
        material={
            "elasticity": "flex 1D discrete elastic rod (bending + torsion)",
            "young_Pa": r["young"],
            "poisson": r["poisson"],
            "radius_m": r["radius"],
            "bending_EI_Nm2": EI,
            "rayleigh_damping_s": ROPE_DAMPING,
            "edges": "inextensible (equality constraints)",
        },
        converted={"stiffness": k_stretch, "bend_stiffness": k_bend, "note": "approximate; see the scene"},
        nominal={"stiffness": k_stretch / 5, "bend_stiffness": k_bend / 5},
        extra={"segment_stretch_range": [float(seg.min()), float(seg.max())]},
    )
    return [_track_fixture("mujoco_rope", x, np.arange(1, n + 1), args, meta, scene, t0)]


def main(argv: list[str] | None = None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("object", choices=["cloth", "cube", "rope", "all"])
    ap.add_argument("--tracks", type=int, default=40, help="tracked vertices (a fixed random subset)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    make = {"cloth": cloth, "cube": cube, "rope": rope}
    rows = []
    for obj in make if args.object == "all" else (args.object,):
        rows += make[obj](args)
    for row in rows:
        print(json.dumps(row), flush=True)
    return rows


if __name__ == "__main__":
    main()
