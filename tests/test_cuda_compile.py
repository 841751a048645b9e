"""The CUDA side of every kernel compiles, on any machine with Warp's NVRTC (no GPU needed): the CPU-only
suite otherwise never compiles a kernel's ``__CUDA_ARCH__`` paths (atomics, intrinsics, the adjoint), and
no GPU is lent to most sessions. ``tests/cuda_compile.py`` says what is covered."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

#: Modules the check must reach (a floor, so that a registration that silently stops working fails here).
MUST_COMPILE = {
    "pliant.solvers.fast_mass_spring._system",
    "pliant.solvers.fast_mass_spring._cg",
    "pliant.solvers.fast_mass_spring._explicit",
    "pliant.solvers.fast_mass_spring._fused_frame",
    "pliant.solvers.xpbd._kernels",
    "pliant.solvers.xpbd._tolerance",
    "pliant.solvers.minimizers._assembly",
    "pliant.solvers.minimizers._pcg",
    "pliant.solvers.minimizers._pcg_kernels",
    "pliant.solvers.minimizers._band",
    "pliant.solvers.force._solver",
    "pliant.integrators._symplectic",
    "pliant.integrators._implicit",
    "pliant.energies._spring",
    "pliant.energies._fem.neohookean_hessian",
    "pliant.energies._fem.stvk_hessian",
    "pliant.energies._fem.corotated_hessian",
    "pliant.energies._fem.linear_hessian",
    "pliant.collision._selfcollision",
    "pliant.constraints._shape",
    "pliant.gaussians._project",
    "pliant.gaussians._composite",
    "pliant.sim._simulator",
    # the adjoints and losses of tests/test_devices_grad.py
    "pliant.solvers.fast_mass_spring._adjoint",
    "pliant.solvers.minimizers._adjoint",
    "pliant.fit._losses",
    "pliant.gaussians._bind",
    "pliant.gaussians._correct",
}


def test_every_kernel_compiles_for_cuda_sm90(tmp_path):
    r = subprocess.run(
        [sys.executable, str(ROOT / "tests" / "cuda_compile.py"), "--arch", "90", "--out", str(tmp_path)],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    result = json.loads([ln for ln in r.stdout.splitlines() if ln.startswith("{")][-1])
    if "unavailable" in result:
        pytest.skip(f"this Warp build cannot compile for CUDA: {result['unavailable']}")
    assert result["errors"] == {}, json.dumps(result["errors"], indent=1)[:6000]
    missing = MUST_COMPILE - set(result["compiled"])
    assert not missing, f"not compiled (no overload registered?): {sorted(missing)}"
    # the "ell" gather's kernels live in a module of their own per slot count (module="unique")
    assert any("_symplectic_gather_ell" in name for name in result["compiled"]), result["compiled"]
    assert list(tmp_path.glob("*.sm90.ptx")), "no PTX written"
