"""GPU experiment: trace-kernel variants (ledger, launch bounds, march) on the Cornell box and the pool, 2M photons."""
import os, sys, time, json
import numpy as np
import warp as wp
wp.config.log_level = wp.LOG_WARNING
wp.init()
from cisp_warp.photons import PhotonSettings
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.usd import load_usd
import cisp_warp.photons.kernels_cisp as KC
import cisp_warp.photons.kernels_world as KW
import cisp_warp.photons.common as C
import cisp_warp.photons.march as M

ROOT = os.getcwd()
dev = wp.get_device("cuda:0")
OUT = os.environ.get("OUT", "/tmp")

@wp.func
def ledger_noop(ledger: wp.array(dtype=wp.vec3d), tally: C.Tally, lane: int, entries: int):
    return

def kernel_ms(r, frames, key):
    g = r.gbuffer
    wp.timing_begin(cuda_filter=wp.TIMING_KERNEL)
    for f in range(frames):
        r.photons.trace(g, r.view_params, 100 + f)
    res = wp.timing_end()
    return sum(x.elapsed for x in res if key in x.name) / frames

def make(mod, name, patch=None, **opts):
    saved = {}
    for k, v in (patch or {}).items():
        saved[k] = getattr(mod, k)
        setattr(mod, k, v)
    k = wp.kernel(getattr(mod, name).func, module="unique", enable_backward=False, **opts)
    return k, saved

results = {}
for scene_name in ("cornell_flooded", "pool"):
    scene = load_usd(f"{ROOT}/scenes_usd/{scene_name}.usda", width=1920, height=1080, device=dev)
    for method, mod, kname in (("cisp", KC, "trace_photons"), ("sspm", KW, "trace_sspm")):
        r = Renderer(scene, RenderSettings(rsm_size=2048, method=method, photons=PhotonSettings(photons=2_000_000)), device=dev)
        for _ in range(3):
            r.render_frame()
        orig = getattr(mod, kname)
        variants = [("current", {}, {})]
        variants.append(("ledger_off", {"ledger_add": ledger_noop}, {}))
        if method == "cisp":
            variants += [("lb128x5", {}, {"launch_bounds": (128, 5)}), ("lb128x6", {}, {"launch_bounds": (128, 6)})]
        for vname, patch, opts in variants:
            if vname == "current":
                k, saved = orig, {}
            else:
                k, saved = make(mod, kname, patch, **opts)
            setattr(mod, kname, k)
            try:
                r.photons.trace(r.gbuffer, r.view_params, 99)  # build + warm
                wp.synchronize()
            finally:
                for a, v in saved.items():
                    setattr(mod, a, v)
            ms = kernel_ms(r, 10, kname)
            led = r.photons.read_ledger()
            pm = r.photons.photon_map.numpy()
            results[f"{scene_name}/{method}/{vname}"] = dict(ms=ms, stored=float(led["stored"].sum()),
                                                            sampled=float(led["sampled"].sum()), closure=led.closure(),
                                                            map_sum=float(pm.sum()))
            print(f"{scene_name:16s} {method:5s} {vname:24s} {ms:8.3f} ms  stored {led['stored'].sum():.6g} "
                  f"closure {led.closure():.1e} map {pm.sum():.6g}", flush=True)
            setattr(mod, kname, orig)
        for bd in (64, 256):
            r.photons.ledger_block = bd
            r.photons.trace(r.gbuffer, r.view_params, 99)
            ms = kernel_ms(r, 10, kname)
            print(f"{scene_name:16s} {method:5s} {'block' + str(bd):24s} {ms:8.3f} ms", flush=True)
            r.photons.ledger_block = C.LEDGER_BLOCK
json.dump(results, open(f"{OUT}/exp1.json", "w"), indent=1)
