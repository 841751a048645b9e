"""``pl.twin.build_twin``: calibrated pictures → a simulated twin that predicts (``pliant twin``).

The steps, in the order of Physically Embodied Gaussians' builder and PhysTwin's processing (notes in
``../shared/REAL2SIM.md`` §1.3; the code here is pliant's own):

1. **reconstruct**: the object's volume at frame 0 by space carving from the masks (and free-space
   carving with depth where given), at a voxel spacing the cameras resolve (two pixels at the object's
   distance in the coarsest camera);
2. **splats**: Gaussians at the voxel centres trained on the first frame (colour inside the masks over a
   random background, collisions between particles, pruning by opacity); voxels whose splat is pruned go;
3. **model**: the kept voxels as cubes of six tetrahedra, a physical model on them (``--models``);
4. **observe**: every frame's point cloud from the pictures (masked depth, or the carved hull's surface);
5. **detect**: the ground (a floor in the background depth, or a flat patch where the object lands) and
   what holds the object (regions of the surface that never move);
6. **fit**: ``pl.fit.fit`` on the first ``train_fraction`` of the frames with the pictures' losses —
   the one-sided Chamfer distance to each frame's cloud (depth, or the silhouettes through the carved hull),
   PhysTwin's geometric loss — for each model; the model with the lowest validation loss (the last part
   of the training frames, predicted open loop) wins;
7. **evaluate**: the twin rolled out over every frame: Chamfer distance, mask IoU and PSNR of its splats on
   the training and the held-out frames, beside a twin that does not move.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from ..io import Observations, atomic_output, atomic_write_text
from ._detect import FixedRegions, Ground, detect_fixed, detect_ground, surface_motion
from ._scene import camera_table, twin_scene, write_mesh

if TYPE_CHECKING:
    from ..geometry import TetMesh
    from ._splats import TwinSplats

_T = TypeVar("_T")

#: Models the twin can build on the carved volume (``--models``).
TWIN_MODELS = ("fem", "mass_spring", "springs")
#: Global parameters the fit searches per model: the stiffness scale and the damping; ν is not identifiable
#: from a beam's bending (it trades against E) and the twin keeps 0.3.
TWIN_PARAMS = {
    "fem": ["E", "damping_rate"],
    "mass_spring": ["stiffness", "damping_rate"],
    "springs": ["stiffness", "damping_rate"],
}


#: Least share of a view's mask that the other views' hull must cover (consistent cameras: 1.0; MuJoCo's
#: beam and pliant's renders measure 1.0, one camera 5 cm off 0.97, 50 cm off 0.15).
MIN_AGREEMENT = 0.8
#: How many times ``max_particles`` the raw hull carved from masks alone may hold before the spacing grows
#: (the splat stage prunes the excess; MuJoCo's beam from masks alone: 5,713 of 8,362 voxels pruned).
RAW_VOXELS = 3
#: The files the twin's scenes name: (tet mesh, particles) of the fine model and of the fit's coarse stage.
GEOMETRY_FILES = {
    "fine": ("twin_mesh.vtu", "twin_particles.npy"),
    "coarse": ("twin_coarse.vtu", "twin_particles_coarse.npy"),
}
#: Fewest carved voxels that make an object (fewer: the cameras and the masks disagree).
MIN_VOXELS = 8
#: Most points per frame of the clouds the detectors read (all a 200 × 150 camera sees of a small object).
DENSE_POINTS = 100_000
#: Background depth points kept for the floor's plane fit (every k-th).
MAX_BACKGROUND = 200_000


class TwinError(ValueError):
    """Observations that cannot make a twin; the message names the file, the array and the fix."""


@dataclass
class TwinOptions:
    """Settings of :func:`build_twin` (each is a ``pliant twin`` flag).

    Attributes:
        train_fraction: Fraction of the frames the fit trains on (the rest are held out).
        models: Candidate models (:data:`TWIN_MODELS`); with several, the validation loss chooses.
        fixed: ``"auto"`` (detect), ``"none"``, or boxes ``[(centre [3], half extents [3])]`` [m].
        ground: ``"auto"`` (detect), ``"none"``, or a height [m].
        spacing: Voxel spacing [m]; None: two pixels at the object's distance in the coarsest camera (finer
            voxels than the cameras resolve are carved by nothing but the masks' aliasing).
        max_particles: Largest particle count (from masks alone the raw carved hull may hold
            :data:`RAW_VOXELS` times as many before pruning); the spacing grows until the carved volume fits.
        density: Mass density [kg/m³] of the object (only ratios of stiffness to mass are seen in motion).
        generations: Most CMA-ES generations per model.
        splat_iterations: Adam iterations of the first-frame splat training.
        seed: Seed of every random choice.
        progress: Print each step.
        resume: Continue each model's fit from its checkpoint in ``out/fit/<model>/`` where one exists (the
            steps before the fit are deterministic and run again); the twin is then the one an uninterrupted
            run makes.
        workers, ray, address: Who evaluates each CMA-ES generation of the coarse fit (``pl.fit.fit``'s
            arguments: processes, or Ray actors on the cluster at ``address``): the same twin either way.
    """

    train_fraction: float = 0.7
    models: Sequence[str] = ("fem",)
    fixed: str | list[tuple[np.ndarray, np.ndarray]] = "auto"
    ground: str | float = "auto"
    spacing: float | None = None
    max_particles: int = 3000
    density: float = 1000.0
    generations: int = 8
    splat_iterations: int = 60
    seed: int = 42
    progress: bool = True
    resume: bool = False
    workers: int | str = "auto"
    ray: bool = False
    address: str | None = None


@dataclass
class _Steps:
    """Timing and findings of each step, in order (``twin.json``'s ``steps``)."""

    progress: bool
    rows: list[dict[str, Any]] = field(default_factory=list)

    def run(self, name: str, fn: Callable[[], _T], say: Callable[[_T], str]) -> _T:
        t0 = time.perf_counter()
        value = fn()
        row = {"step": name, "seconds": time.perf_counter() - t0, "result": say(value)}
        self.rows.append(row)
        if self.progress:
            print(f"twin: {name:<12} {row['seconds']:7.1f} s  {row['result']}", flush=True)
        return value


def check_observations(obs: Observations) -> None:
    """Refuse observations a twin cannot be built from, naming the array and the fix."""
    if obs.images is None or obs.K is None or obs.world_to_camera is None:
        raise TwinError(
            f"{obs.source}: images: pliant twin needs calibrated camera videos (images [C, T, H, W, 3], K, "
            "world_to_camera)"
        )
    if obs.masks is None:
        raise TwinError(
            f"{obs.source}: masks: pliant twin needs the object's masks [C, T, H, W] (bool) to carve its "
            "volume; segment the object in every camera (e.g. with SAM) and add them"
        )


def _mask(obs: Observations, c: int, f: int) -> np.ndarray:
    m = obs.mask(c, f)
    assert m is not None  # check_observations
    return np.asarray(m) > 0.5


def reconstruct(obs: Observations, opts: TwinOptions) -> tuple[np.ndarray, float, np.ndarray | None]:
    """Carved voxel centres [M, 3] at frame 0, the spacing [m], and the background points [B, 3] of frame
    0's depth (None without depth), for the ground.

    Raises:
        TwinError: masks that no voxel satisfies in every view (the view that disagrees is named when
            :func:`pliant.geometry.view_agreement` can tell), or no depth reading on the object.
    """
    from ..geometry import backproject, carve, hull_bounds, remove_outliers, view_agreement

    assert obs.K is not None and obs.world_to_camera is not None
    C = obs.cameras
    masks = np.stack([_mask(obs, c, 0) for c in range(C)])
    depth = None if obs.depth is None else np.stack([obs.depth_m(c, 0) for c in range(C)])
    background = None
    if depth is not None:
        pts = np.concatenate(
            [backproject(depth[c], obs.K[c], obs.world_to_camera[c], masks[c]) for c in range(C)]
        )
        if len(pts) < MIN_VOXELS:
            raise TwinError(
                f"{obs.source}: depth: fewer than {MIN_VOXELS} readings inside the masks at frame 0; give "
                "depth where the object is, or leave depth out"
            )
        # Flying pixels at silhouettes would stretch the box; the carving removes what the box has too much.
        with np.errstate(over="ignore", invalid="ignore"):  # readings near 1e308 m: refused just below
            radius = 4.0 * _footprint(obs, pts.mean(axis=0))
        keep = remove_outliers(pts, radius, 8) if np.isfinite(radius) else np.zeros(len(pts), bool)
        if keep.sum() < MIN_VOXELS:
            raise TwinError(
                f"{obs.source}: depth: fewer than {MIN_VOXELS} readings inside the masks at frame 0 lie near "
                "each other (within four pixels' footprint); depth is metres along each camera's optical "
                "axis (or uint16 millimetres): check its units and the masks"
            )
        lo, hi = pts[keep].min(axis=0), pts[keep].max(axis=0)
        bg = np.concatenate(
            [backproject(depth[c], obs.K[c], obs.world_to_camera[c], ~masks[c]) for c in range(C)]
        )
        background = bg[:: max(1, len(bg) // MAX_BACKGROUND)]
    else:
        try:
            lo, hi = hull_bounds(obs.K, obs.world_to_camera, masks)
        except ValueError as exc:
            raise TwinError(f"{obs.source}: masks: {exc}") from None
    # Each view's mask against the hull the others carve (coarse voxels): a wrong pose, K or mask shows up
    # here, before it carves the object away or leaves a sliver.
    agree = view_agreement(obs.K, obs.world_to_camera, masks, lo, hi, float(np.max(hi - lo)) / 40.0)
    c = int(np.argmin(agree))
    if agree[c] < MIN_AGREEMENT:
        raise TwinError(
            f"{obs.source}: world_to_camera: camera {c} disagrees with the others at frame 0: the hull they "
            f"carve covers {agree[c]:.0%} of its mask (consistent cameras cover all of it); check its "
            "world_to_camera and K against its masks"
        )
    spacing = opts.spacing or 2.0 * _footprint(obs, (lo + hi) / 2.0)
    for _ in range(8):
        pad = 2.0 * spacing
        vox = carve(obs.K, obs.world_to_camera, masks, lo - pad, hi + pad, spacing, depth=depth)
        # From masks alone the raw hull may hold several times the object (four silhouettes leave bulges
        # that the splat stage prunes), so the cap applies to RAW_VOXELS times as many voxels there; depth
        # carves the hull tight (MuJoCo's beam: 31 of 2,493 voxels pruned), so there the cap is the cap.
        cap = opts.max_particles * (RAW_VOXELS if depth is None else 1)
        if len(vox.centres) <= cap or opts.spacing is not None:
            break
        spacing *= (len(vox.centres) / cap) ** (1.0 / 3.0) * 1.05
    if len(vox.centres) < MIN_VOXELS:
        raise TwinError(
            f"{obs.source}: masks: only {len(vox.centres)} voxels lie inside every camera's mask (and behind "
            f"its depth) at frame 0 at a spacing of {spacing * 1e3:.1f} mm; give a finer --spacing"
        )
    return vox.centres, spacing, background


def _footprint(obs: Observations, centre: np.ndarray) -> float:
    """The largest pixel footprint [m] over the cameras at ``centre``: depth over focal length."""
    assert obs.K is not None and obs.world_to_camera is not None
    z = np.abs((obs.world_to_camera[:, :3, :3] @ centre) + obs.world_to_camera[:, :3, 3])[:, 2]
    return float(np.max(z / np.minimum(obs.K[:, 0, 0], obs.K[:, 1, 1])))


def observed_clouds(
    obs: Observations, spacing: float, max_points: int = 3000
) -> tuple[np.ndarray, np.ndarray]:
    """Every frame's point cloud of the object from the pictures (:func:`pliant.geometry.frame_clouds`:
    masked depth, or the surface of each frame's carved hull at ``spacing`` [m])."""
    from ..geometry import frame_clouds

    assert obs.K is not None and obs.world_to_camera is not None and obs.masks is not None
    depth = obs.depth
    if depth is not None and depth.dtype != np.uint16:
        depth = depth.astype(np.float64)
    return frame_clouds(
        obs.K, obs.world_to_camera, obs.masks, depth=depth, spacing=spacing, max_points=max_points
    )


def build_twin(obs: Observations, out: str | Path, options: TwinOptions | None = None) -> dict[str, Any]:
    """Build a twin from calibrated pictures and write it into ``out``.

    Writes ``twin.toml`` (the fitted scene, runnable by ``pliant run`` and ``pliant view``), the files it
    names (``twin_mesh.vtu``, ``splats.ply``), ``twin.json`` (every step with its time and findings, the
    fitted values, the metrics), ``twin_nominal.toml``, ``fit/<model>/`` (each model's fit), and pictures
    (``reconstruction.png``: the particles over every camera; ``twin_fit.png``: the fit's curves).

    Args:
        obs: Observations with ``images``, ``K``, ``world_to_camera``, ``masks`` and optionally ``depth``.
        out: Output folder (created).
        options: :class:`TwinOptions` (default settings when None).

    Returns:
        The contents of ``twin.json``.

    Raises:
        TwinError: observations without images or masks, masks the cameras cannot explain; ``ray``, no Ray.
        FitError: with ``resume``, a model's fit checkpoint that is unreadable, edited or of another format
            or version (before any work), or from another scene or options (at that model's fit).
    """
    from ..fit import toml_dumps as dumps
    from ..scene import parse_scene

    opts = options or TwinOptions()
    t_start = time.perf_counter()
    check_observations(obs)
    _check_models(opts.models)
    out = Path(out)
    _check_checkpoints(out, opts)  # a bad checkpoint or Ray missing is refused now, not after the splats
    out.mkdir(parents=True, exist_ok=True)
    steps = _Steps(opts.progress)
    assert obs.K is not None and obs.world_to_camera is not None and obs.images is not None
    C, T = obs.cameras, obs.frames
    H, W = obs.images.shape[2:4]

    spacing, background, splat, tm, coarse = _geometry(steps, obs, opts, out)
    # Two samplings of the same clouds: every point, for telling still from moving (a random subset of each
    # frame would put different points there each frame, a few millimetres apart on a still surface), and
    # a subset per frame for the fit's loss.
    (dense, dense_counts), (clouds, counts) = steps.run(
        "observe",
        lambda: (observed_clouds(obs, spacing, DENSE_POINTS), observed_clouds(obs, spacing)),
        lambda r: (
            f"{int(np.median(r[0][1]))} points per frame (median) over {T} frames, "
            f"{int(np.median(r[1][1]))} of them for the fit"
        ),
    )
    ground = steps.run(
        "ground", lambda: _ground(opts, dense, dense_counts, spacing, background), lambda g: g.reason
    )
    fixed, fixed_coarse = steps.run(
        "fixed",
        lambda: _both_fixed(opts, tm, coarse, dense, dense_counts, spacing, ground, background),
        lambda r: r[0].reason,
    )
    common: dict[str, Any] = dict(
        density=opts.density,
        frame_dt=float(np.median(np.diff(obs.t))),
        frames=T - 1,
        ground=ground.height,
        splats_file="splats.ply",
        camera=camera_table(obs.K[0], obs.world_to_camera[0], H, tm.points.mean(axis=0)),
        background=_background(obs),
    )
    meshes = {"fine": (tm, fixed.boxes, spacing), "coarse": (coarse, fixed_coarse.boxes, 2.0 * spacing)}

    def scene(m: str, coarse_stage: bool) -> dict[str, Any]:
        return _model_scene(m, "coarse" if coarse_stage else "fine", meshes, common)

    scenes = {m: scene(m, coarse_stage=False) for m in opts.models}
    atomic_write_text(out / "twin_nominal.toml", dumps(scenes[opts.models[0]], "pliant twin: before the fit"))
    track_free = Observations.from_arrays(t=obs.t, cloud=clouds, cloud_count=counts, source=obs.source)
    fits = steps.run("fit", lambda: _fit_models(scenes, scene, track_free, out, opts), _fit_summary)
    from ._evaluate import evaluate, validation_loss

    n_train = min(max(2, int(round(opts.train_fraction * T))), T)
    scores = {m: validation_loss(row["cfg"], track_free, n_train) for m, row in fits.items()}
    best = min(scores, key=scores.__getitem__)
    cfg = fits[best]["cfg"]
    data = cfg.model_dump(mode="json", exclude_unset=True, exclude_none=True)
    text = dumps(data, f"pliant twin from {obs.source}: model {best}, fitted on frames 0-{n_train - 1}")
    atomic_write_text(out / "twin.toml", text)
    metrics = steps.run(
        "evaluate",
        lambda: evaluate(parse_scene(text, str(out / "twin.toml"), out), obs, clouds, counts, n_train),
        lambda r: (
            f"held-out Chamfer {r['chamfer_mm']['test']:.2f} mm (a twin that does not move: "
            f"{r['chamfer_still_mm']['test']:.2f} mm), IoU {r['iou']['test']:.3f}, PSNR "
            f"{r['psnr_db']['test']:.1f} dB"
        ),
    )
    with atomic_output(out / "twin_rollout.npz") as tmp:
        np.savez_compressed(tmp, x=metrics.pop("positions"), t=obs.t)
    from ._pictures import draw_fit, draw_reconstruction

    draw_reconstruction(out / "reconstruction.png", obs, tm.points, fixed.fixed)
    draw_fit(out / "twin_fit.png", metrics, fits, n_train)
    report: dict[str, Any] = {
        "observations": obs.source,
        "cameras": C,
        "frames": T,
        "image_size": [int(W), int(H)],
        "depth": obs.depth is not None,
        "train_frames": [0, n_train - 1],
        "spacing_m": spacing,
        "particles": len(tm.points),
        "tetrahedra": len(tm.tets),
        "splats": splat.summary(),
        "ground": ground.summary(),
        "fixed": fixed.summary(),
        "models": _model_rows(fits, scores),
        "model": best,
        "metrics": metrics,
        "steps": steps.rows,
        "wall_time": time.perf_counter() - t_start,
        "files": list(TWIN_FILES),
    }
    atomic_write_text(out / "twin.json", json.dumps(report, indent=2, default=_json) + "\n")
    return report


def _check_checkpoints(out: Path, opts: TwinOptions) -> None:
    """With ``resume``, read each existing checkpoint ``out/fit/<model>/``: a bad one raises FitError; with
    ``ray``, Ray missing raises TwinError."""
    from .._extras import missing_ray
    from ..fit import CHECKPOINT_FILE, read_checkpoint

    if opts.ray and missing_ray():
        raise TwinError(missing_ray())
    for m in opts.models if opts.resume else ():
        if (out / "fit" / m / CHECKPOINT_FILE).exists():
            read_checkpoint(out / "fit" / m / CHECKPOINT_FILE)


def _check_models(models: Sequence[str]) -> None:
    """The twin builds the models of :data:`TWIN_MODELS` (at least one)."""
    bad = [m for m in models if m not in TWIN_MODELS]
    if bad or not models:
        raise TwinError(
            f"--models: the twin builds {', '.join(TWIN_MODELS)}; got {','.join(models) or 'none'}"
        )


#: The files a twin's folder holds besides twin.json, as twin.json lists them.
TWIN_FILES = (
    *("twin.toml", "twin_mesh.vtu", "twin_coarse.vtu", "splats.ply", "reconstruction.png", "twin_fit.png"),
    "twin_rollout.npz",
)


def _geometry(
    steps: _Steps, obs: Observations, opts: TwinOptions, out: Path
) -> tuple[float, np.ndarray | None, TwinSplats, TetMesh, TetMesh]:
    """Steps "reconstruct", "splats" and "model": (voxel spacing [m], frame 0's background points [B, 3]
    from depth or None, the splats, the fine and the coarse tet mesh), the meshes written into ``out``."""
    from ..geometry import coarsen_voxels, largest_piece, voxel_tets

    C = obs.cameras
    centres, spacing, background = steps.run(
        "reconstruct",
        lambda: reconstruct(obs, opts),
        lambda r: (
            f"{len(r[0])} voxels of {r[1] * 1e3:.1f} mm carved from {C} masks"
            + (" and depth" if r[2] is not None else "")
        ),
    )
    splat = steps.run("splats", lambda: _splats(obs, centres, spacing, opts, out / "splats.ply"), str)
    tm, coarse = steps.run(
        "model",
        lambda: (
            largest_piece(voxel_tets(splat.particles, spacing, dual=True)),
            largest_piece(voxel_tets(coarsen_voxels(splat.particles, spacing), 2.0 * spacing, dual=True)),
        ),
        lambda m: (
            f"{len(m[0].points)} particles, {len(m[0].tets)} tetrahedra (the fit's coarse stage: "
            f"{len(m[1].points)} particles)"
        ),
    )
    for key, m in (("fine", tm), ("coarse", coarse)):
        write_mesh(out / GEOMETRY_FILES[key][0], m.points, m.tets)
        np.save(out / GEOMETRY_FILES[key][1], m.points)
    return spacing, background, splat, tm, coarse


def _both_fixed(
    opts: TwinOptions,
    tm: TetMesh,
    coarse: TetMesh,
    dense: np.ndarray,
    dense_counts: np.ndarray,
    spacing: float,
    ground: Ground,
    background: np.ndarray | None,
) -> tuple[FixedRegions, FixedRegions]:
    """Step "fixed": the fixed regions of the fine and of the coarse model (spacing 2 · ``spacing`` [m])."""
    # The surface's motion depends on the clouds alone: measured once for the fine and the coarse model.
    surface = surface_motion(dense, dense_counts) if opts.fixed == "auto" else None
    seen = (dense, dense_counts)
    return (
        _fixed(opts, tm.points, *seen, spacing, ground, background, None, surface),
        _fixed(opts, coarse.points, *seen, 2.0 * spacing, ground, background, spacing, surface),
    )


def _model_scene(
    m: str,
    key: str,
    meshes: dict[str, tuple[TetMesh, list[tuple[np.ndarray, np.ndarray]], float]],
    common: dict[str, Any],
) -> dict[str, Any]:
    """The scene table of model ``m`` on the ``key`` ("fine" or "coarse") mesh of ``meshes`` (mesh, fixed
    boxes, spacing [m]), with the settings ``common`` to every model."""
    mesh, boxes, h = meshes[key]
    return twin_scene(
        geometry_file=GEOMETRY_FILES[key][m == "springs"],
        model=m,
        spacing=h,
        boxes=boxes,
        centre=mesh.points.mean(axis=0),
        particles=len(mesh.points),
        **common,
    )


def _fit_models(
    scenes: dict[str, dict[str, Any]],
    scene: Callable[[str, bool], dict[str, Any]],
    track_free: Observations,
    out: Path,
    opts: TwinOptions,
) -> dict[str, dict[str, Any]]:
    """Step "fit": each model fitted on its coarse scene, then its values refined on the fine one; per
    model its values, the coarse ones, the fine scales and their search, the fitted config and the report."""
    from ..fit import apply_globals, fit
    from ..fit import toml_dumps as dumps
    from ..scene import parse_scene
    from ._fit import refine_on_fine

    rows = {}
    for m, data in scenes.items():
        small = parse_scene(dumps(scene(m, True)), f"{out} (coarse {m})", out)
        rep = fit(
            small,
            track_free,
            out / "fit" / m,
            resume=opts.resume and (out / "fit" / m / "fit_checkpoint.json").exists(),
            params=TWIN_PARAMS[m],
            per_element="none",
            train_fraction=opts.train_fraction,
            generations=opts.generations,
            seed=opts.seed,
            progress=opts.progress,
            video=False,
            workers=opts.workers,
            ray=opts.ray,
            address=opts.address,
        )
        coarse_values = {k: p["value"] for k, p in rep["params"].items()}
        cfg = parse_scene(dumps(data), f"{out / 'twin_nominal.toml'} ({m})", out)
        search = refine_on_fine(cfg, track_free, coarse_values, train_fraction=opts.train_fraction)
        rows[m] = {
            "values": search.values,
            "coarse_values": coarse_values,
            "scale": search.scales,
            "scale_history": search.history,
            "cfg": apply_globals(cfg, search.values),
            "report": rep,
        }
    return rows


def _fit_summary(fits: dict[str, dict[str, Any]]) -> str:
    """The fit step's line: each model's values and the fine scales of its coarse values."""
    return "; ".join(
        f"{m}: "
        + ", ".join(f"{k} {v:.4g}" for k, v in row["values"].items())
        + " (coarse x "
        + ", ".join(f"{v:.3g}" for v in row["scale"].values())
        + ")"
        for m, row in fits.items()
    )


def _model_rows(fits: dict[str, dict[str, Any]], scores: dict[str, float]) -> dict[str, dict[str, Any]]:
    """twin.json's ``models``: each model's values, search and validation loss."""
    return {
        m: {
            "values": row["values"],
            "coarse_values": row["coarse_values"],
            "fine_scales": row["scale"],
            "scale_search": row["scale_history"],
            "validation_loss": scores[m],
            "coarse_fit_seconds": row["report"]["wall_time"],
        }
        for m, row in fits.items()
    }


def _background(obs: Observations) -> list[float]:
    """The footage's median colour outside the masks at frame 0 (the splats' ``background``, so that the
    twin's videos look like the footage)."""
    cols = [obs.image(c, 0)[~_mask(obs, c, 0)] for c in range(obs.cameras)]
    px = np.concatenate(cols) if any(len(c) for c in cols) else np.ones((1, 3))
    return [float(v) for v in np.median(px, axis=0)]


def _json(v: object) -> object:
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    return str(v)


def _splats(
    obs: Observations, centres: np.ndarray, spacing: float, opts: TwinOptions, ply: Path
) -> TwinSplats:
    from ._splats import train_splats

    return train_splats(obs, centres, spacing, ply, iterations=opts.splat_iterations, seed=opts.seed)


def _ground(
    opts: TwinOptions, clouds: np.ndarray, counts: np.ndarray, spacing: float, background: np.ndarray | None
) -> Ground:
    if opts.ground == "auto":
        return detect_ground(clouds, counts, spacing=spacing, background=background)
    if opts.ground == "none":
        return Ground(None, reason="--ground none: no ground")
    h = float(opts.ground)
    return Ground(h, reason=f"--ground {h:g}: a ground at y = {h:g} m, as given")


def _fixed(
    opts: TwinOptions,
    particles: np.ndarray,
    clouds: np.ndarray,
    counts: np.ndarray,
    spacing: float,
    ground: Ground,
    background: np.ndarray | None,
    resolution: float | None = None,
    surface: tuple[np.ndarray, np.ndarray] | None = None,
) -> FixedRegions:
    n = len(particles)
    if opts.fixed == "auto":
        # Depth points sit on the surface to within the readings' resolution; carved hulls move in whole
        # voxels (of the observations' spacing, ``resolution``, which the coarse model does not change).
        tol = (0.25 if background is not None else 0.5) * (resolution or spacing)
        return detect_fixed(
            particles, clouds, counts, tol=tol, spacing=spacing, ground=ground.height, surface=surface
        )
    if opts.fixed == "none":
        return FixedRegions(np.zeros(n, bool), [], 0.0, np.zeros(0), "--fixed none: nothing is held")
    assert not isinstance(opts.fixed, str)  # "auto" and "none" are handled above
    boxes = [(np.asarray(c, float), np.asarray(h, float)) for c, h in opts.fixed]
    inside = np.zeros(n, bool)
    for c, h in boxes:
        inside |= np.all(np.abs(particles - c) <= h, axis=1)
    return FixedRegions(
        inside, boxes, 0.0, np.zeros(0), f"--fixed: {int(inside.sum())} particles in the given boxes"
    )


__all__ = ["TWIN_MODELS", "TwinError", "TwinOptions", "build_twin", "check_observations"]
