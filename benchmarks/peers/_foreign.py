"""Shared helpers of the cross-engine fixture generators (``observe_mujoco.py``, ``observe_newton.py``):
noisy, occluded tracks, OpenCV cameras, and writing a fixture (observation NPZ, truth NPZ, JSON sidecar,
pliant scene TOML) without pliant.

Kept free of pliant imports: the generators run in the peers' venv (README.md). The files follow pliant's
observation contract (``pliant/io/_observations.py``): ``t`` [T], ``points`` [T, K, 3] (NaN where unseen),
``visible`` [T, K]; image fixtures add ``images`` [C, T, H, W, 3] uint8, ``K`` [C, 3, 3], ``world_to_camera``
[C, 4, 4] (OpenCV axes) and ``masks`` [C, T, H, W]. Everything is in pliant's axes: metres, y up.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

FPS = 30.0
NOISE = 0.0015  # standard deviation of the track noise per axis [m]
OCCLUDED = 0.3  # fraction of the tracks that go unseen for one stretch
OCCLUSION_FRAMES = (6, 20)  # shortest and longest unseen stretch [frames]
#: The soft box both engines throw onto the ground (pliant's soft_box: Kuhn tets, centre, [m], [m/s],
#: [kg/m³]); its bottom starts 0.35 m above the ground.
THROWN_BOX = dict(
    cells=(4, 4, 4), size=(0.2, 0.2, 0.2), centre=(0.0, 0.45, 0.0), velocity=(1.2, -1.0, 0.0), density=500.0
)
#: Where the fixtures go (relative to this file): the repository's tests/data/foreign/.
FIXTURES = Path(__file__).resolve().parents[2] / "tests" / "data" / "foreign"


def noisy_tracks(
    x: np.ndarray,
    candidates: np.ndarray,
    tracks: int,
    rng: np.random.Generator,
    noise: float = NOISE,
    occluded: float = OCCLUDED,
    stretch: tuple[int, int] = OCCLUSION_FRAMES,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict]]:
    """Tracks of a random subset of the vertices, with Gaussian noise and one unseen stretch on some.

    Args:
        x: true vertex positions [T, N, 3] [m].
        candidates: vertex indices that may be tracked (e.g. the free ones).
        tracks: number of tracks K (at most ``candidates.size``).
        rng: random generator (its seed is recorded in the sidecar).
        noise: standard deviation of the isotropic Gaussian noise [m].
        occluded: fraction of the tracks that get one unseen stretch.
        stretch: (shortest, longest) unseen stretch [frames]; it never covers frame 0, so every track is
            bound to its particle at frame 0.

    Returns:
        (points [T, K, 3] with NaN where unseen, visible [T, K] bool, vertex index of each track [K],
        the unseen stretches as ``{"track", "first", "last"}`` dicts).
    """
    T = x.shape[0]
    pick = np.sort(rng.choice(candidates, size=min(tracks, candidates.size), replace=False))
    pts = x[:, pick] + rng.normal(0.0, noise, size=(T, pick.size, 3))
    visible = np.ones((T, pick.size), bool)
    gaps = []
    for k in np.sort(rng.choice(pick.size, size=int(round(occluded * pick.size)), replace=False)):
        n = int(rng.integers(stretch[0], stretch[1] + 1))
        first = int(rng.integers(1, T - n + 1))
        visible[first : first + n, k] = False
        gaps.append({"track": int(k), "first": first, "last": first + n - 1})
    pts[~visible] = np.nan
    return pts, visible, pick, gaps


def look_at(eye: np.ndarray, target: np.ndarray, up: tuple = (0.0, 1.0, 0.0)) -> np.ndarray:
    """OpenCV world → camera transform [4, 4] (x right, y down, z forward) of a camera at ``eye`` looking at
    ``target`` (pliant axes, metres); the same construction as ``pliant.gaussians.Camera.look_at``."""
    eye = np.asarray(eye, np.float64)
    f = np.asarray(target, np.float64) - eye
    f /= np.linalg.norm(f)
    x = np.cross(f, np.asarray(up, np.float64))
    x /= np.linalg.norm(x)
    y = np.cross(f, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, f])
    T[:3, 3] = -T[:3, :3] @ eye
    return T


def intrinsics(fovy_deg: float, width: int, height: int) -> np.ndarray:
    """OpenCV K [3, 3] of a symmetric OpenGL frustum of vertical field of view ``fovy_deg``: pixel centres at
    integers (pliant's convention), so the principal point is ((W − 1)/2, (H − 1)/2)."""
    f = 0.5 * height / np.tan(0.5 * np.radians(fovy_deg))
    return np.array([[f, 0.0, 0.5 * (width - 1)], [0.0, f, 0.5 * (height - 1)], [0.0, 0.0, 1.0]])


def write_fixture(
    name: str,
    arrays: dict[str, np.ndarray],
    meta: dict,
    *,
    truth: np.ndarray | None = None,
    scene: str | None = None,
    out: Path = FIXTURES,
) -> list[Path]:
    """Write ``NAME.npz`` (compressed), ``NAME.json`` (the sidecar), and optionally ``NAME_truth.npz`` (every
    vertex, noise-free, all visible: an observation file for held-out evaluation) and ``NAME.toml``.

    Args:
        name: fixture name.
        arrays: the observation arrays (pliant's names only: the loader refuses unknown arrays).
        meta: the sidecar's content (JSON-serialisable).
        truth: true vertex positions [T, N, 3] [m], stored as float32.
        scene: pliant scene TOML text.
        out: output folder.

    Returns:
        The paths written.
    """
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / f"{name}.npz", out / f"{name}.json"]
    np.savez_compressed(paths[0], **arrays)
    if truth is not None:
        paths.append(out / f"{name}_truth.npz")
        t = arrays["t"][: truth.shape[0]]
        np.savez_compressed(
            paths[-1], t=t, points=truth.astype(np.float32), visible=np.ones(truth.shape[:2], bool)
        )
        meta = {**meta, "truth": paths[-1].name}
    if scene is not None:
        paths.append(out / f"{name}.toml")
        paths[-1].write_text(scene)
        meta = {**meta, "scene": paths[-1].name}
    paths[1].write_text(json.dumps(meta, indent=1) + "\n")
    return paths


#: pliant.geometry.box_tets' Kuhn split of a cell (corner id = dx + 2 dy + 4 dz).
_KUHN = np.array([[0, 1, 3, 7], [0, 2, 6, 7], [0, 4, 5, 7], [0, 1, 7, 5], [0, 2, 7, 3], [0, 4, 7, 6]])


def box_tets(cells, size, origin):
    """pliant.geometry.box_tets without pliant: points [(nx+1)(ny+1)(nz+1), 3], tets [6 nx ny nz, 4]."""
    nx, ny, nz = cells
    axes = [np.linspace(0.0, size[d], cells[d] + 1) for d in range(3)]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    points = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1) + np.asarray(origin)
    k, j, i = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
    base = (i + (nx + 1) * (j + (ny + 1) * k)).reshape(-1, 1)
    corner = np.array(
        [dx + (nx + 1) * (dy + (ny + 1) * dz) for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)]
    )
    return points, (base + corner[None, :])[:, _KUHN].reshape(-1, 4).astype(np.int32)


def cloth_mesh(c: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """pliant's cloth grid: points [(n+1)², 3] (vertex (i, j) at j (n+1) + i, i along x, j along z),
    triangles (diagonals alternating as pliant's), texture coordinates [(n+1)², 2] and the two pinned
    vertices (pliant's ``top-corners``: largest z)."""
    n = c["n"]
    j, i = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    i, j = i.ravel(), j.ravel()
    h = c["size"] / n
    pts = np.asarray(c["origin"], np.float64) + np.stack([i * h, np.zeros_like(i, float), j * h], axis=1)
    tris = []
    for jj in range(n):
        for ii in range(n):
            a = jj * (n + 1) + ii
            b, d, e = a + 1, a + n + 1, a + n + 2
            # pliant's diagonals: (i, j)-(i+1, j+1) where i + j is even; normals along +y as pliant's "xz".
            tris += [[a, d, e], [a, e, b]] if (ii + jj) % 2 == 0 else [[a, d, b], [b, d, e]]
    uv = np.stack([i, j], axis=1) / n
    return pts, np.asarray(tris, np.int64), uv, np.array([n * (n + 1), n * (n + 1) + n])


def lumped_by_area(pts: np.ndarray, tris: np.ndarray, total: float) -> np.ndarray:
    """Masses [kg] lumped by triangle area (a third on each corner), summing to ``total``, as pliant's."""
    p = pts[tris]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    m = np.zeros(len(pts))
    np.add.at(m, tris.ravel(), np.repeat(area / 3.0, 3))
    return m * total / m.sum()


def fixture_meta(
    name: str, engine: str, t: np.ndarray, pick: np.ndarray, gaps: list[dict], seed: int, command: str
) -> dict:
    """The sidecar fields every track fixture has (the generators add the model and materials).

    Args:
        name: fixture name.
        engine: engine and version, e.g. ``"mujoco 4.0.0"``.
        t: observation times [s].
        pick: the vertex each track follows [K].
        gaps: the unseen stretches of :func:`noisy_tracks`.
        seed: the random seed of the tracks.
        command: how to regenerate the fixture.
    """
    return {
        "fixture": name,
        "data": "SYNTHETIC: another engine's simulation standing in for real measurements",
        "engine": engine,
        "frames": int(t.size),
        "fps": FPS,
        "tracks": int(pick.size),
        "track_vertex": pick.tolist(),
        "noise_std_m": NOISE,
        "occlusion": {
            "fraction_of_tracks": OCCLUDED,
            "stretch_frames": list(OCCLUSION_FRAMES),
            "frame0_always_visible": True,
            "stretches": gaps,
        },
        "seed": seed,
        "command": command,
    }


def scene_toml(comments: list[str], name: str, substeps: int, frames: int, body: str) -> str:
    """A fixture's pliant scene: ``comments`` (where it comes from, the conversion), a float64 scene at the
    fixtures' frame rate, the objects (and ground) of ``body``, and undamped symplectic Euler."""
    head = "".join(f"# {line}\n" for line in comments)
    return f"""{head}[scene]
name = "{name}"
frame_dt = {1.0 / FPS!r}
substeps = {substeps}
frames = {frames}
dtype = "float64"

{body}
[solver]
integrator = "SymplecticEuler"
damping_rate = 0.0
"""


def _vec(v) -> str:
    return "[" + ", ".join(f"{a:g}" for a in v) + "]"


def cloth_toml(c: dict, Et: float, nu: float, Et_converted: float, pinned: str) -> str:
    """The ``[[objects]]`` table of the cloth ``c`` (n, size, origin, mass) with membrane ``Et`` [N/m]."""
    return f"""[[objects]]
kind = "cloth"
nx = {c["n"]}
ny = {c["n"]}
size = {c["size"]}
origin = {_vec(c["origin"])}
plane = "xz"
mass = {c["mass"]}          # [kg], lumped by area in both engines
pin = "top-corners"  # the two corners of largest z, {pinned}

[objects.material]
Et = {Et:g}   # [N/m]; converted: {Et_converted:.4g}
nu = {nu:g}
"""


def soft_box_toml(c: dict, E: float, E_converted: float, nu: float, law: str | None) -> str:
    """The ``[[objects]]`` table of the soft box ``c`` (cells, size, centre, density, velocity, radius,
    friction) with Young's modulus ``E`` [Pa], and its ground (height 0)."""
    law_line = "" if law is None else f'law = "{law}"\n'
    return f"""[[objects]]
kind = "soft_box"
model = "fem"
cells = {_vec(c["cells"])}
size = {_vec(c["size"])}
origin = {_vec(c["centre"])}      # centre [m]
density = {c["density"]:g}               # [kg/m³], lumped rho V / 4 in both engines
velocity = {_vec(c["velocity"])}  # [m/s]
particle_radius = {c["radius"]}

[objects.material]
E = {E:g}        # [Pa]; converted: {E_converted:g}
nu = {nu}
{law_line}
[ground]
height = 0.0
friction = {c["friction"]}
"""


def floats(a: np.ndarray) -> str:
    """Numbers as a space-separated MJCF attribute."""
    return " ".join(f"{v:.9g}" for v in np.asarray(a, np.float64).ravel())
