"""FEM maths: materials, element Warp functions against float64 oracles, mass matrices, barycentrics."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import warp as wp
from reference import fem as ref

from pliant.energies import _fem_math as fm
from pliant.energies._materials import (
    MATERIAL_MODELS,
    Material,
    get_material_model,
    lame_parameters,
    young_poisson,
)
from pliant.geometry._barycentric import barycentric_coordinates, interpolate, locate_points, shape_functions
from pliant.model._mass import tet_consistent_mass, tet_lumped_mass, triangle_lumped_mass

NAMES = ["linear", "stvk", "corotated", "neohookean"]
ISOTROPIC = ["stvk", "corotated", "neohookean"]
MU, LAM = lame_parameters(1.0, 0.4)

# ------------------------------------------------------------------------------------- test kernels


@wp.kernel(enable_backward=False)
def _eval_materials(
    F: wp.array(dtype=Any),
    mu: Any,
    lam: Any,
    psi_out: wp.array2d(dtype=Any),
    P_out: wp.array2d(dtype=Any),
    H_out: wp.array2d(dtype=Any),
    Hp_out: wp.array2d(dtype=Any),
):
    t = wp.tid()
    f = F[t]
    psi_out[t, 0] = fm.linear_psi(f, mu, lam)
    P_out[t, 0] = fm.linear_pk1(f, mu, lam)
    H_out[t, 0] = fm.linear_dpk1_df(f, mu, lam)
    Hp_out[t, 0] = fm.linear_dpk1_df_psd(f, mu, lam)
    psi_out[t, 1] = fm.stvk_psi(f, mu, lam)
    P_out[t, 1] = fm.stvk_pk1(f, mu, lam)
    H_out[t, 1] = fm.stvk_dpk1_df(f, mu, lam)
    Hp_out[t, 1] = fm.stvk_dpk1_df_psd(f, mu, lam)
    psi_out[t, 2] = fm.corotated_psi(f, mu, lam)
    P_out[t, 2] = fm.corotated_pk1(f, mu, lam)
    H_out[t, 2] = fm.corotated_dpk1_df(f, mu, lam)
    Hp_out[t, 2] = fm.corotated_dpk1_df_psd(f, mu, lam)
    psi_out[t, 3] = fm.neohookean_psi(f, mu, lam)
    P_out[t, 3] = fm.neohookean_pk1(f, mu, lam)
    H_out[t, 3] = fm.neohookean_dpk1_df(f, mu, lam)
    Hp_out[t, 3] = fm.neohookean_dpk1_df_psd(f, mu, lam)


@wp.kernel(enable_backward=False)
def _eval_elements(
    X: wp.array2d(dtype=Any),
    x: wp.array2d(dtype=Any),
    mu: Any,
    lam: Any,
    F_out: wp.array2d(dtype=Any),
    f_out: wp.array3d(dtype=Any),
    H_out: wp.array3d(dtype=Any),
):
    """Per tet t and material m: F, the 4 forces and the 16 projected Hessian blocks."""
    t, m = wp.tid()
    Dm = fm.tet_rest_matrix(X[t, 0], X[t, 1], X[t, 2], X[t, 3])
    Dm_inv = wp.inverse(Dm)
    V = fm.tet_signed_volume(Dm)
    F = fm.deformation_gradient(x[t, 0], x[t, 1], x[t, 2], x[t, 3], Dm_inv)
    P = fm.linear_pk1(F, mu, lam)
    A = fm.linear_dpk1_df_psd(F, mu, lam)
    if m == 1:
        P = fm.stvk_pk1(F, mu, lam)
        A = fm.stvk_dpk1_df_psd(F, mu, lam)
    elif m == 2:
        P = fm.corotated_pk1(F, mu, lam)
        A = fm.corotated_dpk1_df_psd(F, mu, lam)
    elif m == 3:
        P = fm.neohookean_pk1(F, mu, lam)
        A = fm.neohookean_dpk1_df_psd(F, mu, lam)
    F_out[t, m] = F
    f0, f1, f2, f3 = fm.tet_forces(P, Dm_inv, V)
    f_out[t, m, 0] = f0
    f_out[t, m, 1] = f1
    f_out[t, m, 2] = f2
    f_out[t, m, 3] = f3
    for a in range(4):
        for b in range(4):
            H_out[t, m, 4 * a + b] = fm.tet_hessian_block(A, Dm_inv, V, a, b)


@wp.kernel
def _energy_sum(
    F: wp.array(dtype=wp.mat33d), mu: wp.float64, lam: wp.float64, psi_sum: wp.array(dtype=wp.float64)
):
    """psi_sum[m] += ψ_m(F[t]) for the four materials m (for wp.Tape)."""
    t = wp.tid()
    wp.atomic_add(psi_sum, 0, fm.linear_psi(F[t], mu, lam))
    wp.atomic_add(psi_sum, 1, fm.stvk_psi(F[t], mu, lam))
    wp.atomic_add(psi_sum, 2, fm.corotated_psi(F[t], mu, lam))
    wp.atomic_add(psi_sum, 3, fm.neohookean_psi(F[t], mu, lam))


_TYPES = {
    "float32": (wp.float32, wp.vec3f, wp.mat33f, fm.mat99f, np.float32),
    "float64": (wp.float64, wp.vec3d, wp.mat33d, fm.mat99d, np.float64),
}
# declare both overloads up front so the test module compiles once
for _s, _v, _m, _h, _ in _TYPES.values():
    wp.overload(
        _eval_materials,
        {
            "F": wp.array(dtype=_m),
            "mu": _s,
            "lam": _s,
            "psi_out": wp.array2d(dtype=_s),
            "P_out": wp.array2d(dtype=_m),
            "H_out": wp.array2d(dtype=_h),
            "Hp_out": wp.array2d(dtype=_h),
        },
    )
    wp.overload(
        _eval_elements,
        {
            "X": wp.array2d(dtype=_v),
            "x": wp.array2d(dtype=_v),
            "mu": _s,
            "lam": _s,
            "F_out": wp.array2d(dtype=_m),
            "f_out": wp.array3d(dtype=_v),
            "H_out": wp.array3d(dtype=_m),
        },
    )


def run_materials(Fs: np.ndarray, dtype: str) -> dict[str, np.ndarray]:
    """Evaluate ψ, P, ∂P/∂F, projected ∂P/∂F of the four materials in Warp at each F [n, 3, 3]."""
    s, _, m33, m99, np_t = _TYPES[dtype]
    n = len(Fs)
    F = wp.array(np.asarray(Fs, dtype=np_t), dtype=m33, device="cpu")
    psi = wp.zeros((n, 4), dtype=s, device="cpu")
    P = wp.zeros((n, 4), dtype=m33, device="cpu")
    H = wp.zeros((n, 4), dtype=m99, device="cpu")
    Hp = wp.zeros((n, 4), dtype=m99, device="cpu")
    wp.launch(_eval_materials, dim=n, inputs=[F, s(MU), s(LAM)], outputs=[psi, P, H, Hp], device="cpu")
    return {"psi": psi.numpy(), "P": P.numpy(), "H": H.numpy(), "Hp": Hp.numpy()}


def run_elements(X: np.ndarray, x: np.ndarray, dtype: str) -> dict[str, np.ndarray]:
    """Evaluate F, forces [n, 4, 4, 3] and projected Hessian blocks [n, 4, 16, 3, 3] for rest X, current x."""
    s, v3, m33, _, np_t = _TYPES[dtype]
    n = len(X)
    Xw = wp.array(np.asarray(X, dtype=np_t), dtype=v3, device="cpu")
    xw = wp.array(np.asarray(x, dtype=np_t), dtype=v3, device="cpu")
    F = wp.zeros((n, 4), dtype=m33, device="cpu")
    f = wp.zeros((n, 4, 4), dtype=v3, device="cpu")
    H = wp.zeros((n, 4, 16), dtype=m33, device="cpu")
    wp.launch(_eval_elements, dim=(n, 4), inputs=[Xw, xw, s(MU), s(LAM)], outputs=[F, f, H], device="cpu")
    return {"F": F.numpy(), "f": f.numpy(), "H": H.numpy()}


def blocks_to_12x12(blocks: np.ndarray) -> np.ndarray:
    """[16, 3, 3] blocks H_ab (index 4a + b) -> 12×12."""
    return blocks.reshape(4, 4, 3, 3).transpose(0, 2, 1, 3).reshape(12, 12)


def max_rel(a: np.ndarray, b: np.ndarray) -> float:
    """max |a − b| / max |b| (error relative to the scale of the reference)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


# ------------------------------------------------------------------------------------------- inputs

_rng = np.random.default_rng(20240611)
F_SETS = {
    "near": np.array(ref.random_deformations(_rng, 12, near_rest=True)),
    "far": np.array(ref.random_deformations(_rng, 12, near_rest=False)),
    # inverted: σ = (σ1, σ2, −σ3), |σ3| < σ2
    "inverted": np.array(
        [
            ref.random_rotation(_rng)
            @ np.diag([_rng.uniform(1.0, 2.0), _rng.uniform(1.0, 1.5), -_rng.uniform(0.2, 0.6)])
            @ ref.random_rotation(_rng).T
            for _ in range(8)
        ]
    ),
    # uniform-ish tension: every material's ∂P/∂F is PSD here
    "tension": np.array(
        [
            ref.random_rotation(_rng) @ np.diag(_rng.uniform(1.01, 1.05, 3)) @ ref.random_rotation(_rng).T
            for _ in range(6)
        ]
    ),
}
Q_ROT = [ref.random_rotation(_rng) for _ in range(12)]
F_SETS["rotated"] = np.array([Q @ F for Q, F in zip(Q_ROT, F_SETS["far"])])
SMALL_EPS = 1e-6
SMALL_H = _rng.standard_normal((6, 3, 3))
F_SETS["small"] = np.eye(3) + SMALL_EPS * SMALL_H
STRETCH = np.linspace(0.5, 2.0, 7)
F_SETS["uniaxial"] = np.array([np.diag([s, 1.0, 1.0]) for s in STRETCH])
F_SETS["rest"] = np.eye(3)[None]
_ORDER = list(F_SETS)
_ALL_F = np.concatenate([F_SETS[k] for k in _ORDER])
_OFFSETS = np.cumsum([0] + [len(F_SETS[k]) for k in _ORDER])


def _split(out: dict[str, np.ndarray]) -> dict[str, dict[str, np.ndarray]]:
    return {k: {q: v[_OFFSETS[i] : _OFFSETS[i + 1]] for q, v in out.items()} for i, k in enumerate(_ORDER)}


@pytest.fixture(scope="module")
def warp_materials() -> dict[str, dict[str, dict[str, np.ndarray]]]:
    """Warp results for every F set, in both precisions (one launch each)."""
    return {dt: _split(run_materials(_ALL_F, dt)) for dt in _TYPES}


def _ref_all(F: np.ndarray, name: str, mu: float = MU, lam: float = LAM) -> dict[str, np.ndarray]:
    psi, pk1, dpk1 = ref.MATERIALS[name]
    H = dpk1(F, mu, lam)
    return {"psi": psi(F, mu, lam), "P": pk1(F, mu, lam), "H": H, "Hp": ref.project_psd(H)}


# ---------------------------------------------------------------------------------------- materials


def test_lame_parameters_values_and_inverse():
    """E = 1, ν = 0.25 gives μ = λ = 0.4, arrays work, and young_poisson inverts lame_parameters."""
    assert lame_parameters(1.0, 0.25) == pytest.approx((0.4, 0.4), rel=1e-15)
    mu, lam = lame_parameters(np.array([1.0, 2.0]), np.array([0.25, 0.0]))
    np.testing.assert_allclose(mu, [0.4, 1.0], rtol=1e-15)
    np.testing.assert_allclose(lam, [0.4, 0.0], atol=1e-15)
    assert young_poisson(*lame_parameters(3.0e5, 0.45)) == pytest.approx((3.0e5, 0.45), rel=1e-12)


@pytest.mark.parametrize(
    "E, nu, field", [(0.0, 0.3, "E"), (-1.0, 0.3, "E"), (1.0, 0.5, "nu"), (1.0, -1.0, "nu")]
)
def test_lame_parameters_rejects_invalid(E, nu, field):
    """Invalid E or ν raises ValueError naming the field."""
    with pytest.raises(ValueError, match=rf"^{field} "):
        lame_parameters(E, nu)


def test_material_registry():
    """The registry holds the four models; unknown names and bad constants raise a descriptive ValueError."""
    assert sorted(MATERIAL_MODELS) == sorted(NAMES)
    assert get_material_model("stvk").pk1 is fm.stvk_pk1
    with pytest.raises(ValueError, match="allowed values: 'linear', 'stvk', 'corotated', 'neohookean'"):
        get_material_model("mooney")
    m = Material("neohookean", E=1e6, nu=0.45, density=1100.0)
    assert (m.mu, m.lam) == pytest.approx(lame_parameters(1e6, 0.45))
    with pytest.raises(ValueError, match="unknown material model"):
        Material("rubber", E=1e6, nu=0.45, density=1100.0)
    with pytest.raises(ValueError, match="density"):
        Material("stvk", E=1e6, nu=0.3, density=0.0)


# ---------------------------------------------------------------------- reference against finite differences


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("regime", ["near", "far"])
def test_reference_derivatives(name, regime):
    """Reference P = ∂ψ/∂F and ∂P/∂F = ∂P/∂F by central differences (rtol 1e-6 of the scale)."""
    psi, pk1, dpk1 = ref.MATERIALS[name]
    for F in F_SETS[regime][:6]:
        P = pk1(F, MU, LAM)
        P_fd = ref.central_diff(lambda G: psi(G, MU, LAM), F, h=1e-6)
        assert max_rel(P, P_fd) < 1e-6, (name, regime, max_rel(P, P_fd))
        H = dpk1(F, MU, LAM)
        H_fd = ref.central_diff(lambda v: ref.vec(pk1(ref.unvec(v), MU, LAM)), ref.vec(F), h=1e-6)
        assert max_rel(H, H_fd) < 1e-6, (name, regime, max_rel(H, H_fd))
        np.testing.assert_allclose(H, H.T, atol=1e-12 * np.abs(H).max())


def test_reference_element_forces_and_hessian():
    """Reference element forces = −∇(Vψ) and Hessian = −∂f/∂x by central differences."""
    X = np.array([[0.0, 0.0, 0.0], [1.0, 0.1, 0.0], [0.2, 0.9, 0.1], [0.1, 0.2, 1.1]])
    x = X @ np.array([[1.2, 0.1, 0.0], [-0.1, 0.9, 0.2], [0.1, 0.0, 1.1]]).T + 0.02 * _rng.standard_normal(
        (4, 3)
    )
    for name in NAMES:
        psi, pk1, dpk1 = ref.MATERIALS[name]
        f = ref.tet_forces(x, X, pk1, MU, LAM)
        g_fd = ref.central_diff(lambda y: ref.tet_energy(y, X, psi, MU, LAM), x, h=1e-6)
        assert max_rel(f, -g_fd) < 1e-6, name
        H = ref.tet_hessian(x, X, dpk1, MU, LAM)
        H_fd = -ref.central_diff(lambda y: ref.tet_forces(y, X, pk1, MU, LAM).ravel(), x, h=1e-6).reshape(
            12, 12
        )
        assert max_rel(H, H_fd) < 1e-6, name


# ----------------------------------------------------------------------------- Warp against the reference

_TOL = {"float64": 1e-10, "float32": 1e-4}


@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("regime", ["near", "far", "inverted", "tension"])
def test_warp_materials_match_reference(warp_materials, dtype, regime):
    """Warp ψ, P, ∂P/∂F and projected ∂P/∂F equal the float64 reference (f64 1e-10, f32 1e-4 relative)."""
    got = warp_materials[dtype][regime]
    np_t = _TYPES[dtype][4]
    mu, lam = float(np_t(MU)), float(np_t(LAM))
    worst = {}
    for c, name in enumerate(NAMES):
        for i, F in enumerate(F_SETS[regime]):
            F = np.asarray(F, dtype=np_t).astype(np.float64)  # the F Warp saw
            want = _ref_all(F, name, mu, lam)
            for q in ("psi", "P", "H", "Hp"):
                worst[(name, q)] = max(worst.get((name, q), 0.0), max_rel(got[q][i, c], want[q]))
    bad = {k: v for k, v in worst.items() if v > _TOL[dtype]}
    assert not bad, f"relative errors above {_TOL[dtype]}: {bad}"


def test_tape_gradient_of_psi_is_pk1(warp_materials):
    """wp.Tape's adjoint of ψ (through det and svd3) equals the analytic P (f64, 1e-9)."""
    Fs = np.concatenate([F_SETS["near"], F_SETS["far"]])
    F = wp.array(Fs, dtype=wp.mat33d, device="cpu", requires_grad=True)
    for m, name in enumerate(NAMES):
        psi_sum = wp.zeros(4, dtype=wp.float64, device="cpu", requires_grad=True)
        tape = wp.Tape()
        with tape:
            wp.launch(_energy_sum, dim=len(Fs), inputs=[F, MU, LAM], outputs=[psi_sum], device="cpu")
        tape.backward(grads={psi_sum: wp.array(np.eye(4)[m], dtype=wp.float64, device="cpu")})
        P = np.concatenate(
            [warp_materials["float64"]["near"]["P"][:, m], warp_materials["float64"]["far"]["P"][:, m]]
        )
        assert max_rel(F.grad.numpy(), P) < 1e-9, (name, max_rel(F.grad.numpy(), P))
        tape.zero()


def test_rest_state_is_stress_free(warp_materials):
    """At F = I every material has ψ = 0 and P = 0 (Warp f64 and f32)."""
    for dtype, tol in (("float64", 1e-14), ("float32", 1e-6)):
        got = warp_materials[dtype]["rest"]
        assert np.abs(got["psi"]).max() <= tol * MU, (dtype, got["psi"])
        assert np.abs(got["P"]).max() <= tol * MU, (dtype, got["P"])
    for name in NAMES:
        assert ref.MATERIALS[name][0](np.eye(3), MU, LAM) == pytest.approx(0.0, abs=1e-15)


def test_rotation_invariance(warp_materials):
    """ψ(QF) = ψ(F) and P(QF) = Q P(F) for random rotations Q (isotropic materials, Warp f64)."""
    far = warp_materials["float64"]["far"]
    rot = warp_materials["float64"]["rotated"]
    for c, name in enumerate(NAMES):
        if name not in ISOTROPIC:
            continue
        assert max_rel(rot["psi"][:, c], far["psi"][:, c]) < 1e-12, name
        QP = np.array([Q @ P for Q, P in zip(Q_ROT, far["P"][:, c])])
        assert max_rel(rot["P"][:, c], QP) < 1e-12, name


def test_small_strain_limit(warp_materials):
    """For F = I + εH (ε = 1e-6), P of StVK, corotated and neo-Hookean equals linear elasticity's to 1e-4."""
    got = warp_materials["float64"]["small"]
    P_lin = got["P"][:, 0]
    for c, name in enumerate(NAMES):
        if name == "linear":
            continue
        err = max(max_rel(got["P"][i, c], P_lin[i]) for i in range(len(P_lin)))
        assert err < 1e-4, (name, err)
        # the difference is second order: ~ε relative, far below the tolerance
        assert err < 100 * SMALL_EPS, (name, err)


def test_uniaxial_stress_closed_forms(warp_materials):
    """Under F = diag(s, 1, 1), P11 and P22 match hand-derived closed forms for each material."""
    s = STRETCH
    mu, lam = MU, LAM
    expect = {
        "linear": ((2 * mu + lam) * (s - 1), lam * (s - 1)),
        "stvk": (s * (mu + lam / 2) * (s**2 - 1), lam / 2 * (s**2 - 1)),
        "corotated": ((2 * mu + lam) * (s - 1), lam * (s - 1) * s),
        "neohookean": ((2 * mu + lam) * (s - 1), mu * (1 - s) + (lam + mu) * (s - 1) * s),
    }
    for dtype, tol in (("float64", 1e-12), ("float32", 1e-5)):
        P = warp_materials[dtype]["uniaxial"]["P"]
        for c, name in enumerate(NAMES):
            p11, p22 = expect[name]
            np.testing.assert_allclose(P[:, c, 0, 0], p11, rtol=0, atol=tol * np.abs(p11).max(), err_msg=name)
            np.testing.assert_allclose(P[:, c, 1, 1], p22, rtol=0, atol=tol * np.abs(p22).max(), err_msg=name)
            np.testing.assert_allclose(P[:, c, 2, 2], p22, rtol=0, atol=tol * np.abs(p22).max(), err_msg=name)


def test_projected_hessians_are_psd(warp_materials):
    """Projected ∂P/∂F is symmetric with min eigenvalue ≥ −1e-8·scale, and unprojected ones are not always."""
    found_indefinite = set()
    for regime in ("near", "far", "inverted"):
        got = warp_materials["float64"][regime]
        for c, name in enumerate(NAMES):
            for H, Hp in zip(got["H"][:, c], got["Hp"][:, c]):
                scale = np.abs(H).max()
                assert np.abs(Hp - Hp.T).max() <= 1e-12 * scale, name
                assert np.linalg.eigvalsh(Hp).min() >= -1e-8 * scale, (name, np.linalg.eigvalsh(Hp).min())
                if np.linalg.eigvalsh(H).min() < -1e-3 * scale:
                    found_indefinite.add(name)
    assert found_indefinite >= set(ISOTROPIC), found_indefinite  # the projection was exercised


def test_projection_keeps_psd_hessians(warp_materials):
    """Where ∂P/∂F is already PSD (mild tension), the projection returns it unchanged."""
    for dtype, tol in (("float64", 1e-13), ("float32", 1e-6)):
        got = warp_materials[dtype]["tension"]
        for c, name in enumerate(NAMES):
            for F, H, Hp in zip(F_SETS["tension"], got["H"][:, c], got["Hp"][:, c]):
                H_ref = ref.MATERIALS[name][2](F, MU, LAM)
                assert np.linalg.eigvalsh(H_ref).min() > 0.0 or name == "linear"
                assert max_rel(Hp, H) <= tol, (dtype, name, max_rel(Hp, H))


# ------------------------------------------------------------------------------------------ element level


def _random_tets(rng, n: int) -> np.ndarray:
    """Well-shaped, positively oriented random tetrahedra [n, 4, 3]."""
    base = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    X = base[None] + 0.15 * rng.standard_normal((n, 4, 3)) + rng.standard_normal((n, 1, 3))
    assert all(ref.tet_volume(t) > 0.05 for t in X)
    return X


_TETS = _random_tets(_rng, 6)
_A_AFFINE = np.array([np.eye(3) + 0.3 * _rng.standard_normal((3, 3)) for _ in range(6)])
_B_AFFINE = _rng.standard_normal((6, 1, 3))
_X_DEFORMED = _TETS + 0.1 * _rng.standard_normal(_TETS.shape)
_Q_RIGID = np.array([ref.random_rotation(_rng) for _ in range(6)])
_X_RIGID = np.einsum("nij,nvj->nvi", _Q_RIGID, _X_DEFORMED) + _rng.standard_normal((6, 1, 3))


@pytest.fixture(scope="module")
def warp_elements():
    """Warp element results for (deformed, affine, rigidly moved) configurations in both precisions."""
    X = np.concatenate([_TETS] * 3)
    x = np.concatenate([_X_DEFORMED, np.einsum("nij,nvj->nvi", _A_AFFINE, _TETS) + _B_AFFINE, _X_RIGID])
    out = {}
    for dt in _TYPES:
        r = run_elements(X, x, dt)
        n = len(_TETS)
        out[dt] = {
            k: {q: v[i * n : (i + 1) * n] for q, v in r.items()} for i, k in enumerate(["def", "aff", "rig"])
        }
    return out


def test_affine_deformation_gives_F_equal_A(warp_elements):
    """x = A X + b of a random tetrahedron gives F = A (f64 1e-12, f32 1e-5)."""
    for dtype, tol in (("float64", 1e-12), ("float32", 1e-5)):
        F = warp_elements[dtype]["aff"]["F"]
        for m in range(4):
            assert np.abs(F[:, m] - _A_AFFINE).max() < tol, dtype


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_element_forces_and_hessians_match_reference(warp_elements, dtype):
    """Warp tet_forces and the 16 projected Hessian blocks equal the reference (f64 1e-10, f32 1e-4)."""
    got = warp_elements[dtype]["def"]
    np_t = _TYPES[dtype][4]
    X32 = np.asarray(_TETS, dtype=np_t).astype(np.float64)
    x32 = np.asarray(_X_DEFORMED, dtype=np_t).astype(np.float64)
    mu, lam = float(np_t(MU)), float(np_t(LAM))
    for m, name in enumerate(NAMES):
        _, pk1, dpk1 = ref.MATERIALS[name]
        for t in range(len(_TETS)):
            f_ref = ref.tet_forces(x32[t], X32[t], pk1, mu, lam)
            assert max_rel(got["f"][t, m], f_ref) < _TOL[dtype], (name, t)
            H_ref = ref.tet_hessian(x32[t], X32[t], dpk1, mu, lam, project=True)
            assert max_rel(blocks_to_12x12(got["H"][t, m]), H_ref) < _TOL[dtype], (name, t)


def test_element_forces_conserve_momentum_and_rotate(warp_elements):
    """Element forces sum to zero, and a rigid motion x -> Qx + b rotates them: f(Qx + b) = Q f(x)."""
    got = warp_elements["float64"]
    for m, name in enumerate(NAMES):
        f = got["def"]["f"][:, m]
        scale = np.abs(f).max()
        assert np.abs(f.sum(axis=1)).max() < 1e-12 * scale, name
        if name in ISOTROPIC:
            f_rot = np.einsum("nij,nvj->nvi", _Q_RIGID, f)
            assert max_rel(got["rig"]["f"][:, m], f_rot) < 1e-11, name


def test_element_hessian_blocks_symmetric(warp_elements):
    """Assembled 12×12 element Hessians are symmetric (H_ab = H_baᵀ) and annihilate rigid translations."""
    r = warp_elements["float64"]["def"]
    for m in range(4):
        for t in range(len(_TETS)):
            H = blocks_to_12x12(r["H"][t, m])
            scale = np.abs(H).max()
            assert np.abs(H - H.T).max() < 1e-12 * scale
            # translation invariance: H (1 ⊗ e_k) = 0
            assert np.abs(H.reshape(12, 4, 3).sum(axis=1)).max() < 1e-12 * scale


# ------------------------------------------------------------------------------------------------ mass


def test_consistent_mass_single_tet():
    """One tet: diagonal ρV/10, off-diagonal ρV/20, N×N total ρV and 3N×3N total 3ρV (1e-12)."""
    X = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.3, 0.2, 1.5]])
    rho = 700.0
    V = ref.tet_volume(X)
    M = tet_consistent_mass(X, [[0, 1, 2, 3]], rho, per_dof=False).toarray()
    expect = rho * V * (np.ones((4, 4)) + np.eye(4)) / 20.0
    np.testing.assert_allclose(M, expect, rtol=1e-12)
    assert M.sum() == pytest.approx(rho * V, rel=1e-12)
    M3 = tet_consistent_mass(X, [[0, 1, 2, 3]], rho).toarray()
    np.testing.assert_allclose(M3, np.kron(expect, np.eye(3)), rtol=1e-12, atol=0)


def test_consistent_mass_matches_quadrature():
    """The consistent mass equals ∫ρ φ_r φ_s dΩ by exact (degree-2) quadrature on a random tet."""
    X = _TETS[0]
    V = ref.tet_volume(X)
    # Keast degree-2 rule: 4 points, equal weights V/4, at barycentric (a, b, b, b) permutations
    a, b = 0.5854101966249685, 0.1381966011250105
    pts = np.full((4, 4), b) + np.eye(4) * (a - b)
    M_q = 3.0 * V / 4.0 * np.einsum("qr,qs->rs", pts, pts)
    M = tet_consistent_mass(X, [[0, 1, 2, 3]], 3.0, per_dof=False).toarray()
    np.testing.assert_allclose(M, M_q, rtol=1e-12)


def test_lumped_mass_totals():
    """Lumped tet mass sums to ρΣV and equals the consistent mass's row sums; cloth mass sums to ρ_A A."""
    P, T = _cube_mesh(3)
    rho = 1200.0
    m = tet_lumped_mass(P, T, rho)
    assert m.sum() == pytest.approx(rho * 8.0, rel=1e-12)  # the mesh is a 2×2×2 cube
    M = tet_consistent_mass(P, T, rho, per_dof=False)
    np.testing.assert_allclose(np.asarray(M.sum(axis=1)).ravel(), m, rtol=1e-12)
    tris = np.array([[0, 1, 2], [1, 3, 2]])
    sq = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    assert triangle_lumped_mass(sq, tris, 0.3).sum() == pytest.approx(0.3, rel=1e-12)


# ------------------------------------------------------------------------------------------- barycentric


def _cube_mesh(n: int) -> tuple[np.ndarray, np.ndarray]:
    """[0, 2]³ as (n−1)³ cubes, each split into 6 positively oriented tets (Kuhn split along the diagonal)."""
    g = np.linspace(0.0, 2.0, n)
    P = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    idx = np.arange(n**3).reshape(n, n, n)
    corner = idx[:-1, :-1, :-1].ravel()
    step = np.array([n * n, n, 1])  # index offsets of +x, +y, +z
    tets = []
    for perm in ([0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]):
        a = corner
        b = a + step[perm[0]]
        c = b + step[perm[1]]
        d = c + step[perm[2]]
        tets.append(np.stack([a, b, c, d], axis=1))
    T = np.concatenate(tets)
    vol = np.array([ref.tet_volume(P[t]) for t in T])
    T[vol < 0] = T[vol < 0][:, [0, 2, 1, 3]]
    return P, T


def test_barycentric_coordinates_reproduce_points():
    """Σ φ_i X_i = X and Σ φ_i = 1 for random points and tets; shape_functions is the same function."""
    pts = _rng.standard_normal((6, 3))
    phi = barycentric_coordinates(pts, _TETS)
    np.testing.assert_allclose(np.einsum("pi,pij->pj", phi, _TETS), pts, atol=1e-12)
    np.testing.assert_allclose(phi.sum(axis=1), 1.0, atol=1e-13)
    assert shape_functions is barycentric_coordinates
    with pytest.raises(ValueError, match="degenerate"):
        barycentric_coordinates(pts[:1], np.zeros((1, 4, 3)))


def test_locate_points_in_box_mesh():
    """locate_points finds a containing tet for inside points, flags outside ones; interpolation is exact."""
    P, T = _cube_mesh(3)
    inner = _rng.uniform(0.0, 2.0, (200, 3))
    outer = np.array([[2.5, 1.0, 1.0], [-0.3, -0.3, 0.5], [1.0, 1.0, 3.0]])
    ids, bary, inside = locate_points(np.vstack([inner, outer]), P, T)
    assert inside[:200].all() and not inside[200:].any()
    assert bary[:200].min() >= -1e-12
    # the reported tet contains the point: its barycentrics rebuild it
    rebuilt = interpolate(P, T, ids, bary)
    np.testing.assert_allclose(rebuilt[:200], inner, atol=1e-12)
    # outside points: clamped barycentrics (≥ 0, sum 1) in a tet on the boundary nearest to them
    assert bary[200:].min() >= 0.0
    np.testing.assert_allclose(bary[200:].sum(axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(rebuilt[200], [2.0, 1.0, 1.0], atol=0.35)
    # a linear field interpolates exactly; a [N, 2, 3] field keeps its trailing shape
    field = P @ np.array([[1.0, -2.0, 0.5]]).T + 3.0
    np.testing.assert_allclose(
        interpolate(field, T, ids[:200], bary[:200]), inner @ [[1.0], [-2.0], [0.5]] + 3.0
    )
    assert interpolate(np.zeros((len(P), 2, 3)), T, ids, bary).shape == (203, 2, 3)
