"""Warp kernels of wavefront splatting over the water mesh (``PhotonSettings.wavefront_grid = "mesh"``): the
wavefront's cells laid over the specular mesh's own triangles instead of the RSM's texel lattice.

The RSM grid (:mod:`.kernels_wavefront`) cuts the light's image into square cells; where a cell straddles a
mesh edge (the water's interpolated normals are continuous there but their gradient jumps, so does the caustic's
irradiance), a silhouette or a crease in the light view, its landing triangle is not the affine image it is
taken for. Here every specular triangle of the scene is cut into ``n`` × ``n`` sub-triangles in its own
barycentric coordinates, so a cell never crosses a mesh edge:

* **Grid triangles.** The specular triangles, elongated ones first cut across their length into pieces
  (their corners kept in the scene triangle's barycentric coordinates, ``MeshGrid.bary``): a strip of the
  sinusoid's water, 400 times longer than wide, cut n × n would give cells as long as a tenth of the water.
* **Corners.** Lattice point (i, j), i + j <= n, of grid triangle abc is the surface point
  ``a + (b − a)·i/n + (c − a)·j/n``, exactly on the scene triangle, with the vertex normals interpolated there;
  ``(n + 1)(n + 2)/2`` corners per triangle, traced by :func:`~.kernels_wavefront.trace_corner_cisp` (or
  ``trace_corner_world``) once refracted and once reflected, as the RSM grid's corners are.
* **Cells.** Sub-triangle s of row j (``2(n − j) − 1`` per row: upright (i, j) (i+1, j) (i, j+1), inverted
  (i+1, j) (i+1, j+1) (i, j+1)), ``n²`` per triangle. Its power is the flux through its area on the
  surface: ``E⊥ · |cos θ| · area`` for a distant light (E⊥ the irradiance across the beam), ``I · Ω`` for a
  point or spot light (Ω the triangle's exact solid angle, times the spot profile at its centroid), times the
  share of its corners the light reaches (the light view's nearest depth as a shadow map), split by the exact
  Fresnel factor at its centroid's interpolated normal into the refracted and reflected sheets.
* **Views.** A point belongs to the light view it projects into, outside the window a finer cascade takes (the
  skip window; :func:`owner_view`). Each corner is traced in its own view (CISP marches in that view's
  depth), each cell is booked by its centroid's view, once every corner of the light is traced the cells are
  splatted. A cell with a corner outside every view is not sampled: it is left to ``outside_fitted_view``
  (booked by the pass from the pilot's texels), as the RSM grid leaves the texels outside the windows.
* **Splat**: :func:`~.kernels_splat.splat_corners`, shared with the RSM grid; cells whose corners diverge are
  refined (:mod:`.kernels_meshrefine`).

Every watt a cell samples ends in exactly one ledger entry. The luminance cutoff is not applied (the cells are
few and every one is traced); the roughness cutoff is.
"""

from __future__ import annotations

import warp as wp

from ..optics import fresnel_dielectric
from ..raster.kernels import spot_falloff
from ..raster.light_maps import CascadeState
from ..raster.views import ViewParams, pixel_ray_world, world_project
from .common import L_ABSORBED, L_CULLED_ROUGH, L_REFLECTED, L_REFRACTED, L_SAMPLED
from .kernels_splat import splat_corners
from .kernels_wavefront import (SHEET_REFLECTED, SHEET_REFRACTED, LedgerRows, Records, clear_record, ledger_flush,
                                rows_add, trace_corner_cisp, trace_corner_world)
from .kernels_world import CameraBuffers, WorldScene

wp.set_module_options({"enable_backward": False})


@wp.struct
class MeshGrid:
    """The photon grid over the scene's specular triangles."""

    tris: wp.array(dtype=wp.int32)  #: (T,) scene triangle of each grid triangle (the specular layer) (read)
    #: (3T,) the grid triangle's corners in its scene triangle's barycentric coordinates (weights of vertices 1, 2):
    #: the scene triangle itself, or a piece of an elongated one (``meshgrid.grid_triangles``) (read)
    bary: wp.array(dtype=wp.vec2)
    count: int  #: T
    n: int  #: sub-triangles per triangle edge
    cells: int  #: n² sub-triangles (cells) per triangle
    corners: int  #: (n + 1)(n + 2) / 2 lattice corners per triangle


@wp.func
def corner_slot(n: int, i: int, j: int) -> int:
    """Lattice corner (i, j), i + j <= n, in a triangle's corner list (row j holds n + 1 − j corners)."""
    return j * (n + 1) - j * (j - 1) / 2 + i


@wp.func
def corner_lattice(n: int, q: int):
    """Inverse of :func:`corner_slot`: (i, j) of a triangle's corner ``q``."""
    i = int(q)
    j = int(0)
    while i >= n + 1 - j:
        i -= n + 1 - j
        j += 1
    return i, j


@wp.func
def sub_cell(n: int, s: int):
    """Sub-triangle ``s`` of a triangle cut n × n: its three lattice corners (i, j) each, in the winding of
    the triangle. Row j holds 2(n − j) − 1 sub-triangles (rows before it j(2n − j)); even places along a row
    are upright, odd ones inverted."""
    j = int(float(n) - wp.sqrt(float(n * n - s)))
    while j > 0 and j * (2 * n - j) > s:
        j -= 1
    while (j + 1) * (2 * n - j - 1) <= s:
        j += 1
    u = s - j * (2 * n - j)
    i = u / 2
    if u % 2 == 0:
        return wp.vec2i(i, j), wp.vec2i(i + 1, j), wp.vec2i(i, j + 1)
    return wp.vec2i(i + 1, j), wp.vec2i(i + 1, j + 1), wp.vec2i(i, j + 1)


@wp.func
def lattice_point(grid: MeshGrid, points: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3),
                  indices: wp.array(dtype=wp.int32), k: int, ij: wp.vec2i):
    """Lattice corner ``ij`` of grid triangle ``k``: (point [m], its interpolated vertex normal, not normalised)."""
    return lattice_point_uv(grid, points, normals, indices, k, float(ij[0]), float(ij[1]))


@wp.func
def lattice_point_uv(grid: MeshGrid, points: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3),
                     indices: wp.array(dtype=wp.int32), k: int, u: float, v: float):
    """Point (u, v) of grid triangle ``k``'s lattice (continuous: 0 <= u, v, u + v <= n), on its scene triangle
    (through the grid triangle's corners in the scene triangle's barycentric coordinates): (point [m], the
    vertex normals interpolated there, not normalised)."""
    tri = grid.tris[k]
    b0 = grid.bary[3 * k]
    bary = b0 + (grid.bary[3 * k + 1] - b0) * (u / float(grid.n)) + (grid.bary[3 * k + 2] - b0) * (v / float(grid.n))
    wb = bary[0]
    wc = bary[1]
    wa = 1.0 - wb - wc
    va = indices[3 * tri]
    vb = indices[3 * tri + 1]
    vc = indices[3 * tri + 2]
    x = points[va] * wa + points[vb] * wb + points[vc] * wc
    nrm = normals[va] * wa + normals[vb] * wb + normals[vc] * wc
    return x, nrm


@wp.func
def in_view(light: ViewParams, skip_window: wp.vec4, x: wp.vec3) -> int:
    """1 when point ``x`` belongs to this light view: an active view, ``x`` in front of it, inside its image and
    outside the window a finer cascade covers (x0, y0, x1, y1; empty when x1 <= x0)."""
    if light.far <= 0.0:
        return 0
    q = world_project(light, x)
    if q[2] <= 0.0 or q[0] < 0.0 or q[1] < 0.0 or q[0] >= float(light.width) or q[1] >= float(light.height):
        return 0
    if q[0] >= skip_window[0] and q[0] < skip_window[2] and q[1] >= skip_window[1] and q[1] < skip_window[3]:
        return 0
    return 1


@wp.func
def owner_view(views: wp.array(dtype=ViewParams), states: wp.array(dtype=CascadeState), view_count: int,
               x: wp.vec3) -> int:
    """The light view point ``x`` belongs to (:func:`in_view` with its skip window: one of nested cascades, one
    of a point light's cube faces), or -1 outside every active view."""
    for v in range(view_count):
        if states[v].active != 0 and in_view(views[v], states[v].skip_window, x) != 0:
            return v
    return -1


@wp.func
def light_reaches(light: ViewParams, shadow_depth: wp.array(dtype=wp.float32), x: wp.vec3, thickness: float,
                  thickness_rel: float) -> float:
    """1 when the light view's nearest surface (``shadow_depth``, 0 = none) at ``x``'s texel is not in front of
    ``x`` by more than the thickness, else 0."""
    q = world_project(light, x)
    ix = wp.clamp(int(q[0]), 0, light.width - 1)
    iy = wp.clamp(int(q[1]), 0, light.height - 1)
    z = shadow_depth[iy * light.width + ix]
    if z > 0.0 and z < q[2] - (thickness + thickness_rel * q[2]):
        return 0.0
    return 1.0


@wp.func
def light_direction(light: ViewParams, light_kind: int, light_pos: wp.vec3, x: wp.vec3) -> wp.vec3:
    """Unit direction the light travels at ``x``: the view's axis (distant), from the light's position (else)."""
    if light_kind != 0:
        return wp.normalize(x - light_pos)
    lo, ld = pixel_ray_world(light, light.cx, light.cy)
    return wp.normalize(ld)


@wp.func
def triangle_solid_angle(a: wp.vec3, b: wp.vec3, c: wp.vec3) -> float:
    """Solid angle [sr] of triangle abc (relative to the origin), Van Oosterom & Strackee (1983)."""
    la = wp.length(a)
    lb = wp.length(b)
    lc = wp.length(c)
    num = wp.abs(wp.dot(a, wp.cross(b, c)))
    den = la * lb * lc + wp.dot(a, b) * lc + wp.dot(a, c) * lb + wp.dot(b, c) * la
    return 2.0 * wp.atan2(num, den)


@wp.func
def cell_flux(light: ViewParams, light_kind: int, light_pos: wp.vec3, light_rgb: wp.vec3, spot_axis: wp.vec3,
              cone_angle: float, cone_softness: float, xa: wp.vec3, xb: wp.vec3, xc: wp.vec3) -> wp.vec3:
    """Flux [W] the light sends through triangle (xa, xb, xc) (shadows aside)."""
    g = (xa + xb + xc) / 3.0
    d_in = light_direction(light, light_kind, light_pos, g)
    if light_kind == 0:
        area = 0.5 * wp.cross(xb - xa, xc - xa)
        return light_rgb * wp.abs(wp.dot(d_in, area))
    f = triangle_solid_angle(xa - light_pos, xb - light_pos, xc - light_pos)
    if light_kind == 2:
        f = f * spot_falloff(wp.dot(d_in, spot_axis), cone_angle, cone_softness)
    return light_rgb * f


@wp.kernel
def mesh_cells(
    views: wp.array(dtype=ViewParams),  # (V,) the light's views (read)
    states: wp.array(dtype=CascadeState),  # (V,) their states: active, skip window (read)
    view_count: int,
    view_index: int,  # the view whose cells this launch books
    light_kind: int,  # 0 distant, 1 point, 2 spot
    light_pos: wp.vec3,  # [m]
    light_rgb: wp.vec3,  # irradiance across the beam [W/m²] (distant) or intensity [W/sr] (point, spot)
    spot_axis: wp.vec3,  # unit, the spot's axis (spot only)
    cone_angle: float,  # [rad] spot half-angle
    cone_softness: float,
    grid: MeshGrid,
    shadow_depth: wp.array(dtype=wp.float32),  # (H_l*W_l,) the view's nearest depth of any surface [m], 0 none (read)
    points: wp.array(dtype=wp.vec3),  # (V,) [m] (read)
    normals: wp.array(dtype=wp.vec3),  # (V,) unit vertex normals (read)
    indices: wp.array(dtype=wp.int32),  # (3T,) (read)
    triangle_material: wp.array(dtype=wp.int32),
    mat_roughness: wp.array(dtype=wp.float32),
    mat_opacity: wp.array(dtype=wp.float32),
    mat_albedo: wp.array(dtype=wp.vec3),
    mat_ior: wp.array(dtype=wp.float32),
    roughness_cutoff: float,
    thickness: float,  # [m] the shadow test's tolerance, absolute
    thickness_rel: float,  # and relative (× depth)
    tri_power: wp.array(dtype=wp.vec3),  # (2 sheets · T · n²,) [W] (write: this view's cells; zeroed per light)
    ledger: wp.array(dtype=wp.float64),  # (3*LEDGER_ENTRIES,) [W] (accumulate, once per block and entry)
):
    """One thread per cell (grid triangle k, sub-triangle s), launched tiled: a cell of this view (its centroid
    here, each corner in some view, so traced) gets its flux, split into the two sheets; the block's ledger rows
    added once."""
    light = views[view_index]
    skip_window = states[view_index].skip_window
    block, lane = wp.tid()
    c = block * wp.block_dim() + lane
    rows = LedgerRows()
    total = grid.count * grid.cells
    if c < total:
        k = c / grid.cells
        s = c - k * grid.cells
        tri = grid.tris[k]
        zero = wp.vec3(0.0)
        refr = zero
        refl = zero
        ca, cb, cc = sub_cell(grid.n, s)
        xa, na = lattice_point(grid, points, normals, indices, k, ca)
        xb, nb = lattice_point(grid, points, normals, indices, k, cb)
        xc, nc = lattice_point(grid, points, normals, indices, k, cc)
        mine = in_view(light, skip_window, (xa + xb + xc) / 3.0)
        if mine != 0:
            for q in range(3):
                xq = xa
                if q == 1:
                    xq = xb
                elif q == 2:
                    xq = xc
                if owner_view(views, states, view_count, xq) < 0:
                    mine = 0  # a corner outside every view: no trace, the cell is left to outside_fitted_view
        if mine != 0:
            lit = (light_reaches(light, shadow_depth, xa, thickness, thickness_rel)
                   + light_reaches(light, shadow_depth, xb, thickness, thickness_rel)
                   + light_reaches(light, shadow_depth, xc, thickness, thickness_rel)) / 3.0
            flux = cell_flux(light, light_kind, light_pos, light_rgb, spot_axis, cone_angle, cone_softness, xa, xb,
                             xc) * lit
            rows = rows_add(rows, L_SAMPLED, flux)
            m = triangle_material[tri]
            if mat_roughness[m] > roughness_cutoff:
                rows = rows_add(rows, L_CULLED_ROUGH, flux)
            elif mat_opacity[m] < 1.0:
                g = (xa + xb + xc) / 3.0
                d_in = light_direction(light, light_kind, light_pos, g)
                nn = wp.normalize(na + nb + nc)  # the interpolated normal at the centroid
                eta = mat_ior[m]
                if wp.dot(d_in, nn) > 0.0:
                    nn = -nn
                    eta = 1.0 / eta
                refl = flux * fresnel_dielectric(-wp.dot(d_in, nn), eta)
                refr = flux - refl
            else:
                refl = wp.cw_mul(flux, mat_albedo[m])
                rows = rows_add(rows, L_ABSORBED, flux - refl)
            rows = rows_add(rows, L_REFRACTED, refr)
            rows = rows_add(rows, L_REFLECTED, refl)
            tri_power[SHEET_REFRACTED * total + c] = refr
            tri_power[SHEET_REFLECTED * total + c] = refl
    ledger_flush(ledger, rows, lane)


@wp.func
def mesh_corner(grid: MeshGrid, p: int):
    """Photon ``p``'s sheet, grid triangle and lattice corner (records: sheet-major, then triangle, corner)."""
    per_sheet = grid.count * grid.corners
    sheet = p / per_sheet
    r = p - sheet * per_sheet
    k = r / grid.corners
    i, j = corner_lattice(grid.n, r - k * grid.corners)
    return sheet, k, wp.vec2i(i, j)


@wp.func
def corner_normals(tri: int, nrm: wp.vec3, points: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32)):
    """(unit normal, geometric normal on its side) of a corner on scene triangle ``tri`` with interpolated normal
    ``nrm`` (the geometric one where ``nrm`` vanishes)."""
    a = points[indices[3 * tri]]
    ng = wp.normalize(wp.cross(points[indices[3 * tri + 1]] - a, points[indices[3 * tri + 2]] - a))
    n = ng
    if wp.length_sq(nrm) > 1.0e-20:
        n = wp.normalize(nrm)
    if wp.dot(n, ng) < 0.0:
        ng = -ng
    return n, ng


@wp.func
def corner_start(grid: MeshGrid, k: int, ij: wp.vec2i, points: wp.array(dtype=wp.vec3),
                 normals: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32)):
    """Corner ``ij`` of grid triangle ``k``: (scene triangle, point [m], unit normal, geometric normal on the
    normal's side)."""
    tri = grid.tris[k]
    x, nrm = lattice_point(grid, points, normals, indices, k, ij)
    n, ng = corner_normals(tri, nrm, points, indices)
    return tri, x, n, ng


@wp.kernel
def trace_mesh_cisp(
    views: wp.array(dtype=ViewParams),  # (V,) the light's views (read)
    states: wp.array(dtype=CascadeState),  # (V,) their states (read)
    view_count: int,
    view_index: int,  # this launch traces the corners of this view
    light_kind: int,
    light_pos: wp.vec3,
    grid: MeshGrid,
    rsm_opaque_depth: wp.array(dtype=wp.float32),  # (H_l*W_l,) [m] (read)
    rsm_depth_bounds: wp.array(dtype=wp.vec2),  # its march.depth_bounds (read)
    points: wp.array(dtype=wp.vec3),  # (V,) scene vertices [m] (read)
    normals: wp.array(dtype=wp.vec3),  # (V,) unit vertex normals (read)
    indices: wp.array(dtype=wp.int32),  # (3T,) (read)
    triangle_material: wp.array(dtype=wp.int32),
    mat_roughness: wp.array(dtype=wp.float32),
    mat_opacity: wp.array(dtype=wp.float32),
    mat_ior: wp.array(dtype=wp.float32),
    roughness_cutoff: float,
    camera: ViewParams,
    cam_depth: wp.array(dtype=wp.float32),  # (H*W,) [m] (read)
    cam_depth_bounds: wp.array(dtype=wp.vec2),  # march.depth_bounds of cam_depth (read)
    cam_position: wp.array(dtype=wp.vec3),  # (H*W,) [m] (read)
    cam_normal: wp.array(dtype=wp.vec3),  # (H*W,) unit (read)
    max_steps: int,
    thickness: float,
    thickness_rel: float,
    t_max: float,
    use_cascade: int,
    rec: Records,  # (2 · T · corners,) (write)
):
    """One thread per corner photon of the grid: a corner of this view (:func:`owner_view`) from its exact surface
    point, by :func:`trace_corner_cisp` in this light view."""
    p = wp.tid()
    sheet, k, ij = mesh_corner(grid, p)
    tri, x, n, ng = corner_start(grid, k, ij, points, normals, indices)
    m = triangle_material[tri]
    if mat_roughness[m] > roughness_cutoff or owner_view(views, states, view_count, x) != view_index:
        return  # another view's corner (or none's: its record stays cleared)
    light = views[view_index]
    d_in = light_direction(light, light_kind, light_pos, x)
    trace_corner_cisp(p, sheet, x, n, d_in, int(mat_opacity[m] < 1.0), mat_ior[m], light, rsm_opaque_depth,
                      rsm_depth_bounds, camera, cam_depth, cam_depth_bounds, cam_position, cam_normal, max_steps,
                      thickness, thickness_rel, t_max, use_cascade, rec)


@wp.kernel
def trace_mesh_world(
    views: wp.array(dtype=ViewParams),  # (V,) the light's views (read)
    states: wp.array(dtype=CascadeState),  # (V,) their states (read)
    view_count: int,
    view_index: int,  # this launch traces the corners of this view
    light_kind: int,
    light_pos: wp.vec3,
    grid: MeshGrid,
    ws: WorldScene,
    cam: CameraBuffers,
    seed: int,  # random streams of later Fresnel bounces (after the first, deterministic one)
    roughness_cutoff: float,
    thickness: float,
    thickness_rel: float,
    t_max: float,
    max_bounces: int,
    rec: Records,  # (2 · T · corners,) (write)
):
    """One thread per corner photon of the grid: a corner of this view (:func:`owner_view`) from its exact surface
    point, by :func:`trace_corner_world`."""
    p = wp.tid()
    sheet, k, ij = mesh_corner(grid, p)
    tri, x, n, ng = corner_start(grid, k, ij, ws.points, ws.normals, ws.indices)
    m = ws.triangle_material[tri]
    if ws.roughness[m] > roughness_cutoff or owner_view(views, states, view_count, x) != view_index:
        return  # another view's corner (or none's: its record stays cleared)
    light = views[view_index]
    d_in = light_direction(light, light_kind, light_pos, x)
    trace_corner_world(p, sheet, x, n, ng, d_in, int(ws.opacity[m] < 1.0), ws.ior[m], ws, cam, seed,
                       roughness_cutoff, thickness, thickness_rel, t_max, max_bounces, rec)


@wp.kernel
def clear_records(rec: Records):
    """Every corner photon's record: none yet (a light's corners are traced view by view)."""
    clear_record(rec, wp.tid())


@wp.kernel
def splat_mesh(
    grid: MeshGrid,
    rec: Records,  # (2 · T · corners,) (read)
    tri_power: wp.array(dtype=wp.vec3),  # (2 sheets · T · n²,) [W] (read)
    cam: CameraBuffers,
    thickness: float,  # [m] receiver tolerance, absolute
    thickness_rel: float,  # relative (× depth)
    max_span: int,  # [pixels] a landing triangle wider or taller than this falls back
    footprint_mode: int,
    photon_map: wp.array(dtype=wp.vec3),  # (H*W,) irradiance [W/m²] (accumulate)
    tri_state: wp.array(dtype=wp.int32),  # (2 sheets · T · n²,) TRI_* (write)
    refine: int,  # 1: cells that would fall back with a corner on a camera surface are left to refinement
    ledger: wp.array(dtype=wp.float64),  # (3*LEDGER_ENTRIES,) [W] (accumulate, once per block and entry)
):
    """One thread per cell and sheet: its corner photons, then :func:`splat_corners`, launched tiled."""
    block, lane = wp.tid()
    t = block * wp.block_dim() + lane
    rows = LedgerRows()
    total = grid.count * grid.cells
    if t < 2 * total:
        sheet = t / total
        c = t - sheet * total
        k = c / grid.cells
        ca, cb, cc = sub_cell(grid.n, c - k * grid.cells)
        base = (sheet * grid.count + k) * grid.corners
        rows = splat_corners(t, base + corner_slot(grid.n, ca[0], ca[1]), base + corner_slot(grid.n, cb[0], cb[1]),
                             base + corner_slot(grid.n, cc[0], cc[1]), rec, tri_power, cam, thickness, thickness_rel,
                             max_span, footprint_mode, photon_map, tri_state, refine)
    ledger_flush(ledger, rows, lane)

