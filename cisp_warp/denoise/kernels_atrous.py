"""The edge-avoiding à-trous wavelet level in one launch a level, read once from shared memory: SVGF's levels.

(The caustics denoiser's gated levels run :func:`launch_atrous_level`, the per-pixel three-pass level of
:mod:`.kernels_atrous_pixel`, re-exported here: measured faster there, see that module.)

A level of tap spacing ``step`` couples only pixels whose coordinates agree modulo ``step``: the image is
``step``² interleaved sub-lattices, and on each one the level is a dense 5x5 filter. :func:`atrous_level`
gives a block of ``BLOCK_THREADS`` threads a ``TILE_Y`` x ``TILE_X`` tile of one sub-lattice and reads its
neighbourhood once into shared memory (Warp shared tiles):

1. guides of the tile plus an apron of 4 sub-lattice points (``GUIDE_Y`` x ``GUIDE_X``): the packed G-buffer
   ``(n, z)``, ‖∇z‖, and from the level's input (colour, Var) the 3x3 Gaussian g3x3(Var) over pixels with a
   surface (paper eq. 5), the luminance and, on gated levels, the footprint R still needed;
2. every w_pq = w_qp of the tile plus an apron of 2, evaluated once per unordered pair (12 forward offsets
   per pixel) and kept in shared memory;
3. W_q = Σ_r w_qr for the tile plus its apron of 2 (sums of the shared pair weights);
4. the filter of the tile's pixels from the same pair weights:
   c'_p = c_p + Σ_{q≠p} A_pq (c_q − c_p), Var'_p = Σ_q A_pq² Var_q, with
   A_pq = w_pq / max(W_p, W_q) (energy-conserving) or w_pq / W_p (the paper's gather).

w_pq (Schied et al. 2017, eqs. 3-5, made symmetric in p and q) is evaluated as one exponential:

    w_pq = h(dx) h(dy) · exp(σ_n ln max(0, n_p·n_q) − |z_p − z_q| / φ_z − |l_p − l_q| / φ_l) · g_pq

with φ_z = σ_z (max(‖∇z_p‖, ‖∇z_q‖) ‖p − q‖ + ε_z max(z_p, z_q)), φ_l = σ_l sqrt((g3x3(Var)_p + g3x3(Var)_q)/2 + ε)
(the paper's max(0, n_p·n_q)^σ_n, two exponentials and a power become one exp and one log), and the gate
g_pq = clamp(2 min(R_p, R_q) / step − 1, 0, 1): a level of tap spacing ``step`` acts fully between pixels
that both still need a footprint of ``step`` pixels and not at all where either needs less than half of it
(a pixel whose own R is below half the step keeps its value). For SVGF R = 1e30 and every gate is 1.
Pixels without a surface (depth 0) take no part and come out 0.

Between levels the image travels packed (SVGF's ``filter_moments`` packs the first): ``color_variance`` = (colour, Var),
Var = −1 marking a pixel without a surface, and the static guide ``guide`` = (n, z). The naive twin is
:func:`cisp_warp.denoise.naive.atrous_level_naive`.
"""

from __future__ import annotations

import warp as wp

from .kernels_atrous_pixel import UNGATED_RADIUS, footprint_radius, launch_atrous_level  # noqa: F401 (re-exported)
from .kernels_svgf import DEPTH_NOISE_REL, VARIANCE_EPS, b3_spline, luminance


#: Var of a packed pixel without a surface
NO_SURFACE = wp.constant(-1.0)

#: output tile [sub-lattice points]: a block filters TILE_Y x TILE_X pixels of one sub-lattice. Larger tiles
#: share their aprons among more pixels: per pixel filtered, a 16 x 32 tile reads 1.9 guides, evaluates 20.6
#: pair weights (the least possible is 12) and sums 1.4 weights; 16 x 16: 2.25, 24.8, 1.6
TILE_Y = 16
TILE_X = 32
#: threads per block (one per output pixel on CUDA; the CPU runs one lane that does them all)
BLOCK_THREADS = TILE_Y * TILE_X
#: guide region: the tile and an apron of 4 (taps of 2 whose weight sums reach 2 further)
GUIDE_Y = TILE_Y + 8
GUIDE_X = TILE_X + 8
GUIDE_PIXELS = GUIDE_Y * GUIDE_X
#: rows of the region whose forward pair weights are kept: tile rows − 4 ... tile rows + 1 (all guide columns)
PAIR_ROWS = TILE_Y + 6
PAIR_PIXELS = PAIR_ROWS * GUIDE_X
#: forward tap offsets per pixel: (0, 1), (0, 2), (1, −2..2), (2, −2..2); the other 12 are their mirrors
FORWARD_TAPS = 12
#: region whose weight sums are needed: the tile and an apron of 2
SUM_Y = TILE_Y + 4
SUM_X = TILE_X + 4

# Loops stay loops (the work is spread over the block by index arithmetic, unrolling buys nothing); tiles are
# compiled for the block the level is launched with.
wp.set_module_options({"max_unroll": 1, "enable_backward": False, "block_dim": BLOCK_THREADS})

_TILE_Y = wp.constant(TILE_Y)
_TILE_X = wp.constant(TILE_X)
_GUIDE_X = wp.constant(GUIDE_X)
_GUIDE_N = wp.constant(GUIDE_PIXELS)
_PAIR_PIXELS = wp.constant(PAIR_PIXELS)
_PAIR_N = wp.constant(FORWARD_TAPS * PAIR_PIXELS)
_SUM_X = wp.constant(SUM_X)
_SUM_N = wp.constant(SUM_Y * SUM_X)


# Single-instruction intrinsics on CUDA (2 ulp; the pair weight and the filter's A_pq take them), the exact
# operations on the CPU. Their error moves a weight by ~1e-6 relative, under the 1e-5 the twin is held to.
@wp.func_native("""
#if defined(__CUDA_ARCH__)
return __expf(x);
#else
return expf(x);
#endif
""")
def fast_exp(x: float) -> float: ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
return __fdividef(a, b);
#else
return a / b;
#endif
""")
def fast_div(a: float, b: float) -> float: ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
return rsqrtf(x);
#else
return 1.0f / sqrtf(x);
#endif
""")
def fast_rsqrt(x: float) -> float: ...


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


# Per-thread writes into the level's shared tables without a barrier each (Warp's tile_scatter_masked and
# element assignment end in __syncthreads, which cost a barrier per round of 512 items); block_sync() once a phase.
@wp.func_native("t.data(wp::tile_coord(i)) = v;")
def write_guide(t: wp.tile[wp.vec4, GUIDE_PIXELS], i: int, v: wp.vec4): ...


@wp.func_native("t.data(wp::tile_coord(i)) = v;")
def write_guide_scalar(t: wp.tile[wp.float32, GUIDE_PIXELS], i: int, v: float): ...


@wp.func_native("t.data(wp::tile_coord(i)) = v;")
def write_pair(t: wp.tile[wp.float32, FORWARD_TAPS * PAIR_PIXELS], i: int, v: float): ...


@wp.func_native("WP_TILE_SYNC();")
def block_sync():
    """Barrier of the block (every thread must reach it); a no-op for a CPU block of one lane."""
    ...


@wp.func
def log_cosine(c: float) -> float:
    """ln c of a cosine c in (0, 1] to ~1e-9 absolute where it matters (σ_n up to hundreds multiplies it):
    2 atanh(t), t = (c − 1)/(c + 1) in [−1/3, 0], by its series to t¹¹ (error below 3e-8 t); ``wp.log`` below
    c = 0.5, where c^σ_n is negligible for any σ_n worth using and which real normals rarely reach."""
    if c < 0.5:
        return wp.log(c)
    t = fast_div(c - 1.0, c + 1.0)
    t2 = t * t
    series = 1.0 + t2 * (1.0 / 3.0 + t2 * (1.0 / 5.0 + t2 * (1.0 / 7.0 + t2 * (1.0 / 9.0 + t2 * (1.0 / 11.0)))))
    return 2.0 * t * series


@wp.func
def forward_tap(f: int) -> wp.vec2i:
    """(dy, dx) [taps] of forward offset ``f`` in [0, 12): (0, 1), (0, 2), then (1, −2..2), (2, −2..2)."""
    if f < 2:
        return wp.vec2i(0, f + 1)
    g = f - 2
    return wp.vec2i(1 + g // 5, g % 5 - 2)


@wp.func
def pair_weight(gs_p: wp.vec4, gd_p: wp.vec4, gs_q: wp.vec4, gd_q: wp.vec4, kernel_weight: float, dist: float,
                step: float, sigma_depth: float, sigma_normal: float, sigma_luminance: float) -> float:
    """w_pq of the module docstring, symmetric in p and q, from the guides ``gs`` = (n, z) and ``gd`` =
    (‖∇z‖, g3x3(Var), luminance, R); ``dist`` = ‖p − q‖ [pixels]; 0 unless both have a surface."""
    if gs_p[3] <= 0.0 or gs_q[3] <= 0.0:
        return 0.0
    n_dot = gs_p[0] * gs_q[0] + gs_p[1] * gs_q[1] + gs_p[2] * gs_q[2]
    gate = wp.clamp(2.0 * wp.min(gd_p[3], gd_q[3]) / step - 1.0, 0.0, 1.0)
    if n_dot <= 0.0 or gate <= 0.0:
        return 0.0
    phi_z = sigma_depth * (wp.max(gd_p[0], gd_q[0]) * dist + DEPTH_NOISE_REL * wp.max(gs_p[3], gs_q[3]))
    inv_phi_l = fast_rsqrt(0.5 * wp.max(gd_p[1] + gd_q[1], 0.0) + VARIANCE_EPS) / sigma_luminance
    e = (sigma_normal * log_cosine(n_dot) - fast_div(wp.abs(gs_p[3] - gs_q[3]), phi_z)
         - wp.abs(gd_p[2] - gd_q[2]) * inv_phi_l)
    return kernel_weight * fast_exp(e) * gate


@wp.func
def fill_weights(guide_s: wp.tile[wp.vec4, GUIDE_PIXELS], guide_d: wp.tile[wp.vec4, GUIDE_PIXELS],
                 pair: wp.tile[wp.float32, FORWARD_TAPS * PAIR_PIXELS], weight_sum: wp.tile[wp.float32, GUIDE_PIXELS],
                 lane: int, threads: int, s: float, sigma_depth: float, sigma_normal: float, sigma_luminance: float):
    """Steps 2 and 3 of :func:`atrous_level` (cooperative: every thread of the block calls it). Writes ``pair``
    (shared, the forward pair weights w(u, u + f) of the guide rows 0 .. PAIR_ROWS - 1 at f * PAIR_PIXELS + u)
    and ``weight_sum`` (shared, W_q of the tile and an apron of 2, at their guide index)."""
    # 2. forward pair weights, once per unordered pair
    for k in range(lane, _PAIR_N, threads):
        w = float(0.0)
        f = k // _PAIR_PIXELS
        u = k - f * _PAIR_PIXELS
        tap = forward_tap(f)
        i = u // _GUIDE_X
        j = u % _GUIDE_X
        j2 = j + tap[1]
        if j2 >= 0 and j2 < _GUIDE_X:  # pairs leaving the guide region are never needed
            v = (i + tap[0]) * _GUIDE_X + j2
            w = pair_weight(guide_s[u], guide_d[u], guide_s[v], guide_d[v], b3_spline(tap[0]) * b3_spline(tap[1]),
                            s * wp.sqrt(float(tap[0] * tap[0] + tap[1] * tap[1])), s,
                            sigma_depth, sigma_normal, sigma_luminance)
        write_pair(pair, k, w)
    block_sync()

    # 3. W_q = Σ_r w_qr of the tile and an apron of 2 (centre (3/8)² included)
    for k in range(lane, _SUM_N, threads):
        u = (2 + k // _SUM_X) * _GUIDE_X + 2 + k % _SUM_X
        sum_w = b3_spline(0) * b3_spline(0)
        for f in range(FORWARD_TAPS):
            tap = forward_tap(f)
            sum_w += pair[f * _PAIR_PIXELS + u] + pair[f * _PAIR_PIXELS + u - tap[0] * _GUIDE_X - tap[1]]
        write_guide_scalar(weight_sum, u, sum_w)
    block_sync()


@wp.func
def read_signal(packed: int, color_variance: wp.array(dtype=wp.vec4), color_in: wp.array(dtype=wp.vec3),
                variance_in: wp.array(dtype=wp.float32), depth: wp.array(dtype=wp.float32), p: int) -> wp.vec4:
    """(colour, Var) of pixel ``p`` from the packed input or from the unpacked one; Var = NO_SURFACE without
    a surface (depth 0), else clamped to >= 0 (as the packed input holds it)."""
    if packed != 0:
        return load_vec4(color_variance, p)
    if depth[p] <= 0.0:
        return wp.vec4(0.0, 0.0, 0.0, NO_SURFACE)
    c = color_in[p]
    return wp.vec4(c[0], c[1], c[2], wp.max(variance_in[p], 0.0))


@wp.kernel(launch_bounds=(BLOCK_THREADS, 2))
def atrous_level(
    packed: int,
    color_variance: wp.array(dtype=wp.vec4),
    guide: wp.array(dtype=wp.vec4),
    color_in: wp.array(dtype=wp.vec3),
    variance_in: wp.array(dtype=wp.float32),
    depth: wp.array(dtype=wp.float32),
    normal: wp.array(dtype=wp.vec3),
    slope: wp.array(dtype=wp.float32),
    width: int,
    height: int,
    step: int,
    tiles_x: int,
    sigma_depth: float,
    sigma_normal: float,
    sigma_luminance: float,
    conserve_energy: int,
    gated: int,
    noise_target: float,
    write_packed: int,
    color_variance_out: wp.array(dtype=wp.vec4),
    write_public: int,
    color_out: wp.array(dtype=wp.vec3),
    variance_out: wp.array(dtype=wp.float32),
    write_history: int,
    parity: wp.array(dtype=wp.int32),
    hist_color: wp.array2d(dtype=wp.vec3),
):
    """One à-trous level (module docstring), ``wp.launch_tiled`` over ``tiles_y * tiles_x * step²`` blocks of
    ``BLOCK_THREADS``; block ``((ty * tiles_x + tx) * step + a) * step + b`` filters the sub-lattice points
    (TILE_Y ty + i, TILE_X tx + j), i < TILE_Y, j < TILE_X, i.e. pixels (a + step (TILE_Y ty + i),
    b + step (TILE_X tx + j)).

    Reads, with ``packed`` != 0, the packed level input ``color_variance`` (H*W vec4: colour [W/m²], Var;
    Var < 0 = no surface) and ``guide`` (H*W vec4: n, z [m]), else the same from ``color_in`` (H*W vec3),
    ``variance_in`` (H*W float32), ``depth`` (H*W float32 [m], 0 = none) and ``normal`` (H*W vec3); and
    ``slope`` (H*W float32 [m/pixel]). ``gated`` != 0: R from g3x3(Var)
    and the same Gaussian's mean luminance (:func:`footprint_radius`, relative ``noise_target``), else
    R = ``UNGATED_RADIUS``. Writes, each when its flag is set: ``color_variance_out`` (packed, the next
    level's input), ``color_out`` (H*W vec3 [W/m²]) and ``variance_out`` (H*W float32; both 0 without a
    surface), and row ``1 - parity[0]`` of ``hist_color`` (2 x H*W vec3, the colour history). The outputs
    must not alias the inputs.
    """
    block, lane = wp.tid()
    threads = wp.block_dim()
    cell = step * step
    sub = block % cell
    row0 = sub // step  # sub-lattice: pixel rows ≡ row0, columns ≡ col0 (mod step)
    col0 = sub % step
    t = block // cell
    sy0 = (t // tiles_x) * _TILE_Y - 4  # sub-lattice coordinates of guide element (0, 0)
    sx0 = (t % tiles_x) * _TILE_X - 4
    s = float(step)

    # 1. guides of the tile and an apron of 4, read once
    guide_s = wp.tile_empty(shape=_GUIDE_N, dtype=wp.vec4, storage="shared")  # (n, z)
    guide_d = wp.tile_empty(shape=_GUIDE_N, dtype=wp.vec4, storage="shared")  # (‖∇z‖, g3x3 Var, l, R)
    signal = wp.tile_empty(shape=_GUIDE_N, dtype=wp.vec4, storage="shared")  # (colour, Var)
    filtered = int(0)  # pixels of the output tile with a surface and some gate open that this thread read
    for k in range(lane, _GUIDE_N, threads):
        gs = wp.vec4(0.0)
        gd = wp.vec4(0.0)
        cv = wp.vec4(0.0)
        y = row0 + step * (sy0 + k // _GUIDE_X)
        x = col0 + step * (sx0 + k % _GUIDE_X)
        if y >= 0 and y < height and x >= 0 and x < width:
            p = y * width + x
            cv = read_signal(packed, color_variance, color_in, variance_in, depth, p)
            if cv[3] >= 0.0:
                if packed != 0:
                    gs = load_vec4(guide, p)
                else:
                    n = normal[p]
                    gs = wp.vec4(n[0], n[1], n[2], depth[p])
                sum_k = float(0.0)
                sum_v = float(0.0)
                sum_l = float(0.0)
                for dy in range(-1, 2):
                    for dx in range(-1, 2):
                        qx = x + dx
                        qy = y + dy
                        if qx >= 0 and qx < width and qy >= 0 and qy < height:
                            cv_q = read_signal(packed, color_variance, color_in, variance_in, depth,
                                               qy * width + qx)
                            if cv_q[3] >= 0.0:
                                kq = wp.where(dx == 0, 0.5, 0.25) * wp.where(dy == 0, 0.5, 0.25)
                                sum_k += kq
                                sum_v += kq * cv_q[3]
                                if gated != 0:
                                    sum_l += kq * luminance(wp.vec3(cv_q[0], cv_q[1], cv_q[2]))
                var_blur = sum_v / sum_k
                radius = UNGATED_RADIUS
                if gated != 0:
                    radius = footprint_radius(var_blur, sum_l / sum_k, noise_target)
                gd = wp.vec4(slope[p], var_blur, luminance(wp.vec3(cv[0], cv[1], cv[2])), radius)
                i = k // _GUIDE_X
                j = k % _GUIDE_X
                if i >= 4 and i < 4 + _TILE_Y and j >= 4 and j < 4 + _TILE_X and 2.0 * radius > s:
                    filtered += 1
            else:
                cv = wp.vec4(0.0)
        write_guide(guide_s, k, gs)
        write_guide(guide_d, k, gd)
        write_guide(signal, k, cv)
    block_sync()

    pair = wp.tile_empty(shape=_PAIR_N, dtype=wp.float32, storage="shared")
    weight_sum = wp.tile_empty(shape=_GUIDE_N, dtype=wp.float32, storage="shared")
    # a block whose tile has no surface (the sky, the space around the Cornell box) or, on a gated level, only
    # pixels that need less than half the step (converged) skips 2 and 3: step 4 reads neither table then
    if wp.tile_sum(wp.tile(filtered))[0] > 0:
        fill_weights(guide_s, guide_d, pair, weight_sum, lane, threads, s, sigma_depth, sigma_normal,
                     sigma_luminance)

    # 4. the filter of the tile's pixels
    for k in range(lane, _TILE_Y * _TILE_X, threads):
        y = row0 + step * (sy0 + 4 + k // _TILE_X)
        x = col0 + step * (sx0 + 4 + k % _TILE_X)
        if y < height and x < width:
            p = y * width + x
            u = (4 + k // _TILE_X) * _GUIDE_X + 4 + k % _TILE_X
            cv_p = signal[u]
            c_p = wp.vec3(cv_p[0], cv_p[1], cv_p[2])
            v_p = cv_p[3]
            c_new = wp.vec3(0.0)
            v_new = float(0.0)
            if guide_s[u][3] > 0.0:
                c_new = c_p
                v_new = v_p
            if guide_s[u][3] > 0.0 and 2.0 * guide_d[u][3] > s:  # else every gate of p is 0: A_pp = 1
                w_p = weight_sum[u]
                sum_a = float(0.0)  # Σ_{q≠p} A_pq
                sum_dc = wp.vec3(0.0)  # Σ_{q≠p} A_pq (c_q − c_p)
                sum_av = float(0.0)  # Σ_{q≠p} A_pq² Var_q
                for m in range(2 * FORWARD_TAPS):
                    f = m // 2
                    tap = forward_tap(f)
                    off = tap[0] * _GUIDE_X + tap[1]
                    q = u + off
                    w = float(0.0)
                    if m % 2 == 0:
                        w = pair[f * _PAIR_PIXELS + u]
                    else:
                        q = u - off
                        w = pair[f * _PAIR_PIXELS + q]
                    if w > 0.0:
                        a = fast_div(w, wp.where(conserve_energy != 0, wp.max(w_p, weight_sum[q]), w_p))
                        cv_q = signal[q]
                        sum_a += a
                        sum_dc += a * (wp.vec3(cv_q[0], cv_q[1], cv_q[2]) - c_p)
                        sum_av += a * a * cv_q[3]
                a_centre = 1.0 - sum_a
                c_new = c_p + sum_dc
                v_new = sum_av + a_centre * a_centre * v_p
            if write_packed != 0:
                color_variance_out[p] = wp.vec4(c_new[0], c_new[1], c_new[2],
                                                wp.where(guide_s[u][3] > 0.0, v_new, NO_SURFACE))
            if write_public != 0:
                color_out[p] = c_new
                variance_out[p] = v_new
            if write_history != 0:
                hist_color[1 - parity[0], p] = c_new


_SPARE: dict = {}


def spare_outputs(device) -> dict:
    """One-element stand-ins (allocated once per device) for the outputs a launch does not write."""
    key = str(device)
    if key not in _SPARE:
        _SPARE[key] = {"vec3": wp.zeros(1, dtype=wp.vec3, device=device),
                       "vec4": wp.zeros(1, dtype=wp.vec4, device=device),
                       "float": wp.zeros(1, dtype=wp.float32, device=device),
                       "hist": wp.zeros((2, 1), dtype=wp.vec3, device=device),
                       "parity": wp.zeros(1, dtype=wp.int32, device=device)}
    return _SPARE[key]


def atrous_blocks(width: int, height: int, step: int) -> tuple[int, int]:
    """(blocks, tiles_x) of :func:`atrous_level` at tap spacing ``step``."""
    sub_w = (width + step - 1) // step
    sub_h = (height + step - 1) // step
    tiles_x = (sub_w + TILE_X - 1) // TILE_X
    tiles_y = (sub_h + TILE_Y - 1) // TILE_Y
    return tiles_y * tiles_x * step * step, tiles_x


def launch_atrous(color_variance: wp.array | None, guide: wp.array | None, slope: wp.array, width: int, height: int,
                  step: int, sigma_depth: float, sigma_normal: float, sigma_luminance: float, conserve_energy: bool,
                  noise_target: float | None = None, color_variance_out: wp.array | None = None,
                  color_out: wp.array | None = None, variance_out: wp.array | None = None,
                  hist_color: wp.array | None = None, parity: wp.array | None = None,
                  unpacked: tuple | None = None) -> None:
    """Launch :func:`atrous_level` on the packed input (``color_variance``, ``guide``: H*W vec4, see the module
    docstring) or, given ``unpacked`` = (color_in, variance_in, depth, normal), on those (the packed ones then
    None); ``slope``: H*W float32 [m/pixel]. ``noise_target`` (relative, e.g. 0.05): gate the level by the
    footprint the remaining variance needs; None: ungated (SVGF). Each output given is written:
    ``color_variance_out`` (packed, H*W vec4), ``color_out`` + ``variance_out`` (H*W vec3 [W/m²] and float32,
    given together), ``hist_color`` + ``parity`` (the colour history row ``1 - parity[0]``). No output may
    alias an input (blocks read their neighbours' inputs while others write)."""
    d = slope.device
    spare = spare_outputs(d)
    blocks, tiles_x = atrous_blocks(width, height, step)
    gated = noise_target is not None
    write_public = color_out is not None
    if write_public != (variance_out is not None):
        raise ValueError("color_out and variance_out are written together")
    write_history = hist_color is not None
    if write_history and parity is None:
        raise ValueError("hist_color needs parity")
    packed = unpacked is None
    if packed:
        color_in, variance_in, depth, normal = spare["vec3"], spare["float"], spare["float"], spare["vec3"]
    else:
        color_in, variance_in, depth, normal = unpacked
        color_variance = guide = spare["vec4"]
    wp.launch_tiled(atrous_level, dim=blocks, block_dim=BLOCK_THREADS, device=d,
                    inputs=[int(packed), color_variance, guide, color_in, variance_in, depth, normal, slope, width,
                            height, int(step), tiles_x, float(sigma_depth), float(sigma_normal),
                            float(sigma_luminance), int(conserve_energy), int(gated),
                            float(noise_target) if gated else 0.0,
                            int(color_variance_out is not None),
                            color_variance_out if color_variance_out is not None else spare["vec4"],
                            int(write_public), color_out if write_public else spare["vec3"],
                            variance_out if write_public else spare["float"], int(write_history),
                            parity if write_history else spare["parity"],
                            hist_color if write_history else spare["hist"]])
