"""Warp kernels of SVGF (Schied et al. 2017) for caustic irradiance, one per Falcor SVGFPass stage.

Stages (Falcor ``RenderPasses/SVGFPass``): :func:`reproject` (temporal accumulation of colour and
luminance moments, and what FilterMoments computes per pixel: the temporal variance, the depth slope, the
first level's packed input), :func:`filter_moments` (the spatial variance where history is short), then the
à-trous levels of :mod:`.kernels_atrous` (the variance-guided wavelet, made energy-conserving); the feedback
level's output becomes the colour history (:func:`store_history` when that is the temporal accumulation).
Falcor's FinalModulate multiplies by albedo; the signal here is irradiance [W/m²], never demodulated, so it
has no such stage.

History is double-buffered as rows of ``(2, H*W)`` arrays (the guide as one array of 2*H*W vec4);
``parity[0]`` (a one-element int32 device array) names the row that holds the last frame, the kernels write row
``1 - parity[0]``, and :func:`flip_parity` swaps them at the end of the frame. Nothing is swapped on the host, so
one captured CUDA graph replays every frame.

Every image is a flat array of ``height * width`` pixels, row-major, row 0 at the top; kernels are
launched with ``dim=(height, width)``. A pixel *has a surface* when its depth is > 0 and its ``tri_id`` >= 0
(the reproject stage's guide holds depth 0 elsewhere), and pixels without one are excluded from every
neighbourhood and come out 0.
"""

from __future__ import annotations

import warp as wp

#: bilinear footprint below which a reprojection counts as disoccluded (Falcor SVGFReproject ``sumw >= 0.01``)
MIN_BILINEAR_WEIGHT = wp.constant(0.01)
#: history length [frames] below which variance is estimated spatially (paper section 4.2; Falcor FilterMoments)
SPATIAL_VARIANCE_HISTORY = wp.constant(4)
#: half width [pixels] of the spatial variance estimate: 7x7 (paper section 4.2)
SPATIAL_VARIANCE_RADIUS = wp.constant(3)
#: floor of the luminance variance [luminance²] so sigma_l·sqrt(var) never divides by 0 (Falcor ``epsVariance``)
VARIANCE_EPS = wp.constant(1.0e-10)
#: depth noise floor relative to depth: float32 and interpolation error of the rasterized linear depth
DEPTH_NOISE_REL = wp.constant(1.0e-4)


@wp.func
def luminance(c: wp.vec3) -> float:
    """Rec. 709 luminance of linear RGB (Falcor's ``luminance()``)."""
    return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]


@wp.func
def b3_spline(i: int) -> float:
    """1-D B3-spline à-trous tap weight at offset ``i`` in [-2, 2]: (1/16, 1/4, 3/8, 1/4, 1/16)."""
    a = wp.abs(i)
    return wp.where(a == 0, 0.375, wp.where(a == 1, 0.25, 0.0625))


@wp.func_native("""
#if defined(__CUDA_ARCH__)
const float4 v = __ldg(reinterpret_cast<const float4*>(a.data) + p);
return wp::vec4(v.x, v.y, v.z, v.w);
#else
return a.data[p];
#endif
""")
def load_vec4(a: wp.array(dtype=wp.vec4), p: int) -> wp.vec4:
    """``a[p]`` of a contiguous vec4 array in one 16-byte load on CUDA (Warp's own indexing issues four 4-byte
    loads, and the level's loads are strided across a warp: each of the four touches as many sectors as one
    16-byte load would)."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
reinterpret_cast<float4*>(a.data)[p] = make_float4(v[0], v[1], v[2], v[3]);
#else
a.data[p] = v;
#endif
""")
def store_vec4(a: wp.array(dtype=wp.vec4), p: int, v: wp.vec4):
    """``a[p] = v`` of a contiguous vec4 array in one 16-byte store on CUDA (Warp's own issues four 4-byte
    stores: four partial writes of each sector)."""
    ...


# Loads issued where they stand (volatile: the compiler neither drops them nor sinks them into the branch that uses
# their value, which would put them one memory round trip behind the test before it); plain reads on the CPU.
@wp.func_native("""
#if defined(__CUDA_ARCH__)
const float* f = reinterpret_cast<const float*>(a.data) + 3 * p;
float x, y, z;
asm volatile("ld.global.nc.f32 %0, [%3];\\n\\tld.global.nc.f32 %1, [%3+4];\\n\\tld.global.nc.f32 %2, [%3+8];"
             : "=f"(x), "=f"(y), "=f"(z) : "l"(f));
return wp::vec3(x, y, z);
#else
return a.data[p];
#endif
""")
def load_vec3_now(a: wp.array(dtype=wp.vec3), p: int) -> wp.vec3:
    """``a[p]`` of a contiguous vec3 array, its three 4-byte loads issued here on CUDA (not moved)."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
const float* f = reinterpret_cast<const float*>(a.data) + 2 * p;
float x, y;
asm volatile("ld.global.nc.v2.f32 {%0, %1}, [%2];" : "=f"(x), "=f"(y) : "l"(f));
return wp::vec2(x, y);
#else
return a.data[p];
#endif
""")
def load_vec2_now(a: wp.array(dtype=wp.vec2), p: int) -> wp.vec2:
    """``a[p]`` of a contiguous vec2 array in one 8-byte load issued here on CUDA (not moved)."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
return __any_sync(__activemask(), x);
#else
return x;
#endif
""")
def warp_any(x: bool) -> int:
    """1 if ``x`` holds on any active lane of the warp (CUDA), else 0; on the CPU ``x`` itself."""
    ...


@wp.func
def surface_depth(depth: wp.array(dtype=wp.float32), tri_id: wp.array(dtype=wp.int32), q: int) -> float:
    """Depth [m] of pixel ``q`` as every later stage sees it: the G-buffer's where it has a surface (depth > 0
    and ``tri_id`` >= 0), else 0."""
    z = depth[q]
    t = tri_id[q]
    return wp.where(z > 0.0 and t >= 0, z, 0.0)


@wp.func_native("""
#if defined(__CUDA_ARCH__)
return __ffs(step) - 1;
#else
return __builtin_ctz((unsigned)step);
#endif
""")
def step_shift(step: int) -> int:
    """log2 of a power of two ``step`` > 0 (one instruction pair on CUDA)."""
    ...


@wp.func
def lattice_index(y: int, x: int, width: int, height: int, step: int) -> int:
    """Index of pixel (y, x) (>= 0) in the sub-lattice-major order of tap spacing ``step``, a power of two:
    sub-lattice (y mod step, x mod step) after sub-lattice, each ceil(height/step) x ceil(width/step) points
    row-major (points past the image unused; :func:`.kernels_atrous.lattice_size` entries in all). Shifts and masks,
    not the integer divisions by a runtime ``step`` (~20 instructions each on CUDA, six of them)."""
    k = step_shift(step)
    mask = step - 1
    sub_h = (height + mask) >> k
    sub_w = (width + mask) >> k
    return ((((y & mask) << k) + (x & mask)) * sub_h + (y >> k)) * sub_w + (x >> k)



@wp.func
def one_sided_slope(z: float, z_lo: float, z_hi: float) -> float:
    """|dz/dpixel| along one axis from the depths ``z_lo``, ``z_hi`` of the two neighbours (0: no surface, or off
    the image): the smaller one-sided difference to a neighbour with a surface, 0 without one. The smaller of
    the two is taken so that a depth edge on one side does not inflate the slope."""
    s = wp.where(z_lo > 0.0, wp.abs(z - z_lo), -1.0)
    d = wp.abs(z_hi - z)
    s = wp.where(z_hi > 0.0, wp.where(s < 0.0, d, wp.min(s, d)), s)
    return wp.max(s, 0.0)


@wp.func
def depth_gradient_length(depth: wp.array(dtype=wp.float32), tri_id: wp.array(dtype=wp.int32), z: float, x: int,
                          y: int, width: int, height: int) -> float:
    """‖∇z‖ [m/pixel] of linear depth at pixel (x, y), whose depth ``z`` > 0 (paper eq. 3's ∇z; Falcor stores
    max(|ddx|, |ddy|)), over the neighbours with a surface (:func:`surface_depth`). The four neighbours are read
    at clamped indices, unconditionally, and masked after: their loads are in flight together."""
    p = y * width + x
    z_l = surface_depth(depth, tri_id, wp.where(x > 0, p - 1, p))
    z_r = surface_depth(depth, tri_id, wp.where(x < width - 1, p + 1, p))
    z_u = surface_depth(depth, tri_id, wp.where(y > 0, p - width, p))
    z_d = surface_depth(depth, tri_id, wp.where(y < height - 1, p + width, p))
    gx = one_sided_slope(z, wp.where(x > 0, z_l, 0.0), wp.where(x < width - 1, z_r, 0.0))
    gy = one_sided_slope(z, wp.where(y > 0, z_u, 0.0), wp.where(y < height - 1, z_d, 0.0))
    return wp.sqrt(gx * gx + gy * gy)


@wp.func
def edge_stop_depth_normal(z_p: float, z_q: float, phi_z: float, n_p: wp.vec3, n_q: wp.vec3,
                           sigma_normal: float) -> float:
    """Geometric edge-stopping weight: exp(-|z_p - z_q| / phi_z) · max(0, n_p·n_q)^sigma_n (paper eqs. 3, 4)."""
    w_n = wp.pow(wp.max(wp.dot(n_p, n_q), 0.0), sigma_normal)
    return wp.exp(-wp.abs(z_p - z_q) / phi_z) * w_n


@wp.func
def write_guides(depth: wp.array(dtype=wp.float32), tri_id: wp.array(dtype=wp.int32), n: wp.vec3, z: float,
                 surface: bool, x: int, y: int, width: int, height: int, hist_guide: wp.array(dtype=wp.vec4),
                 guide_at: int, lattice_a: int, lattice_b: int, slope_out: wp.array(dtype=wp.float32),
                 guide_lattice_a: wp.array(dtype=wp.vec4), guide_lattice_b: wp.array(dtype=wp.vec4)):
    """Pixel (x, y)'s guide (n, z) (0 without a surface) into ``hist_guide[guide_at]`` and the lattices of
    ``lattice_a`` / ``lattice_b`` (where != 0), its ‖∇z‖ into ``slope_out``: :func:`reproject`'s G-buffer part."""
    p = y * width + x
    slope = wp.where(surface, depth_gradient_length(depth, tri_id, z, x, y, width, height), 0.0)
    g = wp.where(surface, wp.vec4(n[0], n[1], n[2], z), wp.vec4(0.0))
    if lattice_a != 0:
        store_vec4(guide_lattice_a, lattice_index(y, x, width, height, lattice_a), g)
    if lattice_b != 0:
        store_vec4(guide_lattice_b, lattice_index(y, x, width, height, lattice_b), g)
    store_vec4(hist_guide, guide_at, g)
    slope_out[p] = slope


@wp.kernel
def reproject_guides(
    depth: wp.array(dtype=wp.float32),
    normal: wp.array(dtype=wp.vec3),
    tri_id: wp.array(dtype=wp.int32),
    parity: wp.array(dtype=wp.int32),
    width: int,
    height: int,
    lattice_a: int,
    lattice_b: int,
    hist_guide: wp.array(dtype=wp.vec4),
    slope_out: wp.array(dtype=wp.float32),
    guide_lattice_a: wp.array(dtype=wp.vec4),
    guide_lattice_b: wp.array(dtype=wp.vec4),
):
    """:func:`reproject`'s writes that read the G-buffer alone (the guide into row ``1 - parity[0]`` of
    ``hist_guide``, its sub-lattice-major copies, ``slope_out``), the same values: launched before the photons are
    known (beside them, in ``Renderer``'s concurrent program), then :func:`reproject` with ``guides_written``."""
    y, x = wp.tid()
    p = y * width + x
    z = depth[p]
    surface = z > 0.0 and tri_id[p] >= 0
    n = wp.vec3(0.0)
    if surface:
        n = normal[p]
    write_guides(depth, tri_id, n, z, surface, x, y, width, height, hist_guide, (1 - parity[0]) * width * height + p,
                 lattice_a, lattice_b, slope_out, guide_lattice_a, guide_lattice_b)


@wp.kernel
def reproject(
    irradiance: wp.array(dtype=wp.vec3),
    depth: wp.array(dtype=wp.float32),
    normal: wp.array(dtype=wp.vec3),
    motion: wp.array(dtype=wp.vec2),
    tri_id: wp.array(dtype=wp.int32),
    hist_guide: wp.array(dtype=wp.vec4),
    hist_color: wp.array2d(dtype=wp.vec3),
    hist_moments: wp.array2d(dtype=wp.vec2),
    hist_length: wp.array2d(dtype=wp.int32),
    parity: wp.array(dtype=wp.int32),
    width: int,
    height: int,
    alpha_color: float,
    alpha_moments: float,
    max_history: int,
    depth_tolerance: float,
    normal_tolerance: float,
    write_integrated: int,
    write_variance: int,
    lattice_a: int,
    lattice_b: int,
    guides_written: int,
    color_variance_out: wp.array(dtype=wp.vec4),
    slope_out: wp.array(dtype=wp.float32),
    integrated: wp.array(dtype=wp.vec3),
    variance_out: wp.array(dtype=wp.float32),
    guide_lattice_a: wp.array(dtype=wp.vec4),
    guide_lattice_b: wp.array(dtype=wp.vec4),
):
    """Temporal accumulation (Falcor SVGFReproject), and the per-pixel part of FilterMoments.

    Reads: ``irradiance`` (H*W vec3 [W/m²], this frame's noisy signal); G-buffer ``depth`` (float32 [m],
    0 = none), ``normal`` (vec3, unit), ``motion`` (vec2 [pixels]: previous position minus pixel centre),
    ``tri_id`` (int32, -1 = none); row ``parity[0]`` of the history (rows of H*W each): ``hist_guide`` (vec4
    (n, z [m]), 2*H*W, row r at r*H*W: this pass's own G-buffer copy; z = 0 = no surface), ``hist_color`` (vec3
    [W/m²], colour history), ``hist_moments`` (vec2: luminance mean and mean square), ``hist_length`` (int32
    [frames]).

    Writes (H*W each): into row ``1 - parity[0]`` of the history, which this frame's later stages and the next
    frame read, the guide (vec4 (n, z) [m], 0 without a surface: the G-buffer copy the filters use; no surface
    where depth <= 0 or ``tri_id`` < 0; one copy, not a per-frame one besides), the moments (vec2) and the history
    length (int32 [frames], 1 on disocclusion, 0 without a surface); ``color_variance_out`` (vec4: the accumulated
    colour [W/m²] and, with a history of at least ``SPATIAL_VARIANCE_HISTORY`` frames, the temporal luminance
    variance E[l²] − E[l]², the first à-trous level's packed input; (0, 0, 0, −1) without a surface; below that
    history :func:`filter_moments` writes the variance), ``slope_out`` (float32 [m/pixel], ‖∇z‖ for the à-trous
    levels); with ``write_integrated`` the colour alone, ``integrated`` (vec3 [W/m²]); with ``write_variance`` the
    temporal variance, ``variance_out`` (float32; 0 without a surface); the guide again in the sub-lattice-major
    order of step ``lattice_a`` into ``guide_lattice_a`` and of ``lattice_b`` into ``guide_lattice_b`` (each where
    != 0; :func:`lattice_index`), which those à-trous levels read. With ``guides_written`` the guide (row
    ``1 - parity[0]``), its lattice copies and ``slope_out`` are :func:`reproject_guides`' already (launched earlier
    in the frame, from the G-buffer alone): not written again, the rest the same.

    A previous-frame tap is consistent when it lies on screen, has a surface, its depth is within
    ``depth_tolerance`` (relative) of this pixel's and its normal's cosine to this one's is at least
    ``normal_tolerance``. The 2x2 bilinear taps that pass are renormalised; none → disoccluded.

    Loads are issued in two rounds, not four: the pixel's own G-buffer, motion and signal and its four neighbours'
    depths before the surface test, and every history value of a tap (guide, colour, moments, length) together,
    before the consistency test that decides whether they count (a tap that fails it adds 0).
    """
    y, x = wp.tid()
    p = y * width + x
    pixels = width * height
    prev = parity[0]
    cur = 1 - prev
    z = depth[p]
    t_id = tri_id[p]
    surface = z > 0.0 and t_id >= 0
    if warp_any(surface) == 0:  # a warp without a surface (uniform: the loads below are not issued for it)
        if guides_written == 0:
            if lattice_a != 0:
                store_vec4(guide_lattice_a, lattice_index(y, x, width, height, lattice_a), wp.vec4(0.0))
            if lattice_b != 0:
                store_vec4(guide_lattice_b, lattice_index(y, x, width, height, lattice_b), wp.vec4(0.0))
            slope_out[p] = 0.0
            store_vec4(hist_guide, cur * pixels + p, wp.vec4(0.0))
        store_vec4(color_variance_out, p, wp.vec4(0.0, 0.0, 0.0, -1.0))
        hist_moments[cur, p] = wp.vec2(0.0)
        hist_length[cur, p] = 0
        if write_integrated != 0:
            integrated[p] = wp.vec3(0.0)
        if write_variance != 0:
            variance_out[p] = 0.0
        return
    # every pixel of a warp with a surface takes the one path below, its values selected by `surface` (no branch
    # on it), so that the pixel's own loads are all issued before the history's
    n = load_vec3_now(normal, p)
    m = load_vec2_now(motion, p)
    c = load_vec3_now(irradiance, p)
    if guides_written == 0:
        write_guides(depth, tri_id, n, z, surface, x, y, width, height, hist_guide, cur * pixels + p, lattice_a,
                     lattice_b, slope_out, guide_lattice_a, guide_lattice_b)

    # previous position in pixel units with pixel centres on integers
    px = float(x) + m[0]
    py = float(y) + m[1]
    fx0 = wp.floor(px)
    fy0 = wp.floor(py)
    fx = px - fx0
    fy = py - fy0
    x0 = int(fx0)
    y0 = int(fy0)

    sum_w = float(0.0)
    color_prev = wp.vec3(0.0)
    moments_prev = wp.vec2(0.0)
    best_w = float(-1.0)
    history_prev = int(0)
    for tap in range(4):
        dx = tap % 2
        dy = tap // 2
        tx = x0 + dx
        ty = y0 + dy
        w = wp.where(dx == 1, fx, 1.0 - fx) * wp.where(dy == 1, fy, 1.0 - fy)
        # a tap of weight 0 (a still pixel's three others) adds nothing, and is never the best tap where the
        # history is kept (some tap of weight > 0 is, or the sum stays under MIN_BILINEAR_WEIGHT): not read
        if surface and w > 0.0 and tx >= 0 and tx < width and ty >= 0 and ty < height:
            q = ty * width + tx
            g_q = load_vec4(hist_guide, prev * pixels + q)
            c_q = hist_color[prev, q]
            m_q = hist_moments[prev, q]
            h_q = hist_length[prev, q]
            z_q = g_q[3]
            n_q = wp.vec3(g_q[0], g_q[1], g_q[2])
            # the test selects, it does not branch: the tap's four loads stay in flight together
            ok = z_q > 0.0 and wp.abs(z_q - z) <= depth_tolerance * z and wp.dot(n_q, n) >= normal_tolerance
            w_ok = wp.where(ok, w, 0.0)
            sum_w += w_ok
            color_prev += w_ok * c_q
            moments_prev += w_ok * m_q
            better = ok and w > best_w
            history_prev = wp.where(better, h_q, history_prev)
            best_w = wp.where(better, w, best_w)

    lum = luminance(c)
    m_new = wp.vec2(lum, lum * lum)
    h = int(1)  # disoccluded: this frame alone
    if sum_w >= MIN_BILINEAR_WEIGHT:
        h = wp.min(history_prev + 1, max_history)
        a = wp.max(1.0 / float(h), alpha_color)  # equal weights while history is short
        a_m = wp.max(1.0 / float(h), alpha_moments)
        m_new = wp.lerp(moments_prev / sum_w, m_new, a_m)
        c = wp.lerp(color_prev / sum_w, c, a)
    h = wp.where(surface, h, 0)
    m_new = wp.where(surface, m_new, wp.vec2(0.0))
    c = wp.where(surface, c, wp.vec3(0.0))
    hist_moments[cur, p] = m_new
    hist_length[cur, p] = h
    if write_integrated != 0:
        integrated[p] = c
    var = float(0.0)  # below SPATIAL_VARIANCE_HISTORY filter_moments writes it
    if h >= SPATIAL_VARIANCE_HISTORY:
        var = wp.max(m_new[1] - m_new[0] * m_new[0], 0.0)
    if write_variance != 0:
        variance_out[p] = var
    store_vec4(color_variance_out, p, wp.vec4(c[0], c[1], c[2], wp.where(surface, var, -1.0)))


#: pixels of a row that one thread of :func:`filter_moments` takes (most need nothing: four loads a thread instead
#: of a thread a load, which the launch's cost followed)
MOMENTS_RUN = wp.constant(4)


@wp.func
def spatial_variance(moments: wp.array(dtype=wp.vec2), guide: wp.array(dtype=wp.vec4), guide_row: int,
                     slope: wp.array(dtype=wp.float32), x: int, y: int, width: int, height: int, sigma_depth: float,
                     sigma_normal: float, h: int) -> float:
    """The spatial luminance variance of pixel (x, y) (with a surface, history ``h`` frames): its moments averaged
    over a 7x7 bilateral neighbourhood weighted by depth and normal (paper section 4.2), boosted by 4/h; the guide
    (n, z) of pixel q at ``guide[guide_row + q]``."""
    p = y * width + x
    g = load_vec4(guide, guide_row + p)
    z = g[3]
    n = wp.vec3(g[0], g[1], g[2])
    slope_p = slope[p]
    sum_w = float(0.0)
    sum_m = wp.vec2(0.0)
    for dy in range(-SPATIAL_VARIANCE_RADIUS, SPATIAL_VARIANCE_RADIUS + 1):
        for dx in range(-SPATIAL_VARIANCE_RADIUS, SPATIAL_VARIANCE_RADIUS + 1):
            qx = x + dx
            qy = y + dy
            if qx >= 0 and qx < width and qy >= 0 and qy < height:
                q = qy * width + qx
                g_q = load_vec4(guide, guide_row + q)
                z_q = g_q[3]
                if z_q > 0.0:
                    dist = wp.sqrt(float(dx * dx + dy * dy))
                    phi_z = sigma_depth * (slope_p * dist + DEPTH_NOISE_REL * z)
                    w = edge_stop_depth_normal(z, z_q, phi_z, n, wp.vec3(g_q[0], g_q[1], g_q[2]), sigma_normal)
                    sum_w += w
                    sum_m += w * moments[q]
    sum_m = sum_m / sum_w  # the centre pixel has weight 1
    return wp.max(sum_m[1] - sum_m[0] * sum_m[0], 0.0) * float(SPATIAL_VARIANCE_HISTORY) / float(h)


@wp.kernel
def filter_moments(
    hist_moments: wp.array2d(dtype=wp.vec2),
    hist_length: wp.array2d(dtype=wp.int32),
    parity: wp.array(dtype=wp.int32),
    hist_guide: wp.array(dtype=wp.vec4),
    slope: wp.array(dtype=wp.float32),
    width: int,
    height: int,
    sigma_depth: float,
    sigma_normal: float,
    variance_out: wp.array(dtype=wp.float32),
    color_variance: wp.array(dtype=wp.vec4),
):
    """The spatial luminance variance of FilterMoments (Falcor SVGFFilterMoments) where the history is short;
    ``dim=(height, ceil(width / MOMENTS_RUN))``, a thread the ``MOMENTS_RUN`` pixels of a row from x = tid *
    ``MOMENTS_RUN``.

    Reads the outputs of :func:`reproject` (row ``1 - parity[0]`` of ``hist_moments`` vec2, ``hist_length``
    int32 [frames], 2 x H*W each, and ``hist_guide`` vec4 (n, z [m]), 2*H*W, row r at r*H*W, z = 0 = no surface;
    ``slope`` float32 [m/pixel]). For a pixel with a surface and a history below
    ``SPATIAL_VARIANCE_HISTORY`` frames it writes the variance (:func:`spatial_variance`) into ``variance_out``
    (float32) and the Var of its packed ``color_variance`` (vec4: colour, Var); every other pixel keeps what
    :func:`reproject` wrote there (the temporal variance E[l²] − E[l]²).

    Unlike Falcor, the colour is not replaced by the moments' neighbourhood average (the paper only estimates
    variance here; the à-trous levels do the spatial filtering, and the colour stays untouched by any filter that
    does not conserve energy), and Falcor's luminance term in absolute units, which has no meaning for W/m², is
    left out.
    """
    y, i = wp.tid()
    cur = 1 - parity[0]
    moments = hist_moments[cur]
    history = hist_length[cur]
    x0 = i * MOMENTS_RUN
    p0 = y * width + x0
    run = wp.min(width - x0, MOMENTS_RUN)  # pixels of the row from x0
    need = int(0)  # bit k: pixel x0 + k needs the spatial variance
    for k in range(MOMENTS_RUN):  # unrolled: the loads in flight together
        h = history[p0 + wp.min(k, run - 1)]
        if k < run and h > 0 and h < SPATIAL_VARIANCE_HISTORY:
            need = need | (1 << k)
    if need == 0:
        return
    k = int(0)
    while k < run:
        if ((need >> k) & 1) != 0:
            p = p0 + k
            h = history[p]
            var = spatial_variance(moments, hist_guide, cur * width * height, slope, x0 + k, y, width, height,
                                   sigma_depth, sigma_normal, h)
            variance_out[p] = var
            cv = color_variance[p]
            color_variance[p] = wp.vec4(cv[0], cv[1], cv[2], var)
        k += 1


@wp.kernel
def store_history(color: wp.array(dtype=wp.vec3), parity: wp.array(dtype=wp.int32),
                  hist_color: wp.array2d(dtype=wp.vec3)):
    """Colour history of this frame: ``color`` (H*W vec3 [W/m²], read) into row ``1 - parity[0]`` of
    ``hist_color`` (2 x H*W vec3, written)."""
    p = wp.tid()
    hist_color[1 - parity[0], p] = color[p]


@wp.kernel
def flip_parity(parity: wp.array(dtype=wp.int32)):
    """End of frame: the row just written becomes the one the next frame reads (``parity``: 1 int32)."""
    parity[0] = 1 - parity[0]
