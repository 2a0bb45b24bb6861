"""Shading: direct light with shadow maps, and compositing of the water layer into the final HDR image.

Radiance is in W/(m² sr) per RGB channel; a diffuse receiver reflects L = albedo/π · E.
Specular surfaces cast shadows here: light that reaches a receiver through water arrives only as
photons (the caustic irradiance), so nothing is counted twice.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from .optics import fresnel_dielectric, reflect, refract
from .photons.march import MARCH_HIT, screen_march_super_plain
from .raster.views import ViewParams, fixed_projection, pixel_ray_world, read_again, view_eye_world, world_project
from .raster import GBuffer, LightMaps
from .raster.kernels import spot_falloff
from .scene.model import LightKind
from .sky import SkyMap, pcf_visibility, sky_radiance

INV_PI = wp.constant(1.0 / math.pi)


@wp.func
def shadow_visibility(view: ViewParams, shadow_depth: wp.array(dtype=wp.float32), x: wp.vec3, n: wp.vec3, to_light: wp.vec3):
    """(inside, visibility in [0, 1]) of world point ``x`` in one shadow map, bilinear percentage-closer.

    The lookup point is pushed off the surface along its normal by 1.5 texels and compared with a
    one-texel depth bias: texel size is 1/fx [m] for orthographic views and depth/fx for perspective.
    """
    q0 = world_project(view, x)
    texel = 1.0 / view.fx
    if view.orthographic == 0:
        texel = q0[2] / view.fx
    nl = n
    if wp.dot(nl, to_light) < 0.0:
        nl = -nl
    return pcf_visibility(view, shadow_depth, 0, x, nl, texel)


@wp.func
def direct_at(
    shadow_view: ViewParams,
    shadow_depth: wp.array(dtype=wp.float32),
    exclusive: int,
    kind: int,
    light_rgb: wp.vec3,
    light_pos: wp.vec3,
    light_dir: wp.vec3,
    cone_angle: float,
    cone_softness: float,
    x: wp.vec3,
    n: wp.vec3,
) -> wp.vec3:
    """Direct irradiance [W/m²] at world point ``x`` with unit normal ``n`` from one shadow map of one light (zero
    where it adds nothing): the camera's surfaces (:func:`_direct`) and the hidden ones the composite's rays reach
    (``shade_hidden.hidden_direct``)."""
    e = wp.vec3(0.0)
    to_light = -light_dir
    if kind == 0:
        e = light_rgb
    else:
        dl = light_pos - x
        r2 = wp.max(wp.dot(dl, dl), 1.0e-12)
        to_light = dl / wp.sqrt(r2)
        e = light_rgb / r2
        if kind == 2:
            e = e * spot_falloff(wp.dot(-to_light, light_dir), cone_angle, cone_softness)
    cos_n = wp.dot(n, to_light)
    if cos_n <= 0.0:
        return wp.vec3(0.0)
    inside, vis = shadow_visibility(shadow_view, shadow_depth, x, n, to_light)
    if exclusive != 0 and inside == 0:
        return wp.vec3(0.0)
    return e * (cos_n * vis)


@wp.func
def _direct(
    shadow_view: ViewParams,
    shadow_depth: wp.array(dtype=wp.float32),
    exclusive: int,
    kind: int,
    light_rgb: wp.vec3,
    light_pos: wp.vec3,
    light_dir: wp.vec3,
    cone_angle: float,
    cone_softness: float,
    depth: wp.array(dtype=wp.float32),
    position: wp.array(dtype=wp.vec3),
    normal: wp.array(dtype=wp.vec3),
    p: int,
) -> wp.vec3:
    """Pixel ``p``'s direct irradiance [W/m²] from one shadow map of one light (zero where it adds nothing)."""
    if depth[p] <= 0.0:
        return wp.vec3(0.0)
    return direct_at(shadow_view, shadow_depth, exclusive, kind, light_rgb, light_pos, light_dir, cone_angle,
                     cone_softness, position[p], normal[p])


@wp.kernel
def direct_light(
    shadow_view: ViewParams,
    shadow_depth: wp.array(dtype=wp.float32),  # (Hs*Ws,) nearest surface depth of the shadow map [m] (read)
    exclusive: int,  # 1: add only points inside this view (one of several cube faces)
    kind: int,  # LightKind
    light_rgb: wp.vec3,  # W/m² (distant) or W/sr (point, spot)
    light_pos: wp.vec3,  # [m]
    light_dir: wp.vec3,  # unit direction of travel (distant), spot axis
    cone_angle: float,
    cone_softness: float,
    depth: wp.array(dtype=wp.float32),  # (H*W,) camera G-buffer (read)
    position: wp.array(dtype=wp.vec3),
    normal: wp.array(dtype=wp.vec3),
    first: int,  # 1: the frame's first shadow map: write the irradiance (0 where unlit), else add to it
    irradiance: wp.array(dtype=wp.vec3),  # (H*W,) direct irradiance [W/m²] on the opaque surface (write or accumulate)
):
    p = wp.tid()
    e = _direct(shadow_view, shadow_depth, exclusive, kind, light_rgb, light_pos, light_dir, cone_angle, cone_softness,
                depth, position, normal, p)
    if first != 0:
        irradiance[p] = wp.vec3(0.0) + e  # as adding to a zeroed buffer (-0 becomes +0)
    elif e[0] != 0.0 or e[1] != 0.0 or e[2] != 0.0:
        irradiance[p] = irradiance[p] + e


@wp.kernel
def direct_light_pair(
    view_a: ViewParams,  # the first shadow map, as direct_light's arguments
    depth_a: wp.array(dtype=wp.float32),
    exclusive_a: int,
    kind_a: int,
    rgb_a: wp.vec3,
    pos_a: wp.vec3,
    dir_a: wp.vec3,
    cone_a: float,
    softness_a: float,
    view_b: ViewParams,  # the second, added after it
    depth_b: wp.array(dtype=wp.float32),
    exclusive_b: int,
    kind_b: int,
    rgb_b: wp.vec3,
    pos_b: wp.vec3,
    dir_b: wp.vec3,
    cone_b: float,
    softness_b: float,
    depth: wp.array(dtype=wp.float32),  # (H*W,) camera G-buffer (read)
    position: wp.array(dtype=wp.vec3),
    normal: wp.array(dtype=wp.vec3),
    first: int,  # 1: the frame's first shadow maps: write the irradiance, else add to it
    irradiance: wp.array(dtype=wp.vec3),  # (H*W,) direct irradiance [W/m²] (write or accumulate)
):
    """Two shadow maps in one pass: :func:`direct_light` for map a, then for map b, the same float32 sums in the
    same order, with the G-buffer read and the irradiance written once instead of twice."""
    p = wp.tid()
    e = _direct(view_a, depth_a, exclusive_a, kind_a, rgb_a, pos_a, dir_a, cone_a, softness_a, depth, position, normal, p)
    f = _direct(view_b, depth_b, exclusive_b, kind_b, rgb_b, pos_b, dir_b, cone_b, softness_b, depth, position, normal, p)
    acc = wp.vec3(0.0)
    add_e = e[0] != 0.0 or e[1] != 0.0 or e[2] != 0.0
    add_f = f[0] != 0.0 or f[1] != 0.0 or f[2] != 0.0
    if first != 0:
        acc = wp.vec3(0.0) + e
    elif add_e or add_f:
        acc = irradiance[p]
        if add_e:
            acc = acc + e
    if add_f:
        acc = acc + f
    if first != 0 or add_e or add_f:
        irradiance[p] = acc


@wp.func
def lambert_radiance_at(albedo: wp.array(dtype=wp.vec3), direct_irradiance: wp.array(dtype=wp.vec3),
                        caustic_irradiance: wp.array(dtype=wp.vec3), sky_irradiance: wp.array(dtype=wp.vec3),
                        p: int) -> wp.vec3:
    """Pixel ``p``'s Lambertian radiance [W/(m² sr)] where it has an opaque surface: :func:`surface_radiance_at`
    without its depth test, for :func:`composite_gather`'s ``PIXEL_OPAQUE`` pixels, whose depth
    :func:`composite_march` found > 0 (the test's load, and its round trip before the four terms' loads, saved)."""
    return wp.cw_mul(albedo[p], direct_irradiance[p] + caustic_irradiance[p] + sky_irradiance[p]) * INV_PI


@wp.func
def surface_radiance_at(depth: wp.array(dtype=wp.float32), albedo: wp.array(dtype=wp.vec3),
                        direct_irradiance: wp.array(dtype=wp.vec3), caustic_irradiance: wp.array(dtype=wp.vec3),
                        sky_irradiance: wp.array(dtype=wp.vec3), p: int) -> wp.vec3:
    """Pixel ``p``'s Lambertian radiance [W/(m² sr)] (zero without an opaque surface): what :func:`surface_radiance`
    writes, and :func:`composite_gather` computes where it reads it."""
    l_surface = wp.vec3(0.0)
    if depth[p] > 0.0:
        l_surface = lambert_radiance_at(albedo, direct_irradiance, caustic_irradiance, sky_irradiance, p)
    return l_surface


@wp.kernel
def surface_radiance(
    depth: wp.array(dtype=wp.float32),  # (H*W,) opaque depth [m], 0 = none (read)
    albedo: wp.array(dtype=wp.vec3),
    direct_irradiance: wp.array(dtype=wp.vec3),  # [W/m²] (read)
    caustic_irradiance: wp.array(dtype=wp.vec3),  # [W/m²] (read)
    sky_irradiance: wp.array(dtype=wp.vec3),  # [W/m²] from the dome light, occluded (read)
    radiance: wp.array(dtype=wp.vec3),  # (H*W,) Lambertian radiance of the opaque surface [W/(m² sr)] (write)
    flip: int,  # as composite_gather's: 1: parity[0] = 1 - parity[0] (SVGF's deferred frame ends here)
    parity: wp.array(dtype=wp.int32),
):
    """The sequential program's surface radiance (``caustic_irradiance`` possibly SVGF's packed output in place, as
    :func:`composite_gather`'s)."""
    p = wp.tid()
    if flip != 0 and p == 0:
        parity[0] = 1 - parity[0]
    radiance[p] = surface_radiance_at(depth, albedo, direct_irradiance, caustic_irradiance, sky_irradiance, p)


#: CUDA launch bounds of :func:`composite` (threads a block, blocks an SM): its two marches are latency-bound (one
#: dependent depth or bounds read a step), so warps in flight matter more than registers. nvcc gives it 110
#: registers unbounded (2 blocks of 256 an SM); measured on an H100, pool 1080p: 0.617 ms unbounded, 0.463 at
#: (256, 3), 0.401 at (256, 4), images bitwise equal (the bound changes register allocation, not arithmetic).
COMPOSITE_LAUNCH_BOUNDS = (256, 4)
#: threads a block :func:`composite` and :func:`composite_march` are launched with (at most the bounds' 256; at 64
#: registers an SM holds the same 1024 threads in blocks of 64, and a block whose one water warp marches long holds
#: 2 warps' slot instead of 8). 256 as measured so far; 64 is the probe of docs/perf_notes.md section 72
COMPOSITE_BLOCK_DIM = 256


MISSED_REFRACTED = wp.constant(1)  #: ``composite``'s ``missed`` bit: the refracted ray's march found nothing
MISSED_REFLECTED = wp.constant(2)  #: ``composite``'s ``missed`` bit: the reflected ray's march found nothing


@wp.func
def water_rays(camera: ViewParams, x: wp.vec3, n_surface: wp.vec3, ior: float):
    """A water pixel's camera ray at its surface point ``x``: (Fresnel reflectance F, reflected direction, refracted
    direction, relative index η as the ray crosses the boundary). Seen from inside the medium the normal and η are
    turned round; under total internal reflection F = 1 and the refracted direction is unused (zero)."""
    v = view_eye_world(camera, x)  # towards the eye; the view plane's normal for an orthographic camera
    n = n_surface
    eta = ior
    if wp.dot(v, n) < 0.0:  # seen from inside the medium
        n = -n
        eta = 1.0 / eta
    f = fresnel_dielectric(wp.dot(v, n), eta)
    d_in = -v
    dr = reflect(d_in, n)
    dt = wp.vec3(0.0)
    if f < 1.0:
        dt = refract(d_in, n, eta)
    return f, dr, dt, eta


HIT_NONE = wp.constant(-1)  #: :func:`composite_march`'s ``hits``: the ray adds no surface's radiance
PIXEL_OPAQUE = wp.constant(-2)  #: ``hits[p][0]`` of a pixel without water that sees an opaque surface
PIXEL_SKY = wp.constant(-3)  #: ``hits[p][0]`` of a pixel that sees nothing (its sky radiance is in ``final``)


def _make_composite(camera_ortho: int = -1):
    """:func:`screen_space_hit`, :func:`screen_space_lookup` and the kernels :func:`composite` and
    :func:`composite_march`. ``camera_ortho``: -1 reads the camera's projection (``ViewParams.orthographic``) at run
    time (the module's kernels, the twins); 0 or 1 compiles them for a perspective or an orthographic camera
    (:func:`projected_composite`): the camera is read with its ``orthographic`` field replaced by the constant,
    which the compiler folds through ``water_rays`` (``view_eye_world``), ``pixel_ray_world``, the marches and
    ``world_project``, so a launch carries only its projection's code (docs/perf_notes.md sections 51, 56); the same
    values wherever the constant equals the camera's field: the same bits. Such kernels are modules of their own,
    compiled when first launched; an orthographic camera's are named ``*_orthocam``."""
    CAMERA_ORTHO = int(camera_ortho)
    kernel_module = None if CAMERA_ORTHO < 0 else "unique"

    camera_projected = fixed_projection(CAMERA_ORTHO)

    @wp.func
    def camera_view(cameras: wp.array(dtype=ViewParams), anchor: int) -> ViewParams:
        """``read_again(cameras, 0, anchor)``, its projection the compiled one where the composite has one."""
        return camera_projected(read_again(cameras, 0, anchor))

    @wp.func
    def screen_space_hit(cameras: wp.array(dtype=ViewParams), anchor: int, depth: wp.array(dtype=wp.float32),
                         depth_bounds: wp.array(dtype=wp.vec2), super_bounds: wp.array(dtype=wp.vec2), o: wp.vec3,
                         d: wp.vec3, t_max: float, max_steps: int, thickness: float) -> int:
        """The camera pixel (``j·W + i``) whose opaque surface a ray from ``o`` along ``d`` reaches in the camera's depth
        buffer, or -1 when the ray leaves the image or runs out of steps (the camera ``cameras[0]``, read where the march
        needs it and again after it, ``anchor`` >= 0: see ``views.read_again``; its projection the compiled one where
        the composite has one). Reads the G-buffer's depth only, through its bounds' three levels (``super_bounds``:
        ``march.super_bounds`` of ``depth_bounds``; the march ends where the naive one does, docs/perf_notes.md
        section 72)."""
        status, t, steps = screen_march_super_plain(camera_view(cameras, anchor), depth, depth_bounds, super_bounds, o,
                                                    d, t_max, max_steps, thickness, 0.02)  # the front depths only (H*W)
        if status != MARCH_HIT:
            return int(-1)
        camera = camera_view(cameras, steps)
        q = world_project(camera, o + d * t)
        i = wp.clamp(int(q[0]), 0, camera.width - 1)
        j = wp.clamp(int(q[1]), 0, camera.height - 1)
        return j * camera.width + i


    @wp.func
    def screen_space_lookup(cameras: wp.array(dtype=ViewParams), anchor: int, depth: wp.array(dtype=wp.float32),
                            depth_bounds: wp.array(dtype=wp.vec2), super_bounds: wp.array(dtype=wp.vec2),
                            radiance: wp.array(dtype=wp.vec3), o: wp.vec3, d: wp.vec3, t_max: float, max_steps: int,
                            thickness: float):
        """Radiance of the opaque surface a ray from ``o`` along ``d`` reaches in the camera's depth buffer
        (:func:`screen_space_hit`'s pixel). Returns (found, radiance); not found when the ray leaves the image or runs
        out of steps."""
        h = screen_space_hit(cameras, anchor, depth, depth_bounds, super_bounds, o, d, t_max, max_steps, thickness)
        if h < 0:
            return int(0), wp.vec3(0.0)
        return int(1), radiance[h]

    def composite(
        cameras: wp.array(dtype=ViewParams),  # (2,) this frame's camera first (frame.FrameInputs.cameras, read)
        depth: wp.array(dtype=wp.float32),  # (H*W,) opaque depth [m], 0 = none (read)
        depth_bounds: wp.array(dtype=wp.vec2),  # march.depth_bounds of depth with (thickness, 0.02) (read)
        super_bounds: wp.array(dtype=wp.vec2),  # (march.super_shape,) march.super_bounds of depth_bounds (read)
        radiance: wp.array(dtype=wp.vec3),  # (H*W,) opaque surface radiance [W/(m² sr)] (read)
        water_depth: wp.array(dtype=wp.float32),  # (H*W,) water layer depth [m], 0 = none (read)
        water_position: wp.array(dtype=wp.vec3),
        water_normal: wp.array(dtype=wp.vec3),
        water_ior: wp.array(dtype=wp.float32),
        t_max: float,
        max_steps: int,
        thickness: float,
        sky: SkyMap,  # radiance of the dome light, seen where a ray finds no surface (black without one)
        final: wp.array(dtype=wp.vec3),  # (H*W,) HDR radiance reaching the camera [W/(m² sr)] (write)
        missed: wp.array(dtype=wp.int32),  # (H*W,) MISSED_* bits of the rays left to shade_hidden (write)
        hidden_rays: int,  # MISSED_* bits of the rays handed to shade_hidden when their march finds nothing
    ):
        """Opaque pixels show their surface; water pixels Fresnel-blend screen-space refraction and reflection.

        The refracted camera ray is marched through the opaque G-buffer (how caustics under water are
        seen, the ESDSL paths of seed 000 Fig. 3); radiance crossing the boundary is scaled by
        (n_t/n_i)² (L/n² is invariant along a ray). A camera ray that meets no surface sees the sky (``sky``; black
        when the scene has none). A reflected or refracted ray whose march finds nothing (it leaves the image, or passes
        behind a surface) and whose bit is set in ``hidden_rays`` adds nothing here: its bit in ``missed`` hands it to
        :mod:`cisp_warp.shade_hidden`, which traces it against the opaque layer and adds what it reaches. Without its
        bit, the screen-space fallbacks: a reflected ray sees the sky, a refracted one the opaque surface behind the
        water pixel itself (the undistorted background).
        """
        p = wp.tid()
        camera = camera_view(cameras, 0)
        l = radiance[p]
        bits = int(0)
        if depth[p] <= 0.0 and water_depth[p] <= 0.0:
            px = float(p % camera.width) + 0.5
            py = float(p // camera.width) + 0.5
            o, d = pixel_ray_world(camera, px, py)
            l = sky_radiance(sky, d)
        if water_depth[p] > 0.0:
            x = water_position[p]
            f, dr, dt, eta = water_rays(camera, x, water_normal[p], water_ior[p])
            l = wp.vec3(0.0)
            if f > 0.0:
                found, lr = screen_space_lookup(cameras, p, depth, depth_bounds, super_bounds, radiance, x, dr, t_max,
                                                max_steps, thickness)
                if found == 0:
                    if (hidden_rays & MISSED_REFLECTED) != 0:
                        bits = bits | MISSED_REFLECTED
                    else:
                        lr = sky_radiance(sky, dr)
                l = l + lr * f
            if f < 1.0:
                found, lt = screen_space_lookup(cameras, p + 1, depth, depth_bounds, super_bounds, radiance, x, dt,
                                                t_max, max_steps, thickness)
                if found == 0:
                    if (hidden_rays & MISSED_REFRACTED) != 0:
                        bits = bits | MISSED_REFRACTED
                    else:
                        lt = radiance[p]
                l = l + lt * ((1.0 - f) / (eta * eta))
        final[p] = l
        missed[p] = bits

    def composite_march(
        cameras: wp.array(dtype=ViewParams),  # (2,) this frame's camera first (frame.FrameInputs.cameras, read)
        depth: wp.array(dtype=wp.float32),  # (H*W,) opaque depth [m], 0 = none (read)
        depth_bounds: wp.array(dtype=wp.vec2),  # march.depth_bounds of depth with (thickness, 0.02) (read)
        super_bounds: wp.array(dtype=wp.vec2),  # (march.super_shape,) march.super_bounds of depth_bounds (read)
        water_depth: wp.array(dtype=wp.float32),  # (H*W,) water layer depth [m], 0 = none (read)
        water_position: wp.array(dtype=wp.vec3),
        water_normal: wp.array(dtype=wp.vec3),
        water_ior: wp.array(dtype=wp.float32),
        t_max: float,
        max_steps: int,
        thickness: float,
        sky: SkyMap,
        final: wp.array(dtype=wp.vec3),  # (H*W,) what the composite adds before any surface's radiance (write; see below)
        hits: wp.array(dtype=wp.vec2i),  # (H*W,) per pixel (reflected, refracted) hit pixel, HIT_NONE, or a PIXEL_* code
        weights: wp.array(dtype=wp.vec2),  # (H*W,) water pixels: (F, (1 − F)/η²), the rays' throughputs (write)
        missed: wp.array(dtype=wp.int32),  # (H*W,) MISSED_* bits of the rays left to shade_hidden (write)
        hidden_rays: int,  # MISSED_* bits of the rays handed to shade_hidden when their march finds nothing
    ):
        """:func:`composite`'s G-buffer half: everything it computes but the opaque radiance read at the marches' hits,
        which :func:`composite_gather` adds once the caustics are known. Reads the camera, depth, bounds and water layer
        only, so it runs beside the photon trace.

        Per pixel: a sky pixel's radiance goes to ``final`` (``hits`` = (PIXEL_SKY, 0)); an opaque pixel writes
        (PIXEL_OPAQUE, 0); a water pixel writes the hit pixels of its reflected and refracted rays (HIT_NONE where the
        ray adds no surface's radiance: F = 0, F = 1, or handed to shade_hidden; the refracted ray's screen-space
        fallback is the pixel itself), their throughputs, and to ``final`` the composite's sum before its reflected
        ray's radiance (zero, or the sky's radiance along a missed reflected ray times F), with the same float32
        operations in the same order as :func:`composite`."""
        p = wp.tid()
        camera = camera_view(cameras, 0)
        bits = int(0)
        if water_depth[p] > 0.0:
            x = water_position[p]
            f, dr, dt, eta = water_rays(camera, x, water_normal[p], water_ior[p])
            l = wp.vec3(0.0)
            hr = int(HIT_NONE)
            ht = int(HIT_NONE)
            wt = float(0.0)
            if f > 0.0:
                hr = screen_space_hit(cameras, p, depth, depth_bounds, super_bounds, x, dr, t_max, max_steps, thickness)
                if hr < 0:
                    lr = wp.vec3(0.0)
                    if (hidden_rays & MISSED_REFLECTED) != 0:
                        bits = bits | MISSED_REFLECTED
                    else:
                        lr = sky_radiance(sky, dr)
                    l = l + lr * f
            if f < 1.0:
                wt = (1.0 - f) / (eta * eta)
                ht = screen_space_hit(cameras, p + 1, depth, depth_bounds, super_bounds, x, dt, t_max, max_steps,
                                    thickness)
                if ht < 0:
                    if (hidden_rays & MISSED_REFRACTED) != 0:
                        bits = bits | MISSED_REFRACTED  # composite adds zero · wt: l unchanged (l is never -0)
                    else:
                        ht = p  # the undistorted background
            final[p] = l
            hits[p] = wp.vec2i(hr, ht)
            weights[p] = wp.vec2(f, wt)
        elif depth[p] <= 0.0:
            px = float(p % camera.width) + 0.5
            py = float(p // camera.width) + 0.5
            o, d = pixel_ray_world(camera, px, py)
            final[p] = sky_radiance(sky, d)
            hits[p] = wp.vec2i(PIXEL_SKY, 0)
        else:
            hits[p] = wp.vec2i(PIXEL_OPAQUE, 0)
        missed[p] = bits

    def kernel(f):
        f.__qualname__ = f.__name__ + ("_orthocam" if CAMERA_ORTHO == 1 else "")
        if CAMERA_ORTHO < 0:
            return wp.kernel(f, launch_bounds=COMPOSITE_LAUNCH_BOUNDS, module=kernel_module)
        return wp.kernel(f, launch_bounds=COMPOSITE_LAUNCH_BOUNDS, module=kernel_module, enable_backward=False)

    return screen_space_hit, screen_space_lookup, kernel(composite), kernel(composite_march)


#: the run-time kernels (the camera's projection read per launch): the twins of the projected ones
screen_space_hit, screen_space_lookup, composite, composite_march = _make_composite()

#: ``projected_composite`` gives the kernels compiled for the camera's projection (False: the run-time ones, the twins)
PROJECTED = True

_PROJECTED_COMPOSITES: dict = {}


def projected_composite(camera_ortho: int) -> tuple:
    """(:func:`composite`, :func:`composite_march`) compiled for a perspective (0) or orthographic (1) camera
    (:func:`_make_composite`), made on first use, each a module of its own. The same inputs, the same outputs bit for
    bit where ``cameras[0]`` has that projection (``tests/test_shade_projected.py``)."""
    key = int(camera_ortho)
    if key not in _PROJECTED_COMPOSITES:
        _PROJECTED_COMPOSITES[key] = _make_composite(key)[2:]
    return _PROJECTED_COMPOSITES[key]


def composite_kernels(orthographic: bool | None) -> tuple:
    """The (composite, composite_march) to launch for a camera of that projection (the host's ``View.orthographic``):
    the projected ones with :data:`PROJECTED`, else (or ``orthographic`` None) the run-time ones."""
    if orthographic is None or not PROJECTED:
        return composite, composite_march
    return projected_composite(int(bool(orthographic)))


@wp.func
def gather_pixel(
    depth: wp.array(dtype=wp.float32),
    albedo: wp.array(dtype=wp.vec3),
    direct_irradiance: wp.array(dtype=wp.vec3),
    caustic_irradiance: wp.array(dtype=wp.vec3),
    sky_irradiance: wp.array(dtype=wp.vec3),
    hits: wp.array(dtype=wp.vec2i),
    weights: wp.array(dtype=wp.vec2),
    missed: wp.array(dtype=wp.int32),
    hidden_sum: wp.array(dtype=wp.vec3),
    hidden: int,
    final: wp.array(dtype=wp.vec3),
    p: int,
):
    """Pixel ``p`` of :func:`composite_gather`: (1, what it writes to ``final[p]``, the pixel's ``missed`` bits where
    ``hidden``, else 0), or (0, zero, 0) for a sky pixel, whose ``final`` is :func:`composite_march`'s already (the
    kernel that folds the hidden hits' shading into the gather, ``shade_hidden.composite_gather_hidden``, calls it
    too)."""
    h = hits[p]
    if h[0] == PIXEL_SKY:
        return int(0), wp.vec3(0.0), int(0)
    if h[0] == PIXEL_OPAQUE:  # composite_march's depth[p] > 0: surface_radiance_at's value without its test
        return int(1), lambert_radiance_at(albedo, direct_irradiance, caustic_irradiance, sky_irradiance, p), int(0)
    w = weights[p]
    bits = int(0)
    if hidden != 0:
        bits = missed[p]
    l = final[p]
    if h[0] >= 0 and (bits & MISSED_REFLECTED) == 0:
        lr = surface_radiance_at(depth, albedo, direct_irradiance, caustic_irradiance, sky_irradiance, h[0])
        l = wp.vec3(0.0) + lr * w[0]
    if h[1] >= 0 and (bits & MISSED_REFRACTED) == 0:
        lt = surface_radiance_at(depth, albedo, direct_irradiance, caustic_irradiance, sky_irradiance, h[1])
        l = l + lt * w[1]
    if (bits & (MISSED_REFRACTED | MISSED_REFLECTED)) != 0:
        # trace_hidden's sum: refracted ray first, then reflected; a ray seen by the camera reads its pixel here, the
        # others' terms are summed in hidden_sum (from zero, in that order)
        lh = hidden_sum[p]
        if (bits & MISSED_REFRACTED) != 0 and h[1] >= 0:
            lt = surface_radiance_at(depth, albedo, direct_irradiance, caustic_irradiance, sky_irradiance, h[1])
            lh = wp.vec3(0.0) + lt * w[1]
            if (bits & MISSED_REFLECTED) != 0 and h[0] < 0:
                lh = lh + hidden_sum[p]  # = 0 + the reflected term: adding it to a sum that is never -0 is the same
        if (bits & MISSED_REFLECTED) != 0 and h[0] >= 0:
            lr = surface_radiance_at(depth, albedo, direct_irradiance, caustic_irradiance, sky_irradiance, h[0])
            lh = lh + lr * w[0]
        l = l + lh
    return int(1), l, bits


@wp.kernel
def composite_gather(
    depth: wp.array(dtype=wp.float32),  # (H*W,) opaque depth [m], 0 = none (read)
    albedo: wp.array(dtype=wp.vec3),  # the opaque surface's radiance terms, as surface_radiance's (read)
    direct_irradiance: wp.array(dtype=wp.vec3),  # [W/m²]
    caustic_irradiance: wp.array(dtype=wp.vec3),  # [W/m²] (the denoiser's)
    sky_irradiance: wp.array(dtype=wp.vec3),  # [W/m²]
    hits: wp.array(dtype=wp.vec2i),  # (H*W,) composite_march's, with shade_hidden's seen pixels where ``hidden`` (read)
    weights: wp.array(dtype=wp.vec2),  # (H*W,) composite_march's throughputs (read)
    missed: wp.array(dtype=wp.int32),  # (H*W,) MISSED_* bits (read where ``hidden``)
    hidden_sum: wp.array(dtype=wp.vec3),  # (H*W,) shade_hidden's sum of its rays' terms that need no radiance (read)
    hidden: int,  # 1: shade_hidden traced the missed rays (trace_hidden_rays): add what they bring
    final: wp.array(dtype=wp.vec3),  # (H*W,) composite_march's partial sums (read); the HDR image (write)
    flip: int,  # 1: end SVGF's frame here, parity[0] = 1 - parity[0] (its deferred output: SVGF.denoise's ``defer``)
    parity: wp.array(dtype=wp.int32),  # (1,) SVGF's parity (written where ``flip``)
):
    """:func:`composite`'s photon half, after the denoiser: the opaque radiance (:func:`surface_radiance_at`, read
    where needed: no radiance buffer) at :func:`composite_march`'s hits, blended with its throughputs; with
    ``hidden``, then what ``shade_hidden.trace_hidden_rays`` found for the missed rays. :func:`surface_radiance` +
    :func:`composite` + ``shade_hidden.trace_hidden`` in one pass: the same float32 sums in the same order, so the
    image is theirs bit for bit on the CPU (:func:`gather_pixel`). ``caustic_irradiance`` may be SVGF's packed output
    read in place (``SVGF.packed_color``, a strided view), ``flip`` then ending SVGF's frame (no launch reads the
    parity after this one in the frame)."""
    p = wp.tid()
    if flip != 0 and p == 0:
        parity[0] = 1 - parity[0]
    written, l, bits = gather_pixel(depth, albedo, direct_irradiance, caustic_irradiance, sky_irradiance, hits, weights,
                                    missed, hidden_sum, hidden, final, p)
    if written != 0:
        final[p] = l


def shadow_map_args(lights: list[LightMaps]) -> list[list]:
    """The first nine arguments of :func:`direct_light` (those of :func:`direct_at`: view, depth, exclusive, kind,
    RGB, position, direction, cone angle and softness) for every shadow map of every light, in order."""
    maps = []
    for lm in lights:
        light = lm.light
        light_maps = lm.shadow_maps()
        rgb = light.radiometric_rgb.astype(np.float32)
        for view, depth in light_maps:
            maps.append([view, depth, int(len(light_maps) > 1), int(light.kind), wp.vec3(*rgb),
                         wp.vec3(*np.asarray(light.position, np.float32)),
                         wp.vec3(*np.asarray(light.direction, np.float32)),
                         float(light.cone_angle), float(light.cone_softness)])
    return maps


class DirectLighting:
    """Direct irradiance [W/m²] on the camera's opaque surfaces from every light, shadowed by every surface."""

    def __init__(self, gbuffer: GBuffer, device):
        self.device = device
        self.irradiance = wp.zeros(gbuffer.width * gbuffer.height, dtype=wp.vec3, device=device)
        self.pairs = True  #: two shadow maps a launch (False: one a launch, direct_light alone: the twin)

    def render(self, gbuffer: GBuffer, lights: list[LightMaps]) -> None:
        """Write ``irradiance``: the first launch writes every pixel (no memset first), the rest add. Shadow maps go
        two at a time (:func:`direct_light_pair`; the lights' maps in order, across lights), an odd one last alone
        (:func:`direct_light`, the twin); ``pairs`` = False launches every map alone."""
        maps = shadow_map_args(lights)
        if not maps:
            self.irradiance.zero_()
        g = [gbuffer.depth, gbuffer.position, gbuffer.normal]
        n = gbuffer.width * gbuffer.height
        first = 1
        i = 0
        while i < len(maps):
            if self.pairs and i + 1 < len(maps):
                wp.launch(direct_light_pair, dim=n, device=self.device,
                          inputs=maps[i] + maps[i + 1] + g + [first, self.irradiance])
                i += 2
            else:
                wp.launch(direct_light, dim=n, device=self.device, inputs=maps[i] + g + [first, self.irradiance])
                i += 1
            first = 0


__all__ = ["DirectLighting", "HIT_NONE", "MISSED_REFLECTED", "MISSED_REFRACTED", "PIXEL_OPAQUE", "PIXEL_SKY",
           "composite", "composite_gather", "composite_kernels", "composite_march", "direct_at", "direct_light",
           "direct_light_pair", "gather_pixel", "lambert_radiance_at", "LightKind", "projected_composite",
           "shadow_map_args", "surface_radiance_at", "water_rays"]
