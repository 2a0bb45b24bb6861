"""Cascaded Image-Space Photon Tracing: photons from the RSMs, traced light view -> camera view."""

from __future__ import annotations

import warp as wp

from ..raster import GBuffer, LightMaps
from ..raster.views import View
from ..scene import DeviceScene
from . import kernels_cisp as K
from . import march as M
from .base import Ledger, PhotonPass, PhotonSettings, camera_pixel_solid_angle, frame_random

__all__ = ["CISP", "Ledger", "PhotonSettings", "camera_pixel_solid_angle", "frame_random"]


def build_bounds(depth: wp.array, width: int, height: int, thickness: float, thickness_rel: float, bounds: wp.array,
                 device, views: wp.array | None = None, view_index: int = 0) -> None:
    """Fill ``bounds`` (``march.bounds_size``) with the fine and coarse depth bounds of ``depth``. ``views``: the
    light views ``depth`` belongs to, ``views[view_index]`` (device array): when that view is inactive this frame
    (a fitted cascade with ``far`` = 0, launched on CUDA with fixed dims) the kernels return at once and the bounds
    keep their last values, which nothing marches; None: always build (the camera)."""
    fx, fy = M.bounds_shape(width, height, M.BOUNDS_CELL)
    cx, cy = M.bounds_shape(width, height, M.BOUNDS_COARSE)
    inputs = [views, int(view_index), depth, width, height, float(thickness), float(thickness_rel), bounds]
    # one thread walks a cell: measured faster on the H100 than a block per cell with tile min/max (Cornell box,
    # 3 builds: 0.135 ms against 0.080 for 4; docs/perf_notes.md section 8)
    wp.launch(M.depth_bounds, dim=fx * fy, device=device, inputs=inputs)
    wp.launch(M.coarsen_bounds, dim=cx * cy, device=device, inputs=[views, int(view_index), width, height, bounds])


class CISP(PhotonPass):
    """The photon pass of seed 000: allocates once, ``trace`` fills ``photon_map`` each frame."""

    name = "cisp"
    #: with ``FOLDED_OUTCOMES``: write each photon's outcome record as well (tests that read them; ``record_hits``
    #: writes them too)
    record_outcomes = False

    def __init__(self, scene: DeviceScene, gbuffer: GBuffer, camera_view: View, lights: list[LightMaps],
                 settings: PhotonSettings, device, t_max: float):
        super().__init__(scene, gbuffer, camera_view, lights, settings, device, t_max)
        self.camera_orthographic = int(bool(camera_view.orthographic))  #: the projection the trace is compiled for
        n_hits = self.max_photons_per_view() if settings.splat == "point" else 1  # the grid keeps its own records
        #: (N,) each photon's landing point [m] and camera pixel (-1: not stored) of the last view traced, written only
        #: while ``record_hits`` is set (tests, statistics): the frame loop does not pay 16 B a photon for them
        self.hits = wp.zeros(n_hits, dtype=wp.vec4, device=self.device)
        self.record_hits = False
        #: (N,) each photon's final entry and power, added to the ledger after the trace (K.trace_photons) by the outcome
        #: pass (``FOLDED_OUTCOMES`` False, the twin); with ``FOLDED_OUTCOMES`` the trace adds them itself and writes
        #: these records only while ``record_hits`` or ``record_outcomes`` is set (tests)
        self.outcome = wp.zeros(n_hits, dtype=wp.vec4, device=self.device)
        self.wavefront = None
        # the trace's flow inputs while no caustic flow is kept (flow_args): allocated here, not in a captured frame
        self._no_flow = [1, 1, 0, wp.zeros((2, 1), dtype=wp.vec4, device=self.device),
                         wp.zeros(1, dtype=wp.int32, device=self.device), wp.zeros(0, dtype=wp.vec2i, device=self.device), 0]
        if settings.splat == "point":
            self.keep_photon_m2(gbuffer.width * gbuffer.height)
            self.keep_hidden()
        if settings.splat == "wavefront":
            from .kernels_world import CameraBuffers
            from .wavefront import make_wavefront

            cam = CameraBuffers()
            cam.view = camera_view.params()
            # the depth with its back-face layer behind it (march.surface_far)
            cam.depth, cam.position, cam.normal = gbuffer.depth_layers, gbuffer.position, gbuffer.normal
            cam.solid_angle = self.solid_angle
            self.wavefront = make_wavefront(self, cam)
        # depth bounds per 8x8 cell of every light view's opaque depth and of the camera's, rebuilt each frame:
        # the march skips the steps they prove hitless
        self.cam_bounds = self._bounds_for(gbuffer.width, gbuffer.height)
        self.rsm_bounds = [[self._bounds_for(r.width, r.height) for r in lm.rsm] for lm in lights]
        # the resolves write the bounds (LightMaps / GBuffer.fused_resolve): each light's of its views, the G-buffer's
        # back-face resolve the camera's
        for lm, bounds in zip(lights, self.rsm_bounds):
            lm.keep_depth_bounds(bounds, settings.thickness, settings.thickness_rel)
        gbuffer.keep_depth_bounds(self.cam_bounds, settings.thickness, settings.thickness_rel)

    def keep_caustic_flow(self, width: int, height: int) -> None:
        if self.settings.splat != "point":
            super().keep_caustic_flow(width, height)
        if self.flow is None:
            from .caustic_flow import CausticFlow

            self.flow = CausticFlow(self.lights, self.settings.photons, self.max_photons_per_view(), width, height,
                                    self.device)

    def flow_args(self, b) -> list:
        """The trace kernel's last eight inputs for batch ``b``: its light's caustic-flow cells, or empty ones."""
        if self.flow is not None:
            return self.flow.trace_args(b.light_index, b.view_index)
        return [b.lights.views] + self._no_flow

    #: launch the trace compiled for each RSM view's projection and the camera's (``K.projected_trace``: only that
    #: projection's code in the marches, perf_notes section 51); False: the kernels that read it at run time (twin)
    PROJECTED = True

    def trace_kernel(self, light_orthographic: bool | None = None):
        """The trace kernel for this pass: with the caustic flow's code only while a flow is kept
        (``K.trace_photons_flow``), else ``K.trace_photons``, compiled without it (perf_notes section 39); given the
        RSM view's projection (``light_orthographic``) and with ``PROJECTED``, that kernel compiled for it and the
        camera's (``K.projected_trace``; the camera's as :meth:`set_camera_view` last saw it: ``Renderer``'s captured
        frame is captured again when it changes)."""
        flow = self.flow is not None
        if light_orthographic is None or not self.PROJECTED:
            return K.trace_photons_flow if flow else K.trace_photons
        return K.projected_trace(flow, int(bool(light_orthographic)), self.camera_orthographic)

    def set_camera_view(self, camera_view) -> None:
        super().set_camera_view(camera_view)
        self.camera_orthographic = int(bool(camera_view.orthographic))

    def _bounds_for(self, width: int, height: int) -> wp.array:
        return wp.zeros(M.bounds_size(width, height), dtype=wp.vec2, device=self.device)

    def _build_bounds(self, depth: wp.array, width: int, height: int, bounds: wp.array, views: wp.array | None = None,
                      view_index: int = 0) -> None:
        build_bounds(depth, width, height, self.settings.thickness, self.settings.thickness_rel, bounds, self.device,
                     views, view_index)

    def build_rsm_bounds(self, lights: LightMaps, light_index: int, view_index: int) -> wp.array:
        """The depth bounds of RSM view ``view_index`` of light ``light_index`` (``lights``) for this frame: written by
        the light's resolve already (``LightMaps.keep_depth_bounds``), else built here from its opaque depth."""
        bounds = self.rsm_bounds[light_index][view_index]
        if not lights.builds_depth_bounds(bounds):
            r = lights.rsm[view_index]
            self._build_bounds(r.opaque_depth, r.width, r.height, bounds, lights.views, view_index)
        return bounds

    def trace(self, gbuffer: GBuffer, camera: wp.struct, frame: int) -> None:
        """Trace every light's photons for ``frame`` into ``photon_map`` (zeroed first) and the ledger."""
        s = self.settings
        self.frame_inputs(camera, frame)
        self.begin()
        if self.flow is not None:
            self.flow.begin()
        # from the depth with its back-face layer, which the camera marches read (march.depth_bounds widens a cell by
        # the layer's far sides): bounds of the front depth alone let 1.2% of the Cornell box's camera marches skip a
        # cell where the naive march ends in an object's hidden half (branch hiermarch, perf_notes section 30)
        if not gbuffer.builds_depth_bounds(self.cam_bounds):
            self._build_bounds(gbuffer.depth_layers, gbuffer.width, gbuffer.height, self.cam_bounds)
        if self.wavefront is not None:
            self.wavefront.cam.view = camera
            self.wavefront.trace(frame, "cisp")
            return
        fold = int(self.FOLDED_OUTCOMES)
        for b in self.rsm_batches(frame):
            r, sc = b.rsm, b.lights.scene
            sp = r.specular
            rsm_bounds = self.build_rsm_bounds(b.lights, b.light_index, b.view_index)
            self.launch_photons(self.trace_kernel(r.view.orthographic), b.slots, inputs=[
                b.lights.views, b.lights.states, b.view_index, int(b.lights.light.kind), b.light_pos,
                r.opaque_depth, rsm_bounds, sp.depth, b.lights.emission(r), sp.tri_id,
                sc.geometry, sc.triangle_material, sc.opacity, sc.albedo, self._max_lum_of[b.light_index],
                self.inputs.cameras, gbuffer.depth_layers, self.cam_bounds, gbuffer.position, gbuffer.normal, self.solid_angle,
                b.light_photons, b.slots, self.inputs.randoms, b.stream, b.order, self.use_order,
                float(s.roughness_cutoff), b.luminance_cutoff, int(s.max_steps),
                float(s.thickness), float(s.thickness_rel), self.t_max, self.footprint_mode, int(s.cascade),
                self.photon_map, self.photon_m2, self.ledger_rows, self.hits if self.record_hits else None,
                self.outcome if not fold or self.record_hits or self.record_outcomes else None, fold,
                *self.hidden_args(b), *self.flow_args(b)])
            if not fold:
                self.add_outcomes(self.outcome, b, 1, K.CISP_FINAL_ENTRIES)
        if self.flow is not None:
            self.join_lights()  # the flow's cells hold every light's landings
            self.flow.finish()
