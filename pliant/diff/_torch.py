"""A ``torch.autograd.Function`` around :func:`pliant.diff.rollout` (optional ``torch`` extra)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

from ..model import Control, Model, State
from ._rollout import PARAMETERS, rollout

if TYPE_CHECKING:
    from ..solvers import Solver


def _import_torch() -> Any:
    try:
        import torch
    except ImportError as e:  # optional dependency
        from .._extras import pip_install

        raise ImportError(
            f"pliant.diff.torch_rollout needs PyTorch: {pip_install('torch')} (or pip install torch)"
        ) from e
    return torch


def torch_rollout(
    model: Model,
    solver: Solver,
    loss_fn: Callable[[State], wp.array],
    params: Sequence[str],
    **rollout_kwargs: Any,
) -> Callable[..., Any]:
    """A function f(*tensors) → loss tensor, differentiable by PyTorch autograd.

    Each tensor sets the parameter of the same position in ``params`` (names from
    :data:`pliant.diff.PARAMETERS`, shaped like the parameter: [S] for per-spring values, [N, 3] for
    ``x0``/``v0``) before the rollout; ``backward`` returns ``grad_output`` × ∂loss/∂parameter. The rollout
    computes its gradients in the forward call (one forward, one recomputation, one backward pass), so
    call f only where the loss is differentiated.

    Args:
        model: Model finalised with ``requires_grad=True``.
        solver: a differentiable solver on ``model`` (any solver :func:`pliant.diff.rollout` accepts:
            explicit or implicit ForceSolver, FastMassSpring symplectic, XPBD/PBD Jacobi).
        loss_fn: final State → 1-element Warp array with the loss (see :func:`pliant.diff.rollout`).
        params: parameter names, one per tensor argument of f.
        **rollout_kwargs: ``frames``, ``dt``, ``substeps``, ``state0``, ``control``, ``checkpoint_every``.

    Example::

        f = pl.diff.torch_rollout(model, solver, loss, ["spring_stiffness"], frames=10, dt=1e-3)
        k = torch.tensor(model.spring_stiffness.numpy(), requires_grad=True)
        f(k).backward(); k.grad
    """
    torch = _import_torch()
    names = list(params)
    for n in names:
        if n not in PARAMETERS:
            raise ValueError(f"unknown parameter {n!r}; differentiable: {sorted(PARAMETERS)}")
    control: Control | None = rollout_kwargs.get("control")
    state0: State = rollout_kwargs.pop("state0", None) or model.state()

    function: Any = torch.autograd.Function  # a base class from the optional import

    class _Rollout(function):
        @staticmethod
        def forward(ctx: Any, *tensors: Any) -> Any:
            for name, t in zip(names, tensors, strict=False):
                a = PARAMETERS[name](model, solver, state0, control)
                value = t.detach().cpu().numpy().astype(np.float64)
                if isinstance(a, tuple):  # a scalar inside a shared array (ground coefficients)
                    arr, comp = a
                    host = arr.numpy()
                    host[comp] = value
                    arr.assign(host)
                else:
                    a.assign(value.reshape(a.numpy().shape))
            res = rollout(model, solver, loss_fn, params=names, state0=state0, **rollout_kwargs)
            pairs = zip(names, tensors, strict=True)
            ctx.grads = [torch.as_tensor(res.grads[n], dtype=t.dtype) for n, t in pairs]
            ctx.shapes = [t.shape for t in tensors]
            return torch.tensor(res.loss, dtype=tensors[0].dtype if tensors else torch.float64)

        @staticmethod
        def backward(ctx: Any, grad_output: Any) -> Any:
            return tuple(grad_output * g.reshape(s) for g, s in zip(ctx.grads, ctx.shapes, strict=False))

    def f(*tensors: Any) -> Any:
        if len(tensors) != len(names):
            raise ValueError(f"expected {len(names)} tensors ({names}), got {len(tensors)}")
        return _Rollout.apply(*tensors)

    return f
