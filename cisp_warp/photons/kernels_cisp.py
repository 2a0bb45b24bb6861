"""Warp kernels of Cascaded Image-Space Photon Tracing (seed 000, section 3).

One thread per photon: sample an RSM texel, bounce by exact Fresnel, march the light view,
reproject into the camera view, march on there, validate, and add irradiance to the photon map.
Every photon's power ends in exactly one ledger entry, tallied per thread and added once per block.
"""

from __future__ import annotations

import warp as wp

from ..scene.device import SurfaceGeometry
from ..raster.kernels import TexelEmission, texel_ior
from ..raster.light_maps import CascadeState, cascade_photons
from ..raster.views import ViewParams, fixed_projection, read_again, world_project
from .common import (L_ABSORBED, L_CULLED_LUM, L_CULLED_ROUGH, L_LOST_CAMERA, L_LOST_LIGHT, L_OCCLUDED, L_REFLECTED,
                     L_REFRACTED, L_REJECTED, L_SAMPLED, L_STEPS, L_STORED, PHOTON_LAUNCH_BOUNDS, Tally, book, deposit,
                     emit_sample, entry_mask, ledger_slot, record_outcome, photon_index, specular_scatter, tally_new)
from .caustic_flow import add_landing, flow_cell
from .hidden_flux import store_hidden
from .march import (MARCH_HIDDEN, MARCH_HIT, MARCH_STEPS, WORK_TESTS, bounded_march, counted_marches,
                    screen_march_bounded, screen_march_bounded_plain, surface_far)

wp.set_module_options({"enable_backward": False})  # forward only (the ledger's tallies are passed by reference)

#: the ways a CISP photon ends after its bounce (trace_photon and deposit book nothing else): added per block by
#: trace_photons' epilogue (final_add), or (the twin) written to its outcome record and added by ledger_add_outcomes
CISP_FINAL_ENTRIES = entry_mask(L_LOST_LIGHT, L_LOST_CAMERA, L_OCCLUDED, L_REJECTED, L_STEPS, L_STORED)

#: the emission's six entries (EMISSION_ENTRIES: sampled, culled by roughness, by luminance, absorbed, reflected,
#: refracted) side by side, RGB each: one block reduction for all of them (emission_add)
vec18d = wp.types.vector(length=18, dtype=wp.float64)


@wp.func
def _add_entry(ledger: wp.array(dtype=wp.vec3d), block: int, entry: int, s: vec18d, i: int):
    """Add entry ``entry``, values ``3i``..``3i+2`` of the block's sums ``s``, to the block's ledger stripe."""
    wp.atomic_add(ledger, ledger_slot(ledger, block, entry), wp.vec3d(s[3 * i], s[3 * i + 1], s[3 * i + 2]))


#: CUDA only (blocks of whole warps): the block's sums of ``v`` (18 doubles a thread) by a reduce-scatter in each warp
#: (rounds of 9, 5, 3, 2 and 1 shuffles at lane distances 16..1, a lane keeping the half of its values its bit
#: selects and adding its partner's copy of that half: 20 shuffled doubles instead of Warp's 5 x 18, none looping
#: over a vector kept in local memory), each lane left with one value's warp sum (lane bits -> value
#: 9*b4 + 5*b3 + 3*b2 + 2*b1 + b0 where the bits do not select padding), written to shared memory; one barrier;
#: thread i < 18 then adds the warps' sums of value i in warp order and adds it to the ledger (one float64 atomic a
#: thread, all 18 in one instruction of warp 0). Deterministic within a block (a fixed tree); the ledger's stripes
#: take the blocks' adds in any order, as before. On the CPU (or blocks of a partial warp) it returns 0 and
#: :func:`emission_add` sums with Warp's tiles (the CPU's blocks are one thread, or fibers with
#: ``enable_cpu_blocks``).
_EMISSION_REDUCE = """
#if defined(__CUDA_ARCH__) && (WP_TILE_BLOCK_DIM % 32 == 0)
constexpr int NW = WP_TILE_BLOCK_DIM / 32;
__shared__ double emission_partials[NW][18];
const unsigned FULL = 0xffffffffu;
const int lane = threadIdx.x & 31;
const int warp = threadIdx.x >> 5;
double a[10];
{
    const bool h = (lane & 16) != 0;
    #pragma unroll
    for (int i = 0; i < 9; ++i) {
        const double send = h ? v.c[i] : v.c[i + 9];
        const double keep = h ? v.c[i + 9] : v.c[i];
        a[i] = keep + __shfl_xor_sync(FULL, send, 16);
    }
    a[9] = 0.0;
}
double b[6];
{
    const bool h = (lane & 8) != 0;
    #pragma unroll
    for (int i = 0; i < 5; ++i) {
        const double send = h ? a[i] : a[i + 5];
        const double keep = h ? a[i + 5] : a[i];
        b[i] = keep + __shfl_xor_sync(FULL, send, 8);
    }
    b[5] = 0.0;
}
double c[4];
{
    const bool h = (lane & 4) != 0;
    #pragma unroll
    for (int i = 0; i < 3; ++i) {
        const double send = h ? b[i] : b[i + 3];
        const double keep = h ? b[i + 3] : b[i];
        c[i] = keep + __shfl_xor_sync(FULL, send, 4);
    }
    c[3] = 0.0;
}
double d[2];
{
    const bool h = (lane & 2) != 0;
    #pragma unroll
    for (int i = 0; i < 2; ++i) {
        const double send = h ? c[i] : c[i + 2];
        const double keep = h ? c[i + 2] : c[i];
        d[i] = keep + __shfl_xor_sync(FULL, send, 2);
    }
}
double e;
{
    const bool h = (lane & 1) != 0;
    const double send = h ? d[0] : d[1];
    const double keep = h ? d[1] : d[0];
    e = keep + __shfl_xor_sync(FULL, send, 1);
}
const int b0 = lane & 1, b1 = (lane >> 1) & 1, b2 = (lane >> 2) & 1, b3 = (lane >> 3) & 1, b4 = (lane >> 4) & 1;
const int i3 = 2 * b1 + b0;   // index into c (3 values and a pad)
const int i2 = 3 * b2 + i3;   // into b (5 and a pad)
const int i1 = 5 * b3 + i2;   // into a (9 and a pad)
if (i3 < 3 && i2 < 5 && i1 < 9)
    emission_partials[warp][9 * b4 + i1] = e;
__syncthreads();
if (threadIdx.x < 18) {
    const int i = threadIdx.x;
    double s = emission_partials[0][i];
    #pragma unroll
    for (int w = 1; w < NW; ++w)
        s += emission_partials[w][i];
    const int q = i / 3;
    const int entry = q == 0 ? e0 : q == 1 ? e1 : q == 2 ? e2 : q == 3 ? e3 : q == 4 ? e4 : e5;
    double* p = reinterpret_cast<double*>(wp::address(ledger, stripe + entry));
    atomicAdd(p + (i - 3 * q), s);
}
return 1;
#else
return 0;
#endif
"""


@wp.func_native(_EMISSION_REDUCE)
def _emission_reduce(ledger: wp.array(dtype=wp.vec3d), stripe: int, v: vec18d, e0: int, e1: int, e2: int, e3: int,
                     e4: int, e5: int) -> int:
    """On CUDA (blocks of whole warps): the block's sums of ``v`` added to entries ``e0``..``e5`` (three values
    each) of the ledger's row ``stripe`` (see ``_EMISSION_REDUCE``); returns 1. Elsewhere it does nothing and
    returns 0."""
    ...


@wp.func
def _vec18(a: wp.vec3, b: wp.vec3, c: wp.vec3, d: wp.vec3, f: wp.vec3, g: wp.vec3) -> vec18d:
    """Six RGB values in float64, in order: what :func:`emission_add` and :func:`final_add` reduce."""
    return vec18d(wp.float64(a[0]), wp.float64(a[1]), wp.float64(a[2]), wp.float64(b[0]), wp.float64(b[1]),
                  wp.float64(b[2]), wp.float64(c[0]), wp.float64(c[1]), wp.float64(c[2]), wp.float64(d[0]),
                  wp.float64(d[1]), wp.float64(d[2]), wp.float64(f[0]), wp.float64(f[1]), wp.float64(f[2]),
                  wp.float64(g[0]), wp.float64(g[1]), wp.float64(g[2]))


@wp.func
def _tile_add18(ledger: wp.array(dtype=wp.vec3d), block: int, lane: int, v: vec18d, e0: int, e1: int, e2: int,
                e3: int, e4: int, e5: int):
    """Where the warp reduce-scatter does not run (the CPU, blocks of a partial warp): ``v`` summed over the block
    with Warp's tiles and added by its first thread to entries ``e0``..``e5`` (three values each), in that order."""
    s = wp.tile_extract(wp.tile_sum(wp.tile(v, preserve_type=True)), 0)
    if lane == 0:
        _add_entry(ledger, block, e0, s, 0)
        _add_entry(ledger, block, e1, s, 1)
        _add_entry(ledger, block, e2, s, 2)
        _add_entry(ledger, block, e3, s, 3)
        _add_entry(ledger, block, e4, s, 4)
        _add_entry(ledger, block, e5, s, 5)


@wp.func
def emission_add(ledger: wp.array(dtype=wp.vec3d), block: int, lane: int, entry: int, sampled: wp.vec3,
                 absorbed: wp.vec3, power: wp.vec3, refracted: int):
    """The emission's ledger entries (``EMISSION_ENTRIES``) of the block's photons from what each thread kept of
    its emission and bounce (:func:`emit_and_scatter`: ``entry`` -1 none sampled, ``L_CULLED_*`` culled,
    ``L_SAMPLED`` emitted; the power as sampled, absorbed at a metal, and after the bounce): all six summed in
    float64 over the block in one reduction (18 values), added once a block. These are the values
    ``emit_and_bounce`` books into a tally and ``ledger_add(..., EMISSION_ENTRIES)`` adds, each at most once a
    photon, so a float32 value converted equals the float64 tally's sum (on the CPU, a block of one thread: the same
    adds bit for bit); no tally is held through the emission, and one reduction replaces six (docs/perf_notes.md
    section 39). On CUDA the reduction is :func:`_emission_reduce` (a reduce-scatter: section 64), elsewhere one
    tile reduction of a ``vec18d`` added by the block's first thread in entry order. Every thread of the block calls
    it (no early return before it)."""
    zero = wp.vec3(0.0)
    a = sampled
    b = wp.where(entry == L_CULLED_ROUGH, sampled, zero)
    c = wp.where(entry == L_CULLED_LUM, sampled, zero)
    d = absorbed
    emitted = entry == L_SAMPLED
    f = wp.where(emitted and refracted == 0, power, zero)
    g = wp.where(emitted and refracted != 0, power, zero)
    v = _vec18(a, b, c, d, f, g)
    if _emission_reduce(ledger, ledger_slot(ledger, block, 0), v, L_SAMPLED, L_CULLED_ROUGH, L_CULLED_LUM,
                        L_ABSORBED, L_REFLECTED, L_REFRACTED) == 0:
        _tile_add18(ledger, block, lane, v, L_SAMPLED, L_CULLED_ROUGH, L_CULLED_LUM, L_ABSORBED, L_REFLECTED,
                    L_REFRACTED)


#: CUDA only: the block's sums of the trace's final entries, ``_EMISSION_REDUCE``'s reduce-scatter with its first round
#: on the records themselves: a thread holds one final entry (``slot`` 0..5 of the six contiguous entries from
#: ``e0``; anything else: none) and its power (float32 RGB), so at lane distance 16 a lane exchanges its record with
#: its partner (4 shuffled words instead of 9 doubles) and makes the 9 values its lane bit keeps (entries 3h..3h+2)
#: as its own share plus its partner's, converted to float64: the same sums, added in the same order, as the
#: 18-double round (own value + partner's), without the 18 doubles held before it. Then rounds 8..1 and the warps'
#: sums as ``_EMISSION_REDUCE`` (its own shared partials: a warp that reaches the epilogue early must not overwrite
#: the emission's while warp 0 still sums them), thread i < 18 adding value i to entry e0 + i / 3.
_FIRST_ROUND = """double a[10];
{
    const bool h = (lane & 16) != 0;
    #pragma unroll
    for (int i = 0; i < 9; ++i) {
        const double send = h ? v.c[i] : v.c[i + 9];
        const double keep = h ? v.c[i + 9] : v.c[i];
        a[i] = keep + __shfl_xor_sync(FULL, send, 16);
    }
    a[9] = 0.0;
}"""
_FIRST_ROUND_RECORDS = """double a[10];
{
    const int base = (lane & 16) != 0 ? 3 : 0;
    const int slot_o = __shfl_xor_sync(FULL, slot, 16);
    float p_o[3];
    #pragma unroll
    for (int c = 0; c < 3; ++c)
        p_o[c] = __shfl_xor_sync(FULL, p.c[c], 16);
    #pragma unroll
    for (int k = 0; k < 3; ++k) {
        #pragma unroll
        for (int c = 0; c < 3; ++c)
            a[3 * k + c] = (slot == base + k ? (double)p.c[c] : 0.0) + (slot_o == base + k ? (double)p_o[c] : 0.0);
    }
    a[9] = 0.0;
}"""
_ENTRY_OF_VALUE = "const int entry = q == 0 ? e0 : q == 1 ? e1 : q == 2 ? e2 : q == 3 ? e3 : q == 4 ? e4 : e5;"
assert _EMISSION_REDUCE.count(_FIRST_ROUND) == 1 and _EMISSION_REDUCE.count(_ENTRY_OF_VALUE) == 1
_FINAL_REDUCE = (_EMISSION_REDUCE.replace("emission_partials", "final_partials")
                 .replace(_FIRST_ROUND, _FIRST_ROUND_RECORDS).replace(_ENTRY_OF_VALUE, "const int entry = e0 + q;"))
# the six final entries are contiguous (_final_reduce and final_add number them from L_LOST_LIGHT)
assert CISP_FINAL_ENTRIES == entry_mask(*range(int(L_LOST_LIGHT), int(L_STORED) + 1))


@wp.func_native(_FINAL_REDUCE)
def _final_reduce(ledger: wp.array(dtype=wp.vec3d), stripe: int, slot: int, p: wp.vec3, e0: int) -> int:
    """On CUDA (blocks of whole warps): the block's sums of each thread's power ``p`` under its entry ``e0 + slot``
    (``slot`` 0..5; anything else adds nothing) added to entries ``e0``..``e0 + 5`` of the ledger's row ``stripe``
    (see ``_FINAL_REDUCE``); returns 1. Elsewhere it does nothing and returns 0."""
    ...


@wp.func
def final_add(ledger: wp.array(dtype=wp.vec3d), block: int, lane: int, entry: int, power: wp.vec3):
    """The block's final entries (``CISP_FINAL_ENTRIES``: lost from the light view, from the camera view,
    occluded, rejected, out of steps, stored) from each thread's one final entry and its power (the tally's
    ``entry``, -1 none, and ``power``): six entries × RGB summed in float64 over the block in one reduction and
    added once a block, as :func:`emission_add` adds the emission's, in the trace's epilogue instead of an outcome
    record a photon and ``ledger_add_outcomes`` after the trace (``PhotonPass.FOLDED_OUTCOMES``, docs/perf_notes.md
    section 79). The trace's one photon a thread holds nothing across a loop: the 18 doubles are made here from
    four registers. On the CPU (blocks of one thread) each photon's entry is added in photon order, as the outcome
    pass added its record: the same adds bit for bit. Every thread of the block calls it (no early return before
    it)."""
    if _final_reduce(ledger, ledger_slot(ledger, block, 0), entry - L_LOST_LIGHT, power, L_LOST_LIGHT) == 0:
        zero = wp.vec3(0.0)
        a = wp.where(entry == L_LOST_LIGHT, power, zero)
        b = wp.where(entry == L_LOST_CAMERA, power, zero)
        c = wp.where(entry == L_OCCLUDED, power, zero)
        d = wp.where(entry == L_REJECTED, power, zero)
        f = wp.where(entry == L_STEPS, power, zero)
        g = wp.where(entry == L_STORED, power, zero)
        _tile_add18(ledger, block, lane, _vec18(a, b, c, d, f, g), L_LOST_LIGHT, L_LOST_CAMERA, L_OCCLUDED,
                    L_REJECTED, L_STEPS, L_STORED)


@wp.func
def emit_and_scatter(
    light: ViewParams,
    light_kind: int,
    light_pos: wp.vec3,
    k: int,
    n_photons: int,
    scramble: wp.vec2i,
    seed: int,
    rsm_depth: wp.array(dtype=wp.float32),  # specular layer: depth [m] (point, normal: texel_surface)
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
):
    """``emit_and_bounce`` without a tally: photon k emitted (:func:`~.common.emit_sample`) and scattered by its
    specular surface (:func:`~.common.specular_scatter`). Returns (texel or -1 when none, power [W] after the
    bounce, origin [m], surface normal, outgoing direction, rng state, entry, power as sampled, power absorbed,
    refracted 0/1): what :func:`emission_add` books."""
    texel, sampled, origin, d_in, n, entry = emit_sample(light, light_kind, light_pos, k, n_photons, scramble,
                                                         rsm_depth, rsm_emission, rsm_tri,
                                                         geometry, skip_window, max_lum, roughness_cutoff,
                                                         luminance_cutoff)
    state = wp.rand_init(seed, k)
    zero = wp.vec3(0.0)
    if texel < 0:
        return texel, zero, origin, n, d_in, state, entry, sampled, zero, int(0)
    tri = rsm_tri[texel]
    m = triangle_material[tri]
    transmissive = int(mat_opacity[m] < 1.0)
    d, power, refracted, state = specular_scatter(d_in, n, transmissive, texel_ior(rsm_emission, tri), mat_albedo[m],
                                                  sampled, state)
    absorbed = zero
    if transmissive == 0:
        absorbed = sampled - power
    return texel, power, origin, n, d, state, entry, sampled, absorbed, refracted


@wp.func
def march_light(
    light: ViewParams,
    rsm_opaque_depth: wp.array(dtype=wp.float32),  # (H_l*W_l,) the light view's opaque depth [m] (read)
    rsm_depth_bounds: wp.array(dtype=wp.vec2),  # its march.depth_bounds (read)
    origin: wp.vec3,  # [m] where the photon leaves the specular surface
    d: wp.vec3,  # unit direction after the bounce
    t_max: float,
    max_steps: int,
    thickness: float,
    thickness_rel: float,
):
    """Step 4 of seed 000 for one photon: march the light view's opaque depth from a hair off the surface.
    Returns (march status, end point [m]): the crossing on ``MARCH_HIT``, else the last point inside the view."""
    o = origin + d * (1.0e-4 * t_max)
    status, t_end, steps = screen_march_bounded_plain(light, rsm_opaque_depth, rsm_depth_bounds, o, d, t_max,
                                                       max_steps, thickness, thickness_rel)  # no back-face layer
    return status, o + d * t_end


#: :func:`reproject_to_camera`'s answer for a photon floating in front of the camera's surfaces (not a ledger entry)
MARCH_ON = wp.constant(-1)


@wp.func
def reproject_to_camera(
    camera: ViewParams,
    cam_depth: wp.array(dtype=wp.float32),  # (H*W,) the camera's opaque depth [m] (read)
    status: int,  # what :func:`march_light` returned
    x_end: wp.vec3,  # [m] where the light-view march ended
    thickness: float,
    thickness_rel: float,
    use_cascade: int,  # 0: light view only (no camera march)
):
    """Step 5 of seed 000, the cascade (Fig. 7): where the light-view march that ended at ``x_end`` with ``status``
    lands in the camera view. Returns (entry, camera pixel): ``L_STORED`` on the surface pixel ``pix`` shows (a
    light-view crossing within the thickness of it), ``MARCH_ON`` floating in front of the camera's surfaces or a
    light-view miss within their thickness (march on in the camera view: :func:`camera_marches`),
    else the ledger entry where the photon was lost (``L_STEPS``, ``L_LOST_*``, ``L_OCCLUDED``)."""
    if status == MARCH_STEPS:
        return L_STEPS, int(-1)
    q = world_project(camera, x_end)
    inside = q[2] > camera.near and q[0] >= 0.0 and q[1] >= 0.0 and q[0] < float(camera.width) and q[1] < float(camera.height)
    if not inside:
        if status == MARCH_HIT:
            return L_LOST_CAMERA, int(-1)
        return L_LOST_LIGHT, int(-1)
    pix = int(q[1]) * camera.width + int(q[0])
    zc = cam_depth[pix]
    tol = thickness + thickness_rel * zc
    # behind the surface's far side (a point on a closed object's far half: hidden, march.surface_far)
    if zc > 0.0 and q[2] > surface_far(camera, cam_depth, pix, zc, thickness, thickness_rel):
        return L_OCCLUDED, pix
    if zc > 0.0 and q[2] >= zc - tol and status == MARCH_HIT:
        return L_STORED, pix
    # a miss ends in the air (where the ray left the light view), on no surface even within the thickness of one:
    # the camera march finds where it lands (stored here, a ray leaving the light view a few cm before a wall
    # landed that far short of it)
    if use_cascade == 0:
        return L_LOST_LIGHT, int(-1)
    return MARCH_ON, int(-1)


@wp.func
def _camera_entry(status: int) -> int:
    """The entry of a photon whose cascade march in the camera view (pass 0 of :func:`camera_marches`) ended with
    ``status``."""
    if status == MARCH_STEPS:
        return L_STEPS
    if status == MARCH_HIDDEN:  # it ends on a closed object's far side, which the camera does not see
        return L_OCCLUDED
    if status != MARCH_HIT:
        return L_LOST_CAMERA
    return L_STORED


@wp.func
def camera_pixel(camera: ViewParams, x: wp.vec3) -> int:
    """The camera pixel a camera-march crossing ``x`` [m] lies in (clamped to the image)."""
    q = world_project(camera, x)
    return wp.clamp(int(q[1]), 0, camera.height - 1) * camera.width + wp.clamp(int(q[0]), 0, camera.width - 1)


#: one receiver: normals within ~26° (a refined landing's pixel; the wavefront splat's corners and covered pixels)
NORMAL_COS = wp.constant(0.9)


@wp.func
def refine_landing(
    camera: ViewParams,
    cam_depth: wp.array(dtype=wp.float32),
    cam_position: wp.array(dtype=wp.vec3),
    cam_normal: wp.array(dtype=wp.vec3),
    origin: wp.vec3,  # [m] where the photon left the specular surface
    d: wp.vec3,  # its direction
    x_end: wp.vec3,  # [m] where the march put it
    pix: int,  # camera pixel of x_end
    thickness: float,
    thickness_rel: float,
):
    """The photon's ray cut with the tangent plane of the surface camera pixel ``pix`` shows (its G-buffer
    position and normal). A march lands within a depth texel of the surface (nearest-texel depth, linear
    between two steps): points that scatter by that much scatter a wavefront's triangle areas, where a point
    photon's noise hides it. Kept only where the cut stays on the same surface within the thickness;
    returns (landing point [m], its camera pixel)."""
    n = cam_normal[pix]
    den = wp.dot(d, n)
    if den >= -1.0e-6:
        return x_end, pix
    t = wp.dot(cam_position[pix] - origin, n) / den
    x = origin + d * t
    tol = thickness + thickness_rel * cam_depth[pix]
    if t <= 0.0 or wp.length(x - x_end) > tol:
        return x_end, pix
    q = world_project(camera, x)
    if q[2] <= camera.near or q[0] < 0.0 or q[1] < 0.0 or q[0] >= float(camera.width) or q[1] >= float(camera.height):
        return x_end, pix
    pix2 = int(q[1]) * camera.width + int(q[0])
    z2 = cam_depth[pix2]
    if z2 <= 0.0 or wp.dot(cam_normal[pix2], n) < NORMAL_COS:
        return x_end, pix
    if wp.abs(wp.dot(x - cam_position[pix2], cam_normal[pix2])) > thickness + thickness_rel * z2:
        return x_end, pix
    return x, pix2


@wp.func
def _rescue_pass(entry: int, use_cascade: int) -> int:
    """1 where the photon is marched again in the camera view from its start (pass 1 of :func:`camera_marches`: the
    cascade lost it to the light view or found it occluded), else 2 (no more camera marches)."""
    if (entry == L_LOST_LIGHT or entry == L_OCCLUDED) and use_cascade != 0:
        return 1
    return 2


@wp.func
def camera_marches(
    camera: ViewParams,
    cam_depth: wp.array(dtype=wp.float32),  # (H*W,) [m] (read)
    cam_depth_bounds: wp.array(dtype=wp.vec2),  # march.depth_bounds of cam_depth (read)
    origin: wp.vec3,  # [m] where the photon left the specular surface
    d: wp.vec3,  # its direction
    t_max: float,
    max_steps: int,
    thickness: float,
    thickness_rel: float,
    use_cascade: int,
    entry: int,  # :func:`reproject_to_camera`'s entry
    x_end: wp.vec3,  # [m] where the light-view march ended
    pix: int,  # and its camera pixel (or -1)
):
    """Steps 5-6 of seed 000 after :func:`reproject_to_camera`, in the camera view, at one call site of the march
    (a loop of up to two passes: one inlined march, not two; docs/perf_notes.md section 23):

    * pass 0, the cascade's second chance where ``entry`` is ``MARCH_ON``: march on from ``x_end``; ``L_STORED``
      with the crossing, else ``L_STEPS``, ``L_OCCLUDED`` (it ends on a closed object's far side, which the camera
      does not see: ``MARCH_HIDDEN``) or ``L_LOST_CAMERA`` with ``x_end`` (:func:`_camera_entry`);
    * pass 1, the rescue of a photon the cascade lost to the light view or found occluded (``L_LOST_LIGHT``,
      ``L_OCCLUDED``, with ``use_cascade``): the light-view march walks on behind the light's depth buffer where
      the ray runs into surfaces the light does not see (on the pool: the floor along the end wall in the lee of
      the deck, which refracted light reaches and direct light does not): it crosses a false surface far below
      the floor or leaves the view, and the reprojected end point is off the screen or behind the camera's
      surfaces, although the camera sees the floor it reaches. The camera's own depth buffer shows that floor:
      march the ray there from its start (a crossing the camera sees along the ray is a surface the photon meets
      first): ``L_STORED`` on a crossing, else the entry it had.

    Returns (entry, end point [m], camera pixel). :func:`trace_photon` runs the same passes reading the camera
    where it needs it (``read_again``)."""
    camera_pass = int(0)
    if entry != MARCH_ON:
        camera_pass = _rescue_pass(entry, use_cascade)
    while camera_pass < 2:
        o_m = x_end
        if camera_pass == 1:
            o_m = origin + d * (1.0e-4 * t_max)
        status, t_m, steps = screen_march_bounded(camera, cam_depth, cam_depth_bounds, o_m, d, t_max, max_steps,
                                                  thickness, thickness_rel)
        if camera_pass == 0:
            entry = _camera_entry(status)
            if entry == L_STORED:
                x_end = x_end + d * t_m
                pix = camera_pixel(camera, x_end)
            camera_pass = _rescue_pass(entry, use_cascade)
        else:
            if status == MARCH_HIT:
                x_end = origin + d * (1.0e-4 * t_max + t_m)
                pix = camera_pixel(camera, x_end)
                entry = L_STORED
            camera_pass = 2
    return entry, x_end, pix


#: ``counted`` traces (:func:`counted_trace`): the phases a photon ran, bits of its count record
COUNT_TRACED = wp.constant(1)  #: emitted and bounced: the light-view march and the reprojection ran
COUNT_CASCADE = wp.constant(2)  #: the camera march of the cascade (pass 0)
COUNT_RESCUE = wp.constant(4)  #: the rescue's camera march (pass 1)
COUNT_REFINE = wp.constant(8)  #: refine_landing
COUNT_HIDDEN = wp.constant(16)  #: store_hidden
COUNT_DEPOSIT = wp.constant(32)  #: deposit (validation and the photon map's atomics)


@wp.func
def write_counts(hits: wp.array(dtype=wp.vec4), k: int, work_l: int, work_0: int, work_1: int, phases: int):
    """Photon ``k``'s count record, behind the ``N = hits.shape[0] / 3`` landings: ``hits[N + 2k]`` = the light-view
    march's cell tests and pixel steps, the cascade's camera march's; ``hits[N + 2k + 1]`` = the rescue's, its
    ``COUNT_*`` bits (0: not traced) and 1 (written). Floats: exact below 2^24."""
    n = hits.shape[0] / 3
    hits[n + 2 * k] = wp.vec4(float(work_l / WORK_TESTS), float(work_l % WORK_TESTS), float(work_0 / WORK_TESTS),
                              float(work_0 % WORK_TESTS))
    hits[n + 2 * k + 1] = wp.vec4(float(work_1 / WORK_TESTS), float(work_1 % WORK_TESTS), float(phases), 1.0)


#: the projected traces (:func:`projected_trace`, the frame's) and the counted one march the light view (the camera)
#: with the failed cells' proven prefixes skipped (``march._make_marches``' ``partial``: 2 the coarse and the fine
#: cells', 1 the fine cells' only, 0 none: the bounded march as before; 3 (experimental) as 2 with a level of 2x2
#: coarse cells above the coarse ones; the same output bit for bit whatever the level, docs/perf_notes.md section
#: 74). ``PARTIAL_LIGHT`` may also be a pair (perspective light's level, orthographic light's). Read when a kernel
#: is made (first use): set before the first frame to compare
PARTIAL_LIGHT = 2
PARTIAL_CAMERA = 0


def _light_level(light_ortho: int) -> int:
    """``PARTIAL_LIGHT`` for a trace compiled for this light projection (-1, run time: the perspective one's)."""
    if isinstance(PARTIAL_LIGHT, (tuple, list)):
        return int(PARTIAL_LIGHT[1 if light_ortho == 1 else 0])
    return int(PARTIAL_LIGHT)


def _make_trace(counted: bool, flows: tuple = (False, True), light_ortho: int = -1, camera_ortho: int = -1,
                partial: tuple = (0, 0)):
    """:func:`trace_photon` and the kernels :func:`trace_photons` (one per entry of ``flows``: with ``flow`` False
    the caustic flow's code is left out at compile time, ``trace_photons``; True: ``trace_photons_flow``, which adds
    each stored photon's landing to its flow cell where ``flow_records`` is not empty), or with ``counted`` (probes
    only, ``tools/trace_steps.py``; :func:`counted_trace`) the same trace on the ``counted`` marches
    (:func:`~.march.counted_marches`), which writes each photon's work per phase into ``hits`` (:func:`write_counts`;
    ``hits`` then holds 3 records a slot) and is a module of its own; everything else, outputs included, the same.
    Every variant takes the same inputs (a kernel without the flow ignores its eight flow inputs).

    ``light_ortho``, ``camera_ortho``: -1 reads each view's projection (``ViewParams.orthographic``) at run time;
    0 or 1 compiles the trace for that projection of the light's RSM views or of the camera (:func:`projected_trace`):
    the views are read with their ``orthographic`` field replaced by the constant, which the compiler folds, so
    the marches, reprojections and the emission carry only that projection's code (the same values wherever the
    constant equals the views' field: the same bits). Such kernels are modules of their own, compiled when first
    launched.

    ``partial``: (light, camera), the level at which that march skips its failed cells' proven prefixes
    (``PARTIAL_LIGHT``, ``PARTIAL_CAMERA``); the same outputs at any. A kernel with one is a module of its own."""
    partial_light, partial_camera = int(partial[0]), int(partial[1])
    camera_march = bounded_march(True, partial_camera)
    light_march = bounded_march(False, partial_light)
    kernel_module = "unique" if partial_light or partial_camera else None
    if counted:
        camera_march = counted_marches(True, partial_camera)[2]
        light_march = counted_marches(False, partial_light)[2]
        kernel_module = "unique"
    LIGHT_ORTHO = int(light_ortho)
    CAMERA_ORTHO = int(camera_ortho)
    if LIGHT_ORTHO >= 0 or CAMERA_ORTHO >= 0:
        kernel_module = "unique"

    light_projected = fixed_projection(LIGHT_ORTHO)
    camera_projected = fixed_projection(CAMERA_ORTHO)

    @wp.func
    def light_view(light_views: wp.array(dtype=ViewParams), view_index: int) -> ViewParams:
        """``light_views[view_index]``, its projection the compiled one where the trace has one (``light_ortho``)."""
        return light_projected(light_views[view_index])

    @wp.func
    def camera_view(cameras: wp.array(dtype=ViewParams), anchor: int) -> ViewParams:
        """``read_again(cameras, 0, anchor)``, its projection the compiled one where the trace has one
        (``camera_ortho``)."""
        return camera_projected(read_again(cameras, 0, anchor))

    @wp.func
    def trace_photon(
        k: int,  # photon index
        origin: wp.vec3,  # [m] on the specular surface
        d: wp.vec3,  # unit direction after the bounce
        power: wp.vec3,  # [W] after the bounce
        light_views: wp.array(dtype=ViewParams),  # (V,) the light's RSM views (read)
        view_index: int,  # the view the photon left from
        rsm_opaque_depth: wp.array(dtype=wp.float32),  # (Hl*Wl,) light view's opaque depth [m] (read)
        rsm_depth_bounds: wp.array(dtype=wp.vec2),  # its march.depth_bounds (read)
        cameras: wp.array(dtype=ViewParams),  # (2,) this frame's camera first (read)
        cam_depth: wp.array(dtype=wp.float32),
        cam_depth_bounds: wp.array(dtype=wp.vec2),  # march.depth_bounds of cam_depth (read)
        cam_position: wp.array(dtype=wp.vec3),
        cam_normal: wp.array(dtype=wp.vec3),
        cam_solid_angle: wp.array(dtype=wp.float32),  # (H*W,) exact pixel solid angle [sr]
        max_steps: int,
        thickness: float,
        thickness_rel: float,
        t_max: float,
        footprint_mode: int,
        use_cascade: int,  # 0: light view only (no camera march), for comparisons
        photon_map: wp.array(dtype=wp.vec3),  # (H*W,) irradiance [W/m²] (accumulate)
        photon_m2: wp.array(dtype=wp.float32),  # (H*W,) Σ luminance(e)² [(W/m²)²] (accumulate; None: not kept)
        tally: wp.ref[Tally],  # this thread's ledger share: the photon's final entry (write)
        hits: wp.array(dtype=wp.vec4),  # (n_photons,) world hit point and pixel index (write where stored; empty: none)
        hidden_views: wp.array(dtype=ViewParams),  # the light's whole views, of its landed-photon map (read)
        hidden_flux: wp.array(dtype=wp.vec3),  # that map, power [W] per texel (hidden_flux.py; accumulate; empty: none)
        hidden_w: int,  # its texels per whole view, across
        hidden_h: int,  # and down
    ):
        """Steps 4-7 of one emitted photon: march the light view (:func:`march_light`), cascade into the camera view
        (:func:`reproject_to_camera`, pass 0 of :func:`camera_marches`), a photon the cascade lost marched in the camera
        view from its start (pass 1), the landing cut with its receiver's tangent plane (:func:`refine_landing`),
        validate, store; its final entry booked. Each view is read
        from memory where it is needed (the camera again after its march, ``read_again``), so that no view is held in
        registers through a march that does not use it: the trace's stack frame at its launch bound 336 -> 216 B
        (sm_90, ``tools/regcount.py``; before the rescue and the refinement, docs/perf_notes.md section 17). The cascade's
        camera march and the rescue's share one inlined march (a loop of up to two passes): 440 -> 304 B (section 23).
        Every photon with a landing point is also added to ``hidden_flux`` there (:func:`~.hidden_flux.store_hidden`;
        its booking unchanged): one the camera sees (stored or rejected) and one whose light-view march landed
        (``MARCH_HIT``) where the camera does not see (``L_OCCLUDED``, or ``L_LOST_CAMERA`` outside the image) and no
        camera march stored. Returns (1 if stored, else 0; the landing point [m]; its camera pixel)."""
        o_l = origin + d * (1.0e-4 * t_max)  # march_light's march, its work kept where counted
        status, t_l, work_l = light_march(light_view(light_views, view_index), rsm_opaque_depth, rsm_depth_bounds, o_l, d, t_max,
                                          max_steps, thickness, thickness_rel)
        x_end = o_l + d * t_l
        work_0 = int(0)  # ``counted``: the camera passes' work (counted_marches), and the phases run (COUNT_*)
        work_1 = int(0)
        phases = COUNT_TRACED
        entry, pix = reproject_to_camera(camera_view(cameras, 0), cam_depth, status, x_end, thickness, thickness_rel, use_cascade)
        landed = status == MARCH_HIT  # x_end is a light-view surface crossing (kept unless a camera march stores it)
        # :func:`camera_marches`' two passes, reading the camera where needed (it is not held through the march)
        camera_pass = int(0)
        if entry != MARCH_ON:
            camera_pass = _rescue_pass(entry, use_cascade)
        while camera_pass < 2:
            o_m = x_end
            if camera_pass == 1:
                o_m = origin + d * (1.0e-4 * t_max)
            status, t_m, steps = camera_march(camera_view(cameras, pix + 1), cam_depth, cam_depth_bounds, o_m, d,
                                              t_max, max_steps, thickness, thickness_rel)
            if wp.static(counted):
                if camera_pass == 0:
                    work_0 = steps
                    phases = phases | COUNT_CASCADE
                else:
                    work_1 = steps
                    phases = phases | COUNT_RESCUE
            if camera_pass == 0:
                entry = _camera_entry(status)
                if entry == L_STORED:
                    x_end = x_end + d * t_m
                    pix = camera_pixel(camera_view(cameras, steps), x_end)
                camera_pass = _rescue_pass(entry, use_cascade)
            else:
                if status == MARCH_HIT:
                    x_end = origin + d * (1.0e-4 * t_max + t_m)
                    pix = camera_pixel(camera_view(cameras, steps), x_end)
                    entry = L_STORED
                camera_pass = 2
        if entry != L_STORED:
            book(tally, entry, power)
            if landed and (entry == L_OCCLUDED or entry == L_LOST_CAMERA):  # on a surface the camera does not see
                store_hidden(hidden_views, x_end, power, hidden_flux, hidden_w, hidden_h)
                if wp.static(counted):
                    phases = phases | COUNT_HIDDEN
            if wp.static(counted):
                write_counts(hits, k, work_l, work_0, work_1, phases)
            return int(0), x_end, pix
        # the landing cut with the tangent plane of the surface its pixel shows (a light-view crossing lies within an
        # RSM texel's depth of the surface; the G-buffer holds it to the camera's pixel)
        x_end, pix = refine_landing(camera_view(cameras, pix), cam_depth, cam_position, cam_normal, origin, d, x_end, pix,
                                    thickness, thickness_rel)
        store_hidden(hidden_views, x_end, power, hidden_flux, hidden_w, hidden_h)
        # 6.-7. validate against the camera's surface normal, store irradiance over the pixel's footprint
        stored = deposit(camera_view(cameras, pix), pix, d, power, cam_depth, cam_position, cam_normal,
                         cam_solid_angle, footprint_mode, photon_map, photon_m2, tally)
        if stored != 0:
            if hits.shape[0] > 0:
                hits[k] = wp.vec4(x_end[0], x_end[1], x_end[2], float(pix))
        if wp.static(counted):
            write_counts(hits, k, work_l, work_0, work_1, phases | COUNT_REFINE | COUNT_HIDDEN | COUNT_DEPOSIT)
        return stored, x_end, pix


    def make_kernel(flow: bool):
        def trace_photons(
            light_views: wp.array(dtype=ViewParams),  # (V,) the light's RSM views (LightMaps.views, read)
            states: wp.array(dtype=CascadeState),  # (V,) what each emits (LightMaps.states, read)
            view_index: int,  # the view these photons leave from
            light_kind: int,  # 0 distant, 1 point, 2 spot
            light_pos: wp.vec3,
            # RSM view of the light (flat H*W arrays)
            rsm_opaque_depth: wp.array(dtype=wp.float32),
            rsm_depth_bounds: wp.array(dtype=wp.vec2),  # march.depth_bounds of rsm_opaque_depth (read)
            rsm_depth: wp.array(dtype=wp.float32),  # specular layer: depth [m] (point, normal: texel_surface)
            rsm_emission: TexelEmission,  # its specular texels' flux, roughness and IOR from the light and materials (read)
            rsm_tri: wp.array(dtype=wp.int32),
            geometry: SurfaceGeometry,  # the scene's triangles, for each photon's exact origin and normal (read)
            triangle_material: wp.array(dtype=wp.int32),
            mat_opacity: wp.array(dtype=wp.float32),
            mat_albedo: wp.array(dtype=wp.vec3),
            max_lum: wp.array(dtype=wp.float32),  # (1,) brightest texel luminance of this light [W]
            # camera G-buffer (flat H*W arrays)
            cameras: wp.array(dtype=ViewParams),  # (2,) this frame's camera first (frame.FrameInputs.cameras, read)
            cam_depth: wp.array(dtype=wp.float32),
            cam_depth_bounds: wp.array(dtype=wp.vec2),  # march.depth_bounds of cam_depth (read)
            cam_position: wp.array(dtype=wp.vec3),
            cam_normal: wp.array(dtype=wp.vec3),
            cam_solid_angle: wp.array(dtype=wp.float32),  # (H*W,) exact pixel solid angle [sr]
            # settings
            light_photons: int,  # the light's photons, split over its active views (cascade_photons)
            n_slots: int,  # threads launched (>= this view's photons; the surplus emits nothing and records zero power)
            randoms: wp.array(dtype=wp.vec3i),  # (S,) per stream: R2 scramble (x, y) and rng seed (FrameInputs, read)
            stream: int,  # this (light, view)'s stream
            order: wp.array(dtype=wp.int32),  # (N,) photon index per thread when use_order (read)
            use_order: int,
            roughness_cutoff: float,
            luminance_cutoff: float,  # relative to max_lum, per whole-view texel (scaled by the view's texel_scale)
            max_steps: int,
            thickness: float,
            thickness_rel: float,
            t_max: float,
            footprint_mode: int,
            use_cascade: int,  # 0: light view only (no camera march), for comparisons
            # outputs
            photon_map: wp.array(dtype=wp.vec3),  # (H*W,) irradiance [W/m²] (accumulate)
            photon_m2: wp.array(dtype=wp.float32),  # (H*W,) Σ luminance(e)² of the stored photons [(W/m²)²] (add)
            ledger: wp.array(dtype=wp.vec3d),  # (LEDGER_ENTRIES,) power [W] per entry, RGB (accumulate)
            hits: wp.array(dtype=wp.vec4),  # (>= n_slots,) world hit point and pixel index (-1 none), tests and stats
            # (write; an empty array: not recorded, as in the frame loop)
            outcome: wp.array(dtype=wp.vec4),  # (>= n_slots,) per thread: final power [W] and entry (write; empty
            # with fold: none written)
            fold: int,  # 1: the final entries added by the block's epilogue (final_add); 0: by the outcome pass
            hidden_views: wp.array(dtype=ViewParams),  # the light's whole views, of its landed-photon map (read)
            hidden_flux: wp.array(dtype=wp.vec3),  # that map, power [W] per texel (hidden_flux.py; add; empty: none)
            hidden_w: int,  # its texels per whole view, across
            hidden_h: int,  # and down
            flow_views: wp.array(dtype=ViewParams),  # the light's whole views, of the caustic flow's cells (read)
            flow_w: int,  # cells per whole view, across
            flow_h: int,  # and down
            flow_base: int,  # the light's first cell
            flow_cells: wp.array2d(dtype=wp.vec4),  # (2, cells) CausticFlow.cells (add to this frame's row)
            flow_parity: wp.array(dtype=wp.int32),  # (1,) its parity (read)
            flow_records: wp.array(dtype=wp.vec2i),  # per slot (cell + 1, pixel) where stored (write; empty: no flow)
            flow_offset: int,  # this view's first record
        ):
            """One thread per photon, ``wp.launch_tiled`` in blocks (:meth:`~.base.PhotonPass.launch_photons`).
            The ledger is added per block after emission and bounce (sampled, culled, absorbed, reflected/refracted),
            so that no float64 sum is held in registers through the march; each photon's final entry is added per
            block at the end (``fold`` 1: :func:`final_add`, one reduction after the march), or (``fold`` 0, the
            twin) goes to its outcome record, added per block by ``ledger_add_outcomes`` after this kernel. With
            ``fold`` 1 the records are written only where ``outcome`` is not empty (tests)."""
            block, lane = wp.tid()
            t = block * wp.block_dim() + lane
            light = light_view(light_views, view_index)
            cascade = states[view_index]
            n_photons = cascade_photons(cascade, light_photons)
            if block * wp.block_dim() >= n_photons:  # slots past this view's photons: the whole block (fixed dims)
                return
            skip_window = cascade.skip_window
            rnd = randoms[stream]
            seed = rnd[2]  # seed of this (frame, view)'s random streams
            scramble = wp.vec2i(rnd[0], rnd[1])  # per-frame Cranley-Patterson rotation of R2 (fixed point)
            k = int(0)
            texel = int(-1)
            power = wp.vec3(0.0)
            origin = wp.vec3(0.0)
            n = wp.vec3(0.0)
            d = wp.vec3(0.0)
            state = wp.uint32(0)
            entry = int(-1)  # the emission's bookings (emission_add): none sampled yet
            sampled = wp.vec3(0.0)
            absorbed = wp.vec3(0.0)
            refracted = int(0)
            if t < n_photons:
                k = photon_index(order, use_order, t)
                if hits.shape[0] > 0:
                    hits[k] = wp.vec4(0.0, 0.0, 0.0, -1.0)
                    if wp.static(counted):
                        write_counts(hits, k, 0, 0, 0, 0)  # not traced (trace_photon writes its own)
                # 1.-3. texel from the scrambled R2 sequence, origin and normal on the texel's triangle, bounce by
                # exact Fresnel as a probability (power unchanged); metals reflect with their albedo
                texel, power, origin, n, d, state, entry, sampled, absorbed, refracted = emit_and_scatter(
                    light, light_kind, light_pos, k, n_photons, scramble, seed, rsm_depth,
                    rsm_emission, rsm_tri, geometry, skip_window, triangle_material, mat_opacity,
                    mat_albedo, max_lum[0], roughness_cutoff, luminance_cutoff * cascade.texel_scale)
            emission_add(ledger, block, lane, entry, sampled, absorbed, power, refracted)
            tally = tally_new()
            if texel >= 0:  # the views are read again where each march needs them (trace_photon)
                stored, x_end, pix = trace_photon(
                    k, origin, d, power, light_views, view_index, rsm_opaque_depth, rsm_depth_bounds, cameras,
                    cam_depth, cam_depth_bounds, cam_position, cam_normal, cam_solid_angle, max_steps, thickness,
                    thickness_rel, t_max, footprint_mode, use_cascade, photon_map, photon_m2, tally, hits,
                    hidden_views, hidden_flux, hidden_w, hidden_h)
                if wp.static(flow):  # compiled only into the flow's kernel (perf_notes section 39)
                    # the caustic flow (caustic_flow.py): its cell's landings
                    if stored != 0 and flow_records.shape[0] > 0:
                        camera = camera_view(cameras, pix)
                        cell = flow_cell(flow_views, flow_w, flow_h, origin)
                        add_landing(flow_cells, flow_parity, flow_records, flow_offset + t,
                                    wp.where(cell >= 0, cell + flow_base, -1), pix, world_project(camera, x_end),
                                    camera.width, camera.height)
            if fold != 0:  # uniform over the launch: every thread of the block reaches the reduction
                final_add(ledger, block, lane, tally.entry, tally.power)
            if t < n_slots and (fold == 0 or outcome.shape[0] > 0):
                record_outcome(outcome, t, tally)

        # named as a kernel at module level (the per-kernel tables, tools/regcount.py), the counted one apart, and
        # an orthographic light's or camera's apart (the pool's sun: its launches timed apart from its spot's)
        trace_photons.__qualname__ = ("trace_photons" + ("_flow" if flow else "") + ("_counted" if counted else "")
                                      + ("_ortho" if LIGHT_ORTHO == 1 else "") + ("_orthocam" if CAMERA_ORTHO == 1 else ""))
        return wp.kernel(trace_photons, launch_bounds=PHOTON_LAUNCH_BOUNDS, enable_backward=False,
                         module=kernel_module)

    return (trace_photon, *[make_kernel(f) for f in flows])


#: the trace (one photon: :func:`trace_photon`; the kernels: :func:`trace_photons` without the caustic flow's code,
#: :func:`trace_photons_flow` with it, launched when the pass keeps a flow: ``CISP.trace_kernel``)
trace_photon, trace_photons, trace_photons_flow = _make_trace(False)

_PROJECTED_TRACES: dict = {}


def projected_trace(flow: bool, light_ortho: int, camera_ortho: int):
    """:func:`trace_photons` (``flow`` False) or :func:`trace_photons_flow` compiled for one projection of the light's
    RSM views and one of the camera (0 perspective, 1 orthographic; :func:`_make_trace`), made on first use, each a
    module of its own: the kernel ``CISP.trace_kernel`` launches (the pool's sun is orthographic, its spot and every
    camera perspective). Named as the kernel it specialises; the same inputs, the same outputs bit for bit where
    the views have those projections (``tests/test_cisp.py``)."""
    key = (bool(flow), int(light_ortho), int(camera_ortho), _light_level(int(light_ortho)), int(PARTIAL_CAMERA))
    if key not in _PROJECTED_TRACES:
        _PROJECTED_TRACES[key] = _make_trace(False, (key[0],), key[1], key[2], key[3:])[1]
    return _PROJECTED_TRACES[key]


def trace_kernels() -> tuple:
    """Every trace kernel made so far: :func:`trace_photons`, :func:`trace_photons_flow` and the projected ones."""
    return (trace_photons, trace_photons_flow, *_PROJECTED_TRACES.values())


_COUNTED_TRACE: dict = {}


def counted_trace():
    """The ``counted`` :func:`trace_photons` (made on first use, per ``PARTIAL_LIGHT`` / ``PARTIAL_CAMERA``;
    ``tools/trace_steps.py``)."""
    key = (_light_level(-1), int(PARTIAL_CAMERA))
    if key not in _COUNTED_TRACE:
        # with the flow's code (run only where records exist)
        _COUNTED_TRACE[key] = _make_trace(True, (True,), partial=key)[1]
    return _COUNTED_TRACE[key]
