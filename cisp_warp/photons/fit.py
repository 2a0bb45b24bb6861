"""Light views fitted to the camera (DESIGN, CISP step 0): cascaded shadow maps for photons.

Per frame, after the camera's G-buffer and before the lights' RSM views are drawn:

1. every light's pilot views (its whole views, ``pilot_size``²) are drawn;
2. :func:`pilot_receivers` sends one photon per pilot texel and branch (reflected; refracted where the
   surface transmits) from the surface under the texel's centre, traces it through the scene's BVH
   (further specular bounces by Fresnel probability) and keeps the camera depth [m] where it lands on
   a surface the camera sees (the depth-visibility test of the photon stores), 0 where neither lands;
3. the host reads those depths back (the one device->host copy of the frame, ``pilot_size``² floats
   per whole view: a view's pose and scale are launch arguments, so the host must know them), turns each
   whole view about its axis to fit them tightest (``views.fit_angle``) and fits nested windows to them
   (``views.fit_windows``): one near the camera, coarser ones further out;
4. ``LightMaps.set_windows`` moves the cascades; their RSMs are then drawn at full size.

Photons are then emitted from the cascades (``PhotonPass.rsm_batches``): each active cascade gets an
equal share of the light's photons, a cascade leaves the samples inside the next finer window to it,
and the power on the pilot texels outside the coarsest window is booked as ``outside_fitted_view``
(``common.book_outside_window``), so the ledger still closes to the light's whole specular power.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..optics import reflect, refract
from ..raster import GBuffer, LightMaps, Rasterizer
from ..raster.views import ViewParams, fit_angle, fit_windows, pixel_ray_world
from ..scene import DeviceScene
from ..scene.device import SurfaceGeometry
from .common import surface_at_sample, tally_new
from .kernels_world import WT_LANDED, CameraBuffers, WorldScene, camera_pixel, world_trace
from .world import world_scene

wp.set_module_options({"enable_backward": False})  # forward only (world_trace books into a tally by reference)


@wp.kernel
def pilot_receivers(
    light: ViewParams,  # a pilot (whole) view of the light
    light_kind: int,  # 0 distant, 1 point, 2 spot
    light_pos: wp.vec3,  # [m]
    rsm_position: wp.array(dtype=wp.vec3),  # (P*P,) specular layer [m] (read)
    rsm_normal: wp.array(dtype=wp.vec3),  # (P*P,) authored unit normal (read)
    rsm_flux: wp.array(dtype=wp.vec3),  # (P*P,) [W] (read)
    rsm_roughness: wp.array(dtype=wp.float32),  # (P*P,) (read)
    rsm_ior: wp.array(dtype=wp.float32),  # (P*P,) (read)
    rsm_tri: wp.array(dtype=wp.int32),  # (P*P,) -1 = none (read)
    geometry: SurfaceGeometry,
    ws: WorldScene,
    cam: CameraBuffers,
    roughness_cutoff: float,
    thickness: float,  # [m] depth-visibility tolerance, absolute
    thickness_rel: float,  # relative (× depth)
    t_max: float,  # [m]
    max_bounces: int,
    seed: int,
    receiver_depth: wp.array(dtype=wp.float32),  # (P*P,) nearest camera depth [m] a texel's light is seen at, 0 = none (write)
):
    p = wp.tid()
    receiver_depth[p] = 0.0
    tri = rsm_tri[p]
    if tri < 0 or rsm_roughness[p] > roughness_cutoff or wp.length(rsm_flux[p]) <= 0.0:
        return
    lo, ld = pixel_ray_world(light, float(p % light.width) + 0.5, float(p / light.width) + 0.5)
    x, n = surface_at_sample(lo, ld, tri, rsm_position[p], rsm_normal[p], geometry)
    d_in = wp.normalize(ld)
    if light_kind != 0:
        d_in = wp.normalize(x - light_pos)
    nn = n
    eta = rsm_ior[p]
    if wp.dot(d_in, n) > 0.0:
        nn = -n
        eta = 1.0 / eta
    transmissive = int(ws.opacity[ws.triangle_material[tri]] < 1.0)
    nearest = float(0.0)
    tally = tally_new()  # the pilot's bookings: discarded
    for branch in range(2):
        d = reflect(d_in, nn)
        if branch == 1:
            if transmissive == 0:
                continue
            d = refract(d_in, nn, eta)
            if wp.length(d) == 0.0:  # total internal reflection
                continue
        state = wp.rand_init(seed, 2 * p + branch)
        status, y, nr, d_end, power, state = world_trace(ws, x, n, d, wp.vec3(1.0), state, roughness_cutoff, t_max,
                                                         max_bounces, tally)
        if status != WT_LANDED:
            continue
        pix, q = camera_pixel(cam, y)
        if pix < 0:
            continue
        zc = cam.depth[pix]
        if zc <= 0.0 or wp.abs(q[2] - zc) > thickness + thickness_rel * zc or wp.dot(-d_end, cam.normal[pix]) < 0.0:
            continue
        if nearest == 0.0 or q[2] < nearest:
            nearest = q[2]
    receiver_depth[p] = nearest


class LightViewFitter:
    """Fits every light's cascades to the camera each frame; its pilot buffers are allocated once."""

    def __init__(self, scene: DeviceScene, gbuffer: GBuffer, lights: list[LightMaps], roughness_cutoff: float,
                 thickness: float, thickness_rel: float, max_bounces: int, t_max: float, seed: int = 0):
        self.scene = scene
        self.lights = [lm for lm in lights if lm.fitted]
        self.device = scene.device
        self.world = world_scene(scene) if self.lights else None
        self.cam = CameraBuffers()
        self.cam.depth, self.cam.position, self.cam.normal = gbuffer.depth, gbuffer.position, gbuffer.normal
        self.cam.solid_angle = wp.zeros(1, dtype=wp.float32, device=self.device)  # not read by the pilot
        self.receiver_depth = [[wp.zeros(r.width * r.height, dtype=wp.float32, device=self.device) for r in lm.pilot]
                               for lm in self.lights]
        self.roughness_cutoff, self.thickness, self.thickness_rel = roughness_cutoff, thickness, thickness_rel
        self.max_bounces, self.t_max, self.seed = max_bounces, t_max, seed
        self.last_depth: list[list[np.ndarray]] = []  #: the pilots' receiver depths of the last fit (host)

    def fit(self, raster: Rasterizer, camera: wp.struct, frame: int) -> None:
        """Draw the pilots, trace them, read their receiver depths back and fit every light's cascades."""
        if not self.lights:
            return
        self.cam.view = camera
        for lm in self.lights:
            lm.render_pilot(raster)
        for lm, depths in zip(self.lights, self.receiver_depth):
            light_pos = wp.vec3(*np.asarray(lm.light.position, np.float32))
            for vi, (r, depth) in enumerate(zip(lm.pilot, depths)):
                sp = r.specular
                wp.launch(pilot_receivers, dim=r.width * r.height, device=self.device, inputs=[
                    r.view.params(), int(lm.light.kind), light_pos, sp.position, sp.normal, r.flux, sp.roughness,
                    sp.ior, sp.tri_id, self.scene.geometry, self.world, self.cam, float(self.roughness_cutoff),
                    float(self.thickness), float(self.thickness_rel), float(self.t_max), int(self.max_bounces),
                    int(self.seed * 7919 + frame * 131 + vi), depth])
        self.last_depth = []
        for lm, depths in zip(self.lights, self.receiver_depth):
            vs = lm.view_settings
            host = [d.numpy().reshape(r.height, r.width) for d, r in zip(depths, lm.pilot)]  # the frame's one sync
            self.last_depth.append(host)
            aspects = [r.view.fx / r.view.fy for r in lm.pilot]
            angles = [fit_angle(h, k) for h, k in zip(host, aspects)]
            lm.set_windows([fit_windows(h, vs.cascades, vs.margin, a, k) for h, a, k in zip(host, angles, aspects)],
                           angles)
