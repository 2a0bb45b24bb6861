"""Warp kernels of Caustics Mapping (seed 004, Wyman & Davis 2006; Shah et al. 2007): light space only.

Per RSM view of a light, every frame:

1. ``receiver_footprints`` (per light texel): the opaque surface the texel sees, its geometric normal
   (facing the light) and the world-space area of it that the texel covers;
2. ``trace_to_caustic_map`` (per photon): the photon end point is found by marching the light view's
   opaque depth only (no camera view), and its power is splatted into the texel it lands in;
3. ``temporal_filter`` (per light texel): this frame's irradiance, power / receiver area, into a ring
   of the last frames, and their mean (seed 004, 3.2.3);
4. (``cmap_gather="light"``) the Gaussian gather of :mod:`cisp_warp.denoise.gather` in light space;
5. ``project_caustic_map`` (per camera pixel): the opaque G-buffer point is looked up in the light view
   like a shadow map; where the light sees that very surface, the map's irradiance is added to the
   camera photon map.
"""

from __future__ import annotations

import warp as wp

from ..scene.device import SurfaceGeometry
from ..raster.kernels import TexelEmission
from ..raster.views import ViewParams, pixel_ray_world, view_eye_world, world_project
from .common import (EMISSION_ENTRIES, FOOTPRINT_EXACT, L_LOST_LIGHT, L_REJECTED, L_STEPS, L_STORED,
                     Tally, book, emit_and_bounce, entry_mask, ledger_add, photon_index,
                     pixel_footprint, tally_new)
from .march import MARCH_HIT, MARCH_STEPS, screen_march_plain

wp.set_module_options({"enable_backward": False})  # forward only (the ledger's tallies are passed by reference)

#: the ways a caustics-map photon ends after its bounce
CMAP_FINAL_ENTRIES = wp.constant(entry_mask(L_LOST_LIGHT, L_REJECTED, L_STEPS, L_STORED))

SQRT2 = wp.constant(1.4142135623730951)
#: steepest receiver slope (tan θ between its normal and the light ray) the depth test allows for; steeper
#: receivers (θ > 84°) are seen edge-on by the light and carry almost no irradiance in its map anyway
MAX_SLOPE = wp.constant(10.0)


@wp.func
def geometric_normal(tri: int, points: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32)) -> wp.vec3:
    """Unit normal of the plane of triangle ``tri`` (orientation: counter-clockwise winding)."""
    p0 = points[indices[3 * tri]]
    return wp.normalize(wp.cross(points[indices[3 * tri + 1]] - p0, points[indices[3 * tri + 2]] - p0))


@wp.kernel
def receiver_footprints(
    light: ViewParams,
    opaque_depth: wp.array(dtype=wp.float32),  # (Hl*Wl,) depth of the nearest opaque surface [m], 0 = none (read)
    opaque_tri: wp.array(dtype=wp.int32),  # (Hl*Wl,) its triangle, -1 = none (read)
    texel_solid_angle: wp.array(dtype=wp.float32),  # (Hl*Wl,) [sr], perspective views; zeros for orthographic (read)
    points: wp.array(dtype=wp.vec3),  # (V,) vertex positions [m] (read)
    indices: wp.array(dtype=wp.int32),  # (3T,) triangle vertex indices (read)
    receiver_normal: wp.array(dtype=wp.vec3),  # (Hl*Wl,) unit geometric normal facing the light; 0 = none (write)
    receiver_area: wp.array(dtype=wp.float32),  # (Hl*Wl,) receiver area the texel covers [m²]; 0 = none (write)
):
    """The receiver of each light texel and the area of it the texel covers.

    Orthographic: A = (1 / (fx·fy)) / |cos θ|, the texel's cross-section over the cosine between the
    receiver normal and the light's view axis. Perspective: A = Ω_t · r² / |cos θ|, with Ω_t the texel's
    exact solid angle, r the distance from the light and θ the angle to the ray through the texel centre.
    This is :func:`pixel_footprint` with the light as the viewer (the receiver is the flat triangle the
    rasterizer drew, so its geometric normal is the right one for the area).
    """
    t = wp.tid()
    tri = opaque_tri[t]
    z = opaque_depth[t]
    if tri < 0 or z <= 0.0:
        receiver_normal[t] = wp.vec3(0.0)
        receiver_area[t] = 0.0
        return
    o, d = pixel_ray_world(light, float(t % light.width) + 0.5, float(t / light.width) + 0.5)
    x = o + d * z  # t along a view ray is the linear depth
    n = geometric_normal(tri, points, indices)
    if wp.dot(n, view_eye_world(light, x)) < 0.0:
        n = -n
    receiver_normal[t] = n
    receiver_area[t] = pixel_footprint(light, texel_solid_angle[t], x, n, FOOTPRINT_EXACT)


@wp.func
def trace_to_caustic_map_photon(
    origin: wp.vec3,  # [m] on the specular surface
    d: wp.vec3,  # unit direction after the bounce
    power: wp.vec3,  # [W] after the bounce
    light: ViewParams,
    rsm_opaque_depth: wp.array(dtype=wp.float32),  # (Hl*Wl,) [m], 0 = none (read)
    rsm_opaque_tri: wp.array(dtype=wp.int32),  # (Hl*Wl,) -1 = none (read)
    receiver_normal: wp.array(dtype=wp.vec3),  # (Hl*Wl,) (read)
    max_steps: int,
    thickness: float,  # [m]
    thickness_rel: float,
    t_max: float,  # [m]
    texel_power: wp.array(dtype=wp.vec3),  # (Hl*Wl,) power landed per light texel this frame [W] (accumulate)
    tally: wp.ref[Tally],  # this thread's ledger share: the photon's final entry (write)
):
    """An emitted photon's end point in the light view's opaque depth only, splatted into its texel.

    A photon whose march leaves the light view (or lands in a texel without an opaque surface) is
    ``lost_light_view``; one arriving on the side of its receiver the light does not see is ``rejected``;
    the rest are ``stored``: splatted into the caustic map in light space.
    """
    o = origin + d * (1.0e-4 * t_max)  # start a hair off the specular surface, as CISP does
    status, t_end, steps = screen_march_plain(light, rsm_opaque_depth, o, d, t_max, max_steps, thickness,
                                             thickness_rel)  # a light view: no back-face layer
    if status == MARCH_STEPS:
        book(tally, L_STEPS, power)
        return
    if status != MARCH_HIT:
        book(tally, L_LOST_LIGHT, power)
        return
    q = world_project(light, o + d * t_end)
    i = wp.clamp(int(q[0]), 0, light.width - 1)
    j = wp.clamp(int(q[1]), 0, light.height - 1)
    t = j * light.width + i
    if rsm_opaque_tri[t] < 0:  # the refined crossing fell just off a silhouette, onto no surface
        book(tally, L_LOST_LIGHT, power)
        return
    if wp.dot(-d, receiver_normal[t]) < 0.0:
        book(tally, L_REJECTED, power)
        return
    wp.atomic_add(texel_power, t, power)
    book(tally, L_STORED, power)


@wp.kernel
def trace_to_caustic_map(
    light: ViewParams,
    light_kind: int,  # 0 distant, 1 point, 2 spot
    light_pos: wp.vec3,  # [m] (point and spot lights)
    # RSM view of the light (flat Hl*Wl arrays, read)
    rsm_opaque_depth: wp.array(dtype=wp.float32),  # linear depth of the nearest opaque surface [m], 0 = none
    rsm_opaque_tri: wp.array(dtype=wp.int32),  # its triangle, -1 = none
    rsm_depth: wp.array(dtype=wp.float32),  # specular layer: depth [m] (point, normal: texel_surface)
    rsm_emission: TexelEmission,  # its specular texels' flux, roughness and IOR from the light and materials (read)
    rsm_tri: wp.array(dtype=wp.int32),  # specular layer triangle, -1 = none
    geometry: SurfaceGeometry,  # the scene's triangles, for each photon's exact origin and normal (read)
    skip_window: wp.vec4,  # this view's pixels sampled by a finer cascade (x0, y0, x1, y1); empty if x1 <= x0
    receiver_normal: wp.array(dtype=wp.vec3),  # (Hl*Wl,) from receiver_footprints, facing the light
    # scene materials (read)
    triangle_material: wp.array(dtype=wp.int32),  # (T,)
    mat_opacity: wp.array(dtype=wp.float32),  # (M,)
    mat_albedo: wp.array(dtype=wp.vec3),  # (M,)
    max_lum: wp.array(dtype=wp.float32),  # (1,) brightest texel luminance of this light [W]
    # settings
    n_photons: int,
    seed: int,  # seed of this (frame, view)'s random streams
    scramble: wp.vec2i,  # per-frame Cranley-Patterson rotation of the R2 sequence (fixed point)
    order: wp.array(dtype=wp.int32),  # (N,) photon index per thread when use_order (read)
    use_order: int,
    roughness_cutoff: float,
    luminance_cutoff: float,  # relative to max_lum
    max_steps: int,
    thickness: float,  # [m]
    thickness_rel: float,
    t_max: float,  # [m]
    # outputs
    texel_power: wp.array(dtype=wp.vec3),  # (Hl*Wl,) power landed per light texel this frame [W] (accumulate)
    ledger: wp.array(dtype=wp.vec3d),  # (LEDGER_ENTRIES,) power [W] per entry, RGB (accumulate)
):
    """One thread per photon, ``wp.launch_tiled`` in blocks (:meth:`~.base.PhotonPass.launch_photons`): same
    emission and bounce as CISP, then the light view's opaque depth only. The ledger is added per block after
    the bounce and at the end."""
    block, lane = wp.tid()
    t = block * wp.block_dim() + lane
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
            rsm_tri, geometry, skip_window, triangle_material, mat_opacity, mat_albedo,
            max_lum[0], roughness_cutoff, luminance_cutoff, emitted)
    ledger_add(ledger, emitted, block, EMISSION_ENTRIES)
    tally = tally_new()
    if texel >= 0:
        trace_to_caustic_map_photon(origin, d, power, light, rsm_opaque_depth, rsm_opaque_tri, receiver_normal,
                                    max_steps, thickness, thickness_rel, t_max, texel_power, tally)
    ledger_add(ledger, tally, block, CMAP_FINAL_ENTRIES)


@wp.kernel
def temporal_filter(
    texel_power: wp.array(dtype=wp.vec3),  # (Hl*Wl,) power landed this frame [W] (read)
    receiver_area: wp.array(dtype=wp.float32),  # (Hl*Wl,) [m²], 0 = no receiver (read)
    slot: int,  # ring slot of this frame, in [0, history_length)
    frames: int,  # filled slots, this one included: min(frames traced, history_length)
    history: wp.array2d(dtype=wp.vec3),  # (history_length, Hl*Wl) irradiance of the last frames [W/m²] (write slot)
    irradiance: wp.array(dtype=wp.vec3),  # (Hl*Wl,) mean of the filled slots [W/m²] (write)
):
    """E = P / A for this frame into the ring; out: the mean over the last ``frames`` frames (seed 004, 3.2.3)."""
    t = wp.tid()
    a = receiver_area[t]
    e = wp.vec3(0.0)
    if a > 0.0:
        e = texel_power[t] / a
    history[slot, t] = e
    n = history.shape[0]
    total = wp.vec3(0.0)
    for back in range(frames):
        total += history[(slot - back + n) % n, t]
    irradiance[t] = total / float(frames)


@wp.kernel
def project_caustic_map(
    light: ViewParams,
    light_opaque_depth: wp.array(dtype=wp.float32),  # (Hl*Wl,) [m], 0 = none (read)
    caustic_map: wp.array(dtype=wp.vec3),  # (Hl*Wl,) irradiance on each texel's receiver [W/m²] (read)
    cam_depth: wp.array(dtype=wp.float32),  # (H*W,) camera opaque depth [m], 0 = none (read)
    cam_position: wp.array(dtype=wp.vec3),  # (H*W,) world position [m] (read)
    cam_normal: wp.array(dtype=wp.vec3),  # (H*W,) unit normal facing the camera (read)
    thickness: float,  # [m] absolute part of the same-surface depth tolerance
    thickness_rel: float,  # relative part (× light depth)
    photon_map: wp.array(dtype=wp.vec3),  # (H*W,) irradiance [W/m²] (accumulate)
):
    """Shadow-map lookup of each camera pixel's surface point in the caustic map, bilinear over the taps
    whose light depth is that same surface.

    A tap is the same surface when its light depth is within ``thickness + thickness_rel·z + √2·s·tan θ``
    of the point's: ``s`` is the texel size at the point and θ the angle between its normal and the light
    ray, so a plane seen at a slant still matches the (exact, per texel centre) depths of taps up to
    √2 texels away. Taps nearer the light are occluders (the point is in the light's shadow), farther
    ones lie beyond a silhouette; the bilinear weights are renormalised over the matching taps. A point
    whose visible side faces away from the light takes nothing: photons were validated on the lit side.
    """
    p = wp.tid()
    if cam_depth[p] <= 0.0:
        return
    x = cam_position[p]
    n = cam_normal[p]
    q = world_project(light, x)
    if q[2] <= light.near or q[0] < 0.0 or q[1] < 0.0 or q[0] >= float(light.width) or q[1] >= float(light.height):
        return
    to_light = view_eye_world(light, x)
    cos_t = wp.dot(n, to_light)
    if cos_t <= 0.0:
        return
    texel = wp.max(1.0 / light.fx, 1.0 / light.fy)
    if light.orthographic == 0:
        texel = q[2] * texel
    tan_t = wp.min(wp.sqrt(wp.max(1.0 - cos_t * cos_t, 0.0)) / cos_t, MAX_SLOPE)
    tol = thickness + thickness_rel * q[2] + SQRT2 * texel * tan_t
    fx = q[0] - 0.5
    fy = q[1] - 0.5
    i0 = int(wp.floor(fx))
    j0 = int(wp.floor(fy))
    ax = fx - float(i0)
    ay = fy - float(j0)
    sum_w = float(0.0)
    sum_e = wp.vec3(0.0)
    for dj in range(2):
        for di in range(2):
            i = wp.clamp(i0 + di, 0, light.width - 1)
            j = wp.clamp(j0 + dj, 0, light.height - 1)
            t = j * light.width + i
            sd = light_opaque_depth[t]
            if sd > 0.0 and wp.abs(q[2] - sd) <= tol:
                w = wp.where(di == 0, 1.0 - ax, ax) * wp.where(dj == 0, 1.0 - ay, ay)
                sum_w += w
                sum_e += w * caustic_map[t]
    if sum_w > 0.0:
        photon_map[p] = photon_map[p] + sum_e / sum_w
