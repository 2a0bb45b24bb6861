"""Steps per photon of the CISP march (light view, then camera view), CPU, at the benchmark's sizes."""
import sys, numpy as np, warp as wp
wp.config.log_level = wp.LOG_WARNING
wp.init()
from cisp_warp.photons import PhotonSettings
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.usd import load_usd
from cisp_warp.photons import common as C
from cisp_warp.photons.march import screen_march, MARCH_HIT
from cisp_warp.raster.views import ViewParams, world_project
wp.set_module_options({"enable_backward": False})

@wp.kernel
def steps_kernel(light: ViewParams, light_kind: int, light_pos: wp.vec3, rsm_opaque_depth: wp.array(dtype=float),
                 rsm_position: wp.array(dtype=wp.vec3), rsm_normal: wp.array(dtype=wp.vec3), rsm_flux: wp.array(dtype=wp.vec3),
                 rsm_roughness: wp.array(dtype=float), rsm_ior: wp.array(dtype=float), rsm_tri: wp.array(dtype=int),
                 triangle_material: wp.array(dtype=int), mat_opacity: wp.array(dtype=float), mat_albedo: wp.array(dtype=wp.vec3),
                 max_lum: wp.array(dtype=float), camera: ViewParams, cam_depth: wp.array(dtype=float),
                 n_photons: int, seed: int, scramble: wp.vec2i, t_max: float, stride: int,
                 out: wp.array(dtype=wp.vec4i)):
    i = wp.tid()
    k = i * stride
    tally = C.tally_new()
    texel, power, origin, n, d, state = C.emit_and_bounce(light, light_kind, light_pos, k, n_photons, scramble, seed,
        rsm_position, rsm_normal, rsm_flux, rsm_roughness, rsm_ior, rsm_tri, triangle_material, mat_opacity, mat_albedo,
        max_lum[0], 0.3, 0.01, tally)
    out[i] = wp.vec4i(-1, 0, 0, 0)
    if texel < 0:
        return
    o = origin + d * (1.0e-4 * t_max)
    status, t_end, steps = screen_march(light, rsm_opaque_depth, o, d, t_max, 2048, 0.02, 0.02)
    s2 = int(0)
    status2 = int(-1)
    if status != 2:
        x_end = o + d * t_end
        q = world_project(camera, x_end)
        inside = q[2] > camera.near and q[0] >= 0.0 and q[1] >= 0.0 and q[0] < float(camera.width) and q[1] < float(camera.height)
        if inside:
            pix = int(q[1]) * camera.width + int(q[0])
            zc = cam_depth[pix]
            tol = 0.02 + 0.02 * zc
            if not (zc > 0.0 and q[2] > zc + tol) and not (zc > 0.0 and q[2] >= zc - tol):
                status2, t2, s2 = screen_march(camera, cam_depth, x_end, d, t_max, 2048, 0.02, 0.02)
    out[i] = wp.vec4i(status, steps, status2, s2)

for name in sys.argv[1:]:
    scene = load_usd(f"scenes_usd/{name}.usda", width=1920, height=1080, device="cpu")
    r = Renderer(scene, RenderSettings(rsm_size=2048, method="cisp", denoiser="none", photons=PhotonSettings(photons=2_000_000)), device="cpu")
    p = r.photons
    g = r.gbuffer
    for lm in r.lights:
        lm.render(r.raster)
    g.render(r.raster, r.view_params, r.view_params)
    p.begin()
    for b in p.rsm_batches(0):
        rr, sc = b.rsm, b.lights.scene
        sp = rr.specular
        m = 20000
        out = wp.zeros(m, dtype=wp.vec4i, device="cpu")
        wp.launch(steps_kernel, dim=m, device="cpu", inputs=[b.params, int(b.lights.light.kind), b.light_pos, rr.opaque_depth,
                  sp.position, sp.normal, rr.flux, sp.roughness, sp.ior, sp.tri_id, sc.triangle_material, sc.opacity, sc.albedo,
                  p._max_lum_of[b.light_index], r.view_params, g.depth, b.n, b.seed, b.scramble, p.t_max, b.n // m, out])
        o = out.numpy()
        em = o[:, 0] >= 0
        s1 = o[em, 1]; s2 = o[em, 3]
        tot = s1 + s2
        print(f"{name} light {b.light_index} view {b.view_index}: emitted {em.mean():.2f}; light-view steps mean {s1.mean():.1f} "
              f"p50 {np.median(s1):.0f} p90 {np.percentile(s1,90):.0f} p99 {np.percentile(s1,99):.0f} max {s1.max()}; "
              f"status hit/exit/steps {[(o[em,0]==s).mean().round(3) for s in range(3)]}; camera march share {(o[em,2]>=0).mean():.3f} "
              f"steps mean {s2.mean():.1f} p99 {np.percentile(s2,99):.0f}; total mean {tot.mean():.1f}")
        # warp-level: mean over groups of 32 consecutive (texel-ordered would be better) of max steps
        print(f"   sum of steps / photons {tot.sum()/em.size:.1f}")
