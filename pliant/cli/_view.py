"""``pliant view``: serve a trajectory in the browser until Ctrl-C (a scene instead runs live: ``_live``)."""

from __future__ import annotations

import argparse
import time

from ._common import EXIT_INTERRUPTED, CliError


def cmd_view(args: argparse.Namespace) -> int:
    """Load the trajectory (or build the scene, run live), start the viewer and keep serving it (Ctrl-C
    stops: exit 130)."""
    if not str(args.trajectory).lower().endswith(".npz"):  # a scene: run it live
        from ._live import start_live

        viewer, what = start_live(args)
    else:
        from ..io import Trajectory
        from ..render._viewer import serve_viewer

        try:
            traj = Trajectory.load(args.trajectory)
        except (OSError, ValueError, KeyError) as exc:
            raise CliError(
                f"{args.trajectory}: not a pliant trajectory ({exc}); write one with pliant run"
            ) from None
        viewer = serve_viewer(traj, host=args.host, port=args.port)
        what = f"{args.trajectory} ({traj.frame_count} frames)"
    print(f"pliant view: {what} at {viewer.url} (Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:  # the way to stop serving: exit 130 without an error line
        return EXIT_INTERRUPTED
    finally:
        viewer.stop()
