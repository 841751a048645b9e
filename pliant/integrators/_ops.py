"""Warp kernels for the vector arithmetic integrators need on (x, v) pairs of particle arrays."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import warp as wp

from .._warp import fresh, grad_enabled, launch

if TYPE_CHECKING:
    from ..model import Model


@wp.kernel
def _lincomb4(
    base: wp.array(dtype=Any),
    a0: wp.array(dtype=Any),
    a1: wp.array(dtype=Any),
    a2: wp.array(dtype=Any),
    a3: wp.array(dtype=Any),
    c0: Any,
    c1: Any,
    c2: Any,
    c3: Any,
    out: wp.array(dtype=Any),
):
    i = wp.tid()
    out[i] = base[i] + c0 * a0[i] + c1 * a1[i] + c2 * a2[i] + c3 * a3[i]


def lincomb(model: Model, out: wp.array, base: wp.array, terms: list[tuple[float, wp.array]]) -> None:
    """out = base + Σ c_k a_k (chunks of four terms per launch; ``out`` may alias ``base``).

    When the model requires gradients, ``out`` must not alias ``base`` or a term (a tape cannot replay an
    in-place update), and the partial sums of more than four terms go to fresh arrays.
    """
    s = model.s
    grad = grad_enabled(model)
    if grad and (out.ptr == base.ptr or any(a.ptr == out.ptr for _, a in terms)):
        raise ValueError("lincomb: out aliases an input, which a wp.Tape cannot replay (requires_grad model)")
    terms = [(c, a) for c, a in terms if c != 0.0]
    if not terms:
        if out.ptr != base.ptr:
            wp.copy(out, base)
        return
    src = base
    for k in range(0, len(terms), 4):
        chunk = terms[k : k + 4]
        while len(chunk) < 4:
            chunk.append((0.0, chunk[0][1]))
        dst = fresh(model, out.shape[0], out.dtype) if grad and k + 4 < len(terms) else out
        launch(
            _lincomb4,
            out.shape[0],
            [src, *(a for _, a in chunk), *(s(c) for c, _ in chunk), dst],
            device=model.device,
        )
        src = dst
