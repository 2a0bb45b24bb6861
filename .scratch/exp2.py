"""Can a steady frame be captured as a CUDA graph? Frame ms: plain launches vs graph replay (same frame replayed)."""
import os, time
import warp as wp
wp.config.log_level = wp.LOG_WARNING
wp.init()
from cisp_warp.photons import PhotonSettings
from cisp_warp.render import Renderer, RenderSettings
from cisp_warp.usd import load_usd
dev = wp.get_device("cuda:0")
for scene_name in ("cornell_flooded", "pool"):
    scene = load_usd(f"scenes_usd/{scene_name}.usda", width=1920, height=1080, device=dev)
    r = Renderer(scene, RenderSettings(rsm_size=2048, method="cisp", photons=PhotonSettings(photons=2_000_000)), device=dev)
    for _ in range(4):
        r.render_frame()
    wp.synchronize()
    t0 = time.perf_counter()
    for _ in range(20):
        r.render_frame()
    wp.synchronize()
    plain = (time.perf_counter() - t0) / 20 * 1e3
    t0 = time.perf_counter()
    for _ in range(20):
        r.render_frame()
    host = (time.perf_counter() - t0) / 20 * 1e3  # host time to enqueue (GPU may still run)
    wp.synchronize()
    try:
        wp.capture_begin(device=dev)
        try:
            r.render_frame()
        finally:
            graph = wp.capture_end(device=dev)
        wp.capture_launch(graph)
        wp.synchronize()
        t0 = time.perf_counter()
        for _ in range(20):
            wp.capture_launch(graph)
        wp.synchronize()
        g = (time.perf_counter() - t0) / 20 * 1e3
        print(f"{scene_name}: wall ms per frame plain {plain:.3f} (host enqueue {host:.3f}), graph replay {g:.3f}")
    except Exception as e:
        print(f"{scene_name}: plain {plain:.3f} ms (host enqueue {host:.3f}); capture failed: {type(e).__name__}: {str(e)[:300]}")
