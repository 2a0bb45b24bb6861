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

Layout (docs/perf_notes.md section 15): :func:`reproject_history` is per pixel; it issues the pixel's loads and
its 2x2 footprint's 16 loads (16-byte history rows) before any branch on them, and Catmull-Rom's 4x4 a row of 4
taps at a time. :func:`accumulate` is tiled: a block reads its tile's window region (the tile and an apron of
``change_radius``: packed surface, ``stats`` with each point's v and 1/n computed once, ``photon_m2``) into shared
memory and every pixel's window from there. Both give the float32 sums of the per-pixel formulation in the same
order (outputs bitwise equal to it on the CPU).

Images are flat arrays of ``height * width`` pixels, row-major; :func:`reproject_history` launches with
``dim=(height, width)``, :func:`accumulate` with ``wp.launch_tiled`` (:func:`accumulate_blocks`).
History arrays are (2, H*W); ``parity[0]`` names the row holding the last frame and the kernels write the
other one (:func:`.kernels_svgf.flip_parity` swaps them at the end of the frame).
"""

from __future__ import annotations

import warp as wp

from .kernels_atrous import block_sync, load_vec4, store_vec4
from .kernels_svgf import MIN_BILINEAR_WEIGHT, SPATIAL_VARIANCE_HISTORY, luminance

#: largest half width of the change window [pixels]; ``window_row`` holds one row of it
MAX_CHANGE_RADIUS = 3
WINDOW_COLUMNS = 2 * MAX_CHANGE_RADIUS + 1
window_row = wp.types.vector(length=WINDOW_COLUMNS, dtype=wp.float32)

#: :func:`accumulate`'s output tile [pixels] (one thread a pixel on CUDA) and its window region in shared memory:
#: the tile and an apron of ``change_radius`` (the table is sized for MAX_CHANGE_RADIUS; a region point is loaded
#: once for the (2 radius + 1)² windows of up to as many tile pixels)
TILE_Y = 16
TILE_X = 16
BLOCK_THREADS = TILE_Y * TILE_X
REGION_PITCH = TILE_X + 2 * MAX_CHANGE_RADIUS
REGION_ROWS = TILE_Y + 2 * MAX_CHANGE_RADIUS
REGION_POINTS = REGION_ROWS * REGION_PITCH

# tiles compiled for the block accumulate is launched with; no adjoints (never differentiated). The window's
# column loop stays a loop (its range is the runtime radius): unrolled for MAX_CHANGE_RADIUS with the rows above
# in registers it took 255 registers and spilled 544 B (sm_90); as a loop, 109 registers and the two rows above
# (56 B) in local memory
wp.set_module_options({"enable_backward": False, "block_dim": BLOCK_THREADS})

#: threads per block of :func:`reproject_history` (``wp.launch``'s default). Both kernels are compiled for 3
#: blocks an SM (at most 85 registers: sm_90 80, with 56 B of spills (reproject) and 168 B, 56 of them the window's
#: two rows (accumulate), outside the window loop); unbounded they took 112 and 109 registers, 2 blocks an SM
REPROJECT_THREADS = 256

_TILE_Y = wp.constant(TILE_Y)
_TILE_X = wp.constant(TILE_X)
_PITCH = wp.constant(REGION_PITCH)
_MAX_R = wp.constant(MAX_CHANGE_RADIUS)
_REGION_N = wp.constant(REGION_POINTS)


@wp.func_native("""
#if defined(__CUDA_ARCH__)
const float4 v = __ldg(reinterpret_cast<const float4*>(reinterpret_cast<const char*>(a.data) + row * a.strides[0]) + q);
return wp::vec4(v.x, v.y, v.z, v.w);
#else
return *(reinterpret_cast<const wp::vec4*>(reinterpret_cast<const char*>(a.data) + row * a.strides[0]) + q);
#endif
""")
def load_row_vec4(a: wp.array2d(dtype=wp.vec4), row: int, q: int) -> wp.vec4:
    """``a[row, q]`` of a history array (rows contiguous) in one 16-byte load on CUDA (Warp's indexing issues four
    4-byte loads). The rows read are never written by the same launch."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
reinterpret_cast<float4*>(reinterpret_cast<char*>(a.data) + row * a.strides[0])[q] = make_float4(v[0], v[1], v[2], v[3]);
#else
reinterpret_cast<wp::vec4*>(reinterpret_cast<char*>(a.data) + row * a.strides[0])[q] = v;
#endif
""")
def store_row_vec4(a: wp.array2d(dtype=wp.vec4), row: int, q: int, v: wp.vec4):
    """``a[row, q] = v`` in one 16-byte store on CUDA."""
    ...


# per-thread reads and writes of accumulate's shared window region (one barrier after the loads; no negative-index
# wrap)
@wp.func_native("t.data(wp::tile_coord(i)) = v;")
def write_region(t: wp.tile[wp.vec4, REGION_POINTS], i: int, v: wp.vec4): ...


@wp.func_native("t.data(wp::tile_coord(i)) = v;")
def write_region_scalar(t: wp.tile[wp.float32, REGION_POINTS], i: int, v: float): ...


@wp.func_native("return t.data(wp::tile_coord(i));")
def read_region(t: wp.tile[wp.vec4, REGION_POINTS], i: int) -> wp.vec4: ...


@wp.func_native("return t.data(wp::tile_coord(i));")
def read_region_scalar(t: wp.tile[wp.float32, REGION_POINTS], i: int) -> float: ...
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
def history_tap_ok(inside: bool, s_q: wp.vec4, frames_q: float, z: float, n: wp.vec3, depth_tolerance: float,
                   normal_tolerance: float) -> bool:
    """Whether a history texel, ``inside`` the screen, with the packed (z, normal) ``s_q`` and effective frames
    ``frames_q``, has a surface and a history and is the same surface as this pixel (relative depth within
    ``depth_tolerance``, normal cosine at least ``normal_tolerance``)."""
    z_q = s_q[0]
    return (inside and z_q > 0.0 and wp.abs(z_q - z) <= depth_tolerance * z
            and s_q[1] * n[0] + s_q[2] * n[1] + s_q[3] * n[2] >= normal_tolerance and frames_q > 0.0)


@wp.struct
class BilinearSum:
    """Running sums of :func:`reproject_history`'s 2x2 footprint over its consistent taps."""

    sum_w: float
    mean: wp.vec3
    moments: wp.vec4
    photon_var: float
    frames: float
    lo: wp.vec3
    hi: wp.vec3
    lo_m: wp.vec2
    hi_m: wp.vec2


@wp.func
def bilinear_tap(acc: BilinearSum, ok: bool, w: float, mean4: wp.vec4, moments4: wp.vec4, var_q: float) -> BilinearSum:
    """``acc`` with one tap of weight ``w`` added if it is consistent (``ok``): its mean and n (``mean4``), moments
    (``moments4``) and p² (``var_q``). Selects, not a branch: the compiler would sink each tap's loads into its
    branch, one memory round trip a tap."""
    out = acc
    mean_q = wp.vec3(mean4[0], mean4[1], mean4[2])
    m12 = wp.vec2(moments4[0], moments4[1])
    out.sum_w = wp.where(ok, acc.sum_w + w, acc.sum_w)
    out.mean = wp.where(ok, acc.mean + w * mean_q, acc.mean)
    out.moments = wp.where(ok, acc.moments + w * moments4, acc.moments)
    out.photon_var = wp.where(ok, acc.photon_var + w * var_q, acc.photon_var)
    out.frames = wp.where(ok, acc.frames + w * mean4[3], acc.frames)
    out.lo = wp.where(ok, wp.min(acc.lo, mean_q), acc.lo)
    out.hi = wp.where(ok, wp.max(acc.hi, mean_q), acc.hi)
    out.lo_m = wp.where(ok, wp.min(acc.lo_m, m12), acc.lo_m)
    out.hi_m = wp.where(ok, wp.max(acc.hi_m, m12), acc.hi_m)
    return out


@wp.kernel(launch_bounds=(REPROJECT_THREADS, 3))
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
    flow_used: wp.array(dtype=wp.float32),
    flow_history: float,
    cur_depth: wp.array(dtype=wp.float32),
    cur_normal: wp.array(dtype=wp.vec3),
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
    à-trous levels), row ``1 - parity[0]`` of ``hist_surface`` (the same packed as (z, normal), also what
    :func:`accumulate`'s change window reads), ``prev_mean`` (vec3 [W/m²], the reprojected history mean),
    ``prev_pairs`` (vec3: its s², kept change ratio and p²) and ``stats`` = (luminance of E, m1, m2, n) of the
    reprojected history (vec4; n = 0: no history, disoccluded or no surface).

    A tap of the 2x2 bilinear footprint is consistent when it is on screen, has a surface, its depth is
    within ``depth_tolerance`` (relative) of this pixel's and its normal's cosine to this one's is at least
    ``normal_tolerance`` (as SVGF's reprojection); the consistent taps are renormalised, and fewer than
    ``MIN_BILINEAR_WEIGHT`` of the footprint means disoccluded. Where all 16 taps of the 4x4 footprint are
    consistent and the motion is fractional, the mean and (m1, m2) take the Catmull-Rom value instead, clamped
    per component to the range of the 2x2 taps (module docstring); s², p² and n stay bilinear. Where ``flow_used``
    (float32, 1 where ``motion`` is the caustic flow, :func:`caustic_motion`; an empty array: nowhere) is set, n is at
    most ``flow_history``: a real caustic flow leaves a residual the change test does not see, which a long history
    would accumulate (docs/perf_notes.md section 35).
    """
    y, x = wp.tid()
    p = y * width + x
    prev = parity[0]
    cur = 1 - prev
    # the pixel's inputs, loads issued together before any branch on them
    z = depth[p]
    tri = tri_id[p]
    n = normal[p]
    m = motion[p]
    lum = luminance(irradiance[p])
    if z <= 0.0 or tri < 0:
        cur_depth[p] = 0.0
        cur_normal[p] = wp.vec3(0.0)
        store_row_vec4(hist_surface, cur, p, wp.vec4(0.0))
        prev_mean[p] = wp.vec3(0.0)
        prev_pairs[p] = wp.vec3(0.0)
        store_vec4(stats, p, wp.vec4(0.0))
        return
    cur_depth[p] = z
    cur_normal[p] = n
    store_row_vec4(hist_surface, cur, p, wp.vec4(z, n[0], n[1], n[2]))

    px = float(x) + m[0]
    py = float(y) + m[1]
    fx0 = wp.floor(px)
    fy0 = wp.floor(py)
    fx = px - fx0
    fy = py - fy0
    x0 = int(fx0)
    y0 = int(fy0)
    # the 2x2 footprint: its 16 loads (three 16-byte rows and p² a texel; off-screen texels read texel 0 and
    # are not used) issued together, then tested and summed tap by tap
    inside_x0 = x0 >= 0 and x0 < width
    inside_x1 = x0 + 1 >= 0 and x0 + 1 < width
    inside_y0 = y0 >= 0 and y0 < height
    inside_y1 = y0 + 1 >= 0 and y0 + 1 < height
    q00 = wp.where(inside_x0 and inside_y0, y0 * width + x0, 0)
    q01 = wp.where(inside_x1 and inside_y0, y0 * width + x0 + 1, 0)
    q10 = wp.where(inside_x0 and inside_y1, (y0 + 1) * width + x0, 0)
    q11 = wp.where(inside_x1 and inside_y1, (y0 + 1) * width + x0 + 1, 0)
    s00 = load_row_vec4(hist_surface, prev, q00)
    s01 = load_row_vec4(hist_surface, prev, q01)
    s10 = load_row_vec4(hist_surface, prev, q10)
    s11 = load_row_vec4(hist_surface, prev, q11)
    h00 = load_row_vec4(hist_mean, prev, q00)
    h01 = load_row_vec4(hist_mean, prev, q01)
    h10 = load_row_vec4(hist_mean, prev, q10)
    h11 = load_row_vec4(hist_mean, prev, q11)
    k00 = load_row_vec4(hist_moments, prev, q00)
    k01 = load_row_vec4(hist_moments, prev, q01)
    k10 = load_row_vec4(hist_moments, prev, q10)
    k11 = load_row_vec4(hist_moments, prev, q11)
    v00 = hist_photon_var[prev, q00]
    v01 = hist_photon_var[prev, q01]
    v10 = hist_photon_var[prev, q10]
    v11 = hist_photon_var[prev, q11]
    tol_z = depth_tolerance
    tol_n = normal_tolerance
    acc = BilinearSum()
    acc.lo = wp.vec3(3.0e38)  # per component: the smallest and largest mean and moments (m1, m2) of the 2x2 taps
    acc.hi = wp.vec3(-3.0e38)
    acc.lo_m = wp.vec2(3.0e38)
    acc.hi_m = wp.vec2(-3.0e38)
    acc = bilinear_tap(acc, history_tap_ok(inside_x0 and inside_y0, s00, h00[3], z, n, tol_z, tol_n),
                       (1.0 - fx) * (1.0 - fy), h00, k00, v00)
    acc = bilinear_tap(acc, history_tap_ok(inside_x1 and inside_y0, s01, h01[3], z, n, tol_z, tol_n),
                       fx * (1.0 - fy), h01, k01, v01)
    acc = bilinear_tap(acc, history_tap_ok(inside_x0 and inside_y1, s10, h10[3], z, n, tol_z, tol_n),
                       (1.0 - fx) * fy, h10, k10, v10)
    acc = bilinear_tap(acc, history_tap_ok(inside_x1 and inside_y1, s11, h11[3], z, n, tol_z, tol_n),
                       fx * fy, h11, k11, v11)
    sum_w = acc.sum_w
    mean = acc.mean
    moments = acc.moments
    photon_var = acc.photon_var
    frames = acc.frames
    lo = acc.lo
    hi = acc.hi
    lo_m = acc.lo_m
    hi_m = acc.hi_m
    if sum_w >= MIN_BILINEAR_WEIGHT:
        inv = 1.0 / sum_w
        mean = mean * inv
        m12 = wp.vec2(moments[0] * inv, moments[1] * inv)
        if sum_w >= 1.0 - 1.0e-6 and (fx > 0.0 or fy > 0.0):
            # the whole 4x4 footprint the same surface: Catmull-Rom, which does not blur the history
            # frame after frame as repeated bilinear fetches do, clamped per component to the 2x2 taps'
            # range (no ringing, never negative). A row of 4 taps at a time, its 12 loads issued together
            # (sums in the same order as tap by tap); the rows stop at the first texel that is not the same
            # surface, and then none is used
            wx = catmull_rom_weights(fx)
            wy = catmull_rom_weights(fy)
            cubic = wp.vec3(0.0)
            cubic_m = wp.vec2(0.0)
            all_ok = bool(True)
            for j in range(4):
                if all_ok:
                    ty = y0 - 1 + j
                    inside_y = ty >= 0 and ty < height
                    row_ok = bool(True)
                    for i in range(4):
                        tx = x0 - 1 + i
                        inside = inside_y and tx >= 0 and tx < width
                        q = wp.where(inside, ty * width + tx, 0)
                        s_q = load_row_vec4(hist_surface, prev, q)
                        mean4 = load_row_vec4(hist_mean, prev, q)
                        moments4 = load_row_vec4(hist_moments, prev, q)
                        ok = history_tap_ok(inside, s_q, mean4[3], z, n, depth_tolerance, normal_tolerance)
                        w = wx[i] * wy[j]
                        cubic = wp.where(ok, cubic + w * wp.vec3(mean4[0], mean4[1], mean4[2]), cubic)
                        cubic_m = wp.where(ok, cubic_m + w * wp.vec2(moments4[0], moments4[1]), cubic_m)
                        row_ok = row_ok and ok
                    all_ok = row_ok
            if all_ok:
                mean = wp.min(wp.max(cubic, lo), hi)
                m12 = wp.min(wp.max(cubic_m, lo_m), hi_m)
        prev_mean[p] = mean
        prev_pairs[p] = wp.vec3(moments[2] * inv, moments[3] * inv, photon_var * inv)
        n_prev = frames * inv
        if flow_used.shape[0] > 0:
            if flow_used[p] > 0.0:  # fetched along the caustic flow: the history at most flow_history frames
                n_prev = wp.min(n_prev, flow_history)
        store_vec4(stats, p, wp.vec4(lum, m12[0], m12[1], n_prev))
    else:
        prev_mean[p] = wp.vec3(0.0)
        prev_pairs[p] = wp.vec3(0.0)
        store_vec4(stats, p, wp.vec4(lum, 0.0, 0.0, 0.0))


@wp.func
def region_one_sided(win_surface: wp.tile[wp.vec4, REGION_POINTS], z: float, v_lo: int, v_hi: int) -> float:
    """:func:`.kernels_svgf.one_sided_slope` from the window region (0 off the image: no surface there)."""
    s = float(-1.0)
    z_lo = read_region(win_surface, v_lo)[0]
    if z_lo > 0.0:
        s = wp.abs(z - z_lo)
    z_hi = read_region(win_surface, v_hi)[0]
    if z_hi > 0.0:
        d = wp.abs(z_hi - z)
        s = wp.where(s < 0.0, d, wp.min(s, d))
    return wp.max(s, 0.0)


@wp.func
def region_slope(win_surface: wp.tile[wp.vec4, REGION_POINTS], u: int, z: float) -> float:
    """‖∇z‖ [m/pixel] of the pixel at region index ``u`` (:func:`.kernels_svgf.depth_gradient_length`)."""
    gx = region_one_sided(win_surface, z, u - 1, u + 1)
    gy = region_one_sided(win_surface, z, u - _PITCH, u + _PITCH)
    return wp.sqrt(gx * gx + gy * gy)


@wp.func
def accumulate_pixel(
    win_surface: wp.tile[wp.vec4, REGION_POINTS],
    win_stats: wp.tile[wp.vec4, REGION_POINTS],
    win_m2: wp.tile[wp.float32, REGION_POINTS],
    keep_p2: bool,
    p: int,
    u: int,
    cur: int,
    irradiance: wp.array(dtype=wp.vec3),
    stats: wp.array(dtype=wp.vec4),
    prev_mean: wp.array(dtype=wp.vec3),
    prev_pairs: wp.array(dtype=wp.vec3),
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
    """:func:`accumulate` of pixel ``p``, index ``u`` in the shared window region (its window and slope read
    from there)."""
    z = read_region(win_surface, u)[0]
    if z <= 0.0:
        hist_mean[cur, p] = wp.vec4(0.0)
        hist_moments[cur, p] = wp.vec4(0.0)
        hist_photon_var[cur, p] = 0.0
        mean_out[p] = wp.vec3(0.0)
        variance_out[p] = 0.0
        frames_out[p] = 0.0
        slope_out[p] = 0.0
        return
    s_p0 = read_region(win_surface, u)
    n = wp.vec3(s_p0[1], s_p0[2], s_p0[3])
    count = float(0.0)  # same-surface pixels of the window
    sum_e = float(0.0)
    sum_p2 = float(0.0)  # Σ photon_m2: the window's Monte-Carlo variance this frame, summed
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
            col = dx + radius
            here = float(-1.0)
            v_q = u + dy * _PITCH + dx  # off the image: z = 0, not the same surface
            s_q = read_region(win_surface, v_q)  # (z, normal)
            z_q = s_q[0]
            if z_q > 0.0 and wp.abs(z_q - z) <= depth_tolerance * z and \
                    s_q[1] * n[0] + s_q[2] * n[1] + s_q[3] * n[2] >= normal_tolerance:
                s = read_region(win_stats, v_q)
                e = s[0]
                here = e
                count += 1.0
                sum_e += e
                if keep_p2:
                    sum_p2 += read_region_scalar(win_m2, v_q)
                if e > 0.0:
                    photon = wp.min(photon, e)
                if left >= 0.0 and left2 >= 0.0:
                    sum_dh += (e - 2.0 * left + left2) * (e - 2.0 * left + left2)
                    pairs_h += 1.0
                if above[col] >= 0.0 and above2[col] >= 0.0:
                    sum_dv += (e - 2.0 * above[col] + above2[col]) * (e - 2.0 * above[col] + above2[col])
                    pairs_v += 1.0
                if s[3] > 0.0:  # 1/n > 0: a history (s = (E, m1, v, 1/n), region table of accumulate)
                    d = e - s[1]
                    with_history += 1.0
                    sum_d += d
                    sum_d2 += d * d
                    v = s[2]  # max(m2 − m1², 0) n / max(n − 1, 1)
                    sum_var += v
                    sum_var2 += v * v
                    sum_m1 += s[1]
                    sum_inv_n += s[3]
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
    s_p = load_vec4(stats, p)  # (E, m1, m2, n)
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
        # the change's size is the excess over the test's threshold (a soft threshold), not the unbiased excess
        # over what noise gives: the test's false alarms are ~10³x nominal (perf_notes section 16), and sized
        # unbiased they cut still histories (perf_notes section 18: Cornell/pool 16 frames +0.8%/+1.1%, moving
        # light 0.075 -> 0.072)
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
    slope_out[p] = region_slope(win_surface, u, z)


@wp.kernel(launch_bounds=(BLOCK_THREADS, 3))
def accumulate(
    irradiance: wp.array(dtype=wp.vec3),
    photon_m2: wp.array(dtype=wp.float32),
    hist_surface: wp.array2d(dtype=wp.vec4),
    prev_mean: wp.array(dtype=wp.vec3),
    prev_pairs: wp.array(dtype=wp.vec3),
    stats: wp.array(dtype=wp.vec4),
    parity: wp.array(dtype=wp.int32),
    width: int,
    height: int,
    tiles_x: int,
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
    (z [m], 0 = none; normal) in row ``1 - parity[0]`` of ``hist_surface`` from :func:`reproject_history`,
    with its ``prev_mean`` (vec3 [W/m²]), ``prev_pairs`` (vec3: s², kept change ratio, p²) and ``stats`` (vec4: luminance of E, m1, m2, n).
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

    ``wp.launch_tiled`` over ``tiles_y * tiles_x`` blocks of ``BLOCK_THREADS`` (:func:`accumulate_blocks`): block
    ``ty * tiles_x + tx`` takes the pixels (TILE_Y ty + i, TILE_X tx + j), i < TILE_Y, j < TILE_X. Its window
    region (the tile and an apron of ``radius``: the packed surface, ``stats`` and ``photon_m2``, 0 off the image,
    where a window has no pixel either) is read into shared memory once, and every pixel's window and depth
    slope read from there.
    """
    block, lane = wp.tid()
    threads = wp.block_dim()
    cur = 1 - parity[0]
    y0 = (block // tiles_x) * _TILE_Y
    x0 = (block % tiles_x) * _TILE_X
    keep_p2 = photon_m2.shape[0] > 0
    # 1. the window region: the tile and an apron of radius, each point's three loads once (at table rows and
    # columns MAX_CHANGE_RADIUS - radius on), then one barrier
    win_surface = wp.tile_empty(shape=_REGION_N, dtype=wp.vec4, storage="shared")  # (z, normal)
    win_stats = wp.tile_empty(shape=_REGION_N, dtype=wp.vec4, storage="shared")  # (luminance of E, m1, v, 1/n)
    win_m2 = wp.tile_empty(shape=_REGION_N, dtype=wp.float32, storage="shared")  # photon_m2
    region_x = _TILE_X + 2 * radius
    offset = _MAX_R - radius
    for k in range(lane, (_TILE_Y + 2 * radius) * region_x, threads):
        i = k // region_x
        j = k - i * region_x
        qy = y0 - radius + i
        qx = x0 - radius + j
        inside = qy >= 0 and qy < height and qx >= 0 and qx < width
        q = wp.where(inside, qy * width + qx, 0)
        s_q = load_row_vec4(hist_surface, cur, q)
        st_q = load_vec4(stats, q)
        m2_q = float(0.0)
        if keep_p2:
            m2_q = photon_m2[q]
        # a window pixel's terms that need divisions, once per point (not once per window that holds it): its
        # temporal per-frame variance v and 1/n (0 without a history)
        n_q = st_q[3]
        var_q = wp.max(st_q[2] - st_q[1] * st_q[1], 0.0) * n_q / wp.max(n_q - 1.0, 1.0)
        inv_n_q = float(0.0)
        if n_q > 0.0:
            inv_n_q = 1.0 / n_q
        v = (i + offset) * _PITCH + j + offset
        write_region(win_surface, v, wp.where(inside, s_q, wp.vec4(0.0)))
        write_region(win_stats, v, wp.where(inside, wp.vec4(st_q[0], st_q[1], var_q, inv_n_q), wp.vec4(0.0)))
        write_region_scalar(win_m2, v, wp.where(inside, m2_q, 0.0))
    block_sync()
    # 2. the tile's pixels
    for k in range(lane, _TILE_Y * _TILE_X, threads):
        i = k // _TILE_X
        j = k - i * _TILE_X
        y = y0 + i
        x = x0 + j
        if y < height and x < width:
            accumulate_pixel(win_surface, win_stats, win_m2, keep_p2, y * width + x,
                             (i + _MAX_R) * _PITCH + j + _MAX_R, cur, irradiance, stats, prev_mean, prev_pairs, radius,
                             max_history, change_sigmas, pixel_sigmas, change_persistence, depth_tolerance,
                             normal_tolerance, hist_mean, hist_moments, hist_photon_var, mean_out, variance_out,
                             frames_out, slope_out)


def accumulate_blocks(width: int, height: int) -> tuple[int, int]:
    """(blocks, tiles_x) of :func:`accumulate`."""
    tiles_x = (width + TILE_X - 1) // TILE_X
    return tiles_x * ((height + TILE_Y - 1) // TILE_Y), tiles_x


@wp.kernel
def caustic_motion(motion: wp.array(dtype=wp.vec2), flow: wp.array(dtype=wp.vec4), width: int, height: int, radius: int,
                   sigmas2: float, motion_out: wp.array(dtype=wp.vec2), flow_used: wp.array(dtype=wp.float32)):
    """The motion a pixel's history is fetched by: the caustic's own where the photon pass measured it and it differs
    from the surface's significantly, else the surface's.

    Reads ``motion`` (H*W vec2 [pixels], the G-buffer's: previous position minus pixel centre) and ``flow`` (H*W vec4:
    Σ D, Σ s_D², count over the photons stored in the pixel whose light-space cell landed in both frames; D the cell's
    previous mean landing minus its current one [pixels], s_D² its variance [pixels²]:
    :mod:`cisp_warp.photons.caustic_flow`), pooled over the (2 ``radius`` + 1)² pixels around (``width`` ×
    ``height`` image; a caustic's displacement varies slowly, its per-pixel estimate is noisy). The caustic flow is
    the mean D̄ = Σ D / count, its variance at most the mean s_D² (photons of one cell share their D); it is used where |D̄ − motion|² > ``sigmas2`` · mean s_D² (k² of a
    2-dof test: false alarm e^(−k²/2), 1.1% at k = 3, on a still caustic). Writes ``motion_out`` (vec2 [pixels])."""
    p = wp.tid()
    m = motion[p]
    f = wp.vec4(0.0)
    y = p // width
    x = p - y * width
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            qx = x + dx
            qy = y + dy
            if qx >= 0 and qx < width and qy >= 0 and qy < height:
                f = f + flow[qy * width + qx]
    out = m
    used = float(0.0)
    if f[3] > 0.0:
        inv = 1.0 / f[3]
        c = wp.vec2(f[0] * inv, f[1] * inv)
        dm = c - m
        if wp.dot(dm, dm) > sigmas2 * f[2] * inv:
            out = c
            used = 1.0
    motion_out[p] = out
    flow_used[p] = used
