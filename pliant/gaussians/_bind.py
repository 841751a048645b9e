"""Bindings: Gaussians that move with simulated particles, differentiable w.r.t. the particle positions.

- ``"barycentric"``: each Gaussian embedded in a tetrahedron (``pl.geometry.locate_points``):
  μ = Σ φ_i x_i and A = F = D_s D_m⁻¹, the tet's deformation gradient (Σ' = F Σ Fᵀ).
- ``"lbs"``: linear blend skinning as PhysTwin does it: every particle is a bone whose rotation R_k is the
  Procrustes (polar) fit of its neighbourhood's motion; a Gaussian follows its K nearest bones with
  normalised inverse-distance weights, μ = Σ_k w_k (R_k (μ⁰ − C_k) + c_k), A = Σ_k w_k R_k.
- ``"rigid"``: each Gaussian rigidly attached to one particle cluster (shape-matching clusters, as Physically
  Embodied Gaussians attach splats to bodies): μ = R (μ⁰ − C) + c, A = R.

Every kernel is one thread per (entry, term) with atomic sums — no loop-carried state — so Warp's
automatic adjoints differentiate them; ``deform`` inside a ``wp.Tape`` chains render → binding → particles.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import warp as wp

from .._warp import active_tape, mat33_type, np_dtype, scalar_type, vec3_type
from ..constraints import polar_rotation
from ._gaussians import Gaussians


@wp.kernel
def _barycentric_kernel(
    x: wp.array(dtype=Any),
    tets: wp.array2d(dtype=wp.int32),
    gauss_tet: wp.array(dtype=wp.int32),
    bary: wp.array2d(dtype=Any),
    rest_inv: wp.array(dtype=Any),
    means_out: wp.array(dtype=Any),
    transforms_out: wp.array(dtype=Any),
):
    g = wp.tid()
    e = gauss_tet[g]
    x0 = x[tets[e, 0]]
    x1 = x[tets[e, 1]]
    x2 = x[tets[e, 2]]
    x3 = x[tets[e, 3]]
    means_out[g] = bary[g, 0] * x0 + bary[g, 1] * x1 + bary[g, 2] * x2 + bary[g, 3] * x3
    Ds = wp.matrix_from_cols(x1 - x0, x2 - x0, x3 - x0)
    transforms_out[g] = Ds * rest_inv[e]


@wp.kernel
def _triangle_kernel(
    x: wp.array(dtype=Any),
    tris: wp.array2d(dtype=wp.int32),
    gauss_tri: wp.array(dtype=wp.int32),
    local: wp.array(dtype=Any),
    rest_inv: wp.array(dtype=Any),
    means_out: wp.array(dtype=Any),
    transforms_out: wp.array(dtype=Any),
):
    g = wp.tid()
    e = gauss_tri[g]
    x0 = x[tris[e, 0]]
    e1 = x[tris[e, 1]] - x0
    e2 = x[tris[e, 2]] - x0
    F = wp.matrix_from_cols(e1, e2, wp.normalize(wp.cross(e1, e2))) * rest_inv[e]
    means_out[g] = x0 + F * local[g]
    transforms_out[g] = F


@wp.kernel
def _group_centre_kernel(
    x: wp.array(dtype=Any),
    member: wp.array(dtype=wp.int32),
    group: wp.array(dtype=wp.int32),
    weight: wp.array(dtype=Any),
    centre_out: wp.array(dtype=Any),
):
    k = wp.tid()
    wp.atomic_add(centre_out, group[k], weight[k] * x[member[k]])


@wp.kernel
def _group_moment_kernel(
    x: wp.array(dtype=Any),
    member: wp.array(dtype=wp.int32),
    group: wp.array(dtype=wp.int32),
    weight: wp.array(dtype=Any),
    rest_offset: wp.array(dtype=Any),
    centre: wp.array(dtype=Any),
    moment_out: wp.array(dtype=Any),
):
    k = wp.tid()
    wp.atomic_add(moment_out, group[k], weight[k] * wp.outer(x[member[k]] - centre[group[k]], rest_offset[k]))


@wp.kernel
def _group_rotation_kernel(moment: wp.array(dtype=Any), rotation_out: wp.array(dtype=Any)):
    b = wp.tid()
    rotation_out[b] = polar_rotation(moment[b])


@wp.kernel
def _group_rotation_adjoint_kernel(
    moment: wp.array(dtype=Any), adj_rotation: wp.array(dtype=Any), adj_moment_out: wp.array(dtype=Any)
):
    # Hand-written adjoint of R = polar(A) (autodiff through wp.svd3 disagrees with finite differences).
    # With A = U Σ Vᵀ (last column of U and σ₃ negated when U Vᵀ is a reflection, so R = U Vᵀ):
    # dR = U Ω Vᵀ, Ω_ij = (M_ij − M_ji)/(σ_i + σ_j), M = Uᵀ dA V, hence ∂L/∂A = U Ψ Vᵀ with
    # Ψ_ij = (G̃_ij − G̃_ji)/(σ_i + σ_j), G̃ = Uᵀ (∂L/∂R) V.
    b = wp.tid()
    A = moment[b]
    U = A
    sigma = wp.get_diag(A)
    V = A
    wp.svd3(A, U, sigma, V)
    one = type(sigma[0])(1.0)
    zero = type(sigma[0])(0.0)
    d = one
    if wp.determinant(U * wp.transpose(V)) < zero:
        d = -one
    U = U * wp.diag(type(sigma)(one, one, d))
    s0 = sigma[0]
    s1 = sigma[1]
    s2 = d * sigma[2]
    G = wp.transpose(U) * adj_rotation[b] * V
    tiny = type(sigma[0])(1.0e-30)
    p01 = (G[0, 1] - G[1, 0]) / wp.max(s0 + s1, tiny)
    p02 = (G[0, 2] - G[2, 0]) / wp.max(s0 + s2, tiny)
    p12 = (G[1, 2] - G[2, 1]) / wp.max(s1 + s2, tiny)
    Psi = wp.matrix(zero, p01, p02, -p01, zero, p12, -p02, -p12, zero, shape=(3, 3))
    adj_moment_out[b] = adj_moment_out[b] + U * Psi * wp.transpose(V)


@wp.kernel
def _skin_kernel(
    link_gauss: wp.array(dtype=wp.int32),
    link_group: wp.array(dtype=wp.int32),
    link_weight: wp.array(dtype=Any),
    link_offset: wp.array(dtype=Any),
    rotation: wp.array(dtype=Any),
    centre: wp.array(dtype=Any),
    means_out: wp.array(dtype=Any),
    transforms_out: wp.array(dtype=Any),
):
    k = wp.tid()
    g = link_gauss[k]
    b = link_group[k]
    w = link_weight[k]
    R = rotation[b]
    wp.atomic_add(means_out, g, w * (R * link_offset[k] + centre[b]))
    wp.atomic_add(transforms_out, g, w * R)


class Binding:
    """Gaussians bound to a particle system; :meth:`deform` places them for given particle positions.

    Build with :func:`bind`. Attributes: ``gaussians`` (the rest set), ``method``, ``particle_count``, and
    for skinning ``link_*`` (Gaussian, group, weight) triples usable to spread per-Gaussian quantities back
    onto particles (:meth:`particle_weights`).
    """

    # Filled by bind() for the method chosen: "barycentric" (tets) ...
    tets: wp.array
    gauss_tet: wp.array
    bary: wp.array
    rest_inv: wp.array
    # ... "triangles" (rest_inv too) ...
    tris: wp.array
    gauss_tri: wp.array
    local: wp.array
    # ... or "skinning": particle groups and (Gaussian, group, weight) links.
    group_count: int
    member: wp.array
    group: wp.array
    member_weight: wp.array
    rest_offset: wp.array
    link_gauss: wp.array
    link_group: wp.array
    link_weight: wp.array
    link_offset: wp.array

    def __init__(self, gaussians: Gaussians, method: str, particle_count: int) -> None:
        self.gaussians = gaussians
        self.method = method
        self.particle_count = particle_count

    def deform(self, particle_q: wp.array) -> Gaussians:
        """The Gaussians placed for particle positions ``particle_q`` [m] (vec3 [particle_count]).

        Differentiable under ``wp.Tape`` w.r.t. ``particle_q``. Colours, opacities, scales and quaternions are
        shared with the rest set; means and ``transforms`` are new arrays.
        """
        g = self.gaussians
        if particle_q.shape != (self.particle_count,) or particle_q.dtype != vec3_type(g.dtype):
            raise ValueError(
                f"particle_q must be {self.particle_count} {vec3_type(g.dtype).__name__}, "
                f"got {particle_q.shape} of {particle_q.dtype.__name__}"
            )
        if str(particle_q.device) != g.device:
            raise ValueError(f"particle_q is on {particle_q.device} but the Gaussians are on {g.device}")
        rg = particle_q.requires_grad
        dev, n = g.device, g.count
        means = wp.zeros(n, dtype=vec3_type(g.dtype), device=dev, requires_grad=rg)
        transforms = wp.zeros(n, dtype=mat33_type(g.dtype), device=dev, requires_grad=rg)
        if self.method == "triangles":
            wp.launch(
                _triangle_kernel,
                dim=n,
                inputs=[particle_q, self.tris, self.gauss_tri, self.local, self.rest_inv],
                outputs=[means, transforms],
                device=dev,
            )
        elif self.method == "barycentric":
            wp.launch(
                _barycentric_kernel,
                dim=n,
                inputs=[particle_q, self.tets, self.gauss_tet, self.bary, self.rest_inv],
                outputs=[means, transforms],
                device=dev,
            )
        else:
            nb = self.group_count
            centre = wp.zeros(nb, dtype=vec3_type(g.dtype), device=dev, requires_grad=rg)
            moment = wp.zeros(nb, dtype=mat33_type(g.dtype), device=dev, requires_grad=rg)
            rotation = wp.zeros(nb, dtype=mat33_type(g.dtype), device=dev, requires_grad=rg)
            m = self.member.shape[0]
            wp.launch(
                _group_centre_kernel,
                dim=m,
                inputs=[particle_q, self.member, self.group, self.member_weight],
                outputs=[centre],
                device=dev,
            )
            wp.launch(
                _group_moment_kernel,
                dim=m,
                inputs=[particle_q, self.member, self.group, self.member_weight, self.rest_offset, centre],
                outputs=[moment],
                device=dev,
            )
            wp.launch(
                _group_rotation_kernel,
                dim=nb,
                inputs=[moment],
                outputs=[rotation],
                device=dev,
                record_tape=False,
            )
            tape = active_tape()
            if tape is not None and rg:
                tape.record_func(
                    backward=lambda: wp.launch(
                        _group_rotation_adjoint_kernel,
                        dim=nb,
                        inputs=[moment, rotation.grad, moment.grad],
                        device=dev,
                        record_tape=False,
                    ),
                    arrays=[moment, rotation],
                )
            wp.launch(
                _skin_kernel,
                dim=self.link_gauss.shape[0],
                inputs=[
                    self.link_gauss,
                    self.link_group,
                    self.link_weight,
                    self.link_offset,
                    rotation,
                    centre,
                ],
                outputs=[means, transforms],
                device=dev,
            )
        return g.with_means(means, transforms=transforms)

    def particle_weights(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Gaussian ids, particle ids, weights) spreading a per-Gaussian quantity onto particles.

        For skinning each link's weight is split over its group's members by their centroid weights; for
        tets the weights are the barycentric coordinates. The weights of one Gaussian sum to 1.
        """
        if self.method == "triangles":
            # μ⁰ − X₀ = a E₁ + b E₂ + c N: the in-plane part splits as barycentric (1 − a − b, a, b)
            inv = self.rest_inv.numpy().astype(np.float64)[self.gauss_tri.numpy()]
            ab = np.einsum("gij,gj->gi", inv, self.local.numpy().astype(np.float64))
            n = self.gaussians.count
            w = np.stack([1.0 - ab[:, 0] - ab[:, 1], ab[:, 0], ab[:, 1]], axis=1)
            w = np.clip(w, 0.0, None)
            w /= np.maximum(w.sum(axis=1, keepdims=True), 1e-300)
            tris = self.tris.numpy()[self.gauss_tri.numpy()]
            return np.repeat(np.arange(n), 3), tris.reshape(-1), w.reshape(-1)
        if self.method == "barycentric":
            n = self.gaussians.count
            tets = self.tets.numpy()[self.gauss_tet.numpy()]
            return (
                np.repeat(np.arange(n), 4),
                tets.reshape(-1),
                self.bary.numpy().reshape(-1).astype(np.float64),
            )
        member, group = self.member.numpy(), self.group.numpy()
        mw = self.member_weight.numpy().astype(np.float64)  # normalised per group
        lg, lb, lw = self.link_gauss.numpy(), self.link_group.numpy(), self.link_weight.numpy()
        order = np.argsort(group, kind="stable")
        starts = np.searchsorted(group[order], np.arange(self.group_count))
        ends = np.searchsorted(group[order], np.arange(self.group_count), side="right")
        counts = ends[lb] - starts[lb]
        gi = np.repeat(lg, counts)
        # the members of every link's group, without a Python loop: a ramp inside each group's CSR range
        ramp = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
        idx = order[np.repeat(starts[lb], counts) + ramp]
        return gi, member[idx], np.repeat(lw, counts) * mw[idx]


def bind(
    gaussians: Gaussians,
    rest_positions: np.ndarray,
    *,
    method: str = "lbs",
    k: int = 16,
    neighbours: int = 16,
    tets: np.ndarray | None = None,
    triangles: np.ndarray | None = None,
    clusters: Sequence[Any] | None = None,
) -> Binding:
    """Bind ``gaussians`` (placed at rest) to particles at ``rest_positions``.

    Args:
        gaussians: The Gaussian set in the rest configuration.
        rest_positions: Particle positions at rest [m], shape [P, 3].
        method: ``"lbs"`` (PhysTwin's skinning), ``"barycentric"`` (tets), ``"triangles"`` (a surface such as
            cloth: each Gaussian in the frame (edge 1, edge 2, unit normal) of its nearest triangle, so
            μ = x₀ + F (μ⁰ − X₀) with ``F = [e₁ e₂ n][E₁ E₂ N]⁻¹``) or ``"rigid"`` (clusters).
        k: Bones (nearest particles) per Gaussian for ``"lbs"``.
        neighbours: Particles in each bone's Procrustes neighbourhood for ``"lbs"`` (itself included).
        tets: Tetrahedra [E, 4] for ``"barycentric"``.
        triangles: Triangles [T, 3] for ``"triangles"``.
        clusters: Particle index lists, one per rigid cluster, for ``"rigid"`` (each Gaussian goes with the
            cluster of its nearest particle; the first such cluster where clusters overlap).

    Raises:
        ValueError: unknown method, missing tets/clusters, or degenerate rest tets.
    """
    from scipy.spatial import cKDTree

    X = np.asarray(rest_positions, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3 or len(X) == 0:
        raise ValueError(f"rest_positions must have shape [P, 3] with P > 0, got {X.shape}")
    P = len(X)
    dtype, dev = gaussians.dtype, gaussians.device
    nd, s, v3 = np_dtype(dtype), scalar_type(dtype), vec3_type(dtype)
    mu = gaussians.means.numpy().astype(np.float64)
    b = Binding(gaussians, method, P)
    if method == "barycentric":
        return _bind_barycentric(b, mu, X, tets, dtype, dev)
    if method == "triangles":
        return _bind_triangles(b, mu, X, triangles, dtype, dev)
    if method == "lbs":
        kb = int(min(max(neighbours, 1), P))
        _, nbr = cKDTree(X).query(X, k=kb)
        nbr = np.asarray(nbr).reshape(P, kb)
        member, group = nbr.reshape(-1), np.repeat(np.arange(P), kb)
        kg = int(min(max(k, 1), P))
        dist, idx = cKDTree(X).query(mu, k=kg)
        dist, idx = np.asarray(dist).reshape(-1, kg), np.asarray(idx).reshape(-1, kg)
        w = 1.0 / np.maximum(dist, 1e-12)  # inverse distance, normalised (PhysTwin's knn_weights)
        w /= w.sum(axis=1, keepdims=True)
        link_gauss, link_group, link_weight = (
            np.repeat(np.arange(len(mu)), kg),
            idx.reshape(-1),
            w.reshape(-1),
        )
        group_count = P
    elif method == "rigid":
        if not clusters:
            raise ValueError('bind(method="rigid") needs clusters (a list of particle index arrays)')
        cl = [np.asarray(c, dtype=np.int64).reshape(-1) for c in clusters]
        if any(len(c) == 0 or c.min() < 0 or c.max() >= P for c in cl):
            raise ValueError(f"bind: every cluster must be a non-empty list of particle indices in [0, {P})")
        member, group = np.concatenate(cl), np.concatenate([np.full(len(c), i) for i, c in enumerate(cl)])
        owner = np.full(P, -1)
        for i in reversed(range(len(cl))):  # the first listed cluster wins where clusters overlap
            owner[cl[i]] = i
        nearest = np.asarray(cKDTree(X).query(mu, k=1)[1]).reshape(-1)
        link_group = owner[nearest]
        if np.any(link_group < 0):
            raise ValueError("bind: some Gaussians' nearest particles belong to no cluster")
        link_gauss, link_weight = np.arange(len(mu)), np.ones(len(mu))
        group_count = len(cl)
    else:
        raise ValueError(
            f'unknown binding method {method!r}; use "lbs", "barycentric", "triangles" or "rigid"'
        )
    counts = np.bincount(group, minlength=group_count).astype(np.float64)
    member_weight = 1.0 / counts[group]  # centroid weights; the moment uses the same weights
    C = np.zeros((group_count, 3))
    np.add.at(C, group, member_weight[:, None] * X[member])
    b.group_count = group_count
    b.member = wp.array(member.astype(np.int32), dtype=wp.int32, device=dev)
    b.group = wp.array(group.astype(np.int32), dtype=wp.int32, device=dev)
    b.member_weight = wp.array(member_weight.astype(nd), dtype=s, device=dev)
    b.rest_offset = wp.array((X[member] - C[group]).astype(nd), dtype=v3, device=dev)
    b.link_gauss = wp.array(link_gauss.astype(np.int32), dtype=wp.int32, device=dev)
    b.link_group = wp.array(link_group.astype(np.int32), dtype=wp.int32, device=dev)
    b.link_weight = wp.array(link_weight.astype(nd), dtype=s, device=dev)
    b.link_offset = wp.array((mu[link_gauss] - C[link_group]).astype(nd), dtype=v3, device=dev)
    return b


def _bind_barycentric(
    b: Binding, mu: np.ndarray, X: np.ndarray, tets: np.ndarray | None, dtype: str, dev: str
) -> Binding:
    """Fill ``b`` for ``method="barycentric"``: each Gaussian centre ``mu`` [G, 3] (m) in the rest tet
    [E, 4] that holds it (or the nearest), with its barycentric weights and the tets' inverse rest edge
    matrices (1/m) at rest positions ``X`` [P, 3] (m)."""
    nd, s, m33 = np_dtype(dtype), scalar_type(dtype), mat33_type(dtype)
    if tets is None:
        raise ValueError('bind(method="barycentric") needs tets [E, 4]')
    from ..geometry import locate_points

    tets = np.asarray(tets, dtype=np.int64)
    tet_ids, bary, _inside = locate_points(mu, X, tets)
    Dm = np.stack([X[tets[:, i]] - X[tets[:, 0]] for i in (1, 2, 3)], axis=2)
    det = np.linalg.det(Dm)
    if np.any(np.abs(det) < 1e-300):
        raise ValueError(f"bind: {int(np.sum(np.abs(det) < 1e-300))} rest tets are degenerate")
    b.tets = wp.array(tets.astype(np.int32), dtype=wp.int32, device=dev)
    b.gauss_tet = wp.array(tet_ids.astype(np.int32), dtype=wp.int32, device=dev)
    b.bary = wp.array(bary.astype(nd), dtype=s, device=dev)
    b.rest_inv = wp.array(np.linalg.inv(Dm).astype(nd), dtype=m33, device=dev)
    return b


def _bind_triangles(
    b: Binding, mu: np.ndarray, X: np.ndarray, triangles: np.ndarray | None, dtype: str, dev: str
) -> Binding:
    """Fill ``b`` for ``method="triangles"``: each Gaussian centre ``mu`` [G, 3] (m) in the frame (edge 1,
    edge 2, unit normal) of its nearest rest triangle [T, 3] at rest positions ``X`` [P, 3] (m)."""
    from scipy.spatial import cKDTree

    P = len(X)
    nd, v3, m33 = np_dtype(dtype), vec3_type(dtype), mat33_type(dtype)
    if triangles is None:
        raise ValueError('bind(method="triangles") needs triangles [T, 3]')
    tris = np.asarray(triangles, dtype=np.int64)
    if tris.ndim != 2 or tris.shape[1] != 3 or len(tris) == 0 or tris.min() < 0 or tris.max() >= P:
        raise ValueError(f"triangles must have shape [T, 3] indexing {P} particles, got {tris.shape}")
    E1, E2 = X[tris[:, 1]] - X[tris[:, 0]], X[tris[:, 2]] - X[tris[:, 0]]
    N = np.cross(E1, E2)
    area2 = np.linalg.norm(N, axis=1)
    if np.any(area2 < 1e-300):
        raise ValueError(f"bind: {int(np.sum(area2 < 1e-300))} rest triangles are degenerate")
    N /= area2[:, None]
    # nearest triangle: among the 8 nearest centroids, the smallest distance to the clamped projection
    kc = int(min(8, len(tris)))
    _, cand = cKDTree(X[tris].mean(axis=1)).query(mu, k=kc)
    cand = np.asarray(cand).reshape(len(mu), kc)
    frames = np.linalg.inv(np.stack([E1, E2, N], axis=2))  # [T, 3, 3]: (a, b, c) of a point - X0
    abc = np.einsum("gkij,gkj->gki", frames[cand], mu[:, None, :] - X[tris[cand, 0]])
    w = np.stack([1.0 - abc[..., 0] - abc[..., 1], abc[..., 0], abc[..., 1]], axis=-1).clip(0.0, None)
    w /= np.maximum(w.sum(axis=-1, keepdims=True), 1e-300)
    foot = np.einsum("gki,gkij->gkj", w, X[tris[cand]])
    best = cand[np.arange(len(mu)), np.argmin(np.linalg.norm(foot - mu[:, None, :], axis=2), axis=1)]
    b.tris = wp.array(tris.astype(np.int32), dtype=wp.int32, device=dev)
    b.gauss_tri = wp.array(best.astype(np.int32), dtype=wp.int32, device=dev)
    b.local = wp.array((mu - X[tris[best, 0]]).astype(nd), dtype=v3, device=dev)
    b.rest_inv = wp.array(frames.astype(nd), dtype=m33, device=dev)
    return b
