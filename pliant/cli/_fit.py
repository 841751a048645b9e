"""``pliant fit`` (fit a scene to observed motion) and ``pliant observe`` (synthetic observations)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from ._common import (
    WORKERS_HELP,
    CliError,
    _positive_float,
    _positive_int,
    _sub,
    _workers,
    add_force,
    add_ray,
    check_ray,
)
from ._run import _load

if TYPE_CHECKING:
    from ..io import Observations
    from ..scene import Scene, SceneConfig
    from ._common import Subparsers


def add_parsers(sub: Subparsers) -> None:
    """Register ``fit`` and ``observe`` on the ``pliant`` sub-parsers."""
    _add_fit_parser(sub)
    _add_observe_parser(sub)


def _add_fit_parser(sub: Subparsers) -> None:
    """``pliant fit``'s options."""
    f = _sub(
        sub,
        "fit",
        "fit a scene's parameters to observed motion (observation NPZ)",
        "pliant observe fit_rope --out obs.npz --set 'objects[0].material.stiffness=480'   # the 'real' rope",
        "pliant fit fit_rope obs.npz --out fit/                        # the material, both stages",
        "pliant fit cloth obs.npz --out fit/ --params stiffness --per-element stiffness",
        "pliant run fit/fitted.toml                                    # the fitted scene",
    )
    f.add_argument("scene", help="a scene .toml file or a built-in scene name")
    f.add_argument(
        "obs",
        metavar="OBS.npz",
        help="observations: t [T], points [T, K, 3], ... and/or camera images [C, T, H, W, 3] with K and "
        "world_to_camera (a photometric fit)",
    )
    f.add_argument("--out", required=True, help="output folder: fitted.toml, fit.json, fit.png, fit.mp4")
    f.add_argument(
        "--params",
        metavar="NAME,...",
        help="global parameters for CMA-ES (default, printed with bounds and why: stiffness or Et, "
        "damping_rate, damping / E, nu, damping_rate / compliance, damping_rate, plus ground friction and "
        "restitution when the tracks reach the ground; 'none' for no global stage)",
    )
    f.add_argument(
        "--models",
        metavar="MODEL,...",
        help="fit each candidate model (mass_spring, fem, pbd) of the same geometry into OUT/<model>/ and "
        "print their held-out errors side by side (OUT/models.json)",
    )
    f.add_argument(
        "--per-element",
        metavar="NAME",
        default="auto",
        help="gradient stage on stiffness, E or compliance (default auto: the model's own, kept only where "
        "it lowers the validation error, not with --params none; none: no per-element stage)",
    )
    f.add_argument("--train-fraction", type=_positive_float, default=0.7, help="frames to train on (0.7)")
    f.add_argument(
        "--iterations",
        type=_positive_int,
        help="CMA-ES generations (a cap: 40; it stops once converged) and gradient epochs (20)",
    )
    f.add_argument(
        "--optimizer",
        choices=("adam", "lbfgs"),
        help="gradient stage (default: lbfgs for camera images, adam for tracks)",
    )
    f.add_argument("--horizon", type=_positive_int, default=1, help="frames per tape, 0: whole rollout (1)")
    f.add_argument(
        "--shooting",
        type=_positive_int,
        metavar="FRAMES",
        help="multiple shooting: restart the training runs from the observed state every FRAMES frames "
        "(teacher forcing); 0: open loop (default: 10 where tracks cover >= 90 %% of the free particles "
        "over >= 30 training frames, else 0; docs/fit.md)",
    )
    f.add_argument("--lr", type=_positive_float, default=0.01, help="Adam step in log-scale units (0.01)")
    f.add_argument(
        "--smoothness",
        type=float,
        default=0.0,
        help="total-variation prior on per-element values over neighbours (0; e.g. 1e-4)",
    )
    f.add_argument(
        "--validation",
        type=float,
        default=0.2,
        help="last fraction of the training frames that decides whether per-element values are kept (0.2)",
    )
    f.add_argument("--seed", type=int, default=42, help="CMA-ES seed (42)")
    f.add_argument("--workers", type=_workers, default="auto", help=WORKERS_HELP + " (auto)")
    add_ray(f)
    f.add_argument("--device", help="cpu or cuda:N (default: the scene's)")
    f.add_argument("--dtype", choices=("float32", "float64"), help="override [scene] dtype")
    f.add_argument("--no-video", action="store_true", help="skip fit.mp4")
    f.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="PATH=VALUE",
        dest="overrides",
        help="override a scene field first, as in `pliant run` (repeatable)",
    )
    f.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    add_force(f, "; and run an image fit whose memory estimate (printed in the plan) exceeds it")
    f.add_argument(
        "--resume",
        action="store_true",
        help="continue a stopped or killed fit from OUT/fit_checkpoint.json (written after every CMA-ES "
        "generation and gradient iteration; the same scene, observations and options): the same fitted.toml "
        "as a fit never stopped",
    )


def _add_observe_parser(sub: Subparsers) -> None:
    """``pliant observe``'s options."""
    o = _sub(
        sub,
        "observe",
        "synthetic observations (tracks) of a simulated scene",
        "pliant observe fit_rope --out obs.npz",
        "pliant observe cloth --out obs.npz --tracks 60 --noise 0.001 --dropout 0.3 --seed 1",
        "pliant observe cloth --out obs.npz --cameras 3 --image-size 96x72   # camera videos, no tracks",
    )
    o.add_argument("scene", help="a scene .toml file or a built-in scene name")
    o.add_argument("--out", required=True, metavar="OBS.npz", help="observation file to write")
    o.add_argument(
        "--tracks", type=_positive_int, help="tracked particles K (60; none by default with --cameras)"
    )
    o.add_argument("--noise", type=float, default=0.0, help="Gaussian noise σ per coordinate [m] (0)")
    o.add_argument("--dropout", type=float, default=0.0, help="probability a track is hidden at a frame (0)")
    o.add_argument("--seed", type=int, default=0, help="random seed (0)")
    o.add_argument(
        "--frames", type=_positive_int, help="observed frames after frame 0 (default: the scene's)"
    )
    o.add_argument("--cloud", action="store_true", help="also write every particle as a depth cloud")
    o.add_argument("--unbound", action="store_true", help="omit `particle` (fit binds tracks by distance)")
    o.add_argument(
        "--cameras",
        type=_positive_int,
        help="also render camera videos from this many cameras (images, K, world_to_camera): the object as "
        "the scene's [gaussians] splats, else Gaussians generated from its surface",
    )
    o.add_argument("--image-size", default="96x72", metavar="WxH", help="video size with --cameras (96x72)")
    o.add_argument("--image-noise", type=float, default=0.0, help="pixel noise σ in [0, 1] units (0)")
    o.add_argument("--masks", action="store_true", help="with --cameras: also write masks (rendered alpha)")
    o.add_argument("--uint8", action="store_true", help="with --cameras: 8-bit images (default float32)")
    o.add_argument("--device", help="cpu or cuda:N (default: the scene's)")
    o.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="PATH=VALUE",
        dest="overrides",
        help="override a scene field first, as in `pliant run` (repeatable)",
    )
    o.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    add_force(o)


def cmd_observe(args: argparse.Namespace) -> int:
    """``pliant observe``: simulate and write an observation NPZ."""
    from dataclasses import replace

    from ..fit import observe
    from ..scene import build_scene

    cfg = _load(args.scene, args.overrides, force=args.force)
    scene = build_scene(cfg, device=args.device)
    scene.prebuild_kernels()  # a built-in scene's first kernels compile on both cores meanwhile
    frames = None if args.frames is None else args.frames + 1
    obs: Observations | None = None
    if args.cameras is None or args.tracks is not None:
        obs = observe(
            scene,
            frames=frames,
            tracks=60 if args.tracks is None else args.tracks,
            noise=args.noise,
            dropout=args.dropout,
            seed=args.seed,
            cloud=args.cloud,
            progress=not args.quiet,
        )
        if args.unbound:
            obs = replace(obs, particle=None)
    if args.cameras is not None:
        obs = _observe_images(scene, frames, obs, args)
    assert obs is not None  # tracks, camera videos or both were observed above
    path = obs.save(args.out)
    what = f"{obs.tracks} tracks ({100 * obs.visible.mean():.0f}% visible)" if obs.tracks else "no tracks"
    if obs.cameras and obs.images is not None:
        h, w = obs.images.shape[2:4]
        what += f", {obs.cameras} camera videos of {w}x{h} px"
    print(f"wrote {path}: {obs.frames} frames, {what}")
    return 0


def _observe_images(
    scene: Scene, frames: int | None, tracks: Observations | None, args: argparse.Namespace
) -> Observations:
    """``pliant observe --cameras``: render camera videos (with the tracks, if any, kept in the file)."""
    from ..fit import observe_images

    try:
        w, h = (int(v) for v in args.image_size.lower().split("x"))
    except ValueError:
        raise CliError(
            f"--image-size: expected WxH in pixels such as 96x72, got {args.image_size!r}"
        ) from None
    try:
        return observe_images(
            scene,
            frames=frames,
            cameras=args.cameras,
            image_size=(w, h),
            noise=args.image_noise,
            masks=args.masks,
            uint8=args.uint8,
            seed=args.seed,
            tracks=tracks,
            progress=not args.quiet,
        )
    except ValueError as exc:
        raise CliError(str(exc)) from None


def cmd_fit(args: argparse.Namespace) -> int:
    """``pliant fit``: both stages and the four outputs."""
    from ..fit import FitError, fit
    from ..io import Observations

    if not 0.0 < args.train_fraction <= 1.0:
        raise CliError(f"--train-fraction: expected a number in (0, 1], got {args.train_fraction}")
    check_ray(args)
    cfg = _load(args.scene, args.overrides, force=args.force)
    obs = Observations.load(args.obs)
    params = None
    if args.params is not None:
        params = (
            [] if args.params.strip() == "none" else [p.strip() for p in args.params.split(",") if p.strip()]
        )
    n = args.iterations
    out = Path(args.out)
    if args.models is not None:
        return _fit_models(args, cfg, obs, params, out)
    try:
        report = fit(
            cfg,
            obs,
            out,
            params=params,
            # "auto" follows the global stage: --params none alone still means nothing to fit
            per_element=None if params == [] and args.per_element == "auto" else args.per_element,
            train_fraction=args.train_fraction,
            generations=40 if n is None else n,  # a cap: CMA-ES stops once converged
            epochs=20 if n is None else n,
            # L-BFGS for images: a few whole-rollout gradients of one smooth loss (docs/gaussians.md)
            optimizer=args.optimizer or ("lbfgs" if obs.images is not None else "adam"),
            horizon=None if args.horizon == 0 else args.horizon,
            shooting=args.shooting,
            lr=args.lr,
            smoothness=args.smoothness,
            validation=args.validation,
            seed=args.seed,
            device=args.device,
            dtype=args.dtype,
            progress=not args.quiet,
            video=not args.no_video,
            force=args.force,
            resume=args.resume,
            workers=args.workers,
            ray=args.ray,
            address=args.address,
        )
    except FitError as exc:
        raise CliError(str(exc)) from None
    except KeyboardInterrupt:
        print(
            f"interrupted: the best parameters so far are in {out}; continue with the same command and "
            "--resume",
            flush=True,
        )
        raise
    for name, p in report["params"].items():
        print(f"{name}: {p['value']:.6g} (nominal {p['nominal']:.6g})")
    for line in _gate_lines(report):
        print(line)
    if "appearance" in report:
        a = report["appearance"]
        print(f"appearance (frame 0): PSNR {a['psnr_before_db']:.1f} -> {a['psnr_after_db']:.1f} dB")
    if report.get("psnr_nominal_train_db") is not None:
        print(
            f"PSNR at the start of the physics fit: {report['psnr_nominal_train_db']:.1f} dB (nominal motion)"
        )
    if report.get("psnr_fitted_test_db") is not None:
        print(
            f"PSNR on the held-out frames: {report['psnr_fitted_test_db']:.1f} dB "
            f"(nominal motion {report['psnr_nominal_test_db']:.1f} dB)"
        )
    if "photometric" in report:
        ph = report["photometric"]["fitted"]
        test = "n/a" if ph["loss_test"] is None else f"{ph['loss_test']:.4g}"
        print(f"image loss: train {ph['loss_train']:.4g}, test {test} (mean squared error per pixel)")
        if "psnr_test_db" in ph:  # without masks the loss is the colour MSE: the PSNR the README quotes
            psnr = report["photometric"]

            def db(v: float | None) -> str:
                return "n/a" if v is None else f"{v:.1f} dB"

            print(
                f"PSNR: train {db(ph.get('psnr_train_db'))}, test {db(ph.get('psnr_test_db'))} (nominal: "
                f"{db(psnr['nominal'].get('psnr_train_db'))}, {db(psnr['nominal'].get('psnr_test_db'))})"
            )
    e, e0 = report["error"], report["error_nominal"]

    def mm(v: float | None) -> str:
        return "n/a" if v is None else f"{1e3 * v:.3g} mm"

    if obs.tracks:  # an image-only file has no tracks to measure
        print(
            f"track error: train {mm(e['train'])}, test {mm(e['test'])} "
            f"(nominal: {mm(e0['train'])}, {mm(e0['test'])})"
        )
    print(f"wrote {out / 'fitted.toml'}, fit.json, fit.png" + ("" if args.no_video else ", fit.mp4"))
    print(f"fitted in {report['wall_time']:.1f} s")
    return 0


def _gate_lines(report: dict) -> list[str]:
    """The summary's lines on the global stage's validation gate and identifiability (fit.json's
    ``global_validation`` and ``identifiability``; none when there was no global stage)."""
    from ..fit import describe_identifiability as describe

    gv, ident = report.get("global_validation"), report.get("identifiability")
    lines = []
    if gv is not None:
        what = "fitted values kept" if gv["kept"] else "KEPT THE SCENE'S VALUES"
        lines.append(f"global stage: {what}: {gv['why']}")
    if ident is not None:
        lines += describe(ident)
    mass = report.get("mass_distribution")
    if mass is not None:
        lines.append(f"mass distribution: {mass['name']}: {mass['reason']}")
    return lines


def _fit_models(
    args: argparse.Namespace, cfg: SceneConfig, obs: Observations, params: list[str] | None, out: Path
) -> int:
    """``pliant fit --models a,b``: each candidate model fitted, held-out errors side by side."""
    from ..fit import FitError, compare_models, models_table

    n = args.iterations
    try:
        report = compare_models(
            cfg,
            obs,
            [m.strip() for m in args.models.split(",") if m.strip()],
            out,
            params=params,
            generations=20 if n is None else n,
            epochs=20 if n is None else n,
            train_fraction=args.train_fraction,
            shooting=args.shooting,
            seed=args.seed,
            device=args.device,
            dtype=args.dtype,
            progress=not args.quiet,
            video=not args.no_video,
            force=args.force,
            resume=args.resume,
            workers=args.workers,
            ray=args.ray,
            address=args.address,
        )
    except FitError as exc:
        raise CliError(str(exc)) from None
    print("\n".join(models_table(report)))
    print(f"wrote {out / 'models.json'} and one folder per model")
    return 0


__all__ = ["add_parsers", "cmd_fit", "cmd_observe"]
