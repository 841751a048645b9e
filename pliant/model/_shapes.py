"""The builder's composite shapes: ropes, cloth grids, soft boxes, tet meshes and point clouds.

A mixin of :class:`pliant.model.ModelBuilder` (its own file so the builder stays readable): each method
makes geometry with :mod:`pliant.geometry` and adds it through the builder's element methods
(``add_particles``, ``add_springs``, ``add_triangles``, ``add_tetrahedra``, ``add_bending``, ``pin``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from ._checks import _as_index_array

_PIN_NAMES = ("top-corners", "top-edge", "corners", "top-left", "top-right", "none")


class ShapesMixin:
    """Composite shapes of :class:`pliant.model.ModelBuilder` (see there)."""

    if TYPE_CHECKING:  # what the shapes use of ModelBuilder, the one class this mixes into
        _render_faces: list[np.ndarray]
        _tet_host: list[np.ndarray]
        add_particles: Callable[..., int]
        add_springs: Callable[..., None]
        add_triangles: Callable[..., None]
        add_bending: Callable[..., None]
        add_tetrahedra: Callable[..., None]
        add_quadratic_tetrahedra: Callable[..., None]
        pin: Callable[[Any], None]
        register_object: Callable[..., None]

    def add_rope(
        self,
        *,
        n_segments: int,
        length: float,
        mass: float,
        stiffness: float,
        damping: float = 0.0,
        start: Sequence[float] = (0.0, 1.0, 0.0),
        direction: Sequence[float] = (1.0, 0.0, 0.0),
        bend_stiffness: float = 0.0,
        pin: str | Sequence[int] = "first",
        radius: float = 0.01,
        name: str = "rope",
    ) -> int:
        """Add a straight rope of ``n_segments`` springs (``n_segments + 1`` particles).

        Args:
            n_segments: number of springs along the rope.
            length: total rest length [m].
            mass: total mass [kg], spread evenly over the particles.
            stiffness: spring constant k of each segment [N/m].
            damping: dashpot coefficient γ of every spring [N s/m].
            start: position of the first particle [m].
            direction: direction the rope extends in [-] (any length: it is normalised).
            bend_stiffness: k of springs joining every second particle [N/m] (0: none).
            pin: ``"first"``, ``"last"``, ``"both"``, ``"none"`` or local particle indices to fix.
            radius: contact radius of each particle [m].
            name: object name (errors, ``model.objects``).

        Returns:
            The global index of the first particle.
        """
        from ..geometry import rope

        r = rope(n_segments, length, start=start, direction=direction)
        n = r.points.shape[0]
        first = self.add_particles(r.points, mass / n, radius=radius, name=name)
        self.add_springs(r.edges + first, stiffness=stiffness, damping=damping)
        if bend_stiffness > 0:
            self.add_springs(r.bend_edges + first, stiffness=bend_stiffness, damping=damping)
        local = (
            {"first": [0], "last": [n - 1], "both": [0, n - 1], "none": []}.get(pin)
            if isinstance(pin, str)
            else list(pin)
        )
        if local is None:
            raise ValueError(f"rope pin must be one of first|last|both|none or indices, got {pin!r}")
        self.pin(np.asarray(local, dtype=np.int64) + first)
        self.register_object(name, "rope", first)
        return first

    def add_cloth_grid(
        self,
        *,
        nx: int,
        ny: int,
        size: float | Sequence[float] = 1.0,
        mass: float,
        stiffness: float | None = None,
        shear_stiffness: float | None = None,
        bend_stiffness: float = 0.0,
        damping: float = 0.0,
        youngs_modulus_thickness: float | None = None,
        poisson: float = 0.3,
        origin: Sequence[float] = (0.0, 1.0, 0.0),
        plane: str = "xz",
        pin: str | Sequence[int] = "none",
        radius: float = 0.005,
        name: str = "cloth",
    ) -> int:
        """Add an nx × ny cell cloth with structural, shear and bend springs and bending pairs.

        Mass [kg] is lumped by triangle area. Give either spring ``stiffness`` [N/m] or the membrane
        stiffness ``youngs_modulus_thickness`` E·t [N/m] with ``poisson`` (mapped by
        :func:`pliant.energies.cloth_spring_stiffness`).

        Args:
            nx: cells along the first in-plane axis ((nx + 1) particles).
            ny: cells along the second in-plane axis ((ny + 1) particles).
            size: side length [m], or the two side lengths (u, v) [m].
            mass: total mass [kg].
            stiffness: k of the structural springs [N/m]; required unless ``youngs_modulus_thickness``.
            shear_stiffness: k of the diagonal springs [N/m] (default: ``stiffness``).
            bend_stiffness: k of springs across two cells [N/m] (0: none).
            damping: dashpot coefficient γ of every spring [N s/m].
            youngs_modulus_thickness: membrane stiffness E·t [N/m]; replaces ``stiffness`` and
                ``shear_stiffness``.
            poisson: Poisson ratio ν [-] used with ``youngs_modulus_thickness``.
            origin: corner of the grid [m].
            plane: ``"xz"`` (horizontal), ``"xy"`` or ``"yz"``.
            pin: ``"none"``, ``"top-corners"``, ``"top-edge"``, ``"corners"``, ``"top-left"``,
                ``"top-right"`` or local particle indices to fix.
            radius: contact radius of each particle [m].
            name: object name (errors, ``model.objects``).

        Returns:
            The global index of the first particle.
        """
        from ..geometry import cloth_grid

        g = cloth_grid(nx, ny, size=size, origin=origin, plane=plane)
        tris = g.triangles
        pts = g.points
        area = 0.5 * np.linalg.norm(
            np.cross(pts[tris[:, 1]] - pts[tris[:, 0]], pts[tris[:, 2]] - pts[tris[:, 0]]), axis=1
        )
        m = np.zeros(pts.shape[0])
        np.add.at(m, tris.ravel(), np.repeat(area / 3.0, 3))
        m *= mass / m.sum()
        if youngs_modulus_thickness is not None:
            from ._materials import cloth_spring_stiffness

            stiffness, shear_stiffness = cloth_spring_stiffness(youngs_modulus_thickness, poisson)
        if stiffness is None:
            raise ValueError("add_cloth_grid: give stiffness [N/m] or youngs_modulus_thickness [N/m]")
        shear_stiffness = stiffness if shear_stiffness is None else shear_stiffness
        first = self.add_particles(pts, m, radius=radius, name=name)
        self.add_springs(g.structural + first, stiffness=stiffness, damping=damping)
        self.add_springs(g.shear + first, stiffness=shear_stiffness, damping=damping)
        if bend_stiffness > 0:
            self.add_springs(g.bend + first, stiffness=bend_stiffness, damping=damping)
        self.add_triangles(tris + first)
        if g.bending_pairs.size:
            self.add_bending(g.bending_pairs + first, stiffness=0.0)
        if isinstance(pin, str):
            if pin not in _PIN_NAMES:
                raise ValueError(f"cloth pin must be one of {_PIN_NAMES} or indices, got {pin!r}")
            local: Sequence[int] | np.ndarray = [] if pin == "none" else g.pin_indices(pin)
        else:
            local = list(pin)
        self.pin(np.asarray(local, dtype=np.int64) + first)
        self.register_object(name, "cloth", first, nx=nx, ny=ny)
        return first

    def add_soft_box(
        self,
        *,
        cells: Sequence[int] = (4, 4, 4),
        size: Sequence[float] = (0.2, 0.2, 0.2),
        origin: Sequence[float] = (0.0, 0.5, 0.0),
        density: float = 1000.0,
        stiffness: float | None = None,
        damping: float = 0.0,
        E: float | None = None,
        nu: float = 0.3,
        velocity: Sequence[float] = (0.0, 0.0, 0.0),
        radius: float = 0.005,
        name: str = "soft_box",
        order: int = 1,
    ) -> int:
        """Add a box meshed into 6 tets per cell; mass is lumped (ρV/4 per tet vertex, or HRZ for order 2).

        ``stiffness`` adds tet-edge springs (a mass-spring volume); ``E`` adds FEM tetrahedra (both may be
        given).

        Args:
            cells: cells along x, y, z (6 tets each).
            size: box side lengths along x, y, z [m].
            origin: centre of the box [m].
            density: mass density ρ [kg/m³], > 0.
            stiffness: k of the tet-edge springs [N/m] (None: no springs).
            damping: dashpot coefficient γ of those springs [N s/m].
            E: Young's modulus of the FEM tetrahedra [Pa] (None: no FEM elements).
            nu: Poisson ratio ν [-] used with ``E``.
            velocity: initial velocity of every particle [m/s].
            radius: contact radius of each particle [m].
            name: object name (errors, ``model.objects``).
            order: 1 (linear 4-node tets) or 2 (quadratic 10-node tets, see :meth:`add_tet_mesh`).

        Returns:
            The global index of the first particle.
        """
        from ..geometry import box_tets

        nx, ny, nz = cells
        mesh = box_tets(nx, ny, nz, size=size, origin=np.asarray(origin) - 0.5 * np.asarray(size))
        return self._add_tet_mesh(
            mesh.points,
            mesh.tets,
            density,
            stiffness,
            damping,
            E,
            nu,
            velocity,
            radius,
            name,
            "soft_box",
            order,
        )

    def add_tet_mesh(
        self,
        points: npt.ArrayLike,
        tets: npt.ArrayLike,
        *,
        density: float = 1000.0,
        stiffness: float | None = None,
        damping: float = 0.0,
        E: float | None = None,
        nu: float = 0.3,
        velocity: Sequence[float] = (0.0, 0.0, 0.0),
        radius: float = 0.005,
        name: str = "tet_mesh",
        kind: str = "mesh",
        order: int = 1,
    ) -> int:
        """Add a tetrahedral mesh as a mass-spring volume (``stiffness``) and/or FEM body (``E``).

        Mass is lumped (ρV/4 per tet vertex). With ``order=2`` the linear mesh is promoted to 10-node
        tets (:func:`pliant.geometry.promote_tets_p2`): one particle at the midpoint of every distinct edge,
        after the mesh's own vertices, so constraints, pins, contact and fitting treat mid-edge nodes like
        any other particle; ρV is lumped by HRZ (1/36 per corner, 4/27 per mid-edge node: positive, unlike
        row sums). Contact and rendering see all nodes: the surface is the boundary of the 8 linear
        sub-tets of each element (4 triangles per face), which is also what export and embedding use.

        Args:
            points: [N, 3] vertex positions [m].
            tets: [E, 4] vertex indices per tetrahedron (0-based, into ``points``).
            density: mass density ρ [kg/m³], > 0.
            stiffness: k of the tet-edge springs [N/m] (None: no springs).
            damping: dashpot coefficient γ of those springs [N s/m].
            E: Young's modulus of the FEM tetrahedra [Pa] (None: no FEM elements).
            nu: Poisson ratio ν [-] used with ``E``.
            velocity: initial velocity of every particle [m/s].
            radius: contact radius of each particle [m].
            name: object name (errors, ``model.objects``).
            kind: the label it gets in ``model.objects`` (e.g. ``"soft_sphere"``).
            order: 1 (linear 4-node tets) or 2 (quadratic 10-node tets; FEM only, needs ``E``).

        Returns:
            The global index of the first particle.
        """
        return self._add_tet_mesh(
            points, tets, density, stiffness, damping, E, nu, velocity, radius, name, kind, order
        )

    def _add_tet_mesh(
        self, points, tets, density, stiffness, damping, E, nu, velocity, radius, name, kind, order=1
    ) -> int:
        from ..geometry import edges_from_tets, signed_tet_volumes, surface_from_tets

        pts = np.asarray(points, np.float64).reshape(-1, 3)
        tets = _as_index_array(tets, 4, "tetrahedron")
        if tets.size and (tets.min() < 0 or tets.max() >= pts.shape[0]):
            raise ValueError(f"{name}: tetrahedron indices out of range [0, {pts.shape[0]})")
        if density <= 0:
            raise ValueError(f"{name}: density must be > 0 kg/m³, got {density}")
        if isinstance(order, bool) or order not in (1, 2):
            raise ValueError(f"{name}: order must be 1 (linear tets) or 2 (quadratic tets), got {order!r}")
        if order == 2:
            return self._add_p2_mesh(pts, tets, density, stiffness, E, nu, velocity, radius, name, kind)
        vol = signed_tet_volumes(pts, tets)
        m = np.zeros(pts.shape[0])
        np.add.at(m, tets.ravel(), np.repeat(np.abs(vol) * density / 4.0, 4))
        vel = np.broadcast_to(np.asarray(velocity, np.float64), pts.shape)
        first = self.add_particles(pts, m, velocities=vel, radius=radius, name=name)
        if stiffness is not None:
            self.add_springs(edges_from_tets(tets) + first, stiffness=stiffness, damping=damping)
        if E is not None:
            self.add_tetrahedra(tets + first, E=E, nu=nu)
        self._render_faces.append(surface_from_tets(tets) + first)
        self._tet_host.append(tets + first)
        self.register_object(name, kind, first)
        return first

    def _add_p2_mesh(self, pts, tets, density, stiffness, E, nu, velocity, radius, name, kind) -> int:
        from ..geometry import p2_lumped_masses, p2_subtets, promote_tets_p2, surface_from_tets

        if stiffness is not None or E is None:
            raise ValueError(
                f"{name}: order = 2 (quadratic tets) is an FEM element: give E (and nu), not springs "
                "(stiffness); use order = 1 for a mass-spring volume"
            )
        pts10, tets10 = promote_tets_p2(pts, tets)
        vel = np.broadcast_to(np.asarray(velocity, np.float64), pts10.shape)
        m = p2_lumped_masses(pts10, tets10, density)
        first = self.add_particles(pts10, m, velocities=vel, radius=radius, name=name)
        self.add_quadratic_tetrahedra(tets10 + first, E=E, nu=nu)
        sub = p2_subtets(pts10, tets10)
        self._render_faces.append(surface_from_tets(sub) + first)
        self._tet_host.append(sub + first)
        self.register_object(name, kind, first, order=2)
        return first

    def add_point_cloud(
        self,
        points: npt.ArrayLike,
        *,
        mass: float,
        stiffness: float,
        radius: float,
        max_neighbors: int = 30,
        damping: float = 0.0,
        particle_radius: float = 0.005,
        name: str = "points",
    ) -> int:
        """Add a point cloud with PhysTwin-style springs to up to ``max_neighbors`` within ``radius``.

        Args:
            points: [N, 3] positions [m].
            mass: total mass [kg], spread evenly.
            stiffness: spring constant k [N/m].
            radius: connection radius [m]: springs join points closer than this.
            max_neighbors: most springs per point.
            damping: dashpot coefficient γ [N s/m].
            particle_radius: contact radius of each particle [m].
            name: object name (errors, ``model.objects``).

        Returns:
            The global index of the first particle.
        """
        from ..geometry import springs_from_points

        pts = np.asarray(points, np.float64).reshape(-1, 3)
        first = self.add_particles(pts, mass / max(len(pts), 1), radius=particle_radius, name=name)
        edges = springs_from_points(pts, radius, max_neighbors)
        if edges.shape[0] == 0:
            raise ValueError(
                f"{name}: no springs within radius {radius} m; increase radius (point spacing is larger)"
            )
        self.add_springs(edges + first, stiffness=stiffness, damping=damping)
        self.register_object(name, "points", first)
        return first
