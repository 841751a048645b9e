"""``pliant view SCENE``: run a scene (a file, a built-in name, a ``fitted.toml``) live in the browser."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ._common import CliError


def start_live(args: argparse.Namespace) -> tuple[Any, str]:
    """Build the scene ``args.trajectory`` names and serve it live, stepping; returns the running
    :class:`pliant.live.LiveViewer` and what ``pliant view`` prints about it."""
    import numpy as np

    from ..live import LiveSession, serve_live
    from ..render import load_viser
    from ..scene import build_scene
    from ..sim import DivergenceError
    from ._run import _load

    load_viser()  # the install advice before a scene is built
    cfg = _load(args.trajectory)
    out = Path(getattr(args, "out", ".") or ".")
    if out.exists() and not out.is_dir():
        raise CliError(f"--out {out}: not a folder; give the folder the record button writes into")
    with np.errstate(over="ignore", invalid="ignore"):
        scene = build_scene(cfg, device=getattr(args, "device", None), dtype=getattr(args, "dtype", None))
    scene.prebuild_kernels()  # the first frames' kernels compile while the session starts
    try:
        session = LiveSession(scene)
    except DivergenceError as exc:
        raise CliError(str(exc)) from None
    out.mkdir(parents=True, exist_ok=True)
    viewer = serve_live(
        session,
        host=args.host,
        port=args.port,
        record_dir=out,
        start=False,
        token=getattr(args, "token", None),
    )
    viewer.paused = bool(getattr(args, "paused", False))
    viewer.start()
    m = scene.model
    what = (
        f"{cfg.scene.name} live ({m.particle_count} particles, {scene.substeps} substeps of "
        f"{scene.substep_dt:.3g} s per frame, {m.device}; drag the object)"
    )
    return viewer, what
