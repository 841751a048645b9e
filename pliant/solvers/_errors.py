"""Errors of the solvers' linear algebra, raised instead of SciPy's own."""

from __future__ import annotations


class SingularSystemError(ValueError):
    """A linear system a solver must factor or solve is singular (or numerically so).

    The message says which system, why it is singular in physical terms, and what to change.
    """


__all__ = ["SingularSystemError"]
