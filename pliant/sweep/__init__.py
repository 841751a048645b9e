"""Parameter sweeps: a grid of scene overrides run as batched copies in one simulation, or as Ray tasks.

``pl.sweep.run_sweep("cloth", ["objects[0].material.stiffness=100,200,400"], "out/sweep")`` runs the scene
once per combination of the ``--set`` lists and writes ``results.csv`` (one row per run: the overrides,
status, error and summary figures), ``results.parquet`` beside it when pyarrow is installed, and each run's
trajectory on request. Runs that change only object sections (``objects[i]...``) are stepped together as
copies of the scene's objects in one model (``worlds`` per simulation), which share the launches, the
ground and the colliders (all per particle, so each copy moves as it would alone); other overrides run one
simulation each. With ``ray=True`` chunks of runs are Ray tasks (a local cluster, or ``address``). A run
that diverges is recorded with its error; a re-run of the same sweep into the same folder skips the runs
already done.
"""

from ._sweep import COLUMNS, SweepError, grid, run_sweep, summarize

__all__ = ["COLUMNS", "SweepError", "grid", "run_sweep", "summarize"]
