"""The barrier contact potential's per-pair mathematics as Warp functions (float64, no kernels).

* the clamped log barrier b(d) = −(d − d̂)² ln(d/d̂) for 0 < d < d̂ (0 beyond) and its first two
  derivatives (Li et al., "Incremental Potential Contact", ACM TOG 39(4), 2020, eq. 6);
* the squared distance of a point–triangle or edge–edge pair, with its gradient and exact Hessian over the
  pair's 12 coordinates, from the closest points (envelope theorem, below);
* the pair's barrier value, gradient and Hessian, and the Hessian's projection to the nearest positive
  semidefinite matrix (cyclic Jacobi in the ≤ 5-dimensional subspace holding its range, negative
  eigenvalues clamped to 0);
* distances alone, for the continuous collision detection of :mod:`._barrier_ccd`.

A pair is four points x₀..x₃ and its closest-point difference r = Σ_k c_k(β) x_k, with c affine in the
closest-point parameters β (those not clamped to the boundary of their domain: none for a vertex–vertex
closest pair, one on an edge, two inside a triangle or for two crossing edges). For f = |r|² minimised over
β, the envelope theorem gives ∇f = 2 c_k r per point and

    ∇²f = 2 (c cᵀ ⊗ I) − B G⁻¹ Bᵀ,   B_{k,a} = 2 (e_{a,k} r + c_k J_a),   G_{ab} = 2 J_a·J_b,

with e_a = ∂c/∂β_a and J_a = ∂r/∂β_a = Σ_k e_{a,k} x_k: exact inside each closest-point region, where the
distance is smooth. Two (nearly) parallel edges keep only one free parameter (their distance is reached at
an end point too); IPC's mollifier of that case is not applied.
"""

from __future__ import annotations

from typing import Any

import warp as wp

# Loops over the 12 pair coordinates stay loops: unrolling the Jacobi sweeps would make huge kernels.
wp.set_module_options({"max_unroll": 0})

mat12d = wp.types.matrix(shape=(12, 12), dtype=wp.float64)
vec12d = wp.types.vector(length=12, dtype=wp.float64)

#: Edges whose |e₁ × e₂|² is below this fraction of |e₁|²|e₂|² count as parallel.
PARALLEL_TOL = 1.0e-10


@wp.func
def to_d(p: Any):
    """``p`` (vec3 of the model's dtype) as a float64 vec3."""
    return wp.vec3d(wp.float64(p[0]), wp.float64(p[1]), wp.float64(p[2]))


@wp.func
def barrier(d: wp.float64, dhat: wp.float64):
    """b(d) = −(d − d̂)² ln(d/d̂) [m²] for 0 < d < d̂, 0 for d ≥ d̂, +inf for d ≤ 0."""
    if d >= dhat:
        return wp.float64(0.0)
    if d <= wp.float64(0.0):
        return wp.float64(wp.inf)
    return -(d - dhat) * (d - dhat) * wp.log(d / dhat)


@wp.func
def barrier_d1(d: wp.float64, dhat: wp.float64):
    """b′(d) = −2(d − d̂) ln(d/d̂) − (d − d̂)²/d [m] (≤ 0 on (0, d̂))."""
    if d >= dhat:
        return wp.float64(0.0)
    return wp.float64(-2.0) * (d - dhat) * wp.log(d / dhat) - (d - dhat) * (d - dhat) / d


@wp.func
def barrier_d2(d: wp.float64, dhat: wp.float64):
    """b″(d) = −2 ln(d/d̂) − 4(d − d̂)/d + (d − d̂)²/d² (≥ 0 on (0, d̂): b is convex)."""
    if d >= dhat:
        return wp.float64(0.0)
    q = (d - dhat) / d
    return wp.float64(-2.0) * wp.log(d / dhat) - wp.float64(4.0) * q + q * q


@wp.func
def _combine(c: wp.vec4d, x0: wp.vec3d, x1: wp.vec3d, x2: wp.vec3d, x3: wp.vec3d):
    return c[0] * x0 + c[1] * x1 + c[2] * x2 + c[3] * x3


@wp.func
def sqdist_derivatives(
    x0: wp.vec3d,
    x1: wp.vec3d,
    x2: wp.vec3d,
    x3: wp.vec3d,
    c0: wp.vec4d,
    e1: wp.vec4d,
    e2: wp.vec4d,
    b1: wp.float64,
    b2: wp.float64,
    m: int,
):
    """(f = |r|² [m²], ∇f [m] (12), ∇²f (12×12)) for r = Σ c_k x_k, c = c₀ + b₁e₁ + b₂e₂ with ``m`` free
    parameters (the module's envelope-theorem formula)."""
    c = c0 + b1 * e1 + b2 * e2
    r = _combine(c, x0, x1, x2, x3)
    J1 = _combine(e1, x0, x1, x2, x3)
    J2 = _combine(e2, x0, x1, x2, x3)
    f = wp.dot(r, r)
    g = vec12d()
    H = mat12d()
    for k in range(4):
        for i in range(3):
            g[3 * k + i] = wp.float64(2.0) * c[k] * r[i]
            for l in range(4):
                H[3 * k + i, 3 * l + i] = wp.float64(2.0) * c[k] * c[l]
    if m > 0:
        B1 = vec12d()
        B2 = vec12d()
        for k in range(4):
            for i in range(3):
                B1[3 * k + i] = wp.float64(2.0) * (e1[k] * r[i] + c[k] * J1[i])
                B2[3 * k + i] = wp.float64(2.0) * (e2[k] * r[i] + c[k] * J2[i])
        g11 = wp.float64(2.0) * wp.dot(J1, J1)
        if m == 1:
            H = H - wp.outer(B1, B1) / g11
        else:
            g12 = wp.float64(2.0) * wp.dot(J1, J2)
            g22 = wp.float64(2.0) * wp.dot(J2, J2)
            det = g11 * g22 - g12 * g12
            i11 = g22 / det
            i12 = -g12 / det
            i22 = g11 / det
            H = H - (
                i11 * wp.outer(B1, B1) + i12 * (wp.outer(B1, B2) + wp.outer(B2, B1)) + i22 * wp.outer(B2, B2)
            )
    return f, g, H


@wp.func
def point_triangle_params(p: wp.vec3d, a: wp.vec3d, b: wp.vec3d, c: wp.vec3d):
    """(c₀, e₁, e₂, β₁, β₂, m) of the closest points of p and triangle abc (Ericson, RTCD §5.1.5): the
    region (vertex, edge or face) decides which barycentric parameters are free."""
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    ab = b - a
    ac = c - a
    ap = p - a
    d1 = wp.dot(ab, ap)
    d2 = wp.dot(ac, ap)
    bp = p - b
    d3 = wp.dot(ab, bp)
    d4 = wp.dot(ac, bp)
    cp = p - c
    d5 = wp.dot(ab, cp)
    d6 = wp.dot(ac, cp)
    vc = d1 * d4 - d3 * d2
    vb = d5 * d2 - d1 * d6
    va = d3 * d6 - d5 * d4
    z4 = wp.vec4d(zero, zero, zero, zero)
    # Vertex regions: r = p − t_j.
    if d1 <= zero and d2 <= zero:
        return wp.vec4d(one, -one, zero, zero), z4, z4, zero, zero, 0
    if d3 >= zero and d4 <= d3:
        return wp.vec4d(one, zero, -one, zero), z4, z4, zero, zero, 0
    if d6 >= zero and d5 <= d6:
        return wp.vec4d(one, zero, zero, -one), z4, z4, zero, zero, 0
    # Edge regions: r = p − t_j − s (t_k − t_j), free s.
    if vc <= zero and d1 >= zero and d3 <= zero:
        return wp.vec4d(one, -one, zero, zero), wp.vec4d(zero, one, -one, zero), z4, d1 / (d1 - d3), zero, 1
    if vb <= zero and d2 >= zero and d6 <= zero:
        return wp.vec4d(one, -one, zero, zero), wp.vec4d(zero, one, zero, -one), z4, d2 / (d2 - d6), zero, 1
    if va <= zero and (d4 - d3) >= zero and (d5 - d6) >= zero:
        s = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return wp.vec4d(one, zero, -one, zero), wp.vec4d(zero, zero, one, -one), z4, s, zero, 1
    # Face: r = p − a − u (b − a) − v (c − a).
    denom = one / (va + vb + vc)
    return (
        wp.vec4d(one, -one, zero, zero),
        wp.vec4d(zero, one, -one, zero),
        wp.vec4d(zero, one, zero, -one),
        vb * denom,
        vc * denom,
        2,
    )


@wp.func
def edge_edge_params(p1: wp.vec3d, q1: wp.vec3d, p2: wp.vec3d, q2: wp.vec3d):
    """(c₀, e₁, e₂, β₁, β₂, m) of the closest points of segments p₁q₁ and p₂q₂ (Ericson, RTCD §5.1.9):
    r = p₁ + s(q₁ − p₁) − p₂ − t(q₂ − p₂); s and t are free where not clamped to 0 or 1."""
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    d1 = q1 - p1
    d2 = q2 - p2
    rr = p1 - p2
    a = wp.dot(d1, d1)
    e = wp.dot(d2, d2)
    f = wp.dot(d2, rr)
    c = wp.dot(d1, rr)
    b = wp.dot(d1, d2)
    denom = a * e - b * b
    parallel = denom <= wp.float64(PARALLEL_TOL) * a * e
    s = zero
    if not parallel:
        s = wp.clamp((b * f - c * e) / denom, zero, one)
    t = (b * s + f) / e
    t_free = True
    if t <= zero:
        t = zero
        t_free = False
        s = wp.clamp(-c / a, zero, one)
    elif t >= one:
        t = one
        t_free = False
        s = wp.clamp((b - c) / a, zero, one)
    s_free = s > zero and s < one and not (parallel and t_free)
    t_free = t_free and t > zero and t < one
    c0 = wp.vec4d(one, zero, -one, zero)
    es = wp.vec4d(-one, one, zero, zero)
    et = wp.vec4d(zero, zero, one, -one)
    z4 = wp.vec4d(zero, zero, zero, zero)
    if s_free and t_free:
        return c0, es, et, s, t, 2
    if s_free:
        return c0 + t * et, es, z4, s, zero, 1
    if t_free:
        return c0 + s * es, et, z4, t, zero, 1
    return c0 + s * es + t * et, z4, z4, zero, zero, 0


@wp.func
def point_triangle_distance(p: wp.vec3d, a: wp.vec3d, b: wp.vec3d, c: wp.vec3d):
    """Distance [m] from p to triangle abc."""
    c0, e1, e2, b1, b2, m = point_triangle_params(p, a, b, c)
    r = _combine(c0 + b1 * e1 + b2 * e2, p, a, b, c)
    return wp.length(r)


@wp.func
def edge_edge_distance(p1: wp.vec3d, q1: wp.vec3d, p2: wp.vec3d, q2: wp.vec3d):
    """Distance [m] between segments p₁q₁ and p₂q₂."""
    c0, e1, e2, b1, b2, m = edge_edge_params(p1, q1, p2, q2)
    r = _combine(c0 + b1 * e1 + b2 * e2, p1, q1, p2, q2)
    return wp.length(r)


@wp.func
def _jacobi_psd(A: mat12d, size: int):
    """V max(Λ, 0) Vᵀ of the symmetric leading ``size`` × ``size`` block of A, by cyclic Jacobi rotations."""
    V = wp.identity(n=12, dtype=wp.float64)
    for _sweep in range(30):
        off = wp.float64(0.0)
        scale = wp.float64(0.0)
        for p in range(size):
            scale = scale + A[p, p] * A[p, p]
            for q in range(p + 1, size):
                off = off + A[p, q] * A[p, q]
        if off <= wp.float64(1.0e-30) * scale or off == wp.float64(0.0):
            break
        for p in range(size - 1):
            for q in range(p + 1, size):
                apq = A[p, q]
                if apq != wp.float64(0.0):
                    theta = (A[q, q] - A[p, p]) / (wp.float64(2.0) * apq)
                    t = wp.float64(1.0) / (wp.abs(theta) + wp.sqrt(theta * theta + wp.float64(1.0)))
                    if theta < wp.float64(0.0):
                        t = -t
                    cs = wp.float64(1.0) / wp.sqrt(t * t + wp.float64(1.0))
                    sn = t * cs
                    for k in range(size):
                        akp = A[k, p]
                        akq = A[k, q]
                        A[k, p] = cs * akp - sn * akq
                        A[k, q] = sn * akp + cs * akq
                    for k in range(size):
                        apk = A[p, k]
                        aqk = A[q, k]
                        A[p, k] = cs * apk - sn * aqk
                        A[q, k] = sn * apk + cs * aqk
                    for k in range(size):
                        vkp = V[k, p]
                        vkq = V[k, q]
                        V[k, p] = cs * vkp - sn * vkq
                        V[k, q] = sn * vkp + cs * vkq
    out = mat12d()
    for k in range(size):
        lam = A[k, k]
        if lam > wp.float64(0.0):
            for i in range(size):
                for j in range(size):
                    out[i, j] = out[i, j] + lam * V[i, k] * V[j, k]
    return out


@wp.func
def project_psd_pair(H: mat12d, c: wp.vec4d, e1: wp.vec4d, e2: wp.vec4d, r: wp.vec3d):
    """The nearest PSD matrix to a pair's barrier Hessian H (negative eigenvalues clamped to 0), computed in
    the ≤ 5-dimensional subspace that holds its range: span{c ⊗ e_i (i = 1..3), e_a ⊗ r} (∇f, ccᵀ ⊗ I
    and B all lie there), orthonormalised as U; then H⁺ = U (UᵀHU)⁺ Uᵀ exactly, for a 5×5 instead of a
    12×12 eigenproblem."""
    U = mat12d()
    k = int(0)  # noqa: UP018
    for j in range(5):
        v = vec12d()
        for a in range(4):
            for i in range(3):
                if j < 3:
                    if i == j:
                        v[3 * a + i] = c[a]
                elif j == 3:
                    v[3 * a + i] = e1[a] * r[i]
                else:
                    v[3 * a + i] = e2[a] * r[i]
        before = wp.length(v)
        for t in range(k):
            proj = wp.float64(0.0)
            for i in range(12):
                proj = proj + U[i, t] * v[i]
            for i in range(12):
                v[i] = v[i] - proj * U[i, t]
        nv = wp.length(v)
        if nv > wp.float64(1.0e-9) * before:
            for i in range(12):
                U[i, k] = v[i] / nv
            k = k + 1
    HU = mat12d()
    for b in range(k):
        for i in range(12):
            acc = wp.float64(0.0)
            for j in range(12):
                acc = acc + H[i, j] * U[j, b]
            HU[i, b] = acc
    K = mat12d()
    for a in range(k):
        for b in range(k):
            acc = wp.float64(0.0)
            for i in range(12):
                acc = acc + U[i, a] * HU[i, b]
            K[a, b] = acc
    Kp = _jacobi_psd(K, k)
    out = mat12d()
    for i in range(12):
        for j in range(12):
            acc = wp.float64(0.0)
            for a in range(k):
                for b in range(k):
                    acc = acc + U[i, a] * Kp[a, b] * U[j, b]
            out[i, j] = acc
    return out


@wp.func
def pair_barrier(
    x0: wp.vec3d,
    x1: wp.vec3d,
    x2: wp.vec3d,
    x3: wp.vec3d,
    edge_edge: int,
    dhat: wp.float64,
    mode: int,
    project: int,
):
    """(b(d) [m²], ∇b [m] (12), ∇²b (12×12)) of a point–triangle (``edge_edge`` 0: x₀ the point) or
    edge–edge (1: x₀x₁ and x₂x₃) pair; the derivatives only for ``mode`` ≥ 1 (1 gradient, 2 Hessian,
    PSD-projected if ``project``). d = √f; ∇b = b′∇f/(2d) and ∇²b = (b″/(4f) − b′/(4d³))∇f∇fᵀ + b′∇²f/(2d)."""
    if edge_edge == 0:
        c0, e1, e2, b1, b2, m = point_triangle_params(x0, x1, x2, x3)
    else:
        c0, e1, e2, b1, b2, m = edge_edge_params(x0, x1, x2, x3)
    g = vec12d()
    H = mat12d()
    if mode == 0:
        d = wp.length(_combine(c0 + b1 * e1 + b2 * e2, x0, x1, x2, x3))
        return barrier(d, dhat), g, H
    f, gf, Hf = sqdist_derivatives(x0, x1, x2, x3, c0, e1, e2, b1, b2, m)
    d = wp.sqrt(f)
    if d >= dhat:
        return wp.float64(0.0), g, H
    db = barrier_d1(d, dhat)
    g = db / (wp.float64(2.0) * d) * gf
    if mode == 2:
        ddb = barrier_d2(d, dhat)
        H = (ddb / (wp.float64(4.0) * f) - db / (wp.float64(4.0) * f * d)) * wp.outer(gf, gf)
        H = H + db / (wp.float64(2.0) * d) * Hf
        if project != 0:
            c = c0 + b1 * e1 + b2 * e2
            H = project_psd_pair(H, c, e1, e2, _combine(c, x0, x1, x2, x3))
    return barrier(d, dhat), g, H
