"""Warp kernels of SVGF (Schied et al. 2017) for caustic irradiance, one per Falcor SVGFPass stage.

Stages (Falcor ``RenderPasses/SVGFPass``): :func:`reproject` (temporal accumulation of colour and
luminance moments), :func:`filter_moments` (variance: temporal, or spatial where history is short;
depth slope), then per à-trous level :func:`blur_variance`, :func:`atrous_weight_sum` and :func:`atrous`
(the variance-guided wavelet, made energy-conserving: see :func:`atrous`). Falcor's FinalModulate
multiplies by albedo; the signal here is irradiance [W/m²], never demodulated, so it has no such stage.

Every image is a flat array of ``height * width`` pixels, row-major, row 0 at the top; kernels are
launched with ``dim=(height, width)``. A pixel *has a surface* when its depth is > 0 (the reproject
stage writes depth 0 where the G-buffer has ``tri_id < 0``), and pixels without one are excluded from
every neighbourhood and come out 0.
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


@wp.func
def one_sided_slope(depth: wp.array(dtype=wp.float32), p: int, z: float, q_lo: int, ok_lo: bool,
                    q_hi: int, ok_hi: bool) -> float:
    """|dz/dpixel| along one axis: the smaller one-sided difference to a neighbour with a surface.

    The smaller of the two is taken so that a depth edge on one side does not inflate the slope.
    """
    s = float(-1.0)
    if ok_lo:
        z_lo = depth[q_lo]
        if z_lo > 0.0:
            s = wp.abs(z - z_lo)
    if ok_hi:
        z_hi = depth[q_hi]
        if z_hi > 0.0:
            d = wp.abs(z_hi - z)
            s = wp.where(s < 0.0, d, wp.min(s, d))
    return wp.max(s, 0.0)


@wp.func
def depth_gradient_length(depth: wp.array(dtype=wp.float32), x: int, y: int, width: int, height: int) -> float:
    """‖∇z‖ [m/pixel] of linear depth at pixel (x, y) (paper eq. 3's ∇z; Falcor stores max(|ddx|, |ddy|))."""
    p = y * width + x
    z = depth[p]
    gx = one_sided_slope(depth, p, z, p - 1, x > 0, p + 1, x < width - 1)
    gy = one_sided_slope(depth, p, z, p - width, y > 0, p + width, y < height - 1)
    return wp.sqrt(gx * gx + gy * gy)


@wp.func
def edge_stop_depth_normal(z_p: float, z_q: float, phi_z: float, n_p: wp.vec3, n_q: wp.vec3,
                           sigma_normal: float) -> float:
    """Geometric edge-stopping weight: exp(-|z_p - z_q| / phi_z) · max(0, n_p·n_q)^sigma_n (paper eqs. 3, 4)."""
    w_n = wp.pow(wp.max(wp.dot(n_p, n_q), 0.0), sigma_normal)
    return wp.exp(-wp.abs(z_p - z_q) / phi_z) * w_n


@wp.kernel
def reproject(
    irradiance: wp.array(dtype=wp.vec3),
    depth: wp.array(dtype=wp.float32),
    normal: wp.array(dtype=wp.vec3),
    motion: wp.array(dtype=wp.vec2),
    tri_id: wp.array(dtype=wp.int32),
    prev_depth: wp.array(dtype=wp.float32),
    prev_normal: wp.array(dtype=wp.vec3),
    prev_color: wp.array(dtype=wp.vec3),
    prev_moments: wp.array(dtype=wp.vec2),
    prev_history: wp.array(dtype=wp.int32),
    width: int,
    height: int,
    alpha_color: float,
    alpha_moments: float,
    max_history: int,
    depth_tolerance: float,
    normal_tolerance: float,
    cur_depth: wp.array(dtype=wp.float32),
    cur_normal: wp.array(dtype=wp.vec3),
    integrated: wp.array(dtype=wp.vec3),
    moments: wp.array(dtype=wp.vec2),
    history: wp.array(dtype=wp.int32),
):
    """Temporal accumulation (Falcor SVGFReproject).

    Reads: ``irradiance`` (H*W vec3 [W/m²], this frame's noisy signal); G-buffer ``depth`` (float32 [m],
    0 = none), ``normal`` (vec3, unit), ``motion`` (vec2 [pixels]: previous position minus pixel centre),
    ``tri_id`` (int32, -1 = none); the previous frame's ``prev_depth``/``prev_normal`` (this pass's own
    copies; depth 0 = no surface), ``prev_color`` (vec3 [W/m²], colour history), ``prev_moments``
    (vec2: luminance mean and mean square), ``prev_history`` (int32 [frames]).

    Writes: ``cur_depth``/``cur_normal`` (the G-buffer copy the next frame reprojects against and the
    later stages filter with; depth 0 where ``tri_id < 0``), ``integrated`` (vec3 [W/m²]),
    ``moments`` (vec2) and ``history`` (int32 [frames], 1 on disocclusion, 0 without a surface).

    A previous-frame tap is consistent when it lies on screen, has a surface, its depth is within
    ``depth_tolerance`` (relative) of this pixel's and its normal's cosine to this one's is at least
    ``normal_tolerance``. The 2x2 bilinear taps that pass are renormalised; none → disoccluded.
    """
    y, x = wp.tid()
    p = y * width + x
    z = depth[p]
    if z <= 0.0 or tri_id[p] < 0:
        cur_depth[p] = 0.0
        cur_normal[p] = wp.vec3(0.0)
        integrated[p] = wp.vec3(0.0)
        moments[p] = wp.vec2(0.0)
        history[p] = 0
        return
    n = normal[p]
    cur_depth[p] = z
    cur_normal[p] = n

    # previous position in pixel units with pixel centres on integers
    m = motion[p]
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
        if tx >= 0 and tx < width and ty >= 0 and ty < height:
            q = ty * width + tx
            z_q = prev_depth[q]
            if z_q > 0.0 and wp.abs(z_q - z) <= depth_tolerance * z and wp.dot(prev_normal[q], n) >= normal_tolerance:
                w = wp.where(dx == 1, fx, 1.0 - fx) * wp.where(dy == 1, fy, 1.0 - fy)
                sum_w += w
                color_prev += w * prev_color[q]
                moments_prev += w * prev_moments[q]
                if w > best_w:
                    best_w = w
                    history_prev = prev_history[q]

    c = irradiance[p]
    lum = luminance(c)
    m_now = wp.vec2(lum, lum * lum)
    if sum_w >= MIN_BILINEAR_WEIGHT:
        h = wp.min(history_prev + 1, max_history)
        a = wp.max(1.0 / float(h), alpha_color)  # equal weights while history is short
        a_m = wp.max(1.0 / float(h), alpha_moments)
        integrated[p] = wp.lerp(color_prev / sum_w, c, a)
        moments[p] = wp.lerp(moments_prev / sum_w, m_now, a_m)
        history[p] = h
    else:  # disoccluded
        integrated[p] = c
        moments[p] = m_now
        history[p] = 1


@wp.kernel
def filter_moments(
    moments: wp.array(dtype=wp.vec2),
    history: wp.array(dtype=wp.int32),
    depth: wp.array(dtype=wp.float32),
    normal: wp.array(dtype=wp.vec3),
    width: int,
    height: int,
    sigma_depth: float,
    sigma_normal: float,
    variance_out: wp.array(dtype=wp.float32),
    slope_out: wp.array(dtype=wp.float32),
):
    """Per-pixel luminance variance (Falcor SVGFFilterMoments) and depth slope.

    Reads the outputs of :func:`reproject` (``moments`` vec2, ``history`` int32) and its G-buffer copy
    (``depth`` [m], 0 = none; ``normal``). Writes ``variance_out`` (float32, luminance variance) and
    ``slope_out`` (float32 [m/pixel], ‖∇z‖ for the à-trous levels).

    With at least ``SPATIAL_VARIANCE_HISTORY`` frames the variance is temporal, E[l²] − E[l]². Below
    that, the moments are averaged over a 7x7 bilateral neighbourhood weighted by depth and normal
    (paper section 4.2) and the variance boosted by 4/h. Unlike Falcor, the colour is not replaced by
    that average (the paper only estimates variance here; the à-trous levels do the spatial filtering,
    and the colour stays untouched by any filter that does not conserve energy), and Falcor's luminance
    term in absolute units, which has no meaning for W/m², is left out.
    """
    y, x = wp.tid()
    p = y * width + x
    z = depth[p]
    if z <= 0.0:
        variance_out[p] = 0.0
        slope_out[p] = 0.0
        return
    slope = depth_gradient_length(depth, x, y, width, height)
    slope_out[p] = slope
    h = history[p]
    if h >= SPATIAL_VARIANCE_HISTORY:
        mo = moments[p]
        variance_out[p] = wp.max(mo[1] - mo[0] * mo[0], 0.0)
        return

    n = normal[p]
    sum_w = float(0.0)
    sum_m = wp.vec2(0.0)
    for dy in range(-SPATIAL_VARIANCE_RADIUS, SPATIAL_VARIANCE_RADIUS + 1):
        for dx in range(-SPATIAL_VARIANCE_RADIUS, SPATIAL_VARIANCE_RADIUS + 1):
            qx = x + dx
            qy = y + dy
            if qx >= 0 and qx < width and qy >= 0 and qy < height:
                q = qy * width + qx
                z_q = depth[q]
                if z_q > 0.0:
                    dist = wp.sqrt(float(dx * dx + dy * dy))
                    phi_z = sigma_depth * (slope * dist + DEPTH_NOISE_REL * z)
                    w = edge_stop_depth_normal(z, z_q, phi_z, n, normal[q], sigma_normal)
                    sum_w += w
                    sum_m += w * moments[q]
    sum_m = sum_m / sum_w  # the centre pixel has weight 1
    variance_out[p] = wp.max(sum_m[1] - sum_m[0] * sum_m[0], 0.0) * float(SPATIAL_VARIANCE_HISTORY) / float(h)


@wp.kernel
def blur_variance(
    variance: wp.array(dtype=wp.float32),
    depth: wp.array(dtype=wp.float32),
    width: int,
    height: int,
    variance_blurred: wp.array(dtype=wp.float32),
):
    """Variance under a 3x3 Gaussian (1/4, 1/8, 1/16) over pixels with a surface, renormalised (paper
    eq. 5's g3x3). Reads ``variance`` (H*W float32), ``depth`` ([m], 0 = none); writes ``variance_blurred``."""
    y, x = wp.tid()
    p = y * width + x
    if depth[p] <= 0.0:
        variance_blurred[p] = 0.0
        return
    sum_w = float(0.0)
    sum_v = float(0.0)
    for dy in range(-1, 2):
        for dx in range(-1, 2):
            qx = x + dx
            qy = y + dy
            if qx >= 0 and qx < width and qy >= 0 and qy < height:
                q = qy * width + qx
                if depth[q] > 0.0:
                    k = wp.where(dx == 0, 0.5, 0.25) * wp.where(dy == 0, 0.5, 0.25)
                    sum_w += k
                    sum_v += k * variance[q]
    variance_blurred[p] = sum_v / sum_w


@wp.func
def atrous_weight(color_in: wp.array(dtype=wp.vec3), variance_blurred: wp.array(dtype=wp.float32),
                  depth: wp.array(dtype=wp.float32), normal: wp.array(dtype=wp.vec3), slope: wp.array(dtype=wp.float32),
                  p: int, q: int, dx: int, dy: int, step: int,
                  sigma_depth: float, sigma_normal: float, sigma_luminance: float) -> float:
    """w_pq of the à-trous level, symmetric in p and q (see :func:`atrous`); q must have a surface."""
    z_p = depth[p]
    z_q = depth[q]
    dist = float(step) * wp.sqrt(float(dx * dx + dy * dy))
    phi_z = sigma_depth * (wp.max(slope[p], slope[q]) * dist + DEPTH_NOISE_REL * wp.max(z_p, z_q))
    phi_l = sigma_luminance * wp.sqrt(0.5 * wp.max(variance_blurred[p] + variance_blurred[q], 0.0) + VARIANCE_EPS)
    w_geo = edge_stop_depth_normal(z_p, z_q, phi_z, normal[p], normal[q], sigma_normal)
    w_lum = wp.exp(-wp.abs(luminance(color_in[p]) - luminance(color_in[q])) / phi_l)
    return b3_spline(dx) * b3_spline(dy) * w_geo * w_lum


@wp.kernel
def atrous_weight_sum(
    color_in: wp.array(dtype=wp.vec3),
    variance_blurred: wp.array(dtype=wp.float32),
    depth: wp.array(dtype=wp.float32),
    normal: wp.array(dtype=wp.vec3),
    slope: wp.array(dtype=wp.float32),
    width: int,
    height: int,
    step: int,
    sigma_depth: float,
    sigma_normal: float,
    sigma_luminance: float,
    weight_sum: wp.array(dtype=wp.float32),
):
    """W_p = Σ_q w_pq over the level's taps, centre ((3/8)², every edge stop 1) included; 0 without a surface.

    Reads the same arrays as :func:`atrous`; writes ``weight_sum`` (H*W float32, in (0, 1]).
    """
    y, x = wp.tid()
    p = y * width + x
    if depth[p] <= 0.0:
        weight_sum[p] = 0.0
        return
    sum_w = b3_spline(0) * b3_spline(0)
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            qx = x + dx * step
            qy = y + dy * step
            if (dx != 0 or dy != 0) and qx >= 0 and qx < width and qy >= 0 and qy < height:
                q = qy * width + qx
                if depth[q] > 0.0:
                    sum_w += atrous_weight(color_in, variance_blurred, depth, normal, slope, p, q, dx, dy, step,
                                           sigma_depth, sigma_normal, sigma_luminance)
    weight_sum[p] = sum_w


@wp.kernel
def atrous(
    color_in: wp.array(dtype=wp.vec3),
    variance_in: wp.array(dtype=wp.float32),
    variance_blurred: wp.array(dtype=wp.float32),
    depth: wp.array(dtype=wp.float32),
    normal: wp.array(dtype=wp.vec3),
    slope: wp.array(dtype=wp.float32),
    weight_sum: wp.array(dtype=wp.float32),
    width: int,
    height: int,
    step: int,
    sigma_depth: float,
    sigma_normal: float,
    sigma_luminance: float,
    conserve_energy: int,
    color_out: wp.array(dtype=wp.vec3),
    variance_out: wp.array(dtype=wp.float32),
):
    """One level of the edge-avoiding à-trous wavelet (paper section 4.3; Falcor SVGFAtrous).

    Reads ``color_in`` (H*W vec3 [W/m²]), ``variance_in`` (float32, luminance variance) and its 3x3 blur
    ``variance_blurred``, the G-buffer copy ``depth`` ([m], 0 = none) and ``normal``, ``slope``
    (float32 [m/pixel], ‖∇z‖) and ``weight_sum`` (float32, W from :func:`atrous_weight_sum`). Writes
    ``color_out`` and ``variance_out``; they must not alias the inputs.

    Taps q are 5x5 at ``step`` pixels apart, each with the B3-spline weight h(dx)·h(dy) times

        w_pq = exp(-|z_p - z_q| / (σ_z max(‖∇z_p‖, ‖∇z_q‖) ‖p - q‖ + ε_z)
                   - |l_p - l_q| / (σ_l sqrt((g3x3(Var)_p + g3x3(Var)_q) / 2) + ε_l)) · max(0, n_p·n_q)^σ_n

    (‖∇z‖‖p−q‖ bounds the paper's |∇z·(p−q)| as Falcor does). Each factor is made symmetric in p and
    q, so w_pq = w_qp; where p and q agree they are the paper's one-sided factors.

    The level is c'_p = Σ_q A_pq c_q = c_p + Σ_{q≠p} A_pq (c_q − c_p) with A_pp = 1 − Σ_{q≠p} A_pq, and
    Var'_p = Σ_q A_pq² Var_q, where for q ≠ p

    * ``conserve_energy == 0``: A_pq = w_pq / W_p, the paper's normalised gather Σ w c / Σ w. A constant
      stays constant, but the luminance weights depend on the signal and A is not symmetric, so the
      image mean is biased (sparse photon maps lose several per cent, compounded through the history);
    * ``conserve_energy != 0``: A_pq = w_pq / max(W_p, W_q), symmetric, so what p takes from q, q gives
      to p and Σ_p c'_p = Σ_p c_p exactly. A constant still stays constant, Σ_{q≠p} A_pq ≤ 1 − w_pp / W_p
      keeps it a convex combination (no negative irradiance), and where neighbours' W agree it is the
      paper's filter. Where they differ (silhouettes, image borders) the pixel with the larger W sets
      the exchange, so the pixel with the smaller one keeps more of itself.
    """
    y, x = wp.tid()
    p = y * width + x
    if depth[p] <= 0.0:
        color_out[p] = wp.vec3(0.0)
        variance_out[p] = 0.0
        return
    c_p = color_in[p]
    w_p = weight_sum[p]
    sum_a = float(0.0)  # Σ_{q≠p} A_pq
    sum_dc = wp.vec3(0.0)  # Σ_{q≠p} A_pq (c_q − c_p)
    sum_av = float(0.0)  # Σ_{q≠p} A_pq² Var_q
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            qx = x + dx * step
            qy = y + dy * step
            if (dx != 0 or dy != 0) and qx >= 0 and qx < width and qy >= 0 and qy < height:
                q = qy * width + qx
                if depth[q] > 0.0:
                    w = atrous_weight(color_in, variance_blurred, depth, normal, slope, p, q, dx, dy, step,
                                      sigma_depth, sigma_normal, sigma_luminance)
                    a = w / wp.where(conserve_energy != 0, wp.max(w_p, weight_sum[q]), w_p)
                    sum_a += a
                    sum_dc += a * (color_in[q] - c_p)
                    sum_av += a * a * variance_in[q]
    a_centre = 1.0 - sum_a
    color_out[p] = c_p + sum_dc
    variance_out[p] = sum_av + a_centre * a_centre * variance_in[p]
