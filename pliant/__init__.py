"""pliant: deformable-object simulation — mass-spring, position-based dynamics and tetrahedral FEM —
with every time integrator of the lecture, on NVIDIA Warp (CPU and CUDA).

Steps are differentiable with ``wp.Tape`` on a model finalised with ``requires_grad=True`` (see
``pliant.diff``): ``ForceSolver`` with explicit integrators, or with BackwardEuler / ImplicitMidpoint / BDF2
(Newton or L-BFGS, implicit-function-theorem adjoint); ``FastMassSpring(method="symplectic")``; ``XPBD`` /
``PBD`` with the Jacobi schedule. What cannot give a gradient (``FastMassSpring(method="implicit")``, the
colouring schedule, ``collisions=`` handlers, the drag handle, ...) raises ``pliant.diff.GradientError``."""

from __future__ import annotations

from ._warp import init as _init

_init()

from . import energies, integrators, io, model, solvers  # noqa: E402
from .io import Trajectory  # noqa: E402
from .model import Control, Model, ModelBuilder, State  # noqa: E402
from .sim import DivergenceError, Simulator  # noqa: E402

__version__ = "0.1.0"


def __getattr__(name: str):
    # Heavier layers (renderer kernels, studies, benchmarks, CLI) load on first use, not on import.
    import importlib

    lazy = (
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
    )
    if name in lazy:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "Control",
    "DivergenceError",
    "Model",
    "ModelBuilder",
    "Simulator",
    "State",
    "Trajectory",
    "__version__",
    "energies",
    "integrators",
    "io",
    "model",
    "solvers",
]
