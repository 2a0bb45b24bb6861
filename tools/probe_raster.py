#!/usr/bin/env python3
"""Raster probe: every draw of one frame of a scene, replayed apart and timed per tile-raster kernel; work counts.

    python tools/probe_raster.py --device cuda:0 --scenes pool,cornell --json out.json
    python tools/probe_raster.py --device cpu --smoke          # tiny sizes: a check that it runs

Renders a few frames of ``cisp`` (the one-stream program), records the draws of the next frame (view, size, layers),
then replays each draw's set-up and times the tile-raster variants on it with CUDA events (``--reps`` launches each,
into scratch buffers: ``atomic_min`` does the same work whatever the buffers hold): ``raster_tiles`` (the naive twin),
``raster_tiles_reject`` (tiles outside an edge skipped; also at 4 blocks an SM),
``raster_tile_rows`` (a thread per item row). Counts per draw: sub-triangles drawn, (sub-triangle, tile)
items, items with no covered pixel centre, pixel tests and fragments (covered, in depth range). The variants' buffers
are compared with the naive twin's (on CUDA they may differ by FMA contraction: the count of differing keys).
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np
import warp as wp

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _make_counter():
    from cisp_warp.raster import kernels as K

    @wp.kernel
    def count_items(sub_v: wp.array(dtype=wp.vec3), sub_bbox: wp.array(dtype=wp.vec4i),
                    tile_end: wp.array(dtype=wp.int32), n_sub: int, out: wp.array(dtype=wp.int32)):
        item = wp.tid()
        s, i_lo, i_hi, j_lo, j_hi = K._tile_of_item(tile_end, n_sub, sub_bbox, item)
        a = sub_v[3 * s + 0]
        b = sub_v[3 * s + 1]
        c = sub_v[3 * s + 2]
        cov = int(0)
        for j in range(j_lo, j_hi + 1):
            y = float(j) + 0.5
            for i in range(i_lo, i_hi + 1):
                x = float(i) + 0.5
                if K._shared_edge(b, c, x, y) >= 0.0 and K._shared_edge(c, a, x, y) >= 0.0 and K._shared_edge(a, b, x, y) >= 0.0:
                    cov += 1
        out[2 * item] = (i_hi - i_lo + 1) * (j_hi - j_lo + 1)
        out[2 * item + 1] = cov

    # raster_tiles_reject at 4 blocks of 256 an SM (64 registers; 3 without the bound): same function, own module
    reject_b4 = wp.kernel(K.raster_tiles_reject.func, launch_bounds=(256, 4), module="unique")
    return count_items, reject_b4


def probe_scene(scene_path, args, device):
    from cisp_warp.photons import PhotonSettings
    from cisp_warp.raster import kernels as K
    from cisp_warp.raster.rasterizer import Rasterizer
    from cisp_warp.render import Renderer, RenderSettings
    from cisp_warp.usd import load_usd

    scene = load_usd(scene_path, width=args.width, height=args.height, device=device)
    settings = RenderSettings(rsm_size=args.rsm_size, method="cisp", photons=PhotonSettings(photons=args.photons),
                              denoiser="svgf")
    r = Renderer(scene, settings, device=device)
    r.set_concurrent(False)
    r.use_graph = False
    for _ in range(3):
        r.render_frame()
    calls = []
    orig_draw = Rasterizer.draw

    def rec(self, views, view_index, width, height, layer, visibility, clear=True, layer_b=0, visibility_b=None):
        calls.append((self, views, view_index, width, height, layer, layer_b))
        return orig_draw(self, views, view_index, width, height, layer, visibility, clear, layer_b, visibility_b)

    Rasterizer.draw = rec
    try:
        r.render_frame()
    finally:
        Rasterizer.draw = orig_draw
    wp.synchronize_device(device)
    counter, reject_b4 = _make_counter()
    rows = []
    for (raster, views, vi, w, h, layer, layer_b) in calls:
        far = float(views.list()[vi].far)
        n_sub = 2 * raster.scene.triangle_count
        raster._setup(views, vi, w, h, layer | layer_b, back_only=False)
        total = int(raster.tile_end.numpy()[-1])
        row = {"size": f"{w}x{h}", "layer": layer, "layer_b": layer_b, "active": far > 0.0, "items": total,
               "subs": int((raster.tile_count.numpy() > 0).sum())}
        if total > 0:
            cnt = wp.zeros(2 * total, dtype=wp.int32, device=device)
            wp.launch(counter, dim=total, device=device, inputs=[raster.sub_v, raster.sub_bbox, raster.tile_end, n_sub, cnt])
            c = cnt.numpy().reshape(-1, 2)
            row.update(pixel_tests=int(c[:, 0].sum()), covered=int(c[:, 1].sum()),
                       empty_items=int((c[:, 1] == 0).sum()))
        bufs = [wp.full(w * h, K.EMPTY_KEY_VALUE, dtype=wp.uint64, device=device) for _ in range(2)]
        s = raster.scene
        variants = {"raster_tiles": (K.raster_tiles, 256), "reject": (K.raster_tiles_reject, 256),
                    "reject_b4": (reject_b4, 256), "reject_bd128": (K.raster_tiles_reject, 128),
                    "tile_rows": (K.raster_tile_rows, 256)}
        ref = None
        for name, (kern, block) in variants.items():
            for b in bufs:
                b.fill_(K.EMPTY_KEY_VALUE)
            inputs = [views, int(vi), raster.sub_v, raster.sub_bbox, raster.tile_end, n_sub, raster.stride,
                      s.triangle_layers, int(layer), bufs[0], int(layer_b), bufs[1]]
            wp.launch(kern, dim=raster.stride, device=device, inputs=inputs, block_dim=block)
            out = [b.numpy().copy() for b in bufs]
            if ref is None:
                ref = out
            else:
                row[f"{name}_diff_keys"] = int(sum((x != y).sum() for x, y in zip(ref, out)))
                low = np.uint64(0xFFFFFFFF)
                row[f"{name}_diff_tri"] = int(sum(((x & low) != (y & low)).sum() for x, y in zip(ref, out)))
            if device.is_cuda:  # a graph of `reps` launches, replayed: no host launch overhead in the time
                wp.capture_begin(device, force_module_load=False)
                try:
                    for _ in range(args.reps):
                        wp.launch(kern, dim=raster.stride, device=device, inputs=inputs, block_dim=block)
                finally:
                    graph = wp.capture_end(device)
                wp.capture_launch(graph)
                e0, e1 = wp.Event(device, enable_timing=True), wp.Event(device, enable_timing=True)
                wp.record_event(e0)
                wp.capture_launch(graph)
                wp.record_event(e1)
                wp.synchronize_device(device)
                row[f"{name}_ms"] = round(wp.get_event_elapsed_time(e0, e1) / args.reps, 5)
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenes", default="pool,cornell")
    p.add_argument("--device", default=None)
    p.add_argument("--width", type=int, default=1920)
    p.add_argument("--height", type=int, default=1080)
    p.add_argument("--rsm-size", type=int, default=2048)
    p.add_argument("--photons", type=int, default=2_000_000)
    p.add_argument("--reps", type=int, default=10)
    p.add_argument("--smoke", action="store_true")
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    if args.smoke:
        args.width, args.height, args.rsm_size, args.photons, args.reps = 64, 36, 64, 2000, 1
    wp.init()
    sys.path.insert(0, ROOT)
    device = wp.get_device(args.device)
    names = {"pool": "pool.usda", "cornell": "cornell_flooded.usda"}
    report = {}
    for sname in args.scenes.split(","):
        print(f"== {sname}", flush=True)
        report[sname] = probe_scene(os.path.join(ROOT, "scenes_usd", names.get(sname, sname)), args, device)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
