"""World-space photon methods: Screen-Space Photon Mapping (seed 003) and the converged reference.

>>> r = Renderer(scene, RenderSettings(method="reference", photons=PhotonSettings(photons=1 << 20)))
>>> r.render_frame()           # accumulates reference_photons per light, in passes of ``photons``
>>> r.aovs()["caustics_stderr"]  # per-pixel standard error of the reference's irradiance
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from ..raster import GBuffer, LightMaps
from ..raster.views import View
from ..scene import DeviceScene
from ..scene.model import LAYER_OPAQUE, LAYER_SPECULAR
from ..sky import sky_map
from . import kernels_world as K
from .base import PhotonPass, PhotonSettings, frame_random


def world_scene(scene: DeviceScene) -> K.WorldScene:
    """The kernels' view of ``scene``: BVHs built once (refit by ``DeviceScene.refit``), material tables."""
    ws = K.WorldScene()
    mesh, face_map = scene.bvh(LAYER_OPAQUE | LAYER_SPECULAR)
    ws.mesh, ws.face_to_tri = mesh.id, face_map
    ws.opaque_mesh = scene.bvh(LAYER_OPAQUE)[0].id if scene.has_layer[LAYER_OPAQUE] else mesh.id
    ws.points, ws.normals, ws.indices = scene.points, scene.normals, scene.indices
    ws.triangle_material, ws.triangle_layers = scene.triangle_material, scene.triangle_layers
    ws.albedo, ws.roughness, ws.opacity, ws.ior = scene.albedo, scene.roughness, scene.opacity, scene.ior
    return ws


class _WorldPass(PhotonPass):
    """Shared set-up of the world-space methods: the BVH view of the scene and the camera's buffers."""

    def __init__(self, scene: DeviceScene, gbuffer: GBuffer, camera_view: View, lights: list[LightMaps],
                 settings: PhotonSettings, device, t_max: float):
        super().__init__(scene, gbuffer, camera_view, lights, settings, device, t_max)
        self.world = world_scene(scene)
        self.cam = K.CameraBuffers()
        self.cam.view = camera_view.params()
        # the depth with its back-face layer behind it (march.surface_far: camera_receiver's visibility test)
        self.cam.depth, self.cam.position, self.cam.normal = gbuffer.depth_layers, gbuffer.position, gbuffer.normal
        self.cam.solid_angle = self.solid_angle


class SSPM(_WorldPass):
    """Screen-Space Photon Mapping (Kim 2019, seed 003): photons emitted as CISP's, traced in world space
    through the BVH with up to ``max_bounces`` specular bounces, stored after a depth-visibility test."""

    name = "sspm"

    def __init__(self, scene: DeviceScene, gbuffer: GBuffer, camera_view: View, lights: list[LightMaps],
                 settings: PhotonSettings, device, t_max: float):
        super().__init__(scene, gbuffer, camera_view, lights, settings, device, t_max)
        self.wavefront = None
        if settings.splat == "point":
            self.keep_photon_m2(gbuffer.width * gbuffer.height)
            self.keep_hidden()
        if settings.splat == "wavefront":
            from .wavefront import make_wavefront

            self.wavefront = make_wavefront(self, self.cam)
        #: (2N,) each photon's final entry and power, then its absorption at further bounces, added to the ledger
        #: after the trace (K.trace_sspm)
        n_out = 2 * self.max_photons_per_view() if self.wavefront is None else 1
        self.outcome = wp.zeros(n_out, dtype=wp.vec4, device=self.device)

    def trace(self, gbuffer: GBuffer, camera: wp.struct, frame: int) -> None:
        s = self.settings
        self.frame_inputs(camera, frame)
        self.begin()
        self.cam.view = camera
        if self.wavefront is not None:
            self.wavefront.trace(frame, "sspm", self.world)
            return
        for b in self.rsm_batches(frame):
            sp = b.rsm.specular
            self.launch_photons(K.trace_sspm, b.slots, inputs=[
                b.lights.views, b.lights.states, b.view_index, int(b.lights.light.kind), b.light_pos,
                sp.depth, b.lights.emission(b.rsm), sp.tri_id, self.scene.geometry,
                self._max_lum_of[b.light_index], self.world, self.cam, self.inputs.cameras, b.light_photons, b.slots,
                self.inputs.randoms, b.stream, b.order, self.use_order,
                float(s.roughness_cutoff), b.luminance_cutoff, float(s.thickness), float(s.thickness_rel),
                self.t_max, int(s.max_bounces), self.footprint_mode, self.photon_map, self.photon_m2, self.ledger_rows,
                self.outcome, *self.hidden_args(b)])
            self.add_outcomes(self.outcome, b, 2, K.SSPM_FINAL_ENTRIES)


def reference_target(settings: PhotonSettings, device) -> int:
    """Photons per light the reference accumulates: the setting, else 1e8 on CUDA and 4e6 on the CPU."""
    if settings.reference_photons > 0:
        return int(settings.reference_photons)
    return 100_000_000 if wp.get_device(device).is_cuda else 4_000_000


class Reference(_WorldPass):
    """Converged world-space photon tracing, the ground truth of every error figure.

    Photons leave the light itself (continuous samples of its views, first hit by ray casting) and are
    traced through the BVH; each is stored into the camera pixel it lands in, if the eye sees it
    (exact BVH visibility) and it lies on the surface the pixel shows (within two pixel widths of the
    G-buffer sample's tangent plane: not another surface at a silhouette), by the exact pixel footprint:
    an unbiased estimate of each pixel's mean irradiance on the opaque G-buffer. ``passes`` passes of ``photons`` photons each are averaged;
    ``caustics_stderr`` is the standard error of that mean, from the pass-to-pass variance.

    The final image follows ``paths_per_pixel`` camera paths per pixel through specular surfaces to the
    first diffuse surface; there the caustic irradiance is a density estimate over each pass's photon
    landing points (``wp.HashGrid``, radius ``gather_radius``), the direct irradiance an exact shadow ray, and the
    sky's the methods' own (:meth:`use_sky`); a path that leaves the scene sees the sky's radiance.
    """

    name = "reference"
    denoise = False

    def __init__(self, scene: DeviceScene, gbuffer: GBuffer, camera_view: View, lights: list[LightMaps],
                 settings: PhotonSettings, device, t_max: float, paths_per_pixel: int | None = None):
        super().__init__(scene, gbuffer, camera_view, lights, settings, device, t_max)
        d = self.device
        self.target = reference_target(settings, d)
        self.passes = max(2, math.ceil(self.target / settings.photons))
        self.paths_per_pixel = paths_per_pixel or (16 if d.is_cuda else 4)
        n = gbuffer.width * gbuffer.height
        self.pass_map = wp.zeros(n, dtype=wp.vec3, device=d)
        self.total = wp.zeros(n, dtype=wp.vec3d, device=d)
        self.total_sq = wp.zeros(n, dtype=wp.vec3d, device=d)
        self.stderr = wp.zeros(n, dtype=wp.vec3, device=d)
        self.final = wp.zeros(n, dtype=wp.vec3, device=d)
        self.offsets = []
        count = 0
        for lm in lights:
            per = self.photons_per_view(lm)
            self.offsets.append([count + i * per for i in range(len(lm.rsm))])
            count += per * len(lm.rsm)
        count = max(count, 1)
        self.landing_pos = wp.zeros(count, dtype=wp.vec3, device=d)
        self.landing_normal = wp.zeros(count, dtype=wp.vec3, device=d)
        self.landing_power = wp.zeros(count, dtype=wp.vec3, device=d)
        self.grid = wp.HashGrid(128, 128, 128, device=d)
        self.gather_radius = gather_radius(camera_view, scene)
        e = n * self.paths_per_pixel
        self.end_pos = wp.zeros(e, dtype=wp.vec3, device=d)
        self.end_normal = wp.zeros(e, dtype=wp.vec3, device=d)
        self.end_weight = wp.zeros(e, dtype=wp.vec3, device=d)
        self.end_primary = wp.zeros(e, dtype=wp.int32, device=d)
        self.end_direct = wp.zeros(e, dtype=wp.vec3, device=d)
        self.end_caustic = wp.zeros(e, dtype=wp.vec3, device=d)
        self.end_sky = wp.zeros(e, dtype=wp.vec3, device=d)
        self.sky_map = sky_map(None, d)  #: the dome's radiance, seen by paths that leave the scene (:meth:`use_sky`)
        self.sky = None  #: the renderer's :class:`cisp_warp.sky.SkyLighting` (:meth:`use_sky`), None without a sky
        self.progress = None  #: optional callable(passes_done, passes) for long runs

    def use_sky(self, sky, radiance_map) -> None:
        """Light the final image with the renderer's sky, as the methods' composite does: ``radiance_map`` (a
        :class:`cisp_warp.sky.SkyMap`) where a camera path leaves the scene, and ``sky`` (its
        :class:`cisp_warp.sky.SkyLighting`, or None) for the sky irradiance at a path's diffuse end, from the same
        SH projection and occlusion maps (drawn by the renderer's sky stage before the photon pass)."""
        self.sky = sky
        self.sky_map = radiance_map

    def trace(self, gbuffer: GBuffer, camera: wp.struct, frame: int) -> None:
        s = self.settings
        d = self.device
        self.begin()
        self.cam.view = camera
        self.total.zero_()
        self.total_sq.zero_()
        self.end_direct.zero_()
        self.end_caustic.zero_()
        e = self.end_pos.shape[0]
        _, _, path_seed = frame_random(s.seed, frame, 1 << 20)
        wp.launch(K.camera_paths, dim=e, device=d, inputs=[
            self.world, self.cam, self.paths_per_pixel, path_seed, float(s.roughness_cutoff), self.t_max,
            int(s.max_bounces), self.end_pos, self.end_normal, self.end_weight, self.end_primary, self.sky_map,
            self.end_sky])
        if self.sky is not None:
            k = self.sky
            wp.launch(K.endpoint_sky, dim=e, device=d, inputs=[
                k.sh, k.view_params, k.directions, k.luminance, k.map_depth, k.map_size * k.map_size,
                self.end_pos, self.end_normal, self.end_weight, self.end_direct])
        for lm in self.lights:
            light = lm.light
            wp.launch(K.endpoint_direct, dim=e, device=d, inputs=[
                self.world, int(light.kind), wp.vec3(*light.radiometric_rgb.astype(np.float32)),
                wp.vec3(*np.asarray(light.position, np.float32)), wp.vec3(*np.asarray(light.direction, np.float32)),
                float(light.cone_angle), float(light.cone_softness), self.t_max,
                self.end_pos, self.end_normal, self.end_weight, self.end_direct])
        for k in range(self.passes):
            self.pass_map.zero_()
            for li, lm in enumerate(self.lights):
                light = lm.light
                for vi, params in enumerate(lm.params):
                    n = self.photons_per_view(lm)
                    sx, sy, rng_seed = frame_random(s.seed, frame, (k + 1) * 4096 + li * 64 + vi)
                    self.launch_photons(K.trace_reference, n, inputs=[
                        params, int(light.kind), wp.vec3(*light.radiometric_rgb.astype(np.float32)),
                        wp.vec3(*np.asarray(light.position, np.float32)),
                        wp.vec3(*np.asarray(light.direction, np.float32)),
                        float(light.cone_angle), float(light.cone_softness),
                        self.world, self.cam, n, rng_seed, wp.vec2i(sx, sy), float(s.roughness_cutoff), self.t_max,
                        int(s.max_bounces), self.footprint_mode, self.offsets[li][vi], self.pass_map, None,
                        self.landing_pos, self.landing_normal, self.landing_power, self.ledger_rows])
            wp.launch(K.accumulate_pass, dim=self.pass_map.shape[0], device=d,
                      inputs=[self.pass_map, self.total, self.total_sq])
            self.grid.build(self.landing_pos, self.gather_radius)
            wp.launch(K.endpoint_gather, dim=e, device=d, inputs=[
                self.grid.id, self.gather_radius, self.landing_pos, self.landing_normal, self.landing_power,
                self.end_pos, self.end_normal, self.end_weight, self.end_primary, self.end_caustic])
            if self.progress is not None:
                self.progress(k + 1, self.passes)
        wp.launch(K.finish_passes, dim=self.pass_map.shape[0], device=d,
                  inputs=[self.total, self.total_sq, self.passes, self.photon_map, self.stderr])
        self.fold_ledger()
        wp.launch(K.scale_ledger, dim=self.ledger.shape[0], device=d, inputs=[self.ledger, wp.float64(1.0 / self.passes)])
        wp.launch(K.resolve_final, dim=self.pass_map.shape[0], device=d, inputs=[
            self.paths_per_pixel, self.passes, self.photon_map, self.end_weight, self.end_primary,
            self.end_direct, self.end_caustic, self.end_sky, self.final])

    def aovs(self, shape: tuple[int, int]) -> dict[str, np.ndarray]:
        return {"caustics_stderr": self.stderr.numpy().reshape(shape + (3,))}


def gather_radius(view: View, scene: DeviceScene) -> float:
    """Density-estimation radius [m] for what is seen through water: two camera pixels at the scene's centre."""
    lo, hi = scene.scene.bounds()
    centre = 0.5 * (np.asarray(lo, np.float64) + np.asarray(hi, np.float64))
    if view.orthographic:
        pixel = 1.0 / view.fx
    else:
        pixel = float(np.linalg.norm(centre - view.to_world[:3, 3])) / view.fx
    return max(2.0 * pixel, 1e-4)
