"""Spring stiffness of a square cloth lattice from membrane elasticity (E·t, ν): defined in
:mod:`pliant.model._materials` (the builder needs it, and model sits below energies), re-exported here."""

from __future__ import annotations

from ..model import cloth_spring_stiffness

__all__ = ["cloth_spring_stiffness"]
