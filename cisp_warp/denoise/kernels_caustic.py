"""Warp kernels of the caustics denoiser's temporal stage (:mod:`.caustic`): reprojection of the raw
history and its reactive accumulation. Its spatial stage is :mod:`.kernels_atrous` with gated levels.

The history is an estimate of the *raw* photon map's mean, never a filtered image: per pixel the mean
irradiance M (vec3 [W/m²]), the luminance moments (m1, m2) of the photon map (m1 = luminance(M) since both
are the same running mean) and s² (below), and the effective number of frames n behind it (float: the history's variance
is σ² / n for a per-frame variance σ²). A new frame's photon map E enters with weight α per pixel:

    α = (r + 1/n) / (r + 1/n + 1),        r = b² / σ²,

the weight that minimises the blend's mean squared error when the history carries a bias b (the caustic
moved) and variance σ²/n and the new frame variance σ²; with b = 0 it is 1/(n + 1), the running mean, and
a large bias resets the history to the new frame. The blend's error is σ² / n_new with

    n_new = 1 / ((1 − α)² (r + 1/n) + α²).

σ² and b² come from a (2·radius + 1)² window of same-surface pixels (photon maps are sparse: one pixel's
frame holds 0 or a few photons, so a single pixel tells little):

* σ²: per-frame variance. From the frames alone: s², the running mean over frames of half the mean squared
  difference of same-surface neighbours in the window, along rows or columns, whichever is smaller:
  E[(E_a − E_b)²] = 2σ² + (μ_a − μ_b)², and a caustic line adds least along itself; s² never counts the
  caustic's motion as noise. The history's pooled temporal variance, v_q = (m2 − m1²) n/(n − 1), Σ v_q / N,
  replaces it where it is smaller and the history has ``SPATIAL_VARIANCE_HISTORY`` frames or more: it is
  free of the caustic's structure for a still caustic, while a moving one inflates it. At least
  (10⁻⁵ mean m1)², the rounding of float32 running means, so a noise-free signal never reads its rounding
  as change;
* the variance handed to the spatial filter is σ²_est / n_new, σ²_est = σ² (while the history is short, the
  larger of the pooled temporal variance and the deviations' own, (D² − b²) / (1 + mean 1/n), free of the
  caustic's structure), at least the pixel's own updated v (a first photon
  in a long-dark pixel leaves an uncertain estimate); disoccluded pixels take the neighbour-difference one;
* b²: the mean squared deviation of the new frame from the history, D² = Σ (E_q − M_q)² / N, beyond what
  noise alone gives it, σ² (1 + mean 1/n), by more than k of its standard error without a change,
  se(D²) = (1 + mean 1/n) sqrt(Σ_q (2 v_q² + e² v_q)) / N (v_q a pixel's per-frame variance; the e² v_q term
  is the heavy tail of few-photon counts: for a Poisson count of photons of irradiance e, Var(d²) = 2σ⁴ +
  e²σ²; e is the window's smallest non-zero irradiance this frame, one photon's or more, at most σ² / mean m1,
  the Poisson quantum of the window); or the squared mean deviation d̄ = Σ (E_q − M_q) / N beyond k² times its
  variance without a change, σ² (1 + mean 1/n) / N:

      b² = max(D² − σ² (1 + 1/n) − k se(D²), d̄² − k² σ² (1 + 1/n) / N, 0).

  The first sees a caustic that moves (its lines leave pixels while the window's total stays), the second
  one that brightens or dims a little in every pixel.

Images are flat arrays of ``height * width`` pixels, row-major; launches use ``dim=(height, width)``.
History arrays are (2, H*W); ``parity[0]`` names the row holding the last frame and the kernels write the
other one (:func:`.kernels_svgf.flip_parity` swaps them at the end of the frame).
"""

from __future__ import annotations

import warp as wp

from .kernels_svgf import MIN_BILINEAR_WEIGHT, SPATIAL_VARIANCE_HISTORY, depth_gradient_length, luminance

#: largest half width of the change window [pixels]; ``window_row`` holds one row of it
MAX_CHANGE_RADIUS = 3
window_row = wp.types.vector(length=2 * MAX_CHANGE_RADIUS + 1, dtype=wp.float32)
#: relative resolution of the float32 running means: deviations below it are rounding, never change
FLOAT_RESOLUTION = wp.constant(1.0e-5)


@wp.kernel
def reproject_history(
    irradiance: wp.array(dtype=wp.vec3),
    depth: wp.array(dtype=wp.float32),
    normal: wp.array(dtype=wp.vec3),
    motion: wp.array(dtype=wp.vec2),
    tri_id: wp.array(dtype=wp.int32),
    hist_depth: wp.array2d(dtype=wp.float32),
    hist_normal: wp.array2d(dtype=wp.vec3),
    hist_mean: wp.array2d(dtype=wp.vec3),
    hist_moments: wp.array2d(dtype=wp.vec3),
    hist_frames: wp.array2d(dtype=wp.float32),
    parity: wp.array(dtype=wp.int32),
    width: int,
    height: int,
    depth_tolerance: float,
    normal_tolerance: float,
    cur_depth: wp.array(dtype=wp.float32),
    cur_normal: wp.array(dtype=wp.vec3),
    prev_mean: wp.array(dtype=wp.vec3),
    prev_pairs: wp.array(dtype=wp.float32),
    stats: wp.array(dtype=wp.vec4),
):
    """Fetch the history under each pixel through the motion vectors.

    Reads ``irradiance`` (H*W vec3 [W/m²], this frame's photon map), the G-buffer ``depth`` (float32 [m],
    0 = none), ``normal`` (vec3), ``motion`` (vec2 [pixels], previous position minus pixel centre),
    ``tri_id`` (int32, -1 = none), and row ``parity[0]`` of the history: ``hist_depth``/``hist_normal``
    (the G-buffer copy of the last frame; depth 0 = no surface), ``hist_mean`` (vec3 [W/m²]),
    ``hist_moments`` (vec3: m1 [W/m²], m2 and s² [(W/m²)²]), ``hist_frames`` (float32, effective frames n).

    Writes ``cur_depth``/``cur_normal`` (this frame's G-buffer copy, depth 0 where ``tri_id < 0``; also
    into row ``1 - parity[0]`` of ``hist_depth``/``hist_normal``), ``prev_mean`` (vec3 [W/m²], the
    reprojected history mean), ``prev_pairs`` (float32, its s²) and ``stats`` = (luminance of E, m1, m2, n)
    of the reprojected history (vec4; n = 0: no history, disoccluded or no surface).

    A tap of the 2x2 bilinear footprint is consistent when it is on screen, has a surface, its depth is
    within ``depth_tolerance`` (relative) of this pixel's and its normal's cosine to this one's is at least
    ``normal_tolerance`` (as SVGF's reprojection); the consistent taps are renormalised, and fewer than
    ``MIN_BILINEAR_WEIGHT`` of the footprint means disoccluded.
    """
    y, x = wp.tid()
    p = y * width + x
    prev = parity[0]
    cur = 1 - prev
    z = depth[p]
    if z <= 0.0 or tri_id[p] < 0:
        cur_depth[p] = 0.0
        cur_normal[p] = wp.vec3(0.0)
        hist_depth[cur, p] = 0.0
        hist_normal[cur, p] = wp.vec3(0.0)
        prev_mean[p] = wp.vec3(0.0)
        prev_pairs[p] = 0.0
        stats[p] = wp.vec4(0.0)
        return
    n = normal[p]
    cur_depth[p] = z
    cur_normal[p] = n
    hist_depth[cur, p] = z
    hist_normal[cur, p] = n

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
    mean = wp.vec3(0.0)
    moments = wp.vec3(0.0)
    frames = float(0.0)
    for tap in range(4):
        dx = tap % 2
        dy = tap // 2
        tx = x0 + dx
        ty = y0 + dy
        if tx >= 0 and tx < width and ty >= 0 and ty < height:
            q = ty * width + tx
            z_q = hist_depth[prev, q]
            n_q = hist_frames[prev, q]
            if (n_q > 0.0 and z_q > 0.0 and wp.abs(z_q - z) <= depth_tolerance * z
                    and wp.dot(hist_normal[prev, q], n) >= normal_tolerance):
                w = wp.where(dx == 1, fx, 1.0 - fx) * wp.where(dy == 1, fy, 1.0 - fy)
                sum_w += w
                mean += w * hist_mean[prev, q]
                moments += w * hist_moments[prev, q]
                frames += w * n_q
    lum = luminance(irradiance[p])
    if sum_w >= MIN_BILINEAR_WEIGHT:
        inv = 1.0 / sum_w
        prev_mean[p] = mean * inv
        prev_pairs[p] = moments[2] * inv
        stats[p] = wp.vec4(lum, moments[0] * inv, moments[1] * inv, frames * inv)
    else:
        prev_mean[p] = wp.vec3(0.0)
        prev_pairs[p] = 0.0
        stats[p] = wp.vec4(lum, 0.0, 0.0, 0.0)


@wp.kernel
def accumulate(
    irradiance: wp.array(dtype=wp.vec3),
    depth: wp.array(dtype=wp.float32),
    normal: wp.array(dtype=wp.vec3),
    prev_mean: wp.array(dtype=wp.vec3),
    prev_pairs: wp.array(dtype=wp.float32),
    stats: wp.array(dtype=wp.vec4),
    parity: wp.array(dtype=wp.int32),
    width: int,
    height: int,
    radius: int,
    max_history: float,
    change_sigmas: float,
    depth_tolerance: float,
    normal_tolerance: float,
    hist_mean: wp.array2d(dtype=wp.vec3),
    hist_moments: wp.array2d(dtype=wp.vec3),
    hist_frames: wp.array2d(dtype=wp.float32),
    mean_out: wp.array(dtype=wp.vec3),
    variance_out: wp.array(dtype=wp.float32),
    frames_out: wp.array(dtype=wp.float32),
    slope_out: wp.array(dtype=wp.float32),
):
    """Reactive temporal accumulation (module docstring).

    Reads ``irradiance`` (H*W vec3 [W/m²]), this frame's G-buffer copy ``depth`` ([m], 0 = none) and
    ``normal`` from :func:`reproject_history`, with its ``prev_mean`` (vec3 [W/m²]) and ``stats``
    (vec4: luminance of E, m1, m2, n). ``radius``: half width of the change-detection window [pixels];
    ``max_history``: cap N on n (the running mean becomes an exponential one of weight 1/N);
    ``change_sigmas`` (k): how many of their standard errors the deviations must exceed to count as change; a window pixel q is the same
    surface when its depth is within ``depth_tolerance`` (relative) and its normal's cosine at least
    ``normal_tolerance``.

    Writes the new history into row ``1 - parity[0]`` of ``hist_mean`` (vec3 [W/m²]), ``hist_moments``
    (vec2) and ``hist_frames`` (float32), and per pixel ``mean_out`` (vec3 [W/m²], the accumulated
    estimate), ``variance_out`` (float32 [(W/m²)²], the variance of its luminance, σ² / n_new),
    ``frames_out`` (n_new) and ``slope_out`` (float32 [m/pixel], ‖∇z‖ for the à-trous levels). 0 without
    a surface.
    """
    y, x = wp.tid()
    p = y * width + x
    cur = 1 - parity[0]
    z = depth[p]
    if z <= 0.0:
        hist_mean[cur, p] = wp.vec3(0.0)
        hist_moments[cur, p] = wp.vec3(0.0)
        hist_frames[cur, p] = 0.0
        mean_out[p] = wp.vec3(0.0)
        variance_out[p] = 0.0
        frames_out[p] = 0.0
        slope_out[p] = 0.0
        return
    n = normal[p]
    count = float(0.0)  # same-surface pixels of the window
    sum_e = float(0.0)
    photon = float(3.0e38)  # smallest non-zero irradiance of the window: one photon's [W/m²]
    with_history = float(0.0)  # ... of which have a history
    sum_d = float(0.0)  # Σ (E − M)
    sum_d2 = float(0.0)  # Σ (E − M)²
    sum_var = float(0.0)  # Σ v, v the temporal per-frame variance of a pixel
    sum_var2 = float(0.0)  # Σ v²
    sum_m1 = float(0.0)  # Σ m1
    sum_inv_n = float(0.0)  # Σ 1/n
    sum_dh = float(0.0)  # Σ (E_q − E_left)² over horizontal pairs of the window, and their count
    pairs_h = float(0.0)
    sum_dv = float(0.0)  # ... vertical pairs
    pairs_v = float(0.0)
    above = window_row(-1.0)  # E of the row above per window column (-1: not the same surface)
    for dy in range(-radius, radius + 1):
        left = float(-1.0)
        for dx in range(-radius, radius + 1):
            qx = x + dx
            qy = y + dy
            col = dx + radius
            here = float(-1.0)
            if qx >= 0 and qx < width and qy >= 0 and qy < height:
                q = qy * width + qx
                z_q = depth[q]
                if z_q > 0.0 and wp.abs(z_q - z) <= depth_tolerance * z and wp.dot(normal[q], n) >= normal_tolerance:
                    s = stats[q]
                    e = s[0]
                    here = e
                    count += 1.0
                    sum_e += e
                    if e > 0.0:
                        photon = wp.min(photon, e)
                    if left >= 0.0:
                        sum_dh += (e - left) * (e - left)
                        pairs_h += 1.0
                    if above[col] >= 0.0:
                        sum_dv += (e - above[col]) * (e - above[col])
                        pairs_v += 1.0
                    n_q = s[3]
                    if n_q > 0.0:
                        d = e - s[1]
                        with_history += 1.0
                        sum_d += d
                        sum_d2 += d * d
                        v = wp.max(s[2] - s[1] * s[1], 0.0) * n_q / wp.max(n_q - 1.0, 1.0)
                        sum_var += v
                        sum_var2 += v * v
                        sum_m1 += s[1]
                        sum_inv_n += 1.0 / n_q
            left = here
            above[col] = here
    mean_e = sum_e / count
    if photon > 1.0e38:
        photon = 0.0
    # per-frame variance from this frame alone: half the mean squared difference of neighbours along the
    # direction where it is smaller (E[(E_a − E_b)²] = 2σ² + (μ_a − μ_b)²: a caustic line adds least along itself)
    var_pairs = float(0.0)
    if pairs_h > 0.0 and pairs_v > 0.0:
        var_pairs = 0.5 * wp.min(sum_dh / pairs_h, sum_dv / pairs_v)
    elif pairs_h > 0.0:
        var_pairs = 0.5 * sum_dh / pairs_h
    elif pairs_v > 0.0:
        var_pairs = 0.5 * sum_dv / pairs_v
    s_p = stats[p]
    n_prev = s_p[3]
    c = irradiance[p]
    lum = s_p[0]
    bias2 = float(0.0)
    # s²: running mean over frames of the neighbour-difference variance (each frame's free of the caustic's
    # motion; the mean over frames free of its noise)
    pairs = var_pairs
    if n_prev <= 0.0:  # disoccluded: the new frame alone, its variance from its neighbour differences
        alpha = float(1.0)
        n_new = float(1.0)
        sigma2_est = var_pairs
    else:
        pairs = wp.lerp(prev_pairs[p], var_pairs, 1.0 / (wp.min(n_prev, max_history - 1.0) + 1.0))
        d2 = sum_d2 / with_history
        temporal = sum_var / with_history
        if n_prev < float(SPATIAL_VARIANCE_HISTORY) or pairs < temporal:
            sum_var = pairs * with_history
            sum_var2 = pairs * pairs * with_history
        sigma2 = sum_var / with_history
        sigma2_est = sigma2
        resolution = FLOAT_RESOLUTION * sum_m1 / with_history  # float32 rounding of the running means
        sigma2 = wp.max(sigma2, resolution * resolution)
        if sigma2 * with_history > sum_var:  # a floor above the pooled variance: a homogeneous window of it
            sum_var = sigma2 * with_history
            sum_var2 = sigma2 * sigma2 * with_history
        if sum_m1 > 0.0:  # one photon's irradiance: at most what Poisson counts of the window's σ² and m1 give
            photon = wp.min(photon, sum_var / sum_m1)
        history_noise = 1.0 + sum_inv_n / with_history
        spread = sigma2 * history_noise  # E[D²] without a change
        se_d2 = history_noise * wp.sqrt(2.0 * sum_var2 + photon * photon * sum_var) / with_history  # its std. error
        mean_d = sum_d / with_history
        bias2 = wp.max(wp.max(d2 - spread - change_sigmas * se_d2,
                              mean_d * mean_d - change_sigmas * change_sigmas * spread / with_history), 0.0)
        r = float(0.0)
        if sigma2 > 0.0:
            r = bias2 / sigma2
        inv_n = 1.0 / wp.min(n_prev, max_history - 1.0)
        alpha = (r + inv_n) / (r + inv_n + 1.0)
        n_new = 1.0 / ((1.0 - alpha) * (1.0 - alpha) * (r + inv_n) + alpha * alpha)
        if n_prev < float(SPATIAL_VARIANCE_HISTORY):  # for the filter: the deviations, less the change found
            sigma2_est = wp.max(temporal, wp.max(d2 - bias2, 0.0) / history_noise)
    mean = wp.lerp(prev_mean[p], c, alpha)
    m1 = wp.lerp(s_p[1], lum, alpha)
    # the pixel's own per-frame variance after the update: the spread of the blend of its history (variance
    # v) and the new sample, (1 − α) v + α (1 − α) (l − m1)², less the change b² found (a detected change is
    # signal, not noise). Stored as the second moment; at least this much goes to the spatial filter (the
    # first photon in a long-dark pixel leaves an uncertain estimate, though its window saw no noise).
    d_p = lum - s_p[1]
    own = (1.0 - alpha) * wp.max(s_p[2] - s_p[1] * s_p[1], 0.0) + alpha * (1.0 - alpha) * wp.max(d_p * d_p - bias2, 0.0)
    moments = wp.vec3(m1, m1 * m1 + own, pairs)
    sigma2_est = wp.max(sigma2_est, own * n_new / wp.max(n_new - 1.0, 1.0))
    hist_mean[cur, p] = mean
    hist_moments[cur, p] = moments
    hist_frames[cur, p] = n_new
    mean_out[p] = mean
    variance_out[p] = sigma2_est / n_new
    frames_out[p] = n_new
    slope_out[p] = depth_gradient_length(depth, x, y, width, height)
