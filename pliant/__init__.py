"""pliant: deformable-object simulation — mass-spring, position-based dynamics and tetrahedral FEM —
with every time integrator of the lecture, on NVIDIA Warp (CPU and CUDA).

Steps are differentiable with ``wp.Tape`` on a model finalised with ``requires_grad=True`` (see
``pliant.diff``): ``ForceSolver`` with explicit integrators, or with BackwardEuler / ImplicitMidpoint / BDF2
(Newton or L-BFGS, implicit-function-theorem adjoint); ``FastMassSpring`` (symplectic, or implicit through
the adjoint of its linear solve); ``XPBD`` / ``PBD`` with the Jacobi schedule; ForceSolver's collider contact.
What cannot give a gradient (the colouring schedule, mesh colliders, in-place ``collisions=`` handlers, the
drag handle, ...) raises ``pliant.diff.GradientError``."""

from __future__ import annotations

__version__ = "0.1.0"

# Nothing heavy is imported here: ``import pliant`` (and so ``pliant --help``) must not load Warp. Each
# name below loads its module on first use (PEP 562); pliant._warp initialises Warp when first imported.
_LAZY = {
    "Control": "model",
    "Model": "model",
    "ModelBuilder": "model",
    "State": "model",
    "Trajectory": "io",
    "DivergenceError": "sim",
    "Simulator": "sim",
    "RunReport": "runner",
    "run_scene": "runner",
}
_SUBMODULES = (
    "energies",
    "integrators",
    "io",
    "model",
    "solvers",
    "render",
    "geometry",
    "constraints",
    "collision",
    "studies",
    "bench",
    "cli",
    "sim",
    "scene",
    "diff",
    "fit",
    "gaussians",
    "sweep",
    "twin",
    "runner",
    "live",
)


def __getattr__(name: str):
    # Every layer loads on first use, not on import (the CLI's --help must not wait for Warp).
    import importlib

    if name in _LAZY or (name in _SUBMODULES and name != "cli"):
        importlib.import_module(f"{__name__}._warp")  # Warp initialised once, quietly, before any layer
    if name in _LAZY:
        value = getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
        globals()[name] = value  # later look-ups skip this function
        return value
    if name in _SUBMODULES:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY, *_SUBMODULES})


# Every name the package exposes: the lazy classes, the version and every public sub-package (but
# ``examples``, user code on top of this surface: ``python -m pliant.examples``). tests/test_public_api.py
# checks that this list, _LAZY, _SUBMODULES and the sub-packages on disk agree.
__all__ = [
    "Control",
    "DivergenceError",
    "Model",
    "ModelBuilder",
    "RunReport",
    "Simulator",
    "State",
    "Trajectory",
    "__version__",
    "bench",
    "cli",
    "collision",
    "constraints",
    "diff",
    "energies",
    "fit",
    "gaussians",
    "geometry",
    "integrators",
    "io",
    "live",
    "model",
    "render",
    "run_scene",
    "runner",
    "scene",
    "sim",
    "solvers",
    "studies",
    "sweep",
    "twin",
]
