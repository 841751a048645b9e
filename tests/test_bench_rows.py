"""The GPU rows of ``pliant bench`` (issue 24 item 6) in their quick form on the CPU: the drape's memory traffic
per substep and the device's peak bandwidth."""

from __future__ import annotations

import pytest

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
