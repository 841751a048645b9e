"""Property-based fuzz of checkpoint files (issue 11): every mutated checkpoint either resumes (with finite
output), or ends in a clear pliant error (CheckpointError naming the file, a DivergenceError, a
SingularSystemError) — never another exception type.

Mutations: drop a key, add a key (unknown names, ``param___class__``, ``solver_*``), replace a value by an
array of random shape / dtype / special values (NaN, inf, huge, negative, complex, strings), set ``frame``
to any integer, truncate the file, overwrite bytes, or replace it by garbage. Two base checkpoints: an
explicit rope (no solver state) and an L-BFGS FEM box (curvature pairs, warm start, lagged H₀).

The default suite runs a fixed, derandomised sample (~20 s); ``-m slow`` runs a long random search.
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import pliant as pl
from pliant.io import CheckpointError
from pliant.solvers import SingularSystemError

FRAMES_BEFORE, FRAMES_AFTER = 3, 5
CLEAN = (CheckpointError, pl.DivergenceError, SingularSystemError)


def _rope() -> pl.Simulator:
    b = pl.ModelBuilder()
    b.add_rope(n_segments=4, length=0.4, mass=0.05, stiffness=400.0, damping=0.01, start=(0.0, 0.5, 0.0))
    b.pin(0)
    model = b.finalize(device="cpu")
    return pl.Simulator(model, pl.solvers.ForceSolver(model), frame_dt=1 / 60, substeps=4)


def _fem() -> pl.Simulator:
    b = pl.ModelBuilder()
    b.add_soft_box(cells=(1, 1, 1), size=(0.2, 0.2, 0.2), origin=(0.0, 0.11, 0.0), E=2e4, nu=0.3)
    b.add_ground(0.0)
    model = b.finalize(device="cpu", dtype="float64")
    solver = pl.solvers.ForceSolver(
        model,
        energies=[pl.energies.NeoHookean(), pl.energies.Gravity()],
        integrator=pl.integrators.BDF2(),
        minimizer={"method": "lbfgs"},
    )
    return pl.Simulator(model, solver, frame_dt=1 / 30, substeps=1)


MAKERS = {"rope": _rope, "fem": _fem}
_BASE: dict[str, bytes] = {}


def _base(kind: str, tmp: Path) -> bytes:
    if kind not in _BASE:
        path = tmp / f"base_{kind}.ckpt.npz"
        MAKERS[kind]().run(FRAMES_BEFORE, progress=False, checkpoint=path)
        _BASE[kind] = path.read_bytes()
    return _BASE[kind]


def _arrays(blob: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(blob)) as z:
        return {k: z[k] for k in z.files}


SPECIAL = st.sampled_from(
    [0.0, -1.0, 1.0, 1e-300, 1e38, 1e39, 1e308, -1e308, float("nan"), float("inf"), -float("inf")]
)
DTYPES = st.sampled_from(["float32", "float64", "int32", "int64", "bool", "complex64", "U3", "uint8"])


@st.composite
def random_array(draw) -> np.ndarray:
    shape = tuple(draw(st.lists(st.integers(0, 6), max_size=3)))
    dtype = draw(DTYPES)
    fill = draw(SPECIAL)
    size = int(np.prod(shape)) if shape else 1
    if dtype == "U3":
        return np.full(shape, draw(st.sampled_from(["", "abc", "{", "1"])), dtype=dtype)
    values = np.full(size, fill)
    if size and draw(st.booleans()):
        values = values * np.linspace(0.5, 1.5, size)
    with np.errstate(all="ignore"):
        if np.dtype(dtype).kind in "iub":
            values = np.nan_to_num(values, nan=0, posinf=2**31 - 1, neginf=-(2**31)).clip(-(2**31), 2**31 - 1)
        return values.astype(dtype).reshape(shape)


@st.composite
def mutation(draw, keys: list[str]):
    """A function blob -> blob applying one to three mutations."""
    ops = []
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(
            st.sampled_from(["drop", "add", "replace", "frame", "perturb", "truncate", "bytes", "garbage"])
        )
        if kind == "drop":
            ops.append(("drop", draw(st.sampled_from(keys))))
        elif kind == "add":
            name = draw(
                st.one_of(
                    st.sampled_from(
                        [
                            "param___class__",
                            "param_tet_mu",
                            "solver_foo",
                            "solver_lbfgs_s",
                            "solver_bdf2_dt",
                            "extra",
                            "param_",
                        ]
                    ),
                    st.text("abcdefghijklmnopqrstuvwxyz_", min_size=1, max_size=12),
                )
            )
            ops.append(("set", name, draw(random_array())))
        elif kind == "replace":
            ops.append(("set", draw(st.sampled_from(keys)), draw(random_array())))
        elif kind == "frame":
            ops.append(("set", "frame", np.array(draw(st.integers(-(10**7), 10**7)))))
        elif kind == "perturb":
            ops.append(("perturb", draw(st.sampled_from(keys)), draw(SPECIAL)))
        elif kind == "truncate":
            ops.append(("truncate", draw(st.floats(0.0, 1.0))))
        elif kind == "bytes":
            ops.append(("bytes", draw(st.floats(0.0, 1.0)), draw(st.binary(min_size=1, max_size=16))))
        else:
            ops.append(("garbage", draw(st.binary(max_size=64))))
    return ops


def _apply(blob: bytes, ops: list) -> bytes:
    for op in ops:
        if op[0] in ("drop", "set", "perturb"):
            try:
                data = _arrays(blob)
            except Exception:  # an earlier byte-level mutation already broke the archive
                continue
            if op[0] == "drop":
                data.pop(op[1], None)
            elif op[0] == "set":
                data[op[1]] = op[2]
            elif op[1] in data and data[op[1]].dtype.kind == "f" and data[op[1]].size:
                a = data[op[1]].copy()
                with np.errstate(all="ignore"):
                    a.flat[a.size // 2] = op[2]
                data[op[1]] = a
            out = io.BytesIO()
            np.savez(out, **data)
            blob = out.getvalue()
        elif op[0] == "truncate":
            blob = blob[: int(op[1] * len(blob))]
        elif op[0] == "bytes":
            at = int(op[1] * max(len(blob) - 1, 0))
            blob = blob[:at] + op[2] + blob[at + len(op[2]) :]
        else:
            blob = op[1]
    return blob


def _check(kind: str, blob: bytes, tmp: Path) -> str:
    path = tmp / "fuzz.ckpt.npz"
    path.write_bytes(blob)
    try:
        traj = MAKERS[kind]().run(FRAMES_AFTER, progress=False, checkpoint=path, resume=True)
    except CLEAN as exc:
        if isinstance(exc, CheckpointError):
            assert str(path) in str(exc), f"CheckpointError does not name the file: {exc}"
        return type(exc).__name__
    assert traj.frame_count == FRAMES_AFTER + 1
    assert np.all(np.isfinite(traj.x)), "a resumed run wrote non-finite output"
    return "ok"


def _fuzz(kind: str, tmp_path_factory, examples: int, derandomize: bool) -> None:
    tmp = tmp_path_factory.mktemp(f"fuzz_{kind}")
    base = _base(kind, tmp)
    keys = sorted(_arrays(base))
    seen: dict[str, int] = {}

    @settings(
        max_examples=examples,
        deadline=None,
        derandomize=derandomize,
        database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    )
    @given(ops=mutation(keys))
    def run(ops):
        outcome = _check(kind, _apply(base, ops), tmp)
        seen[outcome] = seen.get(outcome, 0) + 1

    run()
    # The fuzz must exercise both ends: rejections and successful resumes.
    assert seen.get("CheckpointError", 0) > 0, seen
    print(f"checkpoint fuzz ({kind}): {sum(seen.values())} cases, outcomes {seen}")


def test_untouched_checkpoints_resume(tmp_path):
    """Control: both base checkpoints resume and give finite output."""
    for kind in MAKERS:
        assert _check(kind, _base(kind, tmp_path), tmp_path) == "ok"


@pytest.mark.filterwarnings("ignore:L-BFGS did not converge")
@pytest.mark.parametrize("kind, examples", [("rope", 400), ("fem", 100)])
def test_checkpoint_fuzz(kind, examples, tmp_path_factory):
    """A fixed sample of mutated checkpoints: success or a clear pliant error, never another exception."""
    _fuzz(kind, tmp_path_factory, examples, derandomize=True)


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:L-BFGS did not converge")
@pytest.mark.parametrize("kind, examples", [("rope", 5000), ("fem", 1500)])
def test_checkpoint_fuzz_long(kind, examples, tmp_path_factory):
    """The long random search (run with -m slow)."""
    _fuzz(kind, tmp_path_factory, examples, derandomize=False)


def test_zip_bomb_like_header_is_rejected(tmp_path):
    """An NPZ member whose .npy header claims 10¹² elements: a CheckpointError, not a MemoryError."""
    path = tmp_path / "bomb.ckpt.npz"
    header = b"\x93NUMPY\x01\x00" + b"{'descr': '<f8', 'fortran_order': False, 'shape': (1000000000000, 3), }"
    header = header + b" " * (118 - len(header)) + b"\n"
    with zipfile.ZipFile(path, "w") as z:
        for k in ("frame", "time", "v", "traj_x", "traj_t"):
            z.writestr(f"{k}.npy", header)
        z.writestr("x.npy", header)
    with pytest.raises(CheckpointError, match=str(path)):
        _rope().run(FRAMES_AFTER, progress=False, checkpoint=path, resume=True)
