"""Observation files (issue 13's contract): round trip, validation errors, time checks, particle binding."""

from __future__ import annotations

import numpy as np
import pytest

from pliant.io import ObservationError, Observations


def _arrays(T: int = 4, K: int = 3) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(T, K, 3))
    vis = np.ones((T, K), bool)
    vis[2, 1] = False
    pts[2, 1] = np.nan
    return {
        "t": np.arange(T) * 0.1,
        "points": pts,
        "visible": vis,
        "particle": np.array([0, 2, 1]),
        "controls": rng.normal(size=(T, 2, 3)),
        "cloud": rng.normal(size=(T, 5, 3)),
        "cloud_count": np.array([5, 4, 3, 5]),
    }


def test_round_trip_keeps_every_array(tmp_path):
    """save → load gives back the same arrays (NaN where hidden), optional ones included."""
    a = _arrays()
    obs = Observations.from_arrays(**a)
    obs.save(tmp_path / "o.npz")
    back = Observations.load(tmp_path / "o.npz")
    np.testing.assert_array_equal(back.t, a["t"])
    np.testing.assert_array_equal(back.visible, a["visible"])
    np.testing.assert_array_equal(back.points[a["visible"]], a["points"][a["visible"]])
    assert np.isnan(back.points[2, 1]).all()
    for k in ("particle", "controls", "cloud", "cloud_count"):
        np.testing.assert_array_equal(getattr(back, k), a[k])


def test_visible_defaults_to_finite_points(tmp_path):
    a = _arrays()
    np.savez(tmp_path / "o.npz", t=a["t"], points=a["points"])
    obs = Observations.load(tmp_path / "o.npz")
    np.testing.assert_array_equal(obs.visible, np.isfinite(a["points"]).all(axis=2))
    assert obs.particle is None and obs.cloud is None


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"points": np.zeros((4, 3))}, r"o\.npz: points: expected \[T=4, K, 3\]"),
        ({"visible": np.ones((4, 3), int)}, r"visible: expected a bool array"),
        ({"t": np.array([0.0, 0.2, 0.1, 0.3])}, r"t: times must be finite and strictly increasing"),
        ({"visible": np.zeros((4, 3), bool)}, r"visible: every track is invisible"),
        ({"particle": np.array([0, 1])}, r"particle: expected K=3 particle indices"),
        ({"cloud_count": np.array([5, 4, 3, 9])}, r"cloud_count: counts must lie in \[0, P=5\]"),
        ({"controls": np.zeros((3, 2, 3))}, r"controls: expected \[T=4, C, 3\]"),
        ({"extra": np.zeros(3)}, r"extra: unknown array"),
        # found by tests/test_fuzz_observations.py: complex values were cast to real with a ComplexWarning,
        # strings raised NumPy's ValueError without the file
        ({"t": np.arange(4) * 0.1 + 0j}, r"o\.npz: t: expected times \[T\] in seconds .*complex128"),
        ({"controls": np.full((4, 2, 3), "abc")}, r"o\.npz: controls: expected real numbers, got <U3"),
        ({"cloud": np.zeros((4, 5, 3), complex)}, r"o\.npz: cloud: expected real numbers, got complex128"),
    ],
)
def test_bad_files_name_the_file_and_the_array(tmp_path, change, match):
    a = {**_arrays(), **change}
    np.savez(tmp_path / "o.npz", **a)
    with pytest.raises(ObservationError, match=match):
        Observations.load(tmp_path / "o.npz")


def test_nan_in_a_visible_point_is_an_error(tmp_path):
    a = _arrays()
    a["visible"][2, 1] = True
    np.savez(tmp_path / "o.npz", **a)
    with pytest.raises(ObservationError, match=r"point 1 at frame 2 is NaN or inf but marked visible"):
        Observations.load(tmp_path / "o.npz")


def test_pickled_arrays_are_refused(tmp_path):
    """allow_pickle=False: an object array (which would unpickle arbitrary code) is not read."""
    a = _arrays()
    np.savez(tmp_path / "o.npz", t=a["t"], points=np.array([{"x": 1}], dtype=object))
    with pytest.raises(ObservationError, match="not a readable observation NPZ"):
        Observations.load(tmp_path / "o.npz")


def test_missing_file_and_missing_arrays(tmp_path):
    with pytest.raises(FileNotFoundError, match="observation file not found"):
        Observations.load(tmp_path / "none.npz")
    np.savez(tmp_path / "o.npz", t=np.arange(3.0))
    with pytest.raises(ObservationError, match=r"points: missing"):
        Observations.load(tmp_path / "o.npz")


def test_times_must_match_the_scene_frames():
    obs = Observations.from_arrays(**_arrays())
    obs.check_times(0.1)  # t = 0, 0.1, 0.2, 0.3
    with pytest.raises(ObservationError, match=r"t\[1\] = 0\.1 s but frame 1 of the scene is at 0\.05 s"):
        obs.check_times(0.05)


def test_binding_picks_the_nearest_particle_at_the_first_visible_frame():
    """Track 0 is first seen at frame 0 near particle 2; track 1 first at frame 1 near particle 0 there."""
    x = np.array(
        [
            [[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]],  # frame 0
            [[5.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]],  # frame 1: particle 0 has moved to x = 5
        ]
    )
    pts = np.array([[[1.9, 0.1, 0], [np.nan] * 3], [[2.0, 0, 0], [4.8, 0, 0.1]]])
    obs = Observations.from_arrays(t=np.array([0.0, 0.1]), points=pts).bind(x)
    np.testing.assert_array_equal(obs.particle, [2, 0])
    # With positions of frame 0 only, track 1 goes to the particle nearest x = 4.8 then: particle 2.
    np.testing.assert_array_equal(
        Observations.from_arrays(t=np.array([0.0, 0.1]), points=pts).bind(x[0]).particle, [2, 2]
    )


def test_given_particles_beyond_the_scene_are_an_error():
    a = _arrays()
    obs = Observations.from_arrays(**{**a, "particle": np.array([0, 1, 7])})
    with pytest.raises(ObservationError, match=r"particle: index 7 but the scene has 3 particles"):
        obs.bind(np.zeros((3, 3)))


def test_an_empty_particle_array_beside_no_tracks_loads(tmp_path):
    """Clouds without tracks and ``particle`` [0] (found by the fuzz: ``min()`` of a zero-size array)."""
    a = _arrays()
    np.savez(
        tmp_path / "o.npz",
        t=a["t"],
        points=np.zeros((4, 0, 3)),
        particle=np.zeros(0, int),
        cloud=a["cloud"],
        cloud_count=a["cloud_count"],
    )
    obs = Observations.load(tmp_path / "o.npz")
    assert obs.tracks == 0 and obs.particle.shape == (0,)
