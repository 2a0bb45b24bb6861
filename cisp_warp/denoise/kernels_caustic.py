"""Warp kernels of the caustics denoiser's temporal stage (:mod:`.caustic`): reprojection of the raw
history and its reactive accumulation. Its spatial stage is :mod:`.kernels_atrous` with gated levels.

The history is an estimate of the *raw* photon map's mean, never a filtered image: per pixel the mean
irradiance M (vec3 [W/m²]), the luminance moments (m1, m2) of the photon map (m1 = luminance(M) since both
are the same running mean), and the effective number of frames n behind it (float: the history's variance
is σ² / n for a per-frame variance σ²). A new frame's photon map E enters with weight α per pixel:

    α = (r + 1/n) / (r + 1/n + 1),        r = b² / σ²,

the weight that minimises the blend's mean squared error when the history carries a bias b (the caustic
moved) and variance σ²/n and the new frame variance σ²; with b = 0 it is 1/(n + 1), the running mean, and
a large bias resets the history to the new frame. The blend's error is σ² / n_new with

    n_new = 1 / ((1 − α)² (r + 1/n) + α²).

σ² and b² come from a (2·radius + 1)² window of same-surface pixels (photon maps are sparse: one pixel's
frame holds 0 or a few photons, so a single pixel tells little):

* σ²: the pooled temporal variance of the window's histories, v_q = (m2 − m1²) n/(n − 1), Σ v_q / N; while
  the history is short (n < ``SPATIAL_VARIANCE_HISTORY``) at least the new frame's spatial variance over the
  window (it counts the caustic's own structure as noise, so the test errs towards keeping the history);
  at least (10⁻⁵ mean m1)², the rounding of float32 running means, so a noise-free signal never reads its
  rounding as change;
* the variance handed to the spatial filter is σ²_est / n_new, with σ²_est the pooled temporal variance
  (while the history is short, at least the deviations' own, (D² − b²) / (1 + mean 1/n), which unlike the
  spatial variance does not count the caustic's structure as noise), at least the pixel's own updated v (a
  first photon in a long-dark pixel leaves an uncertain estimate); disoccluded pixels take the new frame's
  spatial variance;
* b²: the mean squared deviation of the new frame from the history, D² = Σ (E_q − M_q)² / N, beyond what
  noise alone gives it, σ² (1 + mean 1/n), by more than k of its standard error without a change,
  se(D²) = (1 + mean 1/n) sqrt(Σ_q (2 v_q² + e² v_q)) / N (v_q a pixel's per-frame variance; the e² v_q term
  is the heavy tail of few-photon counts: for a Poisson count of photons of irradiance e, Var(d²) = 2σ⁴ +
  e²σ², e estimated as Σ v / Σ m1); or the squared mean deviation d̄ = Σ (E_q − M_q) / N beyond k² times its
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
    hist_moments: wp.array2d(dtype=wp.vec2),
    hist_frames: wp.array2d(dtype=wp.float32),
    parity: wp.array(dtype=wp.int32),
    width: int,
    height: int,
    depth_tolerance: float,
    normal_tolerance: float,
    cur_depth: wp.array(dtype=wp.float32),
    cur_normal: wp.array(dtype=wp.vec3),
    prev_mean: wp.array(dtype=wp.vec3),
    stats: wp.array(dtype=wp.vec4),
):
    """Fetch the history under each pixel through the motion vectors.

    Reads ``irradiance`` (H*W vec3 [W/m²], this frame's photon map), the G-buffer ``depth`` (float32 [m],
    0 = none), ``normal`` (vec3), ``motion`` (vec2 [pixels], previous position minus pixel centre),
    ``tri_id`` (int32, -1 = none), and row ``parity[0]`` of the history: ``hist_depth``/``hist_normal``
    (the G-buffer copy of the last frame; depth 0 = no surface), ``hist_mean`` (vec3 [W/m²]),
    ``hist_moments`` (vec2 [W/m², (W/m²)²]), ``hist_frames`` (float32, effective frames n).

    Writes ``cur_depth``/``cur_normal`` (this frame's G-buffer copy, depth 0 where ``tri_id < 0``; also
    into row ``1 - parity[0]`` of ``hist_depth``/``hist_normal``), ``prev_mean`` (vec3 [W/m²], the
    reprojected history mean) and ``stats`` = (luminance of E, m1, m2, n) of the reprojected history
    (vec4; n = 0: no history, disoccluded or no surface).

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
    moments = wp.vec2(0.0)
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
        stats[p] = wp.vec4(lum, moments[0] * inv, moments[1] * inv, frames * inv)
    else:
        prev_mean[p] = wp.vec3(0.0)
        stats[p] = wp.vec4(lum, 0.0, 0.0, 0.0)


@wp.kernel
def accumulate(
    irradiance: wp.array(dtype=wp.vec3),
    depth: wp.array(dtype=wp.float32),
    normal: wp.array(dtype=wp.vec3),
    prev_mean: wp.array(dtype=wp.vec3),
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
    hist_moments: wp.array2d(dtype=wp.vec2),
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
        hist_moments[cur, p] = wp.vec2(0.0)
        hist_frames[cur, p] = 0.0
        mean_out[p] = wp.vec3(0.0)
        variance_out[p] = 0.0
        frames_out[p] = 0.0
        slope_out[p] = 0.0
        return
    n = normal[p]
    count = float(0.0)  # same-surface pixels of the window
    sum_e = float(0.0)
    sum_e2 = float(0.0)
    with_history = float(0.0)  # ... of which have a history
    sum_d = float(0.0)  # Σ (E − M)
    sum_d2 = float(0.0)  # Σ (E − M)²
    sum_var = float(0.0)  # Σ v, v the temporal per-frame variance of a pixel
    sum_var2 = float(0.0)  # Σ v²
    sum_m1 = float(0.0)  # Σ m1
    sum_inv_n = float(0.0)  # Σ 1/n
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            qx = x + dx
            qy = y + dy
            if qx >= 0 and qx < width and qy >= 0 and qy < height:
                q = qy * width + qx
                z_q = depth[q]
                if z_q > 0.0 and wp.abs(z_q - z) <= depth_tolerance * z and wp.dot(normal[q], n) >= normal_tolerance:
                    s = stats[q]
                    e = s[0]
                    count += 1.0
                    sum_e += e
                    sum_e2 += e * e
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
    mean_e = sum_e / count
    var_spatial = wp.max(sum_e2 / count - mean_e * mean_e, 0.0)
    s_p = stats[p]
    n_prev = s_p[3]
    c = irradiance[p]
    lum = s_p[0]
    bias2 = float(0.0)
    if n_prev <= 0.0:  # disoccluded: the new frame alone, its variance from the window
        alpha = float(1.0)
        n_new = float(1.0)
        sigma2_est = var_spatial
    else:
        d2 = sum_d2 / with_history
        sigma2 = sum_var / with_history
        sigma2_est = sigma2
        if n_prev < float(SPATIAL_VARIANCE_HISTORY):
            sigma2 = wp.max(sigma2, var_spatial)
        resolution = FLOAT_RESOLUTION * sum_m1 / with_history  # float32 rounding of the running means
        sigma2 = wp.max(sigma2, resolution * resolution)
        if sigma2 * with_history > sum_var:  # a floor above the pooled variance: a homogeneous window of it
            sum_var = sigma2 * with_history
            sum_var2 = sigma2 * sigma2 * with_history
        photon = float(0.0)  # irradiance of one photon in a pixel [W/m²]: Var = e μ for Poisson counts
        if sum_m1 > 0.0:
            photon = sum_var / sum_m1
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
            sigma2_est = wp.max(sigma2_est, wp.max(d2 - bias2, 0.0) / history_noise)
    mean = wp.lerp(prev_mean[p], c, alpha)
    m1 = wp.lerp(s_p[1], lum, alpha)
    # the pixel's own per-frame variance after the update: the spread of the blend of its history (variance
    # v) and the new sample, (1 − α) v + α (1 − α) (l − m1)², less the change b² found (a detected change is
    # signal, not noise). Stored as the second moment; at least this much goes to the spatial filter (the
    # first photon in a long-dark pixel leaves an uncertain estimate, though its window saw no noise).
    d_p = lum - s_p[1]
    own = (1.0 - alpha) * wp.max(s_p[2] - s_p[1] * s_p[1], 0.0) + alpha * (1.0 - alpha) * wp.max(d_p * d_p - bias2, 0.0)
    moments = wp.vec2(m1, m1 * m1 + own)
    sigma2_est = wp.max(sigma2_est, own * n_new / wp.max(n_new - 1.0, 1.0))
    hist_mean[cur, p] = mean
    hist_moments[cur, p] = moments
    hist_frames[cur, p] = n_new
    mean_out[p] = mean
    variance_out[p] = sigma2_est / n_new
    frames_out[p] = n_new
    slope_out[p] = depth_gradient_length(depth, x, y, width, height)
