"""Warp kernels of Cascaded Image-Space Photon Tracing (seed 000, section 3).

One thread per photon: sample an RSM texel, bounce by exact Fresnel, march the light view,
reproject into the camera view, march on there, validate, and add irradiance to the photon map.
Every photon's power ends in exactly one ledger entry.
"""

from __future__ import annotations

import warp as wp

from ..denoise.kernels_svgf import luminance
from ..optics import fresnel_dielectric, reflect, refract
from ..raster.views import ViewParams, pixel_ray_world, world_project
from .march import MARCH_HIT, MARCH_STEPS, screen_march

# ledger entries: power [W] per RGB channel, slots 3*entry .. 3*entry+2
L_SAMPLED = wp.constant(0)  #: power of the sampled texels (the whole)
L_CULLED_ROUGH = wp.constant(1)  #: texel rougher than the cutoff
L_CULLED_LUM = wp.constant(2)  #: texel dimmer than the luminance cutoff
L_ABSORBED = wp.constant(3)  #: absorbed at a metallic surface
L_LOST_LIGHT = wp.constant(4)  #: left the light view, and its exit point is outside the camera view
L_LOST_CAMERA = wp.constant(5)  #: hit in the light view outside the camera view, or left the camera view
L_OCCLUDED = wp.constant(6)  #: reprojected behind a camera-view surface (Fig. 7, convex case)
L_REJECTED = wp.constant(7)  #: failed validation <-d, n> >= 0 at the camera hit
L_STEPS = wp.constant(8)  #: ran out of march steps
L_STORED = wp.constant(9)  #: stored in the photon map
L_REFLECTED = wp.constant(10)  #: of the traced power, reflected (informative, not part of the sum)
L_REFRACTED = wp.constant(11)  #: of the traced power, refracted (informative, not part of the sum)
LEDGER_ENTRIES = 12

LEDGER_NAMES = ("sampled", "culled_roughness", "culled_luminance", "absorbed", "lost_light_view",
                "lost_camera_view", "occluded", "rejected", "out_of_steps", "stored", "reflected", "refracted")

R2_A1 = wp.constant(wp.uint32(3242174889))  # round(2^32 / phi_2), phi_2 = 1.32471795724... (Roberts' R2)
R2_A2 = wp.constant(wp.uint32(2447445413))  # round(2^32 / phi_2^2)
U32_TO_UNIT = wp.constant(2.3283064365386963e-10)

FOOTPRINT_EXACT = wp.constant(0)
FOOTPRINT_PAPER = wp.constant(1)


@wp.func
def book(ledger: wp.array(dtype=wp.float64), entry: int, power: wp.vec3):
    wp.atomic_add(ledger, 3 * entry + 0, wp.float64(power[0]))
    wp.atomic_add(ledger, 3 * entry + 1, wp.float64(power[1]))
    wp.atomic_add(ledger, 3 * entry + 2, wp.float64(power[2]))


@wp.kernel
def max_luminance(flux: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.float32)):
    """out[0] = max over texels of luminance(flux) (atomic; out must be zeroed first)."""
    p = wp.tid()
    wp.atomic_max(out, 0, luminance(flux[p]))


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


@wp.kernel
def trace_photons(
    light: ViewParams,
    light_kind: int,  # 0 distant, 1 point, 2 spot
    light_pos: wp.vec3,
    light_dir: wp.vec3,
    # RSM view of the light (flat H*W arrays)
    rsm_opaque_depth: wp.array(dtype=wp.float32),
    rsm_depth: wp.array(dtype=wp.float32),  # specular layer depth [m], 0 = none
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
    k = wp.tid()
    hits[k] = wp.vec4(0.0, 0.0, 0.0, -1.0)
    # 1. texel from the scrambled R2 low-discrepancy sequence
    ux = float(wp.uint32(k) * R2_A1 + wp.uint32(scramble[0])) * U32_TO_UNIT
    uy = float(wp.uint32(k) * R2_A2 + wp.uint32(scramble[1])) * U32_TO_UNIT
    sx = ux * float(light.width)
    sy = uy * float(light.height)
    i = wp.min(int(sx), light.width - 1)
    j = wp.min(int(sy), light.height - 1)
    texel = j * light.width + i
    if rsm_tri[texel] < 0:
        return
    scale = float(light.width * light.height) / float(n_photons)
    power = rsm_flux[texel] * scale
    book(ledger, L_SAMPLED, power)
    if rsm_roughness[texel] > roughness_cutoff:
        book(ledger, L_CULLED_ROUGH, power)
        return
    if luminance(rsm_flux[texel]) < luminance_cutoff * max_lum[0]:
        book(ledger, L_CULLED_LUM, power)
        return
    # 2. origin: the light ray through the sample point, cut with the texel's tangent plane
    lo, ld = pixel_ray_world(light, sx, sy)
    n = rsm_normal[texel]
    x0 = rsm_position[texel]
    denom = wp.dot(ld, n)
    origin = x0
    if wp.abs(denom) > 1.0e-8:
        origin = lo + ld * (wp.dot(x0 - lo, n) / denom)
    d_in = wp.normalize(ld)
    if light_kind != 0:
        d_in = wp.normalize(origin - light_pos)
    # 3. bounce: exact Fresnel as a probability (power unchanged), metals reflect with their albedo
    state = wp.rand_init(seed, k)
    tri = rsm_tri[texel]
    m = triangle_material[tri]
    d = wp.vec3(0.0)
    refracted = int(0)
    if mat_opacity[m] < 1.0:
        eta = rsm_ior[texel]
        nn = n
        if wp.dot(d_in, n) > 0.0:  # arriving from inside the medium
            nn = -n
            eta = 1.0 / eta
        f = fresnel_dielectric(-wp.dot(d_in, nn), eta)
        if wp.randf(state) < f:
            d = reflect(d_in, nn)
        else:
            d = refract(d_in, nn, eta)
            refracted = 1
    else:
        nn = n
        if wp.dot(d_in, n) > 0.0:
            nn = -n
        d = reflect(d_in, nn)
        kept = wp.cw_mul(power, mat_albedo[m])
        book(ledger, L_ABSORBED, power - kept)
        power = kept
    if refracted != 0:
        book(ledger, L_REFRACTED, power)
    else:
        book(ledger, L_REFLECTED, power)
    # 4. march the light view's opaque depth (start a hair off the surface)
    o = origin + d * (1.0e-4 * t_max)
    status, t_end, steps = screen_march(light, rsm_opaque_depth, o, d, t_max, max_steps, thickness, thickness_rel)
    light_hit = status == MARCH_HIT
    if status == MARCH_STEPS:
        book(ledger, L_STEPS, power)
        return
    x_end = o + d * t_end
    # 5. cascade: reproject into the camera view (Fig. 7)
    q = world_project(camera, x_end)
    inside = q[2] > camera.near and q[0] >= 0.0 and q[1] >= 0.0 and q[0] < float(camera.width) and q[1] < float(camera.height)
    if not inside:
        if light_hit:
            book(ledger, L_LOST_CAMERA, power)
        else:
            book(ledger, L_LOST_LIGHT, power)
        return
    pix = int(q[1]) * camera.width + int(q[0])
    zc = cam_depth[pix]
    tol = thickness + thickness_rel * zc
    if zc > 0.0 and q[2] > zc + tol:
        book(ledger, L_OCCLUDED, power)
        return
    on_surface = zc > 0.0 and q[2] >= zc - tol
    if not on_surface:
        if use_cascade == 0:
            book(ledger, L_LOST_LIGHT, power)
            return
        # floating in front of the camera's surfaces: the second chance, march on in the camera view
        status, t2, steps2 = screen_march(camera, cam_depth, x_end, d, t_max, max_steps, thickness, thickness_rel)
        if status == MARCH_STEPS:
            book(ledger, L_STEPS, power)
            return
        if status != MARCH_HIT:
            book(ledger, L_LOST_CAMERA, power)
            return
        x_end = x_end + d * t2
        q = world_project(camera, x_end)
        pix = wp.clamp(int(q[1]), 0, camera.height - 1) * camera.width + wp.clamp(int(q[0]), 0, camera.width - 1)
    # 6. validate against the camera's surface normal
    nr = cam_normal[pix]
    if wp.dot(-d, nr) < 0.0 or cam_depth[pix] <= 0.0:
        book(ledger, L_REJECTED, power)
        return
    # 7. store irradiance over the pixel's footprint
    area = pixel_footprint(camera, cam_solid_angle[pix], cam_position[pix], nr, footprint_mode)
    e = power / area
    if footprint_mode == FOOTPRINT_PAPER:
        e = e * wp.dot(-d, nr)
    wp.atomic_add(photon_map, pix, e)
    book(ledger, L_STORED, power)
    hits[k] = wp.vec4(x_end[0], x_end[1], x_end[2], float(pix))
