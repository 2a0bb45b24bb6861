"""Warp kernels of the mesh grid's refinement (``PhotonSettings.wavefront_refine``): the cells whose corner
photons diverge with one of them on a camera surface (``TRI_REFINE``: a silhouette, an occluder's shadow edge) are
listed in cell order (a flag, a scan, a scatter), cut m × m in their own barycentric lattice, their corners traced
as the grid's are (view by view, :func:`~.kernels_wavefront.trace_corner_cisp` or ``trace_corner_world``) and their
sub-cells splatted (:func:`~.kernels_splat.splat_corners`), each with 1/m² of the cell's power. Cells listed past the
refinement's capacity fall back to points at their grid corners. Every watt of a refined cell is booked by its
sub-cells (the grid's splat booked nothing for it).
"""

from __future__ import annotations

import warp as wp

from ..raster.light_maps import CascadeState
from ..raster.views import ViewParams
from .kernels_meshgrid import (MeshGrid, corner_lattice, corner_normals, corner_slot, lattice_point_uv,
                               light_direction, owner_view, sub_cell)
from .kernels_splat import TRI_REFINE, splat_corners
from .kernels_wavefront import LedgerRows, Records, ledger_flush, trace_corner_cisp, trace_corner_world
from .kernels_world import CameraBuffers, WorldScene

wp.set_module_options({"enable_backward": False})


@wp.kernel
def refine_flags(tri_state: wp.array(dtype=wp.int32), flags: wp.array(dtype=wp.int32)):
    """1 for every cell (and sheet) the splat left to refinement (``TRI_REFINE``), else 0."""
    t = wp.tid()
    flags[t] = wp.where(tri_state[t] == TRI_REFINE, 1, 0)


@wp.kernel
def refine_scatter(flags: wp.array(dtype=wp.int32), offsets: wp.array(dtype=wp.int32),
                   refine_list: wp.array(dtype=wp.int32)):
    """Compact the flagged cells (``offsets``: the exclusive scan of ``flags``) into ``refine_list``, in cell
    order (deterministic)."""
    t = wp.tid()
    if flags[t] != 0:
        refine_list[offsets[t]] = t


@wp.func
def refine_corner(grid: MeshGrid, m: int, refine_list: wp.array(dtype=wp.int32), q: int, points: wp.array(dtype=wp.vec3),
                  normals: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32)):
    """Refinement photon ``q``: corner (i, j) of the m × m lattice over refined cell ``refine_list[q / C(m)]``
    (C(m) = (m + 1)(m + 2)/2). Returns (sheet, scene triangle, point [m], unit normal, geometric normal)."""
    cm = (m + 1) * (m + 2) / 2
    r = q / cm
    i, j = corner_lattice(m, q - r * cm)
    total = grid.count * grid.cells
    t = refine_list[r]
    sheet = t / total
    c = t - sheet * total
    k = c / grid.cells
    ca, cb, cc = sub_cell(grid.n, c - k * grid.cells)
    fi = float(i) / float(m)
    fj = float(j) / float(m)
    u = float(ca[0]) + float(cb[0] - ca[0]) * fi + float(cc[0] - ca[0]) * fj
    v = float(ca[1]) + float(cb[1] - ca[1]) * fi + float(cc[1] - ca[1]) * fj
    tri = grid.tris[k]
    x, nrm = lattice_point_uv(grid, points, normals, indices, k, u, v)
    n, ng = corner_normals(tri, nrm, points, indices)
    return sheet, tri, x, n, ng


@wp.kernel
def trace_refine_cisp(
    views: wp.array(dtype=ViewParams),  # (V,) the light's views (read)
    states: wp.array(dtype=CascadeState),  # (V,) their states (read)
    view_count: int,
    view_index: int,  # this launch traces the refinement corners that lie in this view
    light_kind: int,
    light_pos: wp.vec3,
    grid: MeshGrid,
    m: int,  # refined cells are cut m × m
    refine_list: wp.array(dtype=wp.int32),  # (refined,) cells (sheet · T · n² + cell) (read)
    rsm_opaque_depth: wp.array(dtype=wp.float32),  # (H_l*W_l,) [m] (read)
    rsm_depth_bounds: wp.array(dtype=wp.vec2),  # its march.depth_bounds (read)
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    indices: wp.array(dtype=wp.int32),
    triangle_material: wp.array(dtype=wp.int32),
    mat_opacity: wp.array(dtype=wp.float32),
    mat_ior: wp.array(dtype=wp.float32),
    camera: ViewParams,
    cam_depth: wp.array(dtype=wp.float32),
    cam_depth_bounds: wp.array(dtype=wp.vec2),
    cam_position: wp.array(dtype=wp.vec3),
    cam_normal: wp.array(dtype=wp.vec3),
    max_steps: int,
    thickness: float,
    thickness_rel: float,
    t_max: float,
    use_cascade: int,
    rec: Records,  # (refined · C(m),) (write)
):
    """One thread per refinement photon (:func:`refine_corner`) in its cell's sheet, traced as the grid's
    corners are (:func:`trace_corner_cisp`) in the view it lies in."""
    q = wp.tid()
    sheet, tri, x, n, ng = refine_corner(grid, m, refine_list, q, points, normals, indices)
    if owner_view(views, states, view_count, x) != view_index:
        return
    mt = triangle_material[tri]
    d_in = light_direction(views[view_index], light_kind, light_pos, x)
    trace_corner_cisp(q, sheet, x, n, d_in, int(mat_opacity[mt] < 1.0), mat_ior[mt], views[view_index],
                      rsm_opaque_depth, rsm_depth_bounds, camera, cam_depth, cam_depth_bounds, cam_position,
                      cam_normal, max_steps, thickness, thickness_rel, t_max, use_cascade, rec)


@wp.kernel
def trace_refine_world(
    views: wp.array(dtype=ViewParams),
    states: wp.array(dtype=CascadeState),
    view_count: int,
    view_index: int,
    light_kind: int,
    light_pos: wp.vec3,
    grid: MeshGrid,
    m: int,
    refine_list: wp.array(dtype=wp.int32),
    ws: WorldScene,
    cam: CameraBuffers,
    seed: int,
    roughness_cutoff: float,
    thickness: float,
    thickness_rel: float,
    t_max: float,
    max_bounces: int,
    rec: Records,  # (refined · C(m),) (write)
):
    """One thread per refinement photon, traced by :func:`trace_corner_world` (views only tell which launch)."""
    q = wp.tid()
    sheet, tri, x, n, ng = refine_corner(grid, m, refine_list, q, ws.points, ws.normals, ws.indices)
    if owner_view(views, states, view_count, x) != view_index:
        return
    mt = ws.triangle_material[tri]
    d_in = light_direction(views[view_index], light_kind, light_pos, x)
    trace_corner_world(q, sheet, x, n, ng, d_in, int(ws.opacity[mt] < 1.0), ws.ior[mt], ws, cam, seed,
                       roughness_cutoff, thickness, thickness_rel, t_max, max_bounces, rec)


@wp.kernel
def splat_refined(
    grid: MeshGrid,
    m: int,
    refine_list: wp.array(dtype=wp.int32),  # (refined,) (read)
    refined: int,  # cells cut m × m (the rest of the list, past the refinement's capacity, falls back)
    listed: int,  # cells in the list
    rec: Records,  # the grid's corner photons (read)
    sub_rec: Records,  # (refined · C(m),) the refinement's (read)
    tri_power: wp.array(dtype=wp.vec3),  # (2 sheets · T · n²,) [W] (read)
    sub_power: wp.array(dtype=wp.vec3),  # (refined · m²,) [W] (write)
    cam: CameraBuffers,
    thickness: float,
    thickness_rel: float,
    max_span: int,
    footprint_mode: int,
    photon_map: wp.array(dtype=wp.vec3),  # (H*W,) irradiance [W/m²] (accumulate)
    tri_state: wp.array(dtype=wp.int32),  # (2 sheets · T · n²,) TRI_* (write: cells past the capacity)
    sub_state: wp.array(dtype=wp.int32),  # (refined · m²,) TRI_* (write)
    ledger: wp.array(dtype=wp.float64),  # (3*LEDGER_ENTRIES,) [W] (accumulate, once per block and entry)
):
    """One thread per sub-cell of a refined cell (a cell of the barycentric m × m cut holds 1/m² of its area,
    so of its power: the flux density over a cell is uniform, as the cell's power assumes) splatted over its
    corner photons (:func:`splat_corners`, falling back where they still diverge); then one thread per listed
    cell past the capacity, falling back on its grid corners. Launched tiled."""
    block, lane = wp.tid()
    q = block * wp.block_dim() + lane
    rows = LedgerRows()
    m2 = m * m
    if q < refined * m2:
        r = q / m2
        t = refine_list[r]
        sub_power[q] = tri_power[t] / float(m2)
        ca, cb, cc = sub_cell(m, q - r * m2)
        base = r * ((m + 1) * (m + 2) / 2)
        rows = splat_corners(q, base + corner_slot(m, ca[0], ca[1]), base + corner_slot(m, cb[0], cb[1]),
                             base + corner_slot(m, cc[0], cc[1]), sub_rec, sub_power, cam, thickness, thickness_rel,
                             max_span, footprint_mode, photon_map, sub_state, 0)
    elif q < refined * m2 + listed - refined:
        t = refine_list[refined + q - refined * m2]
        total = grid.count * grid.cells
        sheet = t / total
        c = t - sheet * total
        k = c / grid.cells
        ca, cb, cc = sub_cell(grid.n, c - k * grid.cells)
        base = (sheet * grid.count + k) * grid.corners
        rows = splat_corners(t, base + corner_slot(grid.n, ca[0], ca[1]), base + corner_slot(grid.n, cb[0], cb[1]),
                             base + corner_slot(grid.n, cc[0], cc[1]), rec, tri_power, cam, thickness, thickness_rel,
                             max_span, footprint_mode, photon_map, tri_state, 0)
    ledger_flush(ledger, rows, lane)
