"""Cascaded Image-Space Photon Tracing: photons from the RSMs, traced light view -> camera view."""

from __future__ import annotations

import warp as wp

from ..raster import GBuffer, LightMaps
from ..raster.views import View
from ..scene import DeviceScene
from . import kernels_cisp as K
from .base import Ledger, PhotonPass, PhotonSettings, camera_pixel_solid_angle, frame_random

__all__ = ["CISP", "Ledger", "PhotonSettings", "camera_pixel_solid_angle", "frame_random"]


class CISP(PhotonPass):
    """The photon pass of seed 000: allocates once, ``trace`` fills ``photon_map`` each frame."""

    name = "cisp"

    def __init__(self, scene: DeviceScene, gbuffer: GBuffer, camera_view: View, lights: list[LightMaps],
                 settings: PhotonSettings, device, t_max: float):
        super().__init__(scene, gbuffer, camera_view, lights, settings, device, t_max)
        self.hits = wp.zeros(self.max_photons_per_view(), dtype=wp.vec4, device=self.device)

    def trace(self, gbuffer: GBuffer, camera: wp.struct, frame: int) -> None:
        """Trace every light's photons for ``frame`` into ``photon_map`` (zeroed first) and the ledger."""
        s = self.settings
        self.begin()
        for b in self.rsm_batches(frame):
            r, sc = b.rsm, b.lights.scene
            sp = r.specular
            self.launch_photons(K.trace_photons, b.n, inputs=[
                b.params, int(b.lights.light.kind), b.light_pos,
                r.opaque_depth, sp.position, sp.normal, r.flux, sp.roughness, sp.ior, sp.tri_id,
                sc.triangle_material, sc.opacity, sc.albedo, self._max_lum_of[b.light_index],
                camera, gbuffer.depth, gbuffer.position, gbuffer.normal, self.solid_angle,
                b.n, b.seed, b.scramble, b.order, self.use_order,
                float(s.roughness_cutoff), float(s.luminance_cutoff), int(s.max_steps),
                float(s.thickness), float(s.thickness_rel), self.t_max, self.footprint_mode, int(s.cascade),
                self.photon_map, self.ledger, self.hits])
