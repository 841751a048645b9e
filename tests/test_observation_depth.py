"""Masks and depth in the observation file (issue 37): the documented dtypes load (bool / uint8 / float masks,
uint16 millimetre and float metre depth, read back in metres by ``depth_m``), and every wrong case fails
before any work with one line naming the file, the array and the fix."""

from __future__ import annotations

import numpy as np
import pytest

from pliant.gaussians._surface import ring_cameras
from pliant.io import ObservationError, Observations

C, T, H, W = 2, 3, 6, 8


def _arrays() -> dict[str, np.ndarray]:
    """A valid images-only file with masks and float32 depth in metres (0 = no reading at one pixel)."""
    rng = np.random.default_rng(0)
    cams = ring_cameras(rng.normal(size=(10, 3)), C, width=W, height=H)
    depth = rng.uniform(0.5, 3.0, size=(C, T, H, W)).astype(np.float32)
    depth[0, 1, 2, 3] = 0.0
    return {
        "t": np.arange(T) * 0.1,
        "images": rng.random((C, T, H, W, 3)).astype(np.float32),
        "K": np.stack([c.K for c in cams]),
        "world_to_camera": np.stack([c.world_to_camera for c in cams]),
        "masks": rng.random((C, T, H, W)) > 0.5,
        "depth": depth,
    }


def _load(tmp_path, **change) -> Observations:
    a = {**_arrays(), **change}
    np.savez(tmp_path / "o.npz", **{k: v for k, v in a.items() if v is not None})
    return Observations.load(tmp_path / "o.npz")


@pytest.mark.parametrize("mask_dtype", ["bool", "uint8", "float32"])
def test_masks_load_in_every_documented_dtype(tmp_path, mask_dtype):
    m = _arrays()["masks"]
    stored = {"bool": m, "uint8": m.astype(np.uint8) * 255, "float32": m.astype(np.float32)}[mask_dtype]
    obs = _load(tmp_path, masks=stored)
    assert obs.masks.dtype == np.dtype(mask_dtype)
    np.testing.assert_array_equal(obs.mask(1, 2) > 0.5, m[1, 2])


def test_depth_in_millimetres_and_metres_reads_back_in_metres(tmp_path):
    d = _arrays()["depth"]
    mm = np.round(d * 1000.0).astype(np.uint16)
    for stored, tol in ((mm, 1e-7), (d, 0.0), (d.astype(np.float64), 0.0)):
        obs = _load(tmp_path, depth=stored)
        assert obs.depth.dtype == stored.dtype  # stored as given
        got = obs.depth_m(0, 1)
        assert got.dtype == np.float32 and got.shape == (H, W)
        expect = mm[0, 1] / 1000.0 if stored.dtype == np.uint16 else d[0, 1]
        np.testing.assert_allclose(got, expect, rtol=tol, atol=tol)
        assert got[2, 3] == 0.0  # no reading stays 0
        # a round trip keeps the array bit for bit, and a training split cuts it with the images
        obs.save(tmp_path / "b.npz")
        back = Observations.load(tmp_path / "b.npz")
        np.testing.assert_array_equal(back.depth, stored)
        assert back.subset(2).depth.shape == (C, 2, H, W)
    assert _load(tmp_path, depth=None).depth is None


def test_depth_m_without_depth_names_the_array(tmp_path):
    obs = _load(tmp_path, depth=None)
    with pytest.raises(ObservationError, match=r"o\.npz: depth: this file has no depth images"):
        obs.depth_m(0, 0)


def _nan_at(d: np.ndarray) -> np.ndarray:
    d = d.copy()
    d[1, 2, 4, 5] = np.nan
    return d


def _empty_camera(m: np.ndarray) -> np.ndarray:
    m = m.copy()
    m[1] = False
    return m


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (lambda a: {"depth": a["depth"][..., :4]}, r"depth: expected \[C=2, T=3, H=6, W=8\] like images"),
        (lambda a: {"depth": a["depth"][:, :2]}, r"depth: expected \[C=2, T=3, H=6, W=8\] like images"),
        (lambda a: {"masks": a["masks"][:1]}, r"masks: expected \[C=2, T=3, H=6, W=8\] like images"),
        (
            lambda a: {
                "images": None,
                "K": None,
                "world_to_camera": None,
                "masks": None,
                "points": np.zeros((3, 1, 3)),
            },
            r"depth: given without images \[C, T, H, W, 3\]; add the camera images or drop it",
        ),
        (
            lambda a: {"masks": _empty_camera(a["masks"])},
            r"masks: camera 1 has no object pixel in any frame .*drop that camera",
        ),
        (
            lambda a: {"masks": _empty_camera(a["masks"]).astype(np.float32) * 0.4},
            r"masks: camera 0 has no object pixel in any frame \(none above 0.5\)",
        ),
        (
            lambda a: {"depth": (a["depth"] * 1000).astype(np.int32)},
            r"depth: expected uint16 millimetres or float32/float64 metres, got int32",
        ),
        (
            lambda a: {"depth": a["depth"].astype(np.float16)},
            r"depth: expected uint16 millimetres or float32/float64 metres, got float16",
        ),
        (
            lambda a: {"depth": _nan_at(a["depth"])},
            r"depth: 1 values are NaN or inf \(first at camera 1, frame 2, pixel y=4 x=5\); use 0 for no "
            r"reading",
        ),
        (
            lambda a: {"depth": np.where(np.isfinite(_nan_at(a["depth"])), a["depth"], np.inf)},
            r"depth: 1 values are NaN or inf .*use 0 for no reading",
        ),
        (
            lambda a: {"depth": -a["depth"]},
            r"depth: \d+ values are negative .*0 for no reading",
        ),
    ],
)
def test_bad_masks_and_depth_name_the_file_the_array_and_the_fix(tmp_path, change, match):
    a = _arrays()
    with pytest.raises(ObservationError, match=r"o\.npz: " + match) as e:
        _load(tmp_path, **change(a))
    assert "\n" not in str(e.value)


def test_cameras_of_complex_strings_or_overflowing_entries_are_refused_without_warnings(tmp_path):
    """Found by tests/test_fuzz_observations.py: complex K was cast to real (a ComplexWarning), string K
    raised NumPy's ValueError without the file, and a pose with 1e308 entries warned of an overflow."""
    import warnings

    a = _arrays()
    huge = a["world_to_camera"].copy()
    huge[1, 0, 1] = -1e308
    subnormal = a["K"].copy()
    subnormal[0, 0, 0] = 5e-324  # its pixel footprint 1 / fx overflowed in the twin's back-projection
    cases = [
        ({"K": a["K"].astype(complex)}, "K: expected real numbers, got complex128"),
        ({"world_to_camera": np.full((C, 4, 4), "1")}, "world_to_camera: expected real numbers, got <U1"),
        ({"world_to_camera": huge}, "world_to_camera: camera 1: not a rigid transform"),
        ({"K": subnormal}, "K: camera 0: focal lengths must be positive pixels, got fx=4.94066e-324"),
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for change, words in cases:
            with pytest.raises(ObservationError) as info:
                _load(tmp_path, **change)
            assert str(info.value).startswith(f"{tmp_path / 'o.npz'}: {words}"), str(info.value)


def test_float64_depth_beyond_float32_is_refused(tmp_path):
    """Found by tests/test_fuzz_observations.py: float64 depth of 1e300 m passed the check and became inf in
    depth_m (float32), with an overflow warning."""
    d = _arrays()["depth"].astype(np.float64)
    d[1, 2, 3, 4] = 1e300
    with pytest.raises(ObservationError, match=r"o\.npz: depth: 1 values exceed float32's range"):
        _load(tmp_path, depth=d)
    d[1, 2, 3, 4] = 3e38  # within float32: read back finite
    assert np.isfinite(_load(tmp_path, depth=d).depth_m(1, 2)).all()
