"""Warp kernels of the software rasterizer: triangle setup, tiled visibility raster, attribute resolve.

The visibility buffer holds one uint64 per pixel: the high 32 bits are the fragment's float32 depth's own bits
(a positive float's bits grow with it, so ordering is exact to the depth the raster computes; ``DEPTH_KEY_BITS``),
the low 32 bits the triangle id. ``wp.atomic_min`` on it keeps the nearest triangle. The resolve pass then
intersects the pixel's ray with that triangle, so depth, position and barycentrics are exact, not quantised.

Large triangles do not serialise onto one thread: setup counts the 8x8-pixel tiles each (clipped)
triangle's bounding box touches, an inclusive scan turns counts into offsets, and the tile kernel hands
out (triangle, tile) work items: ``raster_tile_columns`` gives each warp a run of consecutive items, 4
adjacent tiles at a time, a thread per pixel column, and skips columns proven outside an edge;
``raster_tiles``, its naive twin, a thread per item found by binary search. The default draws with
``raster_tiles_reject`` (``raster_tiles`` with the tiles proven outside an edge skipped) and, for small views (the
pilots), ``raster_tile_rows`` (a thread per tile row); both are ``raster_tiles``' buffers bit for bit on the CPU.

An RSM view is resolved in one tiled pass (``resolve_rsm_view``: both layers, and the depth bounds of its opaque
depth that the photon march reads, reduced per block in shared memory), the camera's back-face layer likewise with the
camera's bounds (``resolve_back_view``); ``resolve_depth`` + ``resolve_rsm_specular``, ``resolve_back`` and
``photons.march.depth_bounds`` + ``coarsen_bounds`` are their naive twins. By default an RSM view keeps per specular
texel only its triangle and depth: its point and normal (``texel_surface``), its flux (``texel_emitted_flux``) and its
roughness and IOR (``texel_roughness``, ``texel_ior``) are computed where they are read, from the view, the light
(``TexelEmission``) and the triangle, the bits the resolves write where the maps are kept (docs/perf_notes.md
sections 43 and 58).
"""

from __future__ import annotations

import math
import os

import numpy as np
import warp as wp

from .views import ViewParams, pixel_ray_world, read_again, view_point, view_project

TILE = 8  #: tile edge [pixels] of one raster work item
EMPTY_KEY_VALUE = 0xFFFFFFFFFFFFFFFF  #: visibility value of a pixel no triangle covers
EMPTY_KEY = wp.constant(wp.uint64(EMPTY_KEY_VALUE))
DEPTH_STEPS = wp.constant(4294967040.0)  # largest float32 below 2^32: the quantised depth fits 32 bits
#: The visibility key's depth (docs/perf_notes.md section 90): True (default), the fragment's float32 depth's bits,
#: a bit move; False (the twin: ``CISP_DEPTH_KEY=quotient`` in the environment before this module is imported), the
#: depth quantised linearly over [0, far], a float64 division, product and conversion a fragment. Both orders agree
#: wherever the quantised depths differ; the bits also separate depths closer than far·2.3e-10.
DEPTH_KEY_BITS = os.environ.get("CISP_DEPTH_KEY", "bits") != "quotient"

# depth bounds of a depth buffer (``photons.march.depth_bounds``, and :func:`resolve_rsm_view` in its resolve): defined
# here, beside the resolves that may write them, and imported by ``photons.march``
BIG_DEPTH = wp.constant(1.0e30)  #: the depth a hole (no surface) counts as
BOUNDS_CELL = wp.constant(8)  #: edge [texels] of the fine cells of the depth bounds
BOUNDS_COARSE = wp.constant(32)  #: edge [texels] of their coarse cells (4x4 fine cells)
BOUNDS_NEAR = wp.constant(0.999999)  #: a fine cell's nearest depth is widened by this factor (``march.depth_bounds``)
BOUNDS_FAR = wp.constant(1.000001)  #: and its farthest back face by this one


def bounds_size(width: int, height: int) -> int:
    """Length of a depth buffer's bounds array: its fine cells, then its coarse cells."""
    fine = ((width + BOUNDS_CELL - 1) // BOUNDS_CELL) * ((height + BOUNDS_CELL - 1) // BOUNDS_CELL)
    return fine + ((width + BOUNDS_COARSE - 1) // BOUNDS_COARSE) * ((height + BOUNDS_COARSE - 1) // BOUNDS_COARSE)


@wp.func
def bounds_far(zs: float, thickness: float, thickness_rel: float) -> float:
    """The back face of a depth sample ``zs`` [m] in the depth bounds (as the march computes a surface's far side)."""
    return zs + thickness + thickness_rel * zs


@wp.func
def _clip_lerp(p: wp.vec3, q: wp.vec3, dp: float, dq: float, near: float) -> wp.vec3:
    """Point where segment p->q (view space, depths dp, dq) crosses depth ``near``."""
    s = (near - dp) / (dq - dp)
    return p + (q - p) * s


@wp.func
def _emit(
    view: ViewParams,
    slot: int,
    p0: wp.vec3,
    p1: wp.vec3,
    p2: wp.vec3,
    tiles_x: int,
    tiles_y: int,
    sub_v: wp.array(dtype=wp.vec3),
    sub_bbox: wp.array(dtype=wp.vec4i),
    tile_count: wp.array(dtype=wp.int32),
):
    """Project one (clipped) view-space triangle and record its screen vertices and tile box."""
    a = view_project(view, p0)
    b = view_project(view, p1)
    c = view_project(view, p2)
    # third component becomes what interpolates linearly in screen space: 1/depth or depth
    if view.orthographic == 0:
        a = wp.vec3(a[0], a[1], 1.0 / a[2])
        b = wp.vec3(b[0], b[1], 1.0 / b[2])
        c = wp.vec3(c[0], c[1], 1.0 / c[2])
    area2 = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1])
    if wp.abs(area2) < 1.0e-12:
        return
    if area2 < 0.0:
        t = b
        b = c
        c = t
    w = float(view.width)
    h = float(view.height)
    xmin = wp.clamp(wp.min(wp.min(a[0], b[0]), c[0]), -2.0, w + 2.0)
    xmax = wp.clamp(wp.max(wp.max(a[0], b[0]), c[0]), -2.0, w + 2.0)
    ymin = wp.clamp(wp.min(wp.min(a[1], b[1]), c[1]), -2.0, h + 2.0)
    ymax = wp.clamp(wp.max(wp.max(a[1], b[1]), c[1]), -2.0, h + 2.0)
    # pixels whose centres (i + 0.5) can lie inside
    i0 = wp.max(int(wp.ceil(xmin - 0.5)), 0)
    i1 = wp.min(int(wp.floor(xmax - 0.5)), view.width - 1)
    j0 = wp.max(int(wp.ceil(ymin - 0.5)), 0)
    j1 = wp.min(int(wp.floor(ymax - 0.5)), view.height - 1)
    if i0 > i1 or j0 > j1:
        return
    sub_v[3 * slot + 0] = a
    sub_v[3 * slot + 1] = b
    sub_v[3 * slot + 2] = c
    sub_bbox[slot] = wp.vec4i(i0, j0, i1, j1)
    tile_count[slot] = (i1 / TILE - i0 / TILE + 1) * (j1 / TILE - j0 / TILE + 1)


@wp.func
def faces_away(view: ViewParams, t: int, points: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3),
               indices: wp.array(dtype=wp.int32)) -> bool:
    """Whether triangle ``t`` shows the view its back: its geometric normal, turned to the side of its authored
    (outward) vertex normals, points away from the eye (perspective: from the eye to the triangle's plane; the
    sign is the same at every point of the plane) or along the view axis (orthographic). The scene's surfaces are
    two-sided for shading; only this back-face layer asks which side is outside."""
    p0 = points[indices[3 * t]]
    p1 = points[indices[3 * t + 1]]
    p2 = points[indices[3 * t + 2]]
    ng = wp.cross(p1 - p0, p2 - p0)
    na = normals[indices[3 * t]] + normals[indices[3 * t + 1]] + normals[indices[3 * t + 2]]
    if wp.dot(ng, na) < 0.0:
        ng = -ng
    nv = wp.transform_vector(view.world_to_view, ng)
    if view.orthographic != 0:
        return nv[2] < 0.0  # the view looks along -z: the normal points away from the eye
    return wp.dot(nv, view_point(view, p0)) > 0.0


@wp.kernel
def setup_triangles(
    views: wp.array(dtype=ViewParams),  # (V,) views (read): draws views[view_index]
    view_index: int,
    points: wp.array(dtype=wp.vec3),  # (V,) world positions [m] (read)
    indices: wp.array(dtype=wp.int32),  # (3T,) (read)
    layers: wp.array(dtype=wp.int32),  # (T,) layer bits (read)
    layer_mask: int,
    tiles_x: int,
    tiles_y: int,
    sub_v: wp.array(dtype=wp.vec3),  # (6T,) screen vertices (px, py, 1/depth or depth) (write)
    sub_bbox: wp.array(dtype=wp.vec4i),  # (2T,) pixel box i0, j0, i1, j1 (write)
    tile_count: wp.array(dtype=wp.int32),  # (2T,) tiles touched, 0 = culled (write)
    normals: wp.array(dtype=wp.vec3),  # (V,) authored (outward) vertex normals (read; only when back_only != 0)
    back_only: int,  # 1: only the triangles that face away from the view (:func:`faces_away`), 0: all
):
    """Near-clip each triangle of the layer into at most two, project them, count their tiles."""
    view = views[view_index]
    t = wp.tid()
    tile_count[2 * t] = 0
    tile_count[2 * t + 1] = 0
    if (layers[t] & layer_mask) == 0 or view.far <= 0.0:  # far = 0: an inactive view (light_maps.INACTIVE_FAR), nothing drawn
        return
    if back_only != 0:
        if not faces_away(view, t, points, normals, indices):
            return
    a = view_point(view, points[indices[3 * t]])
    b = view_point(view, points[indices[3 * t + 1]])
    c = view_point(view, points[indices[3 * t + 2]])
    da = -a[2]
    db = -b[2]
    dc = -c[2]
    near = view.near
    n_in = int(0)
    if da >= near:
        n_in += 1
    if db >= near:
        n_in += 1
    if dc >= near:
        n_in += 1
    if n_in == 0:
        return
    if n_in == 3:
        _emit(view, 2 * t, a, b, c, tiles_x, tiles_y, sub_v, sub_bbox, tile_count)
        return
    # rotate so that p is the odd vertex out (the one inside when n_in == 1, outside when n_in == 2)
    p = a
    q = b
    r = c
    dp = da
    dq = db
    dr = dc
    odd_b = (n_in == 1 and db >= near) or (n_in == 2 and db < near)
    odd_c = (n_in == 1 and dc >= near) or (n_in == 2 and dc < near)
    if odd_b:
        p = b
        q = c
        r = a
        dp = db
        dq = dc
        dr = da
    elif odd_c:
        p = c
        q = a
        r = b
        dp = dc
        dq = da
        dr = db
    if n_in == 1:
        _emit(view, 2 * t, p, _clip_lerp(p, q, dp, dq, near), _clip_lerp(p, r, dp, dr, near), tiles_x, tiles_y, sub_v, sub_bbox, tile_count)
    else:
        # p outside; polygon q, r, r->p, p->q
        x_rp = _clip_lerp(r, p, dr, dp, near)
        x_pq = _clip_lerp(p, q, dp, dq, near)
        _emit(view, 2 * t, q, r, x_rp, tiles_x, tiles_y, sub_v, sub_bbox, tile_count)
        _emit(view, 2 * t + 1, q, x_rp, x_pq, tiles_x, tiles_y, sub_v, sub_bbox, tile_count)


@wp.func
def _edge(a: wp.vec3, b: wp.vec3, x: float, y: float) -> float:
    return (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0])


@wp.func
def _edge_terms(a: wp.vec3, b: wp.vec3) -> wp.vec4:
    """(p0, p1, dx, dy) with ``dx·(y - p1) - dy·(x - p0)`` equal to ``_shared_edge(a, b, x, y)`` bit for bit: ``p`` is
    the lexicographically smaller end, and the sign of the other orientation is folded into dx and dy (rounding is
    symmetric: fl(-u + v) = -fl(u - v); a zero comes out +0 where ``_shared_edge`` gives -0, which no test or sum
    of :func:`raster_tile_columns` tells apart)."""
    if a[0] < b[0] or (a[0] == b[0] and a[1] < b[1]):
        return wp.vec4(a[0], a[1], b[0] - a[0], b[1] - a[1])
    return wp.vec4(b[0], b[1], -(a[0] - b[0]), -(a[1] - b[1]))


@wp.func
def _edge_at(e: wp.vec4, x: float, y: float) -> float:
    """:func:`_shared_edge` from its :func:`_edge_terms` (the same operations on the same values)."""
    return e[2] * (y - e[1]) - e[3] * (x - e[0])


@wp.func
def _shared_edge(a: wp.vec3, b: wp.vec3, x: float, y: float) -> float:
    """:func:`_edge` evaluated from the edge's lexicographically smaller end, so that the two triangles sharing
    edge ab (one walks it a->b, the other b->a) get bit-for-bit opposite values: a pixel centre on the edge is
    covered by at least one of them. Evaluated from either end as written, the rounding differs: a centre exactly
    on the edge could come out negative for both, a crack of uncovered pixels along the diagonal of a quad. The
    other orientation's sign is folded into the terms (:func:`_edge_terms`), so both evaluate one expression: on
    CUDA, which contracts products into FMAs, ``-(u - v)`` written out contracted one product for one orientation
    and the other for the other (seen in the sm_90 code), and opposite values were not guaranteed there."""
    return _edge_at(_edge_terms(a, b), x, y)


@wp.func
def fragment_depth(view: ViewParams, a: wp.vec3, b: wp.vec3, c: wp.vec3, w0: float, w1: float, w2: float,
                   inv_area: float) -> float:
    """Depth [m] at a covered pixel of the screen triangle ``a, b, c`` (edge weights ``w0..w2``; [2] is 1/depth, or
    depth when orthographic)."""
    z = (w0 * a[2] + w1 * b[2] + w2 * c[2]) * inv_area
    if view.orthographic == 0:
        return 1.0 / z
    return z


@wp.func_native("""
#if defined(__CUDA_ARCH__)
return wp::uint64(__float_as_uint(x));
#else
unsigned int u;
memcpy(&u, &x, 4);
return wp::uint64(u);
#endif
""")
def float_bits(x: float) -> wp.uint64:
    """The IEEE-754 bits of float32 ``x`` (in the low 32 bits): for ``x >= 0`` they order as ``x`` does."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
return __uint_as_float((unsigned int)(u));
#else
unsigned int v = (unsigned int)(u);
float x;
memcpy(&x, &v, 4);
return x;
#endif
""")
def bits_float(u: wp.uint64) -> float:
    """The float32 whose IEEE-754 bits are the low 32 bits of ``u`` (:func:`float_bits`' inverse)."""
    ...


@wp.func
def depth_key(view: ViewParams, depth: float, tri: wp.uint64) -> wp.uint64:
    """The visibility key of a fragment (``0 < depth <= far``): the depth in the high 32 bits (its float32 bits, or
    quantised over [0, far] without ``DEPTH_KEY_BITS``), the triangle id below (an ``atomic_min`` keeps the
    nearest)."""
    if wp.static(DEPTH_KEY_BITS):
        return (float_bits(depth) << wp.uint64(32)) | tri
    q = wp.uint64(wp.min(wp.float64(depth) / wp.float64(view.far), wp.float64(1.0)) * wp.float64(DEPTH_STEPS))
    return (q << wp.uint64(32)) | tri


@wp.func
def key_depth(view: ViewParams, key: wp.uint64) -> float:
    """The depth [m] a (non-empty) visibility key holds: :func:`depth_key`'s depth, or its quantised value."""
    if wp.static(DEPTH_KEY_BITS):
        return bits_float(key >> wp.uint64(32))
    return float(wp.float64(key >> wp.uint64(32)) / wp.float64(DEPTH_STEPS) * wp.float64(view.far))


@wp.func
def write_fragment(view: ViewParams, a: wp.vec3, b: wp.vec3, c: wp.vec3, w0: float, w1: float, w2: float,
                   inv_area: float, tri: wp.uint64, to_a: bool, to_b: bool, p: int,
                   visibility: wp.array(dtype=wp.uint64), visibility_b: wp.array(dtype=wp.uint64)):
    """Depth-test covered pixel ``p`` (edge weights ``w0..w2`` of the screen triangle ``a, b, c``, whose [2] is 1/depth,
    or depth when orthographic): its key (quantised depth | triangle id) into each layer's buffer it is drawn to, by
    ``atomic_min``; shared by :func:`raster_tiles` and :func:`raster_tile_columns`."""
    depth = fragment_depth(view, a, b, c, w0, w1, w2, inv_area)
    if depth > 0.0 and depth <= view.far:
        key = depth_key(view, depth, tri)
        if to_a:
            wp.atomic_min(visibility, p, key)
        if to_b:
            wp.atomic_min(visibility_b, p, key)


@wp.kernel
def raster_tiles(
    views: wp.array(dtype=ViewParams),  # (V,) views (read): draws views[view_index]
    view_index: int,
    sub_v: wp.array(dtype=wp.vec3),  # (6T,) (read)
    sub_bbox: wp.array(dtype=wp.vec4i),  # (2T,) (read)
    tile_end: wp.array(dtype=wp.int32),  # (2T,) inclusive scan of tile counts (read)
    n_sub: int,
    stride: int,
    layers: wp.array(dtype=wp.int32),  # (T,) layer bits per triangle (read)
    mask: int,  # layers drawn into ``visibility``
    visibility: wp.array(dtype=wp.uint64),  # (H*W,) packed depth | triangle id (atomic min)
    mask_b: int,  # layers drawn into ``visibility_b`` (0: none)
    visibility_b: wp.array(dtype=wp.uint64),  # (H*W,) a second layer's buffer (atomic min; unused when mask_b = 0)
):
    """Grid-stride over (sub-triangle, tile) work items; depth-test every covered pixel centre, into the buffer of
    each layer the triangle belongs to (two layers drawn in one pass share the set-up, scan and tile walk). The naive
    twin of :func:`raster_tile_columns` (``Rasterizer.columns = False``): one thread per tile, a binary search per
    item."""
    view = views[view_index]
    item = wp.tid()
    total = tile_end[n_sub - 1]
    while item < total:
        s, i_lo, i_hi, j_lo, j_hi = _tile_of_item(tile_end, n_sub, sub_bbox, item)
        a = sub_v[3 * s + 0]
        b = sub_v[3 * s + 1]
        c = sub_v[3 * s + 2]
        inv_area = 1.0 / _edge(a, b, c[0], c[1])
        tri = wp.uint64(s / 2)
        tri_layers = layers[s / 2]
        to_a = (tri_layers & mask) != 0
        to_b = (tri_layers & mask_b) != 0
        for j in range(j_lo, j_hi + 1):
            y = float(j) + 0.5
            for i in range(i_lo, i_hi + 1):
                x = float(i) + 0.5
                w0 = _shared_edge(b, c, x, y)
                w1 = _shared_edge(c, a, x, y)
                w2 = _shared_edge(a, b, x, y)
                if w0 >= 0.0 and w1 >= 0.0 and w2 >= 0.0:
                    write_fragment(view, a, b, c, w0, w1, w2, inv_area, tri, to_a, to_b, j * view.width + i, visibility,
                                   visibility_b)
        item += stride


@wp.func
def _box_outside(e: wp.vec4, slack: float, box: wp.vec4i) -> bool:
    """Whether no pixel centre of ``box`` (i0, j0, i1, j1) passes the edge test ``_edge_at(e, x, y) >= 0``, proven from
    its four corners (:func:`_edge_slack`: the exact affine G is at most the corners' max over the box, and every
    computed value lies within E of G); False when it cannot be proven."""
    x0 = float(box[0]) + 0.5
    x1 = float(box[2]) + 0.5
    y0 = float(box[1]) + 0.5
    y1 = float(box[3]) + 0.5
    m = wp.max(wp.max(_edge_at(e, x0, y0), _edge_at(e, x1, y0)), wp.max(_edge_at(e, x0, y1), _edge_at(e, x1, y1)))
    return m < -2.0 * slack


@wp.func
def _row_outside(e: wp.vec4, slack: float, y: float, x0: float, x1: float) -> bool:
    """:func:`_column_outside` along a row: no pixel centre (x, y), x in [x0, x1], passes the edge test."""
    return wp.max(_edge_at(e, x0, y), _edge_at(e, x1, y)) < -2.0 * slack


#: threads per block of :func:`raster_tiles_reject`: at its 66 registers (sm_90 cubin, ``tools/regcount.py --modules
#: cisp_warp.raster.kernels``) an SM holds 7 blocks of 128 (28 warps) against 3 of 256 (24 warps); measured 0-10% faster
#: per draw on the H100 than 256 (docs/perf_notes.md section 52)
RASTER_BLOCK = 128


@wp.func
def _item_edges(sub_v: wp.array(dtype=wp.vec3), s: int):
    """Set-up triangle ``s``'s vertices (pixel x, y, depth terms) and its three edges' terms (:func:`_edge_terms`: the
    edge opposite a, b and c)."""
    a = sub_v[3 * s + 0]
    b = sub_v[3 * s + 1]
    c = sub_v[3 * s + 2]
    return a, b, c, _edge_terms(b, c), _edge_terms(c, a), _edge_terms(a, b)


@wp.func
def _item_setup(a: wp.vec3, b: wp.vec3, c: wp.vec3, s: int, layers: wp.array(dtype=wp.int32), mask: int, mask_b: int):
    """Set-up triangle ``s``'s (vertices ``a``, ``b``, ``c``) terms for :func:`_row_fragments`: 1 / its doubled area,
    its triangle id and whether it is drawn into each of the two layers (``mask``, ``mask_b``)."""
    tri_layers = layers[s / 2]
    return 1.0 / _edge(a, b, c[0], c[1]), wp.uint64(s / 2), (tri_layers & mask) != 0, (tri_layers & mask_b) != 0


@wp.func
def _row_fragments(view: ViewParams, a: wp.vec3, b: wp.vec3, c: wp.vec3, e0: wp.vec4, e1: wp.vec4, e2: wp.vec4,
                   inv_area: float, tri: wp.uint64, to_a: bool, to_b: bool, j: int, i_lo: int, i_hi: int,
                   visibility: wp.array(dtype=wp.uint64), visibility_b: wp.array(dtype=wp.uint64)):
    """The fragments of a set-up triangle (vertices ``a``, ``b``, ``c``, edge terms ``e0``-``e2``, :func:`_item_setup`'s
    terms) on pixel row ``j`` from column ``i_lo`` to ``i_hi``: each pixel centre inside all three edges written by
    :func:`write_fragment` (:func:`raster_tiles_reject`'s and :func:`raster_tile_rows`' loop)."""
    y = float(j) + 0.5
    for i in range(i_lo, i_hi + 1):
        x = float(i) + 0.5
        w0 = _edge_at(e0, x, y)
        w1 = _edge_at(e1, x, y)
        w2 = _edge_at(e2, x, y)
        if w0 >= 0.0 and w1 >= 0.0 and w2 >= 0.0:
            write_fragment(view, a, b, c, w0, w1, w2, inv_area, tri, to_a, to_b, j * view.width + i, visibility,
                           visibility_b)


@wp.kernel
def raster_tiles_reject(
    views: wp.array(dtype=ViewParams),  # (V,) views (read): draws views[view_index]
    view_index: int,
    sub_v: wp.array(dtype=wp.vec3),  # (6T,) (read)
    sub_bbox: wp.array(dtype=wp.vec4i),  # (2T,) (read)
    tile_end: wp.array(dtype=wp.int32),  # (2T,) inclusive scan of tile counts (read)
    n_sub: int,
    stride: int,
    layers: wp.array(dtype=wp.int32),  # (T,) layer bits per triangle (read)
    mask: int,  # layers drawn into ``visibility``
    visibility: wp.array(dtype=wp.uint64),  # (H*W,) packed depth | triangle id (atomic min)
    mask_b: int,  # layers drawn into ``visibility_b`` (0: none)
    visibility_b: wp.array(dtype=wp.uint64),  # (H*W,) a second layer's buffer (atomic min; unused when mask_b = 0)
):
    """:func:`raster_tiles` (its naive twin: the same items, threads, pixel order and fragments) with the tiles that no
    pixel centre of which can pass one edge test skipped (proven from their corners, :func:`_box_outside`; two thirds
    of the items on the pool, the boxes of long thin triangles); the edge terms set up once per item. The buffers are
    raster_tiles' bit for bit on the CPU. (Rows proven outside an edge skipped too measured slower on the H100.)"""
    view = views[view_index]
    item = wp.tid()
    total = tile_end[n_sub - 1]
    while item < total:
        s, i_lo, i_hi, j_lo, j_hi = _tile_of_item(tile_end, n_sub, sub_bbox, item)
        item += stride
        a, b, c, e0, e1, e2 = _item_edges(sub_v, s)
        box = wp.vec4i(i_lo, j_lo, i_hi, j_hi)
        if (_box_outside(e0, _edge_slack(e0, box), box) or _box_outside(e1, _edge_slack(e1, box), box)
                or _box_outside(e2, _edge_slack(e2, box), box)):
            continue
        inv_area, tri, to_a, to_b = _item_setup(a, b, c, s, layers, mask, mask_b)
        for j in range(j_lo, j_hi + 1):
            _row_fragments(view, a, b, c, e0, e1, e2, inv_area, tri, to_a, to_b, j, i_lo, i_hi, visibility,
                           visibility_b)


@wp.kernel
def raster_tile_rows(
    views: wp.array(dtype=ViewParams),  # (V,) views (read): draws views[view_index]
    view_index: int,
    sub_v: wp.array(dtype=wp.vec3),  # (6T,) (read)
    sub_bbox: wp.array(dtype=wp.vec4i),  # (2T,) (read)
    tile_end: wp.array(dtype=wp.int32),  # (2T,) inclusive scan of tile counts (read)
    n_sub: int,
    stride: int,
    layers: wp.array(dtype=wp.int32),  # (T,) layer bits per triangle (read)
    mask: int,  # layers drawn into ``visibility``
    visibility: wp.array(dtype=wp.uint64),  # (H*W,) packed depth | triangle id (atomic min)
    mask_b: int,  # layers drawn into ``visibility_b`` (0: none)
    visibility_b: wp.array(dtype=wp.uint64),  # (H*W,) a second layer's buffer (atomic min; unused when mask_b = 0)
):
    """:func:`raster_tiles` (its naive twin) with a thread per (item, pixel row of its tile), each with its own search
    (the 8 threads of an item read the same entries), a row proven outside an edge (:func:`_row_outside`) skipped: 8x
    the threads for the same items, for views with too few items to fill the GPU with a thread each (the pilots:
    ~20k items, a 64-pixel serial walk per thread). The same fragments: the buffers are raster_tiles' bit for bit on
    the CPU."""
    view = views[view_index]
    t = wp.tid()
    total = tile_end[n_sub - 1]
    while t < TILE * total:
        item = t / TILE
        r = t - item * TILE
        t += stride
        s, i_lo, i_hi, j_lo, j_hi = _tile_of_item(tile_end, n_sub, sub_bbox, item)
        j = (j_hi / TILE) * TILE + r
        if j < j_lo or j > j_hi:
            continue
        a, b, c, e0, e1, e2 = _item_edges(sub_v, s)
        box = wp.vec4i(i_lo, j_lo, i_hi, j_hi)
        x0 = float(i_lo) + 0.5
        x1 = float(i_hi) + 0.5
        y = float(j) + 0.5
        if (_row_outside(e0, _edge_slack(e0, box), y, x0, x1) or _row_outside(e1, _edge_slack(e1, box), y, x0, x1)
                or _row_outside(e2, _edge_slack(e2, box), y, x0, x1)):
            continue
        inv_area, tri, to_a, to_b = _item_setup(a, b, c, s, layers, mask, mask_b)
        _row_fragments(view, a, b, c, e0, e1, e2, inv_area, tri, to_a, to_b, j, i_lo, i_hi, visibility, visibility_b)


@wp.kernel
def raster_back_tiles(
    views: wp.array(dtype=ViewParams),  # (V,) views (read): draws views[view_index]
    view_index: int,
    sub_v: wp.array(dtype=wp.vec3),  # (6T,) of a set-up with back_only = 1 (read)
    sub_bbox: wp.array(dtype=wp.vec4i),  # (2T,) (read)
    tile_end: wp.array(dtype=wp.int32),  # (2T,) inclusive scan of tile counts (read)
    n_sub: int,
    stride: int,
    front_depth: wp.array(dtype=wp.float32),  # (H*W,) the resolved front layer's depth [m], 0 = none (read)
    visibility: wp.array(dtype=wp.uint64),  # (H*W,) packed depth | triangle id of the back layer (atomic min)
):
    """The back-face layer: as :func:`raster_tiles` (a thread per (sub-triangle, tile) item, the set-up having kept
    only the triangles that face away), but a fragment counts only at or behind the pixel's front surface
    (depth >= front depth), so the atomic min keeps the nearest back face behind it. Pixels with no front surface
    are skipped. One pass over the back-facing triangles of one layer; its own naive twin is
    ``raycast.raycast_back_depth`` (every triangle against every pixel's ray)."""
    view = views[view_index]
    item = wp.tid()
    total = tile_end[n_sub - 1]
    while item < total:
        s, i_lo, i_hi, j_lo, j_hi = _tile_of_item(tile_end, n_sub, sub_bbox, item)
        a = sub_v[3 * s + 0]
        b = sub_v[3 * s + 1]
        c = sub_v[3 * s + 2]
        inv_area = 1.0 / _edge(a, b, c[0], c[1])
        tri = wp.uint64(s / 2)
        for j in range(j_lo, j_hi + 1):
            y = float(j) + 0.5
            for i in range(i_lo, i_hi + 1):
                x = float(i) + 0.5
                p = j * view.width + i
                zf = front_depth[p]
                if zf > 0.0:
                    w0 = _shared_edge(b, c, x, y)
                    w1 = _shared_edge(c, a, x, y)
                    w2 = _shared_edge(a, b, x, y)
                    if w0 >= 0.0 and w1 >= 0.0 and w2 >= 0.0:
                        depth = fragment_depth(view, a, b, c, w0, w1, w2, inv_area)
                        if depth >= zf and depth <= view.far:
                            wp.atomic_min(visibility, p, depth_key(view, depth, tri))
        item += stride


@wp.func
def _sub_of_item(tile_end: wp.array(dtype=wp.int32), n_sub: int, item: int) -> int:
    """The sub-triangle whose tiles hold work item ``item``: the first ``s`` with ``tile_end[s] > item``."""
    lo = int(0)
    hi = n_sub - 1
    while lo < hi:
        mid = (lo + hi) / 2
        if tile_end[mid] > item:
            hi = mid
        else:
            lo = mid + 1
    return lo


@wp.func
def _tile_of_item(tile_end: wp.array(dtype=wp.int32), n_sub: int, sub_bbox: wp.array(dtype=wp.vec4i), item: int):
    """Work item ``item`` of a tiled raster pass: its sub-triangle ``s`` (:func:`_sub_of_item`) and the pixel
    range (i_lo, i_hi, j_lo, j_hi) of its tile, clipped to the sub-triangle's box."""
    s = _sub_of_item(tile_end, n_sub, item)
    start = int(0)
    if s > 0:
        start = tile_end[s - 1]
    box = sub_bbox[s]
    tx0 = box[0] / TILE
    ty0 = box[1] / TILE
    tw = box[2] / TILE - tx0 + 1
    local = item - start
    tx = tx0 + local % tw
    ty = ty0 + local / tw
    return (s, wp.max(tx * TILE, box[0]), wp.min(tx * TILE + TILE - 1, box[2]), wp.max(ty * TILE, box[1]),
            wp.min(ty * TILE + TILE - 1, box[3]))


#: bound on the rounding of :func:`_edge_at`, relative to the sum of its two products' magnitudes: the differences,
#: the products and the subtraction each round by at most 2^-24 relative, 4·2^-24 ≈ 2.4e-7 in all (less with a
#: fused multiply-add); ~4× that for room (the bound is itself computed in float32). See :func:`_edge_slack`
EDGE_ROUNDING = wp.constant(1.0e-6)


@wp.func
def _edge_slack(e: wp.vec4, box: wp.vec4i) -> float:
    """E: at every pixel centre of ``box`` the computed :func:`_edge_at` lies within E of the exact affine function
    G(x, y) = (q0 - p0)(y - p1) - (q1 - p1)(x - p0) of the edge's float32 ends. So along a column, where G is affine,
    every pixel's computed value is at most max(its two ends' computed values) + 2E: when that is below zero no pixel
    of the column can pass the edge test (:func:`raster_tile_columns` skips it). Overflow or NaN make that test
    False (the column is tested pixel by pixel)."""
    sy = wp.max(wp.abs(float(box[1]) + 0.5 - e[1]), wp.abs(float(box[3]) + 0.5 - e[1]))
    sx = wp.max(wp.abs(float(box[0]) + 0.5 - e[0]), wp.abs(float(box[2]) + 0.5 - e[0]))
    return EDGE_ROUNDING * (wp.abs(e[2]) * sy + wp.abs(e[3]) * sx) + 1.0e-30


@wp.func
def _column_outside(e: wp.vec4, slack: float, x: float, y0: float, y1: float) -> bool:
    """Whether no pixel centre (x, y), y in [y0, y1], passes the edge test ``_edge_at(e, x, y) >= 0``, proven from the
    column's two ends (:func:`_edge_slack`); False when it cannot be proven."""
    return wp.max(_edge_at(e, x, y0), _edge_at(e, x, y1)) < -2.0 * slack


#: threads of a warp: :func:`raster_tile_columns` gives each warp ``WARP_TILES`` adjacent tiles at a time
WARP = 32
WARP_TILES = WARP // TILE


@wp.kernel
def raster_tile_columns(
    views: wp.array(dtype=ViewParams),  # (V,) views (read): draws views[view_index]
    view_index: int,
    sub_v: wp.array(dtype=wp.vec3),  # (6T,) (read)
    sub_bbox: wp.array(dtype=wp.vec4i),  # (2T,) (read)
    tile_end: wp.array(dtype=wp.int32),  # (2T,) inclusive scan of tile counts (read)
    n_sub: int,
    warps: int,  # launched threads / WARP
    layers: wp.array(dtype=wp.int32),  # (T,) layer bits per triangle (read)
    mask: int,  # layers drawn into ``visibility``
    visibility: wp.array(dtype=wp.uint64),  # (H*W,) packed depth | triangle id (atomic min)
    mask_b: int,  # layers drawn into ``visibility_b`` (0: none)
    visibility_b: wp.array(dtype=wp.uint64),  # (H*W,) a second layer's buffer (atomic min; unused when mask_b = 0)
):
    """:func:`raster_tiles` (its twin) with ``TILE`` threads per (sub-triangle, tile) work item, one per pixel column
    of the tile, each walking its column down the tile's rows. A warp (``WARP`` consecutive threads) takes the
    consecutive items ``[w·per, (w+1)·per)`` (``per`` = items / warps, rounded up to a multiple of ``WARP_TILES``),
    ``WARP_TILES`` at a time: adjacent tiles of one sub-triangle, so its lanes test 32 adjacent pixels of a row
    together (one 256-byte run of atomics instead of 32 scattered pixels) and agree on the row loop. A column no
    pixel of which can pass one of the three edge tests (:func:`_column_outside`, from its two ends) is skipped:
    two thirds of the tiles of a triangle's bounding box lie outside it in the shipped scenes' views (long thin
    triangles), in runs along the tile rows, so a warp skips them together. One binary search per warp for its
    first item; its next items are the next tiles of the same sub-triangle (its edges kept) or of the next ones.
    Every pixel's coverage, depth and key come from the same operations on the same values as in
    :func:`raster_tiles` (:func:`_edge_terms`), and ``atomic_min`` does not depend on the order: the buffers are the
    same bit for bit."""
    view = views[view_index]
    t = wp.tid()
    w = t / WARP
    lane = t - w * WARP
    quad = lane / TILE  # this thread's tile of the warp's WARP_TILES
    col = lane - quad * TILE
    total = tile_end[n_sub - 1]
    per = ((total + warps - 1) / warps + WARP_TILES - 1) / WARP_TILES * WARP_TILES
    last = wp.min(w * per + per, total)
    item = w * per + quad
    if item >= last:
        return
    s = _sub_of_item(tile_end, n_sub, item)
    while item < last:  # one sub-triangle's items of this warp a round
        while tile_end[s] <= item:  # the next sub-triangle with tiles (culled ones have none)
            s += 1
        start = int(0)
        if s > 0:
            start = tile_end[s - 1]
        end = wp.min(tile_end[s], last)
        box = sub_bbox[s]
        a = sub_v[3 * s + 0]
        b = sub_v[3 * s + 1]
        c = sub_v[3 * s + 2]
        inv_area = 1.0 / _edge(a, b, c[0], c[1])
        e0 = _edge_terms(b, c)
        e1 = _edge_terms(c, a)
        e2 = _edge_terms(a, b)
        slack0 = _edge_slack(e0, box)
        slack1 = _edge_slack(e1, box)
        slack2 = _edge_slack(e2, box)
        tri = wp.uint64(s / 2)
        tri_layers = layers[s / 2]
        to_a = (tri_layers & mask) != 0
        to_b = (tri_layers & mask_b) != 0
        tx0 = box[0] / TILE
        tw = box[2] / TILE - tx0 + 1
        local = item - start
        tx = tx0 + local % tw
        ty = box[1] / TILE + local / tw
        while item < end:  # its tiles, row by row, WARP_TILES at a time
            i = tx * TILE + col
            j_lo = wp.max(ty * TILE, box[1])
            j_hi = wp.min(ty * TILE + TILE - 1, box[3])
            item += WARP_TILES
            tx += WARP_TILES
            while tx - tx0 >= tw:  # past the row of tiles: on to the next
                tx -= tw
                ty += 1
            if i < box[0] or i > box[2]:
                continue
            x = float(i) + 0.5
            y0 = float(j_lo) + 0.5
            y1 = float(j_hi) + 0.5
            if (_column_outside(e0, slack0, x, y0, y1) or _column_outside(e1, slack1, x, y0, y1)
                    or _column_outside(e2, slack2, x, y0, y1)):
                continue
            for j in range(j_lo, j_hi + 1):
                y = float(j) + 0.5
                w0 = _edge_at(e0, x, y)
                w1 = _edge_at(e1, x, y)
                w2 = _edge_at(e2, x, y)
                if w0 >= 0.0 and w1 >= 0.0 and w2 >= 0.0:
                    write_fragment(view, a, b, c, w0, w1, w2, inv_area, tri, to_a, to_b, j * view.width + i, visibility,
                                   visibility_b)


@wp.func
def take_key(visibility: wp.array(dtype=wp.uint64), p: int) -> wp.uint64:
    """Pixel ``p``'s visibility key, and the pixel reset to EMPTY_KEY: a resolve leaves its visibility buffer clear for
    the next draw, which then writes only the pixels it covers (no fill of the whole buffer per draw; a pixel no
    triangle covered is clear already and is not written)."""
    key = visibility[p]
    if key != EMPTY_KEY:
        visibility[p] = EMPTY_KEY
    return key


@wp.func
def still_empty(key: wp.uint64, tri_id: wp.array(dtype=wp.int32), p: int) -> bool:
    """Whether pixel ``p`` has no surface this frame (``key``) and had none when it was last resolved (``tri_id[p]``
    = -1): every attribute a resolve writes for an empty pixel is a constant, so they hold those values already and
    the resolve may skip the pixel's writes (sky, and the camera's water layer away from the water, every frame).
    Only for a resolve whose ``tri_id`` belongs to its attribute arrays alone (not ``resolve_depth``: the sky's maps
    share one triangle scratch)."""
    return key == EMPTY_KEY and tri_id[p] < 0


@wp.func
def interp_normal(tri: int, bary: wp.vec3, normals: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32)) -> wp.vec3:
    n = normals[indices[3 * tri]] * bary[0] + normals[indices[3 * tri + 1]] * bary[1] + normals[indices[3 * tri + 2]] * bary[2]
    return wp.normalize(n)


@wp.func
def _ray_barycentrics(o: wp.vec3, d: wp.vec3, tri: int, points: wp.array(dtype=wp.vec3),
                      indices: wp.array(dtype=wp.int32)):
    """The ray ``o + d·t``'s cut with triangle ``tri`` (Möller-Trumbore): (u, v, t, 1), or (0, 0, 0, 0) when the ray
    lies in the triangle's plane. :func:`triangle_hit` and :func:`texel_surface` share it, so their barycentrics are
    the same bits."""
    p0 = points[indices[3 * tri + 0]]
    p1 = points[indices[3 * tri + 1]]
    p2 = points[indices[3 * tri + 2]]
    e1 = p1 - p0
    e2 = p2 - p0
    pv = wp.cross(d, e2)
    det = wp.dot(e1, pv)
    if wp.abs(det) > 1.0e-30:
        inv = 1.0 / det
        s = o - p0
        u = wp.dot(s, pv) * inv
        qv = wp.cross(s, e1)
        v = wp.dot(d, qv) * inv
        return u, v, wp.dot(e2, qv) * inv, int(1)
    return float(0.0), float(0.0), float(0.0), int(0)


@wp.func
def _clamped_barycentrics(u: float, v: float) -> wp.vec3:
    """Barycentrics (1 − u − v, u, v) clamped onto the triangle (:func:`triangle_hit`'s)."""
    b1 = wp.clamp(u, 0.0, 1.0)
    b2 = wp.clamp(v, 0.0, 1.0)
    b0 = wp.max(1.0 - b1 - b2, 0.0)
    sb = b0 + b1 + b2
    return wp.vec3(b0, b1, b2) / sb


@wp.func
def triangle_hit(view: ViewParams, key: wp.uint64, pixel: int, points: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32)):
    """Exact hit of a pixel's ray with the triangle of a visibility key.

    Returns (triangle id or -1, depth [m], world position [m], clamped barycentrics, ray direction).
    """
    px = float(pixel % view.width) + 0.5
    py = float(pixel / view.width) + 0.5
    o, d = pixel_ray_world(view, px, py)
    if key == EMPTY_KEY:
        return int(-1), float(0.0), wp.vec3(0.0), wp.vec3(0.0), d
    tri = int(key & wp.uint64(0xFFFFFFFF))
    u, v, t, ok = _ray_barycentrics(o, d, tri, points, indices)
    if ok == 0:  # ray in the triangle's plane: fall back to the raster's depth (u = v = 0)
        t = key_depth(view, key)
    return tri, t, o + d * t, _clamped_barycentrics(u, v), d


@wp.func
def texel_surface(view: ViewParams, pixel: int, tri: int, t: float, points: wp.array(dtype=wp.vec3),
                  normals: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32)):
    """The world point [m] and authored unit normal a specular resolve (:func:`specular_texel_key`) writes for pixel
    ``pixel`` of ``view`` whose triangle is ``tri`` (>= 0) at depth ``t`` [m] (the layer's ``depth``), computed from
    them with :func:`triangle_hit`'s arithmetic, the same bits: the point ``o + d·t`` on the pixel centre's ray, the
    normal interpolated at the clamped barycentrics of the ray's cut with ``tri`` ((1, 0, 0) for a ray in its plane).
    Lets a reader of an RSM view that keeps no ``position`` and ``normal`` (LightMaps.keep_surface_maps) have them.
    Reads the triangle's vertices and normals (``t`` unused for the normal alone: the compiler drops the point)."""
    px = float(pixel % view.width) + 0.5
    py = float(pixel / view.width) + 0.5
    o, d = pixel_ray_world(view, px, py)
    u, v, t_hit, ok = _ray_barycentrics(o, d, tri, points, indices)
    return o + d * t, interp_normal(tri, _clamped_barycentrics(u, v), normals, indices)


@wp.func
def facing_normal(n: wp.vec3, tri: int, d: wp.vec3, points: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32)) -> wp.vec3:
    """Flip shading normal ``n`` to the side of the triangle the ray ``d`` arrives from (two-sided surfaces)."""
    p0 = points[indices[3 * tri]]
    ng = wp.cross(points[indices[3 * tri + 1]] - p0, points[indices[3 * tri + 2]] - p0)
    if wp.dot(ng, d) > 0.0:
        ng = -ng
    if wp.dot(n, ng) < 0.0:
        return -n
    return n


@wp.kernel
def resolve_depth(
    views: wp.array(dtype=ViewParams),  # (V,) views (read): draws views[view_index]
    view_index: int,
    visibility: wp.array(dtype=wp.uint64),  # (H*W,) (read, then reset to EMPTY_KEY for the next draw)
    points: wp.array(dtype=wp.vec3),
    indices: wp.array(dtype=wp.int32),
    depth: wp.array(dtype=wp.float32),  # (H*W,) linear depth [m], 0 = no surface (write)
    tri_id: wp.array(dtype=wp.int32),  # (H*W,) triangle id, -1 = none (write; an empty array: not wanted)
):
    """Depth and triangle of the nearest surface per pixel. Resets the visibility it read, so the next draw into it
    needs no clear (``Rasterizer.draw(clear=False)``); an inactive view drew nothing and leaves it as it was."""
    view = views[view_index]
    if view.far <= 0.0:  # an inactive view (light_maps.INACTIVE_FAR): nothing drawn, its maps are not read
        return
    p = wp.tid()
    tri, t, x, bary, d = triangle_hit(view, take_key(visibility, p), p, points, indices)
    depth[p] = t
    if tri_id.shape[0] > 0:
        tri_id[p] = tri


@wp.kernel
def resolve_back(
    views: wp.array(dtype=ViewParams),  # (V,) views (read): draws views[view_index]
    view_index: int,
    visibility: wp.array(dtype=wp.uint64),  # (H*W,) back layer of :func:`raster_back_tiles` (read, then reset)
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    indices: wp.array(dtype=wp.int32),
    front_tri: wp.array(dtype=wp.int32),  # (H*W,) the front layer's triangle, -1 = none (read)
    depth_layers: wp.array(dtype=wp.float32),  # (2·H*W,) front depth [m] (read), then the back depth (write)
):
    """Depth of the nearest back face behind the front surface per pixel, into ``depth_layers[H*W + p]`` (0 = none:
    no back face behind, or a front surface that itself faces away, seen from its inside: an open surface or a
    sheet, whose back layer would be the surface itself). The exact ray hit, as :func:`resolve_depth`, not below
    the front depth (the raster's fragment depth and the exact hit round differently)."""
    view = views[view_index]
    if view.far <= 0.0:
        return
    p = wp.tid()
    back_texel(view, p, visibility, points, normals, indices, front_tri, depth_layers)


@wp.func
def back_texel(view: ViewParams, p: int, visibility: wp.array(dtype=wp.uint64), points: wp.array(dtype=wp.vec3),
               normals: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32), front_tri: wp.array(dtype=wp.int32),
               depth_layers: wp.array(dtype=wp.float32)) -> float:
    """Resolve pixel ``p`` of the back-face layer (see :func:`resolve_back`); returns the back depth it wrote."""
    n = view.width * view.height
    tri, t, x, bary, d = triangle_hit(view, take_key(visibility, p), p, points, indices)
    zb = float(0.0)
    ft = front_tri[p]
    if tri >= 0 and ft >= 0:
        if not faces_away(view, ft, points, normals, indices):
            zb = wp.max(t, depth_layers[p])
    depth_layers[n + p] = zb
    return zb


@wp.func
def opaque_texel(
    view: ViewParams,
    prev_view: ViewParams,
    p: int,
    key: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    prev_points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    indices: wp.array(dtype=wp.int32),
    triangle_material: wp.array(dtype=wp.int32),
    mat_albedo: wp.array(dtype=wp.vec3),
    mat_roughness: wp.array(dtype=wp.float32),
    depth: wp.array(dtype=wp.float32),
    position: wp.array(dtype=wp.vec3),
    normal: wp.array(dtype=wp.vec3),
    albedo: wp.array(dtype=wp.vec3),
    roughness: wp.array(dtype=wp.float32),
    tri_id: wp.array(dtype=wp.int32),
    motion: wp.array(dtype=wp.vec2),
) -> float:
    """Pixel ``p`` of the opaque G-buffer from its key, taken already (see :func:`resolve_opaque`). Returns its depth
    [m] (0 = none; also for a pixel that stays empty, whose stored depth is 0 and is not written)."""
    if still_empty(key, tri_id, p):
        return 0.0
    tri, t, x, bary, d = triangle_hit(view, key, p, points, indices)
    tri_id[p] = tri
    depth[p] = t
    if tri < 0:
        position[p] = wp.vec3(0.0)
        normal[p] = wp.vec3(0.0)
        albedo[p] = wp.vec3(0.0)
        roughness[p] = 0.0
        motion[p] = wp.vec2(0.0)
        return t
    position[p] = x
    normal[p] = facing_normal(interp_normal(tri, bary, normals, indices), tri, d, points, indices)
    m = triangle_material[tri]
    albedo[p] = mat_albedo[m]
    roughness[p] = mat_roughness[m]
    i0 = indices[3 * tri]
    i1 = indices[3 * tri + 1]
    i2 = indices[3 * tri + 2]
    x_prev = prev_points[i0] * bary[0] + prev_points[i1] * bary[1] + prev_points[i2] * bary[2]
    q = view_project(prev_view, view_point(prev_view, x_prev))
    motion[p] = wp.vec2(q[0] - (float(p % view.width) + 0.5), q[1] - (float(p / view.width) + 0.5))
    return t


@wp.kernel
def resolve_opaque(
    views: wp.array(dtype=ViewParams),  # (V,) views (read): draws views[view_index]
    view_index: int,
    prev_view_index: int,  # views[prev_view_index]: the previous frame's camera, for motion
    visibility: wp.array(dtype=wp.uint64),  # (H*W,) (read, then reset to EMPTY_KEY for the next draw)
    points: wp.array(dtype=wp.vec3),  # (V,) [m] (read)
    prev_points: wp.array(dtype=wp.vec3),  # (V,) previous frame [m] (read)
    normals: wp.array(dtype=wp.vec3),
    indices: wp.array(dtype=wp.int32),
    triangle_material: wp.array(dtype=wp.int32),
    mat_albedo: wp.array(dtype=wp.vec3),
    mat_roughness: wp.array(dtype=wp.float32),
    depth: wp.array(dtype=wp.float32),  # (H*W,) linear depth [m], 0 = none (write)
    position: wp.array(dtype=wp.vec3),  # (H*W,) world position [m] (write)
    normal: wp.array(dtype=wp.vec3),  # (H*W,) unit normal facing the view (write)
    albedo: wp.array(dtype=wp.vec3),  # (H*W,) (write)
    roughness: wp.array(dtype=wp.float32),  # (H*W,) (write)
    tri_id: wp.array(dtype=wp.int32),  # (H*W,) (write)
    motion: wp.array(dtype=wp.vec2),  # (H*W,) pixel offset to where this surface point was last frame (write)
):
    """Opaque G-buffer: every attribute of the nearest opaque surface per pixel (visibility reset as it is read). With
    ``resolve_specular`` after it, the naive twin of :func:`resolve_camera`."""
    view = views[view_index]
    prev_view = views[prev_view_index]
    p = wp.tid()
    opaque_texel(view, prev_view, p, take_key(visibility, p), points, prev_points, normals, indices,
                 triangle_material, mat_albedo, mat_roughness, depth, position, normal, albedo, roughness, tri_id,
                 motion)


@wp.kernel
def resolve_camera(
    views: wp.array(dtype=ViewParams),  # (V,) views (read): draws views[view_index]
    view_index: int,
    prev_view_index: int,  # views[prev_view_index]: the previous frame's camera, for motion
    visibility: wp.array(dtype=wp.uint64),  # (H*W,) opaque layer (read, then reset to EMPTY_KEY)
    visibility_b: wp.array(dtype=wp.uint64),  # (H*W,) specular layer (read, then reset to EMPTY_KEY)
    points: wp.array(dtype=wp.vec3),
    prev_points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    indices: wp.array(dtype=wp.int32),
    triangle_material: wp.array(dtype=wp.int32),
    mat_albedo: wp.array(dtype=wp.vec3),
    mat_roughness: wp.array(dtype=wp.float32),
    mat_ior: wp.array(dtype=wp.float32),
    depth: wp.array(dtype=wp.float32),  # resolve_opaque's outputs (write)
    position: wp.array(dtype=wp.vec3),
    normal: wp.array(dtype=wp.vec3),
    albedo: wp.array(dtype=wp.vec3),
    roughness: wp.array(dtype=wp.float32),
    tri_id: wp.array(dtype=wp.int32),
    motion: wp.array(dtype=wp.vec2),
    w_depth: wp.array(dtype=wp.float32),  # resolve_specular's outputs for the water layer (write)
    w_position: wp.array(dtype=wp.vec3),
    w_normal: wp.array(dtype=wp.vec3),
    w_roughness: wp.array(dtype=wp.float32),
    w_ior: wp.array(dtype=wp.float32),
    w_tri_id: wp.array(dtype=wp.int32),
    nearest_depth: wp.array(dtype=wp.float32),  # as resolve_specular's (an empty array: not wanted)
):
    """The camera's opaque G-buffer and its water layer in one pass (``GBuffer.fused_resolve``): both keys read
    together, then ``resolve_opaque``'s pixel and ``resolve_specular``'s with the opaque depth from a register
    instead of read back; the same buffers bit for bit as those twins one after the other."""
    view = views[view_index]
    prev_view = views[prev_view_index]
    p = wp.tid()
    key = visibility[p]
    key_b = visibility_b[p]
    if key != EMPTY_KEY:
        visibility[p] = EMPTY_KEY
    if key_b != EMPTY_KEY:
        visibility_b[p] = EMPTY_KEY
    od = opaque_texel(view, prev_view, p, key, points, prev_points, normals, indices, triangle_material, mat_albedo,
                      mat_roughness, depth, position, normal, albedo, roughness, tri_id, motion)
    specular_texel_key(view, p, key_b, od, points, normals, indices, triangle_material, mat_roughness, mat_ior,
                       w_depth, w_position, w_normal, w_roughness, w_ior, w_tri_id, nearest_depth)


@wp.func
def specular_texel(
    view: ViewParams,
    p: int,
    visibility: wp.array(dtype=wp.uint64),
    opaque_depth: wp.array(dtype=wp.float32),
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    indices: wp.array(dtype=wp.int32),
    triangle_material: wp.array(dtype=wp.int32),
    mat_roughness: wp.array(dtype=wp.float32),
    mat_ior: wp.array(dtype=wp.float32),
    depth: wp.array(dtype=wp.float32),
    position: wp.array(dtype=wp.vec3),
    normal: wp.array(dtype=wp.vec3),
    roughness: wp.array(dtype=wp.float32),
    ior: wp.array(dtype=wp.float32),
    tri_id: wp.array(dtype=wp.int32),
    nearest_depth: wp.array(dtype=wp.float32),
) -> int:
    """Resolve pixel ``p`` of a specular layer (see :func:`resolve_specular`). Returns its triangle (-1 none), or -2
    when the pixel was empty and stays empty (nothing written but ``nearest_depth``)."""
    return specular_texel_key(view, p, take_key(visibility, p), opaque_depth[p], points, normals, indices,
                              triangle_material, mat_roughness, mat_ior, depth, position, normal, roughness, ior, tri_id,
                              nearest_depth)


@wp.func
def specular_texel_key(
    view: ViewParams,
    p: int,
    key: wp.uint64,
    od: float,
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    indices: wp.array(dtype=wp.int32),
    triangle_material: wp.array(dtype=wp.int32),
    mat_roughness: wp.array(dtype=wp.float32),
    mat_ior: wp.array(dtype=wp.float32),
    depth: wp.array(dtype=wp.float32),
    position: wp.array(dtype=wp.vec3),
    normal: wp.array(dtype=wp.vec3),
    roughness: wp.array(dtype=wp.float32),
    ior: wp.array(dtype=wp.float32),
    tri_id: wp.array(dtype=wp.int32),
    nearest_depth: wp.array(dtype=wp.float32),
) -> int:
    """:func:`specular_texel` with the pixel's key taken already (its visibility reset by the caller) and its opaque
    depth ``od`` [m] given (0 = none) instead of read."""
    if still_empty(key, tri_id, p):
        if nearest_depth.shape[0] > 0:
            nearest_depth[p] = od
        return -2
    tri, t, x, bary, d = triangle_hit(view, key, p, points, indices)
    if tri >= 0 and od > 0.0 and t > od * 1.00001:  # behind an opaque surface (a mirror is both layers)
        tri = -1
    tri_id[p] = tri
    if nearest_depth.shape[0] > 0:
        nearest_depth[p] = wp.where(tri >= 0 and t > 0.0, t, od)
    surface = position.shape[0] > 0  # the point and normal kept (else texel_surface gives them from tri_id, depth)
    material = roughness.shape[0] > 0  # the material kept (else texel_roughness and texel_ior give it from tri_id)
    if tri < 0:
        depth[p] = 0.0
        if surface:
            position[p] = wp.vec3(0.0)
            normal[p] = wp.vec3(0.0)
        if material:
            roughness[p] = 0.0
            ior[p] = 1.0
        return -1
    depth[p] = t
    if surface:
        position[p] = x
        normal[p] = interp_normal(tri, bary, normals, indices)
    if material:
        m = triangle_material[tri]
        roughness[p] = mat_roughness[m]
        ior[p] = mat_ior[m]
    return tri


@wp.kernel
def resolve_specular(
    views: wp.array(dtype=ViewParams),  # (V,) views (read): draws views[view_index]
    view_index: int,
    visibility: wp.array(dtype=wp.uint64),  # (H*W,) specular layer (read, then reset to EMPTY_KEY for the next draw)
    opaque_depth: wp.array(dtype=wp.float32),  # (H*W,) opaque layer depth, 0 = none (read)
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    indices: wp.array(dtype=wp.int32),
    triangle_material: wp.array(dtype=wp.int32),
    mat_roughness: wp.array(dtype=wp.float32),
    mat_ior: wp.array(dtype=wp.float32),
    depth: wp.array(dtype=wp.float32),  # (H*W,) [m], 0 = none or hidden behind opaque (write)
    position: wp.array(dtype=wp.vec3),  # (H*W,) [m] (write)
    normal: wp.array(dtype=wp.vec3),  # (H*W,) authored (outward) unit normal, not flipped (write)
    roughness: wp.array(dtype=wp.float32),  # (H*W,) (write)
    ior: wp.array(dtype=wp.float32),  # (H*W,) (write)
    tri_id: wp.array(dtype=wp.int32),  # (H*W,) -1 = none (write)
    nearest_depth: wp.array(dtype=wp.float32),  # (H*W,) depth of the nearest surface of either layer [m], 0 = none
    # (write; an empty array: not wanted)
):
    """Specular layer (RSM specular texels, camera water layer): nearest specular surface in front of the opaque one
    (visibility reset as it is read); and, where wanted, the nearest surface of either layer (an RSM's shadow depth)."""
    view = views[view_index]
    if view.far <= 0.0:  # an inactive view (light_maps.INACTIVE_FAR): nothing drawn, its maps are not read
        return
    p = wp.tid()
    specular_texel(view, p, visibility, opaque_depth, points, normals, indices, triangle_material, mat_roughness,
                   mat_ior, depth, position, normal, roughness, ior, tri_id, nearest_depth)


@wp.func
def spot_falloff(cos_angle: float, cone_angle: float, softness: float) -> float:
    """Spot cone profile: 1 inside ``cone_angle·(1 − softness)``, smoothstep to 0 at ``cone_angle``."""
    angle = wp.acos(wp.clamp(cos_angle, -1.0, 1.0))
    if angle >= cone_angle:
        return 0.0
    inner = cone_angle * (1.0 - wp.clamp(softness, 0.0, 1.0))
    if angle <= inner:
        return 1.0
    s = (cone_angle - angle) / (cone_angle - inner)
    return s * s * (3.0 - 2.0 * s)


# The spot's falloff without its acos where the cosine decides it (docs/perf_notes.md section 70): a cosine at or
# above ``spot_cone_cosines``' inner bound proves ``spot_falloff`` 1 (the angle inside ``cone_angle·(1 − softness)``),
# at or below its outer bound 0 (the angle beyond ``cone_angle``), so its acos, branches and smoothstep are skipped
# there and the value is the same bits; between them (the smoothstep's band) ``spot_falloff`` as before.
SPOT_COS_MARGIN = 2.0 ** -12  #: the proofs' relative margin on the angles: far above acosf's 2 ulps (2^-22)
SPOT_COS_NONE = 2.0  #: a bound no cosine reaches (an outer bound is its negation): nothing proven


def _f32_cos(angle: float, up: bool) -> float:
    """cos(angle) in float64, rounded to float32 up (``up``) or down: a bound on the side the proof needs."""
    c = math.cos(angle)
    c32 = np.float32(c)
    if (float(c32) < c) if up else (float(c32) > c):
        c32 = np.nextafter(c32, np.float32(2.0 if up else -2.0))
    return float(c32)


def spot_cone_cosines(cone_angle: float, softness: float) -> tuple[float, float]:
    """(c_in, c_out), float32 cosines with ``spot_falloff(c, cone_angle, softness)`` = 1 for c >= c_in and 0 for
    c <= c_out, proven. The angles are the kernel's float32 ``cone_angle`` and inner angle ``cone_angle·(1 − clamp(
    softness))`` as :func:`spot_falloff` computes it; c_in is the cosine of the inner angle less a relative
    ``SPOT_COS_MARGIN`` rounded up, c_out that of the cone angle plus the margin rounded down. For c >= c_in,
    acos(c) <= inner·(1 − 2^-12), and a float acos within 2^-21 of it lies below the inner angle (at most the cone
    angle): both of ``spot_falloff``'s tests give 1. For c <= c_out, acos(clamp(c)) >= cone·(1 + 2^-12) and its float
    above the cone angle: 0. ``SPOT_COS_NONE`` (its negation for c_out) where an angle is not positive or the outer
    one passes π (nothing proven there)."""
    cone = np.float32(cone_angle)
    inner = cone * (np.float32(1.0) - np.clip(np.float32(softness), np.float32(0.0), np.float32(1.0)))
    c_in = _f32_cos(float(inner) * (1.0 - SPOT_COS_MARGIN), up=True) if inner > 0.0 else SPOT_COS_NONE
    outer = float(cone) * (1.0 + SPOT_COS_MARGIN)
    c_out = _f32_cos(outer, up=False) if 0.0 < outer < math.pi else -SPOT_COS_NONE
    return c_in, c_out


@wp.func
def spot_falloff_proven(cos_angle: float, cos_inner: float, cos_outer: float, cone_angle: float,
                        softness: float) -> float:
    """:func:`spot_falloff` (its naive twin) decided from the cosine where it can be: 1 where ``cos_angle >=
    cos_inner``, 0 where ``cos_angle <= cos_outer`` (``spot_cone_cosines`` of the same cone), ``spot_falloff``
    between; the same bits everywhere."""
    if cos_angle >= cos_inner:
        return 1.0
    if cos_angle <= cos_outer:
        return 0.0
    return spot_falloff(cos_angle, cone_angle, softness)


@wp.func
def texel_flux(
    view: ViewParams,
    p: int,
    light_rgb: wp.vec3,
    spot_axis: wp.vec3,
    is_spot: int,
    cone_angle: float,
    cone_softness: float,
    texel_solid_angle: wp.array(dtype=wp.float32),
) -> wp.vec3:
    """Flux [W] the light sends through RSM texel ``p`` onto a surface: irradiance × texel area (orthographic),
    intensity × texel solid angle (perspective), times the spot's falloff."""
    if view.orthographic != 0:
        return light_rgb / (view.fx * view.fy)
    scale = texel_solid_angle[p]
    if is_spot != 0:
        o, d = pixel_ray_world(view, float(p % view.width) + 0.5, float(p / view.width) + 0.5)
        scale = scale * spot_falloff(wp.dot(wp.normalize(d), spot_axis), cone_angle, cone_softness)
    return light_rgb * scale


@wp.func
def texel_flux_proven(
    view: ViewParams,
    p: int,
    i: int,  # the texel's column and row (p = j·view.width + i), which the caller knows
    j: int,
    light_rgb: wp.vec3,
    spot_axis: wp.vec3,
    is_spot: int,
    cone_angle: float,
    cone_softness: float,
    cos_inner: float,
    cos_outer: float,
    texel_solid_angle: wp.array(dtype=wp.float32),
) -> wp.vec3:
    """:func:`texel_flux` (its naive twin, the resolves') of texel ``p`` at column ``i``, row ``j`` (no integer division
    of ``p``), with the spot's falloff through :func:`spot_falloff_proven` ((``cos_inner``, ``cos_outer``) =
    ``spot_cone_cosines`` of the cone: no acos inside the inner cone or beyond the cone): the same bits."""
    if view.orthographic != 0:
        return light_rgb / (view.fx * view.fy)
    scale = texel_solid_angle[p]
    if is_spot != 0:
        o, d = pixel_ray_world(view, float(i) + 0.5, float(j) + 0.5)
        c = wp.dot(wp.normalize(d), spot_axis)
        scale = scale * spot_falloff_proven(c, cos_inner, cos_outer, cone_angle, cone_softness)
    return light_rgb * scale


@wp.struct
class TexelEmission:
    """What an RSM view's specular texel's flux, roughness and IOR are computed from where they are read, instead of
    per-texel maps written by the resolve (docs/perf_notes.md section 58): the light's terms of
    :func:`texel_flux` and the scene's materials. One per RSM view (``LightMaps.emission``)."""

    light_rgb: wp.vec3  # irradiance [W/m²] (distant) or intensity [W/sr] (point, spot), per channel
    spot_axis: wp.vec3  # world direction of the spot axis (unused unless is_spot)
    is_spot: int
    cone_angle: float  # [rad]
    cone_softness: float
    cone_cos_inner: float  # spot_cone_cosines(cone_angle, cone_softness): the falloff is 1 from this cosine up,
    cone_cos_outer: float  # 0 from this one down (a spot must set both: zeros prove wrong values)
    texel_solid_angle: wp.array(dtype=wp.float32)  # (H*W,) [sr] of the view's texels, perspective views (read)
    triangle_material: wp.array(dtype=wp.int32)  # (T,) material per triangle (read)
    mat_roughness: wp.array(dtype=wp.float32)  # (M,) per material (read)
    mat_ior: wp.array(dtype=wp.float32)  # (M,) per material (read)


@wp.func
def texel_emitted_flux(e: TexelEmission, view: ViewParams, p: int) -> wp.vec3:
    """Flux [W] through specular texel ``p`` of ``view`` (its triangle >= 0): the bits the resolve's
    :func:`texel_flux` writes into a kept ``flux`` map (the same function of the same values)."""
    i = int(0)
    j = int(0)
    if e.is_spot != 0 and view.orthographic == 0:  # only the spot's falloff reads them (a view may have no width)
        i = p % view.width
        j = p / view.width
    return texel_flux_proven(view, p, i, j, e.light_rgb, e.spot_axis, e.is_spot, e.cone_angle, e.cone_softness,
                             e.cone_cos_inner, e.cone_cos_outer, e.texel_solid_angle)


@wp.func
def texel_emitted_flux_at(e: TexelEmission, view: ViewParams, p: int, i: int, j: int) -> wp.vec3:
    """:func:`texel_emitted_flux` of texel ``p`` = ``j·view.width + i`` (0 <= i < width, j >= 0) where the caller has
    its column ``i`` and row ``j``: the same bits, without their integer division (the emission's samples)."""
    return texel_flux_proven(view, p, i, j, e.light_rgb, e.spot_axis, e.is_spot, e.cone_angle, e.cone_softness,
                             e.cone_cos_inner, e.cone_cos_outer, e.texel_solid_angle)


@wp.func
def texel_roughness(e: TexelEmission, tri: int) -> float:
    """Roughness of a specular texel whose triangle is ``tri`` >= 0 (what a kept ``roughness`` map holds)."""
    return e.mat_roughness[e.triangle_material[tri]]


@wp.func
def texel_ior(e: TexelEmission, tri: int) -> float:
    """IOR behind a specular texel whose triangle is ``tri`` >= 0 (what a kept ``ior`` map holds)."""
    return e.mat_ior[e.triangle_material[tri]]


@wp.kernel
def rsm_flux(
    views: wp.array(dtype=ViewParams),  # (V,) views (read): draws views[view_index]
    view_index: int,
    light_rgb: wp.vec3,  # irradiance [W/m²] (distant) or intensity [W/sr] (point, spot), per channel
    spot_axis: wp.vec3,  # world direction of the spot axis (unused unless is_spot)
    is_spot: int,
    cone_angle: float,
    cone_softness: float,
    texel_solid_angle: wp.array(dtype=wp.float32),  # (H*W,) [sr], perspective views (read)
    tri_id: wp.array(dtype=wp.int32),  # (H*W,) specular layer (read)
    flux: wp.array(dtype=wp.vec3),  # (H*W,) power the light sends through the texel onto the surface [W] (write)
):
    """Flux per RSM texel of a resolved specular layer (the twin of :func:`resolve_rsm_specular`'s flux)."""
    view = views[view_index]
    if view.far <= 0.0:  # an inactive view (light_maps.INACTIVE_FAR): nothing drawn, its maps are not read
        return
    p = wp.tid()
    if tri_id[p] < 0:
        flux[p] = wp.vec3(0.0)
        return
    flux[p] = texel_flux(view, p, light_rgb, spot_axis, is_spot, cone_angle, cone_softness, texel_solid_angle)


@wp.kernel
def resolve_rsm_specular(
    views: wp.array(dtype=ViewParams),  # (V,) views (read): draws views[view_index]
    view_index: int,
    visibility: wp.array(dtype=wp.uint64),  # (H*W,) specular layer (read, then reset to EMPTY_KEY for the next draw)
    opaque_depth: wp.array(dtype=wp.float32),  # (H*W,) opaque layer depth, 0 = none (read)
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    indices: wp.array(dtype=wp.int32),
    triangle_material: wp.array(dtype=wp.int32),
    mat_roughness: wp.array(dtype=wp.float32),
    mat_ior: wp.array(dtype=wp.float32),
    light_rgb: wp.vec3,  # irradiance [W/m²] (distant) or intensity [W/sr] (point, spot), per channel
    spot_axis: wp.vec3,  # world direction of the spot axis (unused unless is_spot)
    is_spot: int,
    cone_angle: float,
    cone_softness: float,
    texel_solid_angle: wp.array(dtype=wp.float32),  # (H*W,) [sr], perspective views (read)
    depth: wp.array(dtype=wp.float32),  # (H*W,) [m], 0 = none or hidden behind opaque (write)
    position: wp.array(dtype=wp.vec3),  # (H*W,) [m] (write)
    normal: wp.array(dtype=wp.vec3),  # (H*W,) authored (outward) unit normal, not flipped (write)
    roughness: wp.array(dtype=wp.float32),  # (H*W,) (write; an empty array, with ior: not wanted, texel_roughness)
    ior: wp.array(dtype=wp.float32),  # (H*W,) (write; empty with roughness: texel_ior gives it)
    tri_id: wp.array(dtype=wp.int32),  # (H*W,) -1 = none (write)
    nearest_depth: wp.array(dtype=wp.float32),  # (H*W,) the RSM's shadow depth [m], 0 = none (write)
    flux: wp.array(dtype=wp.vec3),  # (H*W,) power the light sends through the texel onto the surface [W] (write; an
    # empty array: not wanted, texel_emitted_flux gives it)
):
    """An RSM view's specular layer (:func:`resolve_specular`), its shadow depth and its flux per texel
    (:func:`rsm_flux`) in one pass: the texel's triangle is known where its flux is computed."""
    view = views[view_index]
    if view.far <= 0.0:  # an inactive view (light_maps.INACTIVE_FAR): nothing drawn, its maps are not read
        return
    p = wp.tid()
    tri = specular_texel(view, p, visibility, opaque_depth, points, normals, indices, triangle_material, mat_roughness,
                         mat_ior, depth, position, normal, roughness, ior, tri_id, nearest_depth)
    if flux.shape[0] == 0:  # not kept: texel_emitted_flux gives it from tri_id
        return
    if tri == -1:
        flux[p] = wp.vec3(0.0)
    elif tri >= 0:  # (-2: empty as before, its flux is zero already)
        flux[p] = texel_flux(view, p, light_rgb, spot_axis, is_spot, cone_angle, cone_softness, texel_solid_angle)


#: threads of a block of :func:`resolve_rsm_view` and :func:`resolve_back_view` on CUDA (the CPU runs a block as one
#: lane)
RESOLVE_THREADS = 256
#: blocks of :func:`resolve_back_view` resident per SM, its launch bound: 64 registers, no stack (sm_90 cubin,
#: ``tools/regcount.py --modules cisp_warp.raster.kernels``)
RESOLVE_BLOCKS_PER_SM = 4
#: the same for :func:`resolve_rsm_view`: 80 registers and no stack at 3 blocks; at 4, 64 registers and 56 B of stack,
#: which measured 3% slower on the H100 (docs/perf_notes.md section 33)
RESOLVE_RSM_BLOCKS_PER_SM = 3
#: texels of one block of :func:`resolve_rsm_view`: one coarse cell of the depth bounds, BOUNDS_COARSE² texels
RESOLVE_TEXELS = wp.constant(1024)
#: texels a thread resolves before the block puts their depths into shared memory (RESOLVE_TEXELS / RESOLVE_THREADS)
RESOLVE_TEXELS_PER_THREAD = wp.constant(4)
#: fine cells across (and down) a coarse cell, and the 8-texel row segments of a coarse cell
_FINE_PER_COARSE = wp.constant(4)
_SEGMENTS = wp.constant(128)
_FINE_CELLS = wp.constant(16)


@wp.func
def _scatter_texel(zs: wp.tile(dtype=wp.float32, shape=(1024,)), c0: int, m: int, threads: int, lane: int, x0: int,
                   y0: int, width: int, height: int, z: float):
    """Texel ``c0 + m·threads + lane`` of the block's coarse cell: its depth ``z`` into ``zs`` when it is in the
    view (every thread of the block calls it: it synchronises the block)."""
    k = c0 + m * threads + lane
    x = x0 + k % BOUNDS_COARSE
    y = y0 + k / BOUNDS_COARSE
    wp.tile_scatter_masked(zs, k, z, k < RESOLVE_TEXELS and x < width and y < height)


@wp.func
def _block_bounds(
    zs: wp.tile(dtype=wp.float32, shape=(1024,)),  # the block's texels' depths [m], 0 = none (shared, row-major)
    back: wp.tile(dtype=wp.float32, shape=(1024,)),  # their back-face layer's depths [m] (read when has_back)
    has_back: bool,
    lane: int,
    threads: int,
    block: int,  # the coarse cell: BOUNDS_COARSE² texels from (x0, y0)
    width: int,
    height: int,
    thickness: float,
    thickness_rel: float,
    bounds: wp.array(dtype=wp.vec2),  # (march.bounds_size,) the coarse cell and its fine cells (write)
):
    """The depth bounds of one coarse cell from its texels' depths in shared memory: its 16 fine cells as
    ``photons.march.depth_bounds`` writes them and the coarse cell as ``coarsen_bounds`` does, the same values bit
    for bit (min and max of depths that are never NaN do not depend on the order they are taken in). Every thread
    of the block calls it (it synchronises the block)."""
    cw = (width + BOUNDS_COARSE - 1) / BOUNDS_COARSE
    x0 = (block % cw) * BOUNDS_COARSE
    y0 = (block / cw) * BOUNDS_COARSE
    # 128 row segments of 8 texels (row r of the coarse cell, fine column c): their nearest depth and farthest back
    # face over the texels in the view, as march.depth_bounds folds them (a hole counts as BIG_DEPTH)
    seg_near = wp.tile_empty(shape=_SEGMENTS, dtype=wp.float32, storage="shared")
    seg_far = wp.tile_empty(shape=_SEGMENTS, dtype=wp.float32, storage="shared")
    for s0 in range(0, _SEGMENTS, threads):
        s = s0 + lane
        z_min = float(BIG_DEPTH)
        z_max = float(0.0)
        if s < _SEGMENTS:
            y = y0 + s / _FINE_PER_COARSE
            xs = x0 + (s % _FINE_PER_COARSE) * BOUNDS_CELL
            if y < height:
                first = (s / _FINE_PER_COARSE) * BOUNDS_COARSE + (s % _FINE_PER_COARSE) * BOUNDS_CELL
                for di in range(wp.min(BOUNDS_CELL, width - xs)):  # the texels in the view (a loop kept rolled)
                    z = zs[first + di]
                    if z <= 0.0:
                        z = BIG_DEPTH
                    z_min = wp.min(z_min, z)
                    z_max = wp.max(z_max, bounds_far(z, thickness, thickness_rel))
                    if has_back:  # a back-face layer: a ray ends in an object's far half too
                        z_max = wp.max(z_max, back[first + di])
        wp.tile_scatter_masked(seg_near, s, z_min, s < _SEGMENTS)
        wp.tile_scatter_masked(seg_far, s, z_max, s < _SEGMENTS)
    # the 16 fine cells (8 segments each), written widened as march.depth_bounds writes them
    fw = (width + BOUNDS_CELL - 1) / BOUNDS_CELL
    fh = (height + BOUNDS_CELL - 1) / BOUNDS_CELL
    cell_near = wp.tile_empty(shape=_FINE_CELLS, dtype=wp.float32, storage="shared")
    cell_far = wp.tile_empty(shape=_FINE_CELLS, dtype=wp.float32, storage="shared")
    for c0 in range(0, _FINE_CELLS, threads):
        c = c0 + lane
        b = wp.vec2(BIG_DEPTH, 0.0)  # a cell off the view adds nothing to the coarse cell
        if c < _FINE_CELLS:
            fx = x0 / BOUNDS_CELL + c % _FINE_PER_COARSE
            fy = y0 / BOUNDS_CELL + c / _FINE_PER_COARSE
            if fx < fw and fy < fh:
                z_min = float(BIG_DEPTH)
                z_max = float(0.0)
                s_first = (c / _FINE_PER_COARSE) * BOUNDS_CELL * _FINE_PER_COARSE + c % _FINE_PER_COARSE
                for r in range(wp.min(BOUNDS_CELL, height - fy * BOUNDS_CELL)):  # its rows in the view
                    s = s_first + r * _FINE_PER_COARSE
                    z_min = wp.min(z_min, seg_near[s])
                    z_max = wp.max(z_max, seg_far[s])
                b = wp.vec2(z_min * BOUNDS_NEAR, z_max * BOUNDS_FAR)
                bounds[fy * fw + fx] = b
        wp.tile_scatter_masked(cell_near, c, b[0], c < _FINE_CELLS)
        wp.tile_scatter_masked(cell_far, c, b[1], c < _FINE_CELLS)
    if lane == 0:  # the coarse cell: min and max over its fine cells (march.coarsen_bounds)
        b = wp.vec2(BIG_DEPTH, 0.0)
        for c in range(wp.min(_FINE_CELLS, threads * _FINE_CELLS)):  # (a loop kept rolled)
            b = wp.vec2(wp.min(b[0], cell_near[c]), wp.max(b[1], cell_far[c]))
        bounds[fw * fh + block] = b



@wp.kernel(launch_bounds=(RESOLVE_THREADS, RESOLVE_RSM_BLOCKS_PER_SM))
def resolve_rsm_view(
    views: wp.array(dtype=ViewParams),  # (V,) views (read): resolves views[view_index]
    view_index: int,
    opaque_visibility: wp.array(dtype=wp.uint64),  # (H*W,) opaque layer (read, then reset to EMPTY_KEY)
    specular_visibility: wp.array(dtype=wp.uint64),  # (H*W,) specular layer (read, then reset to EMPTY_KEY)
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    indices: wp.array(dtype=wp.int32),
    triangle_material: wp.array(dtype=wp.int32),
    mat_roughness: wp.array(dtype=wp.float32),
    mat_ior: wp.array(dtype=wp.float32),
    light_rgb: wp.vec3,  # irradiance [W/m²] (distant) or intensity [W/sr] (point, spot), per channel
    spot_axis: wp.vec3,  # world direction of the spot axis (unused unless is_spot)
    is_spot: int,
    cone_angle: float,
    cone_softness: float,
    texel_solid_angle: wp.array(dtype=wp.float32),  # (H*W,) [sr], perspective views (read)
    opaque_depth: wp.array(dtype=wp.float32),  # (H*W,) nearest opaque surface [m], 0 = none (write)
    opaque_tri: wp.array(dtype=wp.int32),  # (H*W,) its triangle, -1 = none (write; an empty array: not wanted)
    depth: wp.array(dtype=wp.float32),  # (H*W,) specular layer [m], 0 = none or hidden behind opaque (write)
    position: wp.array(dtype=wp.vec3),  # (H*W,) [m] (write; an empty array: not wanted, texel_surface gives it)
    normal: wp.array(dtype=wp.vec3),  # (H*W,) authored (outward) unit normal, not flipped (write; empty with position)
    roughness: wp.array(dtype=wp.float32),  # (H*W,) (write; an empty array, with ior: not wanted, texel_roughness)
    ior: wp.array(dtype=wp.float32),  # (H*W,) (write; empty with roughness: texel_ior gives it)
    tri_id: wp.array(dtype=wp.int32),  # (H*W,) -1 = none (write)
    nearest_depth: wp.array(dtype=wp.float32),  # (H*W,) the RSM's shadow depth [m], 0 = none (write)
    flux: wp.array(dtype=wp.vec3),  # (H*W,) power the light sends through the texel onto the surface [W] (write; an
    # empty array: not wanted, texel_emitted_flux gives it)
    thickness: float,  # [m] the depth bounds' absolute surface thickness (``march.depth_bounds``)
    thickness_rel: float,  # their relative thickness (× sample depth)
    bounds: wp.array(dtype=wp.vec2),  # (march.bounds_size,) depth bounds of opaque_depth (write; empty: not wanted)
):
    """One pass over an RSM view's two visibility buffers: the opaque layer's depth (:func:`resolve_depth`), the
    specular layer with its shadow depth (and its flux, roughness and IOR where kept) (:func:`resolve_rsm_specular`), and the depth bounds of the opaque
    depth (``photons.march.depth_bounds`` then ``coarsen_bounds``), instead of two resolves and two bounds passes
    that read back what the first wrote. ``wp.launch_tiled`` over the view's coarse cells (BOUNDS_COARSE² texels, a
    warp per texel row of it: the same coalesced rows as one thread per texel); the block keeps its texels' opaque
    depths in shared memory and reduces them there to its 16 fine cells and its coarse cell. Every buffer holds the
    same values bit for bit as the three naive twins' (the texel functions are theirs; min and max of the depths,
    never NaN, do not depend on the order they are taken in). On the CPU a block is one lane that does it all."""
    block, lane = wp.tid()
    view = views[view_index]
    if view.far <= 0.0:  # an inactive view (light_maps.INACTIVE_FAR): nothing drawn; its maps and bounds are kept
        return
    threads = wp.block_dim()
    width = view.width
    height = view.height
    cw = (width + BOUNDS_COARSE - 1) / BOUNDS_COARSE
    x0 = (block % cw) * BOUNDS_COARSE
    y0 = (block / cw) * BOUNDS_COARSE
    want_bounds = bounds.shape[0] > 0
    keep_flux = flux.shape[0] > 0  # (else texel_emitted_flux gives it from tri_id where it is read)
    zs = wp.tile_empty(shape=RESOLVE_TEXELS, dtype=wp.float32, storage="shared")
    # RESOLVE_TEXELS_PER_THREAD texels a thread a round (a round is the whole block on CUDA; the CPU's one lane takes
    # 1024 rounds): their opaque depths are kept in registers and put into shared memory after the round, so the
    # block's barriers (one a scatter) come after its texels' memory work, not between texels
    for c0 in range(0, RESOLVE_TEXELS, threads * RESOLVE_TEXELS_PER_THREAD):
        od0 = float(0.0)
        od1 = float(0.0)
        od2 = float(0.0)
        od3 = float(0.0)
        for m in range(wp.min(RESOLVE_TEXELS_PER_THREAD, threads * RESOLVE_TEXELS_PER_THREAD)):  # kept rolled
            k = c0 + m * threads + lane
            x = x0 + k % BOUNDS_COARSE
            y = y0 + k / BOUNDS_COARSE
            if k < RESOLVE_TEXELS and x < width and y < height:
                view = read_again(views, view_index, k)  # read per texel (L1 hits), not kept in registers
                p = y * width + x
                # both keys read before either reset: their two DRAM reads in flight together
                key_o = opaque_visibility[p]
                key_s = specular_visibility[p]
                if key_o != EMPTY_KEY:
                    opaque_visibility[p] = EMPTY_KEY
                if key_s != EMPTY_KEY:
                    specular_visibility[p] = EMPTY_KEY
                tri_o, od, x_o, bary_o, d_o = triangle_hit(view, key_o, p, points, indices)
                opaque_depth[p] = od
                if opaque_tri.shape[0] > 0:
                    opaque_tri[p] = tri_o
                tri = specular_texel_key(view, p, key_s, od, points, normals, indices, triangle_material,
                                         mat_roughness, mat_ior, depth, position, normal, roughness, ior, tri_id,
                                         nearest_depth)
                if tri == -1 and keep_flux:
                    flux[p] = wp.vec3(0.0)
                elif tri >= 0 and keep_flux:  # (-2: empty as before, its flux is zero already)
                    flux[p] = texel_flux(view, p, light_rgb, spot_axis, is_spot, cone_angle, cone_softness,
                                         texel_solid_angle)
                if m == 0:
                    od0 = od
                elif m == 1:
                    od1 = od
                elif m == 2:
                    od2 = od
                else:
                    od3 = od
        if want_bounds:
            _scatter_texel(zs, c0, 0, threads, lane, x0, y0, width, height, od0)
            _scatter_texel(zs, c0, 1, threads, lane, x0, y0, width, height, od1)
            _scatter_texel(zs, c0, 2, threads, lane, x0, y0, width, height, od2)
            _scatter_texel(zs, c0, 3, threads, lane, x0, y0, width, height, od3)
    if not want_bounds:
        return
    _block_bounds(zs, zs, False, lane, threads, block, width, height, thickness, thickness_rel, bounds)


@wp.kernel(launch_bounds=(RESOLVE_THREADS, RESOLVE_BLOCKS_PER_SM))
def resolve_back_view(
    views: wp.array(dtype=ViewParams),  # (V,) views (read): resolves views[view_index]
    view_index: int,
    visibility: wp.array(dtype=wp.uint64),  # (H*W,) back layer of :func:`raster_back_tiles` (read, then reset)
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    indices: wp.array(dtype=wp.int32),
    front_tri: wp.array(dtype=wp.int32),  # (H*W,) the front layer's triangle, -1 = none (read)
    depth_layers: wp.array(dtype=wp.float32),  # (2·H*W,) front depth [m] (read), then the back depth (write)
    thickness: float,  # [m] the depth bounds' absolute surface thickness (``march.depth_bounds``)
    thickness_rel: float,  # their relative thickness (× sample depth)
    bounds: wp.array(dtype=wp.vec2),  # (march.bounds_size,) depth bounds of depth_layers (write; empty: not wanted)
):
    """:func:`resolve_back` (its twin) and the depth bounds of both depth layers (``photons.march.depth_bounds`` of
    ``depth_layers``, then ``coarsen_bounds``) in one pass: ``wp.launch_tiled`` over the view's coarse cells, as
    :func:`resolve_rsm_view`. The same values bit for bit as the twins'."""
    block, lane = wp.tid()
    view = views[view_index]
    if view.far <= 0.0:
        return
    threads = wp.block_dim()
    width = view.width
    height = view.height
    cw = (width + BOUNDS_COARSE - 1) / BOUNDS_COARSE
    x0 = (block % cw) * BOUNDS_COARSE
    y0 = (block / cw) * BOUNDS_COARSE
    want_bounds = bounds.shape[0] > 0
    zs = wp.tile_empty(shape=RESOLVE_TEXELS, dtype=wp.float32, storage="shared")
    zb = wp.tile_empty(shape=RESOLVE_TEXELS, dtype=wp.float32, storage="shared")
    for k0 in range(0, RESOLVE_TEXELS, threads):
        k = k0 + lane
        x = x0 + k % BOUNDS_COARSE
        y = y0 + k / BOUNDS_COARSE
        inside = k < RESOLVE_TEXELS and x < width and y < height
        z_front = float(0.0)
        z_back = float(0.0)
        if inside:
            view = read_again(views, view_index, k)
            p = y * width + x
            z_front = depth_layers[p]
            z_back = back_texel(view, p, visibility, points, normals, indices, front_tri, depth_layers)
        if want_bounds:
            wp.tile_scatter_masked(zs, k, z_front, inside)
            wp.tile_scatter_masked(zb, k, z_back, inside)
    if not want_bounds:
        return
    _block_bounds(zs, zb, True, lane, threads, block, width, height, thickness, thickness_rel, bounds)
