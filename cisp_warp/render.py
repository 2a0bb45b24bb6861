"""The frame: raster light views and camera, light the scene, composite. One class owns every buffer.

>>> r = Renderer(load_usd("scenes_usd/cornell_flooded.usda"), RenderSettings(), device="cpu")
>>> r.render_frame()
>>> aovs = r.aovs()          # dict of numpy arrays, host copies
"""

from __future__ import annotations

from contextlib import nullcontext
from dataclasses import dataclass, field, replace

import numpy as np
import warp as wp

from .denoise import SVGF, GaussianGather, SVGFSettings
from .errors import SceneError
from .photons import PHOTON_METHODS, PhotonSettings, photon_pass_class
from .photons.fit import LightViewFitter
from .raster import GBuffer, LightMaps, LightViewSettings, Rasterizer, camera_view
from .scene import Camera, DeviceScene, Scene
from .shade import DirectLighting, composite, surface_radiance


@dataclass(frozen=True)
class RenderSettings:
    """What a render is asked for. Frozen and hashable: passes may specialise kernels on it."""

    width: int | None = None  #: image width [pixels]; None = the scene camera's
    height: int | None = None  #: image height [pixels]; None = the scene camera's
    rsm_size: int = 1024  #: edge of each reflective-shadow-map view [texels]
    method: str = "cisp"  #: photon method: "cisp", "sspm", "caustics_map", "reference", or "none" (direct only)
    photons: PhotonSettings = PhotonSettings()
    light_views: LightViewSettings = LightViewSettings()  #: RSM views fitted to the camera (cisp, sspm)
    denoiser: str = "svgf"  #: "svgf", "gather" (seed 004's 7×7 Gaussian) or "none" (raw photon map)
    svgf: SVGFSettings = field(default_factory=SVGFSettings)

    def validate(self) -> None:
        for name in ("width", "height"):
            v = getattr(self, name)
            if v is not None and (not isinstance(v, (int, np.integer)) or v <= 0):
                raise SceneError(f"--{name} must be a positive integer, got {v!r}")
        if not isinstance(self.rsm_size, (int, np.integer)) or not (1 <= self.rsm_size <= 16384):
            raise SceneError(f"--rsm-size must be an integer in [1, 16384], got {self.rsm_size!r}")
        if self.method not in METHODS:
            raise SceneError(f"--method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if self.denoiser not in DENOISERS:
            raise SceneError(f"--denoiser must be one of {', '.join(DENOISERS)}, got {self.denoiser!r}")
        self.photons.validate()
        self.light_views.validate()


METHODS = PHOTON_METHODS + ("none",)
#: methods whose RSM views are fitted to the camera; caustics_map keeps whole views: its caustic maps and their
#: temporal history live in light space, which a window that follows the camera would move under them
FITTED_METHODS = ("cisp", "sspm")
DENOISERS = ("svgf", "gather", "none")


class Renderer:
    """Renders frames of one scene on one device. Every buffer is allocated here, once."""

    def __init__(self, scene: Scene, settings: RenderSettings | None = None, device=None):
        self.settings = settings or RenderSettings()
        self.settings.validate()
        self.device = wp.get_device(device)
        cam = scene.camera
        if self.settings.width or self.settings.height:
            cam = replace(cam, width=self.settings.width or cam.width, height=self.settings.height or cam.height)
            scene.camera = cam
        scene.validate()
        self.scene = scene
        self.gpu = DeviceScene(scene, self.device)
        self.raster = Rasterizer(self.gpu)
        self.gbuffer = GBuffer.allocate(cam.width, cam.height, self.device)
        views = self.settings.light_views if self.settings.method in FITTED_METHODS else LightViewSettings(fit="scene")
        self.lights = [LightMaps(self.gpu, light, self.settings.rsm_size, views) for light in scene.lights]
        self.direct = DirectLighting(self.gbuffer, self.device)
        n = cam.width * cam.height
        self.caustic_irradiance = wp.zeros(n, dtype=wp.vec3, device=self.device)  # [W/m²], filled by a photon method
        self.surface_radiance = wp.zeros(n, dtype=wp.vec3, device=self.device)
        self.final = wp.zeros(n, dtype=wp.vec3, device=self.device)
        self.view = camera_view(cam)
        self.view_params = self.view.params()
        self.prev_view_params = self.view_params
        lo, hi = scene.bounds()
        self.t_max = float(2.0 * np.linalg.norm(hi - lo)) + 1e-3  # longest screen-space ray [m]
        self.photons = None
        if self.settings.method != "none":
            cls = photon_pass_class(self.settings.method)
            self.photons = cls(self.gpu, self.gbuffer, self.view, self.lights, self.settings.photons, self.device, self.t_max)
        ps = self.settings.photons
        self.fitter = LightViewFitter(self.gpu, self.gbuffer, self.lights, ps.roughness_cutoff, ps.thickness,
                                      ps.thickness_rel, ps.max_bounces, self.t_max, ps.seed)
        self.denoiser = None
        if self.settings.denoiser == "svgf":
            self.denoiser = SVGF(cam.width, cam.height, self.device, self.settings.svgf)
        elif self.settings.denoiser == "gather":
            self.denoiser = GaussianGather(cam.width, cam.height, self.device)
        self.frame = 0

    def set_camera(self, camera: Camera) -> None:
        """Move the camera (same resolution); the previous pose is kept for motion vectors."""
        if (camera.width, camera.height) != (self.gbuffer.width, self.gbuffer.height):
            camera = replace(camera, width=self.gbuffer.width, height=self.gbuffer.height)
        self.scene.camera = camera
        self.view = camera_view(camera)
        self.view_params = self.view.params()

    def update_scene(self, scene: Scene) -> None:
        """Take the camera and the moved points of ``scene`` (same topology) for the next frame.

        For stages whose animation is baked into USD time samples; this copies the points from the
        host. Simulated water is written in place on the device instead (``sim.WaterMesh``).
        """
        if scene.points.shape != self.scene.points.shape or not np.array_equal(scene.indices, self.scene.indices):
            raise SceneError("the stage's topology changes over time; only points may be animated", file=scene.source)
        self.gpu.begin_frame()
        if any(m.dynamic for m in scene.meshes):
            self.gpu.points.assign(scene.points.astype(np.float32))
            self.gpu.normals.assign(scene.normals.astype(np.float32))
            self.gpu.refit()
        self.scene.points, self.scene.normals, self.scene.time = scene.points, scene.normals, scene.time
        self.set_camera(scene.camera)

    def render_frame(self, timer=None) -> None:
        """Raster, light, trace photons, denoise and composite one frame; everything stays on the device.

        ``timer``: a :class:`cisp_warp.timing.StageTimer` to time the stages (benchmarks only).
        """
        stage = timer.stage if timer is not None else (lambda name: nullcontext())
        g = self.gbuffer
        with stage("raster"):
            g.render(self.raster, self.view_params, self.prev_view_params)
            self.fitter.fit(self.raster, self.view_params, self.frame)  # light views fitted to what the camera sees
            for lm in self.lights:
                lm.render(self.raster)
        with stage("direct"):
            self.direct.render(g, self.lights)
        if self.photons is not None:
            with stage("trace+store"):
                self.photons.trace(g, self.view_params, self.frame)
            with stage("denoise"):
                if not self.photons.denoise:
                    wp.copy(self.caustic_irradiance, self.photons.photon_map)
                elif isinstance(self.denoiser, SVGF):
                    self.denoiser.denoise(self.photons.photon_map, g.depth, g.normal, g.motion, g.tri_id, self.caustic_irradiance)
                elif isinstance(self.denoiser, GaussianGather):
                    self.denoiser.apply(self.photons.photon_map, g.depth, g.normal, g.tri_id, self.caustic_irradiance)
                else:
                    wp.copy(self.caustic_irradiance, self.photons.photon_map)
        w = g.water
        with stage("shade"):
            n = g.width * g.height
            wp.launch(surface_radiance, dim=n, device=self.device,
                      inputs=[g.depth, g.albedo, self.direct.irradiance, self.caustic_irradiance, self.surface_radiance])
            ps = self.settings.photons
            wp.launch(composite, dim=n, device=self.device,
                      inputs=[self.view_params, g.depth, self.surface_radiance, w.depth, w.position, w.normal, w.ior,
                              self.t_max, ps.max_steps, ps.thickness, self.final])
            if self.photons is not None and self.photons.final is not None:
                wp.copy(self.final, self.photons.final)  # a method with its own final image (the reference)
        self.prev_view_params = self.view_params
        self.frame += 1

    def aovs(self, include_rsm: bool = True) -> dict[str, np.ndarray]:
        """Host copies of the frame's AOVs, images of shape (H, W[, C]), float32 / int32."""
        g = self.gbuffer
        shape = (g.height, g.width)
        gb = g.numpy()
        out = {k: gb[k] for k in ("depth", "position", "normal", "albedo", "roughness", "tri_id", "motion",
                                  "water_depth", "water_normal")}
        out["direct_irradiance"] = self.direct.irradiance.numpy().reshape(shape + (3,))
        out["final"] = self.final.numpy().reshape(shape + (3,))
        if self.photons is not None:
            out["photon_map"] = self.photons.photon_map.numpy().reshape(shape + (3,))
            out["caustics"] = self.caustic_irradiance.numpy().reshape(shape + (3,))
            out.update(self.photons.aovs(shape))
        if include_rsm:
            for lm in self.lights:
                for r in lm.rsm:
                    for k, v in r.numpy().items():
                        out[f"{r.view.name}_{k}"] = v
        return out
