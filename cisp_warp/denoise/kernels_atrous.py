"""The edge-avoiding à-trous wavelet level, tiled: a dense guide pass and one tiled launch a level, the level's
neighbourhood read once into shared memory. SVGF's levels and the caustics denoiser's gated levels.

(:mod:`.kernels_atrous_pixel` holds the per-pixel three-pass form of the same level, the caustics denoiser's
``levels="pixel"``; both have one naive twin.)

A level of tap spacing ``step`` couples only pixels whose coordinates agree modulo ``step``: the image is
``step``² interleaved sub-lattices, and on each one the level is a dense 5x5 filter. A level is two launches:

0. :func:`atrous_guide`, dense over the pixels: from the level's input (colour, Var) and ‖∇z‖ it writes the
   per-pixel terms every pair weight takes (σ_z ‖∇z‖, the 3x3 Gaussian g3x3(Var) over pixels with a surface,
   paper eq. 5, the luminance, and on gated levels the footprint R still needed). Its 3x3 neighbourhoods lie
   on other sub-lattices than the pixel's, so the level itself would read them nine scattered loads a guide;
   here they are read once, neighbours in the same cache lines (ungated from a packed input, only their Var: one
   4-byte load each). (It also packs an unpacked input.) At a step of ``LATTICE_STEP`` (8) or more, given the
   buffers (SVGF), it writes its terms and copies of the input and the guide in the step's sub-lattice-major order
   (:func:`lattice_index`), so that the level's tile rows are dense: otherwise each of its 16-byte loads takes its
   own sector at those steps.
   SVGF's chained levels (section 71) feed it what it reads from the level before: each level but the last writes
   its output's Var densely as well (4 bytes a pixel, ``variance_next``), which is all the next guide pass reads of
   its input, and a level whose next one reads the sub-lattice-major order writes its packed output in that order
   (``lattice_out``), so that the guide pass copies no input.
   SVGF's first level (ungated, step 1, packed input, σ_n = 128) has no guide pass (section 68): at step 1 the 3x3
   neighbourhood of a guide point is its neighbourhood in the level's own tile, so that level (compiled with
   ``self_guide``) reads σ_z ‖∇z‖ from ``slope`` and blurs its own variance from an apron of 5 (step 1b below).

:func:`atrous_level` then gives a block of ``BLOCK_THREADS`` threads a ``TILE_Y`` x ``TILE_X`` tile of one
sub-lattice, in shared memory (Warp shared tiles):

1. guides of the tile plus an apron of 4 sub-lattice points (``GUIDE_Y`` x ``GUIDE_X``): the packed G-buffer
   ``(n, z)``, the guide pass's terms and the input (colour, Var), three loads a point (16, 16 and, ungated
   (SVGF), 8 bytes: the guide pass writes only σ_z ‖∇z‖ and g3x3(Var) there, the luminance comes from the colour;
   gated, 16), two points a thread issued together in one round; the barrier after it (``__syncthreads_or``) also tells whether the
   tile has any pixel to filter, and a second one whether the tile or its apron of 2 (the taps) has any signal
   (colour != 0 or Var > 0): without both, 2-4 are skipped and each pixel keeps its input, which is then exactly
   the filter's output (0, or the unfiltered pixel where every gate is closed);
   1b. (``self_guide`` only, where 2-4 run) g3x3(Var) / 2 of every guide point from the Var of the region and its
   outer ring (read in step 1 into the pair table, which 2 then overwrites), and a barrier;
2. every w_pq = w_qp of the tile plus an apron of 2, evaluated once per unordered pair (12 forward offsets
   per pixel, a thread taking two neighbours of a row with their guides in registers and reading each q of
   their taps once for both; offsets, kernel weights and distances known to the compiler) and kept in shared
   memory;
3. 1 / W_q, W_q = Σ_r w_qr, for the tile plus its apron of 2 (sums of the shared pair weights);
4. the filter of the tile's pixels from the same pair weights, branch-free over the 24 taps:
   c'_p = A_pp c_p + Σ_{q≠p} A_pq c_q, A_pp = 1 − Σ_{q≠p} A_pq, Var'_p = Σ_q A_pq² Var_q, with
   A_pq = w_pq min(1/W_p, 1/W_q) = w_pq / max(W_p, W_q) (energy-conserving) or w_pq / W_p (the paper's gather).

w_pq (Schied et al. 2017, eqs. 3-5, made symmetric in p and q) is evaluated as one exponential:

    w_pq = h(dx) h(dy) · exp(σ_n ln max(0, n_p·n_q) − |z_p − z_q| / φ_z − |l_p − l_q| / φ_l) · g_pq

with φ_z = σ_z (max(‖∇z_p‖, ‖∇z_q‖) ‖p − q‖ + ε_z max(z_p, z_q)), φ_l = σ_l sqrt((g3x3(Var)_p + g3x3(Var)_q)/2 + ε)
(the paper's max(0, n_p·n_q)^σ_n, two exponentials and a power become one exp and one log), and the gate
g_pq = clamp(2 min(R_p, R_q) / step − 1, 0, 1): a level of tap spacing ``step`` acts fully between pixels
that both still need a footprint of ``step`` pixels and not at all where either needs less than half of it
(a pixel whose own R is below half the step keeps its value). For SVGF R = 1e30 and every gate is 1.
Pixels without a surface (depth 0) take no part and come out 0.

Between levels the image travels packed (SVGF's ``reproject`` and ``filter_moments`` pack the first; the caustics
denoiser's first :func:`atrous_guide` does): ``color_variance`` = (colour, Var), Var = −1 marking a pixel without a
surface, and the static guide ``guide`` = (n, z). The naive twin is
:func:`cisp_warp.denoise.naive.atrous_level_naive`.

Costs (H100, 1920x1080, docs/perf_notes.md sections 9, 11, 26, 38 and 46): SVGF's 5 levels (``atrous_level`` +
``unpack_level``) 0.69 ms on the Cornell box, 1.09 ms on the pool, plus 0.17 / 0.21 ms of guide passes. Of the
pool's 1.16 before section 46: 0.43 the blocks' guide loads, barriers and the filter phase's reads, whether or not
they filter (a dense kernel that reads three vec4 a pixel and writes one runs 0.050 ms a level), 0.05 their stores,
~0.50 the pair weights and weight sums, ~0.16 the filter taps. Only blocks with a pixel to filter run the last two,
which is why the pool (96% of its blocks) costs more than the Cornell box (41%). Per pixel a level evaluates 20.6
pair weights (~37 instructions each on the common path, ~43 before section 46), 24 filter taps (~10) and reads 1.9
guides; two blocks an SM (the shared tables, 101 KB, and 64 registers a thread allow no more). Section 50: blocks
whose tile and apron hold no signal (a still pool's walls and deck, 28-64% of its blocks by level) skip the pair
weights, sums and taps: SVGF's pool levels 1.075 → 0.76 ms. (Sparing them their guide loads too, through per-block
flags of the previous level, measured slower: section 50.) Section 61: σ_n = 128 (the default) as seven squarings,
~26 instructions a pair weight and no branch: 0.67 → 0.64 (Cornell), 0.72 → 0.70 (pool) on section 38's G-buffers;
with the pair phase skipped altogether the levels still take 0.47 / 0.57 ms (what remains is that fixed part).
Section 68: SVGF's step-1 level makes its own guide terms, one guide pass (~0.03 ms) fewer; the ungated guide
passes read their neighbours' Var alone. Section 71 (predicted, not measured): SVGF's guide passes read a dense
float32 Var the level before wrote (24 instead of ~60-76 bytes a pixel to and from L2), the lattice levels' input
written in their order by the level before. Section 73 (predicted, not measured): those guide passes take 4 pixels of a
row a thread (:func:`make_guide_run`, ``GUIDE_RUN``), the same values; and why the pool's levels cost more than the
Cornell box's (more blocks whose apron holds a signal at steps 8 and 16). Section 83 (predicted, not measured): the
shared tables' rows an odd number of entries apart and the pair phase's items given to lanes by row pairs
(``ODD_PITCH``), so that its 16-byte guide reads and pair writes take no bank conflicts (half the shared-memory
cycles of that phase), the same values. Section 85 (predicted, not measured): SVGF's σ_n = 128 levels evaluate the pair
weights without the select on p's surface (``SELECT_FREE``: a point without a surface has guides whose weights are
0 by their own arithmetic), and its step-2 level blurs its own variance from the step-1 level's dense Var copy
(``FOLD_GUIDE2``): one guide pass fewer; the same values.
"""

from __future__ import annotations

import os

import warp as wp

from .kernels_atrous_pixel import UNGATED_RADIUS, footprint_radius, launch_atrous_level  # noqa: F401 (re-exported)
from .kernels_svgf import (DEPTH_NOISE_REL, VARIANCE_EPS, b3_spline, lattice_index, load_vec4, luminance,  # noqa: F401
                           store_vec4)  # lattice_index and the vec4 accesses re-exported


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
#: the shared tables' rows an odd number of entries apart, and the pair phase's items given to lanes so that each
#: group of 8 lanes takes 4 items of one row and 4 of the next (section 83): its 16-byte guide reads and 4-byte pair
#: writes then spread over every bank (a warp's reads of items 2 entries apart along one row, as with an even pitch,
#: hit every bank twice as often: twice the cycles). The same values bit for bit. Read at import, from the
#: environment (the lead's A/B, before the module is imported: ``os.environ["CISP_ATROUS_ODD_PITCH"] = "0"``: the
#: even pitch and row-major items, as before)
ODD_PITCH = os.environ.get("CISP_ATROUS_ODD_PITCH", "1") != "0"
#: row pitch of the shared guide and pair tables: the guide region's columns and 2 empty (no surface) columns
#: on either side, so that no tap of a guide leaves its row and no pair needs a column test; with ``ODD_PITCH`` one
#: more column, never written nor read
GUIDE_PITCH = GUIDE_X + (5 if ODD_PITCH else 4)
GUIDE_PIXELS = GUIDE_Y * GUIDE_PITCH
#: rows of the region whose forward pair weights are kept: tile rows − 4 ... tile rows + 1 (all guide columns)
PAIR_ROWS = TILE_Y + 6
PAIR_PIXELS = PAIR_ROWS * GUIDE_PITCH
#: forward tap offsets per pixel: (0, 1), (0, 2), (1, −2..2), (2, −2..2); the other 12 are their mirrors
FORWARD_TAPS = 12
#: points of a pair row an item of step 2 takes (a run along the row, all forward taps, guides in registers)
RUN = 2
#: region whose weight sums are needed: the tile and an apron of 2
SUM_Y = TILE_Y + 4
SUM_X = TILE_X + 4

#: bits of what a thread found among its guide points (:func:`store_guide`): a pixel to filter, a signal to filter
TO_FILTER = wp.constant(1)
HAS_SIGNAL = wp.constant(2)

#: levels of this step and above read their input, guides and guide-pass terms in sub-lattice-major order
#: (:func:`lattice_index`), written so by their guide pass when the caller gives the buffers: a row of a tile is
#: then 16 contiguous bytes a point instead of one 16-byte load per 32-byte sector (or per 128-byte line)
LATTICE_STEP = 8
#: a last level of this step and above writes its output packed (one 16-byte store a pixel) and :func:`unpack_level`
#: writes the public colour and variance densely, when the caller gives a scratch: the level's own stores of them
#: (four 4-byte stores a pixel, ``step`` pixels apart) each take a sector of their own
UNPACK_STEP = 8

# Constant-range loops (the 12 forward taps, the 3x3 Gaussian) are unrolled, so every tap's offset, kernel
# weight and distance is a constant; the loops that spread work over the block are not (their range is not
# constant). Tiles are compiled for the block the level is launched with.
wp.set_module_options({"max_unroll": FORWARD_TAPS, "enable_backward": False, "block_dim": BLOCK_THREADS})

_TILE_Y = wp.constant(TILE_Y)
_TILE_X = wp.constant(TILE_X)
_GUIDE_X = wp.constant(GUIDE_X)
_PITCH = wp.constant(GUIDE_PITCH)
_GUIDE_N = wp.constant(GUIDE_PIXELS)
_GUIDE_REAL = wp.constant(GUIDE_Y * GUIDE_X)
_GUIDE_HALF = wp.constant((GUIDE_Y * GUIDE_X + 1) // 2)
_EMPTY_N = wp.constant(GUIDE_Y * 4)
_PAIR_PIXELS = wp.constant(PAIR_PIXELS)
_PAIR_N = wp.constant(FORWARD_TAPS * PAIR_PIXELS)
assert GUIDE_X % RUN == 0 and (GUIDE_X // RUN) % 4 == 0 and PAIR_ROWS % 2 == 0
_RUNS_X = wp.constant(GUIDE_X // RUN)
_RUN_N = wp.constant(PAIR_ROWS * GUIDE_X // RUN)
#: the step-1 level that blurs its own variance (:func:`make_atrous_level`'s ``self_guide``): the guide region and an
#: apron of 1 more, ``RING_Y`` x ``RING_X`` (g3x3(Var) of every guide point), its Var kept in the pair table's
#: first entries until the pair weights overwrite them; the ring outside the guide region has ``RING_N`` points
RING_Y = GUIDE_Y + 2
RING_X = GUIDE_X + 2
RING_N = 2 * RING_X + 2 * GUIDE_Y
assert RING_N <= (GUIDE_Y * GUIDE_X + 1) // 2 and RING_Y * RING_X <= FORWARD_TAPS * PAIR_ROWS * GUIDE_PITCH
_RING_X = wp.constant(RING_X)
_RING_N = wp.constant(RING_N)
#: section 85: SVGF's step-2 level that blurs its own variance (``self_guide`` = 2, :data:`FOLD_GUIDE2`): the dense
#: pixels of its guide region's 3x3 neighbourhoods, ``REGION_Y`` x ``REGION_X`` (the guide points 2 pixels apart and
#: a pixel more on each side), their Var read from the previous level's dense copy into the pair table's first
#: entries, only in blocks that run, a run of ``REGION_RUN`` pixels of a row a thread (its loads in flight together)
REGION_Y = 2 * GUIDE_Y + 1
REGION_X = 2 * GUIDE_X + 1
REGION_RUN = 9
assert REGION_X % REGION_RUN == 0 and REGION_Y * REGION_X // REGION_RUN <= BLOCK_THREADS
assert REGION_Y * REGION_X <= FORWARD_TAPS * PAIR_ROWS * GUIDE_PITCH
_REGION_X = wp.constant(REGION_X)
_REGION_N = wp.constant(REGION_Y * REGION_X)
_REGION_RUNS_X = wp.constant(REGION_X // REGION_RUN)
_REGION_RUNS = wp.constant(REGION_Y * REGION_X // REGION_RUN)
_vec_round = wp.types.vector(length=REGION_RUN, dtype=wp.float32)
_SUM_X = wp.constant(SUM_X)
_SUM_N = wp.constant(SUM_Y * SUM_X)
#: σ_n = 2^NORMAL_SQUARINGS (128, both denoisers' default) has a level of its own whose normal term is that many
#: multiplications (:func:`pair_weight`); MAX_SQUARINGS bounds the unrolled loop that takes them
NORMAL_SQUARINGS = 7
MAX_SQUARINGS = wp.constant(8)
#: Section 85: SVGF's ungated σ_n = 128 levels (steps 1-16) give a point without a surface the guide terms (n, z) = 0
#: and σ_z ‖∇z‖ ln 2 = DEAD_SLOPE (others 0), so that a pair weight with such a p is 0 from its own arithmetic
#: (c = 0, a finite exponent) and :func:`tap_weight` evaluates it without the select on p's surface. Read at launch
#: (:func:`launch_atrous`): True (default) the select-free levels, False the levels with the select (main's, the twin).
SELECT_FREE = True
#: the dead point's σ_z ‖∇z‖ ln 2: φ_z >= DEAD_SLOPE ‖p − q‖ > 0 for every pair with such a point, finite up to
#: steps of 2^30 (‖p − q‖ <= 2.9 step), so that |z_p − z_q| / φ_z is finite and no 0 · ∞ arises
DEAD_SLOPE = wp.constant(1.0e28)
#: W_p's own term h(0)² = (3/8)²
CENTRE_WEIGHT = wp.constant(0.140625)
#: ln 2 and log2(e), the scales of :func:`pair_scales`
LN2 = 0.6931471805599453
LOG2E = 1.4426950408889634


# Single-instruction intrinsics on CUDA (the approximate exp2, reciprocal and reciprocal square root, 2 ulp, with
# subnormals flushed to 0: no fix-up instructions around them), the exact operations on the CPU. Their error
# moves a weight by ~1e-6 relative, under the 1e-5 the twin is held to.
@wp.func_native("""
#if defined(__CUDA_ARCH__)
float y;
asm("ex2.approx.ftz.f32 %0, %1;" : "=f"(y) : "f"(x * 1.4426950408889634f));
return y;
#else
return expf(x);
#endif
""")
def fast_exp(x: float) -> float: ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
float y;
asm("ex2.approx.ftz.f32 %0, %1;" : "=f"(y) : "f"(x));
return y;
#else
return exp2f(x);
#endif
""")
def fast_exp2(x: float) -> float:
    """2^x (the exponential instruction alone on CUDA, 2 ulp, subnormals flushed to 0)."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
float r;
asm("rcp.approx.ftz.f32 %0, %1;" : "=f"(r) : "f"(b));
return a * r;
#else
return a / b;
#endif
""")
def fast_div(a: float, b: float) -> float: ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
float r;
asm("rcp.approx.ftz.f32 %0, %1;" : "=f"(r) : "f"(x));
return r;
#else
return 1.0f / x;
#endif
""")
def fast_rcp(x: float) -> float:
    """1 / x to 1 ulp on CUDA (the reciprocal instruction alone: the correctly rounded one calls a slow path,
    whose calling convention spills the level's registers)."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
float r;
asm("rsqrt.approx.ftz.f32 %0, %1;" : "=f"(r) : "f"(x));
return r;
#else
return 1.0f / sqrtf(x);
#endif
""")
def fast_rsqrt(x: float) -> float: ...


# Per-thread writes into the level's shared tables without a barrier each (Warp's tile_scatter_masked and
# element assignment end in __syncthreads, which cost a barrier per round of 512 items); block_sync() once a phase.
@wp.func_native("t.data(wp::tile_coord(i)) = v;")
def write_guide(t: wp.tile[wp.vec4, GUIDE_PIXELS], i: int, v: wp.vec4): ...


@wp.func_native("t.data(wp::tile_coord(i)) = v;")
def write_guide_scalar(t: wp.tile[wp.float32, GUIDE_PIXELS], i: int, v: float): ...


@wp.func_native("t.data(wp::tile_coord(i)) = v;")
def write_pair(t: wp.tile[wp.float32, FORWARD_TAPS * PAIR_PIXELS], i: int, v: float): ...


# ... and reads without Warp's negative-index wrap (a compare and a select per read)
@wp.func_native("return t.data(wp::tile_coord(i));")
def read_guide(t: wp.tile[wp.vec4, GUIDE_PIXELS], i: int) -> wp.vec4: ...


@wp.func_native("return t.data(wp::tile_coord(i));")
def read_guide_scalar(t: wp.tile[wp.float32, GUIDE_PIXELS], i: int) -> float: ...


@wp.func_native("return t.data(wp::tile_coord(i));")
def read_pair(t: wp.tile[wp.float32, FORWARD_TAPS * PAIR_PIXELS], i: int) -> float: ...


@wp.func_native("WP_TILE_SYNC();")
def block_sync():
    """Barrier of the block (every thread must reach it); a no-op for a CPU block of one lane."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
return __syncthreads_or(x);
#else
WP_TILE_SYNC();
t.data(wp::tile_coord(0)) = 0;
WP_TILE_SYNC();
if (x != 0)
    t.data(wp::tile_coord(0)) = 1;
WP_TILE_SYNC();
return t.data(wp::tile_coord(0));
#endif
""")
def block_sync_or(t: wp.tile[wp.int32, 1], x: int) -> int:
    """Barrier of the block that returns 1 on every thread if ``x`` != 0 on any (``__syncthreads_or`` on CUDA:
    one barrier; the CPU's lanes go through the shared flag ``t``)."""
    ...


@wp.func
def atanh_series(t: float) -> float:
    """atanh(t) = ln((1 + t)/(1 − t)) / 2 for t in [−1/3, 0] by its series to t¹¹ (truncation error below 1.5e-8 |t|)."""
    t2 = t * t
    return t + t * (t2 * (1.0 / 3.0 + t2 * (1.0 / 5.0 + t2 * (1.0 / 7.0 + t2 * (1.0 / 9.0 + t2 * (1.0 / 11.0))))))


@wp.func
def log_series(t: float) -> float:
    """2 atanh(t) = ln((1 + t)/(1 − t)) for t in [−1/3, 0] by its series to t¹¹ (error below 3e-8 |t|)."""
    return 2.0 * atanh_series(t)


@wp.func
def log_cosine(c: float) -> float:
    """ln c of a cosine c in (0, 1] to ~1e-9 absolute where it matters (σ_n up to hundreds multiplies it):
    2 atanh(t), t = (c − 1)/(c + 1) in [−1/3, 0] (:func:`log_series`); ``wp.log`` below c = 0.5, where c^σ_n
    is negligible for any σ_n worth using and which real normals rarely reach."""
    if c < 0.5:
        return wp.log(c)
    return log_series(fast_div(c - 1.0, c + 1.0))


@wp.func
def forward_tap(f: int) -> wp.vec2i:
    """(dy, dx) [taps] of forward offset ``f`` in [0, 12): (0, 1), (0, 2), then (1, −2..2), (2, −2..2)."""
    if f < 2:
        return wp.vec2i(0, f + 1)
    g = f - 2
    return wp.vec2i(1 + g // 5, g % 5 - 2)


@wp.func
def forward_offset(f: int) -> int:
    """Index offset of forward tap ``f`` in the shared tables (row-major, ``GUIDE_PITCH`` wide)."""
    tap = forward_tap(f)
    return tap[0] * _PITCH + tap[1]


@wp.func
def forward_kernel(f: int) -> float:
    """h(dy) h(dx) of forward tap ``f`` (B3 spline)."""
    tap = forward_tap(f)
    return b3_spline(tap[0]) * b3_spline(tap[1])


@wp.func
def log2_b3(i: int) -> float:
    """log2 of the B3-spline tap weight at offset ``i`` in [-2, 2] (:func:`b3_spline`), as a literal."""
    a = wp.abs(i)
    return wp.where(a == 0, -1.415037499278844, wp.where(a == 1, -2.0, -4.0))


@wp.func
def forward_log2_kernel(f: int) -> float:
    """log2(h(dy) h(dx)) of forward tap ``f``."""
    tap = forward_tap(f)
    return log2_b3(tap[0]) + log2_b3(tap[1])


@wp.func
def forward_distance(f: int) -> float:
    """‖(dy, dx)‖ of forward tap ``f`` [taps], as a literal so that a constant ``f`` folds it."""
    tap = forward_tap(f)
    d2 = tap[0] * tap[0] + tap[1] * tap[1]
    return wp.where(d2 == 1, 1.0, wp.where(d2 == 2, 1.4142135623730951, wp.where(d2 == 4, 2.0, wp.where(
        d2 == 5, 2.23606797749979, 2.8284271247461903))))


@wp.func
def pair_weight(gs_p: wp.vec4, gd_p: wp.vec4, gs_q: wp.vec4, gd_q: wp.vec4, log2_kernel_weight: float, dist: float,
                two_over_step: float, depth_eps: float, sigma_normal: float, gated: int, squarings: int) -> float:
    """w_pq of the module docstring, symmetric in p and q, from the guides ``gs`` = (n, z) and ``gd`` =
    (σ_z ‖∇z‖ ln 2, g3x3(Var) / 2, luminance log2(e) / σ_l, R); ``dist`` = ‖p − q‖ [pixels], ``depth_eps`` = σ_z ε_z
    ln 2, ``sigma_normal`` = 2 σ_n log2(e), ``log2_kernel_weight`` = log2(h(dx) h(dy)). p must have a surface; 0
    unless q has one too (a pixel without one has the guide 0, so n_p·n_q = 0).

    The exponent is kept in base 2 (:func:`pair_scales`: the factors log2(e), the 2 of 2 atanh and the kernel weight's
    log2 are folded into the guide pass's terms and the level's constants), so that w_pq = 2^X is the exponential
    instruction alone with no multiplication before or after it. φ_z (scaled by ln 2) enters twice, in 1/φ_z and, for
    c = n_p·n_q ≥ 0.5, in ln c = 2 atanh((c − 1)/(c + 1)): both divisions come from one reciprocal, r = 1 / ((c + 1)
    φ_z). Below c = 0.5 (a normal edge, or q without a surface) the rare branch takes ``wp.log``. g3x3(Var) >= 0,
    so the sum under the square root needs no clamp. (Every branch returns: a value assigned in two branches of a
    loop's body stays live across iterations in Warp's generated code and spills.)

    ``squarings`` = k > 0 (a compile-time constant, σ_n = 2^k, :data:`NORMAL_SQUARINGS` for the default 128):
    max(0, n_p·n_q)^σ_n is k multiplications, w_pq = c^σ_n · 2^(−|z_p − z_q| / φ_z − e_l), with no logarithm, no
    series and no branch (c^128 < 2^−128 below c = 1/2, flushed to 0 on CUDA: the twin's weight there is below
    1e-38 of the centre's); ``sigma_normal`` is then not read."""
    c = gs_p[0] * gs_q[0] + gs_p[1] * gs_q[1] + gs_p[2] * gs_q[2]
    gate = wp.where(gated != 0, wp.clamp(wp.min(gd_p[3], gd_q[3]) * two_over_step - 1.0, 0.0, 1.0), 1.0)
    phi_z = wp.max(gd_p[0], gd_q[0]) * dist + depth_eps * wp.max(gs_p[3], gs_q[3])
    dz = wp.abs(gs_p[3] - gs_q[3])
    if squarings > 0:
        cn = wp.max(c, 0.0)
        for i in range(MAX_SQUARINGS):  # unrolled; the steps at or above a constant ``squarings`` fold away
            cn = wp.where(i < squarings, cn * cn, cn)
        # two FFMA into the exponent; g3x3(Var)_p / 2 + ε is p's, shared by its taps
        x = log2_kernel_weight - dz * fast_rcp(phi_z)
        x = x - wp.abs(gd_p[2] - gd_q[2]) * fast_rsqrt((gd_p[1] + VARIANCE_EPS) + gd_q[1])
        return cn * fast_exp2(x) * gate
    e_l = wp.abs(gd_p[2] - gd_q[2]) * fast_rsqrt(gd_p[1] + gd_q[1] + VARIANCE_EPS) - log2_kernel_weight
    if c < 0.5:
        if gs_q[3] <= 0.0 or c <= 0.0 or gate <= 0.0:
            return 0.0
        return fast_exp2(0.5 * sigma_normal * wp.log(c) - fast_div(dz, phi_z) - e_l) * gate
    den = c + 1.0
    r = fast_rcp(den * phi_z)
    return fast_exp2(sigma_normal * atanh_series((c - 1.0) * phi_z * r) - dz * den * r - e_l) * gate


def pair_scales(sigma_depth: float, sigma_normal: float, sigma_luminance: float) -> tuple[float, float, float]:
    """(σ_z ln 2, 2 σ_n log2(e), log2(e) / σ_l): the scales :func:`atrous_guide` and :func:`atrous_level` take, which
    put :func:`pair_weight`'s exponent in base 2."""
    return (float(sigma_depth) * LN2, 2.0 * LOG2E * float(sigma_normal), LOG2E / float(sigma_luminance))


@wp.func
def tap_weight(gs_p: wp.vec4, gd_p: wp.vec4, gs_q: wp.vec4, gd_q: wp.vec4, f: int, active: bool, s: float,
               two_over_step: float, depth_eps: float, sigma_normal: float, gated: int, squarings: int,
               select_free: int) -> float:
    """w(p, p + forward tap ``f``) from the loaded guides of p and q; 0 where p is not ``active`` (no surface, or
    a closed gate). ``f`` is a constant where it is called, so its kernel weight and distance fold. With
    ``squarings`` (no branch in :func:`pair_weight`) the weight is evaluated either way and selected, without a
    branch (an inactive p's weight may be NaN: q without a surface either, φ_z = 0; it is never used).
    ``select_free`` (ungated, ``squarings`` > 0; a compile-time constant): no select either; the level gave every
    point without a surface the guides (0, DEAD_SLOPE, 0, ...) (:func:`store_guide`), whose weight with any q is
    max(0, 0·n_q)^σ_n 2^X = 0 with X finite (φ_z >= DEAD_SLOPE ‖p − q‖ > 0): the same 0 as the select's (a zero of
    either sign, which adds nothing to the sums it enters; every sum starts at +0 or above). This needs every p
    with a surface (Var >= 0) to have z > 0, as SVGF's inputs do (:func:`.kernels_svgf.surface_depth`)."""
    if squarings > 0 and select_free != 0:
        return pair_weight(gs_p, gd_p, gs_q, gd_q, forward_log2_kernel(f), s * forward_distance(f), two_over_step,
                           depth_eps, sigma_normal, gated, squarings)
    if squarings > 0:
        return wp.where(active, pair_weight(gs_p, gd_p, gs_q, gd_q, forward_log2_kernel(f), s * forward_distance(f),
                                            two_over_step, depth_eps, sigma_normal, gated, squarings), 0.0)
    if not active:
        return 0.0
    return pair_weight(gs_p, gd_p, gs_q, gd_q, forward_log2_kernel(f), s * forward_distance(f), two_over_step, depth_eps,
                       sigma_normal, gated, squarings)


@wp.func
def fill_weights(guide_s: wp.tile[wp.vec4, GUIDE_PIXELS], guide_d: wp.tile[wp.vec4, GUIDE_PIXELS],
                 pair: wp.tile[wp.float32, FORWARD_TAPS * PAIR_PIXELS], inv_weight_sum: wp.tile[wp.float32, GUIDE_PIXELS],
                 lane: int, threads: int, s: float, depth_eps: float, sigma_normal: float, gated: int,
                 squarings: int, select_free: int):
    """Steps 2 and 3 of :func:`atrous_level` (cooperative: every thread of the block calls it). Writes ``pair``
    (shared, the forward pair weights w(u, u + f) of the guide rows 0 .. PAIR_ROWS - 1 at f * PAIR_PIXELS + u)
    and ``inv_weight_sum`` (shared, 1 / W_q of the tile and an apron of 2, at their guide index)."""
    two_over_step = 2.0 / s
    # 2. forward pair weights, once per unordered pair. An item is a run of two points u, u + 1 of a row and
    # all 24 of their forward taps, with both points' guides in registers: the q of a tap row are read once for
    # both (16 guide points read from shared memory for 24 pairs; one point and 3 taps an item read 4 for 3)
    k = lane
    while k < _RUN_N:
        i = k // _RUNS_X
        m = k - i * _RUNS_X  # item m of row i: points 2m, 2m + 1 of the guide region's row
        if wp.static(ODD_PITCH):
            # items 8r .. 8r + 7 of a row pair: 4 consecutive of its first row, then the same 4 of its second
            # (rows an odd pitch apart: the 8 lanes' first points lie in 8 different 16-byte banks)
            pair_row = k // (2 * _RUNS_X)
            r = k - pair_row * (2 * _RUNS_X)
            i = 2 * pair_row + (r // 4) % 2
            m = 4 * (r // 8) + r % 4
        u = i * _PITCH + 2 * m + 2
        gs_1 = read_guide(guide_s, u)
        gd_1 = read_guide(guide_d, u)
        gs_2 = read_guide(guide_s, u + 1)
        gd_2 = read_guide(guide_d, u + 1)
        active_1 = gs_1[3] > 0.0 and (gated == 0 or gd_1[3] * two_over_step > 1.0)
        active_2 = gs_2[3] > 0.0 and (gated == 0 or gd_2[3] * two_over_step > 1.0)
        # row 0: taps (0, 1) and (0, 2); u + 1 is p_1's first q
        write_pair(pair, u, tap_weight(gs_1, gd_1, gs_2, gd_2, 0, active_1, s, two_over_step, depth_eps, sigma_normal, gated, squarings, select_free))
        for j in range(2):  # q = u + 2 + j: p_1's tap (0, 2) (j = 0), p_2's tap (0, 1 + j)
            gs_q = read_guide(guide_s, u + 2 + j)
            gd_q = read_guide(guide_d, u + 2 + j)
            if j == 0:
                write_pair(pair, _PAIR_PIXELS + u, tap_weight(gs_1, gd_1, gs_q, gd_q, 1, active_1, s, two_over_step, depth_eps, sigma_normal, gated, squarings, select_free))
            write_pair(pair, j * _PAIR_PIXELS + u + 1, tap_weight(gs_2, gd_2, gs_q, gd_q, j, active_2, s, two_over_step, depth_eps, sigma_normal, gated, squarings, select_free))
        # rows 1 and 2: q = u + dy PITCH + dx, dx = -2 .. 3: p_1's tap (dy, dx) for dx <= 2 (f = 5 dy - 1 + dx),
        # p_2's tap (dy, dx - 1) for dx >= -1
        for t in range(12):
            dy = 1 + t // 6
            dx = t % 6 - 2
            v = u + dy * _PITCH + dx
            gs_q = read_guide(guide_s, v)
            gd_q = read_guide(guide_d, v)
            if dx <= 2:
                write_pair(pair, (5 * dy - 1 + dx) * _PAIR_PIXELS + u, tap_weight(gs_1, gd_1, gs_q, gd_q, 5 * dy - 1 + dx, active_1, s, two_over_step, depth_eps, sigma_normal, gated, squarings, select_free))
            if dx >= -1:
                write_pair(pair, (5 * dy - 2 + dx) * _PAIR_PIXELS + u + 1, tap_weight(gs_2, gd_2, gs_q, gd_q, 5 * dy - 2 + dx, active_2, s, two_over_step, depth_eps, sigma_normal, gated, squarings, select_free))
        k += threads
    block_sync()

    # 3. 1 / W_q, W_q = Σ_r w_qr of the tile and an apron of 2 (centre (3/8)² included)
    k = lane
    while k < _SUM_N:
        u = (2 + k // _SUM_X) * _PITCH + 4 + k % _SUM_X
        sum_w = CENTRE_WEIGHT
        for f in range(FORWARD_TAPS):
            sum_w += read_pair(pair, f * _PAIR_PIXELS + u) + read_pair(pair, f * _PAIR_PIXELS + u - forward_offset(f))
        write_guide_scalar(inv_weight_sum, u, fast_rcp(sum_w))
        k += threads
    block_sync()


@wp.func_native("""
#if defined(__CUDA_ARCH__)
const float2 v = __ldg(reinterpret_cast<const float2*>(a.data) + p);
return wp::vec2(v.x, v.y);
#else
return reinterpret_cast<const wp::vec2*>(a.data)[p];
#endif
""")
def load_half(a: wp.array(dtype=wp.vec4), p: int) -> wp.vec2:
    """Entry ``p`` of a vec4 buffer read as a vec2 array (its first half holds 2 x its length of them): one 8-byte
    load on CUDA."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
reinterpret_cast<float2*>(a.data)[p] = make_float2(v[0], v[1]);
#else
reinterpret_cast<wp::vec2*>(a.data)[p] = v;
#endif
""")
def store_half(a: wp.array(dtype=wp.vec4), p: int, v: wp.vec2):
    """Entry ``p`` of a vec4 buffer written as a vec2 array (:func:`load_half`): one 8-byte store on CUDA."""
    ...


@wp.func
def load_aux(aux: wp.array(dtype=wp.vec4), p: int, cv: wp.vec4, luminance_scale: float, gated: int) -> wp.vec4:
    """The guide-pass terms of point ``p`` as :func:`pair_weight` takes them (σ_z ‖∇z‖ ln 2, g3x3(Var) / 2,
    luminance log2(e) / σ_l, R) from ``aux`` as :func:`atrous_guide` wrote it: gated, the vec4; ungated, the vec2 of
    the first two (8 bytes a point), the luminance from the point's colour ``cv`` (the guide pass's expression, the
    same value) and R = 0 (never read)."""
    if gated != 0:
        return load_vec4(aux, p)
    a = load_half(aux, p)
    return wp.vec4(a[0], a[1], luminance(wp.vec3(cv[0], cv[1], cv[2])) * luminance_scale, 0.0)


@wp.func_native("""
#if defined(__CUDA_ARCH__)
return __ldg(reinterpret_cast<const float*>(a.data) + 4 * p + 3);
#else
return reinterpret_cast<const float*>(a.data)[4 * p + 3];
#endif
""")
def load_variance(a: wp.array(dtype=wp.vec4), p: int) -> float:
    """The fourth component (Var) of entry ``p`` of a packed (colour, Var) buffer: one 4-byte load on CUDA."""
    ...


@wp.func
def read_signal(packed: int, color_variance: wp.array(dtype=wp.vec4), color_in: wp.array(dtype=wp.vec3),
                variance_in: wp.array(dtype=wp.float32), depth: wp.array(dtype=wp.float32), p: int) -> wp.vec4:
    """(colour, Var) of pixel ``p`` from the packed input or from the unpacked one; Var = NO_SURFACE without
    a surface (depth 0), else clamped to >= 0 (as the packed input holds it). The unpacked loads do not wait
    for the depth test (loads behind a branch on an earlier load's value are issued one after the other).
    ``packed`` = 3: only Var, from ``variance_in`` (the previous level's own dense copy of its output's Var, NO_SURFACE
    without a surface; :func:`atrous_level`'s ``variance_next``), the colour 0: one 4-byte load."""
    if packed == 3:
        return wp.vec4(0.0, 0.0, 0.0, variance_in[p])
    if packed != 0:
        return load_vec4(color_variance, p)
    z = depth[p]
    c = color_in[p]
    v = variance_in[p]
    return wp.where(z > 0.0, wp.vec4(c[0], c[1], c[2], wp.max(v, 0.0)), wp.vec4(0.0, 0.0, 0.0, NO_SURFACE))


@wp.func
def gaussian_sums(packed: int, color_variance: wp.array(dtype=wp.vec4), color_in: wp.array(dtype=wp.vec3),
                  variance_in: wp.array(dtype=wp.float32), depth: wp.array(dtype=wp.float32), x: int, y: int,
                  width: int, height: int) -> wp.vec3:
    """(Σ k, Σ k Var, Σ k l) of the 3x3 Gaussian (1/4, 1/8, 1/16) at pixel (x, y) over the pixels with a surface.
    Neighbours are clamped into the image and read unconditionally, masked after: the nine loads are in flight
    together (a load behind a branch on another's value waits for it). ``packed`` = 2: a packed input whose
    luminance is not needed (Σ k l = 0): only each neighbour's Var is read, a 4-byte load instead of 16; 3: the
    same from the dense Var copy ``variance_in`` (4 bytes a pixel, a warp's row of them one 128-byte line)."""
    sums = wp.vec3(0.0)
    for dy in range(-1, 2):
        for dx in range(-1, 2):
            qx = wp.clamp(x + dx, 0, width - 1)
            qy = wp.clamp(y + dy, 0, height - 1)
            cv_q = wp.vec4(0.0)
            if packed == 2:  # a constant where it is called: no branch
                cv_q = wp.vec4(0.0, 0.0, 0.0, load_variance(color_variance, qy * width + qx))
            elif packed == 3:
                cv_q = wp.vec4(0.0, 0.0, 0.0, variance_in[qy * width + qx])
            else:
                cv_q = read_signal(packed, color_variance, color_in, variance_in, depth, qy * width + qx)
            inside = qx == x + dx and qy == y + dy and cv_q[3] >= 0.0
            kq = wp.where(inside, wp.where(dx == 0, 0.5, 0.25) * wp.where(dy == 0, 0.5, 0.25), 0.0)
            sums += kq * wp.vec3(1.0, wp.max(cv_q[3], 0.0), luminance(wp.vec3(cv_q[0], cv_q[1], cv_q[2])))
    return sums


@wp.func
def blur_variance(packed: int, color_variance: wp.array(dtype=wp.vec4), color_in: wp.array(dtype=wp.vec3),
                  variance_in: wp.array(dtype=wp.float32), depth: wp.array(dtype=wp.float32), x: int, y: int,
                  width: int, height: int, gated: int, noise_target: float) -> wp.vec2:
    """(g3x3(Var), R) of pixel (x, y), which has a surface: the 3x3 Gaussian (1/4, 1/8, 1/16) renormalised over
    pixels with a surface (paper eq. 5) and, ``gated``, the footprint R of the same Gaussian's variance and mean
    luminance (:func:`footprint_radius`, relative ``noise_target``); R = ``UNGATED_RADIUS`` otherwise."""
    sums = wp.vec3(0.0)
    if packed == 3:  # ungated: the dense Var copy alone
        sums = gaussian_sums(3, color_variance, color_in, variance_in, depth, x, y, width, height)
    elif packed != 0 and gated == 0:  # one branch outside the unrolled loop, not one per neighbour
        sums = gaussian_sums(2, color_variance, color_in, variance_in, depth, x, y, width, height)  # Var alone
    elif packed != 0:
        sums = gaussian_sums(1, color_variance, color_in, variance_in, depth, x, y, width, height)
    else:
        sums = gaussian_sums(0, color_variance, color_in, variance_in, depth, x, y, width, height)
    var_blur = sums[1] / sums[0]
    if gated != 0:
        return wp.vec2(var_blur, footprint_radius(var_blur, sums[2] / sums[0], noise_target))
    return wp.vec2(var_blur, UNGATED_RADIUS)


def lattice_size(width: int, height: int, step: int) -> int:
    """Entries of a buffer in the sub-lattice-major order of tap spacing ``step``."""
    return step * step * ((height + step - 1) // step) * ((width + step - 1) // step)


@wp.kernel
def atrous_guide(
    packed: int,
    color_variance: wp.array(dtype=wp.vec4),
    color_in: wp.array(dtype=wp.vec3),
    variance_in: wp.array(dtype=wp.float32),
    depth: wp.array(dtype=wp.float32),
    normal: wp.array(dtype=wp.vec3),
    slope: wp.array(dtype=wp.float32),
    width: int,
    height: int,
    gated: int,
    noise_target: float,
    depth_scale: float,
    luminance_scale: float,
    aux: wp.array(dtype=wp.vec4),
    write_packed: int,
    color_variance_out: wp.array(dtype=wp.vec4),
    guide_out: wp.array(dtype=wp.vec4),
    lattice: int,
    guide_in: wp.array(dtype=wp.vec4),
    color_variance_lattice: wp.array(dtype=wp.vec4),
    guide_lattice: wp.array(dtype=wp.vec4),
    copy_guide: int,
    guide_parity: wp.array(dtype=wp.int32),
    guide_row: int,
):
    """The per-pixel guides of a level that its input's 3x3 neighbourhood gives, dense over
    ``dim=height * width``, so that :func:`atrous_level` reads three aligned vec4 a guide instead of nine scattered
    ones.

    Reads the level's input as :func:`atrous_level` does (``packed`` != 0: ``color_variance``; else
    ``color_in``, ``variance_in``, ``depth``, ``normal``) and ``slope`` (H*W float32 [m/pixel]). Writes ``aux``
    (H*W vec4: σ_z ‖∇z‖ ln 2, g3x3(Var) / 2, luminance log2(e) / σ_l, R, the scaled terms :func:`pair_weight`
    takes, with ``depth_scale`` = σ_z ln 2 and ``luminance_scale`` = log2(e) / σ_l, :func:`pair_scales`; 0 without a
    surface; ``gated`` == 0: only the first two, as a vec2 array in the buffer's first half, :func:`load_aux`) and,
    with ``write_packed`` (unpacked input only), the packed input ``color_variance_out`` (colour, Var; Var =
    NO_SURFACE without a surface) and ``guide_out`` (n, z) that the level then reads instead. ``gated`` != 0: R from
    g3x3(Var) and the same Gaussian's mean luminance (:func:`footprint_radius`, relative ``noise_target``).

    ``lattice`` = the level's step (>= 2; 0: off): ``aux`` is written in that step's sub-lattice-major order
    (:func:`lattice_index`, :func:`lattice_size` entries) and so are copies of the packed input,
    ``color_variance_lattice``, and of the packed guide ``guide_in`` (n, z), ``guide_lattice``, which the level
    then reads instead (packed input only); the guide only with ``copy_guide`` (else ``guide_lattice`` holds it in
    that order already: SVGF's :func:`.kernels_svgf.reproject` writes it so), from ``guide_in``'s row
    ``1 - guide_parity[0]`` of ``guide_row`` entries (0: one row).

    ``packed`` = 3 (ungated only): the level's input is packed but this pass reads only its Var, from
    ``variance_in`` (H*W float32, NO_SURFACE without a surface), the dense copy the previous level wrote
    (:func:`atrous_level`'s ``variance_next``): 4 bytes a pixel and 4 a neighbour instead of 16 and a 4-byte load at
    +12 of each neighbour's vec4; with ``lattice`` the input is in that order already (the previous level's
    ``lattice_out``) and is not copied.
    """
    p = wp.tid()
    y = p // width
    x = p - y * width
    cv = read_signal(packed, color_variance, color_in, variance_in, depth, p)
    o = p
    if write_packed != 0:
        store_vec4(color_variance_out, p, cv)
        if cv[3] >= 0.0:
            n = normal[p]
            store_vec4(guide_out, p, wp.vec4(n[0], n[1], n[2], depth[p]))
        else:
            store_vec4(guide_out, p, wp.vec4(0.0))
    elif lattice != 0:
        o = lattice_index(y, x, width, height, lattice)
        if packed != 3:  # else the previous level wrote its output in this order itself
            store_vec4(color_variance_lattice, o, cv)
        if copy_guide != 0:
            store_vec4(guide_lattice, o, load_vec4(guide_in, (1 - guide_parity[0]) * guide_row + p))
    if cv[3] < 0.0:
        if gated != 0:
            store_vec4(aux, o, wp.vec4(0.0))
        else:
            store_half(aux, o, wp.vec2(0.0))
        return
    b = blur_variance(packed, color_variance, color_in, variance_in, depth, x, y, width, height, gated, noise_target)
    if gated != 0:
        store_vec4(aux, o, wp.vec4(depth_scale * slope[p], 0.5 * b[0],
                                   luminance(wp.vec3(cv[0], cv[1], cv[2])) * luminance_scale, b[1]))
    else:  # the level takes the luminance from the colour it reads anyway, and no R
        store_half(aux, o, wp.vec2(depth_scale * slope[p], 0.5 * b[0]))


#: SVGF's ungated guide passes from the previous level's dense Var (``packed`` = 3) run :func:`atrous_guide_run` with
#: this many pixels of a row a thread (4 or 8; the same values bit for bit), 0: :func:`atrous_guide`, a pixel a
#: thread. Read at launch (the lead's A/B: ``import cisp_warp.denoise.kernels_atrous as m; m.GUIDE_RUN = 0``)
GUIDE_RUN = 4
_vec6 = wp.types.vector(length=6, dtype=wp.float32)
_vec10 = wp.types.vector(length=10, dtype=wp.float32)


@wp.func_native("""
#if defined(__CUDA_ARCH__)
const float4 v = __ldg(reinterpret_cast<const float4*>(a.data + p));
return wp::vec4(v.x, v.y, v.z, v.w);
#else
return wp::vec4(a.data[p], a.data[p + 1], a.data[p + 2], a.data[p + 3]);
#endif
""")
def load_float4(a: wp.array(dtype=wp.float32), p: int) -> wp.vec4:
    """Entries ``p`` ... ``p`` + 3 of a float32 array, ``p`` a multiple of 4 and the array 16-byte aligned: one
    16-byte load on CUDA."""
    ...


@wp.func
def load_four(a: wp.array(dtype=wp.float32), r: int, x: int, width: int, aligned: int) -> wp.vec4:
    """Entries r + x ... r + x + 3 of a row of ``a`` that starts at ``r``, each column clamped to ``width`` − 1;
    ``aligned`` (:func:`runs_aligned`, x a multiple of 4 < width): one 16-byte load."""
    if aligned != 0:
        return load_float4(a, r + x)
    return wp.vec4(a[r + wp.min(x, width - 1)], a[r + wp.min(x + 1, width - 1)], a[r + wp.min(x + 2, width - 1)],
                   a[r + wp.min(x + 3, width - 1)])


@wp.func
def variance_row4(variance_in: wp.array(dtype=wp.float32), qy: int, x0: int, width: int, aligned: int) -> _vec6:
    """The Var of row ``qy`` at the columns x0 − 1 ... x0 + 4, each clamped into the image (as :func:`gaussian_sums`
    clamps them), loads issued together (``aligned``: the middle four in one 16-byte load)."""
    r = qy * width
    left = variance_in[r + wp.max(x0 - 1, 0)]
    right = variance_in[r + wp.min(x0 + 4, width - 1)]
    m = load_four(variance_in, r, x0, width, aligned)
    return _vec6(left, m[0], m[1], m[2], m[3], right)


@wp.func
def variance_row8(variance_in: wp.array(dtype=wp.float32), qy: int, x0: int, width: int, aligned: int) -> _vec10:
    """:func:`variance_row4` for the columns x0 − 1 ... x0 + 8."""
    r = qy * width
    left = variance_in[r + wp.max(x0 - 1, 0)]
    right = variance_in[r + wp.min(x0 + 8, width - 1)]
    m = load_four(variance_in, r, x0, width, aligned)
    n = load_four(variance_in, r, x0 + 4, width, wp.where(x0 + 4 < width, aligned, 0))
    return _vec10(left, m[0], m[1], m[2], m[3], n[0], n[1], n[2], n[3], right)


def runs_aligned(width: int, *arrays) -> int:
    """1 where :func:`atrous_guide_run` may read four float32 of a row in one 16-byte load: ``width`` a multiple of 4
    and every array 16-byte aligned."""
    return int(width % 4 == 0 and all(a.ptr % 16 == 0 for a in arrays))


def make_guide_run(run: int):
    """:func:`atrous_guide_run` for ``run`` (4 or 8) pixels a thread."""
    RUN = int(run)
    assert RUN in (4, 8)

    # sm_90 (tools/regcount.py): 4 pixels a thread 48 registers, 2 blocks of the module's 512 threads an SM, no stack
    # (bounded to 3 blocks: 40 registers and a 32-byte stack frame); 8 pixels bounded to 2 blocks: 64 registers, an
    # 8-byte frame (unbounded: 72 registers, 1 block)
    @wp.kernel(name=f"atrous_guide_run{RUN}", launch_bounds=(BLOCK_THREADS, 2) if RUN == 8 else None)
    def atrous_guide_run(
        variance_in: wp.array(dtype=wp.float32),
        slope: wp.array(dtype=wp.float32),
        width: int,
        height: int,
        depth_scale: float,
        aux: wp.array(dtype=wp.vec4),
        lattice: int,
        guide_in: wp.array(dtype=wp.vec4),
        guide_lattice: wp.array(dtype=wp.vec4),
        copy_guide: int,
        guide_parity: wp.array(dtype=wp.int32),
        guide_row: int,
        aligned: int,
    ):
        """:func:`atrous_guide` for SVGF's chained levels (ungated, ``packed`` = 3: the input's Var alone from the
        previous level's dense copy ``variance_in``), ``RUN`` consecutive pixels of a row a thread, ``dim=(height,
        ceil(width / RUN))``: the run's three rows of Var (RUN + 2 columns each) are read once for its pixels' 3x3
        neighbourhoods (18 loads for 4 pixels instead of 4 + 32), the centre row and the slopes first, the rows
        above and below only where the run has a surface. Writes what :func:`atrous_guide` writes there, bit for
        bit: ``aux`` (its first half as a vec2 array, :func:`load_aux`: σ_z ‖∇z‖ ln 2, g3x3(Var) / 2; 0 without a
        surface; ``lattice`` != 0: in that step's sub-lattice-major order) and, with ``lattice`` and
        ``copy_guide``, ``guide_lattice`` from row ``1 - guide_parity[0]`` of ``guide_in`` (rows of ``guide_row``
        entries). The sums are :func:`gaussian_sums`' in its order. ``aligned`` (:func:`runs_aligned`): the width
        is a multiple of 4 and ``variance_in`` and ``slope`` are 16-byte aligned, so that four Var or slopes of a
        row are one 16-byte load."""
        y, j = wp.tid()
        x0 = j * RUN
        row = y * width
        if wp.static(RUN == 4):
            centre = variance_row4(variance_in, y, x0, width, aligned)
        else:
            centre = variance_row8(variance_in, y, x0, width, aligned)
        sz = load_four(slope, row, x0, width, aligned)
        sz8 = sz
        if wp.static(RUN == 8):
            sz8 = load_four(slope, row, x0 + 4, width, wp.where(x0 + 4 < width, aligned, 0))
        any_surface = False
        for k in range(RUN):
            any_surface = any_surface or (x0 + k < width and centre[k + 1] >= 0.0)
        above = centre
        below = centre
        if any_surface:
            if wp.static(RUN == 4):
                above = variance_row4(variance_in, wp.max(y - 1, 0), x0, width, aligned)
                below = variance_row4(variance_in, wp.min(y + 1, height - 1), x0, width, aligned)
            else:
                above = variance_row8(variance_in, wp.max(y - 1, 0), x0, width, aligned)
                below = variance_row8(variance_in, wp.min(y + 1, height - 1), x0, width, aligned)
        g_row = (1 - guide_parity[0]) * guide_row
        for k in range(RUN):
            x = x0 + k
            if x < width:
                p = row + x
                o = p
                if lattice != 0:
                    o = lattice_index(y, x, width, height, lattice)
                    if copy_guide != 0:
                        store_vec4(guide_lattice, o, load_vec4(guide_in, g_row + p))
                if centre[k + 1] < 0.0:
                    store_half(aux, o, wp.vec2(0.0))
                else:
                    s0 = float(0.0)
                    s1 = float(0.0)
                    for dy in range(-1, 2):
                        for dx in range(-1, 2):
                            v = wp.where(dy == 0, centre[k + 1 + dx],
                                         wp.where(dy < 0, above[k + 1 + dx], below[k + 1 + dx]))
                            inside = (y + dy >= 0 and y + dy < height and x + dx >= 0 and x + dx < width
                                      and v >= 0.0)
                            kq = wp.where(inside, wp.where(dx == 0, 0.5, 0.25) * wp.where(dy == 0, 0.5, 0.25), 0.0)
                            s0 += kq * 1.0
                            s1 += kq * wp.max(v, 0.0)
                    sz_k = wp.where(k < 4, sz[k % 4], sz8[k % 4])
                    store_half(aux, o, wp.vec2(depth_scale * sz_k, 0.5 * (s1 / s0)))

    return atrous_guide_run


#: SVGF's chained guide passes by pixels a thread (:data:`GUIDE_RUN`)
ATROUS_GUIDE_RUN = {r: make_guide_run(r) for r in (4, 8)}


@wp.func
def store_guide(guide_s: wp.tile[wp.vec4, GUIDE_PIXELS], guide_d: wp.tile[wp.vec4, GUIDE_PIXELS],
                signal: wp.tile[wp.vec4, GUIDE_PIXELS], k: int, inside: bool, cv: wp.vec4, gs: wp.vec4, ax: wp.vec4,
                s: float, gated: int, select_free: int) -> int:
    """Step 1 of :func:`atrous_level` for guide point ``k`` (``inside`` the image) from its loaded input ``cv``,
    guide ``gs`` and guide-pass output ``ax``: writes the shared guides (0 without a surface); returns the bits
    ``TO_FILTER`` if the point is a pixel of the output tile that some gate lets be filtered (``gated`` == 0: any
    with a surface) and ``HAS_SIGNAL`` if it is a point of the tile or its apron of 2 (the filter's taps) with a
    surface and a signal: a colour channel != 0 or Var > 0 (NaN counts as signal). ``select_free``: a point without
    a surface gets ``guide_d`` = (DEAD_SLOPE, 0, 0, 0) (:func:`tap_weight`)."""
    surface = inside and cv[3] >= 0.0
    if not surface:
        write_guide(guide_s, k, wp.vec4(0.0))
        write_guide(guide_d, k, wp.vec4(wp.where(select_free != 0, DEAD_SLOPE, 0.0), 0.0, 0.0, 0.0))
        write_guide(signal, k, wp.vec4(0.0))
        return 0
    write_guide(guide_s, k, gs)
    write_guide(guide_d, k, ax)
    write_guide(signal, k, cv)
    i = k // _PITCH
    j = k - i * _PITCH - 2
    bits = int(0)
    if i >= 4 and i < 4 + _TILE_Y and j >= 4 and j < 4 + _TILE_X and (gated == 0 or 2.0 * ax[3] > s):
        bits = TO_FILTER
    if (i >= 2 and i < 6 + _TILE_Y and j >= 2 and j < 6 + _TILE_X
            and (cv[0] != 0.0 or cv[1] != 0.0 or cv[2] != 0.0 or not (cv[3] <= 0.0))):
        bits = bits | HAS_SIGNAL
    return bits


@wp.func
def blur_own_variance(guide_d: wp.tile[wp.vec4, GUIDE_PIXELS], ring: wp.tile[wp.float32, FORWARD_TAPS * PAIR_PIXELS],
                      lane: int, threads: int):
    """Step 1b of the step-1 level that blurs its own variance (cooperative): g3x3(Var) / 2 of every guide point with
    a surface into ``guide_d``'s second term, from ``ring`` (shared, the Var of the guide region and an apron of 1,
    ``RING_Y`` x ``RING_X`` row-major; ``NO_SURFACE`` outside the image). At step 1 a point's 3x3 neighbourhood is
    its neighbourhood in the tile: the same sums in the same order as :func:`gaussian_sums` (a neighbour outside the
    image or without a surface weighs 0), so the same value as :func:`atrous_guide`'s."""
    k = lane
    while k < _GUIDE_REAL:
        i = k // _GUIDE_X
        j = k - i * _GUIDE_X
        c = (i + 1) * _RING_X + j + 1
        if read_pair(ring, c) >= 0.0:
            sums = wp.vec3(0.0)
            for dy in range(-1, 2):
                for dx in range(-1, 2):
                    v = read_pair(ring, c + dy * _RING_X + dx)
                    kq = wp.where(v >= 0.0, wp.where(dx == 0, 0.5, 0.25) * wp.where(dy == 0, 0.5, 0.25), 0.0)
                    sums += kq * wp.vec3(1.0, wp.max(v, 0.0), 0.0)
            u = i * _PITCH + j + 2
            gd = read_guide(guide_d, u)
            write_guide(guide_d, u, wp.vec4(gd[0], 0.5 * (sums[1] / sums[0]), gd[2], gd[3]))
        k += threads


@wp.func_native("""
#if defined(__CUDA_ARCH__)
return __ldg(a.data + p);
#else
return a.data[p];
#endif
""")
def load_float(a: wp.array(dtype=wp.float32), p: int) -> float:
    """Entry ``p`` of a float32 array through the read-only path (``__ldg`` on CUDA)."""
    ...


@wp.func
def load_region2(region: wp.tile[wp.float32, FORWARD_TAPS * PAIR_PIXELS], variance_in: wp.array(dtype=wp.float32),
                 lane: int, threads: int, oy: int, ox: int, width: int, height: int):
    """The step-2 level's region (cooperative, no barrier): the Var of pixels (oy + r, ox + c), r < REGION_Y, c <
    REGION_X, from ``variance_in`` (H*W float32, NO_SURFACE without a surface) into ``region`` row-major
    (NO_SURFACE outside the image); a run of REGION_RUN pixels of a row a thread, one 64-bit address and its
    loads at constant offsets from it, issued before their stores."""
    k = lane
    while k < _REGION_RUNS:  # a run of REGION_RUN consecutive pixels of a row (on CUDA one a lane, 441 of 512)
        r = k // _REGION_RUNS_X
        x0 = ox + (k - r * _REGION_RUNS_X) * REGION_RUN
        y = oy + r
        row_in = y >= 0 and y < height
        p = wp.where(row_in, y * width, 0) + x0
        vals = _vec_round()
        for m in range(REGION_RUN):  # the loads predicated, all in flight together
            v = NO_SURFACE
            if row_in and x0 + m >= 0 and x0 + m < width:
                v = load_float(variance_in, p + m)
            vals[m] = v
        o = r * _REGION_X + x0 - ox
        for m in range(REGION_RUN):
            write_pair(region, o + m, vals[m])
        k += threads


@wp.func
def blur_region2(guide_d: wp.tile[wp.vec4, GUIDE_PIXELS], region: wp.tile[wp.float32, FORWARD_TAPS * PAIR_PIXELS],
                 lane: int, threads: int):
    """:func:`blur_own_variance` for the step-2 level (cooperative): guide point (i, j) is pixel (2i + 1, 2j + 1) of
    ``region`` (:func:`load_region2`), its 3x3 neighbourhood the pixels around it there (other sub-lattices); the
    same sums in the same order as :func:`gaussian_sums` and :func:`atrous_guide_run`, the same value as the guide
    pass's bit for bit."""
    k = lane
    while k < _GUIDE_REAL:
        i = k // _GUIDE_X
        j = k - i * _GUIDE_X
        c = (2 * i + 1) * _REGION_X + 2 * j + 1
        if read_pair(region, c) >= 0.0:
            sums = wp.vec3(0.0)
            for dy in range(-1, 2):
                for dx in range(-1, 2):
                    v = read_pair(region, c + dy * _REGION_X + dx)
                    kq = wp.where(v >= 0.0, wp.where(dx == 0, 0.5, 0.25) * wp.where(dy == 0, 0.5, 0.25), 0.0)
                    sums += kq * wp.vec3(1.0, wp.max(v, 0.0), 0.0)
            u = i * _PITCH + j + 2
            gd = read_guide(guide_d, u)
            write_guide(guide_d, u, wp.vec4(gd[0], 0.5 * (sums[1] / sums[0]), gd[2], gd[3]))
        k += threads


def make_atrous_level(gated: int, squarings: int = 0, self_guide: int = 0, select_free: int = 0):
    """:func:`atrous_level` compiled for one value of ``gated`` and of ``squarings`` (closure constants, folded by
    the compiler): the ungated level (SVGF) has no gate arithmetic in its pair weights and no R test; the gated one
    (the caustics denoiser) is the same code with every gate evaluated. Same arithmetic either way (an open gate
    multiplies by 1). ``squarings`` = k > 0: the form for σ_n = 2^k, whose normal term is k multiplications
    (:func:`pair_weight`); 0: any σ_n, through a logarithm. ``self_guide`` (ungated, step 1, a packed input not
    in sub-lattice-major order): the level needs no guide pass; it reads σ_z ‖∇z‖ from ``slope`` and blurs its own
    variance (:func:`blur_own_variance`) from an apron of 5 instead of 4 (the Var of its outer ring, ``RING_N``
    loads a block more), one barrier more. ``select_free`` (ungated, ``squarings`` > 0; section 85): the pair
    weights without the select on p's surface (:func:`tap_weight`; a point without a surface gets the dead guide of
    :func:`store_guide`), the same values. ``self_guide`` = 2 (ungated, step 2, a packed input not in sub-lattice-major
    order; section 85): as 1, the blur's Var from the previous level's dense copy ``variance_in`` over the pixels
    of the guide region's 3x3 neighbourhoods (:func:`load_region2`, :func:`blur_region2`), read only by blocks that
    run, after the flags' barriers (one load round and two barriers more there)."""
    GATED = int(gated)
    SQUARINGS = int(squarings)
    SELF_GUIDE = int(self_guide)
    SELECT_FREE_ = int(select_free)
    assert not (SELF_GUIDE and GATED)
    assert not (SELECT_FREE_ and (GATED or not SQUARINGS))
    assert SELF_GUIDE in (0, 1, 2)
    name = (("atrous_level_gated" if GATED else "atrous_level") + (f"_pow{SQUARINGS}" if SQUARINGS else "")
            + {0: "", 1: "_self", 2: "_guide2"}[SELF_GUIDE] + ("_free" if SELECT_FREE_ else ""))

    @wp.kernel(name=name,
               launch_bounds=(BLOCK_THREADS, 1024 // BLOCK_THREADS))
    def atrous_level(
        color_variance: wp.array(dtype=wp.vec4),
        guide: wp.array(dtype=wp.vec4),
        aux: wp.array(dtype=wp.vec4),
        width: int,
        height: int,
        step: int,
        tiles_x: int,
        depth_scale: float,
        normal_scale: float,
        luminance_scale: float,
        conserve_energy: int,
        write_packed: int,
        color_variance_out: wp.array(dtype=wp.vec4),
        write_public: int,
        color_out: wp.array(dtype=wp.vec3),
        variance_out: wp.array(dtype=wp.float32),
        write_history: int,
        parity: wp.array(dtype=wp.int32),
        hist_color: wp.array2d(dtype=wp.vec3),
        lattice: int,
        guide_parity: wp.array(dtype=wp.int32),
        guide_row: int,
        slope: wp.array(dtype=wp.float32),
        lattice_out: int,
        write_variance: int,
        variance_next: wp.array(dtype=wp.float32),
        variance_in: wp.array(dtype=wp.float32),
    ):
        """One à-trous level (module docstring), ``wp.launch_tiled`` over ``tiles_y * tiles_x * step²`` blocks of
        ``BLOCK_THREADS``; block ``((ty * tiles_x + tx) * step + a) * step + b`` filters the sub-lattice points
        (TILE_Y ty + i, TILE_X tx + j), i < TILE_Y, j < TILE_X, i.e. pixels (a + step (TILE_Y ty + i),
        b + step (TILE_X tx + j)).

        Reads the packed level input ``color_variance`` (H*W vec4: colour [W/m²], Var; Var < 0 = no surface) and
        ``guide`` (H*W vec4: n, z [m]), and ``aux`` (H*W vec4 of :func:`atrous_guide` for this input, with the same
        scales: σ_z ‖∇z‖ ln 2, g3x3(Var) / 2, luminance log2(e) / σ_l, R; ``depth_scale``, ``normal_scale`` and
        ``luminance_scale`` from :func:`pair_scales`). Gated (:func:`make_atrous_level`):
        the gates act (R from ``aux``), else every gate is 1 and R is not read. Writes, each when its
        flag is set: ``color_variance_out`` (packed, the next level's input), ``color_out`` (H*W vec3 [W/m²]) and
        ``variance_out`` (H*W float32; both 0 without a surface), and row ``1 - parity[0]`` of ``hist_color``
        (2 x H*W vec3, the colour history). The outputs must not alias the inputs. ``lattice`` != 0: the three
        inputs are in the step's sub-lattice-major order (:func:`atrous_guide`'s ``lattice``), the outputs not.
        ``guide_row`` != 0: ``guide`` holds rows of that many entries and the level reads row ``1 -
        guide_parity[0]`` (SVGF's guide history, whose row this frame's :func:`.kernels_svgf.reproject` wrote).
        ``slope`` (H*W float32 [m/pixel], ‖∇z‖): read only by the level compiled with ``self_guide`` (step 1,
        ``lattice`` 0), which does not read ``aux`` but makes its terms itself.
        ``lattice_out`` != 0 (a power of two): ``color_variance_out`` is written in that step's sub-lattice-major order
        (the next level's, whose guide pass then copies nothing); ``write_variance``: ``variance_next`` (H*W float32)
        gets the packed output's Var densely (NO_SURFACE without a surface), all the next guide pass reads of it.
        ``variance_in`` (H*W float32): the input's Var densely, read only by the level compiled with ``self_guide`` =
        2 (it must not alias ``variance_next``).
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
        sub_w = (width + step - 1) // step
        lattice_row = sub * ((height + step - 1) // step)  # sub-lattice-major: point (sy, sx) at (lattice_row + sy) sub_w + sx
        guide_offset = (1 - guide_parity[0]) * guide_row  # the guide's row (SVGF: its history's, this frame's)

        # 1. guides of the tile and an apron of 4, read once
        guide_s = wp.tile_empty(shape=_GUIDE_N, dtype=wp.vec4, storage="shared")  # (n, z)
        guide_d = wp.tile_empty(shape=_GUIDE_N, dtype=wp.vec4, storage="shared")  # (σ_z ‖∇z‖, g3x3 Var / 2, l / σ_l, R)
        signal = wp.tile_empty(shape=_GUIDE_N, dtype=wp.vec4, storage="shared")  # (colour, Var)
        # the forward pair weights of 2; self_guide: first the Var of the guide region and its apron of 1 (RING_Y x RING_X)
        pair = wp.tile_empty(shape=_PAIR_N, dtype=wp.float32, storage="shared")
        # TO_FILTER: this thread read a pixel of the output tile with a surface and some gate open; HAS_SIGNAL: a
        # point of the tile or its apron of 2 with a surface and a signal (a colour or a variance != 0)
        found = int(0)
        # the GUIDE_Y x GUIDE_X points of the guide region, two a thread in one round (960 <= 2 x 512: one memory
        # latency), their six loads issued before any is used; the empty columns are written without loads
        for r0 in range(lane, _GUIDE_HALF, threads):
            r1 = r0 + _GUIDE_HALF
            i0 = r0 // _GUIDE_X
            j0 = r0 - i0 * _GUIDE_X
            i1 = r1 // _GUIDE_X
            j1 = r1 - i1 * _GUIDE_X
            y0 = row0 + step * (sy0 + i0)
            x0 = col0 + step * (sx0 + j0)
            y1 = row0 + step * (sy0 + i1)
            x1 = col0 + step * (sx0 + j1)
            in0 = y0 >= 0 and y0 < height and x0 >= 0 and x0 < width
            in1 = r1 < _GUIDE_REAL and y1 >= 0 and y1 < height and x1 >= 0 and x1 < width
            p0 = wp.where(in0, wp.where(lattice != 0, (lattice_row + sy0 + i0) * sub_w + sx0 + j0, y0 * width + x0), 0)
            p1 = wp.where(in1, wp.where(lattice != 0, (lattice_row + sy0 + i1) * sub_w + sx0 + j1, y1 * width + x1), 0)
            cv0 = load_vec4(color_variance, p0)
            cv1 = load_vec4(color_variance, p1)
            gs0 = load_vec4(guide, guide_offset + p0)
            gs1 = load_vec4(guide, guide_offset + p1)
            if wp.static(SELF_GUIDE == 2):  # the guide pass's terms but g3x3(Var) (1b, from the region's Var)
                ax0 = wp.vec4(depth_scale * slope[p0], 0.0, luminance(wp.vec3(cv0[0], cv0[1], cv0[2])) * luminance_scale, 0.0)
                ax1 = wp.vec4(depth_scale * slope[p1], 0.0, luminance(wp.vec3(cv1[0], cv1[1], cv1[2])) * luminance_scale, 0.0)
            elif wp.static(SELF_GUIDE == 1):  # the guide pass's terms but g3x3(Var) (1b), which needs the ring's Var
                sz0 = slope[p0]
                sz1 = slope[p1]
                # ring point r0 (< RING_N): the apron-5 rows 0 and RING_Y - 1, then its columns 0 and RING_X - 1
                i5 = wp.where(r0 < _RING_X, 0, wp.where(r0 < 2 * _RING_X, RING_Y - 1, r0 - 2 * _RING_X + 1 - wp.where(
                    r0 < 2 * _RING_X + GUIDE_Y, 0, GUIDE_Y)))
                j5 = wp.where(r0 < 2 * _RING_X, r0 % _RING_X, wp.where(r0 < 2 * _RING_X + GUIDE_Y, 0, RING_X - 1))
                y5 = row0 + step * (sy0 - 1 + i5)
                x5 = col0 + step * (sx0 - 1 + j5)
                in5 = r0 < _RING_N and y5 >= 0 and y5 < height and x5 >= 0 and x5 < width
                cv5 = load_vec4(color_variance, wp.where(in5, y5 * width + x5, 0))
                ax0 = wp.vec4(depth_scale * sz0, 0.0, luminance(wp.vec3(cv0[0], cv0[1], cv0[2])) * luminance_scale, 0.0)
                ax1 = wp.vec4(depth_scale * sz1, 0.0, luminance(wp.vec3(cv1[0], cv1[1], cv1[2])) * luminance_scale, 0.0)
                if r0 < _RING_N:
                    write_pair(pair, i5 * _RING_X + j5, wp.where(in5, cv5[3], NO_SURFACE))
                write_pair(pair, (i0 + 1) * _RING_X + j0 + 1, wp.where(in0, cv0[3], NO_SURFACE))
                if r1 < _GUIDE_REAL:
                    write_pair(pair, (i1 + 1) * _RING_X + j1 + 1, wp.where(in1, cv1[3], NO_SURFACE))
            else:
                ax0 = load_aux(aux, p0, cv0, luminance_scale, GATED)
                ax1 = load_aux(aux, p1, cv1, luminance_scale, GATED)
            found = found | store_guide(guide_s, guide_d, signal, i0 * _PITCH + j0 + 2, in0, cv0, gs0, ax0, s, GATED,
                                         SELECT_FREE_)
            if r1 < _GUIDE_REAL:
                found = found | store_guide(guide_s, guide_d, signal, i1 * _PITCH + j1 + 2, in1, cv1, gs1, ax1, s,
                                             GATED, SELECT_FREE_)
        # the empty columns (GUIDE_Y rows x 4), from the last lane down (on CUDA the lanes above GUIDE_HALF)
        for m in range(threads - 1 - lane, _EMPTY_N, threads):
            c = m % 4
            store_guide(guide_s, guide_d, signal, (m // 4) * _PITCH + c + wp.where(c >= 2, _GUIDE_X, 0), False,
                        wp.vec4(0.0), wp.vec4(0.0), wp.vec4(0.0), s, GATED, SELECT_FREE_)

        inv_weight_sum = wp.tile_empty(shape=_GUIDE_N, dtype=wp.float32, storage="shared")
        flag = wp.tile_empty(shape=1, dtype=wp.int32, storage="shared")
        # the barrier after 1, which also tells whether any thread read a pixel to filter: a block whose tile has no
        # surface (the sky, the space around the Cornell box) or, on a gated level, only pixels that need less than
        # half the step (converged) skips 2 and 3: step 4 reads neither table then. So does a block whose tile and
        # apron of 2 hold no signal (colour 0 and Var <= 0 at every point with a surface: the walls no photon
        # reaches): every tap it would filter with is 0, c'_p = A_pp c_p + Σ A_pq c_q = 0 and Var'_p = Σ A_pq² Var_q
        # = 0 (the A_pq finite), which are its own c_p and Var_p, kept as a pixel with every gate 0 keeps them
        to_filter = block_sync_or(flag, found & TO_FILTER)
        any_signal = block_sync_or(flag, found & HAS_SIGNAL)
        run = to_filter != 0 and any_signal != 0
        if wp.static(SELF_GUIDE == 1):
            if run:  # 1b, g3x3(Var) / 2 from the ring (the pair table's first entries, overwritten by 2)
                blur_own_variance(guide_d, pair, lane, threads)
                block_sync()
        if wp.static(SELF_GUIDE == 2):
            if run:  # 1b, g3x3(Var) / 2 from the region's Var (the pair table's first entries, overwritten by 2)
                load_region2(pair, variance_in, lane, threads, row0 + 2 * sy0 - 1, col0 + 2 * sx0 - 1, width, height)
                block_sync()
                blur_region2(guide_d, pair, lane, threads)
                block_sync()
        if run:
            fill_weights(guide_s, guide_d, pair, inv_weight_sum, lane, threads, s, depth_scale * DEPTH_NOISE_REL,
                         normal_scale, GATED, SQUARINGS, SELECT_FREE_)

        # 4. the filter of the tile's pixels
        k = lane
        while k < _TILE_Y * _TILE_X:
            y = row0 + step * (sy0 + 4 + k // _TILE_X)
            x = col0 + step * (sx0 + 4 + k % _TILE_X)
            if y < height and x < width:
                p = y * width + x
                u = (4 + k // _TILE_X) * _PITCH + 6 + k % _TILE_X
                cv_p = read_guide(signal, u)
                c_p = wp.vec3(cv_p[0], cv_p[1], cv_p[2])
                v_p = cv_p[3]
                surface = read_guide(guide_s, u)[3] > 0.0
                c_new = wp.vec3(0.0)
                v_new = float(0.0)
                if surface:
                    c_new = c_p
                    v_new = v_p
                # ungated, or else unless every gate of p is 0 (then A_pp = 1); not in a block without signal (then
                # c'_p = c_p = 0 and Var'_p = Var_p = 0, above)
                if surface and run and (GATED == 0 or 2.0 * read_guide(guide_d, u)[3] > s):
                    iw_p = read_guide_scalar(inv_weight_sum, u)
                    sum_a = float(0.0)  # Σ_{q≠p} A_pq
                    sum_ac = wp.vec3(0.0)  # Σ_{q≠p} A_pq c_q
                    sum_av = float(0.0)  # Σ_{q≠p} A_pq² Var_q (w_pq = 0 where q has no surface: no branch)
                    for f in range(FORWARD_TAPS):
                        off = forward_offset(f)
                        q = u + off
                        a = read_pair(pair, f * _PAIR_PIXELS + u) * wp.where(conserve_energy != 0, wp.min(iw_p, read_guide_scalar(inv_weight_sum, q)), iw_p)
                        cv_q = read_guide(signal, q)
                        sum_a += a
                        sum_ac += a * wp.vec3(cv_q[0], cv_q[1], cv_q[2])
                        sum_av += a * a * cv_q[3]
                        q = u - off
                        a = read_pair(pair, f * _PAIR_PIXELS + q) * wp.where(conserve_energy != 0, wp.min(iw_p, read_guide_scalar(inv_weight_sum, q)), iw_p)
                        cv_q = read_guide(signal, q)
                        sum_a += a
                        sum_ac += a * wp.vec3(cv_q[0], cv_q[1], cv_q[2])
                        sum_av += a * a * cv_q[3]
                    a_centre = 1.0 - sum_a  # A_pp, in (0, 1]: Σ_{q≠p} A_pq <= (W_p − w_pp) / W_p
                    c_new = a_centre * c_p + sum_ac
                    v_new = sum_av + a_centre * a_centre * v_p
                v_packed = wp.where(surface, v_new, NO_SURFACE)
                if write_packed != 0:
                    o = p
                    if lattice_out != 0:
                        o = lattice_index(y, x, width, height, lattice_out)
                    store_vec4(color_variance_out, o, wp.vec4(c_new[0], c_new[1], c_new[2], v_packed))
                if write_variance != 0:
                    variance_next[p] = v_packed
                if write_public != 0:
                    color_out[p] = c_new
                    variance_out[p] = v_new
                if write_history != 0:
                    hist_color[1 - parity[0], p] = c_new
            k += threads

    return atrous_level


#: the level by (gating, squarings): gating 0 (SVGF) and 1 (the caustics denoiser's gated levels); squarings
#: NORMAL_SQUARINGS for σ_n = 2^NORMAL_SQUARINGS (both denoisers' default), 0 for any other σ_n
ATROUS_LEVEL = {(g, k): make_atrous_level(g, k) for g in (0, 1) for k in (0, NORMAL_SQUARINGS)}
#: SVGF's first level (ungated, step 1, packed input, σ_n = 2^NORMAL_SQUARINGS) without a guide pass
ATROUS_LEVEL_SELF = make_atrous_level(0, NORMAL_SQUARINGS, self_guide=1)
#: SVGF's ungated σ_n = 128 levels without the pair weights' select (section 85), (chained, step 1 self-guided)
ATROUS_LEVEL_FREE = make_atrous_level(0, NORMAL_SQUARINGS, select_free=1)
ATROUS_LEVEL_SELF_FREE = make_atrous_level(0, NORMAL_SQUARINGS, self_guide=1, select_free=1)
#: SVGF's step-2 level without a guide pass (section 85, :data:`FOLD_GUIDE2`), by :data:`SELECT_FREE`
ATROUS_LEVEL_GUIDE2 = {f: make_atrous_level(0, NORMAL_SQUARINGS, self_guide=2, select_free=int(f)) for f in (False, True)}
#: Section 85: SVGF's step-2 level (ungated, packed, σ_n = 128, its input's dense Var given and not aliasing its
#: ``variance_next``) makes its guide-pass terms itself (``self_guide`` = 2): no guide pass at step 2, the same values.
#: Read at launch: True (default), False: the guide pass and the plain level (main's).
FOLD_GUIDE2 = True


def level_kernel(gated: int, squarings: int, self_guide: int, select_free: bool):
    """The compiled level :func:`launch_atrous` launches: ``self_guide`` 0, 1 (step 1) or 2 (step 2, section 85);
    ``select_free`` (:data:`SELECT_FREE`) picks the select-free form where there is one (ungated, σ_n = 128)."""
    if self_guide == 2:
        return ATROUS_LEVEL_GUIDE2[bool(select_free)]
    if self_guide:
        return ATROUS_LEVEL_SELF_FREE if select_free else ATROUS_LEVEL_SELF
    if select_free and not gated and squarings == NORMAL_SQUARINGS:
        return ATROUS_LEVEL_FREE
    return ATROUS_LEVEL[int(gated), squarings]


def normal_squarings(sigma_normal: float) -> int:
    """The ``squarings`` of the compiled level for σ_n: ``NORMAL_SQUARINGS`` where σ_n = 2^NORMAL_SQUARINGS
    exactly, else 0 (the general form)."""
    return NORMAL_SQUARINGS if float(sigma_normal) == float(2 ** NORMAL_SQUARINGS) else 0


@wp.kernel
def unpack_level(color_variance: wp.array(dtype=wp.vec4), color_out: wp.array(dtype=wp.vec3),
                 variance_out: wp.array(dtype=wp.float32), flip: int, parity: wp.array(dtype=wp.int32)):
    """A level's packed output (H*W vec4: colour [W/m²], Var; Var < 0 = no surface) as the public colour (H*W
    vec3 [W/m²]) and variance (H*W float32), 0 without a surface, as :func:`atrous_level` writes them itself;
    dense over ``dim=height * width``. ``flip`` != 0: also the end of SVGF's frame, ``parity[0] = 1 - parity[0]``
    (:func:`.kernels_svgf.flip_parity`, which no launch of the frame reads after this one)."""
    p = wp.tid()
    cv = load_vec4(color_variance, p)
    color_out[p] = wp.vec3(cv[0], cv[1], cv[2])
    variance_out[p] = wp.where(cv[3] < 0.0, 0.0, cv[3])
    if flip != 0 and p == 0:
        parity[0] = 1 - parity[0]


_SPARE: dict = {}


def spare_outputs(device) -> dict:
    """One-element stand-ins (allocated once per device) for the buffers a launch does not use."""
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
                  aux: wp.array, noise_target: float | None = None, color_variance_out: wp.array | None = None,
                  color_out: wp.array | None = None, variance_out: wp.array | None = None,
                  hist_color: wp.array | None = None, parity: wp.array | None = None,
                  unpacked: tuple | None = None, pack_into: tuple | None = None,
                  lattice: tuple | None = None, unpack_from: wp.array | None = None,
                  lattice_guide_ready: bool = False, flip: wp.array | None = None,
                  guide_parity: wp.array | None = None, variance: wp.array | None = None,
                  input_lattice: bool = False, variance_next: wp.array | None = None, lattice_out: int = 0,
                  defer_unpack: bool = False) -> bool:
    """One level: :func:`atrous_guide`, then :func:`atrous_level` (SVGF's first level, ungated at step 1 from a
    packed input with σ_n = 128, without the guide pass: the level compiled with ``self_guide``; with
    :data:`FOLD_GUIDE2` its second, step 2, given ``variance`` not aliasing ``variance_next``, likewise).

    Input: packed (``color_variance``, ``guide``: H*W vec4, see the module docstring) or, given ``unpacked`` =
    (color_in, variance_in, depth, normal) and ``pack_into`` = (color_variance, guide) (H*W vec4 scratch each,
    the packed ones then None), unpacked, packed there by the guide pass; ``slope``: H*W float32 [m/pixel];
    ``aux``: H*W vec4 scratch (the guide pass's output). ``noise_target`` (relative, e.g. 0.05): gate the level
    by the footprint the remaining variance needs; None: ungated (SVGF). Each output given is written:
    ``color_variance_out`` (packed, H*W vec4), ``color_out`` + ``variance_out`` (H*W vec3 [W/m²] and float32,
    given together), ``hist_color`` + ``parity`` (the colour history row ``1 - parity[0]``). No output may
    alias an input or ``aux`` (blocks read their neighbours' inputs while others write).

    ``lattice`` = (color_variance, guide) scratch (vec4, at least :func:`lattice_size` entries each, and ``aux``
    as many): at a step of ``LATTICE_STEP`` or more with a packed input, the guide pass copies the input and the
    guide there in the step's sub-lattice-major order and writes ``aux`` so, and the level reads them densely.
    ``lattice_guide_ready``: ``lattice[1]`` already holds ``guide`` in this step's order (not copied again); only
    where the level reads the lattice.

    ``unpack_from`` (H*W vec4 scratch, aliasing no input; only with ``color_out`` and no ``color_variance_out``): at
    a step of ``UNPACK_STEP`` or more the level writes its output packed there and :func:`unpack_level` writes
    ``color_out`` and ``variance_out`` densely (the same values); ``defer_unpack``: not launched (the caller reads
    the packed output itself, :func:`packed_color_view`, and launches :func:`unpack_level` when it needs them).

    ``guide_parity`` (1 int32; packed input only): ``guide`` holds two rows of H*W (row r at r*H*W, SVGF's guide
    history) and the level reads row ``1 - guide_parity[0]``.

    ``flip``: the frame's parity (1 int32) to flip at the end, where :func:`unpack_level` runs (it flips it then,
    one launch fewer than :func:`.kernels_svgf.flip_parity`). Returns whether it was flipped (else the caller
    flips it).

    Chained levels (SVGF, section 71 of docs/perf_notes.md): ``variance_next`` (H*W float32; with
    ``color_variance_out``) gets the packed output's Var densely (NO_SURFACE without a surface) and ``lattice_out`` (a
    power of two >= 2) writes ``color_variance_out`` in that step's sub-lattice-major order (it then needs
    :func:`lattice_size` entries); the next level takes them as ``variance`` (ungated, packed: its guide pass reads
    that Var alone, 4 bytes a pixel) and ``input_lattice`` (its packed input is in its own step's order already, with
    ``variance`` and the lattice: the guide pass copies no input, ``lattice[0]`` is not used and may be None)."""
    d = slope.device
    spare = spare_outputs(d)
    blocks, tiles_x = atrous_blocks(width, height, step)
    depth_scale, normal_scale, luminance_scale = pair_scales(sigma_depth, sigma_normal, sigma_luminance)
    gated = noise_target is not None
    write_public = color_out is not None
    if write_public != (variance_out is not None):
        raise ValueError("color_out and variance_out are written together")
    write_history = hist_color is not None
    if write_history and parity is None:
        raise ValueError("hist_color needs parity")
    if (unpacked is None) != (pack_into is None):
        raise ValueError("an unpacked input needs pack_into, a packed one neither")
    if unpacked is None:
        color_in, variance_in, depth, normal = spare["vec3"], spare["float"], spare["float"], spare["vec3"]
        cv_out = guide_out = spare["vec4"]
    else:
        color_in, variance_in, depth, normal = unpacked
        color_variance = cv_out = pack_into[0]
        guide = guide_out = pack_into[1]
    use_lattice = lattice is not None and unpacked is None and step >= LATTICE_STEP
    if variance is not None and (gated or unpacked is not None):
        raise ValueError("variance (the input's Var alone) is for an ungated level with a packed input")
    if input_lattice != (use_lattice and variance is not None):
        raise ValueError("an input in sub-lattice-major order needs variance, the lattice buffers and a step >= "
                         "LATTICE_STEP, and there variance needs it")
    if (variance_next is not None or lattice_out) and color_variance_out is None:
        raise ValueError("variance_next and lattice_out describe color_variance_out, which is not given")
    if lattice_out:
        if lattice_out < 2 or lattice_out & (lattice_out - 1):
            raise ValueError(f"lattice_out must be a power of two >= 2, got {lattice_out}")
        if color_variance_out.shape[0] < lattice_size(width, height, lattice_out):
            raise ValueError(f"color_variance_out needs {lattice_size(width, height, lattice_out)} entries in the "
                             f"sub-lattice-major order of step {lattice_out}")
    if guide_parity is not None and unpacked is not None:
        raise ValueError("guide_parity names a row of a packed guide; an unpacked input has none")
    guide_row = width * height if guide_parity is not None else 0
    guide_parity = guide_parity if guide_parity is not None else spare["parity"]
    if lattice_guide_ready and not use_lattice:
        raise ValueError("lattice_guide_ready needs a packed input, the lattice buffers and a step >= LATTICE_STEP")
    if use_lattice:
        if step & (step - 1):
            raise ValueError(f"the sub-lattice-major order needs a step that is a power of two, got {step}")
        size = lattice_size(width, height, step)
        cv_lattice, guide_lattice = (color_variance if input_lattice else lattice[0]), lattice[1]
        if min(cv_lattice.shape[0], guide_lattice.shape[0], aux.shape[0]) < size:
            raise ValueError(f"the sub-lattice-major buffers and aux need {size} entries at step {step}")
    else:
        cv_lattice = guide_lattice = spare["vec4"]
    # SVGF's first level (ungated, step 1, packed, σ_n = 128) makes its guide-pass terms itself: no guide pass
    self_guide = int(not gated and step == 1 and unpacked is None and not use_lattice
                     and normal_squarings(sigma_normal) == NORMAL_SQUARINGS)
    # section 85: SVGF's step-2 level likewise, its blur from the previous level's dense Var (``variance``), which
    # it must not overwrite while its blocks read it (its own ``variance_next`` another buffer)
    if (FOLD_GUIDE2 and not gated and step == 2 and variance is not None and not use_lattice
            and normal_squarings(sigma_normal) == NORMAL_SQUARINGS and variance_next is not variance
            and (variance_next is None or variance_next.ptr != variance.ptr)):
        self_guide = 2
    if not self_guide and GUIDE_RUN and variance is not None:  # SVGF's chained levels (ungated, packed: checked)
        wp.launch(ATROUS_GUIDE_RUN[GUIDE_RUN], dim=(height, (width + GUIDE_RUN - 1) // GUIDE_RUN), device=d,
                  inputs=[variance, slope, width, height, depth_scale, aux, int(step) if use_lattice else 0, guide,
                          guide_lattice, int(not lattice_guide_ready), guide_parity, guide_row,
                          runs_aligned(width, variance, slope)])
    elif not self_guide:
        wp.launch(atrous_guide, dim=height * width, device=d,
                  inputs=[3 if variance is not None else int(unpacked is None), color_variance, color_in,
                          variance if variance is not None else variance_in, depth, normal, slope, width,
                          height, int(gated), float(noise_target) if gated else 0.0, depth_scale, luminance_scale,
                          aux,
                          int(unpacked is not None), cv_out, guide_out, int(step) if use_lattice else 0, guide,
                          cv_lattice, guide_lattice, int(not lattice_guide_ready), guide_parity, guide_row])
    if use_lattice:
        color_variance, guide, guide_row = cv_lattice, guide_lattice, 0
    unpack = unpack_from is not None and write_public and color_variance_out is None and step >= UNPACK_STEP
    if unpack:
        color_variance_out, unpack_out, write_public = unpack_from, (color_out, variance_out), False
    level = level_kernel(int(gated), normal_squarings(sigma_normal), self_guide, SELECT_FREE)
    wp.launch_tiled(level, dim=blocks, block_dim=BLOCK_THREADS, device=d,
                    inputs=[color_variance, guide, aux, width, height, int(step), tiles_x, depth_scale,
                            normal_scale, luminance_scale, int(conserve_energy),
                            int(color_variance_out is not None),
                            color_variance_out if color_variance_out is not None else spare["vec4"],
                            int(write_public), color_out if write_public else spare["vec3"],
                            variance_out if write_public else spare["float"], int(write_history),
                            parity if write_history else spare["parity"],
                            hist_color if write_history else spare["hist"], int(use_lattice), guide_parity,
                            guide_row, slope, int(lattice_out), int(variance_next is not None),
                            variance_next if variance_next is not None else spare["float"],
                            variance if self_guide == 2 else spare["float"]])
    if unpack and not defer_unpack:
        wp.launch(unpack_level, dim=height * width, device=d,
                  inputs=[color_variance_out, *unpack_out, int(flip is not None),
                          flip if flip is not None else spare["parity"]])
    return unpack and not defer_unpack and flip is not None


def packed_color_view(color_variance: wp.array, n: int) -> wp.array:
    """The colour of a last level's packed output (``launch_atrous``'s ``unpack_from``: vec4 colour [W/m²], Var, in
    pixel order, the colour 0 without a surface) as an H*W vec3 array, a view with a 16-byte stride on the same
    memory: what :func:`unpack_level` writes to ``color_out``, read in place (a kernel's ``x[p]`` on it loads the
    same three floats)."""
    if color_variance.dtype != wp.vec4 or color_variance.ndim != 1 or color_variance.shape[0] < n:
        raise ValueError(f"the packed output is a vec4 array of at least {n} entries")
    view = wp.array(ptr=color_variance.ptr, dtype=wp.vec3, shape=(n,), strides=(16,), device=color_variance.device)
    view._ref = color_variance  # keeps the buffer alive as long as the view
    return view
