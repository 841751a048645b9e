"""The generic force-based solver: every energy term and any integrator, explicit or implicit (an implicit
step's minimisation is :mod:`pliant.solvers.minimizers`'s)."""

from ._solver import ForceSolver

__all__ = ["ForceSolver"]
