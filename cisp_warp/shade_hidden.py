"""The composite's rays that screen space cannot follow: traced against the opaque layer's BVH, shaded at what they hit.

:func:`cisp_warp.shade.composite` follows a water pixel's reflected and refracted camera rays through the camera's
depth buffer. Where that march fails (the ray leaves the image, or passes behind a surface and finds nothing it can
see), it flags the ray in ``missed`` and adds nothing for it; this pass then finds what the ray really reaches, as
the reference's camera paths do (``photons.kernels_world.camera_paths``), on the opaque layer's ``wp.Mesh`` BVH
(``DeviceScene.bvh(LAYER_OPAQUE)``, built once, refit only when opaque geometry moves):

============================  =====================================================================================
the ray ...                   radiance it brings [W/(m² sr)], times its throughput (F reflected, (1 − F)/η² refracted)
============================  =====================================================================================
meets no opaque surface       the sky's radiance along it (``sky.sky_radiance``; black without a sky)
lands on a surface the        that pixel's surface radiance: direct + caustic + sky, the G-buffer's own (the same
camera sees                   test as the reference's photon store: in the pixel, within two pixel widths of its
                              tangent plane)
lands where the camera        albedo/π · (direct + sky + caustic irradiance) at the hit: the sky's occlusion maps
does not see                  (``sky.sky_irradiance_at``) here, the shadow maps in :func:`hidden_direct`, one launch
                              per map; the caustic from the light-space map of every photon that landed
                              (``photons.hidden_flux``) in :func:`hidden_caustic`, one launch per light (none for a
                              method that keeps no such map: caustics_map)
============================  =====================================================================================

Which rays come here is the renderer's ``hidden_rays`` setting (``shade.composite``'s bits): by default only the
refracted ones (docs/perf_notes.md section 31: on the pool 91% of the fallback rays are reflections, which keep the
sky at no cost in FLIP).

Buffers (per pixel p; slot 2p is the refracted ray, 2p + 1 the reflected one):

``missed``      (H*W,) int32: bits MISSED_REFRACTED, MISSED_REFLECTED set by the composite (written for every pixel);
                :func:`trace_hidden` adds HIDDEN_REFRACTED, HIDDEN_REFLECTED where that ray's hit awaits direct light
``hidden_tri``  (2*H*W,) int32: scene triangle + 1 of a hidden hit, negated where the shading normal is flipped
                to face the ray (read only where the HIDDEN bit is set)
``hidden_uvw``  (2*H*W,) vec3: the hit's barycentrics (u, v: weights of the triangle's first and second vertex,
                as ``wp.mesh_query_ray``) and the ray's throughput [1]

The renderer's concurrent program splits this pass round the photons (docs/perf_notes.md section 47):
:func:`trace_hidden_rays` (after ``shade.composite_march``, beside the photon trace) traces and shades what needs no
photons, leaving a hit the camera sees as a pixel index in ``hits`` for ``shade.composite_gather``, which adds what
:func:`trace_hidden` adds, after the denoiser; :func:`trace_hidden` (the sequential program) is its twin. There the
gather also adds what :func:`hidden_direct` and :func:`hidden_caustic` add (:func:`gather_hidden_kernel`'s
``composite_gather_hidden``, one launch instead of one per shadow map and per light after the frame's join;
docs/perf_notes.md section 76); ``HiddenSurfaces.GATHERED`` False launches them apart (the twin).
"""

from __future__ import annotations

import math

import warp as wp

from .raster.views import ViewParams, fixed_projection, world_project
from .photons.hidden_flux import hidden_irradiance
from .scene.model import LAYER_OPAQUE
from .shade import MISSED_REFLECTED, MISSED_REFRACTED, direct_at, gather_pixel, shadow_map_args, water_rays
from .sky import SkyMap, sky_irradiance_at, sky_radiance

INV_PI = wp.constant(1.0 / math.pi)

HIDDEN_REFRACTED = wp.constant(4)  #: the refracted ray landed where the camera does not see: direct light pending
HIDDEN_REFLECTED = wp.constant(8)  #: the reflected ray likewise


@wp.struct
class OpaqueLayer:
    """The opaque triangles as the hidden-surface rays see them (views of ``DeviceScene`` arrays, no copies)."""

    mesh: wp.uint64  #: BVH over the opaque layer (``DeviceScene.bvh(LAYER_OPAQUE)``)
    has_mesh: int  #: 0: the scene has no opaque triangles (``mesh`` unset; every ray meets the sky)
    face_to_tri: wp.array(dtype=wp.int32)  #: (F,) scene triangle of each BVH face
    points: wp.array(dtype=wp.vec3)  #: (V,) [m]
    normals: wp.array(dtype=wp.vec3)  #: (V,) unit vertex normals
    indices: wp.array(dtype=wp.int32)  #: (3T,)
    triangle_material: wp.array(dtype=wp.int32)  #: (T,)
    albedo: wp.array(dtype=wp.vec3)  #: (M,) diffuse reflectance


@wp.struct
class SkyOcclusion:
    """What ``sky.sky_irradiance_at`` reads (``sky.SkyLighting``'s arrays; zeros without a sky: no irradiance)."""

    sh: wp.array(dtype=wp.vec3)  #: (9,) convolved SH coefficients of the sky [W/m²]
    views: wp.array(dtype=ViewParams)  #: (K,) occlusion map views
    directions: wp.array(dtype=wp.vec3)  #: (K,) unit directions towards the sky
    luminance: wp.array(dtype=wp.float32)  #: (K,) sky luminance along them [W/(m² sr)]
    map_depth: wp.array(dtype=wp.float32)  #: (K*S*S,) occlusion maps [m]
    map_texels: int  #: S*S


@wp.func
def opaque_hit(layer: OpaqueLayer, o: wp.vec3, d: wp.vec3, t_max: float):
    """Nearest opaque triangle along ``o + d·t`` (unit ``d``), t in (0, t_max], by the BVH: (scene triangle or -1,
    u, v, t)."""
    q = wp.mesh_query_ray(layer.mesh, o, d, t_max)
    if not q.result:
        return int(-1), float(0.0), float(0.0), float(0.0)
    return layer.face_to_tri[q.face], q.u, q.v, q.t


@wp.func
def opaque_hit_naive(layer: OpaqueLayer, o: wp.vec3, d: wp.vec3, t_max: float):
    """:func:`opaque_hit`'s naive twin: every triangle of the layer (Möller-Trumbore), no BVH. Same returns; u and v
    the weights of the first and second vertex, as ``wp.mesh_query_ray`` gives them."""
    best = int(-1)
    bu = float(0.0)
    bv = float(0.0)
    bt = t_max
    for f in range(layer.face_to_tri.shape[0]):
        tri = layer.face_to_tri[f]
        p0 = layer.points[layer.indices[3 * tri]]
        p1 = layer.points[layer.indices[3 * tri + 1]]
        p2 = layer.points[layer.indices[3 * tri + 2]]
        e1 = p1 - p0
        e2 = p2 - p0
        pv = wp.cross(d, e2)
        det = wp.dot(e1, pv)
        if wp.abs(det) > 1.0e-30:
            inv = 1.0 / det
            s = o - p0
            b1 = wp.dot(s, pv) * inv  # weight of p1
            qv = wp.cross(s, e1)
            b2 = wp.dot(d, qv) * inv  # weight of p2
            t = wp.dot(e2, qv) * inv
            if b1 >= 0.0 and b2 >= 0.0 and b1 + b2 <= 1.0 and t > 0.0 and t <= bt:
                best = tri
                bt = t
                bu = 1.0 - b1 - b2
                bv = b1
    if best < 0:
        return int(-1), float(0.0), float(0.0), float(0.0)
    return best, bu, bv, bt


@wp.func
def hidden_point(layer: OpaqueLayer, tri: int, u: float, v: float):
    """(world point [m], interpolated unit shading normal, geometric normal) of triangle ``tri`` at (u, v)."""
    i0 = layer.indices[3 * tri]
    i1 = layer.indices[3 * tri + 1]
    i2 = layer.indices[3 * tri + 2]
    p0 = layer.points[i0]
    p1 = layer.points[i1]
    p2 = layer.points[i2]
    w = 1.0 - u - v
    y = p0 * u + p1 * v + p2 * w
    ng = wp.cross(p1 - p0, p2 - p0)
    n = layer.normals[i0] * u + layer.normals[i1] * v + layer.normals[i2] * w
    ln = wp.length(n)
    if ln < 1.0e-12:
        n = wp.normalize(ng)
    else:
        n = n / ln
    return y, n, ng


@wp.func
def seen_by_camera(camera: ViewParams, depth: wp.array(dtype=wp.float32), position: wp.array(dtype=wp.vec3),
                   normal: wp.array(dtype=wp.vec3), y: wp.vec3) -> int:
    """Camera pixel whose G-buffer surface is the point ``y`` (the reference's store test: ``y`` projects into the
    pixel and lies within two pixel widths of its tangent plane), or -1."""
    q = world_project(camera, y)
    if q[2] <= camera.near or q[0] < 0.0 or q[1] < 0.0 or q[0] >= float(camera.width) or q[1] >= float(camera.height):
        return -1
    pix = int(q[1]) * camera.width + int(q[0])
    zc = depth[pix]
    if zc <= 0.0:
        return -1
    pixel_size = zc / camera.fx
    if camera.orthographic != 0:
        pixel_size = 1.0 / camera.fx
    if wp.abs(wp.dot(y - position[pix], normal[pix])) > 2.0 * pixel_size:
        return -1
    return pix


def _hidden_ray_func(naive: bool):
    @wp.func
    def hidden_ray(layer: OpaqueLayer, camera: ViewParams, depth: wp.array(dtype=wp.float32),
                   position: wp.array(dtype=wp.vec3), normal: wp.array(dtype=wp.vec3), sky: SkyMap,
                   occlusion: SkyOcclusion, t_max: float, x: wp.vec3, d: wp.vec3, w: float):
        """One ray of :func:`trace_hidden` from ``x`` along ``d`` with throughput ``w``, on the BVH (every triangle:
        ``naive``): (camera pixel that sees its hit, or -1; its radiance term where no pixel sees it: the sky's
        along ``d``, or a hidden hit's albedo/π · sky irradiance, times ``w``; ±(triangle + 1) of a hidden hit, or 0
        (the sign: the shading normal flipped to face the ray); the hit's barycentrics u, v)."""
        tri = int(-1)
        u = float(0.0)
        v = float(0.0)
        t = float(0.0)
        if layer.has_mesh != 0:
            if wp.static(naive):
                tri, u, v, t = opaque_hit_naive(layer, x, d, t_max)
            else:
                tri, u, v, t = opaque_hit(layer, x, d, t_max)
        if tri < 0:
            return int(-1), sky_radiance(sky, d) * w, int(0), u, v
        y, n, ng = hidden_point(layer, tri, u, v)
        pix = seen_by_camera(camera, depth, position, normal, y)
        if pix >= 0:
            return pix, wp.vec3(0.0), int(0), u, v
        sign = int(1)  # the shading normal on the geometric one's side, then facing the ray
        if wp.dot(n, ng) < 0.0:
            sign = -sign
        if wp.dot(n, d) * float(sign) > 0.0:
            sign = -sign
        n = n * float(sign)
        rho = layer.albedo[layer.triangle_material[tri]]
        e_sky = sky_irradiance_at(y, n, occlusion.sh, occlusion.views, occlusion.directions,
                                  occlusion.luminance, occlusion.map_depth, occlusion.map_texels)
        return int(-1), wp.cw_mul(rho, e_sky) * (INV_PI * w), (tri + 1) * sign, u, v

    return hidden_ray


_HIDDEN_RAY = {naive: _hidden_ray_func(naive) for naive in (False, True)}


def _water_ray_func(naive: bool):
    hidden_ray = _HIDDEN_RAY[naive]

    @wp.func
    def water_ray(k: int, p: int, bits: int, layer: OpaqueLayer, camera: ViewParams, depth: wp.array(dtype=wp.float32),
                  position: wp.array(dtype=wp.vec3), normal: wp.array(dtype=wp.vec3), sky: SkyMap,
                  occlusion: SkyOcclusion, t_max: float, x: wp.vec3, f: float, dr: wp.vec3, dt: wp.vec3, eta: float,
                  hidden_tri: wp.array(dtype=wp.int32), hidden_uvw: wp.array(dtype=wp.vec3)):
        """Ray ``k`` (0 refracted, 1 reflected) of water pixel ``p``, one the composite could not follow: the pixel
        the camera sees at its hit (>= 0), or -1 and the ray's term; a hidden hit is booked (``hidden_tri``,
        ``hidden_uvw``, its HIDDEN_* bit added to ``bits``). Returns (pixel, throughput, term, bits): what
        :func:`trace_hidden` and :func:`trace_hidden_rays` share; they differ in where a seen pixel goes."""
        d = dr
        w = f
        if k == 0:
            d = dt
            w = (1.0 - f) / (eta * eta)
        pix, term, code, u, v = hidden_ray(layer, camera, depth, position, normal, sky, occlusion, t_max, x, d, w)
        if pix < 0 and code != 0:
            hidden_tri[2 * p + k] = code
            hidden_uvw[2 * p + k] = wp.vec3(u, v, w)
            bits = bits | wp.where(k == 0, HIDDEN_REFRACTED, HIDDEN_REFLECTED)
        return pix, w, term, bits

    return water_ray


_WATER_RAY = {naive: _water_ray_func(naive) for naive in (False, True)}


def _camera_view_func(camera_ortho: int):
    """``cameras[0]`` as the trace reads it, its projection the constant ``camera_ortho`` (0 or 1; -1: read at run
    time; ``views.fixed_projection``), folded through ``water_rays`` and :func:`seen_by_camera` (the kernel compiled
    for the camera's projection, :func:`projected_hidden`; docs/perf_notes.md section 56)."""
    camera_projected = fixed_projection(camera_ortho)

    @wp.func
    def camera_view(cameras: wp.array(dtype=ViewParams)) -> ViewParams:
        return camera_projected(cameras[0])

    return camera_view


PIXELS_PER_THREAD = 4  #: pixels a thread of the strided trace covers (:func:`_trace_hidden_kernel`, ``strided``; section 67)


@wp.func
def strided_todo(missed: wp.array(dtype=wp.int32), t: int, stride: int, pixels: int, flags: int) -> int:
    """Bit i set where pixel ``t + i·stride`` (< ``pixels``) has one of ``flags`` in ``missed``: a strided thread's
    PIXELS_PER_THREAD words loaded together (one round trip), before any is tested."""
    todo = int(0)
    for i in range(PIXELS_PER_THREAD):
        q = t + i * stride
        b = wp.where(q < pixels, missed[wp.min(q, pixels - 1)], 0)
        todo = todo | wp.where((b & flags) != 0, 1 << i, 0)
    return todo


def _trace_hidden_kernel(naive: bool, camera_ortho: int = -1, strided: bool = False):
    CAMERA_ORTHO = int(camera_ortho)
    camera_view = _camera_view_func(CAMERA_ORTHO)
    water_ray = _WATER_RAY[naive]

    @wp.func
    def trace_pixel(
        p: int,
        bits: int,
        cameras: wp.array(dtype=ViewParams),
        water_position: wp.array(dtype=wp.vec3),
        water_normal: wp.array(dtype=wp.vec3),
        water_ior: wp.array(dtype=wp.float32),
        layer: OpaqueLayer,
        depth: wp.array(dtype=wp.float32),
        position: wp.array(dtype=wp.vec3),
        normal: wp.array(dtype=wp.vec3),
        radiance: wp.array(dtype=wp.vec3),
        sky: SkyMap,
        occlusion: SkyOcclusion,
        t_max: float,
        missed: wp.array(dtype=wp.int32),
        hidden_tri: wp.array(dtype=wp.int32),
        hidden_uvw: wp.array(dtype=wp.vec3),
        final: wp.array(dtype=wp.vec3),
    ):
        """Pixel ``p`` (its ``missed`` bits ``bits``, not 0) of :func:`trace_hidden`."""
        camera = camera_view(cameras)
        f, dr, dt, eta = water_rays(camera, water_position[p], water_normal[p], water_ior[p])
        x = water_position[p]
        l = wp.vec3(0.0)
        for k in range(2):
            flag = wp.where(k == 0, MISSED_REFRACTED, MISSED_REFLECTED)
            if (bits & flag) != 0:
                pix, w, term, bits = water_ray(k, p, bits, layer, camera, depth, position, normal, sky, occlusion,
                                               t_max, x, f, dr, dt, eta, hidden_tri, hidden_uvw)
                if pix >= 0:
                    l = l + radiance[pix] * w
                else:
                    l = l + term
        missed[p] = bits
        final[p] = final[p] + l

    def trace_hidden(
        cameras: wp.array(dtype=ViewParams),  # (2,) this frame's camera first (read)
        water_depth: wp.array(dtype=wp.float32),  # (H*W,) water layer depth [m], 0 = none (read)
        water_position: wp.array(dtype=wp.vec3),  # (H*W,) [m] (read)
        water_normal: wp.array(dtype=wp.vec3),  # (H*W,) (read)
        water_ior: wp.array(dtype=wp.float32),  # (H*W,) (read)
        layer: OpaqueLayer,
        depth: wp.array(dtype=wp.float32),  # (H*W,) camera opaque depth [m], 0 = none (read)
        position: wp.array(dtype=wp.vec3),  # (H*W,) its world position [m] (read)
        normal: wp.array(dtype=wp.vec3),  # (H*W,) its unit normal (read)
        radiance: wp.array(dtype=wp.vec3),  # (H*W,) opaque surface radiance [W/(m² sr)] (read)
        sky: SkyMap,  # the dome's radiance where a ray meets nothing (black without a sky)
        occlusion: SkyOcclusion,  # the sky's irradiance at a hidden hit
        t_max: float,  # longest ray [m]
        missed: wp.array(dtype=wp.int32),  # (H*W,) MISSED_* bits (read); HIDDEN_* bits added (write)
        hidden_tri: wp.array(dtype=wp.int32),  # (2*H*W,) ±(triangle + 1) of a hidden hit (write where HIDDEN)
        hidden_uvw: wp.array(dtype=wp.vec3),  # (2*H*W,) (u, v, throughput) of a hidden hit (write where HIDDEN)
        final: wp.array(dtype=wp.vec3),  # (H*W,) HDR radiance [W/(m² sr)] (read, add)
    ):
        """Each ray the composite's march could not follow: the BVH's nearest opaque hit, shaded (module docstring);
        direct light at hidden hits is :func:`hidden_direct`'s."""
        p = wp.tid()
        bits = missed[p]
        if bits == 0:
            return
        trace_pixel(p, bits, cameras, water_position, water_normal, water_ior, layer, depth, position, normal,
                    radiance, sky, occlusion, t_max, missed, hidden_tri, hidden_uvw, final)

    def trace_hidden_strided(
        cameras: wp.array(dtype=ViewParams),  # (2,) this frame's camera first (read)
        water_depth: wp.array(dtype=wp.float32),  # (H*W,) water layer depth [m], 0 = none (read)
        water_position: wp.array(dtype=wp.vec3),  # (H*W,) [m] (read)
        water_normal: wp.array(dtype=wp.vec3),  # (H*W,) (read)
        water_ior: wp.array(dtype=wp.float32),  # (H*W,) (read)
        layer: OpaqueLayer,
        depth: wp.array(dtype=wp.float32),  # (H*W,) camera opaque depth [m], 0 = none (read)
        position: wp.array(dtype=wp.vec3),  # (H*W,) its world position [m] (read)
        normal: wp.array(dtype=wp.vec3),  # (H*W,) its unit normal (read)
        radiance: wp.array(dtype=wp.vec3),  # (H*W,) opaque surface radiance [W/(m² sr)] (read)
        sky: SkyMap,  # the dome's radiance where a ray meets nothing (black without a sky)
        occlusion: SkyOcclusion,  # the sky's irradiance at a hidden hit
        t_max: float,  # longest ray [m]
        missed: wp.array(dtype=wp.int32),  # (H*W,) MISSED_* bits (read); HIDDEN_* bits added (write)
        hidden_tri: wp.array(dtype=wp.int32),  # (2*H*W,) ±(triangle + 1) of a hidden hit (write where HIDDEN)
        hidden_uvw: wp.array(dtype=wp.vec3),  # (2*H*W,) (u, v, throughput) of a hidden hit (write where HIDDEN)
        final: wp.array(dtype=wp.vec3),  # (H*W,) HDR radiance [W/(m² sr)] (read, add)
        pixels: int,  # H*W
        stride: int,  # the launch's threads, ceil(H*W / PIXELS_PER_THREAD)
    ):
        """:func:`trace_hidden` with a thread for every PIXELS_PER_THREAD pixels ``t + i·stride``: their ``missed``
        words read together (one round trip, not one a pixel), then the pixels with bits traced in turn. The pixels'
        work and results are trace_hidden's, bit for bit; what goes is the launch's floor, a round trip a pixel for
        the ~95% of threads that only read a zero (docs/perf_notes.md section 67)."""
        t = wp.tid()
        todo = strided_todo(missed, t, stride, pixels, -1)  # bit i: pixel t + i·stride has rays to trace
        i = int(0)
        while todo != 0:
            if (todo & 1) != 0:
                p = t + i * stride
                trace_pixel(p, missed[p], cameras, water_position, water_normal, water_ior, layer, depth, position,
                            normal, radiance, sky, occlusion, t_max, missed, hidden_tri, hidden_uvw, final)
            todo = todo >> 1
            i += 1

    kernel = trace_hidden_strided if strided else trace_hidden
    kernel.__qualname__ = kernel.__name__ + ("_orthocam" if CAMERA_ORTHO == 1 else "")
    if CAMERA_ORTHO < 0:
        return wp.kernel(kernel, module="unique")
    return wp.kernel(kernel, module="unique", enable_backward=False)  # no adjoint to compile


trace_hidden = _trace_hidden_kernel(False)
trace_hidden_naive = _trace_hidden_kernel(True)  #: the twin: every opaque triangle against every ray, no BVH


def _trace_hidden_rays_kernel(naive: bool, camera_ortho: int = -1, strided: bool = False):
    CAMERA_ORTHO = int(camera_ortho)
    camera_view = _camera_view_func(CAMERA_ORTHO)
    water_ray = _WATER_RAY[naive]

    @wp.func
    def trace_pixel_rays(
        p: int,
        bits: int,
        cameras: wp.array(dtype=ViewParams),
        water_position: wp.array(dtype=wp.vec3),
        water_normal: wp.array(dtype=wp.vec3),
        water_ior: wp.array(dtype=wp.float32),
        layer: OpaqueLayer,
        depth: wp.array(dtype=wp.float32),
        position: wp.array(dtype=wp.vec3),
        normal: wp.array(dtype=wp.vec3),
        sky: SkyMap,
        occlusion: SkyOcclusion,
        t_max: float,
        missed: wp.array(dtype=wp.int32),
        hidden_tri: wp.array(dtype=wp.int32),
        hidden_uvw: wp.array(dtype=wp.vec3),
        hits: wp.array(dtype=wp.vec2i),
        hidden_sum: wp.array(dtype=wp.vec3),
    ):
        """Pixel ``p`` (its ``missed`` bits ``bits``, not 0) of :func:`trace_hidden_rays`."""
        camera = camera_view(cameras)
        f, dr, dt, eta = water_rays(camera, water_position[p], water_normal[p], water_ior[p])
        x = water_position[p]
        l = wp.vec3(0.0)
        for k in range(2):
            flag = wp.where(k == 0, MISSED_REFRACTED, MISSED_REFLECTED)
            if (bits & flag) != 0:
                pix, w, term, bits = water_ray(k, p, bits, layer, camera, depth, position, normal, sky, occlusion,
                                               t_max, x, f, dr, dt, eta, hidden_tri, hidden_uvw)
                if pix >= 0:
                    h = hits[p]
                    if k == 0:
                        h = wp.vec2i(h[0], pix)
                    else:
                        h = wp.vec2i(pix, h[1])
                    hits[p] = h
                else:
                    l = l + term
        missed[p] = bits
        hidden_sum[p] = l

    def trace_hidden_rays(
        cameras: wp.array(dtype=ViewParams),  # (2,) this frame's camera first (read)
        water_depth: wp.array(dtype=wp.float32),  # (H*W,) water layer depth [m], 0 = none (read)
        water_position: wp.array(dtype=wp.vec3),  # (H*W,) [m] (read)
        water_normal: wp.array(dtype=wp.vec3),  # (H*W,) (read)
        water_ior: wp.array(dtype=wp.float32),  # (H*W,) (read)
        layer: OpaqueLayer,
        depth: wp.array(dtype=wp.float32),  # (H*W,) camera opaque depth [m], 0 = none (read)
        position: wp.array(dtype=wp.vec3),  # (H*W,) its world position [m] (read)
        normal: wp.array(dtype=wp.vec3),  # (H*W,) its unit normal (read)
        sky: SkyMap,  # the dome's radiance where a ray meets nothing (black without a sky)
        occlusion: SkyOcclusion,  # the sky's irradiance at a hidden hit
        t_max: float,  # longest ray [m]
        missed: wp.array(dtype=wp.int32),  # (H*W,) MISSED_* bits (read); HIDDEN_* bits added (write)
        hidden_tri: wp.array(dtype=wp.int32),  # (2*H*W,) ±(triangle + 1) of a hidden hit (write where HIDDEN)
        hidden_uvw: wp.array(dtype=wp.vec3),  # (2*H*W,) (u, v, throughput) of a hidden hit (write where HIDDEN)
        hits: wp.array(dtype=wp.vec2i),  # (H*W,) shade.composite_march's; a seen pixel put in a missed ray's slot
        hidden_sum: wp.array(dtype=wp.vec3),  # (H*W,) the sum of the terms that need no radiance (write where missed)
    ):
        """:func:`trace_hidden` without the photons: what it adds, but a hit the camera sees leaves its pixel in the
        ray's slot of ``hits`` (reflected ``[0]``, refracted ``[1]``) for ``shade.composite_gather`` to read its
        radiance, after the denoiser; the other rays' terms are summed from zero in trace_hidden's order into
        ``hidden_sum``. Reads the G-buffer, the BVH and the sky only, so it runs beside the photon trace."""
        p = wp.tid()
        bits = missed[p]
        if bits == 0:
            return
        trace_pixel_rays(p, bits, cameras, water_position, water_normal, water_ior, layer, depth, position, normal,
                         sky, occlusion, t_max, missed, hidden_tri, hidden_uvw, hits, hidden_sum)

    def trace_hidden_rays_strided(
        cameras: wp.array(dtype=ViewParams),  # (2,) this frame's camera first (read)
        water_depth: wp.array(dtype=wp.float32),  # (H*W,) water layer depth [m], 0 = none (read)
        water_position: wp.array(dtype=wp.vec3),  # (H*W,) [m] (read)
        water_normal: wp.array(dtype=wp.vec3),  # (H*W,) (read)
        water_ior: wp.array(dtype=wp.float32),  # (H*W,) (read)
        layer: OpaqueLayer,
        depth: wp.array(dtype=wp.float32),  # (H*W,) camera opaque depth [m], 0 = none (read)
        position: wp.array(dtype=wp.vec3),  # (H*W,) its world position [m] (read)
        normal: wp.array(dtype=wp.vec3),  # (H*W,) its unit normal (read)
        sky: SkyMap,  # the dome's radiance where a ray meets nothing (black without a sky)
        occlusion: SkyOcclusion,  # the sky's irradiance at a hidden hit
        t_max: float,  # longest ray [m]
        missed: wp.array(dtype=wp.int32),  # (H*W,) MISSED_* bits (read); HIDDEN_* bits added (write)
        hidden_tri: wp.array(dtype=wp.int32),  # (2*H*W,) ±(triangle + 1) of a hidden hit (write where HIDDEN)
        hidden_uvw: wp.array(dtype=wp.vec3),  # (2*H*W,) (u, v, throughput) of a hidden hit (write where HIDDEN)
        hits: wp.array(dtype=wp.vec2i),  # (H*W,) shade.composite_march's; a seen pixel put in a missed ray's slot
        hidden_sum: wp.array(dtype=wp.vec3),  # (H*W,) the sum of the terms that need no radiance (write where missed)
        pixels: int,  # H*W
        stride: int,  # the launch's threads, ceil(H*W / PIXELS_PER_THREAD)
    ):
        """:func:`trace_hidden_rays` strided as :func:`trace_hidden`'s strided kernel: the same results bit for bit."""
        t = wp.tid()
        todo = strided_todo(missed, t, stride, pixels, -1)  # bit i: pixel t + i·stride has rays to trace
        i = int(0)
        while todo != 0:
            if (todo & 1) != 0:
                p = t + i * stride
                trace_pixel_rays(p, missed[p], cameras, water_position, water_normal, water_ior, layer, depth,
                                 position, normal, sky, occlusion, t_max, missed, hidden_tri, hidden_uvw, hits,
                                 hidden_sum)
            todo = todo >> 1
            i += 1

    kernel = trace_hidden_rays_strided if strided else trace_hidden_rays
    kernel.__qualname__ = kernel.__name__ + ("_orthocam" if CAMERA_ORTHO == 1 else "")
    if CAMERA_ORTHO < 0:
        return wp.kernel(kernel, module="unique")
    return wp.kernel(kernel, module="unique", enable_backward=False)  # no adjoint to compile


trace_hidden_rays = _trace_hidden_rays_kernel(False)
trace_hidden_rays_naive = _trace_hidden_rays_kernel(True)

_PROJECTED_HIDDEN: dict = {}


def projected_hidden(camera_ortho: int) -> tuple:
    """(:func:`trace_hidden`, :func:`trace_hidden_rays`) compiled for a perspective (0) or orthographic (1) camera
    (its projection a compile-time constant), made on first use, each a module of its own (the orthographic camera's
    named ``*_orthocam``). The same inputs, the same outputs bit for bit where ``cameras[0]`` has that projection
    (``tests/test_shade_projected.py``)."""
    key = int(camera_ortho)
    if key not in _PROJECTED_HIDDEN:
        _PROJECTED_HIDDEN[key] = (_trace_hidden_kernel(False, key), _trace_hidden_rays_kernel(False, key))
    return _PROJECTED_HIDDEN[key]


_STRIDED_HIDDEN: dict = {}


def strided_hidden(camera_ortho: int) -> tuple:
    """(:func:`trace_hidden`, :func:`trace_hidden_rays`) strided (a thread per :data:`PIXELS_PER_THREAD` pixels, its
    pixels' ``missed`` words read together) and compiled for the camera's projection as :func:`projected_hidden`'s
    (-1: read at run time), made on first use, modules of their own. Launched over :func:`strided_threads` threads
    with ``pixels`` and that count appended to the per-pixel kernel's inputs; each pixel's results those of
    :func:`projected_hidden`'s kernels bit for bit (``tests/test_shade_strided.py``)."""
    key = int(camera_ortho)
    if key not in _STRIDED_HIDDEN:
        _STRIDED_HIDDEN[key] = (_trace_hidden_kernel(False, key, strided=True),
                                _trace_hidden_rays_kernel(False, key, strided=True))
    return _STRIDED_HIDDEN[key]


def strided_threads(pixels: int) -> int:
    """Threads of a strided trace over ``pixels`` pixels: ceil(pixels / PIXELS_PER_THREAD)."""
    return -(-int(pixels) // PIXELS_PER_THREAD)


@wp.func
def hidden_hit(layer: OpaqueLayer, hidden_tri: wp.array(dtype=wp.int32), hidden_uvw: wp.array(dtype=wp.vec3), p: int,
               k: int):
    """Pixel ``p``'s hidden hit ``k`` (0 refracted, 1 reflected) as :func:`trace_hidden` recorded it: (world point
    [m], unit shading normal on the side the ray met, albedo, the ray's throughput)."""
    st = hidden_tri[2 * p + k]
    uvw = hidden_uvw[2 * p + k]
    tri = wp.abs(st) - 1
    y, n, ng = hidden_point(layer, tri, uvw[0], uvw[1])
    if st < 0:
        n = -n
    return y, n, layer.albedo[layer.triangle_material[tri]], uvw[2]


@wp.func
def direct_term(
    p: int,
    bits: int,
    shadow_view: ViewParams,
    shadow_depth: wp.array(dtype=wp.float32),
    exclusive: int,
    kind: int,
    light_rgb: wp.vec3,
    light_pos: wp.vec3,
    light_dir: wp.vec3,
    cone_angle: float,
    cone_softness: float,
    layer: OpaqueLayer,
    hidden_tri: wp.array(dtype=wp.int32),
    hidden_uvw: wp.array(dtype=wp.vec3),
) -> wp.vec3:
    """What :func:`hidden_direct` adds to pixel ``p`` (its ``missed`` bits ``bits``) for one shadow map: its hidden
    hits' albedo/π · E · throughput, summed from zero, the refracted ray's first."""
    l = wp.vec3(0.0)
    for k in range(2):
        if (bits & wp.where(k == 0, HIDDEN_REFRACTED, HIDDEN_REFLECTED)) != 0:
            y, n, rho, w = hidden_hit(layer, hidden_tri, hidden_uvw, p, k)
            e = direct_at(shadow_view, shadow_depth, exclusive, kind, light_rgb, light_pos, light_dir, cone_angle,
                          cone_softness, y, n)
            l = l + wp.cw_mul(rho, e) * (INV_PI * w)
    return l


@wp.func
def direct_pixel(
    p: int,
    bits: int,
    shadow_view: ViewParams,
    shadow_depth: wp.array(dtype=wp.float32),
    exclusive: int,
    kind: int,
    light_rgb: wp.vec3,
    light_pos: wp.vec3,
    light_dir: wp.vec3,
    cone_angle: float,
    cone_softness: float,
    layer: OpaqueLayer,
    hidden_tri: wp.array(dtype=wp.int32),
    hidden_uvw: wp.array(dtype=wp.vec3),
    final: wp.array(dtype=wp.vec3),
):
    """Pixel ``p`` (its ``missed`` bits ``bits``, a HIDDEN one among them) of :func:`hidden_direct`."""
    l = direct_term(p, bits, shadow_view, shadow_depth, exclusive, kind, light_rgb, light_pos, light_dir, cone_angle,
                    cone_softness, layer, hidden_tri, hidden_uvw)
    if l[0] != 0.0 or l[1] != 0.0 or l[2] != 0.0:
        final[p] = final[p] + l


@wp.kernel
def hidden_direct(
    shadow_view: ViewParams,  # one shadow map, as shade.direct_light's arguments
    shadow_depth: wp.array(dtype=wp.float32),
    exclusive: int,
    kind: int,
    light_rgb: wp.vec3,
    light_pos: wp.vec3,
    light_dir: wp.vec3,
    cone_angle: float,
    cone_softness: float,
    layer: OpaqueLayer,
    missed: wp.array(dtype=wp.int32),  # (H*W,) HIDDEN_* bits (read)
    hidden_tri: wp.array(dtype=wp.int32),  # (2*H*W,) (read)
    hidden_uvw: wp.array(dtype=wp.vec3),  # (2*H*W,) (read)
    final: wp.array(dtype=wp.vec3),  # (H*W,) HDR radiance [W/(m² sr)] (read, add)
):
    """Direct light of one shadow map at each hidden hit: albedo/π · E · throughput added to the pixel (the camera's
    own surfaces get theirs from ``shade.direct_light``, by the same function)."""
    p = wp.tid()
    bits = missed[p]
    if (bits & (HIDDEN_REFRACTED | HIDDEN_REFLECTED)) == 0:
        return
    direct_pixel(p, bits, shadow_view, shadow_depth, exclusive, kind, light_rgb, light_pos, light_dir, cone_angle,
                 cone_softness, layer, hidden_tri, hidden_uvw, final)


@wp.kernel
def hidden_direct_strided(
    shadow_view: ViewParams,  # one shadow map, as shade.direct_light's arguments
    shadow_depth: wp.array(dtype=wp.float32),
    exclusive: int,
    kind: int,
    light_rgb: wp.vec3,
    light_pos: wp.vec3,
    light_dir: wp.vec3,
    cone_angle: float,
    cone_softness: float,
    layer: OpaqueLayer,
    missed: wp.array(dtype=wp.int32),  # (H*W,) HIDDEN_* bits (read)
    hidden_tri: wp.array(dtype=wp.int32),  # (2*H*W,) (read)
    hidden_uvw: wp.array(dtype=wp.vec3),  # (2*H*W,) (read)
    final: wp.array(dtype=wp.vec3),  # (H*W,) HDR radiance [W/(m² sr)] (read, add)
    pixels: int,  # H*W
    stride: int,  # the launch's threads, strided_threads(H*W)
):
    """:func:`hidden_direct` strided as the trace (:func:`strided_hidden`): the same results bit for bit."""
    t = wp.tid()
    todo = strided_todo(missed, t, stride, pixels, HIDDEN_REFRACTED | HIDDEN_REFLECTED)
    i = int(0)
    while todo != 0:
        if (todo & 1) != 0:
            p = t + i * stride
            direct_pixel(p, missed[p], shadow_view, shadow_depth, exclusive, kind, light_rgb, light_pos, light_dir,
                         cone_angle, cone_softness, layer, hidden_tri, hidden_uvw, final)
        todo = todo >> 1
        i += 1


@wp.func
def caustic_term(
    p: int,
    bits: int,
    views: wp.array(dtype=ViewParams),
    flux: wp.array(dtype=wp.vec3),
    map_w: int,
    map_h: int,
    gather: int,
    layer: OpaqueLayer,
    hidden_tri: wp.array(dtype=wp.int32),
    hidden_uvw: wp.array(dtype=wp.vec3),
) -> wp.vec3:
    """What :func:`hidden_caustic` adds to pixel ``p`` (its ``missed`` bits ``bits``) for one light: its hidden hits'
    albedo/π · E · throughput, summed from zero, the refracted ray's first."""
    l = wp.vec3(0.0)
    for k in range(2):
        if (bits & wp.where(k == 0, HIDDEN_REFRACTED, HIDDEN_REFLECTED)) != 0:
            y, n, rho, w = hidden_hit(layer, hidden_tri, hidden_uvw, p, k)
            e = hidden_irradiance(views, flux, map_w, map_h, gather, y, n)  # |n · ray|: either side
            l = l + wp.cw_mul(rho, e) * (INV_PI * w)
    return l


@wp.func
def caustic_pixel(
    p: int,
    bits: int,
    views: wp.array(dtype=ViewParams),
    flux: wp.array(dtype=wp.vec3),
    map_w: int,
    map_h: int,
    gather: int,
    layer: OpaqueLayer,
    hidden_tri: wp.array(dtype=wp.int32),
    hidden_uvw: wp.array(dtype=wp.vec3),
    final: wp.array(dtype=wp.vec3),
):
    """Pixel ``p`` (its ``missed`` bits ``bits``, a HIDDEN one among them) of :func:`hidden_caustic`."""
    l = caustic_term(p, bits, views, flux, map_w, map_h, gather, layer, hidden_tri, hidden_uvw)
    if l[0] != 0.0 or l[1] != 0.0 or l[2] != 0.0:
        final[p] = final[p] + l


@wp.kernel
def hidden_caustic(
    views: wp.array(dtype=ViewParams),  # one light's whole views (photons.hidden_flux.HiddenFlux.views, read)
    flux: wp.array(dtype=wp.vec3),  # their landed-photon map, power [W] per map texel (HiddenFlux.flux, read)
    map_w: int,  # its texels per view, across
    map_h: int,  # and down
    gather: int,  # the lookup's (2 gather + 1)² texels
    layer: OpaqueLayer,
    missed: wp.array(dtype=wp.int32),  # (H*W,) HIDDEN_* bits (read)
    hidden_tri: wp.array(dtype=wp.int32),  # (2*H*W,) (read)
    hidden_uvw: wp.array(dtype=wp.vec3),  # (2*H*W,) (read)
    final: wp.array(dtype=wp.vec3),  # (H*W,) HDR radiance [W/(m² sr)] (read, add)
):
    """The caustic of one light's landed photons at each hidden hit: albedo/π · E · throughput added to the pixel,
    E from :func:`~.photons.hidden_flux.hidden_irradiance` (zero outside the light's views)."""
    p = wp.tid()
    bits = missed[p]
    if (bits & (HIDDEN_REFRACTED | HIDDEN_REFLECTED)) == 0:
        return
    caustic_pixel(p, bits, views, flux, map_w, map_h, gather, layer, hidden_tri, hidden_uvw, final)


@wp.kernel
def hidden_caustic_strided(
    views: wp.array(dtype=ViewParams),  # one light's whole views (photons.hidden_flux.HiddenFlux.views, read)
    flux: wp.array(dtype=wp.vec3),  # their landed-photon map, power [W] per map texel (HiddenFlux.flux, read)
    map_w: int,  # its texels per view, across
    map_h: int,  # and down
    gather: int,  # the lookup's (2 gather + 1)² texels
    layer: OpaqueLayer,
    missed: wp.array(dtype=wp.int32),  # (H*W,) HIDDEN_* bits (read)
    hidden_tri: wp.array(dtype=wp.int32),  # (2*H*W,) (read)
    hidden_uvw: wp.array(dtype=wp.vec3),  # (2*H*W,) (read)
    final: wp.array(dtype=wp.vec3),  # (H*W,) HDR radiance [W/(m² sr)] (read, add)
    pixels: int,  # H*W
    stride: int,  # the launch's threads, strided_threads(H*W)
):
    """:func:`hidden_caustic` strided as the trace (:func:`strided_hidden`): the same results bit for bit."""
    t = wp.tid()
    todo = strided_todo(missed, t, stride, pixels, HIDDEN_REFRACTED | HIDDEN_REFLECTED)
    i = int(0)
    while todo != 0:
        if (todo & 1) != 0:
            p = t + i * stride
            caustic_pixel(p, missed[p], views, flux, map_w, map_h, gather, layer, hidden_tri, hidden_uvw, final)
        todo = todo >> 1
        i += 1


#: the most shadow maps, and lights with landed photons, that :func:`composite_gather_hidden` takes (a frame with more
#: keeps the gather and :meth:`HiddenSurfaces.shade_hits`' launches): the pool's two, the Cornell box's one
GATHER_MAPS = 2
GATHER_FLUXES = 2


@wp.struct
class ShadowMap:
    """One shadow map of one light, as ``shade.direct_light`` takes it (``shade.shadow_map_args``' nine values)."""

    view: ViewParams
    depth: wp.array(dtype=wp.float32)
    exclusive: int
    kind: int
    rgb: wp.vec3
    pos: wp.vec3
    dir: wp.vec3
    cone_angle: float
    cone_softness: float


@wp.struct
class LandedFlux:
    """One light's landed-photon map, as :func:`hidden_caustic` takes it (``photons.hidden_flux.HiddenFlux``'s)."""

    views: wp.array(dtype=ViewParams)
    flux: wp.array(dtype=wp.vec3)
    map_w: int
    map_h: int


@wp.struct
class HiddenLights:
    """What :meth:`HiddenSurfaces.shade_hits` launches :func:`hidden_direct` and :func:`hidden_caustic` with, for
    :func:`composite_gather_hidden`: the frame's first ``maps`` shadow maps (at most GATHER_MAPS), then its first
    ``fluxes`` lights' landed photons (at most GATHER_FLUXES), each gathered over (2 ``gather`` + 1)² texels."""

    maps: int
    map0: ShadowMap
    map1: ShadowMap
    fluxes: int
    flux0: LandedFlux
    flux1: LandedFlux
    gather: int


@wp.func
def add_shadow_map(l: wp.vec3, p: int, bits: int, m: ShadowMap, layer: OpaqueLayer,
                   hidden_tri: wp.array(dtype=wp.int32), hidden_uvw: wp.array(dtype=wp.vec3)) -> wp.vec3:
    """``l`` plus what :func:`hidden_direct` adds to pixel ``p`` for the shadow map ``m`` (``l`` where it adds zero)."""
    d = direct_term(p, bits, m.view, m.depth, m.exclusive, m.kind, m.rgb, m.pos, m.dir, m.cone_angle, m.cone_softness,
                    layer, hidden_tri, hidden_uvw)
    if d[0] != 0.0 or d[1] != 0.0 or d[2] != 0.0:
        return l + d
    return l


@wp.func
def add_landed_flux(l: wp.vec3, p: int, bits: int, f: LandedFlux, gather: int, layer: OpaqueLayer,
                    hidden_tri: wp.array(dtype=wp.int32), hidden_uvw: wp.array(dtype=wp.vec3)) -> wp.vec3:
    """``l`` plus what :func:`hidden_caustic` adds to pixel ``p`` for the light of ``f`` (``l`` where it adds zero)."""
    c = caustic_term(p, bits, f.views, f.flux, f.map_w, f.map_h, gather, layer, hidden_tri, hidden_uvw)
    if c[0] != 0.0 or c[1] != 0.0 or c[2] != 0.0:
        return l + c
    return l


#: CUDA launch bounds of :func:`composite_gather_hidden` (threads a block, blocks an SM; None: none, blocks of 256).
#: The gather alone (``shade.composite_gather``) is 32 registers, a dense streaming pass; with the hidden hits' shading
#: folded in, at (256, 3) 80 registers and no spills (3 blocks of 256 an SM); at (256, 4) 64 registers (4 blocks) and
#: a 48 B frame: 7 local operations on every pixel, the rest where a pixel has hidden hits (sm_90, docs/perf_notes.md
#: section 76). Read at each launch (:meth:`HiddenSurfaces.gather`): set it before a frame is captured
GATHER_LAUNCH_BOUNDS = (256, 4)

_GATHER_HIDDEN: dict = {}


def gather_hidden_kernel(bounds="default"):
    """:func:`composite_gather_hidden` compiled with the launch bounds ``bounds`` (default
    :data:`GATHER_LAUNCH_BOUNDS`; None: none), made on first use, a module of its own; the same float operations at
    any bounds."""
    key = GATHER_LAUNCH_BOUNDS if isinstance(bounds, str) else bounds
    key = None if key is None else tuple(int(v) for v in key)
    if key in _GATHER_HIDDEN:
        return _GATHER_HIDDEN[key]

    def composite_gather_hidden(
        depth: wp.array(dtype=wp.float32),  # (H*W,) as shade.composite_gather's (read)
        albedo: wp.array(dtype=wp.vec3),
        direct_irradiance: wp.array(dtype=wp.vec3),
        caustic_irradiance: wp.array(dtype=wp.vec3),
        sky_irradiance: wp.array(dtype=wp.vec3),
        hits: wp.array(dtype=wp.vec2i),
        weights: wp.array(dtype=wp.vec2),
        missed: wp.array(dtype=wp.int32),  # (H*W,) MISSED_* and HIDDEN_* bits (read)
        hidden_sum: wp.array(dtype=wp.vec3),
        lights: HiddenLights,  # the shadow maps and landed photons lighting the hidden hits
        layer: OpaqueLayer,
        hidden_tri: wp.array(dtype=wp.int32),  # (2*H*W,) (read where HIDDEN)
        hidden_uvw: wp.array(dtype=wp.vec3),  # (2*H*W,) (read where HIDDEN)
        final: wp.array(dtype=wp.vec3),  # (H*W,) composite_march's partial sums (read); the HDR image (write)
        flip: int,  # as shade.composite_gather's: 1: parity[0] = 1 - parity[0] (SVGF's deferred frame ends here)
        parity: wp.array(dtype=wp.int32),
    ):
        """``shade.composite_gather`` (with its hidden rays) followed by :func:`hidden_direct` for each shadow map and
        :func:`hidden_caustic` for each light of ``lights``, in one pass: the gather's value, then each map's and each
        light's sum added where it is not zero, in their launches' order, so ``final`` is theirs bit for bit on the CPU.
        The tail after the frame's join loses a launch per shadow map and per light (docs/perf_notes.md section 76)."""
        p = wp.tid()
        if flip != 0 and p == 0:
            parity[0] = 1 - parity[0]
        written, l, bits = gather_pixel(depth, albedo, direct_irradiance, caustic_irradiance, sky_irradiance, hits,
                                        weights, missed, hidden_sum, 1, final, p)
        if written == 0:
            return
        if (bits & (HIDDEN_REFRACTED | HIDDEN_REFLECTED)) != 0:
            if lights.maps > 0:
                l = add_shadow_map(l, p, bits, lights.map0, layer, hidden_tri, hidden_uvw)
            if lights.maps > 1:
                l = add_shadow_map(l, p, bits, lights.map1, layer, hidden_tri, hidden_uvw)
            if lights.fluxes > 0:
                l = add_landed_flux(l, p, bits, lights.flux0, lights.gather, layer, hidden_tri, hidden_uvw)
            if lights.fluxes > 1:
                l = add_landed_flux(l, p, bits, lights.flux1, lights.gather, layer, hidden_tri, hidden_uvw)
        final[p] = l

    composite_gather_hidden.__qualname__ = "composite_gather_hidden"
    kernel = wp.kernel(composite_gather_hidden, module="unique", enable_backward=False, launch_bounds=key)
    _GATHER_HIDDEN[key] = kernel
    return kernel


def hidden_lights(lights, hidden_flux=None) -> HiddenLights | None:
    """The :class:`HiddenLights` of ``lights`` (the renderer's ``LightMaps``) and ``hidden_flux`` (None: no caustic),
    or None where they hold more than GATHER_MAPS shadow maps or GATHER_FLUXES lights with landed photons."""
    maps = shadow_map_args(lights)
    fluxes = 0 if hidden_flux is None else len(lights)
    if len(maps) > GATHER_MAPS or fluxes > GATHER_FLUXES:
        return None
    out = HiddenLights()
    out.maps, out.fluxes, out.gather = len(maps), fluxes, 0 if hidden_flux is None else int(hidden_flux.gather)
    for i, args in enumerate(maps):
        m = ShadowMap()
        (m.view, m.depth, m.exclusive, m.kind, m.rgb, m.pos, m.dir, m.cone_angle, m.cone_softness) = args
        setattr(out, f"map{i}", m)
    for li in range(fluxes):
        f = LandedFlux()
        f.views, f.flux = hidden_flux.views[li], hidden_flux.flux[li]
        f.map_w, f.map_h = (int(v) for v in hidden_flux.shape[li])
        setattr(out, f"flux{li}", f)
    return out


def opaque_layer(scene) -> OpaqueLayer:
    """The kernels' view of ``scene``'s (a ``DeviceScene``) opaque layer: its BVH is ``scene.bvh(LAYER_OPAQUE)``, the
    one the reference and SSPM trace (built once, on first use; refit only when opaque geometry moves)."""
    layer = OpaqueLayer()
    layer.has_mesh = int(scene.has_layer[LAYER_OPAQUE])
    if layer.has_mesh:
        mesh, face_map = scene.bvh(LAYER_OPAQUE)
        layer.mesh, layer.face_to_tri = mesh.id, face_map
    else:
        layer.face_to_tri = wp.zeros(0, dtype=wp.int32, device=scene.device)
    layer.points, layer.normals, layer.indices = scene.points, scene.normals, scene.indices
    layer.triangle_material, layer.albedo = scene.triangle_material, scene.albedo
    return layer


def sky_occlusion(sky, device) -> SkyOcclusion:
    """The arrays of ``sky`` (a ``sky.SkyLighting``) as :func:`trace_hidden` reads them; without a sky, zeros (its
    irradiance is zero: SH coefficients zero, no occlusion maps)."""
    occ = SkyOcclusion()
    if sky is not None:
        occ.sh, occ.views, occ.directions, occ.luminance = sky.sh, sky.view_params, sky.directions, sky.luminance
        occ.map_depth, occ.map_texels = sky.map_depth, sky.map_size * sky.map_size
    else:
        occ.sh = wp.zeros(9, dtype=wp.vec3, device=device)
        occ.views = wp.zeros(1, dtype=ViewParams, device=device)
        occ.directions = wp.zeros(0, dtype=wp.vec3, device=device)
        occ.luminance = wp.zeros(0, dtype=wp.float32, device=device)
        occ.map_depth = wp.zeros(1, dtype=wp.float32, device=device)
        occ.map_texels = 1
    return occ


class HiddenSurfaces:
    """The composite's rays that screen space cannot follow, traced and shaded (module docstring). Allocated once:
    ``missed`` (H*W int32), ``hidden_tri`` (2·H*W int32) and ``hidden_uvw`` (2·H*W vec3), 28 B a pixel."""

    def __init__(self, scene, width: int, height: int, sky, device):
        self.device = wp.get_device(device)
        n = width * height
        self.layer = opaque_layer(scene)
        self.occlusion = sky_occlusion(sky, self.device)
        self.missed = wp.zeros(n, dtype=wp.int32, device=self.device)
        self.hidden_tri = wp.zeros(2 * n, dtype=wp.int32, device=self.device)
        self.hidden_uvw = wp.zeros(2 * n, dtype=wp.vec3, device=self.device)
        self.naive = False  #: trace with :data:`trace_hidden_naive` (every triangle, no BVH): the twin, for tests

    #: trace with the kernels compiled for the camera's projection (:func:`projected_hidden`) where the caller gives
    #: it; False: the run-time kernels :data:`trace_hidden`, :data:`trace_hidden_rays` (the twins)
    PROJECTED = True
    #: a thread per PIXELS_PER_THREAD pixels (docs/perf_notes.md section 67): with :attr:`PROJECTED` the trace by
    #: :func:`strided_hidden`'s kernels, and :func:`hidden_direct_strided`, :func:`hidden_caustic_strided`; False: a
    #: thread a pixel, :func:`projected_hidden`'s kernels, :func:`hidden_direct`, :func:`hidden_caustic` (the twins)
    STRIDED = True
    #: the concurrent program's gather adds the hidden hits' direct light and caustic itself (:meth:`gather`,
    #: :func:`composite_gather_hidden`, one launch after the join); False: ``shade.composite_gather``, then
    #: :meth:`shade_hits`' launch per shadow map and per light (the twin; docs/perf_notes.md section 76)
    GATHERED = True

    def _kernels(self, orthographic: bool | None) -> tuple:
        """(trace_hidden, trace_hidden_rays) to launch for a camera of that projection (None: read at run time)."""
        if self.naive:
            return trace_hidden_naive, trace_hidden_rays_naive
        if orthographic is None or not self.PROJECTED:
            return trace_hidden, trace_hidden_rays
        if self.STRIDED:
            return strided_hidden(int(bool(orthographic)))
        return projected_hidden(int(bool(orthographic)))

    def _launch_trace(self, kernel, n: int, inputs: list) -> None:
        """``kernel`` over ``n`` pixels: a thread a pixel, or a strided kernel's :func:`strided_threads`."""
        if any(kernel in pair for pair in _STRIDED_HIDDEN.values()):
            threads = strided_threads(n)
            wp.launch(kernel, dim=threads, device=self.device, inputs=inputs + [n, threads])
        else:
            wp.launch(kernel, dim=n, device=self.device, inputs=inputs)

    def render(self, gbuffer, lights, cameras: wp.array, radiance: wp.array, sky_map: SkyMap, t_max: float,
               final: wp.array, hidden_flux=None, orthographic: bool | None = None) -> None:
        """Add to ``final`` what the rays flagged in ``missed`` (by ``shade.composite``, just before) reach:
        :func:`trace_hidden`, then :func:`hidden_direct` once per shadow map of every light, and
        :func:`hidden_caustic` once per light view of ``hidden_flux`` (a ``photons.hidden_flux.HiddenFlux``; None:
        no caustic at hidden hits). ``orthographic``: the camera's projection (``cameras[0]``'s, known on the host),
        for the trace compiled for it (:attr:`PROJECTED`); None: read at run time."""
        w = gbuffer.water
        n = gbuffer.width * gbuffer.height
        kernel = self._kernels(orthographic)[0]
        self._launch_trace(kernel, n, [
            cameras, w.depth, w.position, w.normal, w.ior, self.layer, gbuffer.depth, gbuffer.position, gbuffer.normal,
            radiance, sky_map, self.occlusion, float(t_max), self.missed, self.hidden_tri, self.hidden_uvw, final])
        self.shade_hits(gbuffer, lights, final, hidden_flux)

    def trace_rays(self, gbuffer, cameras: wp.array, sky_map: SkyMap, t_max: float, hits: wp.array,
                   hidden_sum: wp.array, orthographic: bool | None = None) -> None:
        """:meth:`render`'s trace without the photons (:func:`trace_hidden_rays`, after ``shade.composite_march``):
        the rays' hits the camera sees go to ``hits``, the other rays' terms to ``hidden_sum``, for
        ``shade.composite_gather``; then :meth:`shade_hits` adds the direct light and caustic at the hidden hits.
        ``orthographic``: as :meth:`render`'s."""
        w = gbuffer.water
        kernel = self._kernels(orthographic)[1]
        self._launch_trace(kernel, gbuffer.width * gbuffer.height, [
            cameras, w.depth, w.position, w.normal, w.ior, self.layer, gbuffer.depth, gbuffer.position, gbuffer.normal,
            sky_map, self.occlusion, float(t_max), self.missed, self.hidden_tri, self.hidden_uvw, hits, hidden_sum])

    def gather(self, gbuffer, direct_irradiance: wp.array, caustic_irradiance: wp.array, sky_irradiance: wp.array,
               split, lights, final: wp.array, hidden_flux=None, parity: wp.array | None = None) -> bool:
        """With :attr:`GATHERED` and at most GATHER_MAPS shadow maps and GATHER_FLUXES lights, launch
        :func:`composite_gather_hidden` (the concurrent program's gather with :meth:`shade_hits` folded in; ``split``
        the renderer's ``composite_split``: ``hits``, ``weights``, ``hidden_sum``) and return True; else launch
        nothing and return False (the caller launches ``shade.composite_gather`` and :meth:`shade_hits`). ``parity``
        (1 int32, SVGF's): flipped by the launch (``shade.composite_gather``'s ``flip``); None: none."""
        packed = hidden_lights(lights, hidden_flux) if self.GATHERED else None
        if packed is None:
            return False
        n = gbuffer.width * gbuffer.height
        bounds = GATHER_LAUNCH_BOUNDS
        wp.launch(gather_hidden_kernel(bounds), dim=n, device=self.device,
                  block_dim=256 if bounds is None else int(bounds[0]), inputs=[
                      gbuffer.depth, gbuffer.albedo, direct_irradiance, caustic_irradiance, sky_irradiance, split.hits,
                      split.weights, self.missed, split.hidden_sum, packed, self.layer, self.hidden_tri,
                      self.hidden_uvw, final, int(parity is not None), parity])
        return True

    def shade_hits(self, gbuffer, lights, final: wp.array, hidden_flux=None) -> None:
        """Add to ``final`` the direct light (:func:`hidden_direct`, once per shadow map of every light) and the
        caustic (:func:`hidden_caustic`, once per light of ``hidden_flux``; None: none) at the hidden hits."""
        n = gbuffer.width * gbuffer.height
        strided = self.STRIDED and not self.naive
        direct = hidden_direct_strided if strided else hidden_direct
        caustic = hidden_caustic_strided if strided else hidden_caustic
        threads = strided_threads(n) if strided else n
        extra = [n, threads] if strided else []
        for args in shadow_map_args(lights):
            wp.launch(direct, dim=threads, device=self.device,
                      inputs=args + [self.layer, self.missed, self.hidden_tri, self.hidden_uvw, final] + extra)
        if hidden_flux is None:
            return
        for li in range(len(lights)):
            w, h = hidden_flux.shape[li]
            wp.launch(caustic, dim=threads, device=self.device, inputs=[
                hidden_flux.views[li], hidden_flux.flux[li], w, h, hidden_flux.gather, self.layer, self.missed,
                self.hidden_tri, self.hidden_uvw, final] + extra)


__all__ = ["GATHER_FLUXES", "GATHER_MAPS", "HIDDEN_REFLECTED", "HIDDEN_REFRACTED", "HiddenLights", "HiddenSurfaces",
           "LandedFlux", "OpaqueLayer", "ShadowMap", "SkyOcclusion", "gather_hidden_kernel", "hidden_caustic",
           "hidden_caustic_strided", "hidden_direct", "hidden_direct_strided", "hidden_lights",
           "opaque_hit", "opaque_hit_naive", "opaque_layer", "projected_hidden", "sky_occlusion", "strided_hidden",
           "strided_threads", "trace_hidden", "trace_hidden_naive",
           "trace_hidden_rays", "trace_hidden_rays_naive"]
