#!/usr/bin/env python3
"""Raster probe: every draw of one frame of a scene, replayed apart and timed per tile-raster kernel; work counts.

    python tools/probe_raster.py --device cuda:0 --scenes pool,cornell --json out.json
    python tools/probe_raster.py --device cpu --smoke          # tiny sizes: a check that it runs

Renders a few frames of ``cisp`` (the one-stream program), records the draws of the next frame (view, size, layers),
then replays each draw's set-up and times the tile-raster variants on it with CUDA events (``--reps`` launches each,
into scratch buffers: ``atomic_min`` does the same work whatever the buffers hold): ``raster_tiles`` (the naive twin),
``raster_tiles_reject`` (tiles outside an edge skipped; with ``--all-variants`` also at 256 and at 4 blocks an SM),
``raster_tile_rows`` (a thread per item row), the binned raster (``raster_bin_items`` + ``raster_bins``, bins of 48
and 96 sub-triangles), ``binned_lb8`` (``raster_bins`` bounded to 8 blocks of 128 an SM), ``binned_px1`` (a thread a
pixel) and ``bins_pass`` (``raster_bins`` alone over the bins one binned draw left: a time, not compared). Counts
per draw: sub-triangles drawn, (sub-triangle, tile) items, items with no covered pixel centre, pixel tests and
fragments (covered, in depth range), bin entries, the fullest bin and the items past full bins (48). The variants'
buffers are compared with the naive twin's (on CUDA they may differ by FMA contraction: the count of differing keys).
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
    @wp.kernel
    def bins_px1(views: wp.array(dtype=K.ViewParams), view_index: int, sub_v: wp.array(dtype=wp.vec3),
                 sub_bbox: wp.array(dtype=wp.vec4i), stride: int, layers: wp.array(dtype=wp.int32), mask: int,
                 visibility: wp.array(dtype=wp.uint64), mask_b: int, visibility_b: wp.array(dtype=wp.uint64),
                 tiles_x: int, tiles: int, capacity: int, bin_fill: wp.array(dtype=wp.int32),
                 bin_subs: wp.array(dtype=wp.int32)):
        """raster_bins with a thread per pixel (two warps a tile, a key per layer a thread): `stride` a multiple of 64."""
        view = views[view_index]
        if view.far <= 0.0:
            return
        t = wp.tid()
        px = t % (K.TILE * K.TILE)
        tile = t / (K.TILE * K.TILE)
        while tile < tiles:
            i = (tile % tiles_x) * K.TILE + px % K.TILE
            j = (tile / tiles_x) * K.TILE + px / K.TILE
            n = wp.min(bin_fill[tile], capacity)
            ka = wp.uint64(K.EMPTY_KEY_VALUE)
            kb = wp.uint64(K.EMPTY_KEY_VALUE)
            for k in range(n):
                sub = bin_subs[tile * capacity + k]
                a, b, c, e0, e1, e2 = K._item_edges(sub_v, sub)
                if K._bin_pixel_covered(e0, e1, e2, sub_bbox[sub], i, j):
                    inv_area, tri, to_a, to_b = K._item_setup(a, b, c, sub, layers, mask, mask_b)
                    x = float(i) + 0.5
                    y = float(j) + 0.5
                    depth = K.fragment_depth(view, a, b, c, K._edge_at(e0, x, y), K._edge_at(e1, x, y),
                                             K._edge_at(e2, x, y), inv_area)
                    if depth > 0.0 and depth <= view.far:
                        key = K.depth_key(view, depth, tri)
                        if to_a:
                            ka = wp.min(ka, key)
                        if to_b:
                            kb = wp.min(kb, key)
            K._bin_write(ka, j * view.width + i, visibility)
            if mask_b != 0:
                K._bin_write(kb, j * view.width + i, visibility_b)
            tile += stride / (K.TILE * K.TILE)

    # raster_bins bounded to 8 blocks of 128 an SM (at most 64 registers; 82 unbounded, 6 blocks): its own module
    bins_lb8 = wp.kernel(K.raster_bins.func, launch_bounds=(K.BIN_BLOCK, 8), module="unique")
    return count_items, reject_b4, bins_lb8, bins_px1


def probe_scene(scene_path, args, device):
    from cisp_warp.photons import PhotonSettings
    from cisp_warp.raster import kernels as K
    from cisp_warp.raster.rasterizer import Rasterizer
    from cisp_warp.render import Renderer, RenderSettings
    from cisp_warp.usd import load_usd

    scene = load_usd(scene_path, width=args.width, height=args.height, device=device)
    settings = RenderSettings(rsm_size=args.rsm_size, method="cisp", photons=PhotonSettings(photons=args.photons),
                              denoiser="svgf")
    binned_default = Rasterizer.BINNED
    Rasterizer.BINNED = False  # every draw through Rasterizer.draw (the fused RSM pass, section 66, draws without it)
    try:
        r = Renderer(scene, settings, device=device)
    finally:
        Rasterizer.BINNED = binned_default
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
    counter, reject_b4, bins_lb8, bins_px1 = _make_counter()
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
        inputs = [views, int(vi), raster.sub_v, raster.sub_bbox, raster.tile_end, n_sub, raster.stride,
                  s.triangle_layers, int(layer), bufs[0], int(layer_b), bufs[1]]

        def kernel_launch(kern, block):
            return lambda: wp.launch(kern, dim=raster.stride, device=device, inputs=inputs, block_dim=block)

        def binned(capacity, bins_kernel=None):
            def go():
                raster.bin_capacity = capacity
                if bins_kernel is None:
                    # the frame's setup_triangles zeroes the counts (clear_bins); the probe set up once, so a memset
                    # here (as section 60's binned_ms had it: comparable with its figures)
                    tiles = raster.bins_for(w, h)
                    raster.bin_fill[:tiles].zero_()
                    raster._draw_binned(views, vi, w, h, layer, bufs[0], layer_b, bufs[1])
                    return
                # Rasterizer._draw_binned with another raster_bins build
                tiles = raster.bins_for(w, h)
                fill = raster.bin_fill[:tiles]
                fill.zero_()
                wp.launch(K.raster_bin_items, dim=raster.stride, device=device, block_dim=K.RASTER_BLOCK,
                          inputs=inputs + [(w + K.TILE - 1) // K.TILE, capacity, fill, raster.bin_subs])
                per_tile = K.TILE * K.TILE if bins_kernel is bins_px1 else K.WARP
                threads = max(per_tile, min(raster.stride, tiles * per_tile) // per_tile * per_tile)
                wp.launch(bins_kernel, dim=threads, device=device, block_dim=K.BIN_BLOCK,
                          inputs=[views, int(vi), raster.sub_v, raster.sub_bbox, threads, s.triangle_layers,
                                  int(layer), bufs[0], int(layer_b), bufs[1], (w + K.TILE - 1) // K.TILE, tiles,
                                  capacity, fill, raster.bin_subs])
            return go

        def bins_pass():  # raster_bins alone, over the bins the last binned draw left (capacity 48)
            tiles = raster.bins_for(w, h)
            threads = min(raster.stride, tiles * K.WARP)
            wp.launch(K.raster_bins, dim=threads, device=device, block_dim=K.BIN_BLOCK,
                      inputs=[views, int(vi), raster.sub_v, raster.sub_bbox, threads, s.triangle_layers, int(layer),
                              bufs[0], int(layer_b), bufs[1], (w + K.TILE - 1) // K.TILE, tiles, 48,
                              raster.bin_fill, raster.bin_subs])

        variants = {"raster_tiles": kernel_launch(K.raster_tiles, 256),
                    "reject_bd128": kernel_launch(K.raster_tiles_reject, 128),
                    "tile_rows": kernel_launch(K.raster_tile_rows, 256), "binned_c96": binned(96),
                    "binned_lb8": binned(48, bins_lb8), "binned_px1": binned(48, bins_px1), "binned": binned(48),
                    "bins_pass": bins_pass}
        if args.all_variants:
            variants.update(reject=kernel_launch(K.raster_tiles_reject, 256), reject_b4=kernel_launch(reject_b4, 256))
        ref = None
        for name, launch in variants.items():
            for b in bufs:
                b.fill_(K.EMPTY_KEY_VALUE)
            launch()
            out = [b.numpy().copy() for b in bufs]
            if name == "binned":
                fill = raster.bin_fill.numpy()[:raster.bins_for(w, h)]
                row.update(bin_entries=int(fill.sum()), bin_max=int(fill.max()) if fill.size else 0,
                           bin_overflow_items=int(np.maximum(fill - 48, 0).sum()))
            if ref is None:
                ref = out
            elif name != "bins_pass":  # bins_pass leaves out the overflowed items: a time, not a raster
                row[f"{name}_diff_keys"] = int(sum((x != y).sum() for x, y in zip(ref, out)))
                low = np.uint64(0xFFFFFFFF)
                row[f"{name}_diff_tri"] = int(sum(((x & low) != (y & low)).sum() for x, y in zip(ref, out)))
            if device.is_cuda:  # a graph of `reps` launches, replayed: no host launch overhead in the time
                wp.capture_begin(device, force_module_load=False)
                try:
                    for _ in range(args.reps):
                        launch()
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
    p.add_argument("--all-variants", action="store_true", help="also raster_tiles_reject at 256 and at 4 blocks an SM")
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
