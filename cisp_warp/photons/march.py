"""Image-space ray march through a linear depth buffer (after McGuire & Mara 2014), shared by every
screen-space pass: the photons' light-view and camera-view traces and the water's refraction.

The ray segment is clipped to the view's near plane and to the image rectangle, then walked one pixel
per step along its major screen axis with perspective-correct depth (1/depth is linear in screen space
for a perspective view, depth itself for an orthographic one). At each step the ray's depth z_r is
compared with the buffer's z_s at that pixel:

* the ray's depth range over the step, [min(z_r, z_r'), max(z_r, z_r')], overlaps the surface's
  [z_s, z_s + thickness]: the ray crossed the surface: the exact crossing is found by intersecting
  the two linear segments of seed 000, eq. 2 (ray depth and sample depth between the last two
  steps), or within the pixel when the ray runs along the view axis, and the march reports a hit;
* otherwise the ray is in front of the surface, or passes behind it: go on.

The surface's far side is z_s + thickness, or, for a depth buffer that carries a back-face layer (the camera's
``GBuffer.depth_layers``), half way to the nearest back face behind it where that is nearer (:func:`surface_far`).
The marches exist twice (:func:`_make_marches`): these, which test for the layer at run time, and ``*_plain``, the
same body compiled without the layer's code, for the depth buffers that never carry one (light views, the
composite's camera depth): no registers or stack spent on it there.

Testing the depth *range* of each step rather than its end point matters for rays close to the
view axis, which advance far in depth per pixel.

``t`` is the parameter of the world-space ray ``o + d·t`` (``d`` need not be unit length).

:func:`screen_march` reads the depth samples of ``MARCH_BATCH`` steps before it tests any of them: the
reads do not depend on each other, so a GPU thread has them in flight together instead of waiting for one
L2 round trip per step; the tests then run in step order with the same arithmetic, so the result is that of
:func:`screen_march_naive` (the one-step-at-a-time twin the tests compare it with) bit for bit.
"""

from __future__ import annotations

import warp as wp

from ..raster.kernels import BIG_DEPTH, BOUNDS_CELL, BOUNDS_COARSE, BOUNDS_FAR, BOUNDS_NEAR, bounds_far, bounds_size
from ..raster.views import ViewParams

MARCH_HIT = wp.constant(0)  #: crossed a surface of the depth buffer
MARCH_EXIT = wp.constant(1)  #: left the view (image border, near plane) or reached t_max
MARCH_STEPS = wp.constant(2)  #: ran out of steps before either
#: entered the hidden (far) half of a closed object: a surface the view cannot see, where the ray ends (only with a
#: back-face layer behind the depth: :func:`surface_far`)
MARCH_HIDDEN = wp.constant(3)

#: BIG_DEPTH (1e30, imported from ``raster.kernels``): the depth a hole counts as
#: diff_prev of :func:`screen_march_bounded` after a skip, until read: no depth difference comes near it (depths and
#: BIG_DEPTH are below 1e31)
DIFF_UNREAD = wp.constant(3.0e38)
#: zr_prev of :func:`screen_march_bounded` after a skip, until its pixel steps need it (depths are > 0): the ray's
#: depth there is computed once when a cell's steps are walked, not at every skip (a division a cell test before)
ZR_UNREAD = wp.constant(-1.0)
#: a perspective cell test's margin in inverse depth (2^-20, 16 float32 ulps): a skip it allows is one the depth
#: test allows, whatever the rounding of the products and of the ray's 1/depth (:func:`_cell_skipped`)
INV_DEPTH_MARGIN = wp.constant(9.5367431640625e-07)


@wp.func
def _buffer_depth(view: ViewParams, depth: wp.array(dtype=wp.float32), sx: float, sy: float) -> float:
    i = wp.clamp(int(wp.floor(sx)), 0, view.width - 1)
    j = wp.clamp(int(wp.floor(sy)), 0, view.height - 1)
    z = depth[j * view.width + i]
    if z <= 0.0:
        return BIG_DEPTH
    return z


#: least thickness a back-face layer leaves a surface, in pixel footprints at its depth (see :func:`surface_far`)
MIN_THICKNESS_PX = wp.constant(0.25)


@wp.func
def _texel_index(view: ViewParams, sx: float, sy: float) -> int:
    """Pixel index of the texel holding continuous pixel coordinates (sx, sy), clamped to the image."""
    i = wp.clamp(int(wp.floor(sx)), 0, view.width - 1)
    j = wp.clamp(int(wp.floor(sy)), 0, view.height - 1)
    return j * view.width + i


@wp.func
def back_depth(view: ViewParams, depth: wp.array(dtype=wp.float32), p: int) -> float:
    """The back-face layer's depth [m] at pixel ``p`` (0 = none, or a plain H*W depth buffer)."""
    n = view.width * view.height
    if depth.shape[0] > n:
        return depth[n + p]
    return 0.0


@wp.func
def _hidden(zr_prev: float, zr: float, zs: float, zb: float) -> bool:
    """Whether the ray's depth over a step, [min, max], reaches into [zs, zb], the span of a closed object along the
    pixel's ray, when it did not cross the visible half (tested first): it is in the object's hidden half."""
    return zb > 0.0 and wp.max(zr, zr_prev) >= zs and wp.min(zr, zr_prev) <= zb


@wp.func
def surface_far(view: ViewParams, depth: wp.array(dtype=wp.float32), p: int, zs: float, thickness: float,
                thickness_rel: float) -> float:
    """Depth [m] of the far side of the surface of pixel ``p`` (front depth ``zs``) for the screen-space tests: ``zs``
    + the constant thickness (``thickness`` + ``thickness_rel``·``zs``), or, where ``depth`` carries a back-face
    layer behind its H*W front depths (``GBuffer.depth_layers``: 2·H*W long) and it holds a back face ``zb`` behind
    this pixel, half way to that back face when that is nearer (docs/perf_notes.md section 21).

    Half way: along the pixel's ray a closed object spans [zs, zb]; a point of its surface at a depth nearer ``zb``
    is on its far side, hidden from the view (the lit top of a ball seen from below its rim: a landing there, or a
    ray entering the object there, was stored on the rim with the constant thickness); a ray whose depth at the
    pixel lies in the near half has entered through the visible side. At the rim zb − zs goes to 0 and so does the
    thickness, where the constant 6.4 cm (at 2.2 m) took photons passing just behind a 12 cm ball as landing on it.

    Never thinner than ``MIN_THICKNESS_PX`` of the pixel's footprint at ``zs``, for numerical safety: front and back
    are float32 ray hits rounded apart (~1e-7 relative) and the march's crossing arithmetic rounds as well; a
    quarter footprint (2-3 mm at 2.2 m, 192 pixels across) is far above those roundings and far below the constant
    thickness. A plain H*W depth buffer (light views, the composite's lookups) keeps the constant thickness."""
    far = zs + thickness + thickness_rel * zs
    n = view.width * view.height
    if depth.shape[0] > n:
        zb = depth[n + p]
        if zb > 0.0:
            foot = wp.where(view.orthographic == 0, zs, 1.0) / view.fx  # (one division, its numerator selected)
            far = wp.min(far, wp.max(zs + 0.5 * (zb - zs), zs + MIN_THICKNESS_PX * foot))
    return far


MARCH_BATCH = 4  #: depth samples :func:`screen_march` reads before testing them


@wp.func
def _ray_depth(orthographic: int, z0: float, z1: float, k0: float, k1: float, s: float) -> float:
    """Linear depth of the ray at screen-segment parameter ``s`` (1/depth is linear for a perspective view)."""
    # both computed and one selected (the same values as a return in each branch; the division in a branch merged
    # through local memory in the marches' cell loops at the trace's register bound: perf_notes section 48)
    return wp.where(orthographic != 0, z0 + (z1 - z0) * s, 1.0 / (k0 + (k1 - k0) * s))


@wp.func
def _cell_skipped(orthographic: int, z0: float, z1: float, k0: float, k1: float, s_prev: float, s_last: float,
                  b: wp.vec2) -> bool:
    """Whether no step of a stretch from screen-segment parameter ``s_prev`` (the last step before it) to ``s_last``
    (its last step) can hit a cell whose depth bounds are ``b`` (nearest surface, farthest back face, :func:`depth_bounds`):
    the ray's depth over the stretch stays in front of ``b[0]`` or behind ``b[1]`` (it is monotonic along the segment,
    so its range is that of the two ends). Orthographic: the depths :func:`_ray_depth` gives, compared. Perspective:
    without their divisions, in inverse depth w = k0 + (k1 − k0)·s (> 0): depth < b[0] where b[0]·w > 1, depth > b[1]
    where b[1]·w < 1, each with ``INV_DEPTH_MARGIN``, far above the rounding of the product and of 1/w (a few ulps)
    and below the bounds' own 1e-6 widening: every skip is still a proof, so the march ends where the naive one does,
    bit for bit (docs/perf_notes.md section 59)."""
    za = z0 + (z1 - z0) * s_prev
    zb = z0 + (z1 - z0) * s_last
    wa = k0 + (k1 - k0) * s_prev
    wb = k0 + (k1 - k0) * s_last
    ortho_skip = wp.max(za, zb) < b[0] or wp.min(za, zb) > b[1]
    persp_skip = b[0] * wp.min(wa, wb) > 1.0 + INV_DEPTH_MARGIN or b[1] * wp.max(wa, wb) < 1.0 - INV_DEPTH_MARGIN
    return wp.where(orthographic != 0, ortho_skip, persp_skip)


@wp.func
def _inv_rate(orthographic: int, z0: float, z1: float, k0: float, k1: float, ds_step: float) -> float:
    """1 / (change of the march's linear quantity a step): depth for an orthographic view, inverse depth for a
    perspective one (:func:`_proven_prefix`); 0 where it does not change. Once a march."""
    rate = wp.where(orthographic != 0, z1 - z0, k1 - k0) * ds_step
    return wp.where(rate != 0.0, 1.0 / wp.where(rate != 0.0, rate, 1.0), 0.0)


@wp.func
def _proven_prefix(orthographic: int, z0: float, z1: float, k0: float, k1: float, inv_rate: float, s_prev: float,
                   ds_step: float, i: int, last: int, b: wp.vec2) -> int:
    """The last step j in [i − 1, last − 1] such that steps i..j of a stretch whose cell test (:func:`_cell_skipped`,
    bounds ``b``) failed are still proven hitless by ``b``: the steps before the ray's depth enters [b[0], b[1]]
    (a ray coming down onto a floor: all its steps above the cell's nearest surface). i − 1: none.

    The step where the march's linear quantity q (depth, or inverse depth for a perspective view: affine in the
    segment parameter s) reaches the bound on the side the stretch starts from (b[0], or b[1] behind; in inverse
    depth the bound with :func:`_cell_skipped`'s margin) is solved for with ``inv_rate`` (:func:`_inv_rate`); that
    estimate only proposes j: :func:`_cell_skipped` over [``s_prev``, s_j] with the same bounds proves it (or
    j − 1, a rounding's step back), else nothing is skipped. So every step skipped is one the cell test itself
    proves hitless (the ray's depth is monotonic along the segment), and the march still ends where the naive one
    does, bit for bit (docs/perf_notes.md section 74)."""
    ortho = orthographic != 0
    q0 = wp.where(ortho, z0, k0)
    q_prev = q0 + wp.where(ortho, z1 - z0, k1 - k0) * s_prev
    front = wp.where(ortho, q_prev < b[0], b[0] * q_prev > 1.0 + INV_DEPTH_MARGIN)
    # the bound the stretch heads for, in q (perspective: one division, its operands selected)
    persp_edge = wp.where(front, 1.0 + INV_DEPTH_MARGIN, 1.0 - INV_DEPTH_MARGIN) / wp.where(front, b[0], b[1])
    edge = wp.where(ortho, wp.where(front, b[0], b[1]), persp_edge)
    j_f = (edge - q0) * inv_rate  # steps from s = 0 to the bound (NaN or out of range: clamped to none)
    j_f = wp.where(j_f > float(i), wp.min(j_f, float(last)), float(i))
    j = int(wp.ceil(j_f)) - 1  # the last step before the bound: in [i - 1, last - 1]
    ok = _cell_skipped(orthographic, z0, z1, k0, k1, s_prev, ds_step * float(j), b)
    ok_back = _cell_skipped(orthographic, z0, z1, k0, k1, s_prev, ds_step * float(j - 1), b)
    return wp.max(wp.where(ok, j, wp.where(ok_back, j - 1, i - 1)), i - 1)


@wp.func
def _crossing(orthographic: int, zr_prev: float, zr: float, zs: float, diff_prev: float, z_far: float) -> float:
    """Where along a step the ray crosses the surface, u in [0, 1], or -1 when the ray's depth over the step,
    [min, max], does not overlap the surface's [zs, z_far] (:func:`surface_far`).

    Eq. 2 of seed 000 (two segments between the last two steps: the ray's depth and the samples') in the quantity
    that is linear in screen space: depth for an orthographic view, 1/depth for a perspective one, where both the
    ray's and a plane's 1/depth are affine in the screen coordinates. Linear depth there puts the crossing of a
    ray that advances far in depth over one step (near the view axis) short of the surface: a ray from depth 0.6
    to 1.2 over the step crossing a floor at 0.95 ended at depth 0.85, 10 cm above it (docs/perf_notes.md
    section 17). After a sample with no surface (BIG_DEPTH) the crossing is that with the current sample's depth."""
    diff = zr - zs
    if wp.max(zr, zr_prev) >= zs and wp.min(zr, zr_prev) <= z_far:
        # the four cases' quotients (orthographic or perspective; eq. 2 or within the pixel), their operands
        # selected and divided once (the same values as a division in each branch: the kernels that inline every
        # march merge fewer divisions through local memory; docs/perf_notes.md section 44)
        persp = orthographic == 0
        zs_prev = zr_prev - diff_prev
        eq2 = diff_prev < 0.0 and diff >= 0.0 and (not persp or zs_prev < BIG_DEPTH)
        inv_prev = 1.0 / zr_prev
        inv_r = 1.0 / zr
        inv_s = 1.0 / zs
        a = inv_prev - 1.0 / zs_prev
        # orthographic: eq. 2, where the two depth segments cross, or the crossing within this pixel;
        # perspective: the same in 1/depth
        num = wp.where(persp, wp.where(eq2, a, inv_prev - inv_s), wp.where(eq2, diff_prev, zs - zr_prev))
        den = wp.where(persp, wp.where(eq2, a - (inv_r - inv_s), inv_prev - inv_r),
                       wp.where(eq2, diff_prev - diff, zr - zr_prev))
        u = float(1.0)
        if eq2 or zr != zr_prev:
            q = num / den
            u = wp.where(eq2, q, wp.clamp(q, 0.0, 1.0))
        return u
    return -1.0


@wp.func
def _segment_t(orthographic: int, k0: float, k1: float, t1: float, s: float) -> float:
    """Ray parameter t of screen-segment parameter ``s`` (perspective-correct)."""
    return wp.where(orthographic == 0, s * k1 / ((1.0 - s) * k0 + s * k1), s) * t1


# BOUNDS_CELL (8): edge [texels] of the fine cells of :func:`depth_bounds`; BOUNDS_COARSE (32): of its coarse cells
# (4x4 fine cells); both imported from ``raster.kernels``, whose ``resolve_rsm_view`` writes an RSM view's bounds in
# its resolve (this kernel and :func:`coarsen_bounds` are its naive twins, and build the camera's)


def bounds_shape(width: int, height: int, cell: int = 8) -> tuple[int, int]:
    """(cells across, cells down) of a depth buffer's bounds with cells of ``cell`` texels."""
    return (width + cell - 1) // cell, (height + cell - 1) // cell




@wp.func
def view_inactive(views: wp.array(dtype=ViewParams), view_index: int) -> bool:
    """Whether ``views[view_index]`` is an inactive cascade (``far`` = 0: nothing drawn, nothing marched); never for
    an empty ``views`` (a depth buffer that is always in use, such as the camera's)."""
    if views.shape[0] == 0:
        return False
    return views[view_index].far <= 0.0


@wp.kernel
def depth_bounds(
    views: wp.array(dtype=ViewParams),  # (V,) the view the depth buffer belongs to (read; empty: always active)
    view_index: int,  # an inactive views[view_index] (far = 0) keeps its bounds: nothing marches it this frame
    depth: wp.array(dtype=wp.float32),  # (H*W,) linear depth [m], 0 = no surface (read)
    width: int,
    height: int,
    thickness: float,  # [m] absolute part of the surface thickness
    thickness_rel: float,  # relative part (× sample depth)
    bounds: wp.array(dtype=wp.vec2),  # (bounds_size,) fine cells first: (min z_s, max z_s + thickness) [m] (write)
):
    """Per fine cell of BOUNDS_CELL² texels: the nearest surface depth and the farthest back face of a surface
    (z_s + thickness + thickness_rel·z_s, computed as :func:`screen_march` does), holes counting as BIG_DEPTH. A
    ray whose depth over a stretch of steps stays in front of the first or behind the second cannot hit in
    that cell, so :func:`screen_march_bounded` skips those steps. :func:`coarsen_bounds` then fills the
    coarse cells. A depth buffer carrying a back-face layer (:func:`surface_far`) is bounded by its constant
    thickness all the same: the layer only ever brings a surface's far side nearer, so these bounds still hold
    (exact skips, a little fewer of them behind closed objects) without a second read per texel."""
    if view_inactive(views, view_index):
        return
    c = wp.tid()
    cw = (width + BOUNDS_CELL - 1) / BOUNDS_CELL
    i0 = (c % cw) * BOUNDS_CELL
    j0 = (c / cw) * BOUNDS_CELL
    z_min = float(BIG_DEPTH)
    z_max = float(0.0)
    for dj in range(BOUNDS_CELL):
        j = j0 + dj
        if j < height:
            for di in range(BOUNDS_CELL):
                i = i0 + di
                if i < width:
                    zs = depth[j * width + i]
                    if zs <= 0.0:
                        zs = BIG_DEPTH
                    z_min = wp.min(z_min, zs)
                    z_max = wp.max(z_max, bounds_far(zs, thickness, thickness_rel))
                    if depth.shape[0] > width * height:  # a back-face layer: a ray ends in an object's far half too
                        z_max = wp.max(z_max, depth[width * height + j * width + i])
    # a hair wider (1e-6 relative) than the exact bounds: a kernel elsewhere may round z_s + thickness one ulp
    # apart (CUDA fuses multiply-adds as it sees fit); wider bounds only skip less
    bounds[c] = wp.vec2(z_min * BOUNDS_NEAR, z_max * BOUNDS_FAR)


@wp.kernel
def coarsen_bounds(
    views: wp.array(dtype=ViewParams),  # (V,) as for depth_bounds (read; empty: always active)
    view_index: int,
    width: int,
    height: int,
    bounds: wp.array(dtype=wp.vec2),  # (bounds_size,) fine cells (read), then coarse cells (write)
):
    """Coarse cell = min and max over its (BOUNDS_COARSE / BOUNDS_CELL)² fine cells."""
    if view_inactive(views, view_index):
        return
    c = wp.tid()
    fw = (width + BOUNDS_CELL - 1) / BOUNDS_CELL
    fh = (height + BOUNDS_CELL - 1) / BOUNDS_CELL
    cw = (width + BOUNDS_COARSE - 1) / BOUNDS_COARSE
    r = BOUNDS_COARSE / BOUNDS_CELL
    i0 = (c % cw) * r
    j0 = (c / cw) * r
    b = wp.vec2(BIG_DEPTH, 0.0)
    for dj in range(r):
        for di in range(r):
            if i0 + di < fw and j0 + dj < fh:
                f = bounds[(j0 + dj) * fw + i0 + di]
                b = wp.vec2(wp.min(b[0], f[0]), wp.max(b[1], f[1]))
    bounds[fw * fh + c] = b


@wp.func
def _texel(view: ViewParams, s0: wp.vec2, ds: wp.vec2, s: float) -> wp.vec2i:
    """The texel (i, j) the march samples at screen-segment parameter ``s`` (as :func:`_buffer_depth` reads it)."""
    sp = s0 + ds * s
    return wp.vec2i(wp.clamp(int(wp.floor(sp[0])), 0, view.width - 1),
                    wp.clamp(int(wp.floor(sp[1])), 0, view.height - 1))


#: log2 of the cells' edges: a cell index is a texel coordinate shifted right (texel coordinates are >= 0, clamped
#: to the image: the same integer as the division, one instruction instead of a signed division's three)
CELL_SHIFT = wp.constant(int(BOUNDS_CELL).bit_length() - 1)
COARSE_SHIFT = wp.constant(int(BOUNDS_COARSE).bit_length() - 1)
assert 1 << int(CELL_SHIFT) == int(BOUNDS_CELL) and 1 << int(COARSE_SHIFT) == int(BOUNDS_COARSE)


@wp.func
def _cell_exit(ci: int, shift: int, s0: float, ds: float, inv_step: float) -> float:
    """Step index (as a float) past which the samples leave cell ``ci`` (of ``1 << shift`` texels) along one screen
    axis; 1e9 if never. ``inv_step`` = 1 / (ds · ds_step), computed once per march (no divisions per cell: an ulp
    off only moves the estimate by one step, which :func:`_cell_span` checks). The cell's far edge selected by the
    sign of ``ds`` and the value by whether it moves (the same values as a return in each branch, without the
    branches: this runs four times a cell test of every march; docs/perf_notes.md section 59)."""
    forward = ds > 0.0
    edge = (ci << shift) + wp.where(forward, 1 << shift, 0)
    return wp.where(forward or ds < 0.0, (float(edge) - s0) * inv_step, 1.0e9)


@wp.func
def _cell_span(view: ViewParams, s0: wp.vec2, ds: wp.vec2, ds_step: float, inv_step: wp.vec2, i: int, n: int,
               tx: wp.vec2i, shift: int):
    """The cell (ci, cj) of ``1 << shift`` texels that step i's sample (texel ``tx``) lies in, and a step ``last`` in
    [i, n] whose sample still does: all samples between lie in it too (texel coordinates are monotonic in the
    step). ``last`` is the cell's last step up to rounding: one step short only costs another visit of the cell."""
    ci = tx[0] >> shift
    cj = tx[1] >> shift
    last_f = wp.min(_cell_exit(ci, shift, s0[0], ds[0], inv_step[0]), _cell_exit(cj, shift, s0[1], ds[1], inv_step[1]))
    # selected, not assigned in a branch (the same value; a predicated store of ``last`` to local memory in the
    # light march's cell loop at the trace's register bound, docs/perf_notes.md section 70); the ceiling of at most
    # n, so the unselected conversion never leaves int's range
    last = wp.where(last_f < float(n), wp.max(int(wp.ceil(wp.min(last_f, float(n)))) - 1, i), n)
    tl = _texel(view, s0, ds, ds_step * float(last))
    while last > i and ((tl[0] >> shift) != ci or (tl[1] >> shift) != cj):  # rounding: step back into the cell
        last -= 1
        tl = _texel(view, s0, ds, ds_step * float(last))
    return last, ci, cj


#: ``partial`` 3: log2 of a pair cell's edge (2x2 coarse cells, 64 texels), bounded by its coarse cells' bounds
PAIR_SHIFT = wp.constant(int(COARSE_SHIFT) + 1)


@wp.func
def _pair_bounds(bounds: wp.array(dtype=wp.vec2), coarse_0: int, coarse_x: int, coarse_y: int, pi: int,
                 pj: int) -> wp.vec2:
    """Bounds of pair cell (pi, pj): min and max over its (up to) 2x2 coarse cells (an edge cell's repeated)."""
    i0 = 2 * pi
    i1 = wp.min(i0 + 1, coarse_x - 1)
    r0 = coarse_0 + 2 * pj * coarse_x
    r1 = coarse_0 + wp.min(2 * pj + 1, coarse_y - 1) * coarse_x
    a = bounds[r0 + i0]
    b = bounds[r0 + i1]
    c = bounds[r1 + i0]
    d = bounds[r1 + i1]
    return wp.vec2(wp.min(wp.min(a[0], b[0]), wp.min(c[0], d[0])), wp.max(wp.max(a[1], b[1]), wp.max(c[1], d[1])))


@wp.func
def _screen_segment(view: ViewParams, o: wp.vec3, d: wp.vec3, t_max: float, max_steps: int):
    """The screen segment the marches step along: the ray ``o + d·t``, t in (0, t_max], cut at the near plane,
    projected and clipped to the image (Liang-Barsky), in ``n`` steps of ``ds_step`` (a fraction of the segment:
    a pixel a step, at most ``max_steps``). Returns (inside, status, n, ds_step, t1, z0, z1, k0, k1, s0, ds):
    ``inside`` 0 where the origin lies before the near plane or off the image (the march ends there, ``MARCH_EXIT``);
    ``status`` the march's end without a hit (``MARCH_STEPS`` when ``max_steps`` cut it short); t1 the ray length
    the segment spans; z0, z1 its end depths [m], k0, k1 their inverses (1 for an orthographic view); s0 its
    screen start and ds its screen extent [pixels] before clipping (:func:`_ray_depth`, :func:`_segment_t`)."""
    p0 = wp.transform_point(view.world_to_view, o)
    dv = wp.transform_vector(view.world_to_view, d)
    z0 = -p0[2]
    rate = -dv[2]  # d(depth)/dt
    t1 = t_max
    near = view.near * 1.0001
    if z0 < near:
        return (0, MARCH_EXIT, int(0), float(0.0), float(0.0), float(0.0), float(0.0), float(0.0), float(0.0),
                wp.vec2(0.0), wp.vec2(0.0))
    t1 = wp.where(rate < 0.0, wp.min(t1, (z0 - near) / (-rate)), t1)  # selected, as the divisions below
    if view.orthographic == 0:
        t1 = wp.min(t1, 1.0e6)
    p1 = p0 + dv * t1
    z1 = -p1[2]
    # the perspective reciprocals and both projections computed, the view's selected (the same values as the
    # branches; no division merged through local memory: perf_notes section 48)
    ortho = view.orthographic != 0
    r0 = 1.0 / z0
    r1 = 1.0 / z1
    k0 = wp.where(ortho, 1.0, r0)
    k1 = wp.where(ortho, 1.0, r1)
    s0 = wp.where(ortho, wp.vec2(view.cx + view.fx * p0[0], view.cy - view.fy * p0[1]),
                  wp.vec2(view.cx + view.fx * p0[0] * r0, view.cy - view.fy * p0[1] * r0))
    s1 = wp.where(ortho, wp.vec2(view.cx + view.fx * p1[0], view.cy - view.fy * p1[1]),
                  wp.vec2(view.cx + view.fx * p1[0] * r1, view.cy - view.fy * p1[1] * r1))
    # clip the screen segment to the image (Liang-Barsky); the origin must lie inside
    w = float(view.width)
    h = float(view.height)
    if s0[0] < 0.0 or s0[1] < 0.0 or s0[0] >= w or s0[1] >= h:
        return (0, MARCH_EXIT, int(0), float(0.0), float(0.0), float(0.0), float(0.0), float(0.0), float(0.0),
                wp.vec2(0.0), wp.vec2(0.0))
    ds = s1 - s0
    # one division per axis and one for the step, their operands selected first: the same quotients as a division
    # in each branch, with fewer of the divisions' slow-path merges in the kernels that inline every march
    s_end = float(1.0)
    if ds[0] > 0.0 or ds[0] < 0.0:  # not for 0 (nor NaN), as the branches were
        s_end = wp.min(s_end, wp.where(ds[0] > 0.0, w - 1.0e-3 - s0[0], 1.0e-3 - s0[0]) / ds[0])
    if ds[1] > 0.0 or ds[1] < 0.0:
        s_end = wp.min(s_end, wp.where(ds[1] > 0.0, h - 1.0e-3 - s0[1], 1.0e-3 - s0[1]) / ds[1])
    s_end = wp.max(s_end, 0.0)
    pixels = wp.max(wp.abs(ds[0]), wp.abs(ds[1])) * s_end
    n = int(wp.ceil(pixels))
    status = MARCH_EXIT
    if n > max_steps:
        n = max_steps
        status = MARCH_STEPS
    n = wp.max(n, 1)
    ds_step = s_end / wp.where(pixels > float(max_steps), pixels, float(n))
    return 1, status, n, ds_step, t1, z0, z1, k0, k1, s0, ds


#: ``counted`` marches' work (the third value they return): cell tests × WORK_TESTS + pixel steps
WORK_TESTS = 65536


def _make_marches(back_layer: bool, counted: bool = False, partial: int = 0):
    """The three marches (:func:`screen_march_naive`, :func:`screen_march`, :func:`screen_march_bounded`) for a depth
    buffer that may carry a back-face layer (``back_layer`` True: the far side and the hidden-half test of
    :func:`surface_far` and ``MARCH_HIDDEN``, decided at run time by the array's length), or compiled for a plain
    H*W depth buffer only (False: the constant thickness, never ``MARCH_HIDDEN``; no layer code in the kernel). One
    body for both (``wp.static`` drops the layer's code at compile time), so the two agree bit for bit on a plain
    buffer. The plain ones are for the marches that never have a layer: the light views, the composite's lookups,
    the caustics map (docs/perf_notes.md section 23).

    ``counted`` (probes only: :func:`counted_marches`, ``tools/trace_steps.py``): :func:`screen_march_bounded`
    returns the work its loops did in place of the step index: its cell tests (coarse and fine) × ``WORK_TESTS`` +
    its pixel steps, compiled in only then (``wp.static``); status and end point are the same.

    ``partial`` (0 none): :func:`screen_march_bounded` also skips the proven prefix of a cell whose test failed
    (:func:`_proven_prefix`: the steps before the ray's depth reaches the cell's bounds): 1 a fine cell's, before its
    pixel steps are walked; 2 also a coarse cell's, before its fine cells are tested. ``counted`` counts each such
    prefix as a cell test. The same results bit for bit (docs/perf_notes.md section 74)."""

    @wp.func
    def _steps_out(i: int, work: int) -> int:
        """The third value :func:`screen_march_bounded` returns: the step index ``i``, or with ``counted`` its work."""
        if wp.static(counted):
            return work
        return i

    @wp.func
    def _far(view: ViewParams, depth: wp.array(dtype=wp.float32), sx: float, sy: float, zs: float, thickness: float,
             thickness_rel: float) -> float:
        """The far side of the surface the sample at (sx, sy) reads (front depth ``zs``): :func:`surface_far`."""
        if wp.static(back_layer):
            return surface_far(view, depth, _texel_index(view, sx, sy), zs, thickness, thickness_rel)
        return zs + thickness + thickness_rel * zs

    @wp.func
    def screen_march_naive(
        view: ViewParams,
        depth: wp.array(dtype=wp.float32),  # (H*W,) linear depth [m], 0 = no surface (read)
        o: wp.vec3,  # world origin [m]
        d: wp.vec3,  # world direction
        t_max: float,
        max_steps: int,
        thickness: float,  # [m] absolute part of the surface thickness
        thickness_rel: float,  # relative part (× sample depth)
    ):
        """March ``o + d·t`` for t in (0, t_max], one step at a time. Returns (status, t_end, steps taken).

        On a hit, ``t_end`` is the refined crossing; otherwise the last point inside the view. The twin of
        :func:`screen_march`.
        """
        inside, status, n, ds_step, t1, z0, z1, k0, k1, s0, ds = _screen_segment(view, o, d, t_max, max_steps)
        if inside == 0:
            return MARCH_EXIT, float(0.0), int(0)
        s_prev = float(0.0)
        zr_prev = z0
        diff_prev = z0 - _buffer_depth(view, depth, s0[0], s0[1])
        s_last = float(0.0)
        for i in range(1, n + 1):
            s = ds_step * float(i)
            sp = s0 + ds * s
            zr = float(0.0)
            if view.orthographic != 0:
                zr = z0 + (z1 - z0) * s
            else:
                zr = 1.0 / (k0 + (k1 - k0) * s)
            zs = _buffer_depth(view, depth, sp[0], sp[1])
            diff = zr - zs
            # the ray's depth over this step, [min, max], overlaps the surface's [zs, its far side]
            z_far = _far(view, depth, sp[0], sp[1], zs, thickness, thickness_rel)
            if wp.max(zr, zr_prev) >= zs and wp.min(zr, zr_prev) <= z_far:
                u = float(1.0)
                if view.orthographic != 0:  # depth is linear in screen space: the ray's and a plane's
                    if diff_prev < 0.0 and diff >= 0.0:
                        u = diff_prev / (diff_prev - diff)  # eq. 2: where the two depth segments cross
                    elif zr != zr_prev:
                        u = wp.clamp((zs - zr_prev) / (zr - zr_prev), 0.0, 1.0)  # crossing within this pixel
                else:  # 1/depth is: eq. 2 in 1/depth, exact for the ray and for a plane between the samples
                    zs_prev = zr_prev - diff_prev
                    if diff_prev < 0.0 and diff >= 0.0 and zs_prev < BIG_DEPTH:
                        a = 1.0 / zr_prev - 1.0 / zs_prev
                        u = a / (a - (1.0 / zr - 1.0 / zs))
                    elif zr != zr_prev:
                        u = wp.clamp((1.0 / zr_prev - 1.0 / zs) / (1.0 / zr_prev - 1.0 / zr), 0.0, 1.0)
                s_hit = s_prev + (s - s_prev) * u
                lam = s_hit
                if view.orthographic == 0:
                    lam = s_hit * k1 / ((1.0 - s_hit) * k0 + s_hit * k1)
                return MARCH_HIT, lam * t1, i
            if wp.static(back_layer):  # compiled out for a plain depth buffer
                if _hidden(zr_prev, zr, zs, back_depth(view, depth, _texel_index(view, sp[0], sp[1]))):
                    lam_h = s_prev
                    if view.orthographic == 0:
                        lam_h = s_prev * k1 / ((1.0 - s_prev) * k0 + s_prev * k1)
                    return MARCH_HIDDEN, lam_h * t1, i
            s_prev = s
            zr_prev = zr
            diff_prev = diff
            s_last = s
        lam_last = s_last
        if view.orthographic == 0:
            lam_last = s_last * k1 / ((1.0 - s_last) * k0 + s_last * k1)
        return status, lam_last * t1, n


    @wp.func
    def screen_march(
        view: ViewParams,
        depth: wp.array(dtype=wp.float32),  # (H*W,) linear depth [m], 0 = no surface (read)
        o: wp.vec3,  # world origin [m]
        d: wp.vec3,  # world direction
        t_max: float,
        max_steps: int,
        thickness: float,  # [m] absolute part of the surface thickness
        thickness_rel: float,  # relative part (× sample depth)
    ):
        """March ``o + d·t`` for t in (0, t_max]. Returns (status, t_end, steps taken).

        On a hit, ``t_end`` is the refined crossing; otherwise the last point inside the view. Reads
        MARCH_BATCH depth samples ahead (clamped to the image, so reads past the last step are harmless and
        untested); the same result as :func:`screen_march_naive`.
        """
        inside, status, n, ds_step, t1, z0, z1, k0, k1, s0, ds = _screen_segment(view, o, d, t_max, max_steps)
        if inside == 0:
            return MARCH_EXIT, float(0.0), int(0)
        ortho = view.orthographic
        s_prev = float(0.0)
        zr_prev = z0
        diff_prev = z0 - _buffer_depth(view, depth, s0[0], s0[1])
        i = int(1)
        while i <= n:
            # the batch's reads first (independent of each other), then its tests in step order
            sa = ds_step * float(i)
            sb = ds_step * float(i + 1)
            sc = ds_step * float(i + 2)
            sd = ds_step * float(i + 3)
            pa = s0 + ds * sa
            pb = s0 + ds * sb
            pc = s0 + ds * sc
            pd = s0 + ds * sd
            zsa = _buffer_depth(view, depth, pa[0], pa[1])
            zfa = _far(view, depth, pa[0], pa[1], zsa, thickness, thickness_rel)
            zsb = _buffer_depth(view, depth, pb[0], pb[1])
            zfb = _far(view, depth, pb[0], pb[1], zsb, thickness, thickness_rel)
            zsc = _buffer_depth(view, depth, pc[0], pc[1])
            zfc = _far(view, depth, pc[0], pc[1], zsc, thickness, thickness_rel)
            zsd = _buffer_depth(view, depth, pd[0], pd[1])
            zfd = _far(view, depth, pd[0], pd[1], zsd, thickness, thickness_rel)
            zr = _ray_depth(ortho, z0, z1, k0, k1, sa)
            u = _crossing(ortho, zr_prev, zr, zsa, diff_prev, zfa)
            if u >= 0.0:
                return MARCH_HIT, _segment_t(ortho, k0, k1, t1, s_prev + (sa - s_prev) * u), i
            if wp.static(back_layer):  # compiled out for a plain depth buffer
                if _hidden(zr_prev, zr, zsa, back_depth(view, depth, _texel_index(view, pa[0], pa[1]))):
                    return MARCH_HIDDEN, _segment_t(ortho, k0, k1, t1, s_prev), i
            s_prev = sa
            zr_prev = zr
            diff_prev = zr - zsa
            if i + 1 > n:
                break
            zr = _ray_depth(ortho, z0, z1, k0, k1, sb)
            u = _crossing(ortho, zr_prev, zr, zsb, diff_prev, zfb)
            if u >= 0.0:
                return MARCH_HIT, _segment_t(ortho, k0, k1, t1, s_prev + (sb - s_prev) * u), i + 1
            if wp.static(back_layer):  # compiled out for a plain depth buffer
                if _hidden(zr_prev, zr, zsb, back_depth(view, depth, _texel_index(view, pb[0], pb[1]))):
                    return MARCH_HIDDEN, _segment_t(ortho, k0, k1, t1, s_prev), i + 1
            s_prev = sb
            zr_prev = zr
            diff_prev = zr - zsb
            if i + 2 > n:
                break
            zr = _ray_depth(ortho, z0, z1, k0, k1, sc)
            u = _crossing(ortho, zr_prev, zr, zsc, diff_prev, zfc)
            if u >= 0.0:
                return MARCH_HIT, _segment_t(ortho, k0, k1, t1, s_prev + (sc - s_prev) * u), i + 2
            if wp.static(back_layer):  # compiled out for a plain depth buffer
                if _hidden(zr_prev, zr, zsc, back_depth(view, depth, _texel_index(view, pc[0], pc[1]))):
                    return MARCH_HIDDEN, _segment_t(ortho, k0, k1, t1, s_prev), i + 2
            s_prev = sc
            zr_prev = zr
            diff_prev = zr - zsc
            if i + 3 > n:
                break
            zr = _ray_depth(ortho, z0, z1, k0, k1, sd)
            u = _crossing(ortho, zr_prev, zr, zsd, diff_prev, zfd)
            if u >= 0.0:
                return MARCH_HIT, _segment_t(ortho, k0, k1, t1, s_prev + (sd - s_prev) * u), i + 3
            if wp.static(back_layer):  # compiled out for a plain depth buffer
                if _hidden(zr_prev, zr, zsd, back_depth(view, depth, _texel_index(view, pd[0], pd[1]))):
                    return MARCH_HIDDEN, _segment_t(ortho, k0, k1, t1, s_prev), i + 3
            s_prev = sd
            zr_prev = zr
            diff_prev = zr - zsd
            i += MARCH_BATCH
        return status, _segment_t(ortho, k0, k1, t1, s_prev), n


    @wp.func
    def screen_march_bounded(
        view: ViewParams,
        depth: wp.array(dtype=wp.float32),  # (H*W,) linear depth [m], 0 = no surface (read)
        bounds: wp.array(dtype=wp.vec2),  # (bounds_size,) :func:`depth_bounds` of ``depth``, these thicknesses (read)
        o: wp.vec3,  # world origin [m]
        d: wp.vec3,  # world direction
        t_max: float,
        max_steps: int,
        thickness: float,  # [m] absolute part of the surface thickness
        thickness_rel: float,  # relative part (× sample depth)
    ):
        """:func:`screen_march_naive`, skipping the steps depth bounds prove hitless. Returns (status, t_end, steps
        taken), the same as the naive march: a step tests the ray's depth range over it against the surface at its
        sample; while the ray's depth over all the steps whose samples lie in one cell stays in front of the cell's
        nearest surface or behind its farthest back face, none of them can hit, and the march jumps to the first
        step past the cell (the ray's depth is monotonic along the segment, so its range over those steps is that
        of their two ends). It tries the coarse cell first, then the fine one, else tests the fine cell's steps one
        by one."""
        inside, status, n, ds_step, t1, z0, z1, k0, k1, s0, ds = _screen_segment(view, o, d, t_max, max_steps)
        if inside == 0:
            return MARCH_EXIT, float(0.0), int(0)
        ortho = view.orthographic
        fine_x = (view.width + BOUNDS_CELL - 1) >> CELL_SHIFT  # (sizes and texel coordinates >= 0: shifts)
        coarse_0 = fine_x * ((view.height + BOUNDS_CELL - 1) >> CELL_SHIFT)
        coarse_x = (view.width + BOUNDS_COARSE - 1) >> COARSE_SHIFT
        # 1 / (screen pixels per step) along each axis (0 where the segment does not move along it), for the cell
        # exits; selected, not assigned in branches (the same values, no division merged through local memory)
        inv_step = wp.vec2(wp.where(ds[0] != 0.0, 1.0 / (ds[0] * ds_step), 0.0),
                           wp.where(ds[1] != 0.0, 1.0 / (ds[1] * ds_step), 0.0))
        inv_rate = float(0.0)
        if wp.static(partial > 0):
            inv_rate = _inv_rate(ortho, z0, z1, k0, k1, ds_step)
        s_prev = float(0.0)
        zr_prev = z0
        diff_prev = z0 - _buffer_depth(view, depth, s0[0], s0[1])
        failed_pair = int(-1)  # ``partial`` 3: the pair cell whose bounds last failed
        failed_coarse = int(-1)  # the coarse cell (index) whose bounds last failed: not tested again
        work = int(0)  # ``counted`` only: cell tests × WORK_TESTS + pixel steps
        i = int(1)
        while i <= n:
            tx = _texel(view, s0, ds, ds_step * float(i))
            # coarse cell of step i's sample, then its fine cell: skip all their steps when the bounds allow
            last = n
            skip = False
            coarse_failed = False  # ``partial``: the coarse cell failed this iteration (its prefix, then its fine cells)
            if wp.static(partial >= 3):  # 2x2 coarse cells first, their bounds from the coarse cells'
                if (tx[1] >> PAIR_SHIFT) * coarse_x + (tx[0] >> PAIR_SHIFT) != failed_pair:
                    last, pi, pj = _cell_span(view, s0, ds, ds_step, inv_step, i, n, tx, PAIR_SHIFT)
                    b = _pair_bounds(bounds, coarse_0, coarse_x, (view.height + BOUNDS_COARSE - 1) >> COARSE_SHIFT, pi,
                                     pj)
                    if wp.static(counted):
                        work += WORK_TESTS
                    skip = _cell_skipped(ortho, z0, z1, k0, k1, s_prev, ds_step * float(last), b)
                    if not skip:
                        failed_pair = pj * coarse_x + pi
                        coarse_failed = True
            if not skip and not coarse_failed and (tx[1] >> COARSE_SHIFT) * coarse_x + (tx[0] >> COARSE_SHIFT) != failed_coarse:
                last, ci, cj = _cell_span(view, s0, ds, ds_step, inv_step, i, n, tx, COARSE_SHIFT)
                b = bounds[coarse_0 + cj * coarse_x + ci]
                if wp.static(counted):
                    work += WORK_TESTS
                skip = _cell_skipped(ortho, z0, z1, k0, k1, s_prev, ds_step * float(last), b)
                if not skip:
                    failed_coarse = cj * coarse_x + ci
                    if wp.static(partial >= 2):
                        coarse_failed = True
            if not skip and not coarse_failed:
                last, ci, cj = _cell_span(view, s0, ds, ds_step, inv_step, i, last, tx, CELL_SHIFT)
                b = bounds[cj * fine_x + ci]
                if wp.static(counted):
                    work += WORK_TESTS
                skip = _cell_skipped(ortho, z0, z1, k0, k1, s_prev, ds_step * float(last), b)
            if skip:
                # no step i..last can hit: continue after them, as the naive march would
                s_prev = ds_step * float(last)
                zr_prev = ZR_UNREAD  # the ray's depth at s_prev, computed only if its next steps are walked
                diff_prev = DIFF_UNREAD  # the sample at s_prev is read only if the next step crosses
                i = last + 1
                continue
            if wp.static(partial > 0):
                # the failed cell's proven prefix (one call site for both levels): steps i..j skipped, as a skip
                # would (selected, not assigned in a branch: j = i - 1 leaves every value as it is); after a coarse
                # cell's, the next iteration tests the fine cell of step j + 1
                if wp.static(counted):
                    work += WORK_TESTS
                j = _proven_prefix(ortho, z0, z1, k0, k1, inv_rate, s_prev, ds_step, i, last, b)
                moved = j >= i
                s_prev = wp.where(moved, ds_step * float(j), s_prev)
                zr_prev = wp.where(moved, ZR_UNREAD, zr_prev)
                diff_prev = wp.where(moved, DIFF_UNREAD, diff_prev)
                i = j + 1
                if coarse_failed:
                    continue
            if zr_prev < 0.0:  # ZR_UNREAD: the value the naive march had there (its step at s_prev)
                zr_prev = _ray_depth(ortho, z0, z1, k0, k1, s_prev)
            while i <= last:
                if wp.static(counted):
                    work += 1
                s = ds_step * float(i)
                sp = s0 + ds * s
                zr = _ray_depth(ortho, z0, z1, k0, k1, s)
                zs = _buffer_depth(view, depth, sp[0], sp[1])
                z_far = _far(view, depth, sp[0], sp[1], zs, thickness, thickness_rel)
                if wp.max(zr, zr_prev) >= zs and wp.min(zr, zr_prev) <= z_far:
                    if diff_prev == DIFF_UNREAD:  # the sample after a skip, read now (the naive march read it then)
                        sp_prev = s0 + ds * s_prev
                        diff_prev = zr_prev - _buffer_depth(view, depth, sp_prev[0], sp_prev[1])
                    u = _crossing(ortho, zr_prev, zr, zs, diff_prev, z_far)
                    return MARCH_HIT, _segment_t(ortho, k0, k1, t1, s_prev + (s - s_prev) * u), _steps_out(i, work)
                if wp.static(back_layer):  # compiled out for a plain depth buffer
                    if _hidden(zr_prev, zr, zs, back_depth(view, depth, _texel_index(view, sp[0], sp[1]))):
                        return MARCH_HIDDEN, _segment_t(ortho, k0, k1, t1, s_prev), _steps_out(i, work)
                s_prev = s
                zr_prev = zr
                diff_prev = zr - zs
                i += 1
        return status, _segment_t(ortho, k0, k1, t1, s_prev), _steps_out(n, work)


    return screen_march_naive, screen_march, screen_march_bounded


#: the marches of a depth buffer that may carry a back-face layer (the camera's ``GBuffer.depth_layers``)
screen_march_naive, screen_march, screen_march_bounded = _make_marches(True)
#: the same marches compiled for a plain H*W depth buffer (light views, the composite, the caustics map)
screen_march_naive_plain, screen_march_plain, screen_march_bounded_plain = _make_marches(False)
#: :func:`screen_march_bounded` and its plain twin with the failed cells' proven prefixes skipped, coarse and fine
#: (``partial`` 2)
screen_march_bounded_partial = _make_marches(True, partial=2)[2]
screen_march_bounded_partial_plain = _make_marches(False, partial=2)[2]
_PARTIAL: dict[tuple, object] = {(True, 2): screen_march_bounded_partial, (False, 2): screen_march_bounded_partial_plain,
                                 (True, 0): screen_march_bounded, (False, 0): screen_march_bounded_plain}


def bounded_march(back_layer: bool, partial: int):
    """:func:`screen_march_bounded` (``back_layer``) or its plain twin at a level of ``partial`` (0, 1, 2:
    :func:`_make_marches`), made on first use."""
    key = (bool(back_layer), int(partial))
    if key not in _PARTIAL:
        _PARTIAL[key] = _make_marches(key[0], partial=key[1])[2]
    return _PARTIAL[key]


_COUNTED: dict[tuple, tuple] = {}


def counted_marches(back_layer: bool, partial: int = 0) -> tuple:
    """The marches of :func:`_make_marches` compiled ``counted`` (made once per ``back_layer`` and ``partial``, on
    first use: the frame's kernels never reference them)."""
    key = (bool(back_layer), int(partial))
    if key not in _COUNTED:
        _COUNTED[key] = _make_marches(key[0], counted=True, partial=key[1])
    return _COUNTED[key]


#: edge [texels] of the super cells of :func:`super_bounds` (4x4 coarse cells): the composite's reflected rays, which
#: mostly leave the image in front of everything, prove their way out in a few of these (docs/perf_notes.md section 72)
BOUNDS_SUPER = wp.constant(128)
SUPER_SHIFT = wp.constant(int(BOUNDS_SUPER).bit_length() - 1)
assert 1 << int(SUPER_SHIFT) == int(BOUNDS_SUPER) and int(BOUNDS_SUPER) % int(BOUNDS_COARSE) == 0


def super_shape(width: int, height: int) -> tuple[int, int]:
    """(super cells across, down) of a depth buffer of ``width`` × ``height`` texels (:func:`super_bounds`)."""
    return bounds_shape(width, height, int(BOUNDS_SUPER))


@wp.kernel
def super_bounds(
    bounds: wp.array(dtype=wp.vec2),  # (bounds_size,) :func:`depth_bounds` + :func:`coarsen_bounds` (read: coarse cells)
    width: int,  # of the depth buffer [texels]
    height: int,
    supers: wp.array(dtype=wp.vec2),  # (super_shape,) per super cell (min, max) of its coarse cells' bounds (write)
):
    """Super cell = min and max over its (BOUNDS_SUPER / BOUNDS_COARSE)² coarse cells (:func:`coarsen_bounds`, one
    level up): bounds of the same proofs over BOUNDS_SUPER² texels."""
    c = wp.tid()
    fw = (width + BOUNDS_CELL - 1) / BOUNDS_CELL
    fh = (height + BOUNDS_CELL - 1) / BOUNDS_CELL
    cw = (width + BOUNDS_COARSE - 1) / BOUNDS_COARSE
    ch = (height + BOUNDS_COARSE - 1) / BOUNDS_COARSE
    sw = (width + BOUNDS_SUPER - 1) / BOUNDS_SUPER
    r = BOUNDS_SUPER / BOUNDS_COARSE
    i0 = (c % sw) * r
    j0 = (c / sw) * r
    b = wp.vec2(BIG_DEPTH, 0.0)
    for dj in range(r):
        for di in range(r):
            if i0 + di < cw and j0 + dj < ch:
                f = bounds[fw * fh + (j0 + dj) * cw + i0 + di]
                b = wp.vec2(wp.min(b[0], f[0]), wp.max(b[1], f[1]))
    supers[c] = b


def _make_super_march(counted: bool = False):
    """:func:`screen_march_super_plain`: ``screen_march_bounded_plain`` with a third level of bounds above its coarse
    cells (``counted``: as :func:`_make_marches`)."""

    @wp.func
    def _steps_out(i: int, work: int) -> int:
        if wp.static(counted):
            return work
        return i

    @wp.func
    def screen_march_super_plain(
        view: ViewParams,
        depth: wp.array(dtype=wp.float32),  # (H*W,) linear depth [m], 0 = no surface (read; no back-face layer)
        bounds: wp.array(dtype=wp.vec2),  # (bounds_size,) :func:`depth_bounds` of ``depth``, these thicknesses (read)
        supers: wp.array(dtype=wp.vec2),  # (super_shape,) :func:`super_bounds` of ``bounds`` (read)
        o: wp.vec3,  # world origin [m]
        d: wp.vec3,  # world direction
        t_max: float,
        max_steps: int,
        thickness: float,  # [m] absolute part of the surface thickness
        thickness_rel: float,  # relative part (× sample depth)
    ):
        """``screen_march_bounded_plain`` (plain H*W depth buffer) that tries the step's super cell (BOUNDS_SUPER²
        texels) before its coarse and fine cells: the same skips are proofs one level up, so it returns what the naive
        march returns (status, t_end, steps taken), bit for bit. A super cell whose bounds failed is not tested again
        (as the coarse one). Where a ray leaves the image in front of every surface (the pool's reflected rays), its
        march proves it a super cell at a time: ~4 tests across a 1080p image instead of one a coarse cell."""
        inside, status, n, ds_step, t1, z0, z1, k0, k1, s0, ds = _screen_segment(view, o, d, t_max, max_steps)
        if inside == 0:
            return MARCH_EXIT, float(0.0), int(0)
        ortho = view.orthographic
        fine_x = (view.width + BOUNDS_CELL - 1) >> CELL_SHIFT
        coarse_0 = fine_x * ((view.height + BOUNDS_CELL - 1) >> CELL_SHIFT)
        coarse_x = (view.width + BOUNDS_COARSE - 1) >> COARSE_SHIFT
        super_x = (view.width + BOUNDS_SUPER - 1) >> SUPER_SHIFT
        inv_step = wp.vec2(wp.where(ds[0] != 0.0, 1.0 / (ds[0] * ds_step), 0.0),
                           wp.where(ds[1] != 0.0, 1.0 / (ds[1] * ds_step), 0.0))
        s_prev = float(0.0)
        zr_prev = z0
        diff_prev = z0 - _buffer_depth(view, depth, s0[0], s0[1])
        failed_super = int(-1)  # the super cell whose bounds last failed: not tested again
        failed_coarse = int(-1)
        work = int(0)
        i = int(1)
        while i <= n:
            tx = _texel(view, s0, ds, ds_step * float(i))
            last = n
            skip = False
            if (tx[1] >> SUPER_SHIFT) * super_x + (tx[0] >> SUPER_SHIFT) != failed_super:
                last, ci, cj = _cell_span(view, s0, ds, ds_step, inv_step, i, n, tx, SUPER_SHIFT)
                b = supers[cj * super_x + ci]
                if wp.static(counted):
                    work += WORK_TESTS
                skip = _cell_skipped(ortho, z0, z1, k0, k1, s_prev, ds_step * float(last), b)
                if not skip:
                    failed_super = cj * super_x + ci
            if not skip and (tx[1] >> COARSE_SHIFT) * coarse_x + (tx[0] >> COARSE_SHIFT) != failed_coarse:
                last, ci, cj = _cell_span(view, s0, ds, ds_step, inv_step, i, last, tx, COARSE_SHIFT)
                b = bounds[coarse_0 + cj * coarse_x + ci]
                if wp.static(counted):
                    work += WORK_TESTS
                skip = _cell_skipped(ortho, z0, z1, k0, k1, s_prev, ds_step * float(last), b)
                if not skip:
                    failed_coarse = cj * coarse_x + ci
            if not skip:
                last, ci, cj = _cell_span(view, s0, ds, ds_step, inv_step, i, last, tx, CELL_SHIFT)
                b = bounds[cj * fine_x + ci]
                if wp.static(counted):
                    work += WORK_TESTS
                skip = _cell_skipped(ortho, z0, z1, k0, k1, s_prev, ds_step * float(last), b)
            if skip:
                s_prev = ds_step * float(last)
                zr_prev = ZR_UNREAD
                diff_prev = DIFF_UNREAD
                i = last + 1
                continue
            if zr_prev < 0.0:  # ZR_UNREAD
                zr_prev = _ray_depth(ortho, z0, z1, k0, k1, s_prev)
            while i <= last:
                if wp.static(counted):
                    work += 1
                s = ds_step * float(i)
                sp = s0 + ds * s
                zr = _ray_depth(ortho, z0, z1, k0, k1, s)
                zs = _buffer_depth(view, depth, sp[0], sp[1])
                z_far = zs + thickness + thickness_rel * zs
                if wp.max(zr, zr_prev) >= zs and wp.min(zr, zr_prev) <= z_far:
                    if diff_prev == DIFF_UNREAD:
                        sp_prev = s0 + ds * s_prev
                        diff_prev = zr_prev - _buffer_depth(view, depth, sp_prev[0], sp_prev[1])
                    u = _crossing(ortho, zr_prev, zr, zs, diff_prev, z_far)
                    return MARCH_HIT, _segment_t(ortho, k0, k1, t1, s_prev + (s - s_prev) * u), _steps_out(i, work)
                s_prev = s
                zr_prev = zr
                diff_prev = zr - zs
                i += 1
        return status, _segment_t(ortho, k0, k1, t1, s_prev), _steps_out(n, work)

    return screen_march_super_plain


#: the three-level bounded march of a plain depth buffer (the composite's reflected rays)
screen_march_super_plain = _make_super_march()
_COUNTED_SUPER: list = []


def counted_super_march():
    """:func:`screen_march_super_plain` compiled ``counted`` (probes only; made on first use)."""
    if not _COUNTED_SUPER:
        _COUNTED_SUPER.append(_make_super_march(counted=True))
    return _COUNTED_SUPER[0]
