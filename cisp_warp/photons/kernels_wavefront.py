"""Warp kernels of wavefront splatting, the grid: photons on a regular grid of the RSM, traced by CISP's
cascade (or SSPM's world-space tracer), and each grid cell's power, split into triangles and sheets.

A water caustic is a smooth map of the surface onto the receivers: light leaving a small patch of the
water arrives on a patch of the floor, and the irradiance there is the patch's power over the area it
lands on (Ernst, Akenine-Möller & Jensen 2005; WebGL Water). Here:

* **Grid.** The RSM view is cut into cells of ``cell`` × ``cell`` texels; a photon starts at every cell
  corner (a texel corner), where the light's ray through it meets the specular surface, with the surface's
  interpolated vertex normal: CISP finds it from the triangles of the four texels around the corner (or
  interpolates their texels), SSPM by its BVH. A texel's one normal would put a lattice into the
  caustic, texel centres would shift it by half a texel.
* **Sheets.** Fresnel is not a coin flip here (that would break neighbour coherence): every corner is
  traced twice, refracted and reflected, and each texel's flux splits deterministically into
  ``flux·(1 − F)`` (refracted sheet) and ``flux·F`` (reflected sheet), F of the texel's own incidence.
* **Triangles.** Each cell is split along its diagonal into two triangles; a triangle's power is the flux of
  its texels (diagonal texels half to each). The map from the light's image plane to the receiver is
  affine over a triangle, so its power spreads uniformly over the landing triangle. A triangle that turns
  over (a fold) is simply another sheet: its power spreads over its own area and the sheets add up.
* **Splat** (:mod:`.kernels_splat`): each triangle's power spread over the triangle its corners land on, or
  point deposits at its corners where they diverge.

Every watt of the grid's texels ends in exactly one ledger entry, as with point photons.
"""

from __future__ import annotations

import warp as wp

from ..denoise.kernels_svgf import luminance
from ..optics import fresnel_dielectric, reflect, refract
from ..raster.kernels import TexelEmission, texel_emitted_flux, texel_ior, texel_roughness
from ..raster.views import ViewParams, pixel_ray_world
from .common import (L_ABSORBED, L_CULLED_LUM, L_CULLED_ROUGH, L_REFLECTED, L_REFRACTED, L_SAMPLED, L_STORED,
                     LEDGER_ENTRIES, tally_new)
from .kernels_cisp import camera_marches, march_light, refine_landing, reproject_to_camera
from .kernels_world import (WT_LANDED, CameraBuffers, WorldScene, camera_receiver, is_smooth_specular, world_hit,
                            world_trace)

wp.set_module_options({"enable_backward": False})

SHEET_REFRACTED = wp.constant(0)
SHEET_REFLECTED = wp.constant(1)
NO_PHOTON = wp.constant(-1)  #: record entry of a corner with no specular surface around it


LedgerRows = wp.types.matrix(shape=(LEDGER_ENTRIES, 3), dtype=wp.float64)  #: one thread's share of the ledger [W]


@wp.func
def rows_add(rows: LedgerRows, entry: int, power: wp.vec3) -> LedgerRows:
    """``rows`` with ``power`` [W] added under ``entry`` (registers; the ledger is written by ledger_flush)."""
    out = rows
    for c in range(3):
        out[entry, c] = out[entry, c] + wp.float64(power[c])
    return out


@wp.func
def ledger_flush(ledger: wp.array(dtype=wp.float64), rows: LedgerRows, lane: int):
    """Sum every thread's rows over the block (Warp tiles) and add each non-zero entry to the ledger once,
    from lane 0. Every thread of the block must call it (no early return before it)."""
    for e in range(LEDGER_ENTRIES):
        v = wp.vec3d(rows[e, 0], rows[e, 1], rows[e, 2])
        total = wp.tile_sum(wp.tile(v, preserve_type=True))
        if lane == 0:
            s = total[0]
            if s[0] != wp.float64(0.0) or s[1] != wp.float64(0.0) or s[2] != wp.float64(0.0):
                wp.atomic_add(ledger, 3 * e + 0, s[0])
                wp.atomic_add(ledger, 3 * e + 1, s[1])
                wp.atomic_add(ledger, 3 * e + 2, s[2])


@wp.struct
class Grid:
    """The photon grid over one RSM view."""

    width: int  #: RSM texels
    height: int
    cell: int  #: texels per cell edge
    cells_x: int  #: ceil(width / cell)
    cells_y: int  #: ceil(height / cell)


@wp.struct
class Records:
    """Where each grid photon ended, (2 · corners,) per array: sheet-major, then corner (row-major)."""

    entry: wp.array(dtype=wp.int32)  #: ledger entry it ended in; L_STORED = on a camera surface; NO_PHOTON
    pos: wp.array(dtype=wp.vec3)  #: end point [m]
    pix: wp.array(dtype=wp.int32)  #: camera pixel of the end point (-1 none)
    dir: wp.array(dtype=wp.vec3)  #: arrival direction (unit)
    throughput: wp.array(dtype=wp.vec3)  #: power kept along the way (metal albedo after the first bounce)


@wp.func
def grid_corners(grid: Grid) -> int:
    return (grid.cells_x + 1) * (grid.cells_y + 1)


@wp.func
def texel_outside(i: int, j: int, window: wp.vec4) -> float:
    """The share of texel (i, j)'s area outside ``window`` (x0, y0, x1, y1) [pixels]: the rest belongs to a finer
    cascade, which samples the window exactly (as point photons leave samples inside it to that cascade)."""
    ox = wp.max(wp.min(float(i + 1), window[2]) - wp.max(float(i), window[0]), 0.0)
    oy = wp.max(wp.min(float(j + 1), window[3]) - wp.max(float(j), window[1]), 0.0)
    return 1.0 - ox * oy


@wp.func
def grid_cell(
    c: int,  # cell
    light: ViewParams,
    light_kind: int,  # 0 distant, 1 point, 2 spot
    light_pos: wp.vec3,  # [m]
    grid: Grid,
    rsm_position: wp.array(dtype=wp.vec3),  # (H*W,) specular layer [m] (read)
    rsm_normal: wp.array(dtype=wp.vec3),  # (H*W,) authored unit normal (read)
    rsm_emission: TexelEmission,  # its specular texels' flux, roughness and IOR from the light and materials (read)
    rsm_tri: wp.array(dtype=wp.int32),  # -1 = no specular surface
    triangle_material: wp.array(dtype=wp.int32),
    mat_opacity: wp.array(dtype=wp.float32),
    mat_albedo: wp.array(dtype=wp.vec3),
    max_lum: wp.array(dtype=wp.float32),  # (1,) brightest texel luminance of this light [W]
    roughness_cutoff: float,
    luminance_cutoff: float,
    skip_window: wp.vec4,
    tri_power: wp.array(dtype=wp.vec3),  # (2 sheets · cells · 2 triangles,) [W] (write)
):
    """Cell ``c``: its texels' flux, culled as point photons are, split by exact Fresnel into the refracted
    and reflected sheets and by the cell's diagonal into its two triangles. Returns its ledger rows."""
    cells = grid.cells_x * grid.cells_y
    cx = c % grid.cells_x
    cy = c // grid.cells_x
    x0 = cx * grid.cell
    y0 = cy * grid.cell
    x1 = wp.min(x0 + grid.cell, grid.width)
    y1 = wp.min(y0 + grid.cell, grid.height)
    zero = wp.vec3(0.0)
    sampled = zero
    rough = zero
    dim = zero
    absorbed = zero
    refr0 = zero  # refracted sheet, triangle 0 (u >= v) and 1 (v >= u)
    refr1 = zero
    refl0 = zero
    refl1 = zero
    for j in range(y0, y1):
        for i in range(x0, x1):
            t = j * grid.width + i
            tri = rsm_tri[t]
            if tri < 0:
                continue
            keep = texel_outside(i, j, skip_window)
            if keep <= 0.0:
                continue  # a finer cascade's texels
            flux = texel_emitted_flux(rsm_emission, light, t)
            dimmed = luminance(flux) < luminance_cutoff * max_lum[0]  # the texel's whole flux, as points test it
            flux = flux * keep
            sampled += flux
            if texel_roughness(rsm_emission, tri) > roughness_cutoff:
                rough += flux
                continue
            if dimmed:
                dim += flux
                continue
            lo, ld = pixel_ray_world(light, float(i) + 0.5, float(j) + 0.5)
            d_in = wp.normalize(ld)
            if light_kind != 0:
                d_in = wp.normalize(rsm_position[t] - light_pos)
            n = rsm_normal[t]
            m = triangle_material[tri]
            refl = zero
            refr = zero
            if mat_opacity[m] < 1.0:
                nn = n
                eta = texel_ior(rsm_emission, tri)
                if wp.dot(d_in, n) > 0.0:
                    nn = -n
                    eta = 1.0 / eta
                f = fresnel_dielectric(-wp.dot(d_in, nn), eta)
                refl = flux * f
                refr = flux - refl
            else:
                refl = wp.cw_mul(flux, mat_albedo[m])
                absorbed += flux - refl
            # which triangle of the cell: texel centre (u, v) in cell units above or below the diagonal u = v (on
            # it: half each); compared in integers, (2(i - x0) + 1) / (2 (x1 - x0)) against the same in j: exact
            # on every device (float division under CUDA's fast math tipped diagonal texels either way)
            su = (2 * (i - x0) + 1) * (y1 - y0)
            sv = (2 * (j - y0) + 1) * (x1 - x0)
            w0 = float(0.5)
            if su > sv:
                w0 = 1.0
            elif su < sv:
                w0 = 0.0
            refr0 += refr * w0
            refr1 += refr * (1.0 - w0)
            refl0 += refl * w0
            refl1 += refl * (1.0 - w0)
    tri_power[(SHEET_REFRACTED * cells + c) * 2 + 0] = refr0
    tri_power[(SHEET_REFRACTED * cells + c) * 2 + 1] = refr1
    tri_power[(SHEET_REFLECTED * cells + c) * 2 + 0] = refl0
    tri_power[(SHEET_REFLECTED * cells + c) * 2 + 1] = refl1
    rows = LedgerRows()
    rows = rows_add(rows, L_SAMPLED, sampled)
    rows = rows_add(rows, L_CULLED_ROUGH, rough)
    rows = rows_add(rows, L_CULLED_LUM, dim)
    rows = rows_add(rows, L_ABSORBED, absorbed)
    rows = rows_add(rows, L_REFRACTED, refr0 + refr1)
    rows = rows_add(rows, L_REFLECTED, refl0 + refl1)
    return rows


@wp.kernel
def grid_cells(
    light: ViewParams,
    light_kind: int,  # 0 distant, 1 point, 2 spot
    light_pos: wp.vec3,  # [m]
    grid: Grid,
    rsm_position: wp.array(dtype=wp.vec3),  # (H*W,) specular layer [m] (read)
    rsm_normal: wp.array(dtype=wp.vec3),  # (H*W,) authored unit normal (read)
    rsm_emission: TexelEmission,  # its specular texels' flux, roughness and IOR from the light and materials (read)
    rsm_tri: wp.array(dtype=wp.int32),  # -1 = no specular surface
    triangle_material: wp.array(dtype=wp.int32),
    mat_opacity: wp.array(dtype=wp.float32),
    mat_albedo: wp.array(dtype=wp.vec3),
    max_lum: wp.array(dtype=wp.float32),  # (1,) brightest texel luminance of this light [W]
    roughness_cutoff: float,
    luminance_cutoff: float,  # against max_lum, scaled to this view's texels (RSMBatch.luminance_cutoff)
    skip_window: wp.vec4,  # (x0, y0, x1, y1) this view's pixels a finer cascade covers; empty when x1 <= x0
    tri_power: wp.array(dtype=wp.vec3),  # (2 sheets · cells · 2 triangles,) [W] (write)
    ledger: wp.array(dtype=wp.float64),  # (3*LEDGER_ENTRIES,) [W] (accumulate, once per block and entry)
):
    """One thread per cell (:func:`grid_cell`), launched tiled: the block's ledger rows added once."""
    block, lane = wp.tid()
    c = block * wp.block_dim() + lane
    rows = LedgerRows()
    if c < grid.cells_x * grid.cells_y:
        rows = grid_cell(c, light, light_kind, light_pos, grid, rsm_position, rsm_normal, rsm_emission, rsm_tri,
                         triangle_material, mat_opacity, mat_albedo, max_lum, roughness_cutoff, luminance_cutoff,
                         skip_window, tri_power)
    ledger_flush(ledger, rows, lane)


@wp.func
def corner_on_triangle(points: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3),
                       indices: wp.array(dtype=wp.int32), tri: int, lo: wp.vec3, ld: wp.vec3):
    """The ray ``lo + ld·t`` cut with triangle ``tri``'s plane. Returns (smallest barycentric coordinate,
    negative outside the triangle; point [m]; vertex normal interpolated at the nearest point of the
    triangle; geometric normal on its side)."""
    a = points[indices[3 * tri]]
    b = points[indices[3 * tri + 1]]
    c = points[indices[3 * tri + 2]]
    ng = wp.cross(b - a, c - a)
    area2 = wp.length(ng)
    denom = wp.dot(ld, ng)
    if area2 < 1.0e-20 or wp.abs(denom) < 1.0e-12 * area2 * wp.length(ld):
        return float(-1.0e30), a, ng, ng
    x = lo + ld * (wp.dot(a - lo, ng) / denom)
    ng = ng / area2
    w1 = wp.dot(wp.cross(c - a, x - a), -ng) / area2  # barycentric of b (sign from the orientation)
    w2 = wp.dot(wp.cross(b - a, x - a), ng) / area2  # barycentric of c
    w0 = 1.0 - w1 - w2
    # normal at the nearest point of the triangle (the point itself when inside; a neighbour's plane outside)
    v0 = wp.max(w0, 0.0)
    v1 = wp.max(w1, 0.0)
    v2 = wp.max(w2, 0.0)
    vs = v0 + v1 + v2
    n = (normals[indices[3 * tri]] * v0 + normals[indices[3 * tri + 1]] * v1 + normals[indices[3 * tri + 2]] * v2) / vs
    if wp.length_sq(n) < 1.0e-20:
        n = ng
    n = wp.normalize(n)
    if wp.dot(n, ng) < 0.0:
        ng = -ng
    return wp.min(w0, wp.min(w1, w2)), x, n, ng


@wp.func
def grid_corner(grid: Grid, p: int):
    """Photon ``p``'s sheet and its cell corner in the light view's continuous pixel coordinates."""
    q = grid_corners(grid)
    sheet = p / q
    corner = p - sheet * q
    i = corner % (grid.cells_x + 1)
    j = corner / (grid.cells_x + 1)
    return sheet, wp.min(i * grid.cell, grid.width), wp.min(j * grid.cell, grid.height)


@wp.func
def corner_surface_rsm(
    sx: int,
    sy: int,
    lo: wp.vec3,  # the light's ray through the corner: origin [m]
    ld: wp.vec3,  # and direction
    grid: Grid,
    rsm_position: wp.array(dtype=wp.vec3),
    rsm_normal: wp.array(dtype=wp.vec3),
    rsm_tri: wp.array(dtype=wp.int32),
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    indices: wp.array(dtype=wp.int32),
):
    """The specular surface at a cell corner, from the four RSM texels around it (CISP: no BVH). Where the
    light's ray meets the triangle of one of them, that point and the triangle's interpolated vertex normal;
    where it meets none of their triangles (triangles smaller than texels), the texels' surface interpolated
    bilinearly at the corner (their mean position and normal). Returns (texel or -1, point [m], normal,
    geometric normal on the normal's side)."""
    zero = wp.vec3(0.0)
    pos = zero
    nrm = zero
    count = int(0)
    texel = int(-1)
    for dj in range(2):
        for di in range(2):
            ti = sx - 1 + di
            tj = sy - 1 + dj
            if ti >= 0 and tj >= 0 and ti < grid.width and tj < grid.height:
                t = tj * grid.width + ti
                tri = rsm_tri[t]
                if tri >= 0:
                    inside, x, nt, gt = corner_on_triangle(points, normals, indices, tri, lo, ld)
                    if inside >= -1.0e-5:
                        return t, x, nt, gt
                    pos += rsm_position[t]
                    nrm += rsm_normal[t]
                    count += 1
                    if texel < 0:
                        texel = t
    if count == 0 or wp.length_sq(nrm) < 1.0e-12:
        return int(-1), zero, zero, zero
    x0 = pos / float(count)
    n = wp.normalize(nrm)
    origin = x0
    denom = wp.dot(ld, n)
    if wp.abs(denom) > 1.0e-8:
        origin = lo + ld * (wp.dot(x0 - lo, n) / denom)
    return texel, origin, n, n


@wp.func
def grid_bounce(sheet: int, d_in: wp.vec3, n: wp.vec3, transmissive: int, ior: float):
    """The direction of a corner's photon in its sheet. Returns (1, direction), or (0, ·) when the sheet
    carries nothing here (a metal's refracted sheet; total internal reflection, where F = 1)."""
    nn = n
    eta = ior
    if wp.dot(d_in, n) > 0.0:
        nn = -n
        eta = 1.0 / eta
    if sheet == SHEET_REFLECTED:
        return int(1), reflect(d_in, nn)
    if transmissive == 0:
        return int(0), wp.vec3(0.0)
    d = refract(d_in, nn, eta)
    if wp.length_sq(d) == 0.0:
        return int(0), d
    return int(1), d


@wp.func
def clear_record(rec: Records, p: int):
    rec.entry[p] = NO_PHOTON
    rec.pix[p] = -1
    rec.throughput[p] = wp.vec3(1.0)


@wp.func
def trace_corner_cisp(
    p: int,  # record slot
    sheet: int,  # SHEET_REFRACTED or SHEET_REFLECTED
    origin: wp.vec3,  # [m] the corner's point on the specular surface
    n: wp.vec3,  # its (interpolated) unit normal
    d_in: wp.vec3,  # the light's unit direction arriving there
    transmissive: int,  # 1: a dielectric (both sheets), 0: a metal (reflected sheet only)
    ior: float,
    light: ViewParams,
    rsm_opaque_depth: wp.array(dtype=wp.float32),  # (H_l*W_l,) [m] (read)
    rsm_depth_bounds: wp.array(dtype=wp.vec2),  # its march.depth_bounds (read)
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
    rec: Records,  # (write) slot p, cleared by the caller
):
    """A corner photon of either grid (RSM or mesh) from its surface point: its sheet's bounce, CISP's
    light-view march and cascade with the camera rescue (:func:`camera_marches`) and the landing refined onto
    the receiver's tangent plane, recorded in slot ``p``."""
    ok, d = grid_bounce(sheet, d_in, n, transmissive, ior)
    if ok == 0:
        return
    status, x_end = march_light(light, rsm_opaque_depth, rsm_depth_bounds, origin, d, t_max, max_steps, thickness,
                                thickness_rel)
    entry, pix = reproject_to_camera(camera, cam_depth, status, x_end, thickness, thickness_rel, use_cascade)
    entry, x_end, pix = camera_marches(camera, cam_depth, cam_depth_bounds, origin, d, t_max, max_steps, thickness,
                                       thickness_rel, use_cascade, entry, x_end, pix)
    if entry == L_STORED:
        x_end, pix = refine_landing(camera, cam_depth, cam_position, cam_normal, origin, d, x_end, pix, thickness,
                                    thickness_rel)
    rec.entry[p] = entry
    rec.pos[p] = x_end
    rec.pix[p] = pix
    rec.dir[p] = d


@wp.func
def trace_corner_world(
    p: int,  # record slot
    sheet: int,
    x: wp.vec3,  # [m] the corner's point on the specular surface
    n: wp.vec3,  # its (interpolated) unit normal
    ng: wp.vec3,  # the triangle's geometric normal
    d_in: wp.vec3,  # the light's unit direction arriving there
    transmissive: int,
    ior: float,
    ws: WorldScene,
    cam: CameraBuffers,
    seed: int,  # random streams of later Fresnel bounces (after the first, deterministic one)
    roughness_cutoff: float,
    thickness: float,
    thickness_rel: float,
    t_max: float,
    max_bounces: int,
    rec: Records,  # (write) slot p, cleared by the caller
):
    """A corner photon of either grid from its surface point: its sheet's bounce, SSPM's world-space trace
    (:func:`world_trace`) and depth-visibility test (:func:`camera_receiver`), recorded in slot ``p`` with
    unit power: the record's throughput is what it kept."""
    ok, d = grid_bounce(sheet, d_in, n, transmissive, ior)
    if ok == 0:
        return
    discard = tally_new()  # world_trace books the unit photon's ending here; the splat books the cells' power
    status, y, nr, d2, kept, state = world_trace(ws, x, ng, d, wp.vec3(1.0), wp.rand_init(seed, p),
                                                 roughness_cutoff, t_max, max_bounces, discard)
    entry = status
    pix = int(-1)
    if status == WT_LANDED:
        entry, pix = camera_receiver(cam, y, thickness, thickness_rel)
    rec.entry[p] = entry
    rec.pos[p] = y
    rec.pix[p] = pix
    rec.dir[p] = d2
    rec.throughput[p] = kept


@wp.kernel
def trace_grid_cisp(
    light: ViewParams,
    light_kind: int,
    light_pos: wp.vec3,
    grid: Grid,
    rsm_opaque_depth: wp.array(dtype=wp.float32),  # (H_l*W_l,) [m] (read)
    rsm_depth_bounds: wp.array(dtype=wp.vec2),  # its march.depth_bounds (read)
    rsm_position: wp.array(dtype=wp.vec3),  # (H_l*W_l,) specular layer [m] (read)
    rsm_normal: wp.array(dtype=wp.vec3),
    rsm_tri: wp.array(dtype=wp.int32),
    points: wp.array(dtype=wp.vec3),  # (V,) scene vertices [m] (read)
    normals: wp.array(dtype=wp.vec3),  # (V,) unit vertex normals (read)
    indices: wp.array(dtype=wp.int32),  # (3T,) (read)
    triangle_material: wp.array(dtype=wp.int32),
    mat_opacity: wp.array(dtype=wp.float32),
    mat_ior: wp.array(dtype=wp.float32),  # (M,) per material: the IOR behind the corner's texel (read)
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
    rec: Records,  # (2 · corners,) (write)
):
    """One thread per grid photon: its corner's surface from the RSM, then :func:`trace_corner_cisp`."""
    p = wp.tid()
    clear_record(rec, p)
    sheet, sx, sy = grid_corner(grid, p)
    lo, ld = pixel_ray_world(light, float(sx), float(sy))
    texel, origin, n, ng = corner_surface_rsm(sx, sy, lo, ld, grid, rsm_position, rsm_normal, rsm_tri, points, normals,
                                              indices)
    if texel < 0:
        return
    d_in = wp.normalize(ld)
    if light_kind != 0:
        d_in = wp.normalize(origin - light_pos)
    m = triangle_material[rsm_tri[texel]]
    transmissive = int(mat_opacity[m] < 1.0)
    trace_corner_cisp(p, sheet, origin, n, d_in, transmissive, mat_ior[m], light, rsm_opaque_depth,
                      rsm_depth_bounds, camera, cam_depth, cam_depth_bounds, cam_position, cam_normal, max_steps,
                      thickness, thickness_rel, t_max, use_cascade, rec)


@wp.kernel
def trace_grid_world(
    light: ViewParams,
    light_kind: int,
    light_pos: wp.vec3,
    grid: Grid,
    ws: WorldScene,
    cam: CameraBuffers,
    seed: int,  # random streams of later Fresnel bounces (after the first, deterministic one)
    roughness_cutoff: float,
    thickness: float,
    thickness_rel: float,
    t_max: float,
    max_bounces: int,
    rec: Records,  # (2 · corners,) (write)
):
    """One thread per grid photon: its corner's surface where the light's ray first meets the scene (BVH),
    then :func:`trace_corner_world`."""
    p = wp.tid()
    clear_record(rec, p)
    sheet, sx, sy = grid_corner(grid, p)
    lo, ld = pixel_ray_world(light, float(sx), float(sy))
    d_in = wp.normalize(ld)
    t0 = float(0.0)
    if light.orthographic != 0:
        t0 = light.near
    tri, x, n, ng = world_hit(ws, lo + d_in * t0, d_in, t_max)
    if tri < 0 or is_smooth_specular(ws, tri, roughness_cutoff) == 0:
        return  # the corner's ray meets no smooth specular surface first: its cells fall back
    if light_kind != 0:
        d_in = wp.normalize(x - light_pos)
    m = ws.triangle_material[tri]
    trace_corner_world(p, sheet, x, n, ng, d_in, int(ws.opacity[m] < 1.0), ws.ior[m], ws, cam, seed,
                       roughness_cutoff, thickness, thickness_rel, t_max, max_bounces, rec)
