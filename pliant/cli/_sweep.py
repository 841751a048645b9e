"""``pliant sweep``: a grid of --set values over one scene."""

from __future__ import annotations

import argparse
import sys

from ._common import EXIT_OK, CliError


def cmd_sweep(args: argparse.Namespace) -> int:
    """Run the grid; print where the table is and how many runs finished, diverged or failed."""
    from ..sweep import SweepError, run_sweep

    if not args.sets:
        raise CliError(
            "pliant sweep: give at least one --set PATH=V1,V2,... "
            "(e.g. objects[0].material.stiffness=100,200)"
        )
    if args.address and not args.ray:
        raise CliError("--address goes with --ray")

    def progress(done: int, total: int) -> None:
        if not args.quiet:
            print(f"\rsweep: {done}/{total} runs", end="", file=sys.stderr, flush=True)

    try:
        rows = run_sweep(
            args.scene,
            args.sets,
            args.out,
            worlds=args.worlds,
            frames=args.frames,
            ray=args.ray,
            address=args.address,
            save_trajectories=args.save_trajectories,
            force=args.force,
            progress=progress,
        )
    except SweepError as exc:
        raise CliError(str(exc)) from None
    if not args.quiet:
        print(file=sys.stderr)
    counts = {s: sum(r["status"] == s for r in rows) for s in ("ok", "diverged", "error")}
    print(
        f"wrote {args.out}/results.csv: {counts['ok']} ok, {counts['diverged']} diverged, "
        f"{counts['error']} failed"
    )
    return EXIT_OK
