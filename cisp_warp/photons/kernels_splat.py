"""Warp kernels of wavefront splatting, the splat: every grid triangle's power (:mod:`.kernels_wavefront`)
spread over the triangle its corner photons land on, clipped against the camera's pixels.

* **Splat.** A triangle whose three corners land on the same receiver (at least one on a camera surface,
  the others on one too or off the screen; normals within ``NORMAL_COS``, the three points on one tangent
  plane, every arrival on a camera surface validated) is
  projected into the camera; each pixel receives power × (area of pixel ∩ triangle) / (triangle area),
  areas measured in screen space (exact for an orthographic camera; for a perspective one to second order
  in the triangle's size, a few pixels), and stores it as irradiance over the pixel's exact footprint.
  Focus lines stay finite because the power is integrated per pixel. Parts of the triangle on pixels that
  show another surface are booked ``occluded``; parts off the screen ``lost_camera_view``.
* **Fallback.** A triangle whose corners diverge (a silhouette, an occluder, a lost corner, a span over
  ``max_span`` pixels) gives a third of its power to each corner photon, deposited as a point (validated
  and booked as every point photon is) or booked where that photon ended.

Every watt of a triangle ends in exactly one ledger entry; each thread tallies in registers and the block
adds each entry once.
"""

from __future__ import annotations

import warp as wp

from ..raster.views import world_project
from .common import (FOOTPRINT_PAPER, L_ABSORBED, L_LOST_CAMERA, L_LOST_LIGHT, L_OCCLUDED, L_REJECTED, L_STORED,
                     pixel_footprint)
from .kernels_cisp import NORMAL_COS
from .kernels_wavefront import Grid, LedgerRows, Records, grid_corners, ledger_flush, rows_add
from .kernels_world import CameraBuffers

wp.set_module_options({"enable_backward": False})

TRI_EMPTY = wp.constant(0)  #: the triangle carries no power
TRI_SPLAT = wp.constant(1)  #: splatted over its landing area
TRI_FALLBACK = wp.constant(2)  #: corners diverged: point deposits at the corners
TRI_REFINE = wp.constant(3)  #: corners diverged, one on a camera surface: left to a finer grid (nothing booked yet)

vec8 = wp.types.vector(length=8, dtype=wp.float32)  #: a clipped polygon's coordinates (a triangle cut by 4 lines: 7)


@wp.func
def clip_axis(xs: vec8, ys: vec8, n: int, axis: int, bound: float, keep_above: int):
    """Sutherland-Hodgman: the polygon (xs, ys)[:n] cut to coordinate ``axis`` >= bound (or <= bound)."""
    ox = vec8()
    oy = vec8()
    m = int(0)
    for i in range(n):
        j = (i + 1) % n
        ci = xs[i]
        cj = xs[j]
        if axis == 1:
            ci = ys[i]
            cj = ys[j]
        di = ci - bound
        dj = cj - bound
        if keep_above == 0:
            di = -di
            dj = -dj
        if di >= 0.0:
            ox[m] = xs[i]
            oy[m] = ys[i]
            m += 1
        if (di >= 0.0 and dj < 0.0) or (di < 0.0 and dj >= 0.0):
            t = di / (di - dj)
            ox[m] = xs[i] + t * (xs[j] - xs[i])
            oy[m] = ys[i] + t * (ys[j] - ys[i])
            m += 1
    return ox, oy, m


@wp.func
def triangle_pixel_overlap(a: wp.vec2, b: wp.vec2, c: wp.vec2, px: float, py: float) -> float:
    """Area [pixel²] of triangle abc ∩ the pixel square [px, px+1] × [py, py+1] (either orientation)."""
    xs = vec8()
    ys = vec8()
    xs[0] = a[0]
    ys[0] = a[1]
    xs[1] = b[0]
    ys[1] = b[1]
    xs[2] = c[0]
    ys[2] = c[1]
    n = int(3)
    xs, ys, n = clip_axis(xs, ys, n, 0, px, 1)
    xs, ys, n = clip_axis(xs, ys, n, 0, px + 1.0, 0)
    xs, ys, n = clip_axis(xs, ys, n, 1, py, 1)
    xs, ys, n = clip_axis(xs, ys, n, 1, py + 1.0, 0)
    area2 = float(0.0)
    for i in range(n):
        j = (i + 1) % n
        area2 += (xs[i] - px) * (ys[j] - py) - (xs[j] - px) * (ys[i] - py)
    return 0.5 * wp.abs(area2)


@wp.func
def edge_side(p: wp.vec2, q: wp.vec2, x: float, y: float) -> float:
    """cross(q - p, (x, y) - p): > 0 on the left of pq."""
    return (q[0] - p[0]) * (y - p[1]) - (q[1] - p[1]) * (x - p[0])


@wp.func
def pixel_cover(a: wp.vec2, b: wp.vec2, c: wp.vec2, orient: float, px: float, py: float) -> float:
    """:func:`triangle_pixel_overlap` with two shortcuts from the edge functions at the pixel's four corners
    (``orient``: +1 or -1, the triangle's winding): every corner outside one edge gives 0, every corner inside
    all three gives the whole pixel, neither one clipped. Most pixels of a landing triangle's bounds are one or
    the other; only those its edges cross are clipped (the clip's polygon arrays live in local memory)."""
    inside = int(0)
    for e in range(3):
        p = a
        q = b
        if e == 1:
            p = b
            q = c
        elif e == 2:
            p = c
            q = a
        s0 = orient * edge_side(p, q, px, py)
        s1 = orient * edge_side(p, q, px + 1.0, py)
        s2 = orient * edge_side(p, q, px, py + 1.0)
        s3 = orient * edge_side(p, q, px + 1.0, py + 1.0)
        if s0 <= 0.0 and s1 <= 0.0 and s2 <= 0.0 and s3 <= 0.0:
            return 0.0
        if s0 >= 0.0 and s1 >= 0.0 and s2 >= 0.0 and s3 >= 0.0:
            inside += 1
    if inside == 3:
        return 1.0
    return triangle_pixel_overlap(a, b, c, px, py)


@wp.func
def landed(entry: int) -> int:
    """1 for a photon that landed on a camera surface, or on a surface off the screen."""
    if entry == L_STORED or entry == L_LOST_CAMERA:
        return 1
    return 0


@wp.func
def on_receiver(cam: CameraBuffers, pix: int, x0: wp.vec3, n0: wp.vec3, thickness: float, thickness_rel: float) -> int:
    """1 when camera pixel ``pix`` shows the receiver through ``x0`` with normal ``n0`` (its tangent plane)."""
    z = cam.depth[pix]
    if z <= 0.0:
        return 0
    if wp.dot(cam.normal[pix], n0) < NORMAL_COS:
        return 0
    if wp.abs(wp.dot(cam.position[pix] - x0, n0)) > thickness + thickness_rel * z:
        return 0
    return 1


@wp.func
def splat_pixel(cam: CameraBuffers, pix: int, power: wp.vec3, d: wp.vec3, footprint_mode: int,
                photon_map: wp.array(dtype=wp.vec3)):
    """Add ``power`` [W] to camera pixel ``pix`` as irradiance over its exact footprint."""
    nr = cam.normal[pix]
    area = pixel_footprint(cam.view, cam.solid_angle[pix], cam.position[pix], nr, footprint_mode)
    e = power / area
    if footprint_mode == FOOTPRINT_PAPER:
        e = e * wp.max(wp.dot(-d, nr), 0.0)
    wp.atomic_add(photon_map, pix, e)


@wp.func
def splat_corners(
    t: int,  # the triangle's slot in tri_power and tri_state
    ia: int,  # its corner photons' record slots
    ib: int,
    ic: int,
    rec: Records,  # (read)
    tri_power: wp.array(dtype=wp.vec3),  # [W] (read)
    cam: CameraBuffers,
    thickness: float,  # [m] receiver tolerance, absolute
    thickness_rel: float,  # relative (× depth)
    max_span: int,  # [pixels] a landing triangle wider or taller than this falls back
    footprint_mode: int,
    photon_map: wp.array(dtype=wp.vec3),  # (H*W,) irradiance [W/m²] (accumulate)
    tri_state: wp.array(dtype=wp.int32),  # TRI_* (write)
    defer: int,  # 1: a triangle that would fall back with a corner on a camera surface is left to refinement
):
    """Triangle ``t`` of either grid (RSM or mesh), with corner photons ``ia``, ``ib``, ``ic``: splat its
    power over its landing triangle, or fall back (or, with ``defer``, mark it ``TRI_REFINE`` and book
    nothing: a finer grid over it books its power). Returns its ledger rows."""
    rows = LedgerRows()
    power = tri_power[t]
    if wp.length_sq(power) == 0.0:
        tri_state[t] = TRI_EMPTY
        return rows
    ea = rec.entry[ia]
    eb = rec.entry[ib]
    ec = rec.entry[ic]
    v = cam.view
    # one receiver: every corner on a camera surface, or landed off the screen; the first on a surface is the
    # reference (its tangent plane and normal); corners on surfaces face it and were validated; all lie on its
    # plane and in front of the camera
    ref = int(-1)
    if ea == L_STORED:
        ref = ia
    elif eb == L_STORED:
        ref = ib
    elif ec == L_STORED:
        ref = ic
    coherent = int(0)
    if ref >= 0 and landed(ea) != 0 and landed(eb) != 0 and landed(ec) != 0:
        coherent = 1
        x0 = rec.pos[ref]
        n0 = cam.normal[rec.pix[ref]]
        tol = thickness + thickness_rel * cam.depth[rec.pix[ref]]
        for k in range(3):
            ik = ia
            if k == 1:
                ik = ib
            elif k == 2:
                ik = ic
            if wp.abs(wp.dot(rec.pos[ik] - x0, n0)) > tol or world_project(v, rec.pos[ik])[2] <= v.near:
                coherent = 0
            if rec.entry[ik] == L_STORED:
                nk = cam.normal[rec.pix[ik]]
                if wp.dot(nk, n0) < NORMAL_COS or wp.dot(-rec.dir[ik], nk) < 0.0:
                    coherent = 0
    if coherent != 0:
        qa = world_project(v, rec.pos[ia])
        qb = world_project(v, rec.pos[ib])
        qc = world_project(v, rec.pos[ic])
        a = wp.vec2(qa[0], qa[1])
        b = wp.vec2(qb[0], qb[1])
        cc = wp.vec2(qc[0], qc[1])
        lo = wp.min(wp.min(a, b), cc)
        hi = wp.max(wp.max(a, b), cc)
        if hi[0] - lo[0] > float(max_span) or hi[1] - lo[1] > float(max_span):
            coherent = 0
        else:
            kept = (rec.throughput[ia] + rec.throughput[ib] + rec.throughput[ic]) / 3.0
            p_eff = wp.cw_mul(power, kept)
            d = wp.normalize(rec.dir[ia] + rec.dir[ib] + rec.dir[ic])
            x0 = rec.pos[ref]
            n0 = cam.normal[rec.pix[ref]]
            area = 0.5 * wp.abs((b[0] - a[0]) * (cc[1] - a[1]) - (cc[0] - a[0]) * (b[1] - a[1]))  # [pixel²]
            stored = wp.vec3(0.0)
            occluded = wp.vec3(0.0)
            i0 = int(wp.floor(lo[0]))
            i1 = int(wp.floor(hi[0]))
            j0 = int(wp.floor(lo[1]))
            j1 = int(wp.floor(hi[1]))
            if area < 1.0e-6 or (i0 == i1 and j0 == j1):
                # within one pixel (a focus point, or a small triangle): all of it lands there
                g = (a + b + cc) / 3.0
                gi = int(wp.floor(g[0]))
                gj = int(wp.floor(g[1]))
                if gi >= 0 and gj >= 0 and gi < v.width and gj < v.height:  # else off the screen: lost
                    pix = gj * v.width + gi
                    if on_receiver(cam, pix, x0, n0, thickness, thickness_rel) != 0:
                        splat_pixel(cam, pix, p_eff, d, footprint_mode, photon_map)
                        stored = p_eff
                    else:
                        occluded = p_eff
            else:
                inv_area = 1.0 / area
                orient = wp.sign((b[0] - a[0]) * (cc[1] - a[1]) - (cc[0] - a[0]) * (b[1] - a[1]))
                for j in range(wp.max(j0, 0), wp.min(j1, v.height - 1) + 1):
                    for i in range(wp.max(i0, 0), wp.min(i1, v.width - 1) + 1):
                        o = pixel_cover(a, b, cc, orient, float(i), float(j))
                        if o <= 0.0:
                            continue
                        share = p_eff * (o * inv_area)
                        pix = j * v.width + i
                        if on_receiver(cam, pix, x0, n0, thickness, thickness_rel) != 0:
                            splat_pixel(cam, pix, share, d, footprint_mode, photon_map)
                            stored += share
                        else:
                            occluded += share
            tri_state[t] = TRI_SPLAT
            rows = rows_add(rows, L_STORED, stored)
            rows = rows_add(rows, L_OCCLUDED, occluded)
            rows = rows_add(rows, L_LOST_CAMERA, p_eff - stored - occluded)  # off the screen (and ~1e-7 rounding)
            rows = rows_add(rows, L_ABSORBED, power - p_eff)
            return rows
    if defer != 0 and (ea == L_STORED or eb == L_STORED or ec == L_STORED):
        tri_state[t] = TRI_REFINE
        return rows
    # fallback: a third of the power to each corner photon, as a point (or booked where it ended)
    tri_state[t] = TRI_FALLBACK
    valid = int(0)
    if ea >= 0:
        valid += 1
    if eb >= 0:
        valid += 1
    if ec >= 0:
        valid += 1
    if valid == 0:
        return rows_add(rows, L_LOST_LIGHT, power)  # no corner reached a specular surface: no path for this power
    share = power / float(valid)
    for k in range(3):
        ik = ia
        if k == 1:
            ik = ib
        elif k == 2:
            ik = ic
        e = rec.entry[ik]
        if e < 0:
            continue
        kept = wp.cw_mul(share, rec.throughput[ik])
        rows = rows_add(rows, L_ABSORBED, share - kept)
        if e == L_STORED:
            # a point photon: validated against the receiver's normal (as common.deposit), stored at its pixel
            pk = rec.pix[ik]
            if wp.dot(-rec.dir[ik], cam.normal[pk]) < 0.0 or cam.depth[pk] <= 0.0:
                e = L_REJECTED
            else:
                splat_pixel(cam, pk, kept, rec.dir[ik], footprint_mode, photon_map)
        rows = rows_add(rows, e, kept)
    return rows


@wp.func
def splat_triangle(
    t: int,  # triangle: (sheet · cells + cell) · 2 + half
    grid: Grid,
    rec: Records,  # (2 · corners,) (read)
    tri_power: wp.array(dtype=wp.vec3),  # (2 sheets · cells · 2,) [W] (read)
    cam: CameraBuffers,
    thickness: float,  # [m] receiver tolerance, absolute
    thickness_rel: float,  # relative (× depth)
    max_span: int,  # [pixels] a landing triangle wider or taller than this falls back
    footprint_mode: int,
    photon_map: wp.array(dtype=wp.vec3),  # (H*W,) irradiance [W/m²] (accumulate)
    tri_state: wp.array(dtype=wp.int32),  # (2 sheets · cells · 2,) TRI_* (write)
):
    """RSM grid triangle ``t`` of its sheet: its corner photons, then :func:`splat_corners`."""
    cells = grid.cells_x * grid.cells_y
    half = t % 2
    c = (t / 2) % cells
    sheet = t / (2 * cells)
    row = grid.cells_x + 1
    base = sheet * grid_corners(grid) + (c / grid.cells_x) * row + c % grid.cells_x
    ia = base  # corner (0, 0) of the cell
    ib = base + 1  # (1, 0)
    ic = base + row + 1  # (1, 1)
    if half == 1:
        ib = base + row + 1
        ic = base + row  # (0, 1)
    return splat_corners(t, ia, ib, ic, rec, tri_power, cam, thickness, thickness_rel, max_span, footprint_mode,
                         photon_map, tri_state, 0)


@wp.kernel
def splat_triangles(
    grid: Grid,
    rec: Records,  # (2 · corners,) (read)
    tri_power: wp.array(dtype=wp.vec3),  # (2 sheets · cells · 2,) [W] (read)
    cam: CameraBuffers,
    thickness: float,  # [m] receiver tolerance, absolute
    thickness_rel: float,  # relative (× depth)
    max_span: int,  # [pixels] a landing triangle wider or taller than this falls back
    footprint_mode: int,
    photon_map: wp.array(dtype=wp.vec3),  # (H*W,) irradiance [W/m²] (accumulate)
    tri_state: wp.array(dtype=wp.int32),  # (2 sheets · cells · 2,) TRI_* (write)
    ledger: wp.array(dtype=wp.float64),  # (3*LEDGER_ENTRIES,) [W] (accumulate, once per block and entry)
):
    """One thread per grid triangle and sheet (:func:`splat_triangle`), launched tiled: the block's ledger
    rows added once."""
    block, lane = wp.tid()
    t = block * wp.block_dim() + lane
    rows = LedgerRows()
    if t < 4 * grid.cells_x * grid.cells_y:
        rows = splat_triangle(t, grid, rec, tri_power, cam, thickness, thickness_rel, max_span, footprint_mode,
                              photon_map, tri_state)
    ledger_flush(ledger, rows, lane)
