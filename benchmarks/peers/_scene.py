"""The soft box drop scene of ``pliant/bench/_fem.py``, without pliant: constants, mesh and report helpers.

Kept free of pliant imports so that the peer scripts run in a venv that holds only the peer simulator.
"""

from __future__ import annotations

import resource

import numpy as np

SIDE = 0.5  # cube side [m]
DENSITY = 1000.0  # [kg/m³]
YOUNG = 1.0e5  # [Pa]
POISSON = 0.3
DROP = 0.1  # bottom of the box above the ground [m]
FRICTION = 0.5
RADIUS = 0.005  # particle contact radius [m]
GROUND_STIFFNESS = 1.0e5  # ≈ pliant's ground penalty κ m_i (κ = 1e6 1/s², m_i ≈ 0.09 kg) [N/m]
FRAME_DT = 1.0 / 60.0
FRAMES = 60  # 1 simulated second
GRAVITY = 9.81

MU = YOUNG / (2.0 * (1.0 + POISSON))  # Lamé mu [Pa]
LAM = YOUNG * POISSON / ((1.0 + POISSON) * (1.0 - 2.0 * POISSON))  # Lamé lambda [Pa]

# pliant.geometry.box_tets' Kuhn split of a cell (corner id = dx + 2 dy + 4 dz).
_KUHN = np.array([[0, 1, 3, 7], [0, 2, 6, 7], [0, 4, 5, 7], [0, 1, 7, 5], [0, 2, 7, 3], [0, 4, 7, 6]])


def box_tets(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Points [(n+1)³, 3] and tets [6 n³, 4] of pliant's box: y up, bottom at DROP, centred on x = z = 0."""
    axis = np.linspace(0.0, SIDE, n + 1)
    z, y, x = np.meshgrid(axis, axis, axis, indexing="ij")
    points = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    points += np.array([-0.5 * SIDE, DROP, -0.5 * SIDE])
    k, j, i = np.meshgrid(np.arange(n), np.arange(n), np.arange(n), indexing="ij")
    base = (i + (n + 1) * (j + (n + 1) * k)).reshape(-1, 1)
    corner = np.array([dx + (n + 1) * (dy + (n + 1) * dz) for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)])
    cells = base + corner[None, :]
    return points, cells[:, _KUHN].reshape(-1, 4).astype(np.int32)


def lumped_mass(points: np.ndarray, tets: np.ndarray, density: float = DENSITY) -> np.ndarray:
    """ρV/4 per tet vertex [kg], as pliant and Newton lump it (``density`` ρ in kg/m³)."""
    p = points[tets]
    vol = np.abs(np.einsum("ij,ij->i", p[:, 1] - p[:, 0], np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]))) / 6
    m = np.zeros(len(points))
    np.add.at(m, tets.ravel(), np.repeat(vol * density / 4.0, 4))
    return m


def heights(x: np.ndarray, v: np.ndarray, mass: np.ndarray) -> dict:
    """pliant's sanity figures: final height of the centre of mass, top and bottom [m], max speed [m/s]."""
    x = np.asarray(x, np.float64)
    v = np.asarray(v, np.float64)
    finite = bool(np.all(np.isfinite(x)))
    return {
        "final_height_com": round(float(mass @ x[:, 1] / mass.sum()), 5) if finite else None,
        "final_height_top": round(float(x[:, 1].max()), 5) if finite else None,
        "final_height_bottom": round(float(x[:, 1].min()), 5) if finite else None,
        "final_max_speed": round(float(np.abs(v).max()), 5) if finite else None,
        "stable": finite,
    }


def peak_mem_mb() -> float:
    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)
