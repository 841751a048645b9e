"""Differentiable simulation: rollouts with loss and gradients, and a PyTorch bridge.

Plain Warp path (what :func:`rollout` automates): finalise the model with ``requires_grad=True``, make one
State per step, call ``solver.step`` inside a ``wp.Tape``, then ``tape.backward(loss)`` and read the model's
arrays' ``.grad`` (``spring_stiffness``, ``tet_mu``, ...), the solver's (``ground_coefficients``,
``gravity``, ``damping_rate_array``) and the first state's. Gravity and the damping rate are differentiable
for ForceSolver with explicit integrators (and ``XPBD``'s ``solver.gravity``). Differentiable solvers:
``ForceSolver`` with any explicit integrator or BackwardEuler / ImplicitMidpoint / BDF2 (Newton or L-BFGS,
implicit-function-theorem adjoint), with ground contact and kinematic targets;
``FastMassSpring(method="symplectic")``; ``XPBD`` / ``PBD`` with ``schedule="jacobi"``. What cannot give a
correct gradient raises :class:`GradientError` when asked. A rollout that blew up (non-finite, or faster than
``max_speed``) raises :class:`pliant.sim.DivergenceError` naming the frame (:func:`check_rollout`).

What can be differentiated is declared by the classes that read it (``parameters()``: energies,
constraints, colliders, solvers, the Model / State / Control); :func:`parameters` lists the registry with
units, element kinds and default search ranges, and :data:`PARAMETERS` is its differentiable part.
"""

from .._warp import GradientError
from ._graph import rollout_graphs
from ._rollout import PARAMETERS, RolloutResult, check_rollout, parameters, rollout
from ._torch import torch_rollout

__all__ = [
    "rollout_graphs",
    "PARAMETERS",
    "GradientError",
    "RolloutResult",
    "check_rollout",
    "parameters",
    "rollout",
    "torch_rollout",
]
