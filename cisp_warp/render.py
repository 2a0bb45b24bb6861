"""The frame: raster light views and camera, light the scene, composite. One class owns every buffer.

>>> r = Renderer(load_usd("scenes_usd/cornell_flooded.usda"), RenderSettings(), device="cpu")
>>> r.render_frame()
>>> aovs = r.aovs()          # dict of numpy arrays, host copies

``cisp_warp.render`` is this module and, called, :func:`cisp_warp.api.render` (the one-call API).
"""

from __future__ import annotations

from contextlib import nullcontext
import re
import sys
import types
from dataclasses import dataclass, field, fields, replace

import numpy as np
import warp as wp

from .denoise import SVGF, CausticDenoiser, CausticSettings, GaussianGather, SVGFSettings
from .errors import SceneError
from .frame import FrameInputs, FrameLanes
from .photons import PHOTON_METHODS, PhotonSettings, photon_pass_class
from .photons.cisp import build_bounds
from .photons.fit import LightViewFitter
from .photons.march import bounds_size, super_bounds as march_super_bounds, super_shape
from .raster import GBuffer, LightMaps, LightViewSettings, Rasterizer, camera_view
from .scene import Camera, DeviceScene, Scene
from .shade import (MISSED_REFLECTED, MISSED_REFRACTED, DirectLighting, composite_gather, composite_kernels,
                    surface_radiance)
from . import shade
from .shade_hidden import HiddenSurfaces
from .sky import SkyLighting, sky_map


#: RenderSettings.hidden_rays -> the composite's MISSED_* bits of the rays handed to shade_hidden
HIDDEN_RAYS = {"refracted": int(MISSED_REFRACTED), "both": int(MISSED_REFRACTED) | int(MISSED_REFLECTED), "none": 0}


@dataclass(frozen=True)
class RenderSettings:
    """What a render is asked for. Frozen and hashable: passes may specialise kernels on it.

    Plain values are accepted where a settings object is expected: ``RenderSettings(photons=100_000)``
    means ``PhotonSettings(photons=100_000)``, and a dict gives the fields of ``photons`` or ``svgf``.
    A bad value raises :class:`SettingsError` naming the field (``RenderSettings.width``,
    ``PhotonSettings.photons``, ...).
    """

    width: int | None = None  #: image width [pixels]; None = the scene camera's
    height: int | None = None  #: image height [pixels]; None = the scene camera's
    rsm_size: int = 1024  #: edge of each reflective-shadow-map view [texels]
    method: str = "cisp"  #: photon method: "cisp", "sspm", "caustics_map", "reference", or "none" (direct only)
    photons: PhotonSettings = PhotonSettings()
    light_views: LightViewSettings = LightViewSettings()  #: RSM views fitted to the camera (cisp, sspm); or "scene"
    denoiser: str = "caustic"  #: "caustic" (accumulate the raw map, filter what noise is left), "svgf" (the
    #: paper's), "gather" (seed 004's 7×7 Gaussian) or "none" (raw photon map)
    svgf: SVGFSettings = field(default_factory=SVGFSettings)
    caustic: CausticSettings = field(default_factory=CausticSettings)
    supersample: int = 1  #: anti-aliasing: s × s samples per pixel (every pass runs at s·width × s·height,
    #: the AOVs are box-filtered down); 1 = one sample per pixel. ``cisp_warp.render`` and the CLI use 2.
    sky_maps: int = 32  #: occlusion maps of the sky term (directions over the sphere)
    sky_map_size: int = 256  #: edge of each sky occlusion map [texels]
    #: the composite's rays traced on the opaque layer's BVH where the screen-space march finds nothing
    #: (``shade_hidden``): "refracted" (reflected ones see the sky), "both", or "none" (the screen-space fallbacks
    #: alone: sky, and the undistorted background behind the water pixel). Applies where the hidden hits can be
    #: given their caustic (``cisp`` and ``sspm`` with point photons) and without caustics (method ``none``); the
    #: other methods keep the screen-space fallbacks
    hidden_rays: str = "refracted"

    def __post_init__(self):
        photons = self.photons
        if isinstance(photons, (int, np.integer)) and not isinstance(photons, bool):
            photons = PhotonSettings(photons=int(photons))
        elif isinstance(photons, dict):
            photons = _from_dict(PhotonSettings, photons, "PhotonSettings")
        elif not isinstance(photons, PhotonSettings):
            raise SettingsError("photons", f"must be a photon count or a PhotonSettings, got {photons!r}",
                                owner="RenderSettings")
        object.__setattr__(self, "photons", photons)
        svgf = self.svgf
        if isinstance(svgf, dict):
            svgf = _from_dict(SVGFSettings, svgf, "SVGFSettings")
        elif not isinstance(svgf, SVGFSettings):
            raise SettingsError("svgf", f"must be an SVGFSettings or a dict of its fields, got {svgf!r}",
                                owner="RenderSettings")
        object.__setattr__(self, "svgf", svgf)
        views = self.light_views
        if isinstance(views, str):
            views = LightViewSettings(fit=views)
        elif isinstance(views, dict):
            views = _from_dict(LightViewSettings, views, "LightViewSettings")
        elif not isinstance(views, LightViewSettings):
            raise SettingsError("light_views", f"must be 'camera', 'scene', a LightViewSettings or a dict of its "
                                f"fields, got {views!r}", owner="RenderSettings")
        object.__setattr__(self, "light_views", views)
        caustic = self.caustic
        if isinstance(caustic, dict):
            caustic = _from_dict(CausticSettings, caustic, "CausticSettings")
        elif not isinstance(caustic, CausticSettings):
            raise SettingsError("caustic", f"must be a CausticSettings or a dict of its fields, got {caustic!r}",
                                owner="RenderSettings")
        object.__setattr__(self, "caustic", caustic)
        self.validate()

    def validate(self) -> None:
        """Raise :class:`SettingsError` naming the first field whose value cannot be rendered."""
        for name in ("width", "height"):
            v = getattr(self, name)
            if v is not None and not _is_int(v, 1):
                raise SettingsError(name, f"must be a positive integer, got {v!r}")
        if not _is_int(self.rsm_size, 1, 16384):
            raise SettingsError("rsm_size", f"must be an integer in [1, 16384], got {self.rsm_size!r}")
        if self.method not in METHODS:
            raise SettingsError("method", f"must be one of {', '.join(METHODS)}, got {self.method!r}")
        if self.denoiser not in DENOISERS:
            raise SettingsError("denoiser", f"must be one of {', '.join(DENOISERS)}, got {self.denoiser!r}")
        if not _is_int(self.supersample, 1, 8):
            raise SettingsError("supersample", f"must be an integer in [1, 8], got {self.supersample!r}")
        if not _is_int(self.sky_maps, 0, 1024):
            raise SettingsError("sky_maps", f"must be an integer in [0, 1024], got {self.sky_maps!r}")
        if self.hidden_rays not in HIDDEN_RAYS:
            raise SettingsError("hidden_rays", f"must be one of {', '.join(HIDDEN_RAYS)}, got {self.hidden_rays!r}")
        if not _is_int(self.sky_map_size, 1, 8192):
            raise SettingsError("sky_map_size", f"must be an integer in [1, 8192], got {self.sky_map_size!r}")
        try:
            self.photons.validate()
        except SceneError as exc:  # its messages name cisp-render flags: say the field instead
            flag = re.match(r"--([a-z-]+) (.*)", exc.reason)
            name, rest = (flag.group(1).replace("-", "_"), flag.group(2)) if flag else (None, exc.reason)
            if name is None:
                words = re.match(r"([a-z_]+) (.*)", exc.reason)
                name, rest = (words.group(1), words.group(2)) if words else ("photons", exc.reason)
            raise SettingsError(name, rest, owner="PhotonSettings") from None
        try:
            self.light_views.validate()
        except SceneError as exc:  # "fit must be ...": the field first
            words = re.match(r"([a-z_]+) (.*)", exc.reason)
            name, rest = (words.group(1), words.group(2)) if words else ("fit", exc.reason)
            raise SettingsError(name, rest, owner="LightViewSettings") from None
        if self.photons.splat != "point" and self.method not in ("cisp", "sspm"):
            raise SettingsError("splat", f"{self.photons.splat} works with method cisp or sspm, not {self.method}",
                                owner="PhotonSettings")


class SettingsError(SceneError):
    """A settings field with a value the renderer cannot use; ``field`` and ``owner`` name it
    (the CLI turns them back into its flag)."""

    def __init__(self, field: str, reason: str, owner: str = "RenderSettings"):
        self.field = field
        self.owner = owner
        self.detail = reason
        super().__init__(f"{owner}.{field} {reason}")


def _is_int(v, lo: int, hi: int | None = None) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= lo and (hi is None or v <= hi)


def _from_dict(cls, values: dict, owner: str):
    names = {f.name for f in fields(cls)}
    for k in values:
        if k not in names:
            raise SettingsError(str(k), f"is not a field of {owner} (fields: {', '.join(sorted(names))})", owner=owner)
    try:
        return cls(**values)
    except (TypeError, ValueError) as exc:
        raise SceneError(f"{owner}: {exc}") from None


METHODS = PHOTON_METHODS + ("none",)
#: methods whose RSM views are fitted to the camera; caustics_map keeps whole views: its caustic maps and their
#: temporal history live in light space, which a window that follows the camera would move under them
FITTED_METHODS = ("cisp", "sspm")
DENOISERS = ("caustic", "svgf", "gather", "none")


class Renderer:
    """Renders frames of one scene on one device. Every buffer is allocated here, once."""

    #: the composite's gather (the sequential program's ``surface_radiance``) reads SVGF's last level's output in place
    #: (``SVGF.packed_color``: no ``unpack_level`` launch in the frame; that launch flips SVGF's parity;
    #: :attr:`caustic_irradiance` and ``SVGF.variance`` unpack it on demand); False: SVGF unpacks it into
    #: ``caustic_irradiance`` every frame, which the gather reads (the twin)
    GATHER_PACKED = True

    def __init__(self, scene: Scene, settings: RenderSettings | None = None, device=None):
        self.settings = settings or RenderSettings()
        self.settings.validate()
        self.device = wp.get_device(device)
        cam = scene.camera
        ss = self.settings.supersample
        self.width = int(self.settings.width or cam.width)  #: output image width [pixels]
        self.height = int(self.settings.height or cam.height)  #: output image height [pixels]
        if (cam.width, cam.height) != (self.width * ss, self.height * ss):
            # every pass runs at the supersampled size; aovs() filters down to width x height
            cam = replace(cam, width=self.width * ss, height=self.height * ss)
            scene.camera = cam
        scene.validate()
        self.scene = scene
        self.gpu = DeviceScene(scene, self.device)
        self.raster = Rasterizer(self.gpu)
        self.gbuffer = GBuffer.allocate(cam.width, cam.height, self.device)
        # wavefront splatting lays its grids over the fitted cascades too (photons.wavefront: skip windows honoured)
        fitted = self.settings.method in FITTED_METHODS
        views = self.settings.light_views if fitted else LightViewSettings(fit="scene")
        self.lights = [LightMaps(self.gpu, light, self.settings.rsm_size, views) for light in scene.lights]
        for lm in self.lights:  # the RSM views' opaque triangle ids: read by the caustics map only
            lm.write_opaque_tri = self.settings.method == "caustics_map"
        self.direct = DirectLighting(self.gbuffer, self.device)
        n = cam.width * cam.height
        self.sky = None
        if scene.sky is not None:
            self.sky = SkyLighting(self.gpu, scene.sky, cam.width, cam.height, self.settings.sky_maps,
                                   self.settings.sky_map_size)
        self.sky_map = self.sky.map if self.sky is not None else sky_map(None, self.device)
        self.sky_irradiance = self.sky.irradiance if self.sky is not None else wp.zeros(n, dtype=wp.vec3, device=self.device)
        #: [W/m²], filled by a photon method; read through :attr:`caustic_irradiance` outside the frame
        self._caustic = wp.zeros(n, dtype=wp.vec3, device=self.device)
        #: the opaque surface's radiance [W/(m² sr)] (the sequential program's; the concurrent one computes it where
        #: it reads it, ``shade.composite_gather``)
        self.surface_radiance = wp.zeros(n, dtype=wp.vec3, device=self.device)
        self.final = wp.zeros(n, dtype=wp.vec3, device=self.device)
        #: the composite's rays that screen space cannot follow, traced on the opaque layer's BVH and shaded
        self.hidden = HiddenSurfaces(self.gpu, cam.width, cam.height, self.sky, self.device)
        self._hidden_bits = HIDDEN_RAYS[self.settings.hidden_rays]  #: composite's ``hidden_rays`` bits
        self.depth_bounds = wp.zeros(bounds_size(cam.width, cam.height), dtype=wp.vec2, device=self.device)
        #: the composite's bounds one level above their coarse cells (``march.super_bounds``, built every frame)
        self.super_bounds = wp.zeros(int(np.prod(super_shape(cam.width, cam.height))), dtype=wp.vec2,
                                     device=self.device)
        self.view = camera_view(cam)
        self.view_params = self.view.params()
        self.prev_view_params = self.view_params
        #: what changes per frame, as the kernels read it (this frame's and the last frame's camera, every view's
        #: random streams): one host->device copy per frame, shared by the photon pass and the fitter
        self.inputs = FrameInputs(self.lights, self.settings.photons.seed, self.device)
        lo, hi = scene.bounds()
        self.t_max = float(2.0 * np.linalg.norm(hi - lo)) + 1e-3  # longest screen-space ray [m]
        self.photons = None
        if self.settings.method != "none":
            cls = photon_pass_class(self.settings.method)
            self.photons = cls(self.gpu, self.gbuffer, self.view, self.lights, self.settings.photons, self.device, self.t_max)
            self.photons.inputs = self.inputs
            if hasattr(self.photons, "use_sky"):  # the reference's own final image: the methods' sky
                self.photons.use_sky(self.sky, self.sky_map)
            if self.photons.hidden is None and self.photons.final is None:
                # photons that keep no map of where they landed (caustics_map, the wavefront splat) would leave a
                # hidden hit without its caustic, darker than the screen-space fallback is bright (the sinusoid's
                # caustics_map FLIP 0.033 -> 0.049 at the small preset): those keep the fallback (perf_notes 31)
                self._hidden_bits = 0
        ps = self.settings.photons
        self.fitter = LightViewFitter(self.gpu, self.gbuffer, self.lights, ps.roughness_cutoff, ps.thickness,
                                      ps.thickness_rel, ps.max_bounces, self.t_max, ps.seed, inputs=self.inputs)
        self.denoiser = None
        if self.settings.denoiser == "caustic":
            caustic = self.settings.caustic
            # the caustic's own motion vectors, from where the photons of the same light-space cells landed the frame
            # before (photons/caustic_flow.py): cisp's point photons only; other methods and denoisers do not pay
            # for them, and their denoiser keeps no flow buffers
            flow = caustic.caustic_flow and self.settings.method == "cisp" and ps.splat == "point"
            if caustic.caustic_flow and not flow:
                caustic = replace(caustic, caustic_flow=False)
            self.denoiser = CausticDenoiser(cam.width, cam.height, self.device, caustic)
            if flow:
                self.photons.keep_caustic_flow(cam.width, cam.height)
        elif self.settings.denoiser == "svgf":
            self.denoiser = SVGF(cam.width, cam.height, self.device, self.settings.svgf)
        elif self.settings.denoiser == "gather":
            self.denoiser = GaussianGather(cam.width, cam.height, self.device)
        self.frame = 0
        #: replay one CUDA graph of the frame, frame after frame (``render_frame``); None: when it can
        #: (``graph_capable``). Set False to launch every kernel from Python each frame.
        self.use_graph: bool | None = None
        self._graph = None
        self._graph_key = None
        self._graph_deferred = None  #: the captured frame's ``SVGF.deferred`` (its output left packed), else None
        #: launch the next frame from Python, not captured: it loads the kernels compiled for a camera projection
        #: seen for the first time (``set_camera``) before a capture needs them, as frame 0 does for the first
        self._launch_next = False
        self.graph_captures = 0  #: frames captured as a graph so far (a new capture when the lights change)
        #: ``frame.FrameLanes`` while the frame runs its lights, and the sky and direct light, concurrently on CUDA
        #: streams (:meth:`set_concurrent`); None: every launch in turn on one stream (the sequential twin)
        self.lanes = None
        self._lane_rasters: list[Rasterizer] = []  #: per light lane: its own rasterizer scratch
        self._kept_lanes = None
        #: the concurrent program's composite, split round the photons (``shade.composite_march`` on the shade lane,
        #: ``shade.composite_gather`` after the denoiser): per pixel its rays' hit pixels, their throughputs, and the
        #: hidden rays' terms that need no radiance (``shade_hidden.trace_hidden_rays``); 28 B a pixel, made once
        self.composite_split = None
        self.set_concurrent(CONCURRENT and self.graph_capable)

    @property
    def caustic_irradiance(self) -> wp.array:
        """The frame's caustic irradiance [W/m²], H*W vec3 (the denoiser's output): where the frame's gather read
        SVGF's last level's output packed in place (:attr:`GATHER_PACKED`), it is unpacked here, once, the first time
        it is read after the frame (``SVGF.unpack``; a launch, not for use inside a frame)."""
        if isinstance(self.denoiser, SVGF):
            self.denoiser.unpack()
        return self._caustic

    def _gathers_packed(self) -> bool:
        """Whether the frame's tail leaves SVGF's output packed for its gather (:attr:`GATHER_PACKED`)."""
        return (self.GATHER_PACKED and self.photons is not None and self.photons.denoise
                and isinstance(self.denoiser, SVGF) and self.denoiser.defers)

    def set_concurrent(self, on: bool) -> None:
        """Run the frame's independent work concurrently (``on``; the CUDA default where ``graph_capable``): each
        light's pilots, fit, RSM views and shadow maps on a lane (a CUDA stream) of its own, each RSM view's photon
        order, trace and outcomes on another, the sky and the direct light on a third kind, forked from and joined to
        the frame's stream inside its graph (:meth:`_launch_lanes`). Each light lane gets its own rasterizer scratch,
        each view lane its own photon scratch bank, allocated here once. Off: every launch in turn (the sequential
        program of :meth:`_launch_frame`, the twin). On the CPU, on runs the concurrent program in the order it is
        written, without streams (a test does); the CPU default keeps the sequential one. A frame captured before is
        captured again."""
        if not on:
            self.lanes = None
            if self.photons is not None:
                self.photons.keep_lanes(None)
            return
        if self._kept_lanes is None:  # streams and events made once, kept when turned off
            self._kept_lanes = FrameLanes(self.device, [len(lm.rsm) for lm in self.lights])
        self.lanes = self._kept_lanes
        while len(self._lane_rasters) < len(self.lights):
            self._lane_rasters.append(Rasterizer(self.gpu))
        if self.composite_split is None:
            n = self.gbuffer.width * self.gbuffer.height
            self.composite_split = types.SimpleNamespace(
                hits=wp.zeros(n, dtype=wp.vec2i, device=self.device),
                weights=wp.zeros(n, dtype=wp.vec2, device=self.device),
                hidden_sum=wp.zeros(n, dtype=wp.vec3, device=self.device))
        if self.photons is not None:
            self.photons.keep_lanes(self.lanes)

    def lane_writes(self) -> dict[str, list[wp.array]]:
        """Per lane that runs beside others, the scratch arrays it writes that are not its own light's or view's maps:
        a light lane's rasterizer and fit scratch, a view lane's photon scratch bank (the structural rule a test
        checks: no array of one lane is an array of another). Without lanes, what the sequential frame hands each
        light and view (shared)."""
        fitted = {li: i for i, li in enumerate(self.fitter.light_index)}
        out = {}
        for li, lm in enumerate(self.lights):
            raster = self._lane_rasters[li] if self.lanes is not None else self.raster
            arrays = [raster.sub_v, raster.sub_bbox, raster.tile_count, raster.tile_end]
            if li in fitted:
                arrays += self.fitter.light_scratch(fitted[li])
            out[f"light {li}"] = arrays
            if self.photons is not None:
                for vi in range(len(lm.rsm)):
                    out[f"light {li} view {vi}"] = self.photons.lane_scratch(li, vi)
        return out

    def set_camera(self, camera: Camera) -> None:
        """Move the camera (same resolution); the previous pose is kept for motion vectors."""
        if (camera.width, camera.height) != (self.gbuffer.width, self.gbuffer.height):
            camera = replace(camera, width=self.gbuffer.width, height=self.gbuffer.height)
        self.scene.camera = camera
        old, self.view = self.view, camera_view(camera)
        self.view_params = self.view.params()
        v = self.view
        if self.photons is not None and (old.fx, old.fy, old.principal, old.orthographic) != (v.fx, v.fy, v.principal,
                                                                                              v.orthographic):
            self.photons.set_camera_view(v)  # a zoom: the pixels' solid angles; another projection: the trace's
        self._launch_next = self._launch_next or bool(old.orthographic) != bool(v.orthographic)

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

    @property
    def graph_capable(self) -> bool:
        """Whether a frame launches the same kernels with the same arguments every frame (all per-frame values in
        ``inputs``), so that one CUDA graph replays it: CUDA, and a method and denoiser without host state per
        frame (cisp, sspm with point splats, or none; the caustic or SVGF denoiser, or none)."""
        method_ok = self.settings.method == "none" or (
            self.settings.method in ("cisp", "sspm") and self.settings.photons.splat == "point")
        return self.device.is_cuda and method_ok and self.settings.denoiser in ("caustic", "svgf", "none")

    def _steady_key(self) -> tuple:
        """What a captured frame bakes in besides ``inputs``: the lights (a moved light re-fits its whole views on
        the host), whether their shadow maps are kept while still, whether the sky's maps are drawn, and the camera's
        projection (the trace is compiled for it)."""
        sky = None if self.sky is None else (self.sky.dynamic, self.sky._drawn)
        return tuple((id(lm.light), lm.cache_shadows) for lm in self.lights) + (sky, self.lanes is not None,
                                                                                bool(self.view.orthographic),
                                                                                self._gathers_packed())

    def render_frame(self, timer=None, graph: bool | None = None) -> None:
        """Raster, light, trace photons, denoise and composite one frame; everything stays on the device.

        ``timer``: a :class:`cisp_warp.timing.StageTimer` to time the stages (benchmarks only; launches every
        kernel). ``graph``: replay one captured CUDA graph of the frame (default ``use_graph``, else
        ``graph_capable``): the frame's cameras and random streams are written by one host->device copy, then the
        graph captured at the second frame (and again when the lights or the camera's projection change; the first
        frame with a new projection is launched from Python, loading its kernels) is launched; the CPU never uses one.
        """
        self.inputs.write(self.frame, self.view_params, self.prev_view_params)
        use = self.use_graph if graph is None else graph
        if use is None:
            use = True
        if not (use and timer is None and self.graph_capable and self.frame >= 1) or self._launch_next:
            self._launch_frame(timer)
            self._launch_next = False
        else:
            key = self._steady_key()
            if self._graph is None or key != self._graph_key:
                wp.capture_begin(device=self.device, force_module_load=False)
                try:
                    self._launch_frame(None)
                finally:
                    self._graph = wp.capture_end(device=self.device)
                self._graph_key = key
                self._graph_deferred = self.denoiser.deferred if isinstance(self.denoiser, SVGF) else None
                self.graph_captures += 1
            wp.capture_launch(self._graph)
            if self._graph_deferred is not None:  # each replay leaves SVGF's output packed again: unpacked on demand
                self.denoiser.deferred = self._graph_deferred
        self.prev_view_params = self.view_params
        self.frame += 1

    def _launch_frame(self, timer=None) -> None:
        """Every launch of one frame, reading the cameras and random streams from ``inputs`` (written already): with
        lanes (and no timer, and the fit on the device) the concurrent program, :meth:`_launch_lanes`; else every
        launch in turn, below."""
        if self.lanes is not None and timer is None and self.fitter.on_device:
            self._launch_lanes()
            return
        stage = timer.stage if timer is not None else (lambda name: nullcontext())
        g = self.gbuffer
        with stage("raster"):
            g.render(self.raster, self.inputs.cameras)
            self.fitter.fit(self.raster, self.view_params, self.frame)  # light views fitted to what the camera sees
            for lm in self.lights:
                lm.render(self.raster)
        with stage("direct"):
            self.direct.render(g, self.lights)
        if self.sky is not None:
            with stage("sky"):
                self.sky.render(self.raster, g, self.inputs.cameras)
        if self.photons is not None:
            with stage("trace+store"):
                self.photons.trace(g, self.view_params, self.frame)
        self._denoise_and_shade(stage)

    def _launch_lanes(self) -> None:
        """The concurrent program: the launches of :meth:`_launch_frame`, each light's on its lane, the sky and the
        direct light on the shade lane; every lane forked from the frame's stream (``main``) after the work it
        reads, and joined before the denoiser. The edges:

        * light i: its pilots (no camera) from the frame's start; its pilot trace, fit, RSM views and shadow maps
          after the G-buffer; its luminance maximum and outside booking after the photon pass zeroed its
          accumulators (``PhotonPass.light_lane``);
        * light i's view v: its photon order, trace and outcome pass after light i's lane (its views drawn) and the
          camera's depth bounds (``PhotonPass.view_lane``, entered by ``rsm_batches``);
        * shade: the sky after the G-buffer, the composite's depth bounds (where the photon pass keeps none of the
          same thickness: ``sspm``), the composite's marches and the hidden rays' trace (what they need of the G-buffer,
          :meth:`_march_composite`), SVGF's guides (``SVGF.guides``), the direct light after every light's shadow
          maps (marks);
        * main: G-buffer, the photon pass's zeroing, then (joined) denoise, the composite's gather (the surface
          radiance read where needed) with the hidden hits' direct light and caustic in the same launch
          (``HiddenSurfaces.gather``; apart, after it, with ``HiddenSurfaces.GATHERED`` False or more shadow maps or
          lights than it takes).

        Each light lane draws with its own rasterizer; the shade lane with main's, whose draws (the G-buffer) all
        come before the shade lane is forked."""
        lanes = self.lanes
        lanes.begin()
        try:
            self._issue_lanes(lanes)
        finally:
            lanes.active = False
        self._denoise_and_shade(lambda name: nullcontext(), marched=True)

    def _issue_lanes(self, lanes: FrameLanes) -> None:
        g, f = self.gbuffer, self.fitter
        fitted = {li: i for i, li in enumerate(f.light_index)}
        if fitted:
            f.frame_inputs(self.view_params, self.frame)
        for li, i in fitted.items():
            with lanes.branch(li):
                f.render_pilots(i, self._lane_rasters[li])
        g.render(self.raster, self.inputs.cameras)
        maps = []
        for li, lm in enumerate(self.lights):
            with lanes.branch(li):
                if li in fitted:
                    f.trace_light_pilots(fitted[li])
                    f.fit_light(fitted[li])
                lm.render(self._lane_rasters[li])
            maps.append(lanes.mark(li))
        if self.photons is not None:
            self.photons.trace(g, self.view_params, self.frame)  # its lights' launches on their lanes
        with lanes.branch(lanes.shade):
            if self.sky is not None:
                self.sky.render(self.raster, g, self.inputs.cameras)
            self._build_composite_bounds()  # from the G-buffer alone: beside the photons too
            self._march_composite()  # likewise (the hidden rays read the sky's maps, drawn just before)
            if self._svgf_guides_early():
                self.denoiser.guides(g.depth, g.normal, g.tri_id)  # SVGF's G-buffer part, likewise
            lanes.wait(maps)
            self.direct.render(g, self.lights)
        lanes.end()  # joined

    def _svgf_guides_early(self) -> bool:
        """Whether the concurrent program writes SVGF's guides on the shade lane (``SVGF.guides``)."""
        return self.photons is not None and self.photons.denoise and isinstance(self.denoiser, SVGF)

    def _traces_hidden(self) -> bool:
        """Whether the composite's missed rays go to ``shade_hidden`` (not for a method with its own final image)."""
        return self._hidden_bits != 0 and not (self.photons is not None and self.photons.final is not None)

    def _march_composite(self) -> None:
        """The composite's G-buffer half (``shade.composite_march``: its rays' hits, throughputs, the sky it sees, the
        ``missed`` bits) and the hidden rays' trace (``HiddenSurfaces.trace_rays``), into ``composite_split``, for
        ``_denoise_and_shade(marched=True)``'s gather; the depth bounds built already."""
        g, ps, cs = self.gbuffer, self.settings.photons, self.composite_split
        w = g.water
        wp.launch(composite_kernels(self.view.orthographic)[1], dim=g.width * g.height, device=self.device,
                  block_dim=shade.COMPOSITE_BLOCK_DIM,
                  inputs=[self.inputs.cameras, g.depth, self._composite_bounds(), self.super_bounds, w.depth,
                          w.position, w.normal,
                          w.ior, self.t_max, ps.max_steps, ps.thickness, self.sky_map, self.final, cs.hits,
                          cs.weights, self.hidden.missed, self._hidden_bits])
        if self._traces_hidden():
            self.hidden.trace_rays(g, self.inputs.cameras, self.sky_map, self.t_max, cs.hits, cs.hidden_sum,
                                   self.view.orthographic)

    def _build_composite_bounds(self) -> None:
        """Build ``depth_bounds`` from this frame's depth where the composite marches on them
        (:meth:`_composite_bounds`), then ``super_bounds`` from the composite's bounds (``march.super_bounds``)."""
        g = self.gbuffer
        if self._composite_bounds() is self.depth_bounds:
            ps = self.settings.photons
            build_bounds(g.depth, g.width, g.height, ps.thickness, COMPOSITE_THICKNESS_REL, self.depth_bounds,
                         self.device)
        wp.launch(march_super_bounds, dim=self.super_bounds.shape[0], device=self.device,
                  inputs=[self._composite_bounds(), g.width, g.height, self.super_bounds])

    def _denoise_and_shade(self, stage, marched: bool = False) -> None:
        """The frame's tail, on the frame's stream: denoise the photon map, surface radiance, composite, hidden rays
        (``marched``: the composite's marches, the hidden rays' trace and SVGF's guides ran already, on the shade
        lane: only their gather, ``shade.composite_gather``, and the hidden hits' shading are left, one launch where
        ``HiddenSurfaces.gather`` takes them)."""
        g = self.gbuffer
        packed = False  # SVGF's output left packed: the gather (surface_radiance) reads it in place, flips the parity
        if self.photons is not None:
            with stage("denoise"):
                if not self.photons.denoise:
                    wp.copy(self._caustic, self.photons.photon_map)
                elif isinstance(self.denoiser, CausticDenoiser):
                    self.denoiser.denoise(self.photons.photon_map, g.depth, g.normal, g.motion, g.tri_id,
                                          self._caustic, self.photons.photon_m2,
                                          None if self.photons.flow is None else self.photons.flow.flow)
                elif isinstance(self.denoiser, SVGF):
                    # the gather (the sequential program's surface_radiance) reads the last level's output packed
                    packed = self.denoiser.denoise(self.photons.photon_map, g.depth, g.normal, g.motion, g.tri_id,
                                                   self._caustic, guides_written=marched,
                                                   defer=self._gathers_packed())
                elif isinstance(self.denoiser, GaussianGather):
                    self.denoiser.apply(self.photons.photon_map, g.depth, g.normal, g.tri_id, self._caustic)
                else:
                    wp.copy(self._caustic, self.photons.photon_map)
        w = g.water
        with stage("shade"):
            n = g.width * g.height
            ps = self.settings.photons
            hidden_flux = getattr(self.photons, "hidden", None)
            hits_shaded = False  # the hidden hits' direct light and caustic added by the gather: HiddenSurfaces.gather
            caustic = self.denoiser.packed_color if packed else self._caustic
            parity = self.denoiser.parity if packed else None
            if marched:  # the surface radiance read where the gather needs it (surface_radiance is not written)
                cs = self.composite_split
                if self._traces_hidden():
                    hits_shaded = self.hidden.gather(g, self.direct.irradiance, caustic, self.sky_irradiance, cs,
                                                     self.lights, self.final, hidden_flux, parity)
                if not hits_shaded:
                    wp.launch(composite_gather, dim=n, device=self.device,
                              inputs=[g.depth, g.albedo, self.direct.irradiance, caustic,
                                      self.sky_irradiance, cs.hits, cs.weights, self.hidden.missed, cs.hidden_sum,
                                      int(self._traces_hidden()), self.final, int(packed),
                                      parity])
            else:
                wp.launch(surface_radiance, dim=n, device=self.device,
                          inputs=[g.depth, g.albedo, self.direct.irradiance, caustic, self.sky_irradiance,
                                  self.surface_radiance, int(packed), parity])
                bounds = self._composite_bounds()
                self._build_composite_bounds()
                wp.launch(composite_kernels(self.view.orthographic)[0], dim=n, device=self.device,
                          block_dim=shade.COMPOSITE_BLOCK_DIM,
                          inputs=[self.inputs.cameras, g.depth, bounds, self.super_bounds, self.surface_radiance,
                                  w.depth, w.position,
                                  w.normal, w.ior, self.t_max, ps.max_steps, ps.thickness, self.sky_map, self.final,
                                  self.hidden.missed, self._hidden_bits])
            if self.photons is not None and self.photons.final is not None:
                wp.copy(self.final, self.photons.final)  # a method with its own final image (the reference)
            elif self._hidden_bits != 0:
                if marched:
                    if not hits_shaded:
                        self.hidden.shade_hits(g, self.lights, self.final, hidden_flux)
                else:
                    self.hidden.render(g, self.lights, self.inputs.cameras, self.surface_radiance, self.sky_map,
                                       self.t_max, self.final, hidden_flux, self.view.orthographic)

    def _composite_bounds(self) -> wp.array:
        """The camera depth bounds the composite marches on: the photon pass's own (CISP builds them from this frame's
        depth with the same thicknesses when ``thickness_rel`` is the composite's), else ``depth_bounds``, built
        by the caller."""
        own = getattr(self.photons, "cam_bounds", None)
        if own is not None and float(self.settings.photons.thickness_rel) == COMPOSITE_THICKNESS_REL:
            return own
        return self.depth_bounds

    def aovs(self, include_rsm: bool = True) -> dict[str, np.ndarray]:
        """Host copies of the frame's AOVs, images of shape (height, width[, C]), float32 / int32.

        With ``supersample`` s > 1 the passes ran at s·width × s·height: radiometric AOVs (``final``,
        irradiances, ``albedo``) are the mean of each pixel's s × s samples; geometric ones (depth,
        position, normal, ids, the water layer) are the sample nearest the pixel centre; ``motion`` is
        in output pixels. The RSM AOVs keep their own size.
        """
        g = self.gbuffer
        shape = (g.height, g.width)
        gb = g.numpy()
        out = {k: gb[k] for k in ("depth", "position", "normal", "albedo", "roughness", "tri_id", "motion",
                                  "water_depth", "water_normal")}
        out["direct_irradiance"] = self.direct.irradiance.numpy().reshape(shape + (3,))
        if self.sky is not None:
            out["sky_irradiance"] = self.sky_irradiance.numpy().reshape(shape + (3,))
        out["final"] = self.final.numpy().reshape(shape + (3,))
        if self.photons is not None:
            out["photon_map"] = self.photons.photon_map.numpy().reshape(shape + (3,))
            out["caustics"] = self.caustic_irradiance.numpy().reshape(shape + (3,))
            out.update(self.photons.aovs(shape))
        ss = self.settings.supersample
        if ss > 1:
            out = {k: (box_filter(v, ss) if k in AVERAGED_AOVS else v[ss // 2 :: ss, ss // 2 :: ss])
                   for k, v in out.items()}
            out["motion"] = out["motion"] / np.float32(ss)
        if include_rsm:
            for lm in self.lights:
                for r in lm.rsm:
                    for k, v in r.numpy().items():
                        out[f"{r.view.name}_{k}"] = v
        return out

    def final_image(self) -> np.ndarray:
        """The frame's HDR image [W/(m² sr)], (height, width, 3) float32 on the host (filtered down)."""
        g = self.gbuffer
        return box_filter(self.final.numpy().reshape(g.height, g.width, 3), self.settings.supersample)


#: the CUDA default of ``Renderer.set_concurrent`` (for graph-capable settings): the frame's lights, and its sky and
#: direct light, on lanes of their own (docs/perf_notes.md section 45)
CONCURRENT = True

#: relative surface thickness of the composite's screen-space lookups (``shade.screen_space_lookup``)
COMPOSITE_THICKNESS_REL = 0.02

#: AOVs that are means over a pixel's samples when supersampling (the rest take the central sample)
AVERAGED_AOVS = frozenset({"final", "photon_map", "caustics", "direct_irradiance", "sky_irradiance", "albedo"})


def box_filter(image: np.ndarray, s: int) -> np.ndarray:
    """Mean of each s × s block of ``image`` (H, W[, C]) -> (H/s, W/s[, C]), same dtype."""
    if s == 1:
        return image
    h, w = image.shape[:2]
    return image.reshape(h // s, s, w // s, s, *image.shape[2:]).mean(axis=(1, 3)).astype(image.dtype)


class _CallableModule(types.ModuleType):
    """``cisp_warp.render`` is this module (``Renderer``, ``RenderSettings``) and, called, the one-call
    :func:`cisp_warp.api.render`: importing the module must not hide the package's ``render()``."""

    def __call__(self, *args, **kwargs):
        from .api import render

        return render(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule
