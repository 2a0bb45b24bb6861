"""Warp kernels of Cascaded Image-Space Photon Tracing (seed 000, section 3).

One thread per photon: sample an RSM texel, bounce by exact Fresnel, march the light view,
reproject into the camera view, march on there, validate, and add irradiance to the photon map.
Every photon's power ends in exactly one ledger entry, tallied per thread and added once per block.
"""

from __future__ import annotations

import warp as wp

from ..raster.views import ViewParams, world_project
from .common import (L_LOST_CAMERA, L_LOST_LIGHT, L_OCCLUDED, L_STEPS, Tally, book, deposit, emit_and_bounce, ledger_add,
                     photon_index, tally_new)
from .march import MARCH_HIT, MARCH_STEPS, screen_march

wp.set_module_options({"enable_backward": False})  # forward only (the ledger's tallies are passed by reference)


@wp.func
def trace_photon(
    t: int,  # thread (photon slot) index
    light: ViewParams,
    light_kind: int,  # 0 distant, 1 point, 2 spot
    light_pos: wp.vec3,
    # RSM view of the light (flat H*W arrays)
    rsm_opaque_depth: wp.array(dtype=wp.float32),
    rsm_position: wp.array(dtype=wp.vec3),
    rsm_normal: wp.array(dtype=wp.vec3),
    rsm_flux: wp.array(dtype=wp.vec3),  # [W] per texel
    rsm_roughness: wp.array(dtype=wp.float32),
    rsm_ior: wp.array(dtype=wp.float32),
    rsm_tri: wp.array(dtype=wp.int32),
    triangle_material: wp.array(dtype=wp.int32),
    mat_opacity: wp.array(dtype=wp.float32),
    mat_albedo: wp.array(dtype=wp.vec3),
    max_lum: wp.array(dtype=wp.float32),  # (1,) brightest texel luminance of this light [W]
    # camera G-buffer (flat H*W arrays)
    camera: ViewParams,
    cam_depth: wp.array(dtype=wp.float32),
    cam_position: wp.array(dtype=wp.vec3),
    cam_normal: wp.array(dtype=wp.vec3),
    cam_solid_angle: wp.array(dtype=wp.float32),  # (H*W,) exact pixel solid angle [sr]
    # settings
    n_photons: int,
    seed: int,  # seed of this (frame, view)'s random streams
    scramble: wp.vec2i,  # per-frame Cranley-Patterson rotation of the R2 sequence (fixed point)
    order: wp.array(dtype=wp.int32),  # (N,) photon index per thread when use_order (read)
    use_order: int,
    roughness_cutoff: float,
    luminance_cutoff: float,  # relative to max_lum
    max_steps: int,
    thickness: float,
    thickness_rel: float,
    t_max: float,
    footprint_mode: int,
    use_cascade: int,  # 0: light view only (no camera march), for comparisons
    # outputs
    photon_map: wp.array(dtype=wp.vec3),  # (H*W,) irradiance [W/m²] (accumulate)
    tally: wp.ref[Tally],  # this thread's ledger share (accumulate)
    hits: wp.array(dtype=wp.vec4),  # (n_photons,) world hit point and pixel index (-1 none), for tests and stats
):
    """One photon: emit, bounce, march the light view, cascade into the camera view, store; all booked."""
    k = photon_index(order, use_order, t)
    hits[k] = wp.vec4(0.0, 0.0, 0.0, -1.0)
    # 1.-3. texel from the scrambled R2 sequence, origin on the texel's tangent plane, bounce by exact
    # Fresnel as a probability (power unchanged); metals reflect with their albedo
    texel, power, origin, n, d, state = emit_and_bounce(
        light, light_kind, light_pos, k, n_photons, scramble, seed, rsm_position, rsm_normal, rsm_flux, rsm_roughness,
        rsm_ior, rsm_tri, triangle_material, mat_opacity, mat_albedo, max_lum[0], roughness_cutoff, luminance_cutoff,
        tally)
    if texel < 0:
        return
    # 4. march the light view's opaque depth (start a hair off the surface)
    o = origin + d * (1.0e-4 * t_max)
    status, t_end, steps = screen_march(light, rsm_opaque_depth, o, d, t_max, max_steps, thickness, thickness_rel)
    light_hit = status == MARCH_HIT
    if status == MARCH_STEPS:
        book(tally, L_STEPS, power)
        return
    x_end = o + d * t_end
    # 5. cascade: reproject into the camera view (Fig. 7)
    q = world_project(camera, x_end)
    inside = q[2] > camera.near and q[0] >= 0.0 and q[1] >= 0.0 and q[0] < float(camera.width) and q[1] < float(camera.height)
    if not inside:
        if light_hit:
            book(tally, L_LOST_CAMERA, power)
        else:
            book(tally, L_LOST_LIGHT, power)
        return
    pix = int(q[1]) * camera.width + int(q[0])
    zc = cam_depth[pix]
    tol = thickness + thickness_rel * zc
    if zc > 0.0 and q[2] > zc + tol:
        book(tally, L_OCCLUDED, power)
        return
    on_surface = zc > 0.0 and q[2] >= zc - tol
    if not on_surface:
        if use_cascade == 0:
            book(tally, L_LOST_LIGHT, power)
            return
        # floating in front of the camera's surfaces: the second chance, march on in the camera view
        status, t2, steps2 = screen_march(camera, cam_depth, x_end, d, t_max, max_steps, thickness, thickness_rel)
        if status == MARCH_STEPS:
            book(tally, L_STEPS, power)
            return
        if status != MARCH_HIT:
            book(tally, L_LOST_CAMERA, power)
            return
        x_end = x_end + d * t2
        q = world_project(camera, x_end)
        pix = wp.clamp(int(q[1]), 0, camera.height - 1) * camera.width + wp.clamp(int(q[0]), 0, camera.width - 1)
    # 6.-7. validate against the camera's surface normal, store irradiance over the pixel's footprint
    if deposit(camera, pix, d, power, cam_depth, cam_position, cam_normal, cam_solid_angle, footprint_mode,
               photon_map, tally) != 0:
        hits[k] = wp.vec4(x_end[0], x_end[1], x_end[2], float(pix))


@wp.kernel
def trace_photons(
    light: ViewParams,
    light_kind: int,  # 0 distant, 1 point, 2 spot
    light_pos: wp.vec3,
    # RSM view of the light (flat H*W arrays)
    rsm_opaque_depth: wp.array(dtype=wp.float32),
    rsm_position: wp.array(dtype=wp.vec3),
    rsm_normal: wp.array(dtype=wp.vec3),
    rsm_flux: wp.array(dtype=wp.vec3),  # [W] per texel
    rsm_roughness: wp.array(dtype=wp.float32),
    rsm_ior: wp.array(dtype=wp.float32),
    rsm_tri: wp.array(dtype=wp.int32),
    triangle_material: wp.array(dtype=wp.int32),
    mat_opacity: wp.array(dtype=wp.float32),
    mat_albedo: wp.array(dtype=wp.vec3),
    max_lum: wp.array(dtype=wp.float32),  # (1,) brightest texel luminance of this light [W]
    # camera G-buffer (flat H*W arrays)
    camera: ViewParams,
    cam_depth: wp.array(dtype=wp.float32),
    cam_position: wp.array(dtype=wp.vec3),
    cam_normal: wp.array(dtype=wp.vec3),
    cam_solid_angle: wp.array(dtype=wp.float32),  # (H*W,) exact pixel solid angle [sr]
    # settings
    n_photons: int,
    seed: int,  # seed of this (frame, view)'s random streams
    scramble: wp.vec2i,  # per-frame Cranley-Patterson rotation of the R2 sequence (fixed point)
    order: wp.array(dtype=wp.int32),  # (N,) photon index per thread when use_order (read)
    use_order: int,
    roughness_cutoff: float,
    luminance_cutoff: float,  # relative to max_lum
    max_steps: int,
    thickness: float,
    thickness_rel: float,
    t_max: float,
    footprint_mode: int,
    use_cascade: int,  # 0: light view only (no camera march), for comparisons
    # outputs
    photon_map: wp.array(dtype=wp.vec3),  # (H*W,) irradiance [W/m²] (accumulate)
    ledger: wp.array(dtype=wp.float64),  # (3*LEDGER_ENTRIES,) power [W] (accumulate)
    hits: wp.array(dtype=wp.vec4),  # (n_photons,) world hit point and pixel index (-1 none), for tests and stats
):
    """One thread per photon (``wp.launch_tiled`` over :func:`~.common.photon_blocks`): trace it, then add the
    block's ledger once."""
    block, lane = wp.tid()
    t = block * wp.block_dim() + lane
    tally = tally_new()
    if t < n_photons:
        trace_photon(t, light, light_kind, light_pos, rsm_opaque_depth, rsm_position, rsm_normal, rsm_flux,
                     rsm_roughness, rsm_ior, rsm_tri, triangle_material, mat_opacity, mat_albedo, max_lum, camera,
                     cam_depth, cam_position, cam_normal, cam_solid_angle, n_photons, seed, scramble, order,
                     use_order, roughness_cutoff, luminance_cutoff, max_steps, thickness, thickness_rel, t_max,
                     footprint_mode, use_cascade, photon_map, tally, hits)
    ledger_add(ledger, tally, lane)
