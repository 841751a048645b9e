"""``pliant twin``: calibrated pictures (an observation NPZ with images, masks and optionally depth) →
a fitted, predicting twin (:func:`pliant.twin.build_twin`)."""

from __future__ import annotations

import argparse

from ._common import (
    WORKERS_HELP,
    CliError,
    Subparsers,  # noqa: TC001 - used at run time by the annotations' evaluation only
    _positive_float,
    _positive_int,
    _sub,
    _workers,
    add_ray,
    check_ray,
)


def add_parsers(sub: Subparsers) -> None:
    """Register ``twin`` on the ``pliant`` sub-parsers."""
    p = _sub(
        sub,
        "twin",
        "build a fitted twin from calibrated pictures (images, masks, optional depth)",
        "pliant twin beam.npz --out twin/                   # twin/twin.toml, twin.json, pictures",
        "pliant twin beam.npz --out twin/ --models fem,springs --ground none",
        "pliant run twin/twin.toml --cameras other_camera.npz   # predict a camera the twin never saw",
        "pliant view twin/twin.toml                           # the twin live; drag it",
    )
    p.add_argument(
        "obs",
        metavar="OBS.npz",
        help="observations: t [T], images [C, T, H, W, 3] uint8, K [C, 3, 3], world_to_camera [C, 4, 4], "
        "masks [C, T, H, W] bool, and optionally depth [C, T, H, W] (uint16 mm or float m, 0 = none)",
    )
    p.add_argument("--out", required=True, help="output folder: twin.toml, twin.json, pictures, fits")
    p.add_argument(
        "--models",
        default="fem",
        metavar="MODEL,...",
        help="physical models to fit on the carved volume (fem: neo-Hookean tets; mass_spring: the tet edges "
        "as springs; springs: PhysTwin's springs to neighbours within a radius); with several, the lowest "
        "validation loss wins (default fem)",
    )
    p.add_argument(
        "--fixed",
        default="auto",
        metavar="auto|none|CX,CY,CZ,HX,HY,HZ[;...]",
        help="what holds the object: detected from the regions that never move (auto), nothing (none), or "
        "kinematic boxes (centre and half extents in metres, ';' between boxes)",
    )
    p.add_argument(
        "--ground",
        default="auto",
        metavar="auto|none|HEIGHT",
        help="the ground: detected when the object rests on or hits it (auto), none, or a height [m]",
    )
    p.add_argument("--train-fraction", type=_positive_float, default=0.7, help="frames to fit on (0.7)")
    p.add_argument(
        "--spacing", type=_positive_float, help="voxel spacing [m] (default: 2 pixels at the object)"
    )
    p.add_argument("--max-particles", type=_positive_int, default=3000, help="largest particle count (3000)")
    p.add_argument("--density", type=_positive_float, default=1000.0, help="mass density [kg/m³] (1000)")
    p.add_argument(
        "--generations", type=_positive_int, default=8, help="most CMA-ES generations per model (8)"
    )
    p.add_argument("--splat-iterations", type=_positive_int, default=150, help="Adam steps of the splats")
    p.add_argument("--seed", type=int, default=42, help="seed of every random choice, >= 1 (42)")
    p.add_argument("--workers", type=_workers, default="auto", help=WORKERS_HELP + " (auto)")
    add_ray(p)
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue each model's fit from its checkpoint in OUT/fit/<model>/ (after a kill or Ctrl-C)",
    )
    p.add_argument("-q", "--quiet", action="store_true", help="print only the summary")


def _boxes(text: str) -> str | list:
    if text in ("auto", "none"):
        return text
    boxes = []
    for part in text.split(";"):
        try:
            v = [float(a) for a in part.split(",")]
        except ValueError:
            v = []
        if len(v) != 6 or any(h <= 0 for h in v[3:]):
            raise CliError(
                f"--fixed: expected auto, none or boxes 'cx,cy,cz,hx,hy,hz' in metres (half extents > 0), "
                f"got {part!r}"
            )
        boxes.append((v[:3], v[3:]))
    return boxes


def cmd_twin(args: argparse.Namespace) -> int:
    """Run ``pliant twin``."""
    from ..io import ObservationError, Observations
    from ..twin import TWIN_MODELS, TwinError, TwinOptions, build_twin

    check_ray(args)
    models = [m.strip() for m in args.models.split(",") if m.strip()]
    bad = [m for m in models if m not in TWIN_MODELS]
    if bad or not models:
        raise CliError(f"--models: choose from {', '.join(TWIN_MODELS)}, got {args.models!r}")
    fixed = _boxes(args.fixed)
    if args.ground in ("auto", "none"):
        ground: str | float = args.ground
    else:
        try:
            ground = float(args.ground)
        except ValueError:
            raise CliError(
                f"--ground: expected auto, none or a height in metres, got {args.ground!r}"
            ) from None
    try:
        obs = Observations.load(args.obs)
        opts = TwinOptions(
            train_fraction=args.train_fraction,
            models=models,
            fixed=fixed,
            ground=ground,
            spacing=args.spacing,
            max_particles=args.max_particles,
            density=args.density,
            generations=args.generations,
            splat_iterations=args.splat_iterations,
            seed=args.seed,
            progress=not args.quiet,
            resume=args.resume,
            workers=args.workers,
            ray=args.ray,
            address=args.address,
        )
        rep = build_twin(obs, args.out, opts)
    except (ObservationError, TwinError) as exc:
        raise CliError(str(exc)) from None
    m = rep["metrics"]
    print(
        f"twin: {rep['particles']} particles ({rep['model']}), fixed {rep['fixed']['fixed_particles']}, "
        f"ground {rep['ground']['height']}; held-out Chamfer {m['chamfer_mm']['test']:.2f} mm (still: "
        f"{m['chamfer_still_mm']['test']:.2f} mm), IoU {m['iou']['test']:.3f}, PSNR "
        f"{m['psnr_db']['test']:.1f} dB; {rep['wall_time']:.0f} s\n"
        f"twin: wrote {args.out}/twin.toml (pliant run / pliant view it), twin.json"
    )
    return 0
