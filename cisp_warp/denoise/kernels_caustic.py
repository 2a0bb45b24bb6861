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

* σ²: per-frame variance. From the frames alone: s², the running mean over frames of a sixth of the mean
  squared second difference of three same-surface neighbours in a row of the window, along rows or columns,
  whichever is smaller: E[(E_a − 2E_b + E_c)²] = 6σ² + (μ_a − 2μ_b + μ_c)², and the caustic's curvature adds
  far less than its slope did to first differences (3x too large a σ² on the stability suite's water, which
  hid most changes); s² never counts the caustic's motion as noise. Where the photon pass keeps ``photon_m2``
  (P_q = Σ e² of the photons stored in pixel q this frame: the variance of a sum of independent photons), s² is
  at most p², the running mean over frames (the same weights) of the window's mean Σ P_q / N, which holds the
  photons' noise alone, none of the caustic's curvature. The two running means are compared, not each frame's
  (the smaller of two noisy estimates is biased low: s² at 0.80 of the truth on Poisson maps, against 0.94,
  and false changes cut still histories). Independent photons make p² an upper bound: emission from a
  low-discrepancy sequence leaves far less noise (CISP and SSPM on the stability suite's water: 0.08 p²), so
  the cap acts where the curvature is large (focus lines), and p² = 0 (no photon yet) caps nothing. The
  history's pooled temporal variance,
  v_q = (m2 − m1²) n/(n − 1), Σ v_q / N, is used where the history has ``SPATIAL_VARIANCE_HISTORY`` frames or
  more, scaled down to s² where that is smaller (the pixels' spread kept): it is free of the caustic's
  structure for a still caustic, while a moving one inflates it. At least
  (10⁻⁵ mean m1)², the rounding of float32 running means, so a noise-free signal never reads its rounding
  as change;
* the variance handed to the spatial filter is σ²_est / n_new, σ²_est = σ² (while the history is short, the
  larger of the pooled temporal variance and the deviations' own, (D² − b²) / (1 + mean 1/n), free of the
  caustic's structure, but no more than s²: a moving caustic inflates both, and a filter sized by its
  motion blurs what it should follow), at least the pixel's own updated v (a first photon
  in a long-dark pixel leaves an uncertain estimate); disoccluded pixels take the neighbour-difference one;
* b²: the mean squared deviation of the new frame from the history, D² = Σ (E_q − M_q)² / N, beyond what
  noise alone gives it, σ² (1 + mean 1/n), by more than k of its standard error without a change,
  se(D²) = (1 + mean 1/n) sqrt(Σ_q (2 v_q² + e² v_q)) / N (v_q a pixel's per-frame variance; the e² v_q term
  is the heavy tail of few-photon counts: for a Poisson count of photons of irradiance e, Var(d²) = 2σ⁴ +
  e²σ²; e is the window's smallest non-zero irradiance this frame, one photon's or more, at most σ² / mean m1,
  the Poisson quantum of the window); or the squared mean deviation d̄ = Σ (E_q − M_q) / N beyond k² times its
  variance without a change, σ² (1 + mean 1/n) / N:

      b² = max(D² − σ² (1 + 1/n) − k_n se(D²), d̄² − k_n² σ² (1 + 1/n) / N, 0),   k_n = k min((n/16)^¼, 1):

  the threshold rises with the pixel's history, from k/2 at one frame to k from 16 frames on: a false alarm
  costs a long history much (each frame is another chance for one), while a short one has just been cut
  back because the caustic was moving and will most likely have to follow it again.

  The first sees a caustic that moves (its lines leave pixels while the window's total stays), the second
  one that brightens or dims a little in every pixel;
* and the pixel alone: its share of the window's variance, σ_p² = σ² max(m1_p, l_p) / mean m1 (Poisson counts
  vary as their mean; the new luminance l_p stands in where larger, so one photon in a dark pixel is not a
  change), times (1 + 1/n), and its own deviation d_p = l_p − m1_p beyond k_p of it and a photon's worth,
  b_p² = max(d_p² − k_p² σ_p² − k_p e σ_p, 0), r = max(r, b_p² (1 + 1/n) / σ_p²): a change over part of the
  window (a caustic line sweeping through) is diluted in the window's D².

A caustic that moved keeps moving (a turning sun, travelling waves): the window's ratio r, where its change
passed the full threshold k on a history shorter than ``FULL_THRESHOLD_HISTORY`` frames, is kept with the
history (fourth component of ``hist_moments``, at most ``MAX_KEPT_RATIO``) and fades by p =
``change_persistence`` a frame; a frame's r is at least p times the kept one. A drift too slow for one frame's
test (a third of a pixel a frame) then no longer builds a lagging history, while a still caustic's rare false
alarm on a long history is not kept (the history-length clamp of A-SVGF's temporal gradient, without re-traced
samples).

Reprojection: bilinear over the consistent taps of the 2x2 footprint, renormalised (SVGF's); where the whole
4x4 footprint is consistent and the motion fractional, the mean and the moments (m1, m2) are fetched by
Catmull-Rom instead, clamped per component to the 2x2 taps' range (no ringing, never negative): a camera pan
resamples the history every frame, and bilinear fetches blur a running mean of n frames by about sqrt(n / 8)
pixels, while Catmull-Rom keeps a band-limited caustic (the stability suite's pan: error 0.117 -> 0.080).

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
#: largest change ratio r kept for the next frame (α = 64/65 for a long history: a reset's worth), so that a
#: kept ratio fades however large the change was (r over an underflowing σ² is 1e30)
MAX_KEPT_RATIO = wp.constant(64.0)
#: history length [frames] from which the change test uses its full threshold k (below: k (n/16)^¼)
FULL_THRESHOLD_HISTORY = wp.constant(16.0)


@wp.func
def catmull_rom_weights(t: float) -> wp.vec4:
    """Weights of the Catmull-Rom spline's four taps at offsets -1, 0, 1, 2 for a position ``t`` in [0, 1)
    past tap 0 (they sum to 1; t = 0 gives tap 0 alone)."""
    t2 = t * t
    t3 = t2 * t
    return wp.vec4(-0.5 * t + t2 - 0.5 * t3, 1.0 - 2.5 * t2 + 1.5 * t3, 0.5 * t + 2.0 * t2 - 1.5 * t3,
                   -0.5 * t2 + 0.5 * t3)


@wp.func
def hist_frames_at(hist_mean: wp.array2d(dtype=wp.vec4), prev: int, q: int) -> float:
    """Effective frames n of history texel q (the fourth component of ``hist_mean``)."""
    m = hist_mean[prev, q]
    return m[3]


@wp.func
def history_tap_ok(hist_surface: wp.array2d(dtype=wp.vec4), hist_mean: wp.array2d(dtype=wp.vec4), prev: int,
                   tx: int, ty: int, width: int, height: int,
                   z: float, n: wp.vec3, depth_tolerance: float, normal_tolerance: float) -> bool:
    """Whether the history texel (tx, ty) is on screen, has a surface and a history, and is the same surface
    as this pixel (relative depth within ``depth_tolerance``, normal cosine at least ``normal_tolerance``)."""
    if tx < 0 or tx >= width or ty < 0 or ty >= height:
        return False
    q = ty * width + tx
    s_q = hist_surface[prev, q]  # one 16-byte load: (z, normal)
    z_q = s_q[0]
    return (z_q > 0.0 and wp.abs(z_q - z) <= depth_tolerance * z
            and s_q[1] * n[0] + s_q[2] * n[1] + s_q[3] * n[2] >= normal_tolerance and hist_frames_at(hist_mean, prev, q) > 0.0)


@wp.kernel
def reproject_history(
    irradiance: wp.array(dtype=wp.vec3),
    depth: wp.array(dtype=wp.float32),
    normal: wp.array(dtype=wp.vec3),
    motion: wp.array(dtype=wp.vec2),
    tri_id: wp.array(dtype=wp.int32),
    hist_surface: wp.array2d(dtype=wp.vec4),
    hist_mean: wp.array2d(dtype=wp.vec4),
    hist_moments: wp.array2d(dtype=wp.vec4),
    hist_photon_var: wp.array2d(dtype=wp.float32),
    parity: wp.array(dtype=wp.int32),
    width: int,
    height: int,
    depth_tolerance: float,
    normal_tolerance: float,
    cur_depth: wp.array(dtype=wp.float32),
    cur_normal: wp.array(dtype=wp.vec3),
    surface: wp.array(dtype=wp.vec4),
    prev_mean: wp.array(dtype=wp.vec3),
    prev_pairs: wp.array(dtype=wp.vec3),
    stats: wp.array(dtype=wp.vec4),
):
    """Fetch the history under each pixel through the motion vectors.

    Reads ``irradiance`` (H*W vec3 [W/m²], this frame's photon map), the G-buffer ``depth`` (float32 [m],
    0 = none), ``normal`` (vec3), ``motion`` (vec2 [pixels], previous position minus pixel centre),
    ``tri_id`` (int32, -1 = none), and row ``parity[0]`` of the history (vec4 each, one aligned load per tap):
    ``hist_surface`` (z [m], normal: the G-buffer copy of the last frame; z = 0: no surface), ``hist_mean``
    (mean irradiance [W/m²], effective frames n), ``hist_moments`` (m1 [W/m²], m2 and s² [(W/m²)²], kept
    change ratio) and ``hist_photon_var`` (float32 [(W/m²)²], p²: the running mean of the window's photon_m2).

    Writes ``cur_depth``/``cur_normal`` (this frame's G-buffer copy, depth 0 where ``tri_id < 0``, for the
    à-trous levels), ``surface`` (the same packed as (z, normal) for the change window; also into row
    ``1 - parity[0]`` of ``hist_surface``), ``prev_mean`` (vec3 [W/m²], the reprojected history mean),
    ``prev_pairs`` (vec3: its s², kept change ratio and p²) and ``stats`` = (luminance of E, m1, m2, n) of the
    reprojected history (vec4; n = 0: no history, disoccluded or no surface).

    A tap of the 2x2 bilinear footprint is consistent when it is on screen, has a surface, its depth is
    within ``depth_tolerance`` (relative) of this pixel's and its normal's cosine to this one's is at least
    ``normal_tolerance`` (as SVGF's reprojection); the consistent taps are renormalised, and fewer than
    ``MIN_BILINEAR_WEIGHT`` of the footprint means disoccluded. Where all 16 taps of the 4x4 footprint are
    consistent and the motion is fractional, the mean and (m1, m2) take the Catmull-Rom value instead, clamped
    per component to the range of the 2x2 taps (module docstring); s², p² and n stay bilinear.
    """
    y, x = wp.tid()
    p = y * width + x
    prev = parity[0]
    cur = 1 - prev
    z = depth[p]
    if z <= 0.0 or tri_id[p] < 0:
        cur_depth[p] = 0.0
        cur_normal[p] = wp.vec3(0.0)
        surface[p] = wp.vec4(0.0)
        hist_surface[cur, p] = wp.vec4(0.0)
        prev_mean[p] = wp.vec3(0.0)
        prev_pairs[p] = wp.vec3(0.0)
        stats[p] = wp.vec4(0.0)
        return
    n = normal[p]
    cur_depth[p] = z
    cur_normal[p] = n
    packed = wp.vec4(z, n[0], n[1], n[2])
    surface[p] = packed
    hist_surface[cur, p] = packed

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
    moments = wp.vec4(0.0)
    photon_var = float(0.0)
    frames = float(0.0)
    lo = wp.vec3(3.0e38)  # per component: the smallest and largest mean and moments (m1, m2) of the 2x2 taps
    hi = wp.vec3(-3.0e38)
    lo_m = wp.vec2(3.0e38)
    hi_m = wp.vec2(-3.0e38)
    for tap in range(4):
        dx = tap % 2
        dy = tap // 2
        tx = x0 + dx
        ty = y0 + dy
        if history_tap_ok(hist_surface, hist_mean, prev, tx, ty, width, height, z, n,
                          depth_tolerance, normal_tolerance):
            q = ty * width + tx
            w = wp.where(dx == 1, fx, 1.0 - fx) * wp.where(dy == 1, fy, 1.0 - fy)
            sum_w += w
            mean4 = hist_mean[prev, q]
            mean_q = wp.vec3(mean4[0], mean4[1], mean4[2])
            moments4 = hist_moments[prev, q]
            moments_q = wp.vec3(moments4[0], moments4[1], moments4[2])
            mean += w * mean_q
            moments += w * moments4
            photon_var += w * hist_photon_var[prev, q]
            frames += w * mean4[3]
            lo = wp.min(lo, mean_q)
            hi = wp.max(hi, mean_q)
            lo_m = wp.min(lo_m, wp.vec2(moments_q[0], moments_q[1]))
            hi_m = wp.max(hi_m, wp.vec2(moments_q[0], moments_q[1]))
    lum = luminance(irradiance[p])
    if sum_w >= MIN_BILINEAR_WEIGHT:
        inv = 1.0 / sum_w
        mean = mean * inv
        m12 = wp.vec2(moments[0] * inv, moments[1] * inv)
        if sum_w >= 1.0 - 1.0e-6 and (fx > 0.0 or fy > 0.0):
            # the whole 4x4 footprint the same surface: Catmull-Rom, which does not blur the history
            # frame after frame as repeated bilinear fetches do, clamped per component to the 2x2 taps'
            # range (no ringing, never negative)
            wx = catmull_rom_weights(fx)
            wy = catmull_rom_weights(fy)
            cubic = wp.vec3(0.0)
            cubic_m = wp.vec2(0.0)
            all_ok = bool(True)
            for tap in range(16):
                i = tap % 4
                j = tap // 4
                tx = x0 - 1 + i
                ty = y0 - 1 + j
                if all_ok:
                    if history_tap_ok(hist_surface, hist_mean, prev, tx, ty, width, height, z, n,
                                      depth_tolerance, normal_tolerance):
                        q = ty * width + tx
                        w = wx[i] * wy[j]
                        mean4 = hist_mean[prev, q]
                        moments4 = hist_moments[prev, q]
                        cubic += w * wp.vec3(mean4[0], mean4[1], mean4[2])
                        cubic_m += w * wp.vec2(moments4[0], moments4[1])
                    else:
                        all_ok = False
            if all_ok:
                mean = wp.min(wp.max(cubic, lo), hi)
                m12 = wp.min(wp.max(cubic_m, lo_m), hi_m)
        prev_mean[p] = mean
        prev_pairs[p] = wp.vec3(moments[2] * inv, moments[3] * inv, photon_var * inv)
        stats[p] = wp.vec4(lum, m12[0], m12[1], frames * inv)
    else:
        prev_mean[p] = wp.vec3(0.0)
        prev_pairs[p] = wp.vec3(0.0)
        stats[p] = wp.vec4(lum, 0.0, 0.0, 0.0)


@wp.kernel
def accumulate(
    irradiance: wp.array(dtype=wp.vec3),
    photon_m2: wp.array(dtype=wp.float32),
    depth: wp.array(dtype=wp.float32),
    surface: wp.array(dtype=wp.vec4),
    prev_mean: wp.array(dtype=wp.vec3),
    prev_pairs: wp.array(dtype=wp.vec3),
    stats: wp.array(dtype=wp.vec4),
    parity: wp.array(dtype=wp.int32),
    width: int,
    height: int,
    radius: int,
    max_history: float,
    change_sigmas: float,
    pixel_sigmas: float,
    change_persistence: float,
    depth_tolerance: float,
    normal_tolerance: float,
    hist_mean: wp.array2d(dtype=wp.vec4),
    hist_moments: wp.array2d(dtype=wp.vec4),
    hist_photon_var: wp.array2d(dtype=wp.float32),
    mean_out: wp.array(dtype=wp.vec3),
    variance_out: wp.array(dtype=wp.float32),
    frames_out: wp.array(dtype=wp.float32),
    slope_out: wp.array(dtype=wp.float32),
):
    """Reactive temporal accumulation (module docstring).

    Reads ``irradiance`` (H*W vec3 [W/m²]), ``photon_m2`` (H*W float32 [(W/m²)²], Σ luminance(e)² of the
    frame's photons per pixel; None: not kept, the variance from the frames alone), this frame's G-buffer copy
    ``depth`` ([m], 0 = none) and ``normal`` from :func:`reproject_history`, with its ``prev_mean`` (vec3
    [W/m²]), ``prev_pairs`` (vec3: s², kept change ratio, p²) and ``stats`` (vec4: luminance of E, m1, m2, n).
    ``radius``: half width of the change-detection window [pixels]; ``max_history``: cap N on n (the running mean becomes an exponential one of weight 1/N);
    ``change_sigmas`` (k): how many of their standard errors the deviations must exceed to count as change; a window pixel q is the same
    surface when its depth is within ``depth_tolerance`` (relative) and its normal's cosine at least
    ``normal_tolerance``.

    Writes the new history into row ``1 - parity[0]`` of ``hist_mean`` (vec4: mean [W/m²], n_new) and
    ``hist_moments`` (vec4: m1, m2, s², kept change ratio) and ``hist_photon_var`` (p², 0 without photon_m2),
    and per pixel ``mean_out`` (vec3 [W/m²], the accumulated
    estimate), ``variance_out`` (float32 [(W/m²)²], the variance of its luminance, σ² / n_new),
    ``frames_out`` (n_new) and ``slope_out`` (float32 [m/pixel], ‖∇z‖ for the à-trous levels). 0 without
    a surface.
    """
    y, x = wp.tid()
    p = y * width + x
    cur = 1 - parity[0]
    z = depth[p]
    if z <= 0.0:
        hist_mean[cur, p] = wp.vec4(0.0)
        hist_moments[cur, p] = wp.vec4(0.0)
        hist_photon_var[cur, p] = 0.0
        mean_out[p] = wp.vec3(0.0)
        variance_out[p] = 0.0
        frames_out[p] = 0.0
        slope_out[p] = 0.0
        return
    s_p0 = surface[p]
    n = wp.vec3(s_p0[1], s_p0[2], s_p0[3])
    count = float(0.0)  # same-surface pixels of the window
    sum_e = float(0.0)
    sum_p2 = float(0.0)  # Σ photon_m2: the window's Monte-Carlo variance this frame, summed
    keep_p2 = photon_m2.shape[0] > 0
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
    above2 = window_row(-1.0)  # ... and of the row above that
    for dy in range(-radius, radius + 1):
        left = float(-1.0)
        left2 = float(-1.0)
        for dx in range(-radius, radius + 1):
            qx = x + dx
            qy = y + dy
            col = dx + radius
            here = float(-1.0)
            if qx >= 0 and qx < width and qy >= 0 and qy < height:
                q = qy * width + qx
                s_q = surface[q]  # (z, normal): one aligned load
                z_q = s_q[0]
                if z_q > 0.0 and wp.abs(z_q - z) <= depth_tolerance * z and \
                        s_q[1] * n[0] + s_q[2] * n[1] + s_q[3] * n[2] >= normal_tolerance:
                    s = stats[q]
                    e = s[0]
                    here = e
                    count += 1.0
                    sum_e += e
                    if keep_p2:
                        sum_p2 += photon_m2[q]
                    if e > 0.0:
                        photon = wp.min(photon, e)
                    if left >= 0.0 and left2 >= 0.0:
                        sum_dh += (e - 2.0 * left + left2) * (e - 2.0 * left + left2)
                        pairs_h += 1.0
                    if above[col] >= 0.0 and above2[col] >= 0.0:
                        sum_dv += (e - 2.0 * above[col] + above2[col]) * (e - 2.0 * above[col] + above2[col])
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
            left2 = left
            left = here
            above2[col] = above[col]
            above[col] = here
    mean_e = sum_e / count
    if photon > 1.0e38:
        photon = 0.0
    # per-frame variance from this frame alone: half the mean squared difference of neighbours along the
    # direction where it is smaller (E[(E_a − E_b)²] = 2σ² + (μ_a − μ_b)²: a caustic line adds least along itself)
    var_pairs = float(0.0)
    if pairs_h > 0.0 and pairs_v > 0.0:
        var_pairs = wp.min(sum_dh / pairs_h, sum_dv / pairs_v) / 6.0
    elif pairs_h > 0.0:
        var_pairs = sum_dh / pairs_h / 6.0
    elif pairs_v > 0.0:
        var_pairs = sum_dv / pairs_v / 6.0
    s_p = stats[p]
    n_prev = s_p[3]
    c = irradiance[p]
    lum = s_p[0]
    bias2 = float(0.0)
    kept = float(0.0)  # the window's change ratio kept for the next frame
    # s²: running mean over frames of the neighbour-difference variance (each frame's free of the caustic's
    # motion; the mean over frames free of its noise)
    pairs = var_pairs
    photon_var = sum_p2 / count  # p²: the photons' own variance, the window's mean photon_m2 (0: not kept)
    if n_prev <= 0.0:  # disoccluded: the new frame alone, its variance from its neighbour differences
        alpha = float(1.0)
        n_new = float(1.0)
        sigma2_est = var_pairs
        if photon_var > 0.0:
            sigma2_est = wp.min(var_pairs, photon_var)
    else:
        pr = prev_pairs[p]
        blend = 1.0 / (wp.min(n_prev, max_history - 1.0) + 1.0)
        pairs = wp.lerp(pr[0], var_pairs, blend)
        photon_var = wp.lerp(pr[2], photon_var, blend)
        s2 = pairs  # s², at most p² where the photons' variance is known (the running means compared)
        if photon_var > 0.0:
            s2 = wp.min(pairs, photon_var)
        d2 = sum_d2 / with_history
        temporal = sum_var / with_history
        if n_prev < float(SPATIAL_VARIANCE_HISTORY):
            sum_var = s2 * with_history
            sum_var2 = s2 * s2 * with_history
        elif s2 < temporal:  # the pixels' variances scaled down to the spatial estimate, their spread kept
            scale = s2 / temporal
            sum_var = sum_var * scale
            sum_var2 = sum_var2 * scale * scale
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
        # the threshold rises with the history: a false alarm costs a long history more, while a short one
        # (just reset: the caustic was moving) more often has the next change to follow
        k = change_sigmas * wp.min(wp.pow(n_prev / FULL_THRESHOLD_HISTORY, 0.25), 1.0)
        # the tests decide whether the caustic changed; once one has, the change's size is the unbiased
        # estimate (the excess over what noise gives), not the excess over the test's threshold, which would
        # keep too much of a history that is known to be wrong
        bias2 = wp.max(wp.max(d2 - spread - k * se_d2,
                              mean_d * mean_d - k * k * spread / with_history), 0.0)
        r = float(0.0)
        if sigma2 > 0.0:
            r = bias2 / sigma2
        # a caustic that moved most likely moves on: the window's change ratio is kept, fading by the factor
        # p = change_persistence a frame, and this frame's ratio is at least what is left of it, so a drift too
        # slow for one frame's test keeps the history short. Only a change beyond the window's full threshold
        # (k standard errors, k = 5, not the lowered k_n of a short history: rare false alarms) is kept, not
        # the pixel's (3, Poisson tails: frequent ones), and only below FULL_THRESHOLD_HISTORY frames of history
        # (a still caustic's false alarm on a long history costs one cut, not a dozen frames)
        carried = change_persistence * pr[1]
        confirmed = float(0.0)
        if n_prev < FULL_THRESHOLD_HISTORY and (d2 - spread - change_sigmas * se_d2 > 0.0 or \
                mean_d * mean_d - change_sigmas * change_sigmas * spread / with_history > 0.0):
            confirmed = r
        kept = wp.min(wp.max(confirmed, carried), MAX_KEPT_RATIO)
        r = wp.max(r, carried)
        if n_prev < float(SPATIAL_VARIANCE_HISTORY):  # for the filter: the deviations, less the change found
            sigma2_est = wp.min(s2, wp.max(temporal, wp.max(d2 - bias2, 0.0) / history_noise))
        # the pixel's own deviation, tested alone against its share of the window's variance (Poisson counts:
        # in proportion to its mean, the new value standing in where larger, so one photon in a dark pixel is
        # no change): the window's test dilutes a change that covers only part of it
        if sum_m1 > 0.0:
            sigma2_p = sigma2 * wp.max(s_p[1], lum) * with_history / sum_m1 * (1.0 + 1.0 / n_prev)
            d_own = lum - s_p[1]
            bias2_p = wp.max(d_own * d_own - pixel_sigmas * pixel_sigmas * sigma2_p
                             - pixel_sigmas * photon * wp.sqrt(sigma2_p), 0.0)
            if bias2_p > 0.0:
                r = wp.max(r, bias2_p * (1.0 + 1.0 / n_prev) / sigma2_p)
                bias2 = wp.max(bias2, bias2_p)
        r = wp.min(r, 1.0e30)  # a ratio over an underflowing σ² is inf: α = 1 (reset), never inf / inf = NaN
        inv_n = 1.0 / wp.min(n_prev, max_history - 1.0)
        alpha = (r + inv_n) / (r + inv_n + 1.0)
        n_new = 1.0 / ((1.0 - alpha) * (1.0 - alpha) * (r + inv_n) + alpha * alpha)
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
    hist_mean[cur, p] = wp.vec4(mean[0], mean[1], mean[2], n_new)
    hist_moments[cur, p] = wp.vec4(moments[0], moments[1], moments[2], kept)
    hist_photon_var[cur, p] = photon_var
    mean_out[p] = mean
    variance_out[p] = sigma2_est / n_new
    frames_out[p] = n_new
    slope_out[p] = depth_gradient_length(depth, x, y, width, height)
