"""Caustics Mapping (seed 004, Wyman & Davis 2006; Shah et al. 2007): photons found and gathered in light space.

The baseline CISP improves on. Emission and bounce are CISP's (:mod:`.common`), so the two compare photon
for photon; what differs is everything after the bounce:

* **End points in light space only.** The photon marches the light view's opaque depth and nothing else:
  a photon leaving the light view is lost (``lost_light_view``), so a caustic on a surface the light does
  not see — a reflection onto a wall outside a spot's cone — cannot appear. That is the method's stated
  limit (DESIGN.md, "Baselines"), and a test measures it.
* **Splat into a caustic map** of the RSM view's resolution: each end point's power goes to the light
  texel it lands in, and the map holds irradiance E = P / A, A the area of the receiver the texel covers
  (``kernels_cmap.receiver_footprints``: A = Ω_t·r²/|cos θ| for a perspective view,
  (1/(fx·fy))/|cos θ| for an orthographic one). SI units throughout, no scale factors.
* **Temporal filter** (seed 004, 3.2.3): the mean of the last ``cmap_history`` frames' maps, from a
  ring allocated once (the first frames average over the slots filled so far).
* **Gather**, ``cmap_gather``:

  - ``"light"``: seed 004's Gaussian in the caustic map (7x7, σ = 1.5 texels, same-surface neighbours:
    :class:`~cisp_warp.denoise.GaussianGather` run on the light view), then projected onto the camera like
    a shadow map. The map is already filtered, so the pass sets ``denoise = False`` and the renderer
    shows it without its own denoiser.
  - ``"eye"``: the unfiltered (temporally averaged) map is projected the same way and the eye-space
    filtering is the renderer's denoiser: ``--denoiser gather`` is seed 004's 7x7 eye-space Gaussian.

* **Projection** (``kernels_cmap.project_caustic_map``): each opaque G-buffer point is looked up in the
  light view like a shadow map, and takes the map's irradiance (bilinear over the taps whose light depth
  is that same surface) only where the light sees it.

Ledger: ``stored`` means splatted into a caustic map at a light texel whose opaque surface the photon
reached on its lit side; it is light-space energy: Σ E·A over a view's single-frame map equals it. Whether
the camera sees that receiver is decided per camera pixel at projection, not per photon, so
``lost_camera_view`` and ``occluded`` stay zero for this method. The ledger is this frame's photons; the
photon map is the temporal mean, so with ``cmap_history`` > 1 its energy is the mean of the last frames'.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from ..denoise.gather import GaussianGather
from ..raster import GBuffer, LightMaps, RSMView
from ..raster.views import View
from ..scene import DeviceScene
from ..scene.device import check_memory
from . import kernels_cmap as K
from .base import PhotonPass, PhotonSettings

#: seed 004, 3.2.2: a 7x7 neighbourhood, Gaussian weights; σ = radius / 2 so the window spans ±2σ
GATHER_RADIUS = 3
GATHER_SIGMA = 1.5


@dataclass
class CausticMapBuffers:
    """The caustic map of one RSM view (Hl x Wl texels, flat row-major arrays), allocated once."""

    texel_power: wp.array  #: (Hl*Wl,) vec3 [W]: power of this frame's photons per texel (scratch, zeroed per frame)
    receiver_normal: wp.array  #: (Hl*Wl,) vec3 unit geometric normal of the texel's opaque surface, facing the light
    receiver_area: wp.array  #: (Hl*Wl,) float32 [m²]: area of that surface the texel covers; 0 = none
    history: wp.array  #: (cmap_history, Hl*Wl) vec3 [W/m²]: ring of the last frames' unfiltered irradiance
    irradiance: wp.array  #: (Hl*Wl,) vec3 [W/m²]: the ring's mean (seed 004's temporal filter)
    filtered: wp.array | None  #: (Hl*Wl,) vec3 [W/m²]: Gaussian-gathered in light space ("light" gather only)
    gather: GaussianGather | None  #: the light-space gather ("light" gather only)

    @staticmethod
    def allocate(r: RSMView, history_length: int, light_gather: bool, device) -> "CausticMapBuffers":
        n = r.width * r.height
        check_memory(n * (12 * (history_length + 4) + 4), f"a {r.width}x{r.height} caustic map with "
                     f"{history_length} frames of history", device)
        gather = GaussianGather(r.width, r.height, device, radius=GATHER_RADIUS, sigma=GATHER_SIGMA)
        return CausticMapBuffers(
            wp.zeros(n, dtype=wp.vec3, device=device), wp.zeros(n, dtype=wp.vec3, device=device),
            wp.zeros(n, dtype=wp.float32, device=device), wp.zeros((history_length, n), dtype=wp.vec3, device=device),
            wp.zeros(n, dtype=wp.vec3, device=device),
            wp.zeros(n, dtype=wp.vec3, device=device) if light_gather else None,
            gather if light_gather else None)

    @property
    def projected(self) -> wp.array:
        """The map the camera looks up: filtered in light space, or the unfiltered mean (eye gather)."""
        return self.filtered if self.filtered is not None else self.irradiance


class CausticsMap(PhotonPass):
    """Caustics mapping: allocates every caustic map once; ``trace`` fills ``photon_map`` each frame."""

    name = "caustics_map"

    def __init__(self, scene: DeviceScene, gbuffer: GBuffer, camera_view: View, lights: list[LightMaps],
                 settings: PhotonSettings, device, t_max: float):
        super().__init__(scene, gbuffer, camera_view, lights, settings, device, t_max)
        light_gather = settings.cmap_gather == "light"
        self.denoise = not light_gather  # "light": filtered here already; "eye": the renderer's denoiser filters
        self.history_length = int(settings.cmap_history)
        self.maps = [[CausticMapBuffers.allocate(r, self.history_length, light_gather, self.device) for r in lm.rsm]
                     for lm in lights]
        self.frames_traced = 0  #: frames since construction or :meth:`reset_history`; picks the ring slot

    def reset_history(self) -> None:
        """Forget the temporal filter's past frames (a camera cut, a new scene state)."""
        self.frames_traced = 0

    def trace(self, gbuffer: GBuffer, camera: wp.struct, frame: int) -> None:
        """Trace every light's photons for ``frame`` into the caustic maps, filter them, and project them into
        ``photon_map`` (zeroed first); the ledger books this frame's photons. Launches only, no host copies."""
        s = self.settings
        self.begin()
        slot = self.frames_traced % self.history_length
        frames = min(self.frames_traced + 1, self.history_length)
        n_pixels = gbuffer.width * gbuffer.height
        for b in self.rsm_batches(frame):  # CISP's streams: the same photons
            params, r, sc, light, light_pos, n = b.params, b.rsm, b.lights.scene, b.lights.light, b.light_pos, b.n
            cm = self.maps[b.light_index][b.view_index]
            n_texels = r.width * r.height
            sp = r.specular
            wp.launch(K.receiver_footprints, dim=n_texels, device=self.device,
                      inputs=[params, r.opaque_depth, r.opaque_tri, r.solid_angle, sc.points, sc.indices,
                              cm.receiver_normal, cm.receiver_area])
            cm.texel_power.zero_()
            self.launch_photons(K.trace_to_caustic_map, n, inputs=[
                params, int(light.kind), light_pos,
                r.opaque_depth, r.opaque_tri, sp.depth, b.lights.emission(r), sp.tri_id,
                sc.geometry, b.skip_window, cm.receiver_normal, sc.triangle_material, sc.opacity, sc.albedo,
                self._max_lum_of[b.light_index],
                n, b.seed, b.scramble, b.order, self.use_order,
                float(s.roughness_cutoff), b.luminance_cutoff,
                int(s.max_steps), float(s.thickness), float(s.thickness_rel), self.t_max,
                cm.texel_power, self.ledger_rows])
            wp.launch(K.temporal_filter, dim=n_texels, device=self.device,
                      inputs=[cm.texel_power, cm.receiver_area, slot, frames, cm.history, cm.irradiance])
            if cm.gather is not None:
                cm.gather.apply(cm.irradiance, r.opaque_depth, cm.receiver_normal, r.opaque_tri, cm.filtered)
            wp.launch(K.project_caustic_map, dim=n_pixels, device=self.device,
                      inputs=[params, r.opaque_depth, cm.projected, gbuffer.depth, gbuffer.position, gbuffer.normal,
                              float(s.thickness), float(s.thickness_rel), self.photon_map])
        self.frames_traced += 1

    def aovs(self, shape: tuple[int, int]) -> dict[str, np.ndarray]:
        """The light-space caustic maps that were projected, (Hl, Wl, 3) irradiance [W/m²] per RSM view."""
        out = {}
        for lm, maps in zip(self.lights, self.maps):
            for r, cm in zip(lm.rsm, maps):
                out[f"cmap_{r.view.name}"] = cm.projected.numpy().reshape(r.height, r.width, 3)
        return out
