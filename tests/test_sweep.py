"""pl.sweep / pliant sweep: the grid, batched copies equal to runs alone, divergence recorded per run,
resume (and a folder of another sweep refused), and Ray's local cluster producing the same table."""

from __future__ import annotations

import csv
import subprocess
import sys

import pytest

from pliant.sweep import SweepError, grid, run_sweep
from pliant.sweep._sweep import FIGURES

STIFF = "objects[0].material.stiffness=100,200,400"


def test_grid_is_the_product_and_keeps_bracketed_values():
    runs = grid([STIFF, "objects[0].origin=[0,1,0],[0,2,0]"])
    assert len(runs) == 6
    assert runs[1] == ["objects[0].material.stiffness=100", "objects[0].origin=[0,2,0]"]
    with pytest.raises(SweepError, match="PATH=V1,V2"):
        grid(["stiffness"])
    with pytest.raises(SweepError, match="empty value"):
        grid(["objects[0].material.stiffness=1,,2"])


def test_batched_copies_equal_runs_alone(tmp_path):
    a = run_sweep("rope", [STIFF], tmp_path / "a", worlds=3, frames=8)
    b = run_sweep("rope", [STIFF], tmp_path / "b", worlds=1, frames=8)
    assert [r["batched"] for r in a] == [3, 3, 3] and [r["batched"] for r in b] == [1, 1, 1]
    for ra, rb in zip(a, b, strict=True):
        assert {k: ra[k] for k in FIGURES} == {k: rb[k] for k in FIGURES}  # bit for bit (explicit steps)
    assert a[0]["sag"] != a[2]["sag"]  # the stiffness matters


def test_a_diverging_run_is_recorded_and_the_others_finish(tmp_path):
    rows = run_sweep("rope", ["objects[0].material.stiffness=100,1e12"], tmp_path, worlds=2, frames=8)
    assert [r["status"] for r in rows] == ["ok", "diverged"]
    assert rows[1]["error"] and rows[0]["sag"] > 0
    with open(tmp_path / "results.csv", newline="") as f:
        assert [r["status"] for r in csv.DictReader(f)] == ["ok", "diverged"]


def test_rerun_skips_finished_runs(tmp_path, monkeypatch):
    first = run_sweep("rope", [STIFF], tmp_path, frames=5)
    import pliant.sweep._sweep as sw

    def fail(*a, **k):
        raise AssertionError("a finished run was run again")

    monkeypatch.setattr(sw, "run_chunk", fail)
    again = run_sweep("rope", [STIFF], tmp_path, frames=5)
    assert [{k: r[k] for k in FIGURES} for r in again] == [{k: r[k] for k in FIGURES} for r in first]


def test_a_folder_of_another_sweep_is_refused_before_any_work(tmp_path, monkeypatch):
    """Resuming into a folder whose rows came from another scene or frame count would mix two sweeps'
    results under one table (rows are keyed by their overrides alone): refused with the fix, nothing run."""
    run_sweep("rope", [STIFF], tmp_path, frames=5)
    before = (tmp_path / "results.csv").read_bytes()
    import pliant.sweep._sweep as sw

    def fail(*a, **k):
        raise AssertionError("ran before refusing")

    monkeypatch.setattr(sw, "run_chunk", fail)
    with pytest.raises(SweepError, match="another scene or frame count.*another --out"):
        run_sweep("rope", [STIFF], tmp_path, frames=6)
    with pytest.raises(SweepError, match="another scene"):
        run_sweep("cloth", ["objects[0].material.stiffness=100"], tmp_path, frames=5)
    (tmp_path / "sweep.json").write_text("{truncated")
    with pytest.raises(SweepError, match="sweep.json: not a sweep record"):
        run_sweep("rope", [STIFF], tmp_path, frames=5)
    assert (tmp_path / "results.csv").read_bytes() == before  # the earlier results are kept


def test_cli_sweep_writes_the_table_and_rejects_bad_input(tmp_path):
    cmd = [sys.executable, "-m", "pliant.cli", "sweep", "rope", "--frames", "4", "-q", "--out", str(tmp_path)]
    r = subprocess.run(
        [*cmd, "--set", "objects[0].material.stiffness=100,200"], capture_output=True, text=True
    )
    assert r.returncode == 0, r.stderr
    assert "2 ok" in r.stdout and (tmp_path / "results.csv").exists()
    r = subprocess.run(cmd, capture_output=True, text=True)
    assert r.returncode == 1 and "--set" in r.stderr
    r = subprocess.run([*cmd, "--set", "objects[0].material.stiffnes=1,2"], capture_output=True, text=True)
    assert r.returncode == 1 and "stiffnes" in r.stderr


def test_ray_local_cluster_gives_the_same_table(tmp_path):
    ray = pytest.importorskip("ray", reason="the ray extra: pip install 'pliant[ray]'")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        with_ray = run_sweep("rope", [STIFF], tmp_path / "ray", worlds=2, frames=6, ray=True)
    finally:
        ray.shutdown()
    plain = run_sweep("rope", [STIFF], tmp_path / "plain", worlds=2, frames=6)
    assert [{k: r[k] for k in FIGURES} for r in with_ray] == [{k: r[k] for k in FIGURES} for r in plain]
