"""Tetrahedral FEM elasticity: E(x) = Σ_e V_e ψ(F_e) over the model's linear tetrahedra.

The element maths (ψ, P = ∂ψ/∂F, ∂P/∂F, PSD projection, element forces and Hessian blocks) lives in
:mod:`pliant.energies._fem_math`; this module only writes the kernels that loop over tets and the
:class:`~pliant.energies.Energy` classes that launch them. One set of kernels is built per material model
(a closure over that model's ``@wp.func``\\ s, in its own Warp module), so a material compiles only what it
uses; each kernel is generic over float32 / float64.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import warp as wp

from .._warp import launch
from ..model import TET_LAM, TET_MU, Model, Parameter, declares
from . import _fem_math as fm
from . import _fem_p2 as p2
from ._base import Energy
from ._fem_guards import _fill, _tet_max_step, _tet_min_det, _tet_sigma_min_bound
from ._materials import get_material_model, lame_parameters

# ----------------------------------------------------------------------------------- material-free kernels


@wp.func
def _add_tet_gradient(
    tet_indices: wp.array2d(dtype=wp.int32),
    t: int,
    f0: Any,
    f1: Any,
    f2: Any,
    f3: Any,
    grad_out: wp.array(dtype=Any),
):
    # ∂E/∂x_a = −f_a (element forces); vertices are shared between tets: atomics.
    wp.atomic_sub(grad_out, tet_indices[t, 0], f0)
    wp.atomic_sub(grad_out, tet_indices[t, 1], f1)
    wp.atomic_sub(grad_out, tet_indices[t, 2], f2)
    wp.atomic_sub(grad_out, tet_indices[t, 3], f3)


_KERNELS: dict[str, tuple[Any, Any, Any, Any]] = {}
_OVERLOADED: set[tuple[str, str]] = set()


def _material_kernels(name: str, dtype: str) -> tuple[Any, Any, Any, Any]:
    """(value, gradient [with the value on request], projected Hessian, exact Hessian) kernels for material
    ``name``, built once.

    Value and gradient share one Warp module (with adjoints, for fitting); each Hessian, the costly ones to
    compile, gets its own module without adjoints. The overloads for ``dtype`` are declared for all three
    before the first launch, so each module compiles once per dtype set instead of once per kernel.
    """
    if name not in _KERNELS:
        _KERNELS[name] = _build_material_kernels(name)
    kernels = _KERNELS[name]
    if (name, dtype) not in _OVERLOADED:
        fm.declare_overloads(
            kernels,
            dtype,
            lambda s, m33: {"tet_rest_inv": m33, "tet_rest_volume": s, "tet_mu": s, "tet_lam": s},
        )
        _OVERLOADED.add((name, dtype))
    return kernels


def _build_material_kernels(name: str) -> tuple[Any, Any, Any, Any]:
    mat = get_material_model(name)
    psi_fn, pk1_fn, dpdf_fn, dpdf_psd_fn = mat.psi, mat.pk1, mat.dpk1_df, mat.dpk1_df_psd
    module = wp.get_module(f"pliant.energies._fem.{name}")
    hessian_module = wp.get_module(f"pliant.energies._fem.{name}_hessian")

    @wp.kernel(module=module)
    def tet_value(
        tet_indices: wp.array2d(dtype=wp.int32),
        tet_rest_inv: wp.array(dtype=Any),
        tet_rest_volume: wp.array(dtype=Any),
        tet_mu: wp.array(dtype=Any),
        tet_lam: wp.array(dtype=Any),
        x_in: wp.array(dtype=Any),
        out: wp.array(dtype=Any),
    ):
        t = wp.tid()
        F = fm.tet_deformation_gradient(tet_indices, t, x_in, tet_rest_inv[t])
        wp.atomic_add(out, 0, tet_rest_volume[t] * psi_fn(F, tet_mu[t], tet_lam[t]))

    @wp.kernel(module=module)
    def tet_gradient(
        tet_indices: wp.array2d(dtype=wp.int32),
        tet_rest_inv: wp.array(dtype=Any),
        tet_rest_volume: wp.array(dtype=Any),
        tet_mu: wp.array(dtype=Any),
        tet_lam: wp.array(dtype=Any),
        x_in: wp.array(dtype=Any),
        with_value: int,
        out: wp.array(dtype=Any),
        grad_out: wp.array(dtype=Any),
    ):
        # ∂E/∂x, and E into out[0] when with_value (the quasi-Newton line search: F is built once for both).
        t = wp.tid()
        Dm_inv = tet_rest_inv[t]
        F = fm.tet_deformation_gradient(tet_indices, t, x_in, Dm_inv)
        V = tet_rest_volume[t]
        if with_value != 0:
            wp.atomic_add(out, 0, V * psi_fn(F, tet_mu[t], tet_lam[t]))
        g0, g1, g2, g3 = fm.tet_forces(pk1_fn(F, tet_mu[t], tet_lam[t]), Dm_inv, V)
        _add_tet_gradient(tet_indices, t, g0, g1, g2, g3, grad_out)

    def make_hessian(dpdf: Any, mod: Any) -> Any:
        @wp.kernel(module=mod, enable_backward=False)
        def tet_hessian(
            tet_indices: wp.array2d(dtype=wp.int32),
            tet_rest_inv: wp.array(dtype=Any),
            tet_rest_volume: wp.array(dtype=Any),
            tet_mu: wp.array(dtype=Any),
            tet_lam: wp.array(dtype=Any),
            slots: wp.array(dtype=wp.int32),
            x_in: wp.array(dtype=Any),
            scale: Any,
            values_out: wp.array(dtype=Any),
        ):
            t = wp.tid()
            Dm_inv = tet_rest_inv[t]
            F = fm.tet_deformation_gradient(tet_indices, t, x_in, Dm_inv)
            A = dpdf(F, tet_mu[t], tet_lam[t])
            V = scale * tet_rest_volume[t]
            for a in range(4):
                for b in range(4):
                    block = fm.tet_hessian_block(A, Dm_inv, V, a, b)
                    wp.atomic_add(values_out, slots[16 * t + 4 * a + b], block)

        return tet_hessian

    # The projected and the exact Hessian in modules of their own: a run uses one of them (projected by
    # default), and each is the costliest module of an FEM scene's first build.
    tet_hessian = make_hessian(dpdf_psd_fn, hessian_module)
    tet_hessian_exact = make_hessian(dpdf_fn, wp.get_module(f"pliant.energies._fem.{name}_hessian_exact"))

    return tet_value, tet_gradient, tet_hessian, tet_hessian_exact


def _np(model: Model) -> type:
    return np.float32 if model.dtype == "float32" else np.float64


def _tet10(model: Model, name: str) -> wp.array:
    """The quadratic-tet array ``name`` of a model with ``tet10_count`` > 0 (its builder sets them all)."""
    a = getattr(model, name)
    if a is None:
        raise ValueError(
            f"the model has {model.tet10_count} quadratic tets but no {name}; build it with ModelBuilder"
        )
    return a


def _guard_tets(model: Model) -> list[wp.array]:
    """The linear tets the step bounds watch: the model's tets and the sub-tets of its quadratic ones."""
    out = [model.tet_indices] if model.tet_count else []
    if model.tet10_count:
        out.append(_tet10(model, "tet10_subtets"))
    return out


# ----------------------------------------------------------------------------------------------- classes


@declares
class TetElasticity(Energy):
    """Hyperelastic linear tetrahedra: E(x) = Σ_e V_e ψ(F_e; μ_e, λ_e) [J], F_e = D_s D_m⁻¹.

    The material model is one of :data:`pliant.energies.MATERIAL_MODELS` (``"linear"``, ``"stvk"``,
    ``"corotated"``, ``"neohookean"``); the Lamé parameters are per tet, from the model (``tet_mu``,
    ``tet_lam``, built from E and ν by ``ModelBuilder.add_tetrahedra``), unless ``E`` is given here, which
    overrides them with one uniform material. Forces are f_a = −V P ∂F/∂x_a, accumulated atomically; the
    Hessian is 16 3×3 blocks per tet, V (∂F/∂x_a)ᵀ ∂P/∂F (∂F/∂x_b), with ∂P/∂F projected to PSD per element
    from its analytic eigensystem when ``project_psd`` (Smith, de Goes, Kim, "Analytic Eigensystems for
    Isotropic Distortion Energies", ACM TOG 38(1), 2019).

    ``max_step`` bounds the line search so that no element's volume falls below ``inversion_margin`` times
    its current volume within one step (the first root of the cubic det(D_s + α ΔD_s) = η det(D_s)), so a
    Newton solve started from an uninverted mesh never inverts an element.

    Quadratic (10-node) tets of the model (``add_soft_box(..., order=2)``, ``tet10_*`` arrays) are summed
    too, with F at the points of ``quadrature`` (:mod:`pliant.energies._fem_p2`): they do not lock in
    bending. Their Hessian is 100 blocks per element after the 16 per linear tet; the step bound and the
    inversion diagnostics use their 8 linear sub-tets (corner and mid-edge nodes).

    Limitations: linear (4-node) tets lock in bending and for ν → 0.5; use a fine mesh (see
    ``tests/test_fem_solid_mechanics.py``). ``linear`` is not rotation invariant: large rotations create
    spurious stress.

    Args:
        material: material model name (``"linear"``, ``"stvk"``, ``"corotated"``, ``"neohookean"``);
            None: the class's ``default_material``.
        E: Young's modulus [Pa] overriding the model's per-tet values (None: use the model's).
        nu: Poisson's ratio [-] used with ``E``, in (-1, 0.5).
        inversion_margin: η ∈ [0, 1) [-]: the smallest fraction of its volume an element may keep in one
            step.
        quadrature: polynomial degree of the quadrature rule on quadratic tets: 2 (4 points, exact for
            the linear law's stiffness) or 5 (14 points); None: 2 for ``"linear"``, 5 for the others.

    Example::

        b = pl.ModelBuilder()
        b.add_soft_box(cells=(4, 4, 4), size=(0.2, 0.2, 0.2), E=1e5, nu=0.4)
        model = b.finalize()
        solver = pl.solvers.ForceSolver(model, [pl.energies.NeoHookean(), pl.energies.Gravity()],
                                        pl.integrators.BackwardEuler())
    """

    #: Material model of this class; the named subclasses fix it, TetElasticity takes it as an argument.
    default_material: ClassVar[str] = "neohookean"

    @classmethod
    def parameters(cls) -> tuple[Parameter, ...]:
        """Lamé μ and λ per tet (E and ν through the chain rule)."""
        return (
            TET_MU,
            TET_LAM,
        )

    def __init__(
        self,
        material: str | None = None,
        *,
        E: float | None = None,
        nu: float = 0.3,
        inversion_margin: float = 0.1,
        quadrature: int | None = None,
    ) -> None:
        self.material = get_material_model(self.default_material if material is None else material)
        if quadrature is None:
            quadrature = 2 if self.material.name == "linear" else 5
        if quadrature not in (2, 5):
            raise ValueError(f"quadrature must be 2 (4 points) or 5 (14 points), got {quadrature!r}")
        self.quadrature = int(quadrature)
        if not 0.0 <= inversion_margin < 1.0:
            raise ValueError(f"inversion_margin must be in [0, 1), got {inversion_margin}")
        self.E = None if E is None else float(E)
        self.nu = float(nu)
        self._lame = None if E is None else lame_parameters(E, nu)
        self.inversion_margin = float(inversion_margin)
        self._cache: dict[str, Any] = {}
        if self.material.name not in _KERNELS:
            # Create the material's kernels now, not at the first step: a scene's background prebuild
            # (pliant._prebuild) can then compile their modules before the simulation needs them.
            _KERNELS[self.material.name] = _build_material_kernels(self.material.name)

    def __repr__(self) -> str:
        extra = "" if self.E is None else f", E={self.E:g}, nu={self.nu:g}"
        return f"{type(self).__name__}(material={self.material.name!r}{extra})"

    # ------------------------------------------------------------------ helpers
    def _buffers(self, model: Model) -> dict[str, Any]:
        c = self._cache
        if c.get("model") is not model:
            c.clear()
            c["model"] = model
            d = model.device
            c["alpha"] = wp.zeros(1, dtype=model.scalar, device=d)
            if self._lame is not None:
                mu, lam = self._lame
                c["mu"] = wp.full(model.tet_count, model.s(mu), dtype=model.scalar, device=d)
                c["lam"] = wp.full(model.tet_count, model.s(lam), dtype=model.scalar, device=d)
            else:
                c["mu"], c["lam"] = model.tet_mu, model.tet_lam
            if model.tet10_count:
                from ..geometry import tet_quadrature

                bary, w = tet_quadrature(self.quadrature)
                c["qp_bary"] = wp.array(
                    bary.astype(_np(model)), dtype=wp.types.vector(4, model.scalar), device=d
                )
                c["qp_weight"] = wp.array(w.astype(_np(model)), dtype=model.scalar, device=d)
                if self._lame is not None:
                    mu, lam = self._lame
                    c["mu10"] = wp.full(model.tet10_count, model.s(mu), dtype=model.scalar, device=d)
                    c["lam10"] = wp.full(model.tet10_count, model.s(lam), dtype=model.scalar, device=d)
                else:
                    c["mu10"], c["lam10"] = model.tet10_mu, model.tet10_lam
        return c

    def _inputs10(self, model: Model) -> list:
        c = self._buffers(model)
        return [
            model.tet10_indices,
            model.tet10_rest_inv,
            model.tet10_rest_volume,
            c["mu10"],
            c["lam10"],
            c["qp_bary"],
            c["qp_weight"],
        ]

    def _dim10(self, model: Model) -> int:
        return model.tet10_count * self._buffers(model)["qp_weight"].shape[0]

    def _inputs(self, model: Model) -> list:
        c = self._buffers(model)
        return [model.tet_indices, model.tet_rest_inv, model.tet_rest_volume, c["mu"], c["lam"]]

    # ------------------------------------------------------------------ Energy contract
    def value(self, model: Model, x: wp.array, out: wp.array) -> None:
        """Add Σ V ψ(F) [J] into ``out[0]``."""
        if model.tet_count:
            k = _material_kernels(self.material.name, model.dtype)[0]
            launch(k, model.tet_count, [*self._inputs(model), x, out], device=model.device)
        if model.tet10_count:
            k = p2.p2_material_kernels(self.material.name, model.dtype)[0]
            launch(k, self._dim10(model), [*self._inputs10(model), x, out], device=model.device)

    def gradient(self, model: Model, x: wp.array, out: wp.array) -> None:
        """Add ∂E/∂x [N] (minus the element forces) per particle into ``out``."""
        if model.tet_count:
            k = _material_kernels(self.material.name, model.dtype)[1]
            c = self._buffers(model)
            # with_value = 0: the kernel never touches its value output, so any 1-element array will do.
            launch(k, model.tet_count, [*self._inputs(model), x, 0, c["alpha"], out], device=model.device)
        if model.tet10_count:
            k = p2.p2_material_kernels(self.material.name, model.dtype)[1]
            c = self._buffers(model)
            launch(
                k, self._dim10(model), [*self._inputs10(model), x, 0, c["alpha"], out], device=model.device
            )

    def value_and_gradient(self, model: Model, x: wp.array, value_out: wp.array, grad_out: wp.array) -> None:
        """Add E(x) [J] into ``value_out[0]`` and ∂E/∂x [N] into ``grad_out`` in one pass over the tets."""
        if model.tet_count:
            k = _material_kernels(self.material.name, model.dtype)[1]
            launch(k, model.tet_count, [*self._inputs(model), x, 1, value_out, grad_out], device=model.device)
        if model.tet10_count:
            k = p2.p2_material_kernels(self.material.name, model.dtype)[1]
            launch(
                k,
                self._dim10(model),
                [*self._inputs10(model), x, 1, value_out, grad_out],
                device=model.device,
            )

    def hessian_pattern(self, model: Model) -> tuple[np.ndarray, np.ndarray]:
        """16 blocks per tet, (a, b) for a, b in 0..3 in row-major order: slot 16 t + 4 a + b; then 100 per
        quadratic tet, slot 16 E + 100 t + 10 a + b."""
        idx = model.tet_indices.numpy().astype(np.int32)
        rows = np.repeat(idx, 4, axis=1).ravel()
        cols = np.tile(idx, (1, 4)).ravel()
        if model.tet10_count:
            r10, c10 = p2.p2_hessian_pattern(_tet10(model, "tet10_indices").numpy())
            rows, cols = np.concatenate([rows, r10]), np.concatenate([cols, c10])
        return rows, cols

    def hessian(self, model, x, slots, values, *, project_psd: bool = True, scale: float = 1.0) -> None:
        """Add scale·∂²E/∂x² [N/m] (PSD-projected per element when ``project_psd``) into ``values[slots]``."""
        if model.tet_count:
            k = _material_kernels(self.material.name, model.dtype)[2 if project_psd else 3]
            launch(
                k,
                model.tet_count,
                [*self._inputs(model), slots, x, model.s(scale), values],
                device=model.device,
            )
        if model.tet10_count:
            k = p2.p2_material_kernels(self.material.name, model.dtype)[2 if project_psd else 3]
            launch(
                k,
                self._dim10(model),
                [*self._inputs10(model), slots, x, model.s(scale), 16 * model.tet_count, values],
                device=model.device,
            )

    def max_step(self, model: Model, x: wp.array, dx: wp.array) -> float:
        """Largest α ≤ 1 keeping every element's volume above η times its current one (one host read)."""
        if not (model.tet_count or model.tet10_count):
            return 1.0
        a = self._buffers(model)["alpha"]
        launch(_fill, 1, [model.s(1.0), a], device=model.device)
        self.max_step_into(model, x, dx, a)
        return float(a.numpy()[0])

    def max_step_into(self, model: Model, x: wp.array, dx: wp.array, alpha_io: wp.array) -> bool:
        """Lower ``alpha_io[0]`` to :meth:`max_step`'s bound on the device (atomic min over the tets)."""
        for tets in _guard_tets(model):
            launch(
                _tet_max_step,
                tets.shape[0],
                [tets, x, dx, model.s(self.inversion_margin), alpha_io],
                device=model.device,
            )
        return True

    def max_step_radius(self, model: Model, x: wp.array) -> float:
        """Radius r [m] around x: a displacement with every |u_i| ≤ r keeps each element's volume above η
        times its volume at x.

        Each edge matrix moves by ‖ΔD_s‖₂ ≤ ‖ΔD_s‖_F ≤ 2√3 max_i |u_i|, so det(D_s + ΔD_s)/det(D_s) ≥
        (1 − ‖ΔD_s‖₂/σ_min(D_s))³, which stays above η while max_i |u_i| ≤ (1 − η^⅓) σ_min/(2√3). σ_min is
        bounded below by 2|det D_s|/‖D_s‖_F² (one pass, one host read); 0 when an element is already
        inverted. Solvers skip :meth:`max_step` for steps inside the radius.
        """
        if not (model.tet_count or model.tet10_count):
            return float("inf")
        a = self._buffers(model)["alpha"]
        launch(_fill, 1, [model.s(np.inf), a], device=model.device)
        for tets in _guard_tets(model):
            launch(_tet_sigma_min_bound, tets.shape[0], [tets, x, a], device=model.device)
        sigma = float(a.numpy()[0])
        return (1.0 - self.inversion_margin ** (1.0 / 3.0)) * sigma / (2.0 * np.sqrt(3.0))

    # ------------------------------------------------------------------ diagnostics
    def min_det(self, model: Model, x: wp.array) -> float:
        """min_e det F_e over the model's tets at ``x`` (≤ 0: an element is inverted); one host read.

        Quadratic tets count with det F at each of their quadrature points."""
        if not (model.tet_count or model.tet10_count):
            return 1.0
        out = wp.full(1, model.s(np.inf), dtype=model.scalar, device=model.device)
        if model.tet_count:
            launch(
                _tet_min_det,
                model.tet_count,
                [model.tet_indices, model.tet_rest_inv, x, out],
                device=model.device,
            )
        value = float(out.numpy()[0])
        if model.tet10_count:
            value = min(value, p2.p2_min_det(model, self._buffers(model)["qp_bary"], x))
        return value


class LinearElastic(TetElasticity):
    """Linear elasticity ψ = μ ε:ε + λ/2 tr(ε)², ε = ½(F + Fᵀ) − I (small strains; not rotation invariant).

    See :class:`TetElasticity` for the energy, forces, Hessian and step bound.

    Args:
        material: None (``"linear"``); another model name turns it into that model.
        E: Young's modulus [Pa] overriding the model's per-tet values (None: use the model's, set by
            ``ModelBuilder.add_tetrahedra`` / ``add_soft_box`` / ``add_tet_mesh``).
        nu: Poisson's ratio [-] used with ``E``, in (-1, 0.5).
        inversion_margin: η ∈ [0, 1) [-]: the smallest fraction of its volume an element may keep in one
            step.
        quadrature: polynomial degree of the rule on quadratic tets, 2 (4 points) or 5 (14 points); None:
            2 for ``"linear"``, 5 for the others.
    """

    default_material: ClassVar[str] = "linear"


class StVK(TetElasticity):
    """St. Venant–Kirchhoff ψ = μ E:E + λ/2 tr(E)², E = ½(FᵀF − I) (softens, and can invert, in compression).

    See :class:`TetElasticity` for the energy, forces, Hessian and step bound.

    Args:
        material: None (``"stvk"``); another model name turns it into that model.
        E: Young's modulus [Pa] overriding the model's per-tet values (None: use the model's, set by
            ``ModelBuilder.add_tetrahedra`` / ``add_soft_box`` / ``add_tet_mesh``).
        nu: Poisson's ratio [-] used with ``E``, in (-1, 0.5).
        inversion_margin: η ∈ [0, 1) [-]: the smallest fraction of its volume an element may keep in one
            step.
        quadrature: polynomial degree of the rule on quadratic tets, 2 (4 points) or 5 (14 points); None:
            2 for ``"linear"``, 5 for the others.
    """

    default_material: ClassVar[str] = "stvk"


class Corotated(TetElasticity):
    """Fixed corotated ψ = μ ‖F − R‖² + λ/2 (J − 1)², F = R S (Stomakhin et al. 2012).

    See :class:`TetElasticity` for the energy, forces, Hessian and step bound.

    Args:
        material: None (``"corotated"``); another model name turns it into that model.
        E: Young's modulus [Pa] overriding the model's per-tet values (None: use the model's, set by
            ``ModelBuilder.add_tetrahedra`` / ``add_soft_box`` / ``add_tet_mesh``).
        nu: Poisson's ratio [-] used with ``E``, in (-1, 0.5).
        inversion_margin: η ∈ [0, 1) [-]: the smallest fraction of its volume an element may keep in one
            step.
        quadrature: polynomial degree of the rule on quadratic tets, 2 (4 points) or 5 (14 points); None:
            2 for ``"linear"``, 5 for the others.
    """

    default_material: ClassVar[str] = "corotated"


class NeoHookean(TetElasticity):
    """Stable neo-Hookean ψ = μ/2 (I_C − 3) − μ (J − 1) + (λ + μ)/2 (J − 1)² (Smith, de Goes, Kim 2018).

    See :class:`TetElasticity` for the energy, forces, Hessian and step bound.

    Args:
        material: None (``"neohookean"``); another model name turns it into that model.
        E: Young's modulus [Pa] overriding the model's per-tet values (None: use the model's, set by
            ``ModelBuilder.add_tetrahedra`` / ``add_soft_box`` / ``add_tet_mesh``).
        nu: Poisson's ratio [-] used with ``E``, in (-1, 0.5).
        inversion_margin: η ∈ [0, 1) [-]: the smallest fraction of its volume an element may keep in one
            step.
        quadrature: polynomial degree of the rule on quadratic tets, 2 (4 points) or 5 (14 points); None:
            2 for ``"linear"``, 5 for the others.
    """

    default_material: ClassVar[str] = "neohookean"
