"""The specialised mass-spring solver: fused per-particle kernels for symplectic Euler, and Baraff–Witkin's
linearised implicit step by matrix-free block-Jacobi CG (with its adjoint for recorded steps)."""

from ._solver import FastMassSpring, spring_adjacency

__all__ = ["FastMassSpring", "spring_adjacency"]
