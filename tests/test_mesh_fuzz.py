"""Property-based fuzz of mesh files (issue 11): ``load_mesh`` on mutated OBJ / PLY / STL / VTK / VTU / MSH
files returns a mesh with finite points and in-range indices, or raises ValueError naming the file — never
SystemExit (meshio's ``sys.exit(1)``), never another exception type, never output on stdout.

Mutations: truncate, overwrite bytes, insert bytes, replace numbers by NaN / inf / huge / negative indices,
duplicate or drop lines, or whole garbage. Default suite: a fixed sample; ``-m slow``: a long search.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import pliant as pl

POINTS = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1.0]])
TETS = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
TRIS = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])


def _bases(tmp: Path) -> dict[str, bytes]:
    import meshio
    import trimesh

    out = {}
    for ext in (".obj", ".ply", ".stl"):
        path = tmp / f"base{ext}"
        trimesh.Trimesh(POINTS[:4], TRIS, process=False).export(path)
        out[ext] = path.read_bytes()
    for ext, kw in ((".vtk", {"binary": False}), (".vtu", {"binary": False}), (".msh", {"binary": False})):
        path = tmp / f"base{ext}"
        fmt = {".msh": "gmsh22"}.get(ext)
        meshio.write(path, meshio.Mesh(POINTS, [("tetra", TETS)]), file_format=fmt, **kw)
        out[ext] = path.read_bytes()
    return out


WORDS = [b"nan", b"inf", b"-inf", b"1e39", b"1e308", b"-1", b"99999999", b"0", b"", b"\x00", b"\xff\xfe"]


@st.composite
def mutation(draw):
    ops = []
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["truncate", "overwrite", "insert", "number", "lines", "garbage"]))
        if kind == "truncate":
            ops.append((kind, draw(st.floats(0, 1))))
        elif kind in ("overwrite", "insert"):
            ops.append((kind, draw(st.floats(0, 1)), draw(st.binary(min_size=1, max_size=12))))
        elif kind == "number":
            ops.append((kind, draw(st.integers(0, 200)), draw(st.sampled_from(WORDS))))
        elif kind == "lines":
            ops.append((kind, draw(st.integers(0, 200)), draw(st.sampled_from(["drop", "dup"]))))
        else:
            ops.append((kind, draw(st.binary(max_size=200))))
    return ops


def _apply(blob: bytes, ops: list) -> bytes:
    import re

    for op in ops:
        if op[0] == "truncate":
            blob = blob[: int(op[1] * len(blob))]
        elif op[0] == "overwrite":
            at = int(op[1] * max(len(blob) - 1, 0))
            blob = blob[:at] + op[2] + blob[at + len(op[2]) :]
        elif op[0] == "insert":
            at = int(op[1] * len(blob))
            blob = blob[:at] + op[2] + blob[at:]
        elif op[0] == "number":
            nums = list(re.finditer(rb"-?\d+(\.\d+)?(e[-+]?\d+)?", blob))
            if nums:
                m = nums[op[1] % len(nums)]
                blob = blob[: m.start()] + op[2] + blob[m.end() :]
        elif op[0] == "lines":
            lines = blob.split(b"\n")
            k = op[1] % max(len(lines), 1)
            if lines:
                lines = lines[:k] + lines[k + 1 :] if op[2] == "drop" else lines[: k + 1] + lines[k:]
            blob = b"\n".join(lines)
        else:
            blob = op[1]
    return blob


def _check(path: Path, blob: bytes, capsys) -> str:
    path.write_bytes(blob)
    try:
        mesh = pl.geometry.load_mesh(path)
    except ValueError as exc:
        assert str(path) in str(exc), f"error does not name the file: {exc}"
        outcome = "ValueError"
    else:
        pts = np.asarray(mesh.points)
        cells = np.asarray(getattr(mesh, "tets", None) if hasattr(mesh, "tets") else mesh.triangles)
        assert pts.ndim == 2 and pts.shape[1] == 3 and np.all(np.isfinite(pts))
        assert cells.size and cells.min() >= 0 and cells.max() < len(pts)
        outcome = "ok"
    assert capsys.readouterr().out == "", "a mesh reader printed to stdout"
    return outcome


def _fuzz(tmp_path_factory, capsys, ext: str, examples: int, derandomize: bool) -> None:
    tmp = tmp_path_factory.mktemp("meshfuzz")
    base = _bases(tmp)[ext]
    path = tmp / f"fuzz{ext}"
    seen: dict[str, int] = {}
    assert _check(path, base, capsys) == "ok"  # control: the untouched file loads

    @settings(
        max_examples=examples,
        deadline=None,
        derandomize=derandomize,
        database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
    )
    @given(ops=mutation())
    def run(ops):
        outcome = _check(path, _apply(base, ops), capsys)
        seen[outcome] = seen.get(outcome, 0) + 1

    run()
    assert seen.get("ValueError", 0) > 0, seen
    print(f"mesh fuzz ({ext}): {sum(seen.values())} cases, outcomes {seen}")


@pytest.mark.parametrize("ext", [".obj", ".ply", ".stl", ".vtk", ".vtu", ".msh"])
def test_mesh_fuzz(ext, tmp_path_factory, capsys):
    """A fixed sample of mutated mesh files per format: a valid mesh or a ValueError naming the file."""
    _fuzz(tmp_path_factory, capsys, ext, 60, derandomize=True)


@pytest.mark.slow
@pytest.mark.parametrize("ext", [".obj", ".ply", ".stl", ".vtk", ".vtu", ".msh"])
def test_mesh_fuzz_long(ext, tmp_path_factory, capsys):
    """The long random search (run with -m slow)."""
    _fuzz(tmp_path_factory, capsys, ext, 2000, derandomize=False)
