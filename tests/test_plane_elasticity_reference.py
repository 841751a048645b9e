"""The 2D Q9 plane-elasticity oracle of tests/reference/plane_elasticity.py against closed forms, and the
published Cook's-membrane value it sets the 3D benchmark's reference point by."""

from __future__ import annotations

import numpy as np
import pytest

from tests.reference.plane_elasticity import COOK_CORNERS, cook_membrane_2d, solve_quad_panel


def test_patch_test_reproduces_a_linear_field_on_a_distorted_mesh():
    """Every boundary node held on an affine displacement: the interior nodes of the tapered Cook mesh (its
    elements are not parallelograms) carry it exactly."""
    A = np.array([[0.01, -0.02], [0.03, 0.005]])
    c = np.array([0.1, -0.2])

    def exact(x):
        return x @ A.T + c

    X, u, ids = solve_quad_panel(
        COOK_CORNERS,
        3,
        4,
        E=2.0,
        nu=0.3,
        fixed=lambda st: np.any((st == 0.0) | (st == 1.0), axis=1),
        u_fixed=exact,
    )
    interior = ids[1:-1, 1:-1].ravel()
    assert len(interior) == 5 * 7
    np.testing.assert_allclose(u[interior], exact(X[interior]), atol=1e-12)


@pytest.mark.parametrize("plane", ["stress", "strain"])
def test_cantilever_matches_the_timoshenko_goodier_solution(plane):
    """Cantilever L = 10, depth D = 2, parabolic end shear of total P (Timoshenko & Goodier 1970, §21, in
    the form of Augarde & Deeks 2008): with the exact displacement held at x = 0 and the exact traction on
    x = L, the displacement on 16 × 4 Q9 elements is within 3e-5 of the tip's closed form at every node,
    and 8 times closer than on 8 × 2."""
    L, D, P, E0, nu0 = 10.0, 2.0, 1.0e-3, 1.0e3, 0.3
    # Plane strain is plane stress with E' = E/(1-ν²), ν' = ν/(1-ν) in the closed form.
    E, nu = (E0, nu0) if plane == "stress" else (E0 / (1 - nu0**2), nu0 / (1 - nu0))
    inertia = D**3 / 12.0

    def exact(x):
        X, Y = x[:, 0], x[:, 1]
        ux = -P * Y / (6 * E * inertia) * ((6 * L - 3 * X) * X + (2 + nu) * (Y * Y - D * D / 4))
        uy = (
            P
            / (6 * E * inertia)
            * (3 * nu * Y * Y * (L - X) + (4 + 5 * nu) * D * D * X / 4 + (3 * L - X) * X * X)
        )
        return np.stack([ux, uy], 1)

    corners = np.array([[0.0, -D / 2], [L, -D / 2], [L, D / 2], [0.0, D / 2]])
    tip = exact(np.array([[L, 0.0]]))[0, 1]  # the beam formula plus Timoshenko's shear term
    assert tip == pytest.approx(P * L**3 / (3 * E * inertia) * (1 + (4 + 5 * nu) * D * D / (8 * L * L)))
    errors = []
    for n_s, n_t in ((8, 2), (16, 4)):
        X, u, _ = solve_quad_panel(
            corners,
            n_s,
            n_t,
            E=E0,
            nu=nu0,
            plane=plane,
            u_fixed=exact,
            traction=lambda x: np.stack([0 * x[:, 0], P / (2 * inertia) * (D * D / 4 - x[:, 1] ** 2)], 1),
        )
        errors.append(np.abs(u - exact(X)).max() / tip)
    # u_y is cubic in x, which Q9 cannot hold exactly: the error falls as h^3 or faster at the nodes.
    assert errors[1] < 3e-5 and errors[0] > 8 * errors[1], errors


def test_cook_membrane_reaches_the_published_value_at_the_mid_edge():
    """Plane stress, E = 1, ν = 1/3, F = 1: the vertical displacement of the loaded edge's midpoint
    (48, 52) converges to the published 23.96 (within 0.05 % on 16² Q9 elements, rising to 23.967 on
    128²); the top corner (48, 60), where pliant's 3D benchmark used to measure, sits near 25.2 instead."""
    r8, r16 = cook_membrane_2d(8), cook_membrane_2d(16)
    assert r16["mid_edge"] == pytest.approx(23.96, rel=5e-4)
    assert r8["mid_edge"] < r16["mid_edge"]  # converging from below, as a displacement method must
    assert 25.0 < r16["top_corner"] < 25.2
