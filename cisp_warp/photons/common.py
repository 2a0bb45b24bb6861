"""What every photon method shares, so that their figures compare: the energy ledger, photon emission
from a light's RSM, the specular bounce and the store into the camera's photon map.

* **Ledger.** Every photon's power ends in exactly one entry; ``sampled`` is the whole. ``reflected``
  and ``refracted`` split the traced power for information and are not part of the sum.
* **Emission** (seed 000, 3.1): a scrambled R2 low-discrepancy point picks an RSM texel; its photon
  carries texel power × texels / N, so N photons carry the texels' total flux whatever N is.
* **Bounce:** exact Fresnel as a probability (power unchanged) at a dielectric; a metal reflects with
  its albedo and the rest is booked as absorbed.
* **Store:** irradiance = power / the world-space footprint of the receiving camera pixel; beside it the sum of
  the stored photons' squared luminance per pixel (``photon_m2``), the frame's own Monte-Carlo variance.
"""

from __future__ import annotations

import os

import warp as wp

from ..denoise.kernels_svgf import luminance
from ..optics import fresnel_dielectric, reflect, refract
from ..raster.light_maps import CascadeState, cascade_photons
from ..raster.kernels import (TexelEmission, texel_emitted_flux, texel_emitted_flux_at, texel_ior, texel_roughness,
                               texel_surface)
from ..raster.views import ViewParams, pixel_ray_world
from ..scene.device import SurfaceGeometry

# ledger entries: power [W] per RGB channel, slots 3*entry .. 3*entry+2
L_SAMPLED = wp.constant(0)  #: power of the sampled texels (the whole)
L_CULLED_ROUGH = wp.constant(1)  #: texel (or specular hit) rougher than the cutoff
L_CULLED_LUM = wp.constant(2)  #: texel dimmer than the luminance cutoff
L_ABSORBED = wp.constant(3)  #: absorbed at a metallic surface
L_LOST_LIGHT = wp.constant(4)  #: left the light view, and its exit point is outside the camera view
L_LOST_CAMERA = wp.constant(5)  #: landed outside the camera view, or left the camera view
L_OCCLUDED = wp.constant(6)  #: landed on a surface the camera does not see
L_REJECTED = wp.constant(7)  #: failed validation <-d, n> >= 0 at the camera hit
L_STEPS = wp.constant(8)  #: ran out of march steps
L_STORED = wp.constant(9)  #: stored in the photon map
L_REFLECTED = wp.constant(10)  #: of the traced power, reflected (informative, not part of the sum)
L_REFRACTED = wp.constant(11)  #: of the traced power, refracted (informative, not part of the sum)
L_ESCAPED = wp.constant(12)  #: world-space methods: left the scene without hitting anything
L_BOUNCES = wp.constant(13)  #: world-space methods: still specular after the bounce limit
L_OUTSIDE = wp.constant(14)  #: on specular texels outside every light view fitted to the camera: not traced
LEDGER_ENTRIES = 15

LEDGER_NAMES = ("sampled", "culled_roughness", "culled_luminance", "absorbed", "lost_light_view",
                "lost_camera_view", "occluded", "rejected", "out_of_steps", "stored", "reflected", "refracted",
                "escaped", "bounce_limit", "outside_fitted_view")
INFORMATIVE = ("sampled", "reflected", "refracted")  #: entries that are not parts of the whole

R2_A1 = wp.constant(wp.uint32(3242174889))  # round(2^32 / phi_2), phi_2 = 1.32471795724... (Roberts' R2)
R2_A2 = wp.constant(wp.uint32(2447445413))  # round(2^32 / phi_2^2)
U32_TO_UNIT = wp.constant(2.3283064365386963e-10)

FOOTPRINT_EXACT = wp.constant(0)
FOOTPRINT_PAPER = wp.constant(1)


LEDGER_BLOCK = 128  #: threads per block of the photon kernels on CUDA: each block adds to the ledger once per entry
#: CUDA launch bounds of CISP's trace kernel: blocks of at most LEDGER_BLOCK threads, 8 resident per SM (<= 64
#: registers a thread). Measured on an H100 (Cornell box, 2M photons): 3.03 ms at the 128 registers nvcc picks by
#: itself, 2.51 ms at 80 (a few spilled to L1), 2.76 ms at 96 (section 8); after the marches' divisions were merged
#: without local memory (docs/perf_notes.md section 44) 8 blocks beat 6 by 2-3% on both scenes (4 blocks, 128
#: registers and no spill in any loop, lost 2-6%). Not yet measured on sspm / caustics_map, which keep nvcc's choice.
PHOTON_LAUNCH_BOUNDS = (LEDGER_BLOCK, 8)
#: vec3d slots of one ledger stripe: the LEDGER_ENTRIES entries, padded to 384 bytes (three 128-byte lines)
LEDGER_ROW = wp.constant(16)
#: stripes of the device ledger on CUDA. A block adds its sums to stripe ``block % stripes`` and :func:`ledger_fold`
#: sums the stripes once per frame. One stripe for every block made the ledger's float64 atomics queue on the same
#: three cache lines: each is ~1 ns at one L2 slice (H100, measured: 16k blocks x 18 atomics = 0.28 ms,
#: ``ledger_add_outcomes`` at 2M photons), so they cost time linear in photons whatever the block reduction did.
LEDGER_STRIPES = 256
#: threads per block of :func:`ledger_add_outcomes` on CUDA, and its blocks per SM: one wave of blocks (86 registers:
#: two blocks of 256 fit an SM), each thread summing many records, so that the blocks' tile reductions run once per
#: block and SM instead of once per 256 records (1024 blocks: 0.054 ms for 2M records on an H100, 4 waves)
OUTCOME_BLOCK = 256
OUTCOME_BLOCKS_PER_SM = 2


@wp.struct
class Tally:
    """One photon's (one thread's) share of the ledger, kept in registers while it is traced and added to
    the ledger once per block by :func:`ledger_add`: no atomics onto the ledger's 42 shared addresses per
    photon. Power [W] per RGB channel; the entries a photon may book more than once (bounces of the world
    methods) accumulate in float64, as the ledger does, except ``absorbed``: a photon's absorption over its
    metallic bounces sums in float32 (exact for one bounce; SSPM carries it through the BVH traversal, where each
    register counts), and the ledger sums the photons' shares in float64."""

    sampled: wp.vec3d  #: L_SAMPLED
    absorbed: wp.vec3  #: L_ABSORBED (once per metallic bounce; float32, see above)
    reflected: wp.vec3d  #: L_REFLECTED (once per dielectric or metallic reflection)
    refracted: wp.vec3d  #: L_REFRACTED
    entry: wp.int32  #: the photon's one final entry (culled, lost, occluded, rejected, stored ...); -1 = none yet
    power: wp.vec3  #: power booked under ``entry``


@wp.func
def tally_new() -> Tally:
    """An empty tally (nothing booked)."""
    t = Tally()
    t.sampled = wp.vec3d()
    t.absorbed = wp.vec3(0.0)
    t.reflected = wp.vec3d()
    t.refracted = wp.vec3d()
    t.entry = -1
    t.power = wp.vec3(0.0)
    return t


@wp.func
def book(tally: wp.ref[Tally], entry: int, power: wp.vec3):
    """Book ``power`` [W] under ``entry`` in this thread's tally (``entry`` is a constant at every call site, so
    the branches fold away). Each photon has exactly one final entry; a second one would replace the first
    and the ledger would no longer close (the tests check closure)."""
    p = wp.vec3d(wp.float64(power[0]), wp.float64(power[1]), wp.float64(power[2]))
    if entry == L_SAMPLED:
        tally.sampled = tally.sampled + p
    elif entry == L_ABSORBED:
        tally.absorbed = tally.absorbed + power
    elif entry == L_REFLECTED:
        tally.reflected = tally.reflected + p
    elif entry == L_REFRACTED:
        tally.refracted = tally.refracted + p
    else:
        tally.entry = entry
        tally.power = power


def entry_mask(*entries: int) -> int:
    """Bit mask of ledger entries, for :func:`ledger_add`."""
    m = 0
    for e in entries:
        m |= 1 << int(e)
    return m


#: what emission and the first bounce book (emit_and_bounce, and the reference's first hit)
EMISSION_ENTRIES = wp.constant(entry_mask(0, 1, 2, 3, 10, 11))
#: what may end a photon after its first bounce (absorbed: further metallic bounces of the world methods)
FINAL_ENTRIES = wp.constant(entry_mask(1, 3, 4, 5, 6, 7, 8, 9, 12, 13))
ALL_ENTRIES = wp.constant((1 << LEDGER_ENTRIES) - 1)


@wp.func
def ledger_slot(ledger: wp.array(dtype=wp.vec3d), block: int, entry: int) -> int:
    """Index of ``entry`` in the stripe of the striped ledger that block ``block`` adds to."""
    return (block % (ledger.shape[0] / LEDGER_ROW)) * LEDGER_ROW + entry


@wp.func
def ledger_add(ledger: wp.array(dtype=wp.vec3d), tally: Tally, block: int, entries: int):
    """Sum every thread's tally over the block (Warp tiles) and add each entry in the bit mask ``entries`` to
    ``ledger`` (the striped ledger, (stripes * LEDGER_ROW,) vec3d; stripe ``block % stripes``) once per block.
    Every thread of the block must call this with the same ``entries`` (no early return before it); an entry
    booked but left out of the mask is lost, and the ledger then does not close (the tests check closure). On
    the CPU a block is one thread, so entries are added in photon order, as single atomics would."""
    for e in range(LEDGER_ENTRIES):
        if (entries >> e) & 1 != 0:
            v = wp.vec3d()
            if e == L_SAMPLED:
                v = tally.sampled
            elif e == L_ABSORBED:
                v = wp.vec3d(wp.float64(tally.absorbed[0]), wp.float64(tally.absorbed[1]), wp.float64(tally.absorbed[2]))
            elif e == L_REFLECTED:
                v = tally.reflected
            elif e == L_REFRACTED:
                v = tally.refracted
            if tally.entry == e:
                v = v + wp.vec3d(wp.float64(tally.power[0]), wp.float64(tally.power[1]), wp.float64(tally.power[2]))
            wp.tile_atomic_add(ledger, wp.tile_sum(wp.tile(v, preserve_type=True)), offset=ledger_slot(ledger, block, e))


@wp.kernel
def ledger_fold(
    stripes: wp.array(dtype=wp.vec3d),  # (stripes * LEDGER_ROW,) the striped ledger (read, then zeroed)
    ledger: wp.array(dtype=wp.vec3d),  # (LEDGER_ENTRIES,) power [W] per entry, RGB (accumulate)
):
    """One block per entry: ledger[e] += the sum of entry e over every stripe, then the stripes are zero. Launched
    tiled with one thread per stripe (CUDA) or one thread (CPU: stripes in order)."""
    e, lane = wp.tid()
    bd = wp.block_dim()
    v = wp.vec3d()
    s = lane
    while s * LEDGER_ROW < stripes.shape[0]:
        v = v + stripes[s * LEDGER_ROW + e]
        stripes[s * LEDGER_ROW + e] = wp.vec3d()
        s += bd
    total = wp.tile_sum(wp.tile(v, preserve_type=True))
    if lane == 0:
        ledger[e] = ledger[e] + total[0]


@wp.func
def record_outcome(outcome: wp.array(dtype=wp.vec4), t: int, tally: Tally):
    """Write thread ``t``'s final entry to its outcome record (power [W] RGB, entry code; -1: none), for
    :func:`ledger_add_outcomes` to add per block after the trace: the trace kernel then holds no block reductions
    of its final entries, whose registers cost it warps (SSPM: 115 registers with them in the kernel)."""
    outcome[t] = wp.vec4(tally.power[0], tally.power[1], tally.power[2], float(tally.entry))


@wp.func
def record_absorbed(outcome: wp.array(dtype=wp.vec4), slot: int, tally: Tally):
    """Write the thread's absorption at further metallic bounces (SSPM) as an ``L_ABSORBED`` outcome record at ``slot``
    (its own slot in a second run of records after the final entries)."""
    a = tally.absorbed
    outcome[slot] = wp.vec4(a[0], a[1], a[2], float(L_ABSORBED))


#: the final entries an outcome record may hold, in two groups of five: a thread's sums are two 5×3 float64
#: matrices (rows in this order), summed over the block as two tiles of matrices
OUTCOME_ROWS = ((1, 3, 4, 5, 6), (7, 8, 9, 12, 13))
assert sorted(OUTCOME_ROWS[0] + OUTCOME_ROWS[1]) == [e for e in range(LEDGER_ENTRIES) if (int(FINAL_ENTRIES) >> e) & 1]
#: five final entries' power [W] RGB (one of OUTCOME_ROWS' groups)
OutcomeSums = wp.types.matrix(shape=(5, 3), dtype=wp.float64)
#: the entries of a group's five rows
OutcomeRows = wp.types.vector(length=5, dtype=wp.int32)


#: CUDA: record ``i`` in one 16-byte load (``ld.global.cs.v4.f32``: read once, evict first), where Warp's load of a
#: 4-byte aligned vec4 is four 4-byte loads, each of which asks the L1 for all of a warp's 512 bytes (16 sectors) again;
#: ``a`` must be contiguous and 16-byte aligned (``PhotonPass.add_outcomes`` checks). Elsewhere the plain load
_RECORD16 = """
#if defined(__CUDA_ARCH__)
const float4 v = __ldcs(reinterpret_cast<const float4*>(a.data) + i);
return wp::vec_t<4, float>(v.x, v.y, v.z, v.w);
#else
return wp::index(a, i);
#endif
"""


@wp.func_native(_RECORD16)
def _record16(a: wp.array(dtype=wp.vec4), i: int) -> wp.vec4:
    """``a[i]``, on CUDA in one 16-byte load (``_RECORD16``)."""
    ...


@wp.func
def _outcome_at(outcome: wp.array(dtype=wp.vec4), r: int, end: int, run: int, n_photons: int, one_run: int,
                wide: int) -> wp.vec4:
    """Outcome record ``r``, or an empty one (entry -1) past ``end`` or past the view's photons in its run. With
    ``one_run`` (the records are one run: ``end`` <= the view's photons already) without the division ``r % run``;
    with ``wide`` in one 16-byte load (:func:`_record16`; the same values)."""
    if r >= end:
        return wp.vec4(0.0, 0.0, 0.0, -1.0)
    if one_run == 0:
        if r % run >= n_photons:
            return wp.vec4(0.0, 0.0, 0.0, -1.0)
    if wide != 0:
        return _record16(outcome, r)
    return outcome[r]


@wp.func
def _outcome_add(a: OutcomeSums, b: OutcomeSums, o: wp.vec4):
    """(a, b) with record ``o``'s power added to its entry's row (OUTCOME_ROWS; nothing for entry -1)."""
    code = int(o[3])
    p = wp.vec3d(wp.float64(o[0]), wp.float64(o[1]), wp.float64(o[2]))
    sa = a
    sb = b
    if code == 1:
        sa[0] = sa[0] + p
    elif code == 3:
        sa[1] = sa[1] + p
    elif code == 4:
        sa[2] = sa[2] + p
    elif code == 5:
        sa[3] = sa[3] + p
    elif code == 6:
        sa[4] = sa[4] + p
    elif code == 7:
        sb[0] = sb[0] + p
    elif code == 8:
        sb[1] = sb[1] + p
    elif code == 9:
        sb[2] = sb[2] + p
    elif code == 12:
        sb[3] = sb[3] + p
    elif code == 13:
        sb[4] = sb[4] + p
    return sa, sb


@wp.func
def _outcome_rows_add(ledger: wp.array(dtype=wp.vec3d), block: int, entries: int, sums: OutcomeSums, row_entries: OutcomeRows):
    """Add each row of ``sums`` whose entry (``row_entries``) is in the mask ``entries`` to the block's stripe."""
    for i in range(5):
        e = row_entries[i]
        if ((entries >> e) & 1) != 0:
            wp.atomic_add(ledger, ledger_slot(ledger, block, e), sums[i])


#: CUDA only (blocks of whole warps): the block's sums of a thread's two OutcomeSums (30 doubles: row r of ``sa`` is
#: value 3r..3r+2, row r of ``sb`` value 15+3r..) by a reduce-scatter in each warp, as ``kernels_cisp._EMISSION_REDUCE``
#: does the emission's 18 (docs/perf_notes.md sections 64 and 77): padded to 32 values, rounds of 16, 8, 4, 2 and 1
#: shuffles at lane distances 16..1, a lane keeping the half of its values its bit selects and adding its partner's copy
#: of that half (31 shuffled doubles instead of Warp's two tile sums of 15 doubles, 5 x 30), so lane i holds value i's
#: warp sum; written to shared memory; one barrier; thread i < 30 adds the warps' sums of value i in warp order and,
#: where value i's entry is in ``entries``, adds it to the ledger (one float64 atomic a thread). On the CPU (or blocks
#: of a partial warp) it returns 0 and ledger_add_outcomes sums with Warp's tiles.
_OUTCOME_REDUCE = """
#if defined(__CUDA_ARCH__) && (WP_TILE_BLOCK_DIM % 32 == 0)
constexpr int NW = WP_TILE_BLOCK_DIM / 32;
__shared__ double outcome_partials[NW][32];
const unsigned FULL = 0xffffffffu;
const int lane = threadIdx.x & 31;
const int warp = threadIdx.x >> 5;
double v[32];
#pragma unroll
for (int i = 0; i < 15; ++i) {
    v[i] = sa.data[i / 3][i % 3];
    v[15 + i] = sb.data[i / 3][i % 3];
}
v[30] = 0.0;
v[31] = 0.0;
ROUNDS
outcome_partials[warp][lane] = v[0];
__syncthreads();
if (threadIdx.x < 30) {
    const int i = threadIdx.x;
    double s = outcome_partials[0][i];
    #pragma unroll
    for (int w = 1; w < NW; ++w)
        s += outcome_partials[w][i];
    const int r = i / 3;
    const int entry = ENTRY_OF_ROW;
    if ((entries >> entry) & 1) {
        double* p = reinterpret_cast<double*>(wp::address(ledger, stripe + entry));
        atomicAdd(p + (i - 3 * r), s);
    }
}
return 1;
#else
return 0;
#endif
""".replace("ROUNDS", "".join(f"""{{
    const bool h = (lane & {w}) != 0;
    #pragma unroll
    for (int i = 0; i < {w}; ++i) {{
        const double send = h ? v[i] : v[i + {w}];
        const double keep = h ? v[i + {w}] : v[i];
        v[i] = keep + __shfl_xor_sync(FULL, send, {w});
    }}
}}
""" for w in (16, 8, 4, 2, 1))).replace("ENTRY_OF_ROW", " : ".join(f"r == {i} ? {e}" for i, e in enumerate(OUTCOME_ROWS[0] + OUTCOME_ROWS[1][:-1]))
            + f" : {OUTCOME_ROWS[1][-1]}")


@wp.func_native(_OUTCOME_REDUCE)
def _outcome_reduce(ledger: wp.array(dtype=wp.vec3d), stripe: int, entries: int, sa: OutcomeSums,
                    sb: OutcomeSums) -> int:
    """On CUDA (blocks of whole warps): the block's sums of ``sa`` and ``sb`` (OUTCOME_ROWS) added to the entries of
    ``entries`` in the ledger's row ``stripe`` (see ``_OUTCOME_REDUCE``); returns 1. Elsewhere it does nothing and
    returns 0."""
    ...


OUTCOME_WIDE = wp.constant(2)  #: ledger_add_outcomes' ``fast`` bit: the records in 16-byte loads on CUDA


@wp.func
def _outcome_block_add(ledger: wp.array(dtype=wp.vec3d), block: int, lane: int, entries: int, fast: int,
                       sa: OutcomeSums, sb: OutcomeSums):
    """The outcome passes' block sums of ``sa`` and ``sb`` (OUTCOME_ROWS) added once to the ledger's stripe of
    ``block``: by :func:`_outcome_reduce` where ``fast`` bit 0 asks for it on CUDA, else by two tile sums that lane 0
    adds in entry order (the twin; the CPU's)."""
    reduced = int(0)
    if (fast & 1) != 0:
        reduced = _outcome_reduce(ledger, ledger_slot(ledger, block, 0), entries, sa, sb)
    if reduced == 0:
        ta = wp.tile_sum(wp.tile(sa, preserve_type=True))
        tb = wp.tile_sum(wp.tile(sb, preserve_type=True))
        if lane == 0:
            _outcome_rows_add(ledger, block, entries, ta[0], OutcomeRows(1, 3, 4, 5, 6))
            _outcome_rows_add(ledger, block, entries, tb[0], OutcomeRows(7, 8, 9, 12, 13))


@wp.kernel
def ledger_add_outcomes(
    outcome: wp.array(dtype=wp.vec4),  # (>= count,) per photon: power [W] RGB, final ledger entry (read)
    count: int,  # records
    threads: int,  # threads launched (blocks * block_dim): each sums records t, t + threads, ...
    entries: int,  # bit mask of the entries the records may hold (entry_mask)
    ledger: wp.array(dtype=wp.vec3d),  # the striped ledger, (stripes * LEDGER_ROW,) [W] RGB (accumulate)
    states: wp.array(dtype=CascadeState),  # (V,) the light's views (LightMaps.states, read)
    view_index: int,  # the view whose photons wrote the records
    light_photons: int,  # the light's photons (cascade_photons)
    run: int,  # records per run (the trace's slots): record r is photon slot r % run of its run
    fast: int,  # bit 0: an inactive view returns at once, the block sums by _outcome_reduce on CUDA (0: the twin's
    # tiles); bit 1 (OUTCOME_WIDE): each record in one 16-byte load on CUDA (0: four 4-byte loads, the twin)
):
    """The final entries of ``count`` outcome records: each thread sums its records per entry in registers, the
    block sums every entry at once (two tiles of 5×3 matrices, OUTCOME_ROWS) and lane 0 adds each entry of
    ``entries`` once to its ledger stripe. On CUDA a few hundred blocks read the records once (16 B each,
    coalesced); on the CPU (one thread per block, one record per thread) the entries are summed in photon order, as
    when the trace kernel added them itself. Records of slots past the view's photon count (launched for the most
    a fitted cascade can get; never written this frame) are skipped."""
    block, lane = wp.tid()
    n_photons = cascade_photons(states[view_index], light_photons)
    if (fast & 1) != 0 and n_photons == 0:  # an inactive view wrote no records (uniform over the launch)
        return
    wide = fast & OUTCOME_WIDE
    t = block * wp.block_dim() + lane
    sa = OutcomeSums()
    sb = OutcomeSums()
    # records past the last run's last written one were never written: the loop ends there
    end = wp.min(count, ((count - 1) / run) * run + wp.min(n_photons, run))
    one_run = wp.where(count <= run, 1, 0)  # then end <= n_photons: no record past the photons before it
    # four records a step, their loads issued together, added in the order one at a time would add them
    r = t
    while r < end:
        o0 = _outcome_at(outcome, r, end, run, n_photons, one_run, wide)
        o1 = _outcome_at(outcome, r + threads, end, run, n_photons, one_run, wide)
        o2 = _outcome_at(outcome, r + 2 * threads, end, run, n_photons, one_run, wide)
        o3 = _outcome_at(outcome, r + 3 * threads, end, run, n_photons, one_run, wide)
        sa, sb = _outcome_add(sa, sb, o0)
        sa, sb = _outcome_add(sa, sb, o1)
        sa, sb = _outcome_add(sa, sb, o2)
        sa, sb = _outcome_add(sa, sb, o3)
        r += 4 * threads
    # the block's sums of all entries in two tile sums instead of ten (H100, in the frame against main's kernel in the
    # same call: -16% / -9% with ten, -20% / -18% with two; docs/perf_notes.md section 40), added by lane 0 in order
    _outcome_block_add(ledger, block, lane, entries, fast, sa, sb)


#: the six final entries of a screen-space trace's records (lost from the light view, from the camera, occluded,
#: rejected, out of steps, stored: ``kernels_cisp.CISP_FINAL_ENTRIES``), contiguous: :func:`ledger_add_outcomes6`
FINAL6_ENTRIES = wp.constant(entry_mask(*range(4, 10)))
assert int(L_LOST_LIGHT) == 4 and int(L_STORED) == 9
#: the six entries' power [W] RGB (rows: entries 4 .. 9)
Final6Sums = wp.types.matrix(shape=(6, 3), dtype=wp.float64)
#: blocks of ledger_add_outcomes6 an SM (its launch bound: <= 80 registers for three blocks of OUTCOME_BLOCK)
OUTCOME6_BLOCKS_PER_SM = 3


@wp.func
def _final6_add(s: Final6Sums, o: wp.vec4) -> Final6Sums:
    """``s`` with record ``o``'s power added to its entry's row (entries 4-9; nothing for any other code)."""
    code = int(o[3])
    p = wp.vec3d(wp.float64(o[0]), wp.float64(o[1]), wp.float64(o[2]))
    r = s
    if code == 4:
        r[0] = r[0] + p
    elif code == 5:
        r[1] = r[1] + p
    elif code == 6:
        r[2] = r[2] + p
    elif code == 7:
        r[3] = r[3] + p
    elif code == 8:
        r[4] = r[4] + p
    elif code == 9:
        r[5] = r[5] + p
    return r


@wp.kernel(launch_bounds=(OUTCOME_BLOCK, OUTCOME6_BLOCKS_PER_SM))
def ledger_add_outcomes6(
    outcome: wp.array(dtype=wp.vec4),  # as ledger_add_outcomes'
    count: int,
    threads: int,
    entries: int,  # FINAL6_ENTRIES (the caller launches this kernel for that mask only)
    ledger: wp.array(dtype=wp.vec3d),
    states: wp.array(dtype=CascadeState),
    view_index: int,
    light_photons: int,
    run: int,
    fast: int,  # as ledger_add_outcomes' (bit 0: inactive views return, the reduce-scatter; bit 1: 16-byte loads)
):
    """:func:`ledger_add_outcomes` for records of the six entries 4-9 (CISP's trace; ``PhotonPass.OUTCOMES6``): each
    thread sums them in one 6×3 float64 matrix (36 registers, not the two 5×3 of every final entry: 60), so that the
    kernel fits three blocks of 256 an SM (launch bound; 124 registers and two blocks for the twin) and keeps half as
    many records again in flight. The block sums and the adds are the twin's (the rows placed in its two matrices):
    the same sums in the same order, bit for bit on the CPU."""
    block, lane = wp.tid()
    n_photons = cascade_photons(states[view_index], light_photons)
    if (fast & 1) != 0 and n_photons == 0:  # an inactive view wrote no records (uniform over the launch)
        return
    wide = fast & OUTCOME_WIDE
    t = block * wp.block_dim() + lane
    s = Final6Sums()
    end = wp.min(count, ((count - 1) / run) * run + wp.min(n_photons, run))
    one_run = wp.where(count <= run, 1, 0)
    r = t
    while r < end:
        o0 = _outcome_at(outcome, r, end, run, n_photons, one_run, wide)
        o1 = _outcome_at(outcome, r + threads, end, run, n_photons, one_run, wide)
        o2 = _outcome_at(outcome, r + 2 * threads, end, run, n_photons, one_run, wide)
        o3 = _outcome_at(outcome, r + 3 * threads, end, run, n_photons, one_run, wide)
        s = _final6_add(s, o0)
        s = _final6_add(s, o1)
        s = _final6_add(s, o2)
        s = _final6_add(s, o3)
        r += 4 * threads
    # OUTCOME_ROWS: entries 4, 5, 6 are rows 2-4 of the first matrix, 7, 8, 9 rows 0-2 of the second
    sa = OutcomeSums()
    sb = OutcomeSums()
    sa[2] = s[0]
    sa[3] = s[1]
    sa[4] = s[2]
    sb[0] = s[3]
    sb[1] = s[4]
    sb[2] = s[5]
    _outcome_block_add(ledger, block, lane, entries, fast, sa, sb)


#: the whole frame's clear in 16-byte stores: CUDA's st.global.v4 (Warp's vec4 is 4-byte aligned, so its stores may
#: be split into four 4-byte ones: section 63's 4-byte clear, which lost to the memsets and is gone), elsewhere a vec4 store
_ZERO16 = """
#if defined(__CUDA_ARCH__)
float4 z;
z.x = 0.0f;
z.y = 0.0f;
z.z = 0.0f;
z.w = 0.0f;
reinterpret_cast<float4*>(a.data)[i] = z;
#else
a.data[i] = wp::vec_t<4, float>();
#endif
"""


@wp.func_native(_ZERO16)
def _zero16(a: wp.array(dtype=wp.vec4), i: int):
    """a[i] = 0 in one 16-byte store (``a``'s memory is 16-byte aligned: an allocation's start)."""
    ...


@wp.func
def _zero_strided(a: wp.array(dtype=wp.vec4), t: int, threads: int):
    i = t
    while i < a.shape[0]:
        _zero16(a, i)
        i += threads


@wp.kernel
def clear_frame_wide(
    photon_map: wp.array(dtype=wp.vec4),  # the photon map's 16-byte words (a vec4 alias, write: zero)
    photon_m2: wp.array(dtype=wp.vec4),  # Σ luminance(e)²'s, or empty
    hidden: wp.array(dtype=wp.vec4),  # every light's hidden flux map's (HiddenFlux.all_flux), or empty
    accumulators: wp.array(dtype=wp.vec4),  # the striped ledger's, ledger's and lights' maxima's
    photon_map_tail: wp.array(dtype=wp.float32),  # each array's 4-byte words past its last whole 16-byte word (0-3)
    photon_m2_tail: wp.array(dtype=wp.float32),
    hidden_tail: wp.array(dtype=wp.float32),
    accumulators_tail: wp.array(dtype=wp.float32),
    threads: int,  # threads launched: thread t zeroes 16-byte words t, t + threads, ... of each array
):
    """The photon pass's per-frame accumulators zeroed in one launch of 16-byte stores (``PhotonPass.WIDE_CLEAR``):
    each thread zeroes every ``threads``-th 16-byte word of each array (a warp's stores one contiguous 512-byte run),
    then the first threads the 4-byte words left past each array's last 16-byte word: what ``PhotonPass.begin``'s
    memsets do (the twin), in one launch instead of four."""
    t = wp.tid()
    _zero_strided(photon_map, t, threads)
    _zero_strided(photon_m2, t, threads)
    _zero_strided(hidden, t, threads)
    _zero_strided(accumulators, t, threads)
    if t < photon_map_tail.shape[0]:
        photon_map_tail[t] = 0.0
    if t < photon_m2_tail.shape[0]:
        photon_m2_tail[t] = 0.0
    if t < hidden_tail.shape[0]:
        hidden_tail[t] = 0.0
    if t < accumulators_tail.shape[0]:
        accumulators_tail[t] = 0.0


MAX_LUM_TEXELS = 16  #: texels each thread of ``max_luminance`` reads


@wp.kernel
def max_luminance(
    views: wp.array(dtype=ViewParams),  # the light's whole views (LightMaps.whole_views, read)
    view_index: int,
    rsm_tri: wp.array(dtype=wp.int32),  # (Hl*Wl,) the view's specular layer's triangle per texel, -1 none (read)
    rsm_emission: TexelEmission,  # its specular texels' flux from the light (read)
    count: int,  # texels
    out: wp.array(dtype=wp.float32),  # (1,) max luminance [W] (atomic max; zeroed by the caller)
):
    """out[0] = max over texels of luminance(flux) (a texel without a specular surface sends none): each thread
    reads MAX_LUM_TEXELS texels (coalesced across the block), the block takes the max as a tile and adds it with one
    atomic_max, not one per texel."""
    block, lane = wp.tid()
    bd = wp.block_dim()
    view = views[view_index]
    first = block * bd * MAX_LUM_TEXELS + lane
    m = float(0.0)
    for i in range(MAX_LUM_TEXELS):
        p = first + i * bd
        if p < count:
            if rsm_tri[p] >= 0:
                m = wp.max(m, luminance(texel_emitted_flux(rsm_emission, view, p)))
    block_max = wp.tile_max(wp.tile(m))
    if lane == 0:
        wp.atomic_max(out, 0, block_max[0])


@wp.func
def r2_point(k: int, scramble: wp.vec2i) -> wp.vec2:
    """k-th point of Roberts' R2 sequence in [0, 1)², Cranley-Patterson rotated by ``scramble``."""
    ux = float(wp.uint32(k) * R2_A1 + wp.uint32(scramble[0])) * U32_TO_UNIT
    uy = float(wp.uint32(k) * R2_A2 + wp.uint32(scramble[1])) * U32_TO_UNIT
    return wp.vec2(ux, uy)


@wp.func
def _spread_bits(v: int) -> int:
    """The low 15 bits of v spread to the even bits (for a 2-D Morton code)."""
    x = v & 0x7FFF
    x = (x | (x << 8)) & 0x00FF00FF
    x = (x | (x << 4)) & 0x0F0F0F0F
    x = (x | (x << 2)) & 0x33333333
    x = (x | (x << 1)) & 0x55555555
    return x


@wp.kernel
def photon_sort_keys(
    views: wp.array(dtype=ViewParams),  # (V,) the light's RSM views (LightMaps.views, read)
    states: wp.array(dtype=CascadeState),  # (V,) (LightMaps.states, read)
    view_index: int,
    light_photons: int,  # the light's photons, split over its active views (cascade_photons)
    randoms: wp.array(dtype=wp.vec3i),  # (S,) per stream: R2 scramble (x, y) and seed (frame.FrameInputs, read)
    stream: int,  # this (light, view)'s stream
    keys: wp.array(dtype=wp.int32),  # (2N,) Morton code of each photon's texel (write, first N)
    values: wp.array(dtype=wp.int32),  # (2N,) photon index k (write, first N)
):
    """Keys to trace photons in texel (Morton) order: neighbouring threads then start from neighbouring
    texels and mostly travel alike, which keeps a GPU warp's memory reads and march lengths coherent.
    Each photon is still photon k of the R2 sequence; only the order of the threads changes. Slots past the
    view's photon count (launched with fixed dims) sort last. A view that emits nothing this frame (an inactive
    cascade) writes nothing: its order is sorted all the same (the sort's length is the host's) but never read, as
    its photon_group_keys puts every slot last without reading the order and its trace returns at once."""
    k = wp.tid()
    n_photons = cascade_photons(states[view_index], light_photons)
    if n_photons == 0:
        return
    light = views[view_index]
    u = r2_point(k, wp.vec2i(randoms[stream][0], randoms[stream][1]))
    i = wp.min(int(u[0] * float(light.width)), light.width - 1)
    j = wp.min(int(u[1] * float(light.height)), light.height - 1)
    keys[k] = _spread_bits(i & 0x3FFF) | (_spread_bits(j & 0x3FFF) << 1)
    if k >= n_photons:
        keys[k] = 0x7FFFFFFF  # after every texel's code in the sorted key bits (all ones there): sorts last
    values[k] = k


@wp.kernel
def photon_texel_keys(
    width: int,  # the view's texels across
    height: int,  # and down
    n_photons: int,  # photons of the view: indices from it on sort after every texel
    last_bit: int,  # a key bit above every texel code's: set for the indices past n_photons
    keys: wp.array(dtype=wp.int32),  # (>= N,) Morton code of photon k's texel without the frame's rotation (write)
    values: wp.array(dtype=wp.int32),  # (>= N,) photon index k (write)
):
    """Keys of a fixed texel order (``PhotonPass.texel_order``): photon k's texel as the R2 sequence places it
    before the frame's Cranley-Patterson rotation, as a Morton code; indices k >= n_photons after every code (the
    slots a fitted view launches past its photons). Sorted once per view size and photon count, not per frame: each
    frame's rotation moves every point by the same offset (mod 1), so points that were neighbours (one warp's worth
    in a small Morton cell) stay neighbours; only a cell that the wrap-around cuts is split, in two."""
    k = wp.tid()
    u = r2_point(k, wp.vec2i(0, 0))
    i = wp.min(int(u[0] * float(width)), width - 1)
    j = wp.min(int(u[1] * float(height)), height - 1)
    key = _spread_bits(i & 0x3FFF) | (_spread_bits(j & 0x3FFF) << 1)
    if k >= n_photons:
        key = key | (1 << last_bit)
    keys[k] = key
    values[k] = k


@wp.func
def order_base(cascade: CascadeState, order_stride: int, orders: int) -> int:
    """Where a view's texel order starts in its light's table of orders (``PhotonPass.texel_order``): one order per
    count of active views (their photon counts differ), ``order_stride`` apart (0: a single order)."""
    return wp.min(wp.max(1, cascade.active_views), orders) * order_stride - order_stride


#: The photon order's groups, in the order the trace takes them (the group partition lays them out by number). With
#: ``REFLECTED_FIRST`` (default) the photons predicted to reflect come first: their marches are the longest (up and
#: out of the view), so they start first and the refracted ones' shorter marches fill the launch's tail, as the
#: longest-job-first rule of scheduling says (perf_notes section 92: the pool's traces 1.01 / 0.90 -> 0.92 / 0.75 ms on
#: the H100). ``CISP_REFLECTED_FIRST=0`` in the environment before the import: refracted first (the order before).
REFLECTED_FIRST = os.environ.get("CISP_REFLECTED_FIRST", "1") != "0"
SORT_REFLECTED = wp.constant(0 if REFLECTED_FIRST else 1)  #: sort groups: predicted to reflect (long marches)
SORT_REFRACTED = wp.constant(1 if REFLECTED_FIRST else 0)  #: predicted to refract (most at water: down to the floor)
SORT_NOT_TRACED = wp.constant(2)  #: no specular texel, left to a finer cascade, or culled: no march at all
SORT_GROUP_LAST = wp.constant(3)  #: slots past the view's photon count (fixed launch dims): after every group


SORT_GROUPS = 4  #: march groups including SORT_GROUP_LAST: the partition's block counts per group
SORT_GROUP_BLOCK = 256  #: threads per block (and slots per tile) of the group partition on CUDA (< 2^SORT_COUNT_BITS)
#: blocks of the group partition per SM on CUDA, each over many tiles: photon_group_keys' launch bound (64 registers
#: and 32 B of stack on sm_90 with the texel normal computed, kernels.texel_surface; 76 registers unbounded, which fit
#: only 3 blocks of 256; perf_notes section 43)
SORT_GROUP_BLOCKS_PER_SM = 4
SORT_COUNT_BITS = wp.constant(10)  #: bits of one group's count in a packed block count (blocks of <= 1023 threads)


@wp.func
def _group_count_bit(group: int) -> int:
    """A photon of ``group`` as a packed count: 1 in the group's field for the first three groups (SORT_COUNT_BITS
    each); 0 for SORT_GROUP_LAST (counted as the rest) and for padding lanes (group -1)."""
    if group < 0 or group >= SORT_GROUP_LAST:
        return 0
    return 1 << (SORT_COUNT_BITS * group)


#: CUDA (blocks of whole warps): a tile's photons per group (SORT_COUNT_BITS-packed, as the tile sum of
#: ``_group_count_bit``) by three warp ballots a warp, one shared row of counts a warp and ONE barrier, thread 0 adding
#: the warps' rows: Warp's ``tile_sum`` of an int (warp shuffles, shared partials and three barriers a tile) is the
#: twin (``PhotonPass.BALLOT_GROUPS``). The rows alternate between two buffers by ``parity`` (the caller's round:
#: its tile's ``tile / grid``; the rounds that skip the call are the last ones): a warp writing round n + 1's row
#: passed round n's barrier, and thread 0 read round n - 1's rows before it reached that barrier, so one barrier a
#: round suffices. Returns the packed counts in thread 0 (0 in the others);
#: elsewhere (the CPU, blocks of a partial warp) -1: the caller takes the tile sum.
_GROUP_COUNT_BALLOT = """
#if defined(__CUDA_ARCH__) && (WP_TILE_BLOCK_DIM % 32 == 0)
constexpr int NW = WP_TILE_BLOCK_DIM / 32;
__shared__ int group_count_rows[2][NW][3];
const unsigned FULL = 0xffffffffu;
const int lane = threadIdx.x & 31;
const int warp = threadIdx.x >> 5;
const int p = parity & 1;
const int c0 = __popc(__ballot_sync(FULL, group == 0));
const int c1 = __popc(__ballot_sync(FULL, group == 1));
const int c2 = __popc(__ballot_sync(FULL, group == 2));
if (lane == 0) {
    group_count_rows[p][warp][0] = c0;
    group_count_rows[p][warp][1] = c1;
    group_count_rows[p][warp][2] = c2;
}
__syncthreads();
int packed = 0;
if (threadIdx.x == 0) {
    #pragma unroll
    for (int w = 0; w < NW; ++w)
        packed += group_count_rows[p][w][0] | (group_count_rows[p][w][1] << 10) | (group_count_rows[p][w][2] << 20);
}
return packed;
#else
return -1;
#endif
"""


@wp.func_native(_GROUP_COUNT_BALLOT)
def _group_count_ballot(group: int, parity: int) -> int:
    """On CUDA (blocks of whole warps): the tile's packed group counts in thread 0 (``_GROUP_COUNT_BALLOT``); -1
    elsewhere."""
    ...


#: CUDA (blocks of whole warps): each thread's exclusive prefix of the tile's packed group counts (what
#: ``tile_scan_exclusive`` of ``_group_count_bit`` gives, bit for bit) by ballots: its rank among its warp's lanes below
#: it (popc of the ballot masked to the lower lanes) plus the counts of the warps before its own, from one shared row a
#: warp written behind ONE barrier (two buffers by ``parity``, as ``_GROUP_COUNT_BALLOT``): Warp's scan (the tile
#: copied to shared memory, two warp scans and six barriers a tile) is the twin (``PhotonPass.BALLOT_GROUPS``). A warp
#: writing round n + 1's row has passed round n's barrier, which every thread reached after reading round n - 1's rows.
#: Returns -1 elsewhere (the CPU, blocks of a partial warp): the caller takes the tile scan.
_GROUP_SCAN_BALLOT = """
#if defined(__CUDA_ARCH__) && (WP_TILE_BLOCK_DIM % 32 == 0)
constexpr int NW = WP_TILE_BLOCK_DIM / 32;
__shared__ int group_scan_rows[2][NW][3];
const unsigned FULL = 0xffffffffu;
const int lane = threadIdx.x & 31;
const int warp = threadIdx.x >> 5;
const int p = parity & 1;
const unsigned below = (1u << lane) - 1u;
const unsigned b0 = __ballot_sync(FULL, group == 0);
const unsigned b1 = __ballot_sync(FULL, group == 1);
const unsigned b2 = __ballot_sync(FULL, group == 2);
if (lane == 0) {
    group_scan_rows[p][warp][0] = __popc(b0);
    group_scan_rows[p][warp][1] = __popc(b1);
    group_scan_rows[p][warp][2] = __popc(b2);
}
__syncthreads();
int r0 = __popc(b0 & below);
int r1 = __popc(b1 & below);
int r2 = __popc(b2 & below);
for (int w = 0; w < warp; ++w) {
    r0 += group_scan_rows[p][w][0];
    r1 += group_scan_rows[p][w][1];
    r2 += group_scan_rows[p][w][2];
}
return r0 | (r1 << 10) | (r2 << 20);
#else
return -1;
#endif
"""


@wp.func_native(_GROUP_SCAN_BALLOT)
def _group_scan_ballot(group: int, parity: int) -> int:
    """On CUDA (blocks of whole warps): the exclusive prefix of the tile's packed group counts at this thread
    (``_GROUP_SCAN_BALLOT``); -1 elsewhere."""
    ...


@wp.func
def _march_group(
    views: wp.array(dtype=ViewParams),
    states: wp.array(dtype=CascadeState),
    view_index: int,
    n_photons: int,
    randoms: wp.array(dtype=wp.vec3i),
    stream: int,
    rsm_emission: TexelEmission,  # its specular texels' flux, roughness and IOR from the light and materials (read)
    rsm_tri: wp.array(dtype=wp.int32),
    geometry: SurfaceGeometry,
    triangle_material: wp.array(dtype=wp.int32),
    mat_opacity: wp.array(dtype=wp.float32),
    max_lum: wp.array(dtype=wp.float32),
    roughness_cutoff: float,
    luminance_cutoff: float,
    k: int,
) -> int:
    """The march group of photon ``k`` (a thread's entry of its view's texel order; see :func:`photon_group_keys`)."""
    cascade = states[view_index]
    light = views[view_index]
    rnd = randoms[stream]
    skip_window = cascade.skip_window
    u = r2_point(k, wp.vec2i(rnd[0], rnd[1]))
    sx = u[0] * float(light.width)
    sy = u[1] * float(light.height)
    i = wp.min(int(sx), light.width - 1)
    j = wp.min(int(sy), light.height - 1)
    texel = j * light.width + i
    tri = rsm_tri[texel]
    if tri < 0 or (sx >= skip_window[0] and sx < skip_window[2] and sy >= skip_window[1] and sy < skip_window[3]):
        return SORT_NOT_TRACED
    # every value the prediction may need, read together: one dependent round trip to memory instead of three
    # (roughness, then flux, then normal and IOR), at the price of the normal and IOR of culled texels. The RSM keeps
    # no normal, flux, roughness or IOR per texel (perf_notes sections 43 and 58): the normal is the one the texel's
    # resolve finds (kernels.texel_surface from the texel's triangle, its vertex indices read beside the texel's
    # solid angle, its points and normals beside the material's roughness, IOR and opacity; the point it also gives
    # is not used, so not computed), the flux the one it would write (from the light and the solid angle)
    rough = texel_roughness(rsm_emission, tri)
    flux = texel_emitted_flux_at(rsm_emission, light, texel, i, j)
    x_t, n = texel_surface(light, texel, tri, 0.0, geometry.points, geometry.normals, geometry.indices)
    eta = texel_ior(rsm_emission, tri)
    opacity = mat_opacity[triangle_material[tri]]
    if rough > roughness_cutoff or luminance(flux) < luminance_cutoff * cascade.texel_scale * max_lum[0]:
        return SORT_NOT_TRACED  # culled as emit_photon culls (the same two tests)
    if opacity >= 1.0:
        return SORT_REFLECTED
    # the incident direction along the light ray through the sample (the trace's, for every light kind: a point or
    # spot light's view has its eye at the light), not from the texel's stored position: one array fewer to read
    lo, ld = pixel_ray_world(light, sx, sy)
    d_in = wp.normalize(ld)
    if wp.dot(d_in, n) > 0.0:
        n = -n
        eta = 1.0 / eta
    state = wp.rand_init(rnd[2], k)
    if wp.randf(state) >= fresnel_dielectric(-wp.dot(d_in, n), eta):
        return SORT_REFRACTED
    return SORT_REFLECTED


@wp.kernel(launch_bounds=(SORT_GROUP_BLOCK, SORT_GROUP_BLOCKS_PER_SM))  # 64 registers: 4 blocks an SM
def photon_group_keys(
    views: wp.array(dtype=ViewParams),  # (V,) the light's RSM views (LightMaps.views, read)
    states: wp.array(dtype=CascadeState),  # (V,) (LightMaps.states, read)
    view_index: int,
    light_photons: int,  # the light's photons, split over its active views (cascade_photons)
    randoms: wp.array(dtype=wp.vec3i),  # (S,) per stream: R2 scramble (x, y) and seed (frame.FrameInputs, read)
    stream: int,  # this (light, view)'s stream (the same as the trace kernel's)
    rsm_emission: TexelEmission,  # its specular texels' flux, roughness and IOR from the light and materials (read)
    rsm_tri: wp.array(dtype=wp.int32),
    geometry: SurfaceGeometry,  # the scene's triangles: the texel's normal (kernels.texel_surface, read)
    triangle_material: wp.array(dtype=wp.int32),
    mat_opacity: wp.array(dtype=wp.float32),
    max_lum: wp.array(dtype=wp.float32),  # (1,) brightest texel luminance of this light [W]
    roughness_cutoff: float,
    luminance_cutoff: float,  # relative to max_lum, per whole-view texel (scaled by the view's texel_scale)
    order: wp.array(dtype=wp.int32),  # photon index per thread in texel order, the first n_photons from order_base (read)
    order_stride: int,  # the light's orders per count of active views lie this far apart (0: one order)
    orders: int,  # orders in the table
    n_slots: int,  # N: threads to group (the launch is whole blocks; lanes past N are padding)
    keys: wp.array(dtype=wp.int32),  # (>= N,) march group of thread t's photon (write, the first n_photons)
    block_counts: wp.array(dtype=wp.int32),  # (SORT_GROUPS * tiles,) photons per (group, tile), group-major (write)
    grid: int,  # blocks launched
    ballot: int,  # 1: a tile's counts by warp ballots and one barrier on CUDA (_group_count_ballot); 0: tile_sum (twin)
):
    """The march group of each photon, over the photons already in texel order (so the RSM reads are coherent),
    and how many of each group each block holds; :func:`photon_group_scatter` then groups the photons stably, so
    texel order holds inside each group. The group is a cheap prediction of what the trace kernel will do with
    photon k: not traced (culled exactly as :func:`emit_photon` culls), reflected or refracted (the first draw of
    the photon's own random stream against Fresnel at the texel's normal, along the light ray through the sample;
    the trace uses the exact normal under the sample, so a few photons land in the other group); slots past the
    view's photon count last. Each photon is still traced in full as photon k: only the order of the
    threads changes. Launched tiled, ``grid`` blocks, block b taking tiles b, b + grid, ... of ``block_dim`` slots
    (few blocks, each over many tiles: 8192 blocks of 256 cost ~15 µs to schedule even when they do nothing); a
    tile's counts are one packed tile sum. A tile wholly past the view's photons reads nothing and writes its counts
    only; an inactive view writes nothing (its scatter returns at once).""" 
    block, lane = wp.tid()
    bd = wp.block_dim()
    cascade = states[view_index]
    n_photons = cascade_photons(cascade, light_photons)
    if n_photons == 0:  # an inactive view: nothing (its scatter returns at once and reads no counts)
        return
    base = order_base(cascade, order_stride, orders)
    tiles = block_counts.shape[0] / SORT_GROUPS
    mask = (1 << SORT_COUNT_BITS) - 1
    tile = block
    # each tile's photon indices are loaded one tile ahead (``k``), so that a tile's chain of dependent loads starts
    # at its texel's triangle, not at the order: the next tile's order load is in flight while this tile's chain runs
    k = int(0)
    t_first = tile * bd + lane
    if t_first < n_photons and t_first < n_slots:
        k = order[base + t_first]
    while tile < tiles:  # the same trip count for every thread of the block
        first = tile * bd
        t_next = first + grid * bd + lane
        k_next = int(0)
        if t_next < n_photons and t_next < n_slots:
            k_next = order[base + t_next]
        if first >= n_photons:  # a tile wholly past the view's photons: all last
            if lane == 0:
                for g in range(SORT_GROUPS - 1):
                    block_counts[g * tiles + tile] = 0
                block_counts[(SORT_GROUPS - 1) * tiles + tile] = wp.min(n_slots - first, bd)
        else:
            t = first + lane
            group = int(-1)
            if t < n_slots:
                group = SORT_GROUP_LAST
                if t < n_photons:
                    group = _march_group(views, states, view_index, n_photons, randoms, stream, rsm_emission,
                                         rsm_tri, geometry, triangle_material, mat_opacity,
                                         max_lum, roughness_cutoff, luminance_cutoff, k)
                keys[t] = group
            c = int(-1)
            if ballot != 0:
                c = _group_count_ballot(group, tile / grid)  # the round's parity: tile = block + round * grid
            if c < 0:  # the twin, and the CPU (lane 0 reads the block's sum, as thread 0 has the ballots')
                packed = wp.tile_sum(wp.tile(_group_count_bit(group)))
                if lane == 0:
                    c = packed[0]
            if lane == 0:
                rest = wp.min(n_slots - first, bd)
                for g in range(SORT_GROUPS - 1):
                    n_g = (c >> (SORT_COUNT_BITS * g)) & mask
                    block_counts[g * tiles + tile] = n_g
                    rest -= n_g
                block_counts[(SORT_GROUPS - 1) * tiles + tile] = rest
        k = k_next
        tile += grid


@wp.kernel
def photon_group_scatter(
    states: wp.array(dtype=CascadeState),  # (V,) the light's views (LightMaps.states, read)
    view_index: int,
    light_photons: int,  # the light's photons (cascade_photons)
    keys: wp.array(dtype=wp.int32),  # (>= N,) march group per thread (photon_group_keys, read)
    order: wp.array(dtype=wp.int32),  # photon index per thread in texel order, from order_base (read)
    order_stride: int,  # as photon_group_keys'
    orders: int,
    n_slots: int,  # N
    offsets: wp.array(dtype=wp.int32),  # (SORT_GROUPS * tiles,) exclusive scan of the tile counts (read)
    grouped: wp.array(dtype=wp.int32),  # (>= N,) photon index per thread, grouped (write, first n_photons)
    grid: int,  # blocks launched (block b takes tiles b, b + grid, ...)
    ballot: int,  # 1: the tile's ranks by warp ballots and one barrier on CUDA (_group_scan_ballot); 0: the tile scan
):
    """A stable partition of the photons by march group (the stable sort on the 2-bit group keys, without a radix
    sort's passes and copies): thread t's photon goes to its group's offset for its block plus the photons of its
    group before it in the tile (an exclusive tile scan of packed counts). Same tiles as photon_group_keys.
    Slots of the last group (past the view's photon count) are not written: they would land at positions >= the
    view's photon count, which no kernel reads (the trace reads ``grouped[t]`` for t < its photon count only); tiles
    wholly past the count (every tile of an inactive view) are skipped."""
    block, lane = wp.tid()
    bd = wp.block_dim()
    cascade = states[view_index]
    n_photons = cascade_photons(cascade, light_photons)
    base = order_base(cascade, order_stride, orders)
    tiles = offsets.shape[0] / SORT_GROUPS
    tile = block
    rounds = int(0)  # ballot rounds so far (their shared rows alternate)
    # with ``ballot`` each tile's keys are loaded one tile ahead (``g_next``), so that a tile's chain of loads starts
    # at its photon and offset (key -> photon, offset was two round trips a tile); the twin loads them in the tile
    g_next = int(-1)
    if ballot != 0 and tile * bd + lane < n_slots:
        g_next = keys[tile * bd + lane]
    while tile < tiles and tile * bd < n_photons:  # tiles past the photons have nothing to write; uniform per block
        t = tile * bd + lane
        group = int(-1)
        if ballot != 0:
            group = g_next
            g_next = -1
            if t + grid * bd < n_slots:  # the next tile's (a key past the photons is read for nothing)
                g_next = keys[t + grid * bd]
        elif t < n_slots:
            group = keys[t]
        # the photon and its group's offset loaded before the scan, in flight while the block scans
        k = int(0)
        offset = int(0)
        if t < n_slots and group != SORT_GROUP_LAST:
            k = order[base + t]
            offset = offsets[group * tiles + tile]
        before = int(-1)
        if ballot != 0:
            before = _group_scan_ballot(group, rounds)
            rounds += 1
        if before < 0:  # the twin, and the CPU
            before = wp.untile(wp.tile_scan_exclusive(wp.tile(_group_count_bit(group))))
        if t < n_slots and group != SORT_GROUP_LAST:
            rank = (before >> (SORT_COUNT_BITS * group)) & ((1 << SORT_COUNT_BITS) - 1)
            grouped[offset + rank] = k
        tile += grid


@wp.func
def photon_index(order: wp.array(dtype=wp.int32), use_order: int, tid: int) -> int:
    """The photon a thread traces: ``order[tid]`` when photons are sorted, else ``tid``."""
    if use_order != 0:
        return order[tid]
    return tid


MAX_WALK = wp.constant(64)  #: triangles a photon's sample may walk across from its texel's triangle
BARY_EXTRAPOLATION = wp.constant(0.5)  #: how far (barycentric units) past a boundary edge a sample extrapolates


@wp.func
def _corners(tri: int, geometry: SurfaceGeometry) -> wp.vec3i:
    """Triangle ``tri``'s vertex indices."""
    return wp.vec3i(geometry.indices[3 * tri + 0], geometry.indices[3 * tri + 1], geometry.indices[3 * tri + 2])


@wp.func
def _barycentrics(lo: wp.vec3, ld: wp.vec3, ind: wp.vec3i, geometry: SurfaceGeometry):
    """(b0, b1, b2, t, ok): the ray ``lo + ld·t`` cut with the plane of the triangle of vertices ``ind``, in its
    barycentrics."""
    p0 = geometry.points[ind[0]]
    e1 = geometry.points[ind[1]] - p0
    e2 = geometry.points[ind[2]] - p0
    pv = wp.cross(ld, e2)
    det = wp.dot(e1, pv)
    if wp.abs(det) <= 1.0e-12 * wp.length(ld) * wp.length(e1) * wp.length(e2):
        return 0.0, 0.0, 0.0, 0.0, int(0)
    inv = 1.0 / det
    sv = lo - p0
    b1 = wp.dot(sv, pv) * inv
    qv = wp.cross(sv, e1)
    b2 = wp.dot(ld, qv) * inv
    return 1.0 - b1 - b2, b1, b2, wp.dot(e2, qv) * inv, int(1)


@wp.func
def walk_to_sample(lo: wp.vec3, ld: wp.vec3, tri: int, geometry: SurfaceGeometry):
    """The triangle walk of :func:`surface_at_sample`: from triangle ``tri`` across edges towards where the ray
    ``lo + ld·t`` cuts the surface (to the neighbour opposite the most negative barycentric), until the cut lies
    inside, a boundary edge or ``MAX_WALK`` steps. Returns (ok: 0 when the ray lies in ``tri``'s plane, the last
    triangle, its barycentrics b0, b1, b2 and t of the cut, the steps walked, the last triangle's vertex indices)."""
    cur = tri
    ind = _corners(cur, geometry)
    b0, b1, b2, t, ok = _barycentrics(lo, ld, ind, geometry)
    step = int(0)
    if ok == 0:
        return int(0), cur, b0, b1, b2, t, step, ind
    while step < MAX_WALK:
        corner = int(0)
        bmin = b0
        if b1 < bmin:
            corner = 1
            bmin = b1
        if b2 < bmin:
            corner = 2
            bmin = b2
        if bmin >= 0.0:
            break
        nxt = geometry.neighbors[3 * cur + corner]
        if nxt < 0:
            break
        ind_n = _corners(nxt, geometry)
        c0, c1, c2, tc, okc = _barycentrics(lo, ld, ind_n, geometry)
        if okc == 0:
            break
        cur = nxt
        ind = ind_n
        b0 = c0
        b1 = c1
        b2 = c2
        t = tc
        step += 1
    return int(1), cur, b0, b1, b2, t, step, ind


@wp.func
def surface_at_sample(light: ViewParams, lo: wp.vec3, ld: wp.vec3, tri: int, texel: int,
                      rsm_depth: wp.array(dtype=wp.float32), geometry: SurfaceGeometry):
    """Where the light ray ``lo + ld·t`` meets the surface under it, and the vertex normals interpolated
    there: (point [m], unit normal). Sub-texel exact, so a texel's photons leave with the normals of the
    surface under their own sample points instead of one normal per texel.

    Starts on the RSM texel's triangle ``tri`` (what the texel's centre sees) and walks across edges
    towards the sample (:func:`walk_to_sample`) until the ray cuts the triangle inside, so texels larger than triangles are exact too. At a boundary edge (or after
    ``MAX_WALK`` steps) it keeps the last triangle's plane and the linear extension of its vertex
    normals up to ``BARY_EXTRAPOLATION`` outside, clamped onto the triangle beyond. A ray in a
    triangle's plane keeps the texel's point and normal as the RSM's resolve finds them (``kernels.texel_surface``
    of view ``light``'s texel, its triangle ``tri`` and depth ``rsm_depth[texel]``: computed only then, not for
    every photon; perf_notes sections 39 and 43).
    """
    ok, cur, b0, b1, b2, t, steps, ind = walk_to_sample(lo, ld, tri, geometry)
    if ok == 0:
        return texel_surface(light, texel, tri, rsm_depth[texel], geometry.points, geometry.normals, geometry.indices)
    p0 = geometry.points[ind[0]]
    p1 = geometry.points[ind[1]]
    p2 = geometry.points[ind[2]]
    x = lo + ld * t
    lim = -BARY_EXTRAPOLATION
    if b0 < lim or b1 < lim or b2 < lim:
        b1 = wp.clamp(b1, 0.0, 1.0)
        b2 = wp.clamp(b2, 0.0, 1.0 - b1)
        b0 = 1.0 - b1 - b2
        x = p0 * b0 + p1 * b1 + p2 * b2
    nrm = geometry.normals
    n = nrm[ind[0]] * b0 + nrm[ind[1]] * b1 + nrm[ind[2]] * b2
    ln = wp.length(n)
    if ln < 1.0e-12:
        x_t, n_t = texel_surface(light, texel, tri, 0.0, geometry.points, geometry.normals, geometry.indices)
        return x, n_t
    return x, n / ln


@wp.func
def emit_sample(
    light: ViewParams,
    light_kind: int,  # 0 distant, 1 point, 2 spot
    light_pos: wp.vec3,
    k: int,
    n_photons: int,
    scramble: wp.vec2i,
    rsm_depth: wp.array(dtype=wp.float32),
    rsm_emission: TexelEmission,  # its specular texels' flux, roughness and IOR from the light and materials (read)
    rsm_tri: wp.array(dtype=wp.int32),
    geometry: SurfaceGeometry,
    skip_window: wp.vec4,
    max_lum: float,
    roughness_cutoff: float,
    luminance_cutoff: float,
):
    """Photon k of an RSM view, booking nothing (:func:`emit_photon` books; ``kernels_cisp`` keeps the values
    instead of a tally). Returns (texel or -1 when none is emitted, power [W] as sampled, origin, incident
    direction, surface normal, entry): entry -1 when no texel is sampled (zero power), ``L_CULLED_ROUGH`` or
    ``L_CULLED_LUM`` when the sampled texel is culled (its power; texel -1, the rest zero), ``L_SAMPLED`` when the
    photon is emitted.

    ``geometry``: the scene's triangles (``DeviceScene.geometry``), read: the photon starts where the
    light ray through its sample point meets the surface, found from the texel's triangle, with the
    vertex normals interpolated there (:func:`surface_at_sample`). ``skip_window``: (x0, y0, x1, y1) in this view's
    pixels, the window a finer cascade samples; a sample inside it is left to that view (not sampled here, not
    booked); empty when x1 <= x0.
    """
    u = r2_point(k, scramble)
    sx = u[0] * float(light.width)
    sy = u[1] * float(light.height)
    i = wp.min(int(sx), light.width - 1)
    j = wp.min(int(sy), light.height - 1)
    texel = j * light.width + i
    zero = wp.vec3(0.0)
    tri = rsm_tri[texel]
    if tri < 0:
        return int(-1), zero, zero, zero, zero, int(-1)
    if sx >= skip_window[0] and sx < skip_window[2] and sy >= skip_window[1] and sy < skip_window[3]:
        return int(-1), zero, zero, zero, zero, int(-1)
    flux = texel_emitted_flux_at(rsm_emission, light, texel, i, j)
    power = flux * (float(light.width * light.height) / float(n_photons))
    if texel_roughness(rsm_emission, tri) > roughness_cutoff:
        return int(-1), power, zero, zero, zero, L_CULLED_ROUGH
    if luminance(flux) < luminance_cutoff * max_lum:
        return int(-1), power, zero, zero, zero, L_CULLED_LUM
    # origin and normal: the light ray through the sample point, cut with the texel's triangle
    lo, ld = pixel_ray_world(light, sx, sy)
    origin, n = surface_at_sample(light, lo, ld, tri, texel, rsm_depth, geometry)
    d_in = wp.normalize(ld)
    if light_kind != 0:
        d_in = wp.normalize(origin - light_pos)
    return texel, power, origin, d_in, n, L_SAMPLED


@wp.func
def emit_photon(
    light: ViewParams,
    light_kind: int,  # 0 distant, 1 point, 2 spot
    light_pos: wp.vec3,
    k: int,
    n_photons: int,
    scramble: wp.vec2i,
    rsm_depth: wp.array(dtype=wp.float32),
    rsm_emission: TexelEmission,  # its specular texels' flux, roughness and IOR from the light and materials (read)
    rsm_tri: wp.array(dtype=wp.int32),
    geometry: SurfaceGeometry,
    skip_window: wp.vec4,
    max_lum: float,
    roughness_cutoff: float,
    luminance_cutoff: float,
    tally: wp.ref[Tally],
):
    """Photon k of an RSM view (:func:`emit_sample`). Returns (texel or -1 when none is emitted, power [W], origin,
    incident direction, surface normal); books the power as sampled, and culled when the texel is culled."""
    texel, power, origin, d_in, n, entry = emit_sample(light, light_kind, light_pos, k, n_photons, scramble,
                                                       rsm_depth, rsm_emission, rsm_tri,
                                                       geometry, skip_window, max_lum, roughness_cutoff,
                                                       luminance_cutoff)
    if entry >= 0:
        book(tally, L_SAMPLED, power)
    if entry == L_CULLED_ROUGH:
        book(tally, L_CULLED_ROUGH, power)
        power = wp.vec3(0.0)
    elif entry == L_CULLED_LUM:
        book(tally, L_CULLED_LUM, power)
        power = wp.vec3(0.0)
    return texel, power, origin, d_in, n


OUTSIDE_ENTRIES = wp.constant(entry_mask(L_SAMPLED, L_OUTSIDE))  #: what book_outside_window books
OUTSIDE_SUBSAMPLES = wp.constant(4)  #: per axis: a pilot texel's area inside a turned window, from 4×4 points


@wp.func
def _pilot_texel_flux(views: wp.array(dtype=ViewParams), rsm_tri: wp.array(dtype=wp.int32),
                      rsm_emission: TexelEmission, view_index: int, p: int) -> wp.vec3:
    """Pilot texel ``p``'s flux [W] RGB as the resolve would write it (zero where no specular surface)."""
    f = wp.vec3(0.0)
    if rsm_tri[p] >= 0:
        f = texel_emitted_flux(rsm_emission, views[view_index], p)
    return f


@wp.func
def _outside_fraction(p: int, width: int, window: wp.vec4, angle: float, centre: wp.vec2, aspect: float) -> float:
    """The fraction of pilot texel ``p``'s area outside ``window`` (pilot pixels turned by ``angle`` about
    ``centre``): exact for an unturned window, from 4×4 points for a turned one."""
    i = float(p % width)
    j = float(p / width)
    inside = float(0.0)
    if angle == 0.0:
        ox = wp.max(wp.min(i + 1.0, window[2]) - wp.max(i, window[0]), 0.0)
        oy = wp.max(wp.min(j + 1.0, window[3]) - wp.max(j, window[1]), 0.0)
        inside = ox * oy
    else:
        c = wp.cos(angle)
        s = wp.sin(angle)
        for a in range(OUTSIDE_SUBSAMPLES):
            for b in range(OUTSIDE_SUBSAMPLES):
                dx = i + (float(a) + 0.5) / float(OUTSIDE_SUBSAMPLES) - centre[0]
                dy = j + (float(b) + 0.5) / float(OUTSIDE_SUBSAMPLES) - centre[1]
                u = centre[0] + c * dx - s * aspect * dy
                v = centre[1] + s * dx / aspect + c * dy
                if u >= window[0] and u < window[2] and v >= window[1] and v < window[3]:
                    inside += 1.0 / float(OUTSIDE_SUBSAMPLES * OUTSIDE_SUBSAMPLES)
    return 1.0 - inside


@wp.func
def _book_outside(tally: wp.ref[Tally], f: wp.vec3, outside: float):
    """Book a texel's flux ``f`` [W] times its fraction ``outside`` as sampled and ``outside_fitted_view``."""
    if outside > 0.0 and f[0] + f[1] + f[2] > 0.0:
        book(tally, L_SAMPLED, f * outside)
        book(tally, L_OUTSIDE, f * outside)


@wp.kernel(enable_backward=False)  # books into a tally by reference
def book_outside_window(
    views: wp.array(dtype=ViewParams),  # (V,) the pilot views (LightMaps.pilot_views, read)
    rsm_tri: wp.array(dtype=wp.int32),  # (P*P,) pilot view ``view_index``'s specular layer's triangle, -1 none (read)
    rsm_emission: TexelEmission,  # its specular texels' flux from the light (read)
    width: int,
    count: int,  # texels
    windows: wp.array(dtype=wp.vec4),  # (V,) per pilot view (x0, y0, x1, y1) sampled by the cascades, in its pixels
    # turned by ``angles``; empty when x1 <= x0 (LightMaps.outside, read)
    angles: wp.array(dtype=wp.float32),  # (V,) [rad] (views.rotate_pixels; LightMaps.outside_angle, read)
    view_index: int,  # this pilot view
    centre: wp.vec2,  # the pilot view's principal point [pixels]
    aspect: float,  # the pilot view's fx / fy
    ledger: wp.array(dtype=wp.vec3d),  # (LEDGER_ENTRIES,) power [W] per entry, RGB (accumulate)
):
    """Book the power of each pilot texel's area outside ``window`` as sampled and ``outside_fitted_view``
    (one thread per texel, tallied and added once per block, as the photon kernels do). Unturned windows
    cut texels exactly; a turned one is measured on 4×4 points per texel. With :func:`max_luminance` the twin of
    :func:`pilot_texel_pass`."""
    window = windows[view_index]
    angle = angles[view_index]
    block, lane = wp.tid()
    p = block * wp.block_dim() + lane
    tally = tally_new()
    if p < count:
        f = _pilot_texel_flux(views, rsm_tri, rsm_emission, view_index, p)
        _book_outside(tally, f, _outside_fraction(p, width, window, angle, centre, aspect))
    ledger_add(ledger, tally, block, OUTSIDE_ENTRIES)


@wp.kernel(enable_backward=False)  # books into a tally by reference
def pilot_texel_pass(
    views: wp.array(dtype=ViewParams),  # (V,) the pilot views (LightMaps.pilot_views, read)
    rsm_tri: wp.array(dtype=wp.int32),  # (P*P,) pilot view ``view_index``'s specular layer's triangle, -1 none (read)
    rsm_emission: TexelEmission,  # its specular texels' flux from the light (read)
    width: int,
    count: int,  # texels
    windows: wp.array(dtype=wp.vec4),  # (V,) LightMaps.outside (read), as book_outside_window's
    angles: wp.array(dtype=wp.float32),  # (V,) LightMaps.outside_angle (read)
    view_index: int,  # this pilot view
    centre: wp.vec2,  # the pilot view's principal point [pixels]
    aspect: float,  # the pilot view's fx / fy
    ledger: wp.array(dtype=wp.vec3d),  # the striped ledger, power [W] per entry, RGB (accumulate)
    max_lum: wp.array(dtype=wp.float32),  # (1,) the light's brightest whole-view texel luminance [W] (atomic max;
    # zeroed by the caller)
):
    """A fitted light's pilot view in one pass, one thread per texel (blocks of ``LEDGER_BLOCK``): each texel's flux
    computed once for both :func:`max_luminance` (the block's maximum as a tile, one ``atomic_max`` a block) and
    :func:`book_outside_window` (its area outside the coarsest window booked, tallied and added once per block). The
    same maximum and bookings as those two launches (their twin), in one launch spread over the whole GPU: 16k texels
    of a 128² pilot are 128 blocks, where ``max_luminance``'s 16 texels a thread made 4 blocks on 4 SMs. Its two
    entries (sampled, outside) hold the same value: one block sum for both (section 77)."""
    window = windows[view_index]
    angle = angles[view_index]
    block, lane = wp.tid()
    p = block * wp.block_dim() + lane
    tally = tally_new()
    m = float(0.0)
    if p < count:
        f = _pilot_texel_flux(views, rsm_tri, rsm_emission, view_index, p)
        if rsm_tri[p] >= 0:
            m = wp.max(m, luminance(f))
        _book_outside(tally, f, _outside_fraction(p, width, window, angle, centre, aspect))
    block_max = wp.tile_max(wp.tile(m))
    # the two entries it books are the same value (_book_outside): summed once, added to both (ledger_add sums each
    # apart: the same sums, one block reduction more)
    sampled = wp.vec3d(tally.sampled[0], tally.sampled[1], tally.sampled[2])
    booked = wp.tile_extract(wp.tile_sum(wp.tile(sampled, preserve_type=True)), 0)
    if lane == 0:
        wp.atomic_max(max_lum, 0, block_max[0])
        wp.atomic_add(ledger, ledger_slot(ledger, block, L_SAMPLED), booked)
        wp.atomic_add(ledger, ledger_slot(ledger, block, L_OUTSIDE), booked)


@wp.func
def specular_scatter(d_in: wp.vec3, n: wp.vec3, transmissive: int, ior: float, albedo: wp.vec3, power: wp.vec3,
                     state: wp.uint32):
    """Scatter a photon off a smooth surface, booking nothing. Returns (direction, power kept, refracted 0/1, rng
    state). Dielectric: reflect with probability F(θ), else refract (power unchanged either way). Metal: reflect,
    keeping albedo × power; the rest, ``power - kept``, is absorbed (:func:`specular_bounce` books it)."""
    nn = n
    eta = ior
    if wp.dot(d_in, n) > 0.0:  # arriving from inside the medium
        nn = -n
        eta = 1.0 / ior
    if transmissive != 0:
        f = fresnel_dielectric(-wp.dot(d_in, nn), eta)
        if wp.randf(state) < f:
            return reflect(d_in, nn), power, int(0), state
        return refract(d_in, nn, eta), power, int(1), state
    return reflect(d_in, nn), wp.cw_mul(power, albedo), int(0), state


@wp.func
def specular_bounce(d_in: wp.vec3, n: wp.vec3, transmissive: int, ior: float, albedo: wp.vec3, power: wp.vec3,
                    state: wp.uint32, tally: wp.ref[Tally]):
    """Scatter a photon off a smooth surface (:func:`specular_scatter`). Returns (direction, power, refracted 0/1,
    rng state). Dielectric: reflect with probability F(θ), else refract (power unchanged either way). Metal:
    reflect, keeping albedo × power; the rest is booked as absorbed.
    """
    d, kept, refracted, state = specular_scatter(d_in, n, transmissive, ior, albedo, power, state)
    if transmissive == 0:
        book(tally, L_ABSORBED, power - kept)
    return d, kept, refracted, state


@wp.func
def emit_and_bounce(
    light: ViewParams,
    light_kind: int,
    light_pos: wp.vec3,
    k: int,
    n_photons: int,
    scramble: wp.vec2i,
    seed: int,
    rsm_depth: wp.array(dtype=wp.float32),
    rsm_emission: TexelEmission,  # its specular texels' flux, roughness and IOR from the light and materials (read)
    rsm_tri: wp.array(dtype=wp.int32),
    geometry: SurfaceGeometry,
    skip_window: wp.vec4,
    triangle_material: wp.array(dtype=wp.int32),
    mat_opacity: wp.array(dtype=wp.float32),
    mat_albedo: wp.array(dtype=wp.vec3),
    max_lum: float,
    roughness_cutoff: float,
    luminance_cutoff: float,
    tally: wp.ref[Tally],
):
    """Photon k of an RSM view, emitted (:func:`emit_photon`) and scattered by the specular surface it
    starts on (:func:`specular_bounce`), all booked. Returns (texel or -1 when none, power [W] after the
    bounce, origin [m], surface normal, outgoing direction, rng state)."""
    texel, power, origin, d_in, n = emit_photon(light, light_kind, light_pos, k, n_photons, scramble, rsm_depth,
                                                rsm_emission, rsm_tri, geometry, skip_window,
                                                max_lum, roughness_cutoff, luminance_cutoff, tally)
    state = wp.rand_init(seed, k)
    if texel < 0:
        return texel, power, origin, n, d_in, state
    tri = rsm_tri[texel]
    m = triangle_material[tri]
    d, power, refracted, state = specular_bounce(d_in, n, int(mat_opacity[m] < 1.0), texel_ior(rsm_emission, tri),
                                                 mat_albedo[m], power, state, tally)
    book_bounce(tally, refracted, power)
    return texel, power, origin, n, d, state


@wp.func
def book_bounce(tally: wp.ref[Tally], refracted: int, power: wp.vec3):
    if refracted != 0:
        book(tally, L_REFRACTED, power)
    else:
        book(tally, L_REFLECTED, power)


@wp.func
def pixel_footprint(camera: ViewParams, pixel_solid_angle: float, x: wp.vec3, n: wp.vec3, mode: int) -> float:
    """World-space area [m²] of the receiving surface that camera pixel covers.

    Exact: A = Ω_p · r² / |cos θ|, with Ω_p the pixel's exact solid angle, r the distance from the
    eye and θ the angle between the surface normal and the view ray (orthographic: 1/(fx·fy)/|cos θ|).
    Paper (seed 000, after Kim 2019): A = (2 r tan(θx/2)/w)(2 r tan(θy/2)/h) = r²/(fx·fy), no cosine.
    """
    eye_dir = wp.vec3(0.0)
    r2 = float(0.0)
    if camera.orthographic != 0:
        eye_dir = wp.transform_vector(camera.view_to_world, wp.vec3(0.0, 0.0, 1.0))
    else:
        to_eye = wp.transform_point(camera.view_to_world, wp.vec3(0.0)) - x
        r2 = wp.dot(to_eye, to_eye)
        eye_dir = to_eye / wp.sqrt(r2)
    if mode == FOOTPRINT_PAPER:
        if camera.orthographic != 0:
            return 1.0 / (camera.fx * camera.fy)
        return r2 / (camera.fx * camera.fy)
    cos_t = wp.max(wp.abs(wp.dot(n, eye_dir)), 1.0e-6)
    if camera.orthographic != 0:
        return 1.0 / (camera.fx * camera.fy * cos_t)
    return pixel_solid_angle * r2 / cos_t


@wp.func
def deposit(camera: ViewParams, pix: int, d: wp.vec3, power: wp.vec3,
            cam_depth: wp.array(dtype=wp.float32), cam_position: wp.array(dtype=wp.vec3),
            cam_normal: wp.array(dtype=wp.vec3), cam_solid_angle: wp.array(dtype=wp.float32),
            footprint_mode: int, photon_map: wp.array(dtype=wp.vec3), photon_m2: wp.array(dtype=wp.float32),
            tally: wp.ref[Tally]) -> int:
    """Validate a photon arriving along ``d`` at camera pixel ``pix`` and add its irradiance e to ``photon_map``
    and, unless ``photon_m2`` is empty (None), luminance(e)² to ``photon_m2`` ((H*W,) float32 [(W/m²)²], accumulate):
    the frame's own Monte-Carlo variance of the pixel's luminance, since the map is a sum of independent photons'
    e (Var Σ e_i ≈ Σ e_i², high by the pixel's squared mean over the photons, negligible). 1 if stored."""
    nr = cam_normal[pix]
    if wp.dot(-d, nr) < 0.0 or cam_depth[pix] <= 0.0:
        book(tally, L_REJECTED, power)
        return 0
    area = pixel_footprint(camera, cam_solid_angle[pix], cam_position[pix], nr, footprint_mode)
    e = power / area
    if footprint_mode == FOOTPRINT_PAPER:
        e = e * wp.dot(-d, nr)
    wp.atomic_add(photon_map, pix, e)
    if photon_m2.shape[0] > 0:
        l = luminance(e)
        wp.atomic_add(photon_m2, pix, l * l)
    book(tally, L_STORED, power)
    return 1
