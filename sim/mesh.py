"""Water mesh for the renderer: the periodic FFT patch tiled over a water rectangle.

World frame: Y up, metres. The water rests in the plane y = y0; the patch is anchored at the
world origin and repeats with period L in x and z, so a vertex at (x, z) and one at (x + L, z)
sample the same surface. A vertex at rest position (x, z) moves to

    P(x, z) = (x + lambda Dx, y0 + h, z + lambda Dz)

with the fields sampled by bilinear interpolation of the periodic grid (wrap-around indices).

Normals: the exact normal of the displaced surface P(x, z), from the spectral derivatives
(no finite differences):

    dP/dx = (1 + dDx/dx, dh/dx, dDz/dx),  dP/dz = (dDx/dz, dh/dz, 1 + dDz/dz),
    n = normalize(dP/dz x dP/dx) = normalize((..., J, ...)),

whose y component is the Jacobian J; with choppiness 0 it is Tessendorf's
normalize(-dh/dx, 1, -dh/dz). Where the surface folds (J < 0) the normal honestly points
down. Between grid nodes the derivatives are interpolated bilinearly like the positions, so the
normal is exact at the nodes and an interpolation in between.

Border: with ``pin_border`` (default) the displacement component across the rectangle's edge is
dropped on the border vertices, so the water sheet meets the pool walls without gaps.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .params import SimParameterError, check_finite
from .water import FFTWater

#: Upper bound on mesh vertices (nx * nz). 2^26 vertices = 1.6 GB of positions + normals in
#: float32 and 4e8 int32 indices: far past any view's pixel count, so larger counts are mistakes.
MAX_VERTICES = 1 << 26


@wp.kernel
def water_mesh_kernel(
    height: wp.array2d(dtype=float),  # (N, N) h [m], read
    displacement: wp.array2d(dtype=wp.vec2),  # (N, N) (lambda Dx, lambda Dz) [m], read
    slope: wp.array2d(dtype=wp.vec2),  # (N, N) (dh/dx, dh/dz) [1], read
    displacement_gradient: wp.array2d(dtype=wp.vec3),  # (N, N) (dDx/dx, dDz/dz, dDx/dz), read
    patch_size: float,  # L [m]
    origin: wp.vec2,  # (x_min, z_min) [m]
    spacing: wp.vec2,  # vertex spacing (dx, dz) [m]
    y0: float,  # rest height [m]
    vertex_counts: wp.vec2i,  # (nx, nz)
    pin_border: int,  # 1: no displacement across the rectangle's edges on border vertices
    points: wp.array(dtype=wp.vec3),  # (nx*nz,) positions [m], write
    normals: wp.array(dtype=wp.vec3),  # (nx*nz,) unit normals, write
):
    """One vertex per thread; dim (nz, nx), vertex index iz * nx + ix."""
    iz, ix = wp.tid()
    n = height.shape[0]
    x = origin[0] + float(ix) * spacing[0]
    z = origin[1] + float(iz) * spacing[1]
    # periodic grid coordinates: node (i, j) sits at (j L/N, i L/N)
    to_grid = float(n) / patch_size
    u = x * to_grid
    v = z * to_grid
    u0 = wp.floor(u)
    v0 = wp.floor(v)
    fu = u - u0
    fv = v - v0
    j0 = ((int(u0) % n) + n) % n
    i0 = ((int(v0) % n) + n) % n
    j1 = (j0 + 1) % n
    i1 = (i0 + 1) % n
    w00 = (1.0 - fu) * (1.0 - fv)
    w01 = fu * (1.0 - fv)
    w10 = (1.0 - fu) * fv
    w11 = fu * fv
    h = w00 * height[i0, j0] + w01 * height[i0, j1] + w10 * height[i1, j0] + w11 * height[i1, j1]
    d = (w00 * displacement[i0, j0] + w01 * displacement[i0, j1]
         + w10 * displacement[i1, j0] + w11 * displacement[i1, j1])
    s = w00 * slope[i0, j0] + w01 * slope[i0, j1] + w10 * slope[i1, j0] + w11 * slope[i1, j1]
    g = (w00 * displacement_gradient[i0, j0] + w01 * displacement_gradient[i0, j1]
         + w10 * displacement_gradient[i1, j0] + w11 * displacement_gradient[i1, j1])
    dx = d[0]
    dz = d[1]
    if pin_border != 0:
        if ix == 0 or ix == vertex_counts[0] - 1:
            dx = 0.0
        if iz == 0 or iz == vertex_counts[1] - 1:
            dz = 0.0
    vertex = iz * vertex_counts[0] + ix
    points[vertex] = wp.vec3(x + dx, y0 + h, z + dz)
    tangent_x = wp.vec3(1.0 + g[0], s[0], g[2])  # dP/dx (dDz/dx == dDx/dz)
    tangent_z = wp.vec3(g[2], s[1], 1.0 + g[1])  # dP/dz
    normals[vertex] = wp.normalize(wp.cross(tangent_z, tangent_x))


def grid_triangles(nx: int, nz: int) -> np.ndarray:
    """Triangle indices of an nx x nz vertex grid (vertex iz*nx + ix), int32 shape (T*3,).

    Two triangles per cell, (v00, v01, v10) and (v10, v01, v11) with v01 the +z neighbour:
    counter-clockwise seen from +Y, so (p1 - p0) x (p2 - p0) points along +Y.
    """
    iz, ix = np.meshgrid(np.arange(nz - 1), np.arange(nx - 1), indexing="ij")
    v00 = (iz * nx + ix).ravel()
    v10 = v00 + 1
    v01 = v00 + nx
    v11 = v01 + 1
    return np.stack([v00, v01, v10, v10, v01, v11], axis=-1).astype(np.int32).ravel()


def check_rect(rect) -> tuple[float, float, float, float]:
    """(x_min, z_min, x_max, z_max) [m] as floats, or ``SimParameterError`` naming ``rect``."""
    try:
        x0, z0, x1, z1 = (check_finite("rect", c) for c in rect)
    except (TypeError, ValueError) as error:
        if isinstance(error, SimParameterError):
            raise SimParameterError(f"rect={rect!r} is invalid: {error}") from None
        raise SimParameterError(
            f"rect={rect!r} is invalid: expected (x_min, z_min, x_max, z_max) in metres") from None
    if not (x1 > x0 and z1 > z0):
        raise SimParameterError(
            f"rect={rect!r} is invalid: need x_max > x_min and z_max > z_min "
            "in (x_min, z_min, x_max, z_max)")
    return x0, z0, x1, z1


def check_vertex_counts(vertex_counts) -> tuple[int, int]:
    """(nx, nz) as ints >= 2 with nx * nz <= MAX_VERTICES, or ``SimParameterError``."""
    try:
        nx, nz = vertex_counts
        ok = all(isinstance(c, (int, np.integer)) and not isinstance(c, bool) and c >= 2
                 for c in (nx, nz))
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise SimParameterError(
            f"vertex_counts={vertex_counts!r} is invalid: expected two integers (nx, nz) >= 2")
    if nx * nz > MAX_VERTICES:
        raise SimParameterError(
            f"vertex_counts={vertex_counts!r} is invalid: nx*nz must be <= {MAX_VERTICES}; "
            "use sim.choose_lod to size the mesh")
    return int(nx), int(nz)


class WaterMesh:
    """Triangle mesh of the water over ``rect``, written in place each frame by one kernel.

    - ``points``: (nx*nz,) vec3 vertex positions [m], world frame, written by ``update``/``write``.
    - ``normals``: (nx*nz,) vec3 unit normals, written by ``update``/``write``.
    - ``indices``: (T*3,) int32 triangle vertex indices, T = 2 (nx-1)(nz-1), CCW seen from +Y;
      constant, built once.

    ``points``/``normals`` given to the constructor become the mesh's targets (caller-owned);
    otherwise the mesh allocates them. ``update``/``write`` may also be handed other arrays for one
    call. Vertex (ix, iz) rests at (x_min + ix (x_max - x_min)/(nx - 1), y0, z_min + iz (...)).
    """

    def __init__(self, water: FFTWater, rect, y0: float = 0.0, vertex_counts=(64, 64),
                 points: wp.array | None = None, normals: wp.array | None = None,
                 pin_border: bool = True):
        if not isinstance(water, FFTWater):
            raise SimParameterError(f"water={water!r} is invalid: expected an FFTWater")
        self.water = water
        self.device = water.device
        self.rect = check_rect(rect)
        self.y0 = check_finite("y0", y0)
        self.vertex_counts = check_vertex_counts(vertex_counts)
        nx, nz = self.vertex_counts
        self.vertex_count = nx * nz
        self.pin_border = bool(pin_border)
        x0, z0, x1, z1 = self.rect
        self.spacing = ((x1 - x0) / (nx - 1), (z1 - z0) / (nz - 1))
        self.indices = wp.array(grid_triangles(nx, nz), dtype=wp.int32, device=self.device)
        self.triangle_count = self.indices.shape[0] // 3
        self.points = (self._check_target("points", points) if points is not None
                       else wp.zeros(self.vertex_count, dtype=wp.vec3, device=self.device))
        self.normals = (self._check_target("normals", normals) if normals is not None
                        else wp.zeros(self.vertex_count, dtype=wp.vec3, device=self.device))
        self._launch = wp.launch(
            water_mesh_kernel, dim=(nz, nx),
            inputs=[water.height, water.displacement, water.slope, water.displacement_gradient,
                    water.patch_size, wp.vec2(x0, z0), wp.vec2(*self.spacing), self.y0,
                    wp.vec2i(nx, nz), int(self.pin_border), self.points, self.normals],
            device=self.device, record_cmd=True)

    def _check_target(self, name: str, array) -> wp.array:
        if (not isinstance(array, wp.array) or array.dtype != wp.vec3
                or array.shape != (self.vertex_count,) or array.device != self.device):
            raise SimParameterError(
                f"{name}={array!r} is invalid: expected a wp.array of vec3, shape "
                f"({self.vertex_count},), on device {self.device}")
        return array

    def write(self, points: wp.array | None = None, normals: wp.array | None = None) -> None:
        """Sample the water's current fields (its last ``evaluate``) into points and normals."""
        if self.water.time is None:
            raise RuntimeError("WaterMesh.write: call water.evaluate(t) or mesh.update(t) first")
        self._launch.set_param_by_name(
            "points", self.points if points is None else self._check_target("points", points))
        self._launch.set_param_by_name(
            "normals", self.normals if normals is None else self._check_target("normals", normals))
        self._launch.launch()

    def update(self, t: float, points: wp.array | None = None,
               normals: wp.array | None = None) -> None:
        """Evaluate the water at time ``t`` [s] and write the mesh (in place, no allocation)."""
        self.water.evaluate(t)
        self.write(points, normals)
