"""Read and write the 3D Gaussian splatting PLY layout (the files of the Inria code, gsplat, Nerfstudio,
PhysTwin; opened by common splat viewers).

One ``vertex`` element with float properties ``x y z nx ny nz f_dc_0..2 f_rest_0..(3(K−1)−1) opacity
scale_0..2 rot_0..3``: opacity as a logit, scales as natural logs, rotation as a w x y z quaternion, and the
higher SH coefficients stored channel-major (all K−1 red coefficients, then green, then blue).
"""

from __future__ import annotations

import os

import numpy as np

from ._gaussians import Gaussians

_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
REQUIRED = [
    "x",
    "y",
    "z",
    "f_dc_0",
    "f_dc_1",
    "f_dc_2",
    "opacity",
    "scale_0",
    "scale_1",
    "scale_2",
    "rot_0",
    "rot_1",
    "rot_2",
    "rot_3",
]


class PlyError(ValueError):
    """A PLY file that is not a readable 3D Gaussian splatting file."""


def _read_header(f, path):
    first = f.readline().strip()
    if first != b"ply":
        raise PlyError(f"{path}: not a PLY file (first line {first[:20]!r})")
    fmt = None
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    while True:
        line = f.readline()
        if not line:
            raise PlyError(f"{path}: the header has no end_header line")
        words = line.decode("ascii", errors="replace").split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "end_header":
            break
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "element":
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property":
            if not elements:
                raise PlyError(f"{path}: a property comes before any element")
            if words[1] == "list":
                elements[-1][2].append(("list", words[-1]))
            else:
                if words[1] not in _TYPES:
                    raise PlyError(f"{path}: unknown property type {words[1]!r}")
                elements[-1][2].append((words[1], words[2]))
    if fmt not in ("binary_little_endian", "binary_big_endian", "ascii"):
        raise PlyError(f"{path}: unsupported PLY format {fmt!r}")
    return fmt, elements


def load_ply(
    path: str | os.PathLike, *, dtype: str = "float32", device: str | None = None, requires_grad: bool = False
) -> Gaussians:
    """Load a 3D Gaussian splatting PLY file.

    Args:
        path: File path.
        dtype: ``"float32"`` or ``"float64"`` for the returned arrays.
        device: Warp device (default: CUDA when present).
        requires_grad: Allocate gradients for every parameter.

    Raises:
        PlyError: not a PLY, no ``vertex`` element, list properties in it, required properties missing (all
            are named), or an ``f_rest`` count that is not 0, 9, 24 or 45 (SH degree 0-3).
    """
    path = os.fspath(path)
    with open(path, "rb") as f:
        fmt, elements = _read_header(f, path)
        names = [e[0] for e in elements]
        if "vertex" not in names:
            raise PlyError(f"{path}: no 'vertex' element (elements: {names})")
        data = None
        for name, count, props in elements:
            if any(t == "list" for t, _ in props):
                if name == "vertex":
                    raise PlyError(f"{path}: list properties in the vertex element are not supported")
                if data is None:
                    raise PlyError(f"{path}: element {name!r} with list properties precedes 'vertex'")
                break
            endian = ">" if fmt == "binary_big_endian" else "<"
            record = np.dtype([(pn, endian + _TYPES[pt]) for pt, pn in props])  # one vertex
            # The header's count is checked against the bytes left before anything is allocated for it: an
            # ASCII row needs at least two bytes per property ("0 "), a binary one its record's size.
            need = count * (2 * len(props) if fmt == "ascii" else record.itemsize)
            left = os.fstat(f.fileno()).st_size - f.tell()
            if count < 0 or need > left:
                raise PlyError(
                    f"{path}: element {name!r} declares {count} rows, at least {need} bytes, but the file "
                    f"holds {left} bytes after its header; it is truncated or its header is wrong"
                )
            if fmt == "ascii":
                rows = [f.readline().split() for _ in range(count)]
                arr = np.zeros(count, dtype=record)
                if count:
                    table = np.asarray(rows, dtype=np.float64)
                    for k, (_, pn) in enumerate(props):
                        arr[pn] = table[:, k]
            else:
                arr = np.frombuffer(f.read(record.itemsize * count), dtype=record, count=count)
            if name == "vertex":
                data = arr
                break
    assert data is not None  # "vertex" is an element (checked above), read before any break
    present = set(data.dtype.names or ())
    missing = [p for p in REQUIRED if p not in present]
    if missing:
        raise PlyError(f"{path}: missing required Gaussian properties: {', '.join(missing)}")
    rest = sorted((p for p in present if p.startswith("f_rest_")), key=lambda s: int(s[7:]))
    if len(rest) not in (0, 9, 24, 45) or [int(s[7:]) for s in rest] != list(range(len(rest))):
        raise PlyError(
            f"{path}: {len(rest)} f_rest_* properties; expected f_rest_0.. with 0, 9, 24 or 45 (SH 0-3)"
        )
    col = lambda names: np.stack([np.asarray(data[n], np.float64) for n in names], axis=1)  # noqa: E731
    n = len(data)
    k = len(rest) // 3 + 1
    sh = np.zeros((n, k, 3))
    sh[:, 0] = col(["f_dc_0", "f_dc_1", "f_dc_2"])
    if rest:
        sh[:, 1:] = col(rest).reshape(n, 3, k - 1).transpose(0, 2, 1)
    return Gaussians(
        col(["x", "y", "z"]),
        col([f"rot_{i}" for i in range(4)]),
        col([f"scale_{i}" for i in range(3)]),
        np.asarray(data["opacity"], np.float64),
        sh,
        dtype=dtype,
        device=device,
        requires_grad=requires_grad,
    )


def save_ply(gaussians: Gaussians, path: str | os.PathLike) -> None:
    """Write ``gaussians`` as a binary little-endian 3D Gaussian splatting PLY (float32 properties).

    Args:
        gaussians: The set to write (any dtype or device); ``transforms`` are baked into rotations and scales.
        path: File path (overwritten).
    """
    p = (gaussians if gaussians.transforms is None else gaussians.baked()).numpy()
    n, k = p["sh"].shape[:2]
    rest = p["sh"][:, 1:].transpose(0, 2, 1).reshape(n, 3 * (k - 1))
    cols = [
        p["means"],
        np.zeros((n, 3)),
        p["sh"][:, 0],
        rest,
        p["opacity_logits"][:, None],
        p["log_scales"],
        p["quats"],
    ]
    names = (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(3 * (k - 1))]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    )
    table = np.ascontiguousarray(np.concatenate(cols, axis=1), dtype="<f4")
    header = "ply\nformat binary_little_endian 1.0\ncomment written by pliant\n"
    header += f"element vertex {n}\n" + "".join(f"property float {nm}\n" for nm in names) + "end_header\n"
    with open(os.fspath(path), "wb") as f:
        f.write(header.encode("ascii"))
        f.write(table.tobytes())
