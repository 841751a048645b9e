"""The GPU rows of ``pliant bench`` (issue 24 item 6) in their quick form on the CPU: the 256² and 512² drapes
with their memory traffic, XPBD at 256², the references computed on demand, and the two fit rows."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pliant import bench
from pliant.bench import _drape_motion
from pliant.bench._bandwidth import bytes_per_substep, dram_bandwidth, peak_bandwidth
from pliant.bench._drape_scene import cloth_drape_model


def _counts(n: int) -> tuple[int, int]:
    """Particles and springs of the n × n drape: (n+1)² particles; n(n+1) springs along each axis and two
    diagonals per cell (structural and shear, no bending)."""
    return (n + 1) ** 2, 2 * n * (n + 1) + 2 * n * n


def test_drape_cloth_counts_match_the_formula():
    model = cloth_drape_model(16, device="cpu")
    assert (model.particle_count, model.spring_count) == _counts(16) == (289, 1056)


@pytest.mark.parametrize(
    ("kernel", "dtype", "per_particle", "per_spring", "constant"),
    [
        # gather: x, v, f_ext read and x', v' written (5 vec3) + 1/m + a CSR offset (int32); per spring two
        # adjacency entries of a neighbour index (int32) and (rest, k, γ) (vec3): 2 × (4 + 3 s)
        ("gather", "float32", 5 * 12 + 4 + 4, 2 * (4 + 12), 4),
        ("gather", "float64", 5 * 24 + 8 + 4, 2 * (4 + 24), 4),
        # scatter: springs read their pair (2 int32), rest and k; particles: x, then the force array read and
        # written (atomics); the update reads 1/m, f_ext, x, v, f, clears f and writes x', v' (7 vec3)
        ("scatter", "float32", 3 * 12 + 4 + 7 * 12, 8 + 2 * 4, 0),
    ],
)
def test_bytes_per_substep_is_the_arrays_touched_once(kernel, dtype, per_particle, per_spring, constant):
    from pliant.solvers import FastMassSpring

    model = cloth_drape_model(16, device="cpu", dtype=dtype)
    solver = FastMassSpring(model, method="symplectic", kernel=kernel, damping_rate=0.0)
    n, s = _counts(16)
    assert bytes_per_substep(solver) == per_particle * n + per_spring * s + constant


def test_bytes_per_substep_refuses_the_implicit_step():
    from pliant.solvers import FastMassSpring

    solver = FastMassSpring(cloth_drape_model(4, device="cpu"), method="implicit")
    with pytest.raises(ValueError, match="symplectic"):
        bytes_per_substep(solver)


def test_peak_bandwidth_from_memory_clock_and_bus_width():
    """NVIDIA's published peaks: A100 40 GB (1215 MHz, 5120-bit HBM2) 1555 GB/s; H100 SXM (2619 MHz,
    5120-bit HBM3) 3.35 TB/s. No peak for the CPU (Warp does not expose one; no driver to ask)."""
    assert dram_bandwidth(1_215_000, 5120) == pytest.approx(1555e9, rel=1e-3)
    assert dram_bandwidth(2_619_000, 5120) == pytest.approx(3.35e12, rel=1e-3)
    assert dram_bandwidth(0, 5120) is None
    assert peak_bandwidth("cpu") is None


def test_large_drape_rows_quick_carry_traffic_and_motion():
    """The 512² row in quick form (a 16² cloth at the 512² row's 640 substeps): its motion within 0.5 % of
    the converged curve, and the bytes of the CPU's scatter step (16 B per spring, 124 B per particle)."""
    row = bench.run("cloth_drape_512_symplectic", quick=True, device="cpu")
    n, s = _counts(16)
    assert row["particles"] == n and row["elements"] == s and row["substeps"] == 640
    assert row["stable"] and row["reference"] == "stored"
    assert math.isfinite(row["trajectory_error"]) and row["trajectory_error"] < 0.005
    assert row["bytes_per_substep"] == 16 * s + 124 * n
    expected = row["bytes_per_substep"] * 30 * 640 / row["wall_s"] / 1e9
    assert row["achieved_bandwidth_gbs"] == pytest.approx(expected, rel=0.01)
    assert row["bandwidth_fraction"] is None and row["peak_bandwidth_gbs"] is None


def test_implicit_drape_rows_have_no_traffic_figure():
    row = bench.run("cloth_drape_256_implicit", quick=True, device="cpu")
    assert row["bytes_per_substep"] is None and math.isfinite(row["trajectory_error"])


@pytest.mark.parametrize("schedule", ["coloring", "jacobi", "jacobi_sum"])
def test_xpbd_256_rows_quick(schedule):
    row = bench.run(f"xpbd_cloth_drape_256_{schedule}", quick=True, device="cpu")
    assert row["schedule"] == schedule and row["particles"] == 289 and row["stable"]
    assert row["substeps"] == {"coloring": 500, "jacobi": 1000, "jacobi_sum": 500}[schedule]
    assert math.isfinite(row["trajectory_error"]) and row["reference"] == "stored"


def test_missing_reference_is_computed_on_the_device_and_cached(tmp_path, monkeypatch):
    """A size without a stored reference gets one computed on the row's device, cached and found again;
    on the CPU the large sizes are not computed (None, with the reason)."""
    monkeypatch.setenv("PLIANT_BENCH_CACHE", str(tmp_path))
    monkeypatch.setattr(_drape_motion, "_RESOLVED", {})
    ref, source = _drape_motion.reference_for(8, "cpu")
    assert ref is not None and source.startswith("computed on cpu")
    assert (tmp_path / "cloth_drape_8.npz").exists()
    monkeypatch.setattr(_drape_motion, "_RESOLVED", {})
    again, source = _drape_motion.reference_for(8, "cpu")
    assert source.startswith("cached") and again is not None
    np.testing.assert_array_equal(again, ref)
    # converged: the float32 run at the stable setting (10 substeps per frame at 8²) follows it
    curve = _drape_motion.sag_curve(8, "symplectic", substeps=10)
    assert _drape_motion.trajectory_error(curve, ref) < 0.005
    none, why = _drape_motion.reference_for(256, "cpu")  # 512² is stored (computed on an H100)
    assert none is None and "not computed on the CPU" in why


def test_fit_rope_row_quick_recovers_the_readme_truth():
    row = bench.run("fit_rope", quick=True, device="cpu")
    assert row["truth"] == {"stiffness": 480.0, "damping_rate": 0.5} and row["tracks"] == 10
    assert row["wall_s"] > 0 and row["compile_s"] > 0 and row["cpu_cores"] >= 1
    assert row["max_param_rel_error"] < 0.05, row
    assert row["test_error_mm"] < 0.25 * row["test_error_start_mm"], row


def test_fit_cloth_row_quick_improves_the_held_out_error():
    row = bench.run("fit_cloth_17", quick=True, device="cpu")
    assert row["scene"] == "cloth_7x7" and row["tracks"] == 20 and row["epochs"] == 1
    assert row["param_rel_error"]["damping_rate"] < 0.1, row
    assert row["test_error_mm"] < 0.25 * row["test_error_start_mm"], row


@pytest.mark.slow
def test_fit_rope_row_is_the_readme_fit():
    """The full row fits what the README's commands fit: the same stiffness (README: 479.262 N/m) and
    held-out error (1.7 mm)."""
    row = bench.run("fit_rope", device="cpu")
    assert row["values"]["stiffness"] == pytest.approx(479.262, abs=0.5)
    assert row["test_error_mm"] == pytest.approx(1.7, abs=0.1)
