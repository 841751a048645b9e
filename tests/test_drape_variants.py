"""FastMassSpring's gather variants (``gather="loop" | "unrolled" | "tiled"``): the unrolled kernel is the
loop's step bit for bit on the CPU, the tiled one equal to round-off, each is one launch per substep, and
benchmarks/gpu_drape_variants.py measures them (run here at a tiny size)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import warp as wp
from warp._src import context as wp_context

from pliant.bench._mass_spring import FRAME_DT, cloth_drape_model, sag
from pliant.model import Model
from pliant.solvers import FastMassSpring

ROOT = Path(__file__).resolve().parent.parent
VARIANTS = ("loop", "unrolled", "ell", "tiled", "tiled16")


def _cloth(device: str = "cpu", damping: float = 0.0) -> Model:
    """The 12 × 12 drape with bend springs too: rows of 5 to 12 springs, so that the unrolled kernel's
    chunks of 4 end at every remainder."""
    return cloth_drape_model(12, device=device, damping=damping, bend_stiffness=5.0)


def _drape(device: str, gather: str, *, damping: float = 0.0, frames: int = 3, substeps: int = 20):
    """Final positions [m] and sag curve [m] of :func:`_cloth` after ``frames`` frames."""
    model = _cloth(device, damping)
    solver = FastMassSpring(model, method="symplectic", kernel="gather", gather=gather)
    s0, s1, ctl = model.state(), model.state(), model.control()
    curve = [sag(model, s0.particle_q.numpy())]
    for _ in range(frames):
        for _ in range(substeps):
            solver.step(s0, s1, ctl, FRAME_DT / substeps)
            s0, s1 = s1, s0
        curve.append(sag(model, s0.particle_q.numpy()))
    return s0.particle_q.numpy(), np.asarray(curve)


def test_rows_cover_every_chunk_remainder():
    """The premise of the unrolled test: the cloth's CSR rows have lengths of every residue mod 4."""
    off = FastMassSpring(_cloth(), method="symplectic").adj_offsets.numpy()
    assert set(np.diff(off) % 4) == {0, 1, 2, 3}


@pytest.mark.parametrize("gather", ["unrolled", "ell"])
@pytest.mark.parametrize("damping", [0.0, 0.05])
def test_unrolled_gather_is_the_loop(device, damping, gather):
    """Same loads, same sums in the same order: identical trajectories on the CPU (with and without the
    dashpots); on CUDA the compiler may contract the two kernels' arithmetic differently, so round-off."""
    x_loop, c_loop = _drape(device, "loop", damping=damping)
    x_unr, c_unr = _drape(device, gather, damping=damping)
    assert np.all(np.isfinite(x_loop)) and c_loop[-1] > c_loop[0]  # it fell
    if device == "cpu":
        assert np.array_equal(x_unr, x_loop)
        assert np.array_equal(c_unr, c_loop)
    else:
        assert np.max(np.abs(x_unr - x_loop)) <= 1e-5 * c_loop[-1]


@pytest.mark.parametrize("gather", ["tiled", "tiled16"])
@pytest.mark.parametrize("damping", [0.0, 0.05])
def test_tiled_gather_within_round_off(device, damping, gather):
    """The tiled kernel sums the springs in another order: its positions differ from the loop's by float32
    round-off, far below the trajectory errors the benchmarks accept (1e-3 and up)."""
    x_loop, c_loop = _drape(device, "loop", damping=damping)
    x_til, c_til = _drape(device, gather, damping=damping)
    assert np.max(np.abs(x_til - x_loop)) <= 1e-5 * c_loop[-1]
    assert np.max(np.abs(c_til - c_loop)) <= 1e-5 * c_loop[-1]


@pytest.mark.parametrize("gather", VARIANTS)
def test_one_launch_per_substep(device, gather, monkeypatch):
    """A drape substep launches one kernel and copies nothing (what a captured frame replays), whichever
    variant: kernels launched directly or replayed from recorded commands, and array copies, are counted."""
    model = cloth_drape_model(8, device=device, dtype="float32")
    solver = FastMassSpring(model, method="symplectic", kernel="gather", gather=gather)
    s0, s1, ctl = model.state(), model.state(), model.control()
    dt = FRAME_DT / 20
    solver.step(s0, s1, ctl, dt)  # records the commands
    solver.step(s1, s0, ctl, dt)
    calls: list[str] = []

    def counting(name, fn):
        def wrapped(*args, **kwargs):
            calls.append(name)
            return fn(*args, **kwargs)

        return wrapped

    monkeypatch.setattr(wp_context.Launch, "launch", counting("replay", wp_context.Launch.launch))
    monkeypatch.setattr(wp, "launch", counting("launch", wp.launch))
    monkeypatch.setattr(wp, "launch_tiled", counting("launch_tiled", wp.launch_tiled))
    monkeypatch.setattr(wp, "copy", counting("copy", wp.copy))
    for _ in range(4):
        solver.step(s0, s1, ctl, dt)
        s0, s1 = s1, s0
    assert calls == ["replay"] * 4


def test_gather_option_is_checked():
    model = cloth_drape_model(4, dtype="float32")
    with pytest.raises(ValueError, match="gather must be one of"):
        FastMassSpring(model, gather="fast")
    with pytest.raises(ValueError, match="variant of kernel='gather'"):
        FastMassSpring(model, kernel="scatter", gather="unrolled")
    # a variant picks the gather kernel on the CPU too (where the default is the scatter)
    assert FastMassSpring(model, gather="tiled").kernel == "gather"
    assert FastMassSpring(model).describe()["gather"] == "loop"


def test_default_variant_by_device(device):
    """The default is the measured winner per device: the unrolled gather on CUDA (faster at every size on
    an H100, same trajectory error), the loop (behind the scatter kernel) on the CPU."""
    solver = FastMassSpring(cloth_drape_model(4, device=device, dtype="float32"))
    cuda = wp.get_device(device).is_cuda
    assert solver.gather == ("unrolled" if cuda else "loop")
    assert solver.kernel == ("gather" if cuda else "scatter")


def test_variants_benchmark_smoke(device):
    """benchmarks/gpu_drape_variants.py at 16² (3 frames, 20 substeps; captured in a graph on CUDA): a row
    per variant with the same trajectory error, the unrolled one identical to the loop on the CPU."""
    spec = importlib.util.spec_from_file_location(
        "gpu_drape_variants", ROOT / "benchmarks/gpu_drape_variants.py"
    )
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    rows = bench.measure(16, 20, VARIANTS, device, frames=3, rounds=2)
    by = {r["variant"]: r for r in rows if "variant" in r}
    assert set(by) == set(VARIANTS), rows
    errors = [by[v]["trajectory_error"] for v in VARIANTS]
    assert errors[0] is not None and 0 < errors[0] < 0.01  # a stored reference: the 16² curve
    assert errors == pytest.approx([errors[0]] * len(VARIANTS), abs=1e-5)
    assert all(len(by[v]["fps_rounds"]) == 2 and by[v]["fps"] > 0 for v in VARIANTS)
    assert by[VARIANTS[0]]["graph"] == wp.get_device(device).is_cuda
    if device == "cpu":
        assert by["unrolled"]["bit_equal_loop"] and by["unrolled"]["curve_dev_vs_loop"] == 0.0
    summary = [r for r in rows if r.get("summary")]
    assert len(summary) == 1 and summary[0]["speedup_vs_loop"]["loop"] == 1.0


def test_ell_layout_holds_every_row_in_order():
    """The ELL slots of random CSR rows (lengths 0 to 16): slot k of particle i is its k-th entry while
    k < its length, its last entry after (a particle without springs: entry 0), the slot count is the longest
    row rounded up to 4; a row of 17 is refused with the fix named."""
    from pliant.solvers.fast_mass_spring._explicit import ell_layout

    rng = np.random.default_rng(3)
    lengths = rng.integers(0, 17, size=50)
    lengths[7] = 16
    off = np.concatenate([[0], np.cumsum(lengths)])
    slots, count, entry = ell_layout(off)
    assert slots == 16 and np.array_equal(count, lengths)
    table = entry.reshape(slots, -1)
    for i, n in enumerate(lengths):
        want = [off[i] + min(k, n - 1) if n else 0 for k in range(slots)]
        assert table[:, i].tolist() == want
    assert ell_layout(np.array([0, 3, 5]))[0] == 4
    with pytest.raises(ValueError, match='gather="unrolled"'):
        ell_layout(np.array([0, 17]))


def test_block_dim_by_size_and_the_same_step(device):
    """The gather's block: 64 threads below 32 768 particles, 256 above, any valid one on request; a
    thread's sums do not depend on its block, so the trajectory is the same bit for bit; a bad value names
    the range."""
    small, large = cloth_drape_model(8, device=device), cloth_drape_model(182, device=device)
    assert FastMassSpring(small, kernel="gather").block_dim == 64
    assert FastMassSpring(large, kernel="gather").block_dim == 256
    runs = []
    for bd in (32, 256):
        solver = FastMassSpring(small, kernel="gather", gather="unrolled", block_dim=bd)
        s0, s1, ctl = small.state(), small.state(), small.control()
        for _ in range(20):
            solver.step(s0, s1, ctl, FRAME_DT / 20)
            s0, s1 = s1, s0
        runs.append(s0.particle_q.numpy())
    assert np.array_equal(runs[0], runs[1]) and np.ptp(runs[0][:, 1]) > 0
    with pytest.raises(ValueError, match=r"block_dim must be an integer in \[1, 1024\]"):
        FastMassSpring(small, block_dim=2048)
