"""The sky (a UsdLux dome light): its radiance for rays that leave the screen, and its irradiance on the
camera's diffuse surfaces, with a cheap occlusion term.

Irradiance from the sky on a surface point x with normal n is

    E(x, n) = ∫ L(ω) V(x, ω) max(0, n·ω) dω          [W/m²], L in W/(m² sr)

and is computed as E0(n) · A(x, n):

* ``E0(n) = ∫ L(ω) max(0, n·ω) dω``, the unoccluded irradiance, from the sky's projection on real
  spherical harmonics of order 2 (Ramamoorthi & Hanrahan 2001): exact for a uniform sky (π L) and for
  any sky whose radiance is a polynomial of degree ≤ 2 in ω (a linear horizon-to-zenith gradient, say),
  within a few per cent for others. The projection integrates the lat-long map texel by texel with each
  texel's exact solid angle, so a uniform sky gives π L to rounding.
* ``A(x, n) = Σ_k w_k V_k(x) / Σ_k w_k`` with ``w_k = max(0, n·ω_k) · Y(L(ω_k))`` (Y: luminance): the
  fraction of that irradiance not blocked, estimated from K occlusion maps, orthographic depth maps of the
  opaque geometry looking along −ω_k for K directions ω_k spread evenly over the sphere (a spherical
  Fibonacci set). V_k is the percentage-closer shadow test of ``shade.shadow_visibility``. Unoccluded,
  A = 1 and E = E0 exactly, whatever K.

The occlusion maps are world-space: rendered once, and again each frame only when opaque geometry moves,
so the term neither crawls under a moving camera nor misses geometry off screen (as screen-space AO
would). What they cannot resolve: contact shadows finer than about two map texels. Water (transmissive)
is not in them: skylight reaches the floor of a pool as if the water were not there (the exact value is
(1 − F̄) ≈ 0.93 of that for a flat surface, F̄ the hemispherical Fresnel reflectance of water).
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from .raster import kernels as RK
from .raster.views import ViewParams, _ortho_fit, fixed_projection, world_project
from .scene.model import LAYER_OPAQUE, Sky

PI = wp.constant(math.pi)
SH_BANDS = (0, 1, 1, 1, 2, 2, 2, 2, 2)  #: band l of each of the 9 real SH coefficients
SH_CONVOLUTION = (math.pi, 2.0 * math.pi / 3.0, math.pi / 4.0)  #: Â_l: clamped-cosine kernel per band


@wp.struct
class SkyMap:
    """A sky as kernels see it: lat-long radiance and the dome's orientation."""

    radiance: wp.array(dtype=wp.vec3)  #: (H*W,) lat-long radiance [W/(m² sr)], row 0 = zenith (read)
    width: int
    height: int
    to_local: wp.mat33  #: world direction -> dome-local direction
    present: int  #: 1: a dome light; 0: none, black everywhere (the map is a black 1x2 and is not read)


@wp.func
def sky_radiance(sky: SkyMap, d: wp.vec3) -> wp.vec3:
    """Radiance [W/(m² sr)] arriving from world direction ``d`` (towards the sky), bilinear in the map; zero without
    a sky (what the black map gives for any finite ``d``, without its trigonometry and reads: 63% of the Cornell box's
    pixels and every reflected ray leaving its water ask)."""
    if sky.present == 0:
        return wp.vec3(0.0)
    l = wp.normalize(sky.to_local * d)
    lon = wp.atan2(l[0], l[2])
    lat = wp.asin(wp.clamp(l[1], -1.0, 1.0))
    u = (PI - lon) / (2.0 * PI) * float(sky.width) - 0.5  # texel centres at integers
    v = (0.5 * PI - lat) / PI * float(sky.height) - 0.5
    i0 = int(wp.floor(u))
    j0 = int(wp.floor(v))
    a = u - float(i0)
    b = v - float(j0)
    out = wp.vec3(0.0)
    for dj in range(2):
        j = wp.clamp(j0 + dj, 0, sky.height - 1)
        wy = wp.where(dj == 0, 1.0 - b, b)
        for di in range(2):
            i = (i0 + di) % sky.width
            if i < 0:
                i += sky.width
            wx = wp.where(di == 0, 1.0 - a, a)
            out += sky.radiance[j * sky.width + i] * (wx * wy)
    return out


@wp.func
def sh_irradiance(sh: wp.array(dtype=wp.vec3), n: wp.vec3) -> wp.vec3:
    """Unoccluded irradiance [W/m²] on a surface with unit normal ``n`` from 9 convolved SH coefficients."""
    x = n[0]
    y = n[1]
    z = n[2]
    e = sh[0] * 0.282095
    e += sh[1] * (0.488603 * y) + sh[2] * (0.488603 * z) + sh[3] * (0.488603 * x)
    e += sh[4] * (1.092548 * x * y) + sh[5] * (1.092548 * y * z) + sh[6] * (0.315392 * (3.0 * z * z - 1.0))
    e += sh[7] * (1.092548 * x * z) + sh[8] * (0.546274 * (x * x - y * y))
    return wp.max(e, wp.vec3(0.0))


@wp.func
def pcf_visibility(view: ViewParams, depth: wp.array(dtype=wp.float32), base: int, x: wp.vec3, nl: wp.vec3,
                   texel: float):
    """(inside, visibility in [0, 1]) of world point ``x`` in one depth map (its texels from ``base``), bilinear
    percentage-closer: the point pushed 1.5 ``texel`` [m] along ``nl`` (its normal turned towards the light) and
    compared with a one-texel depth bias; (0, 1) outside the map."""
    q = world_project(view, x + nl * (1.5 * texel))
    if q[2] <= 0.0 or q[0] < 0.0 or q[1] < 0.0 or q[0] >= float(view.width) or q[1] >= float(view.height):
        return int(0), float(1.0)
    fx = q[0] - 0.5
    fy = q[1] - 0.5
    i0 = int(wp.floor(fx))
    j0 = int(wp.floor(fy))
    ax = fx - float(i0)
    ay = fy - float(j0)
    vis = float(0.0)
    for dj in range(2):
        for di in range(2):
            i = wp.clamp(i0 + di, 0, view.width - 1)
            j = wp.clamp(j0 + dj, 0, view.height - 1)
            sd = depth[base + j * view.width + i]
            lit = float(1.0)
            if sd > 0.0 and q[2] > sd + texel:
                lit = 0.0
            vis += wp.where(di == 0, 1.0 - ax, ax) * wp.where(dj == 0, 1.0 - ay, ay) * lit
    return int(1), vis


@wp.func
def map_visibility(view: ViewParams, depth: wp.array(dtype=wp.float32), base: int, x: wp.vec3, n: wp.vec3,
                   to_sky: wp.vec3) -> float:
    """Visibility in [0, 1] of world point ``x`` towards the sky along ``to_sky`` in one occlusion map
    (the map's texels start at ``base``); 1 outside the map. Bias and filter as ``shade.shadow_visibility``
    (:func:`pcf_visibility`), the texel the map's own (orthographic)."""
    nl = n
    if wp.dot(nl, to_sky) < 0.0:
        nl = -nl
    inside, vis = pcf_visibility(view, depth, base, x, nl, 1.0 / view.fx)
    return vis


@wp.func
def same_view(a: ViewParams, b: ViewParams) -> int:
    """1 when every field of ``a`` equals ``b``'s (bitwise for finite values), else 0."""
    same = int(a.fx == b.fx and a.fy == b.fy and a.cx == b.cx and a.cy == b.cy and a.near == b.near and a.far == b.far
               and a.width == b.width and a.height == b.height and a.orthographic == b.orthographic)
    for i in range(4):
        for j in range(4):
            if a.world_to_view[i, j] != b.world_to_view[i, j] or a.view_to_world[i, j] != b.view_to_world[i, j]:
                same = 0
    return same


@wp.kernel
def sky_inputs_changed(
    cameras: wp.array(dtype=ViewParams),  # (2,) this frame's camera first (frame.FrameInputs.cameras, read)
    force: int,  # 1: compute whatever the camera (the occlusion maps are redrawn every frame: opaque geometry moves)
    computed_for: wp.array(dtype=ViewParams),  # (1,) the camera ``irradiance`` was last computed for (read, write)
    changed: wp.array(dtype=wp.int32),  # (1,) 1 when sky_irradiance_kernel must compute this frame (write)
):
    """One thread: whether the irradiance in the buffer still holds. Its inputs are the camera's opaque G-buffer (a
    function of the camera and the opaque geometry), the occlusion maps and the sky: with the opaque geometry static
    (else ``force``), the camera it was computed for gives the same G-buffer, bit for bit, hence the same
    irradiance. Compared with the camera of the buffer's contents, not the last frame's: frames that leave the sky
    out (``sequence.render_history_frame``) do not fool it. The water is not an input (not in the opaque layer, not
    in the maps)."""
    camera = cameras[0]
    if force != 0 or same_view(camera, computed_for[0]) == 0:
        changed[0] = 1
        computed_for[0] = camera
    else:
        changed[0] = 0


occlusion_view = fixed_projection(1)  #: an occlusion map's view: orthographic (``_ortho_fit``), a compile-time constant


@wp.func
def sky_irradiance_at(
    x: wp.vec3,  # world point [m]
    n: wp.vec3,  # its unit normal
    sh: wp.array(dtype=wp.vec3),  # (9,) convolved SH coefficients of the sky [W/m²]
    views: wp.array(dtype=ViewParams),  # (K,) occlusion map views
    directions: wp.array(dtype=wp.vec3),  # (K,) unit directions towards the sky ω_k
    luminance: wp.array(dtype=wp.float32),  # (K,) sky luminance along ω_k [W/(m² sr)]
    map_depth: wp.array(dtype=wp.float32),  # (K*S*S,) occlusion maps, nearest opaque depth [m]
    map_texels: int,  # S*S
) -> wp.vec3:
    """Sky irradiance E0(n) · A(x, n) [W/m²] on a world point (module docstring): what
    :func:`sky_irradiance_kernel` gives a camera pixel, and the reference (:mod:`cisp_warp.photons.world`) the
    diffuse end of a camera path, so both see the same sky."""
    num = float(0.0)
    den = float(0.0)
    for k in range(directions.shape[0]):
        w = wp.dot(n, directions[k]) * luminance[k]
        if w > 0.0:
            # the maps' projection folded (no perspective division a map: docs/perf_notes.md section 67)
            num += w * map_visibility(occlusion_view(views[k]), map_depth, k * map_texels, x, n, directions[k])
            den += w
    a = float(1.0)
    if den > 0.0:
        a = num / den
    return sh_irradiance(sh, n) * a


@wp.kernel
def sky_irradiance_kernel(
    changed: wp.array(dtype=wp.int32),  # (1,) sky_inputs_changed: 0 keeps the last frame's irradiance (read)
    depth: wp.array(dtype=wp.float32),  # (H*W,) camera opaque depth [m], 0 = none (read)
    position: wp.array(dtype=wp.vec3),  # (H*W,) world position [m] (read)
    normal: wp.array(dtype=wp.vec3),  # (H*W,) unit normal (read)
    sh: wp.array(dtype=wp.vec3),  # (9,) convolved SH coefficients of the sky [W/m²] (read)
    views: wp.array(dtype=ViewParams),  # (K,) occlusion map views (read)
    directions: wp.array(dtype=wp.vec3),  # (K,) unit directions towards the sky ω_k (read)
    luminance: wp.array(dtype=wp.float32),  # (K,) sky luminance along ω_k [W/(m² sr)] (read)
    map_depth: wp.array(dtype=wp.float32),  # (K*S*S,) occlusion maps, nearest opaque depth [m] (read)
    map_texels: int,  # S*S
    irradiance: wp.array(dtype=wp.vec3),  # (H*W,) sky irradiance [W/m²] (write when ``changed``)
):
    p = wp.tid()
    if changed[0] == 0:
        return
    if depth[p] <= 0.0:
        irradiance[p] = wp.vec3(0.0)
        return
    irradiance[p] = sky_irradiance_at(position[p], normal[p], sh, views, directions, luminance, map_depth, map_texels)


def fibonacci_directions(count: int) -> np.ndarray:
    """``count`` unit vectors spread evenly over the sphere (spherical Fibonacci lattice), (count, 3) float64."""
    k = np.arange(count, dtype=np.float64) + 0.5
    y = 1.0 - 2.0 * k / count
    r = np.sqrt(np.maximum(0.0, 1.0 - y * y))
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    return np.stack([r * np.cos(phi), y, r * np.sin(phi)], axis=-1)


def latlong_directions(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Dome-local unit direction (H, W, 3) of every lat-long texel centre and its exact solid angle (H, W) [sr]."""
    lat_edges = 0.5 * math.pi - math.pi * np.arange(height + 1) / height
    lat = 0.5 * (lat_edges[:-1] + lat_edges[1:])
    lon = math.pi - 2.0 * math.pi * (np.arange(width) + 0.5) / width
    LAT, LON = np.meshgrid(lat, lon, indexing="ij")
    d = np.stack([np.cos(LAT) * np.sin(LON), np.sin(LAT), np.cos(LAT) * np.cos(LON)], axis=-1)
    solid_angle = (np.sin(lat_edges[:-1]) - np.sin(lat_edges[1:]))[:, None] * (2.0 * math.pi / width)
    return d, np.broadcast_to(solid_angle, (height, width))


def sh_basis(d: np.ndarray) -> np.ndarray:
    """The 9 real SH basis functions (bands 0-2) at unit directions ``d`` (..., 3) -> (..., 9)."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    return np.stack([np.full_like(x, 0.282095), 0.488603 * y, 0.488603 * z, 0.488603 * x, 1.092548 * x * y,
                     1.092548 * y * z, 0.315392 * (3.0 * z * z - 1.0), 1.092548 * x * z,
                     0.546274 * (x * x - y * y)], axis=-1)


def sky_sh_irradiance(sky: Sky) -> np.ndarray:
    """(9, 3) SH coefficients, convolved with the clamped cosine, of the sky in world directions:
    ``sh_basis(n) @ coefficients`` is the unoccluded irradiance [W/m²] on a surface with normal n.

    A uniform sky has only the constant term, L·√(4π), so E = π L exactly. A texture is integrated as
    piecewise constant per texel, each texel split into sub-texels (at least 128 rows in all) with their
    exact solid angles, so that coarse maps are integrated accurately too.
    """
    coeff = np.zeros((9, 3))
    if sky.texture is None:
        coeff[0] = np.asarray(sky.radiance, dtype=np.float64) * math.sqrt(4.0 * math.pi)
    else:
        L = sky.radiance_map()
        f = max(1, -(-128 // L.shape[0]))
        L = np.repeat(np.repeat(L, f, axis=0), f, axis=1)
        d, dw = latlong_directions(*L.shape[:2])
        world = d @ np.asarray(sky.to_world, dtype=np.float64).T
        coeff = np.einsum("hwk,hwc,hw->kc", sh_basis(world), L, dw)
    return coeff * np.array([SH_CONVOLUTION[b] for b in SH_BANDS])[:, None]


def sky_map(sky: Sky | None, device) -> SkyMap:
    """The kernel struct of ``sky`` (a black 1x2 map when there is none). Keep the result: it owns the array."""
    m = SkyMap()
    L = np.zeros((1, 2, 3)) if sky is None else sky.radiance_map()
    m.radiance = wp.array(L.reshape(-1, 3).astype(np.float32), dtype=wp.vec3, device=device)
    m.height, m.width = int(L.shape[0]), int(L.shape[1])
    to_world = np.eye(3) if sky is None else np.asarray(sky.to_world, dtype=np.float64)
    m.to_local = wp.mat33(*np.linalg.inv(to_world).astype(np.float32).flatten())
    m.present = int(sky is not None)
    return m


class SkyLighting:
    """Sky irradiance [W/m²] on the camera's opaque surfaces (see the module docstring).

    ``directions``: K, the number of occlusion maps; ``map_size``: their edge [texels]. Buffers: K·S²
    float32 map depths, one S² visibility scratch, (H*W,) vec3 ``irradiance``.
    """

    def __init__(self, gpu, sky: Sky, width: int, height: int, directions: int = 32, map_size: int = 256):
        self.gpu = gpu
        self.sky = sky
        d = gpu.device
        self.device = d
        scene = gpu.scene
        self.map = sky_map(sky, d)
        self.sh = wp.array(sky_sh_irradiance(sky).astype(np.float32), dtype=wp.vec3, device=d)
        self.irradiance = wp.zeros(width * height, dtype=wp.vec3, device=d)
        layers = scene.triangle_layers()
        opaque = (layers & LAYER_OPAQUE) != 0
        omega = fibonacci_directions(directions) if opaque.any() else np.zeros((0, 3))
        L = sky.radiance_map()
        ld, _ = latlong_directions(*L.shape[:2])
        world = ld @ np.asarray(sky.to_world, dtype=np.float64).T
        lum_map = L @ np.array([0.2126, 0.7152, 0.0722])
        # sky luminance along each ω_k: the texel nearest to it (weights only; E0 carries the radiometry)
        nearest = np.argmax(omega @ world.reshape(-1, 3).T, axis=1) if len(omega) else np.zeros(0, int)
        lum = lum_map.reshape(-1)[nearest] if len(omega) else np.zeros(0)
        self.directions = wp.array(omega.astype(np.float32), dtype=wp.vec3, device=d)
        self.luminance = wp.array(np.maximum(lum, 1e-6).astype(np.float32), dtype=wp.float32, device=d)
        self.map_size = int(map_size)
        if len(omega):
            lo, hi = scene.bounds(LAYER_OPAQUE)
            self.views = [_ortho_fit(-w, lo, hi, lo, hi, self.map_size, f"sky_{k}") for k, w in enumerate(omega)]
        else:
            self.views = []
        self.view_params = wp.array([v.params() for v in self.views] or [self._empty_view()], dtype=ViewParams,
                                    device=d)
        texels = self.map_size * self.map_size
        self.map_depth = wp.zeros(max(1, len(self.views)) * texels, dtype=wp.float32, device=d)
        self.visibility = wp.zeros(texels, dtype=wp.uint64, device=d)
        self.tri_scratch = wp.zeros(texels, dtype=wp.int32, device=d)
        dynamic_opaque = False
        for m in scene.meshes:
            if m.dynamic and opaque[m.triangle_start : m.triangle_start + m.triangle_count].any():
                dynamic_opaque = True
        self.dynamic = dynamic_opaque  #: opaque geometry moves: the maps are redrawn every frame
        self._drawn = False
        #: (1,) int32: whether this frame computes the irradiance (``sky_inputs_changed``); else the buffer's stays
        self.changed = wp.ones(1, dtype=wp.int32, device=d)
        #: (1,) ViewParams: the camera ``irradiance`` was computed for (zeros, a view of no pixels, until the first)
        self.computed_for = wp.zeros(1, dtype=ViewParams, device=d)

    @staticmethod
    def _empty_view() -> ViewParams:
        v = ViewParams()
        v.width, v.height, v.fx, v.fy = 1, 1, 1.0, 1.0
        return v

    def render_maps(self, raster) -> None:
        """Draw the K occlusion maps (the opaque layer's depth along each −ω_k)."""
        s = self.gpu
        texels = self.map_size * self.map_size
        for k, view in enumerate(self.views):
            raster.draw(self.view_params, k, view.width, view.height, LAYER_OPAQUE, self.visibility)
            wp.launch(RK.resolve_depth, dim=texels, device=self.device,
                      inputs=[self.view_params, k, self.visibility, s.points, s.indices,
                              self.map_depth[k * texels : (k + 1) * texels], self.tri_scratch])
        self._drawn = True

    def render(self, raster, gbuffer, cameras: wp.array) -> None:
        """Sky irradiance of this frame's G-buffer into ``irradiance`` (maps redrawn when needed).

        ``cameras``: (2,) ViewParams, the camera ``gbuffer`` was drawn with first (``FrameInputs``). When it is the
        camera the buffer's irradiance was computed for and the opaque geometry is static, the G-buffer is that
        frame's and the irradiance is kept (decided on the device, so a captured frame keeps deciding); the first
        frame, and every frame of a scene whose opaque geometry moves, computes it."""
        if self.dynamic or not self._drawn:
            self.render_maps(raster)
        wp.launch(sky_inputs_changed, dim=1, device=self.device,
                  inputs=[cameras, int(self.dynamic), self.computed_for, self.changed])
        wp.launch(sky_irradiance_kernel, dim=gbuffer.width * gbuffer.height, device=self.device,
                  inputs=[self.changed, gbuffer.depth, gbuffer.position, gbuffer.normal, self.sh, self.view_params,
                          self.directions, self.luminance, self.map_depth, self.map_size * self.map_size,
                          self.irradiance])


__all__ = ["SkyLighting", "SkyMap", "fibonacci_directions", "latlong_directions", "same_view", "sh_basis",
           "sky_irradiance_at", "sky_map", "sky_radiance", "sky_sh_irradiance"]
