"""``pliant view``: serve a trajectory in the browser until Ctrl-C (a scene instead runs live: ``_live``)."""

from __future__ import annotations

import argparse
import time

from ._common import EXIT_INTERRUPTED, CliError


def view_token(args: argparse.Namespace) -> str | None:
    """The token ``pliant view`` requires: ``--token`` as given ('' for none), else a random one when the
    server listens beyond this machine (as Jupyter does), else none; warns on stderr of who can connect."""
    import secrets
    import sys

    from ..render import is_loopback

    token = getattr(args, "token", None)
    open_to_all = not is_loopback(args.host)
    if token is None:
        token = secrets.token_urlsafe(18) if open_to_all else ""
    if open_to_all:
        live = not str(args.trajectory).lower().endswith(".npz")
        what = "drive the simulation (drag it, change its material, write recordings)" if live else "watch it"
        who = "anyone who has the URL below, with its token," if token else "ANYONE"
        print(
            f"pliant view: listening on {args.host}:{args.port}: {who} who can reach the port can {what}",
            file=sys.stderr,
            flush=True,
        )
    return token or None


def cmd_view(args: argparse.Namespace) -> int:
    """Load the trajectory (or build the scene, run live), start the viewer and keep serving it (Ctrl-C
    stops: exit 130)."""
    args.token = view_token(args)
    if not str(args.trajectory).lower().endswith(".npz"):  # a scene: run it live
        from ._live import start_live

        viewer, what = start_live(args)
    else:
        from ..io import Trajectory
        from ..render import serve_viewer

        try:
            traj = Trajectory.load(args.trajectory)
        except (OSError, ValueError, KeyError) as exc:
            raise CliError(
                f"{args.trajectory}: not a pliant trajectory ({exc}); write one with pliant run"
            ) from None
        viewer = serve_viewer(traj, host=args.host, port=args.port, token=args.token)
        what = f"{args.trajectory} ({traj.frame_count} frames)"
    print(f"pliant view: {what} at {viewer.url} (Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:  # the way to stop serving: exit 130 without an error line
        return EXIT_INTERRUPTED
    finally:
        viewer.stop()
