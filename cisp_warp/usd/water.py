"""``cisp:water:*`` meshes: their simulation parameters and their rest grid, checked when the stage is read.

A mesh with ``cisp:water:*`` attributes is simulated by ``sim/`` (see :mod:`cisp_warp.animation`): its
attributes are the fields of :class:`sim.WaterParams` (``cisp:water:<field>``), and its default
(un-sampled) ``points`` must be a regular grid, vertex ``iz * nx + ix``, which the simulation writes in
place. :func:`check_water` validates both while :func:`~cisp_warp.usd.load_usd` reads the mesh, so the
API's ``Renderer`` never sees water that the simulation would refuse; on the CPU the FFT size is further
limited to ``MAX_CPU_RESOLUTION`` (a 4096² FFT takes two minutes and 5 GB per frame there).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim import SimParameterError, WaterParams

from ..errors import SceneError

MAX_CPU_RESOLUTION = 1024  #: largest cisp:water:resolution simulated on the CPU (about 10 s a frame)

GRID_TOLERANCE = 1e-3  #: rest points may miss their grid position by this fraction of the grid spacing


@dataclass(frozen=True)
class WaterGrid:
    """Where a water mesh rests: ``WaterMesh(rect=rect, y0=y0, vertex_counts=counts)``."""

    rect: tuple[float, float, float, float]  #: (x_min, z_min, x_max, z_max) [m]
    y0: float  #: rest height [m]
    counts: tuple[int, int]  #: (nx, nz) vertices


def water_grid(rest: np.ndarray, prim: str = "") -> WaterGrid:
    """The grid of rest points ``rest`` (V, 3) [m], vertex ``iz * nx + ix`` (see the module docstring)."""
    p = np.asarray(rest, dtype=np.float64).reshape(-1, 3)
    v = len(p)
    layout = ("the rest points of a cisp:water mesh must form a regular grid, vertex iz*nx + ix at "
              "(x0 + ix dx, y0, z0 + iz dz) with dx, dz > 0")
    span = float(np.ptp(p[:, [0, 2]], axis=0).max()) if v else 0.0
    same_row = np.abs(p[:, 2] - p[0, 2]) <= 1e-6 * span if v else np.zeros(0, bool)
    nx = int(np.argmin(same_row)) if v and not same_row.all() else v
    if v < 4 or nx < 2 or v % nx or v // nx < 2:
        raise SceneError(f"{layout}; {v} points do not make nx x nz rows (nx = {nx})", prim=prim)
    nz = v // nx
    x0, z0, x1, z1 = float(p[0, 0]), float(p[0, 2]), float(p[-1, 0]), float(p[-1, 2])
    if not (x1 > x0 and z1 > z0):
        raise SceneError(f"{layout}; point 0 is at (x, z) = ({x0:g}, {z0:g}) and the last at ({x1:g}, {z1:g})",
                         prim=prim)
    dx, dz = (x1 - x0) / (nx - 1), (z1 - z0) / (nz - 1)
    iz, ix = np.divmod(np.arange(v), nx)
    miss = max(np.abs(p[:, 0] - (x0 + ix * dx)).max() / dx, np.abs(p[:, 2] - (z0 + iz * dz)).max() / dz)
    if miss > GRID_TOLERANCE:
        raise SceneError(f"{layout}; as a {nx} x {nz} grid over x [{x0:g}, {x1:g}], z [{z0:g}, {z1:g}] a point is "
                         f"{miss:.3g} grid spacings off its place", prim=prim)
    return WaterGrid((x0, z0, x1, z1), float(p[:, 1].mean()), (nx, nz))


def water_params(values: dict, prim: str = "") -> WaterParams:
    """:class:`WaterParams` from a mesh's ``cisp:water:*`` values, or :class:`SceneError` naming the attribute."""
    try:
        return WaterParams.from_dict(values)
    except SimParameterError as exc:
        name = str(exc).split("=", 1)[0]
        known = WaterParams.__dataclass_fields__
        attr = f"cisp:water:{name}" if name in known else "cisp:water attributes"
        raise SceneError(f"{attr}: {exc}", prim=prim) from None


def check_water(values: dict, rest: np.ndarray | None, prim: str, on_cpu: bool) -> tuple[WaterParams, WaterGrid]:
    """The :class:`WaterParams` and :class:`WaterGrid` of a ``cisp:water`` mesh, or :class:`SceneError`.

    ``values``: the mesh's ``cisp:water:*`` values (namespace stripped); ``rest``: its default points in
    world space (V, 3) [m], None when the points have only time samples; ``on_cpu``: the frame is
    rendered on the CPU (caps the FFT size at ``MAX_CPU_RESOLUTION``).
    """
    params = water_params(values, prim)
    if on_cpu and params.resolution > MAX_CPU_RESOLUTION:
        raise SceneError(f"cisp:water:resolution = {params.resolution}: at most {MAX_CPU_RESOLUTION} on the CPU "
                         "(a larger FFT takes seconds to minutes a frame); lower it or render on a CUDA device",
                         prim=prim)
    if rest is None:
        raise SceneError("a cisp:water mesh needs its rest grid as the default (un-sampled) value of points; "
                         "it has only time samples", prim=prim)
    return params, water_grid(rest, prim)
