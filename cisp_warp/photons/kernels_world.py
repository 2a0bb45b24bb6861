"""Warp kernels of the world-space photon methods: SSPM (seed 003) and the reference.

Both trace photons through a ``wp.Mesh`` BVH of the whole scene (refit, never rebuilt, when the
water moves), bouncing at smooth specular surfaces (exact Fresnel, as a probability) until a
diffuse receiver or the bounce limit. They differ in where photons come from and how they are
stored:

* SSPM: emitted exactly as CISP's (RSM texels), stored after a *depth-visibility test* against the
  camera's opaque G-buffer (Kim 2019);
* reference: emitted from the light itself (continuous samples of the light's views, first hit by
  ray casting), stored after an exact *BVH visibility* test to the eye; every photon's landing point
  is also kept for a density estimate where the camera sees the receiver through water.
"""

from __future__ import annotations

import math

import warp as wp

from ..optics import fresnel_dielectric, reflect, refract
from ..raster.kernels import TexelEmission, spot_falloff
from ..scene.device import SurfaceGeometry
from ..raster.light_maps import CascadeState, cascade_photons
from ..raster.views import ViewParams, pixel_ray_world, view_eye_world, world_project
from ..scene.model import LAYER_OPAQUE, LAYER_SPECULAR
from .hidden_flux import store_hidden
from .march import surface_far
from ..sky import SkyMap, sky_irradiance_at, sky_radiance
from .common import (ALL_ENTRIES, EMISSION_ENTRIES, L_ABSORBED, L_BOUNCES, L_CULLED_ROUGH, L_ESCAPED, L_LOST_CAMERA,
                     L_OCCLUDED, L_REJECTED, L_SAMPLED, L_STORED, Tally, book, book_bounce, deposit, emit_and_bounce,
                     entry_mask, ledger_add, photon_index, r2_point, record_absorbed, record_outcome, specular_bounce,
                     tally_new)

#: what an SSPM photon books after its first bounce (world_trace, trace_sspm_photon and deposit book nothing else):
#: its final entry and its absorption at further metallic bounces, written to two outcome records, added afterwards
SSPM_FINAL_ENTRIES = entry_mask(L_ABSORBED, L_CULLED_ROUGH, L_ESCAPED, L_BOUNCES, L_LOST_CAMERA, L_OCCLUDED, L_REJECTED,
                                L_STORED)

WT_LANDED = wp.constant(0)  #: reached a diffuse receiver; any other status is the ledger entry it was booked as

INV_PI = wp.constant(1.0 / math.pi)
wp.set_module_options({"enable_backward": False})  # forward only: no adjoints to compile

LAYER_OPAQUE_C = wp.constant(LAYER_OPAQUE)
LAYER_SPECULAR_C = wp.constant(LAYER_SPECULAR)

FAR_AWAY = wp.constant(1.0e7)  #: where a photon that landed nowhere is parked for the hash grid [m]


@wp.struct
class WorldScene:
    """The scene as world-space tracing sees it."""

    mesh: wp.uint64  #: BVH over every triangle (``DeviceScene.bvh()``)
    face_to_tri: wp.array(dtype=wp.int32)  #: (F,) scene triangle of each BVH face
    opaque_mesh: wp.uint64  #: BVH over the opaque layer (what the camera's G-buffer shows)
    points: wp.array(dtype=wp.vec3)  #: (V,) [m]
    normals: wp.array(dtype=wp.vec3)  #: (V,) unit vertex normals
    indices: wp.array(dtype=wp.int32)  #: (3T,)
    triangle_material: wp.array(dtype=wp.int32)  #: (T,)
    triangle_layers: wp.array(dtype=wp.int32)  #: (T,) LAYER_* bits
    albedo: wp.array(dtype=wp.vec3)  #: (M,)
    roughness: wp.array(dtype=wp.float32)  #: (M,)
    opacity: wp.array(dtype=wp.float32)  #: (M,) < 1: transmissive dielectric
    ior: wp.array(dtype=wp.float32)  #: (M,)


@wp.struct
class CameraBuffers:
    """The camera's opaque G-buffer as photon stores read it (flat H*W arrays)."""

    view: ViewParams
    depth: wp.array(dtype=wp.float32)  #: linear depth [m], 0 = none
    position: wp.array(dtype=wp.vec3)  #: [m]
    normal: wp.array(dtype=wp.vec3)  #: unit, facing the camera
    solid_angle: wp.array(dtype=wp.float32)  #: exact pixel solid angle [sr]


@wp.func
def world_hit(ws: WorldScene, o: wp.vec3, d: wp.vec3, t_max: float):
    """Nearest hit of the ray ``o + d·t`` (unit ``d``), t in (0, t_max].

    Returns (scene triangle or -1, point [m], shading normal, geometric normal); the shading normal is
    flipped onto the geometric normal's side so both agree on which side the ray arrives from.
    """
    q = wp.mesh_query_ray(ws.mesh, o, d, t_max)
    if not q.result:
        return int(-1), wp.vec3(0.0), wp.vec3(0.0), wp.vec3(0.0)
    tri = ws.face_to_tri[q.face]
    i0 = ws.indices[3 * tri]
    i1 = ws.indices[3 * tri + 1]
    i2 = ws.indices[3 * tri + 2]
    ng = wp.normalize(q.normal)
    n = ws.normals[i0] * q.u + ws.normals[i1] * q.v + ws.normals[i2] * (1.0 - q.u - q.v)
    ln = wp.length(n)
    if ln < 1.0e-12:
        n = ng
    else:
        n = n / ln
    if wp.dot(n, ng) < 0.0:
        n = -n
    return tri, o + d * q.t, n, ng


@wp.func
def is_smooth_specular(ws: WorldScene, tri: int, roughness_cutoff: float) -> int:
    m = ws.triangle_material[tri]
    if (ws.triangle_layers[tri] & LAYER_SPECULAR_C) != 0 and ws.roughness[m] <= roughness_cutoff:
        return 1
    return 0


@wp.func
def offset_origin(x: wp.vec3, ng: wp.vec3, d: wp.vec3, eps: float) -> wp.vec3:
    """Start a continuing ray a hair off the surface, on the side it leaves to."""
    if wp.dot(d, ng) < 0.0:
        return x - ng * eps
    return x + ng * eps


@wp.func
def world_trace(ws: WorldScene, x: wp.vec3, ng: wp.vec3, d: wp.vec3, power: wp.vec3, state: wp.uint32,
                roughness_cutoff: float, t_max: float, max_bounces: int, tally: wp.ref[Tally]):
    """Follow a photon leaving the surface point ``x`` along ``d`` through further specular bounces.

    Returns (WT_LANDED or the ledger entry it ended in, landing point, receiver shading normal, arriving
    direction, power, rng). The ways of ending other than landing are booked here (escaped, culled, bounce
    limit, absorbed).
    """
    eps = 1.0e-5 * t_max
    o = offset_origin(x, ng, d, eps)
    bounce = int(0)
    while bounce <= max_bounces:
        tri, y, n, g = world_hit(ws, o, d, t_max)
        if tri < 0:
            book(tally, L_ESCAPED, power)
            return L_ESCAPED, y, n, d, power, state
        if is_smooth_specular(ws, tri, roughness_cutoff) != 0:
            if bounce == max_bounces:
                book(tally, L_BOUNCES, power)
                return L_BOUNCES, y, n, d, power, state
            m = ws.triangle_material[tri]
            d, power, refracted, state = specular_bounce(d, n, int(ws.opacity[m] < 1.0), ws.ior[m], ws.albedo[m],
                                                         power, state, tally)
            o = offset_origin(y, g, d, eps)
            bounce += 1
            continue
        if (ws.triangle_layers[tri] & LAYER_OPAQUE_C) == 0:  # a rough transmissive surface: not modelled
            book(tally, L_CULLED_ROUGH, power)
            return L_CULLED_ROUGH, y, n, d, power, state
        return WT_LANDED, y, n, d, power, state
    book(tally, L_BOUNCES, power)
    return L_BOUNCES, o, ng, d, power, state


@wp.func
def camera_pixel(cam: CameraBuffers, y: wp.vec3):
    """(pixel index or -1 outside the image, projected (px, py, depth))."""
    q = world_project(cam.view, y)
    v = cam.view
    if q[2] <= v.near or q[0] < 0.0 or q[1] < 0.0 or q[0] >= float(v.width) or q[1] >= float(v.height):
        return int(-1), q
    return int(q[1]) * v.width + int(q[0]), q


@wp.func
def camera_receiver(cam: CameraBuffers, y: wp.vec3, thickness: float, thickness_rel: float):
    """Seed 003's depth-visibility test of a landing point ``y``. Returns (``L_STORED`` when the camera sees
    it, validation and store pending, else ``L_LOST_CAMERA`` or ``L_OCCLUDED``; camera pixel or -1)."""
    pix, q = camera_pixel(cam, y)
    if pix < 0:
        return L_LOST_CAMERA, pix
    zc = cam.depth[pix]
    # within the thickness in front of the surface, and behind it no farther than its far side (where the camera's
    # depth carries its back-face layer, half way to a closed object's back face: march.surface_far)
    if zc <= 0.0 or zc - q[2] > thickness + thickness_rel * zc or q[2] > surface_far(cam.view, cam.depth, pix, zc,
                                                                                     thickness, thickness_rel):
        return L_OCCLUDED, pix
    return L_STORED, pix


@wp.func
def trace_sspm_photon(
    origin: wp.vec3,  # [m] on the specular surface
    n: wp.vec3,  # its normal
    d: wp.vec3,  # unit direction after the bounce
    power: wp.vec3,  # [W] after the bounce
    state: wp.uint32,  # rng state
    ws: WorldScene,
    cam: CameraBuffers,  # its ``view`` is replaced by cameras[0]
    cameras: wp.array(dtype=ViewParams),  # (2,) this frame's camera first (frame.FrameInputs.cameras, read)
    roughness_cutoff: float,
    thickness: float,  # [m] depth-visibility tolerance, absolute
    thickness_rel: float,  # relative (× depth)
    t_max: float,
    max_bounces: int,
    footprint_mode: int,
    photon_map: wp.array(dtype=wp.vec3),  # (H*W,) irradiance [W/m²] (accumulate)
    photon_m2: wp.array(dtype=wp.float32),  # (H*W,) Σ luminance(e)² [(W/m²)²] (accumulate; None: not kept)
    tally: wp.ref[Tally],  # this thread's ledger share: further absorption and the final entry (accumulate)
    hidden_views: wp.array(dtype=ViewParams),  # the light's whole views, of its landed-photon map (read)
    hidden_flux: wp.array(dtype=wp.vec3),  # that map, power [W] per texel (hidden_flux.py; accumulate; empty: none)
    hidden_w: int,  # its texels per whole view, across
    hidden_h: int,  # and down
):
    """Seed 003 after the first bounce: traced through the BVH, stored by depth visibility. Every photon that lands
    is also added to ``hidden_flux`` (:func:`~.hidden_flux.store_hidden`; its booking unchanged), where the camera
    sees its landing point or not."""
    status, y, nr, d, power, state = world_trace(ws, origin, n, d, power, state, roughness_cutoff, t_max,
                                                 max_bounces, tally)
    if status != WT_LANDED:
        return
    cam.view = cameras[0]  # read after the BVH loop: not held in registers through it (96 registers, not 128)
    entry, pix = camera_receiver(cam, y, thickness, thickness_rel)
    store_hidden(hidden_views, y, power, hidden_flux, hidden_w, hidden_h)
    if entry != L_STORED:
        book(tally, entry, power)
        return
    deposit(cam.view, pix, d, power, cam.depth, cam.position, cam.normal, cam.solid_angle, footprint_mode,
            photon_map, photon_m2, tally)


@wp.kernel
def trace_sspm(
    light_views: wp.array(dtype=ViewParams),  # (V,) the light's RSM views (LightMaps.views, read)
    states: wp.array(dtype=CascadeState),  # (V,) what each emits (LightMaps.states, read)
    view_index: int,  # the view these photons leave from
    light_kind: int,  # 0 distant, 1 point, 2 spot
    light_pos: wp.vec3,  # [m]
    # RSM view of the light (flat H*W arrays, read)
    rsm_depth: wp.array(dtype=wp.float32),  # specular layer: depth [m] (point, normal: texel_surface)
    rsm_emission: TexelEmission,  # its specular texels' flux, roughness and IOR from the light and materials (read)
    rsm_tri: wp.array(dtype=wp.int32),
    geometry: SurfaceGeometry,  # the scene's triangles, for each photon's exact origin and normal (read)
    max_lum: wp.array(dtype=wp.float32),  # (1,) brightest texel luminance of this light [W]
    ws: WorldScene,
    cam: CameraBuffers,  # its ``view`` is replaced by cameras[0]
    cameras: wp.array(dtype=ViewParams),  # (2,) this frame's camera first (frame.FrameInputs.cameras, read)
    light_photons: int,  # the light's photons, split over its active views (cascade_photons)
    n_slots: int,  # threads launched (>= this view's photons; the surplus emits nothing and records zero power)
    randoms: wp.array(dtype=wp.vec3i),  # (S,) per stream: R2 scramble (x, y) and rng seed (frame.FrameInputs, read)
    stream: int,  # this (light, view)'s stream
    order: wp.array(dtype=wp.int32),  # (N,) photon index per thread when use_order (read)
    use_order: int,
    roughness_cutoff: float,
    luminance_cutoff: float,  # relative to max_lum, per whole-view texel (scaled by the view's texel_scale)
    thickness: float,  # [m] depth-visibility tolerance, absolute
    thickness_rel: float,  # relative (× depth)
    t_max: float,
    max_bounces: int,
    footprint_mode: int,
    photon_map: wp.array(dtype=wp.vec3),  # (H*W,) irradiance [W/m²] (accumulate)
    photon_m2: wp.array(dtype=wp.float32),  # (H*W,) Σ luminance(e)² of the stored photons [(W/m²)²] (accumulate)
    ledger: wp.array(dtype=wp.vec3d),  # (LEDGER_ENTRIES,) power [W] per entry, RGB (accumulate)
    outcome: wp.array(dtype=wp.vec4),  # (>= 2 n_slots,) per thread t: final power [W] and entry at t, absorbed
    # power at n_slots + t (write)
    hidden_views: wp.array(dtype=ViewParams),  # the light's whole views, of its landed-photon map (read)
    hidden_flux: wp.array(dtype=wp.vec3),  # that map, power [W] per texel (hidden_flux.py; accumulate; empty: none)
    hidden_w: int,  # its texels per whole view, across
    hidden_h: int,  # and down
):
    """Seed 003: photons from the RSM (as CISP's), traced through the BVH, stored by depth visibility. One
    thread per photon, ``wp.launch_tiled`` in blocks (:meth:`~.base.PhotonPass.launch_photons`); the ledger is
    added per block after the first bounce (no float64 sum of emission held through the trace); each photon's final
    entry and its absorption at further bounces go to its outcome records, added per block by
    ``ledger_add_outcomes`` after this kernel (block reductions here cost registers: 104 with the absorption's, 96
    without)."""
    block, lane = wp.tid()
    t = block * wp.block_dim() + lane
    light = light_views[view_index]
    cascade = states[view_index]
    n_photons = cascade_photons(cascade, light_photons)
    if block * wp.block_dim() >= n_photons:  # slots past this view's photons: the whole block (fixed launch dims)
        return
    skip_window = cascade.skip_window
    rnd = randoms[stream]
    seed = rnd[2]
    scramble = wp.vec2i(rnd[0], rnd[1])
    texel = int(-1)
    power = wp.vec3(0.0)
    origin = wp.vec3(0.0)
    n = wp.vec3(0.0)
    d = wp.vec3(0.0)
    state = wp.uint32(0)
    emitted = tally_new()
    if t < n_photons:
        k = photon_index(order, use_order, t)
        texel, power, origin, n, d, state = emit_and_bounce(
            light, light_kind, light_pos, k, n_photons, scramble, seed, rsm_depth, rsm_emission,
            rsm_tri, geometry, skip_window, ws.triangle_material, ws.opacity, ws.albedo,
            max_lum[0], roughness_cutoff, luminance_cutoff * cascade.texel_scale, emitted)
    ledger_add(ledger, emitted, block, EMISSION_ENTRIES)
    tally = tally_new()
    if texel >= 0:
        trace_sspm_photon(origin, n, d, power, state, ws, cam, cameras, roughness_cutoff, thickness, thickness_rel, t_max,
                          max_bounces, footprint_mode, photon_map, photon_m2, tally, hidden_views,
                          hidden_flux, hidden_w, hidden_h)
    if t < n_slots:
        record_outcome(outcome, t, tally)
        record_absorbed(outcome, n_slots + t, tally)


@wp.func
def light_sample(light: ViewParams, light_kind: int, light_rgb: wp.vec3, light_pos: wp.vec3, spot_axis: wp.vec3,
                 cone_angle: float, cone_softness: float, sx: float, sy: float, n_photons: int):
    """A photon leaving the light through continuous pixel (sx, sy) of one of its views.

    Returns (origin, unit direction, power [W]). Power = radiant density × view area / N: for an
    orthographic view E/(fx·fy) per pixel; for a perspective view I·falloff·cos³α/(fx·fy) per pixel
    (dΩ = cos³α dA on the unit-depth plane), so N photons carry the light's flux through the view.
    """
    lo, ld = pixel_ray_world(light, sx, sy)
    per_pixel = float(light.width * light.height) / float(n_photons) / (light.fx * light.fy)
    if light.orthographic != 0:
        return lo, wp.normalize(ld), light_rgb * per_pixel
    ln = wp.length(ld)  # ld = (x, y, -1) in view space: |ld| = 1/cos α
    d = ld / ln
    c = 1.0 / ln
    power = light_rgb * (per_pixel * c * c * c)
    if light_kind == 2:
        power = power * spot_falloff(wp.dot(d, spot_axis), cone_angle, cone_softness)
    return light_pos, d, power


@wp.func
def trace_reference_photon(
    t: int,  # thread (photon slot) index
    light: ViewParams,
    light_kind: int,  # 0 distant, 1 point, 2 spot
    light_rgb: wp.vec3,  # W/m² (distant) or W/sr (point, spot)
    light_pos: wp.vec3,  # [m]
    spot_axis: wp.vec3,  # unit
    cone_angle: float,  # [rad]
    cone_softness: float,
    ws: WorldScene,
    cam: CameraBuffers,
    n_photons: int,
    seed: int,
    scramble: wp.vec2i,
    roughness_cutoff: float,
    t_max: float,
    max_bounces: int,
    footprint_mode: int,
    landing_offset: int,  # first slot of this view's photons in the landing arrays
    photon_map: wp.array(dtype=wp.vec3),  # (H*W,) irradiance [W/m²] of this pass (accumulate)
    photon_m2: wp.array(dtype=wp.float32),  # (H*W,) Σ luminance(e)² of this pass (accumulate; None: not kept)
    landing_pos: wp.array(dtype=wp.vec3),  # (P,) where each photon landed [m], FAR_AWAY if nowhere (write)
    landing_normal: wp.array(dtype=wp.vec3),  # (P,) receiver normal (write)
    landing_power: wp.array(dtype=wp.vec3),  # (P,) [W] (write)
    tally: wp.ref[Tally],  # this thread's ledger share (accumulate)
):
    """Ground truth: photons from the light itself, first hit by ray casting, stored by exact visibility.

    Only photons whose first hit is a smooth specular surface are caustic photons; their power is the
    ledger's ``sampled``. Photons that first hit a diffuse surface are direct light (the shadow-mapped
    term) and are not counted.
    """
    k = t
    slot = landing_offset + k
    landing_pos[slot] = wp.vec3(FAR_AWAY)
    landing_normal[slot] = wp.vec3(0.0)
    landing_power[slot] = wp.vec3(0.0)
    u = r2_point(k, scramble)
    o, d, power = light_sample(light, light_kind, light_rgb, light_pos, spot_axis, cone_angle, cone_softness,
                               u[0] * float(light.width), u[1] * float(light.height), n_photons)
    if wp.length(power) <= 0.0:
        return
    t0 = float(0.0)
    if light.orthographic != 0:
        t0 = light.near
    tri, x, n, ng = world_hit(ws, o + d * t0, d, t_max)
    if tri < 0 or is_smooth_specular(ws, tri, roughness_cutoff) == 0:
        return
    book(tally, L_SAMPLED, power)
    m = ws.triangle_material[tri]
    state = wp.rand_init(seed, k)
    d, power, refracted, state = specular_bounce(d, n, int(ws.opacity[m] < 1.0), ws.ior[m], ws.albedo[m], power,
                                                 state, tally)
    book_bounce(tally, refracted, power)
    status, y, nr, d, power, state = world_trace(ws, x, ng, d, power, state, roughness_cutoff, t_max, max_bounces,
                                                 tally)
    if status != WT_LANDED:
        return
    landing_pos[slot] = y
    landing_normal[slot] = nr
    landing_power[slot] = power
    pix, q = camera_pixel(cam, y)
    if pix < 0:
        book(tally, L_LOST_CAMERA, power)
        return
    # exact visibility: nothing opaque between the receiver and the eye
    to_eye = view_eye_world(cam.view, y)
    dist = q[2]
    if cam.view.orthographic == 0:
        dist = wp.length(wp.transform_point(cam.view.view_to_world, wp.vec3(0.0)) - y)
    eps = 1.0e-5 * t_max
    hit = wp.mesh_query_ray(ws.opaque_mesh, offset_origin(y, nr, to_eye, eps), to_eye, dist - 2.0 * eps)
    if hit.result:
        book(tally, L_OCCLUDED, power)
        return
    # the surface the pixel shows (its G-buffer sample): a photon on another surface seen in the same pixel
    # (a silhouette, a crease) is not part of that surface's irradiance, as in every screen-space method
    zc = cam.depth[pix]
    if zc <= 0.0:
        book(tally, L_REJECTED, power)
        return
    pixel_size = zc / cam.view.fx
    if cam.view.orthographic != 0:
        pixel_size = 1.0 / cam.view.fx
    if wp.abs(wp.dot(y - cam.position[pix], cam.normal[pix])) > 2.0 * pixel_size:
        book(tally, L_REJECTED, power)
        return
    deposit(cam.view, pix, d, power, cam.depth, cam.position, cam.normal, cam.solid_angle, footprint_mode,
            photon_map, photon_m2, tally)


@wp.kernel
def trace_reference(
    light: ViewParams,
    light_kind: int,  # 0 distant, 1 point, 2 spot
    light_rgb: wp.vec3,  # W/m² (distant) or W/sr (point, spot)
    light_pos: wp.vec3,  # [m]
    spot_axis: wp.vec3,  # unit
    cone_angle: float,  # [rad]
    cone_softness: float,
    ws: WorldScene,
    cam: CameraBuffers,
    n_photons: int,
    seed: int,
    scramble: wp.vec2i,
    roughness_cutoff: float,
    t_max: float,
    max_bounces: int,
    footprint_mode: int,
    landing_offset: int,  # first slot of this view's photons in the landing arrays
    photon_map: wp.array(dtype=wp.vec3),  # (H*W,) irradiance [W/m²] of this pass (accumulate)
    photon_m2: wp.array(dtype=wp.float32),  # (H*W,) Σ luminance(e)² of this pass (accumulate; None: not kept)
    landing_pos: wp.array(dtype=wp.vec3),  # (P,) where each photon landed [m], FAR_AWAY if nowhere (write)
    landing_normal: wp.array(dtype=wp.vec3),  # (P,) receiver normal (write)
    landing_power: wp.array(dtype=wp.vec3),  # (P,) [W] (write)
    ledger: wp.array(dtype=wp.vec3d),  # (LEDGER_ENTRIES,) power [W] per entry, RGB (accumulate)
):
    """One thread per light photon, ``wp.launch_tiled`` in blocks (:meth:`~.base.PhotonPass.launch_photons`):
    trace it, then add the block's ledger once."""
    block, lane = wp.tid()
    t = block * wp.block_dim() + lane
    tally = tally_new()
    if t < n_photons:
        trace_reference_photon(t, light, light_kind, light_rgb, light_pos, spot_axis, cone_angle, cone_softness, ws,
                               cam, n_photons, seed, scramble, roughness_cutoff, t_max, max_bounces, footprint_mode,
                               landing_offset, photon_map, photon_m2, landing_pos, landing_normal, landing_power, tally)
    ledger_add(ledger, tally, block, ALL_ENTRIES)


@wp.kernel
def accumulate_pass(
    pass_map: wp.array(dtype=wp.vec3),  # (H*W,) irradiance of one pass [W/m²] (read)
    total: wp.array(dtype=wp.vec3d),  # (H*W,) Σ over passes (accumulate)
    total_sq: wp.array(dtype=wp.vec3d),  # (H*W,) Σ of squares (accumulate)
):
    p = wp.tid()
    e = wp.vec3d(wp.float64(pass_map[p][0]), wp.float64(pass_map[p][1]), wp.float64(pass_map[p][2]))
    total[p] = total[p] + e
    total_sq[p] = total_sq[p] + wp.cw_mul(e, e)


@wp.kernel
def finish_passes(
    total: wp.array(dtype=wp.vec3d),  # (H*W,) Σ over passes (read)
    total_sq: wp.array(dtype=wp.vec3d),  # (H*W,) Σ of squares (read)
    passes: int,
    mean: wp.array(dtype=wp.vec3),  # (H*W,) mean irradiance [W/m²] (write)
    stderr: wp.array(dtype=wp.vec3),  # (H*W,) standard error of the mean [W/m²] (write)
):
    """Mean over passes and its standard error sqrt(s²/P), s² the unbiased pass-to-pass variance."""
    p = wp.tid()
    inv = wp.float64(1.0) / wp.float64(passes)
    m = total[p] * inv
    mean[p] = wp.vec3(float(m[0]), float(m[1]), float(m[2]))
    s = wp.vec3(0.0)
    if passes > 1:
        for c in range(3):
            var = (total_sq[p][c] * inv - m[c] * m[c]) * wp.float64(passes) / wp.float64(passes - 1)
            s[c] = wp.sqrt(float(wp.max(var, wp.float64(0.0))) / float(passes))
    stderr[p] = s


@wp.kernel
def scale_ledger(ledger: wp.array(dtype=wp.float64), factor: wp.float64):
    i = wp.tid()
    ledger[i] = ledger[i] * factor


# -------------------------------------------------------------------------------------------------
# the reference's final image: camera paths through specular surfaces, density estimate at the end


@wp.kernel
def camera_paths(
    ws: WorldScene,
    cam: CameraBuffers,
    paths_per_pixel: int,
    seed: int,
    roughness_cutoff: float,
    t_max: float,
    max_bounces: int,
    end_pos: wp.array(dtype=wp.vec3),  # (S*H*W,) diffuse point each path ends on [m] (write)
    end_normal: wp.array(dtype=wp.vec3),  # (S*H*W,) its shading normal, facing the path (write)
    end_weight: wp.array(dtype=wp.vec3),  # (S*H*W,) albedo/π × throughput / S; 0 = the path ends nowhere (write)
    end_primary: wp.array(dtype=wp.int32),  # (S*H*W,) 1: the diffuse point is the pixel's own G-buffer surface
    sky: SkyMap,  # the dome light's radiance (black without one)
    end_sky: wp.array(dtype=wp.vec3),  # (S*H*W,) throughput / S × sky radiance where the path leaves the scene (write)
):
    """Path s of pixel p: from the eye through the pixel centre, through smooth specular surfaces
    (Fresnel chosen at random, radiance scaled by (1 − F)/η² across a boundary, by albedo at a metal)
    to the first diffuse surface, or out of the scene, where it sees the sky (as the methods' composite)."""
    i = wp.tid()
    p = i / paths_per_pixel
    v = cam.view
    o, d = pixel_ray_world(v, float(p % v.width) + 0.5, float(p / v.width) + 0.5)
    d = wp.normalize(d)
    if v.orthographic != 0:
        o = o + d * v.near
    state = wp.rand_init(seed, i)
    w = wp.vec3(1.0 / float(paths_per_pixel))
    end_weight[i] = wp.vec3(0.0)
    end_primary[i] = 0
    end_pos[i] = wp.vec3(FAR_AWAY)
    end_normal[i] = wp.vec3(0.0)
    end_sky[i] = wp.vec3(0.0)
    eps = 1.0e-5 * t_max
    specular_seen = int(0)
    bounce = int(0)
    while bounce <= max_bounces:
        tri, y, n, g = world_hit(ws, o, d, t_max)
        if tri < 0:
            end_sky[i] = wp.cw_mul(w, sky_radiance(sky, d))
            return
        m = ws.triangle_material[tri]
        if is_smooth_specular(ws, tri, roughness_cutoff) == 0:
            if (ws.triangle_layers[tri] & LAYER_OPAQUE_C) == 0:
                return
            if wp.dot(n, d) > 0.0:
                n = -n
            end_pos[i] = y
            end_normal[i] = n
            end_weight[i] = wp.cw_mul(w, ws.albedo[m]) * INV_PI
            if specular_seen == 0:
                end_primary[i] = 1
            return
        specular_seen = 1
        nn = n
        eta = ws.ior[m]
        if wp.dot(d, n) > 0.0:
            nn = -n
            eta = 1.0 / eta
        if ws.opacity[m] < 1.0:
            f = fresnel_dielectric(-wp.dot(d, nn), eta)
            if wp.randf(state) < f:
                d = reflect(d, nn)
            else:
                d = refract(d, nn, eta)
                w = w / (eta * eta)
        else:
            d = reflect(d, nn)
            w = wp.cw_mul(w, ws.albedo[m])
        o = offset_origin(y, g, d, eps)
        bounce += 1


@wp.kernel
def endpoint_direct(
    ws: WorldScene,
    kind: int,  # LightKind: 0 distant, 1 point, 2 spot
    light_rgb: wp.vec3,  # W/m² (distant) or W/sr (point, spot)
    light_pos: wp.vec3,  # [m]
    light_dir: wp.vec3,  # unit direction of travel (distant), spot axis
    cone_angle: float,
    cone_softness: float,
    t_max: float,
    end_pos: wp.array(dtype=wp.vec3),  # (S*H*W,) (read)
    end_normal: wp.array(dtype=wp.vec3),
    end_weight: wp.array(dtype=wp.vec3),
    irradiance: wp.array(dtype=wp.vec3),  # (S*H*W,) direct irradiance [W/m²] (accumulate)
):
    """Direct irradiance from one light at each path's end, with an exact shadow ray: any surface,
    water included, blocks it (light through water arrives as photons, as in the raster pipeline)."""
    i = wp.tid()
    if wp.length(end_weight[i]) <= 0.0:
        return
    x = end_pos[i]
    n = end_normal[i]
    to_light = -light_dir
    dist = t_max
    e = light_rgb
    if kind != 0:
        v = light_pos - x
        dist = wp.length(v)
        to_light = v / dist
        e = light_rgb / (dist * dist)
        if kind == 2:
            e = e * spot_falloff(wp.dot(-to_light, light_dir), cone_angle, cone_softness)
    cos_n = wp.dot(n, to_light)
    if cos_n <= 0.0:
        return
    eps = 1.0e-5 * t_max
    q = wp.mesh_query_ray(ws.mesh, x + n * eps, to_light, dist - 2.0 * eps)
    if q.result:
        return
    irradiance[i] = irradiance[i] + e * cos_n


@wp.kernel
def endpoint_sky(
    sh: wp.array(dtype=wp.vec3),  # (9,) convolved SH coefficients of the sky [W/m²] (read)
    views: wp.array(dtype=ViewParams),  # (K,) occlusion map views (read)
    directions: wp.array(dtype=wp.vec3),  # (K,) unit directions towards the sky (read)
    luminance: wp.array(dtype=wp.float32),  # (K,) sky luminance along them [W/(m² sr)] (read)
    map_depth: wp.array(dtype=wp.float32),  # (K*S*S,) occlusion maps [m] (read)
    map_texels: int,  # S*S
    end_pos: wp.array(dtype=wp.vec3),  # (S*H*W,) (read)
    end_normal: wp.array(dtype=wp.vec3),
    end_weight: wp.array(dtype=wp.vec3),
    irradiance: wp.array(dtype=wp.vec3),  # (S*H*W,) [W/m²] (accumulate)
):
    """Sky irradiance at each path's diffuse end: the methods' own (:func:`cisp_warp.sky.sky_irradiance_at`, the
    same SH projection and occlusion maps), so the reference's final image and theirs light with one sky."""
    i = wp.tid()
    if wp.length(end_weight[i]) <= 0.0:
        return
    irradiance[i] = irradiance[i] + sky_irradiance_at(end_pos[i], end_normal[i], sh, views, directions, luminance,
                                                      map_depth, map_texels)


@wp.kernel
def endpoint_gather(
    grid: wp.uint64,
    radius: float,  # [m] gather radius (the hash grid's cell size)
    landing_pos: wp.array(dtype=wp.vec3),  # (P,) photons of this pass (read)
    landing_normal: wp.array(dtype=wp.vec3),
    landing_power: wp.array(dtype=wp.vec3),  # [W]
    end_pos: wp.array(dtype=wp.vec3),  # (S*H*W,) (read)
    end_normal: wp.array(dtype=wp.vec3),
    end_weight: wp.array(dtype=wp.vec3),
    end_primary: wp.array(dtype=wp.int32),
    irradiance: wp.array(dtype=wp.vec3),  # (S*H*W,) Σ over passes of the caustic irradiance [W/m²] (accumulate)
):
    """Density estimate of the caustic irradiance at the end of each path seen through a specular
    surface: E = Σ Φ_i / (π r²) over this pass's photons within r on a surface facing the same way."""
    i = wp.tid()
    if end_primary[i] != 0 or wp.length(end_weight[i]) <= 0.0:
        return
    x = end_pos[i]
    n = end_normal[i]
    acc = wp.vec3(0.0)
    query = wp.hash_grid_query(grid, x, radius)
    j = int(0)
    while wp.hash_grid_query_next(query, j):
        dx = landing_pos[j] - x
        if wp.dot(dx, dx) < radius * radius and wp.dot(landing_normal[j], n) > 0.7:
            acc = acc + landing_power[j]
    irradiance[i] = irradiance[i] + acc / (wp.pi * radius * radius)


@wp.kernel
def resolve_final(
    paths_per_pixel: int,
    passes: int,
    caustic_mean: wp.array(dtype=wp.vec3),  # (H*W,) the pixel's own caustic irradiance [W/m²] (read)
    end_weight: wp.array(dtype=wp.vec3),  # (S*H*W,) (read)
    end_primary: wp.array(dtype=wp.int32),
    end_direct: wp.array(dtype=wp.vec3),  # (S*H*W,) [W/m²]
    end_caustic: wp.array(dtype=wp.vec3),  # (S*H*W,) Σ over passes [W/m²]
    end_sky: wp.array(dtype=wp.vec3),  # (S*H*W,) sky radiance of the paths that leave the scene, weighted (read)
    final: wp.array(dtype=wp.vec3),  # (H*W,) radiance reaching the camera [W/(m² sr)] (write)
):
    p = wp.tid()
    l = wp.vec3(0.0)
    i = p * paths_per_pixel
    while i < (p + 1) * paths_per_pixel:
        e = end_caustic[i] / float(passes)
        if end_primary[i] != 0:
            e = caustic_mean[p]
        l = l + wp.cw_mul(end_weight[i], end_direct[i] + e) + end_sky[i]
        i += 1
    final[p] = l
