"""Rigid bodies over particle clusters (Newton–Euler), the reference that shape matching is compared with."""

from ._solver import RigidBodySolver

__all__ = ["RigidBodySolver"]
