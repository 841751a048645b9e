"""Position-based dynamics: XPBD (compliant constraints) and PBD (stiffness-scaled projections)."""

from ._solver import PBD, XPBD

__all__ = ["PBD", "XPBD"]
